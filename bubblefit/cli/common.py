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

__all__ = ["parse_floats", "guard_outputs", "guard_args", "scene_inputs", "folder_files", "write_json",
           "input_file", "output_file", "output_folder", "InputFile", "OutputFile", "OutputFolder",
           "model_option_values", "add_film_rgb_option"]

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


class InputFile(str):
    """A command-line value that names a file the command reads (or, for options such as
    ``--illuminant``, may name one). Declared with ``type=input_file``; :func:`guard_args`
    finds every such value in the parsed arguments, so no output can replace it."""


class OutputFile(str):
    """A command-line value that names a file the command writes (``type=output_file``)."""


class OutputFolder(str):
    """A command-line value that names a folder the command writes into, created if
    missing (``type=output_folder``)."""


def _path_text(text: str, kind: str) -> str:
    """``text`` as given, or an ``argparse`` error for a path that cannot be passed on to the
    image libraries (a name that is not valid UTF-8, kept by Python as lone surrogates)."""
    import argparse

    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        shown = text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
        raise argparse.ArgumentTypeError(f"{kind} {shown!r} is not a UTF-8 path (rename it)") from None
    if not text:
        raise argparse.ArgumentTypeError(f"empty {kind} name")
    return text


def input_file(text: str) -> InputFile:
    """``argparse`` type of a file argument the command reads."""
    return InputFile(_path_text(text, "input"))


def output_file(text: str) -> OutputFile:
    """``argparse`` type of a file argument the command writes."""
    return OutputFile(_path_text(text, "output"))


class OutputPrefix(str):
    """A command-line value that starts the names of the files a command writes
    (``type=output_prefix``); the command passes those files to :func:`guard_args`."""


def output_prefix(text: str) -> OutputPrefix:
    """``argparse`` type of a prefix of output file names (``fit -o PREFIX``)."""
    return OutputPrefix(_path_text(text, "output prefix"))


def output_folder(text: str) -> OutputFolder:
    """``argparse`` type of a folder argument the command writes into."""
    return OutputFolder(_path_text(text, "output folder"))


def _declared(args) -> tuple[list, list, list]:
    """(inputs, output files, output folders) declared in the parsed ``args``: every value,
    or list of values, of type :class:`InputFile`, :class:`OutputFile`, :class:`OutputFolder`."""
    ins, outs, folders = [], [], []
    for value in vars(args).values():
        for v in value if isinstance(value, (list, tuple)) else (value,):
            if isinstance(v, InputFile):
                ins.append(v)
            elif isinstance(v, OutputFile):
                outs.append(v)
            elif isinstance(v, OutputFolder):
                folders.append(v)
    return ins, outs, folders


def check_writable(outputs: Iterable[PathLike | None], folders: Iterable[PathLike | None] = ()) -> None:
    """Refuse, before any work, an output whose folder is missing or not writable, and an
    output folder that cannot be created (its parent missing or not writable)."""
    for p in outputs:
        if p is None:
            continue
        real = Path(os.path.realpath(os.fspath(p)))
        if real.is_dir():
            raise OutputError(f"cannot write {p}: it is a folder")
        if not real.parent.is_dir():
            raise OutputError(f"cannot write {p}: folder {Path(p).parent} does not exist")
        if not os.access(real.parent, os.W_OK) and not (real.exists() and not real.is_file()):
            raise OutputError(f"cannot write {p}: folder {Path(p).parent} is not writable")
    for f in folders:
        if f is None:
            continue
        real = Path(os.path.realpath(os.fspath(f)))
        if real.exists() and not real.is_dir():
            raise OutputError(f"cannot write into {f}: it is not a folder")
        target = real if real.is_dir() else real.parent
        if not target.is_dir():
            raise OutputError(f"cannot create {f}: folder {target} does not exist")
        if not os.access(target, os.W_OK):
            raise OutputError(f"cannot write into {f}: folder {target} is not writable")


def guard_args(args, inputs: Iterable[PathLike | None] = (), outputs: Iterable[PathLike | None] = ()) -> None:
    """The output contract, checked before any work, for every file argument declared in
    ``args`` (:func:`input_file`, :func:`output_file`, :func:`output_folder`) and the
    files a command derives (``inputs``: those a scene file names, a folder's frames;
    ``outputs``: previews, ``PREFIX_*`` files): no output is an input or another output
    (:func:`guard_outputs`), and every output's folder exists and is writable
    (:func:`check_writable`)."""
    ins, outs, folders = _declared(args)
    outs = outs + [p for p in outputs if p is not None]
    guard_outputs([*ins, *inputs], outs)
    check_writable(outs, folders)


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
    parser.add_argument("--illuminant", default=None, type=input_file,
                        help="illuminant: D65 (default; a fit takes the lamp a --camera-response CSV from "
                             "calibrate-camera names), E, A, another CIE name, or a CSV wavelength_nm,power")
    parser.add_argument("--camera-response", default=None, type=input_file,
                        help="camera response: srgb (default), a colour-science camera (e.g. 'Nikon 5100 (NPL)'), "
                             "or a CSV wavelength_nm,r,g,b; white-balanced to the illuminant")


