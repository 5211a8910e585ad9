"""Helpers shared by the sub-commands: value parsing, output guards, JSON results.

This module is imported while the parsers are built, so it imports nothing heavy (no
JAX, OpenImageIO, colour-science, OpenCV, SciPy nor Matplotlib): ``bubblefit CMD --help``
and argument errors stay within a few times the start-up of ``python -c "import numpy"``
(``experiments/profile_startup.py``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Iterable

from ..errors import InputError, OutputError
from ..io.atomic import write_json

__all__ = ["parse_floats", "guard_outputs", "scene_inputs", "folder_files", "write_json"]

PathLike = str | os.PathLike


def parse_floats(text: str, n: int, name: str, *, finite: bool = True) -> tuple[float, ...]:
    """Parse ``"a,b,c"`` into ``n`` floats, or raise a one-line error naming ``name``.

    ``finite`` (default) also refuses ``nan`` and ``inf``: no option of the command line
    takes them.
    """
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{name} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n:
        raise InputError(f"{name} must be {n} comma-separated numbers, got {text!r}")
    if finite and not all(math.isfinite(v) for v in vals):
        raise InputError(f"{name} must be finite numbers, got {text!r}")
    return vals


def _identity(path: PathLike) -> tuple[str, tuple[int, int] | None, bool]:
    """(resolved path, (device, inode) when it exists, True when it is a regular file or absent)."""
    real = os.path.realpath(os.fspath(path))
    try:
        st = os.stat(real)
    except OSError:
        return real, None, True
    import stat

    return real, (st.st_dev, st.st_ino), stat.S_ISREG(st.st_mode)


def guard_outputs(inputs: Iterable[PathLike | None], outputs: Iterable[PathLike | None]) -> None:
    """Refuse, in one line, an output that is one of the inputs or another output.

    Every command calls this once it knows all its paths, before any work: the outputs
    it will write (automatic previews included) against the files it reads. Two paths
    are the same file when they resolve to the same path (links followed) or, for files
    that exist, share device and inode (hard links, bind mounts). Non-regular outputs
    (``/dev/null``, FIFOs) are written in place and never clash. ``None`` entries are
    skipped, so optional arguments can be passed as they are.

    Raises
    ------
    OutputError
        An output would overwrite an input, or two outputs are one file.
    """
    seen_in = []
    for p in inputs:
        if p is not None:
            real, ino, _ = _identity(p)
            seen_in.append((p, real, ino))
    seen_out = []
    for p in outputs:
        if p is None:
            continue
        real, ino, regular = _identity(p)
        if not regular:
            continue
        for q, qreal, qino in seen_in:
            if real == qreal or (ino is not None and ino == qino):
                raise OutputError(f"refusing to write {p}: it is the input {q} (choose another output name)")
        for q, qreal, qino in seen_out:
            if real == qreal or (ino is not None and ino == qino):
                raise OutputError(f"refusing to write {p} twice: {q} and {p} are the same file")
        seen_out.append((p, real, ino))


def folder_files(folder: PathLike) -> list[Path]:
    """The files directly inside ``folder`` (none if it is not a folder): inputs of commands that read folders."""
    try:
        return [p for p in Path(folder).iterdir() if p.is_file()]
    except OSError:
        return []


def scene_inputs(scene) -> list[Path]:
    """The files a loaded scene reads: its environment map, background photo, thickness
    map, and illuminant or camera-response tables (``[lighting]``, ``[bubble.thickness]``,
    ``[camera]``), resolved against the scene's folder."""
    out = []
    lighting, camera = scene.table("lighting"), scene.table("camera")
    thickness = scene.table("bubble").get("thickness")
    candidates = [lighting.get("envmap"), lighting.get("background"), lighting.get("illuminant"),
                  camera.get("response"), thickness.get("path") if isinstance(thickness, dict) else None]
    for value in candidates:
        if isinstance(value, str) and value not in ("envmap", "black"):
            path = scene.resolve_path(value)
            if path.exists():
                out.append(path)
    return out


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


def add_index_options(parser, default: str = "1.4") -> None:
    """``--n-film`` and ``--cauchy`` (one or the other; :func:`film_index` reads them)."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--n-film", default=None, help=f"film index: a number or a preset (water, soap); default {default}")
    g.add_argument("--cauchy", metavar="A,B[,C]", help="film index n = A + B/lambda^2 + C/lambda^4, lambda in nm")


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
