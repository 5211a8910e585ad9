"""Helpers shared by the sub-commands."""

from __future__ import annotations

import json

import numpy as np


def _default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    raise TypeError(f"cannot write {type(o).__name__} as JSON")


def write_json(path, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically (temporary file, then rename)."""
    from ..io.images import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w") as fh:
            json.dump(data, fh, indent=2, default=_default, allow_nan=True)
            fh.write("\n")


def parse_floats(text: str, n: int, name: str) -> tuple[float, ...]:
    """Parse ``"a,b,c"`` into ``n`` floats or raise a one-line error naming ``name``."""
    from ..errors import InputError

    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{name} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n:
        raise InputError(f"{name} must be {n} comma-separated numbers, got {text!r}")
    return vals


def film_index(n_film: str | None, cauchy: str | None, default):
    """The film's index from ``--n-film`` (a number or a preset name) or ``--cauchy A,B[,C]``."""
    from ..optics import dispersion

    if cauchy:
        return dispersion.parse_cauchy(cauchy)
    if n_film is None:
        return default
    try:
        value = float(n_film)
    except ValueError:
        return dispersion.parse_index(n_film, "--n-film")
    return dispersion.parse_index(value, "--n-film")


def add_colour_options(parser) -> None:
    """``--illuminant`` and ``--camera-response`` (:mod:`bubblefit.optics.spectral`)."""
    parser.add_argument("--illuminant", default=None,
                        help="illuminant: D65 (default), E, A, another CIE name, or a CSV wavelength_nm,power")
    parser.add_argument("--camera-response", default=None,
                        help="camera response: srgb (default), a colour-science camera (e.g. 'Nikon 5100 (NPL)'), "
                             "or a CSV wavelength_nm,r,g,b; white-balanced to the illuminant")


def colour_option(value: str | None, named, option: str) -> str | None:
    """An option's illuminant/response: a name as is, a file as an absolute path."""
    import os

    if value is None or named(value):
        return value
    if not os.path.isfile(value):
        from ..errors import InputError

        raise InputError(f"{option} {value!r} is neither a known name nor a file")
    return os.path.abspath(value)