def add_film_rgb_option(parser) -> None:
    """``--film-rgb``: how the physical model colours each film
    (:attr:`~bubblefit.model.render.RenderConfig.film_rgb`)."""
    parser.add_argument("--film-rgb", choices=("spectral", "clamped"), default=None,
                        help="how the physical model colours each film: spectral (the physics a camera sees) or "
                             "clamped (each film's RGB reflectance clamped to [0, 1] before the bounces, as Blender "
                             "Cycles' thin film in the Principled BSDF shades it: for renders made by Cycles, not "
                             "photographs); the paper model ignores it [the scene's [film] film_rgb, else spectral]")


def colour_option(value: str | None, named, option: str) -> str | None:
    """An option's illuminant/response: a name as is, a file as an absolute path."""
    import os

    if value is None or named(value):
        return value
    if not os.path.isfile(value):
        from ..errors import InputError

        raise InputError(f"{option} {value!r} is neither a known name nor a file")
    return os.path.abspath(value)


def auto_exposure(img: np.ndarray) -> float:
    """Exposure that maps the 99.5th percentile of a linear image to 0.9 (1 if it is dark):
    the PNG previews of ``render``."""
    import numpy as np

    hi = float(np.percentile(img, 99.5)) if img.size else 0.0
    return 0.9 / hi if hi > 0.9 else 1.0


def write_fit_images(prefix: str, result, write_image, preview_path) -> dict:
    """A fit's images: ``PREFIX_render``, ``_residual``, ``_thickness``, ``_thickness_stderr`` (EXR + PNG; the
    residual's and the maps' PNGs are the figures of :mod:`bubblefit.report.figures`)."""
    import numpy as np

    from ..report import figures

    files = {"render": result.render, "residual": result.residual}
    if result.thickness_map is not None:
        files["thickness"] = result.thickness_map
    if result.thickness_stderr_map is not None:
        files["thickness_stderr"] = result.thickness_stderr_map
    for name, img in files.items():
        path = f"{prefix}_{name}.exr"
        write_image(path, img, bit_depth=32 if name.startswith("thickness") else None)
        if name == "render":
            hi_ = float(np.percentile(img, 99.5)) if img.size else 1.0
            write_image(preview_path(path), img * (0.9 / hi_ if hi_ > 0.9 else 1.0))
        elif name == "residual":  # titled, with a colour bar in the photo's linear units
            figures.residual_figure(preview_path(path), img, result.residual_rms)
        else:  # titled, with a colour bar in nm
            title = "film thickness" if name == "thickness" else "standard error of the thickness"
            figures.map_figure(preview_path(path), img, title, "viridis" if name == "thickness" else "magma",
                               "thickness (nm)" if name == "thickness" else "standard error (nm)")
    return {k: f"{prefix}_{k}.exr" for k in files}


def model_option_values(args) -> dict:
    """``illuminant``, ``camera_response``, ``n_film``, ``samples_per_pixel`` and ``film_rgb`` of
    :class:`~bubblefit.inverse.fit.FitOptions` from the flags of
    :func:`~bubblefit.cli.fit.add_model_options` (None where not given: the scene's then
    apply), checked before any photo is read, and ``judge`` with ``--colour-check``."""
    from ..inverse import JudgeSettings
    from ..model import samples_per_pixel
    from ..optics import spectral

    ill = colour_option(args.illuminant, spectral.is_named_illuminant, "--illuminant")
    resp = colour_option(args.camera_response, spectral.is_named_response, "--camera-response")
    if ill is not None:
        spectral.illuminant_spectrum(ill)
    if resp is not None:
        spectral.response_functions(resp)
    spp = args.samples_per_pixel
    if spp is not None:
        samples_per_pixel(spp, "--samples-per-pixel")
    return dict(illuminant=ill, camera_response=resp, n_film=film_index(args.n_film, args.cauchy, None),
                samples_per_pixel=spp, pixel_footprint=getattr(args, "pixel_footprint", None),
                film_rgb=getattr(args, "film_rgb", None),
                judge=JudgeSettings(colour_check=getattr(args, "colour_check", "decide")))
