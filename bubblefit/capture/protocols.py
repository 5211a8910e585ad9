"""Capture protocols: machine-readable specs and the checks ``bubblefit check-capture`` runs.

Each protocol of ``capture_protocols/`` is a Markdown document for the person with the
camera and a TOML spec (read with :mod:`tomllib`) naming the files, the metadata and the
checks it requires. :func:`check_capture` reads the images of a folder with OpenImageIO
(:func:`bubblefit.io.images.read_image`), runs the checks the spec asks for and returns one
:class:`CheckResult` per check, each with a reason a person can act on.

The checks and what they implement:

- ``files``: every role of the spec (e.g. ``before`` / ``after``) matches the required
  number of files (case-insensitive globs on the file name, one or several per role).
- ``readable``, ``same_size``: each file reads; all have the same pixel size.
- ``bit_depth``: files below the spec's ``min_bit_depth`` give a warning.
- ``metadata``: the EXIF attributes the spec requires are present.
- ``locked``: the listed attributes (exposure time, aperture, ISO, white balance, focal
  length) are equal across the files that must share them.
- ``white_balance``: EXIF WhiteBalance is manual (1), not auto (0) (EXIF 2.3, tag 0xA403).
- ``photometric``: the pair shows the same background with the same exposure and white
  balance: the per-channel median ratio of the pair over well-exposed pixels outside the
  subject is within the
  tolerance of 1 (a changed exposure scales all channels, a changed white balance does not).
- ``registration``: the camera did not move between the pair (or the brackets): frames
  that agree pixel by pixel outside the subject are registered; otherwise a translation
  by phase correlation of the log luminance (Kuglin & Hines 1975, OpenCV
  ``phaseCorrelate``) is reported only when the colour channels agree on it and undoing
  it explains the difference (:func:`bubblefit.capture.measure.measure_shift`).
- ``subject``: the bubble is found where the pair differs (or the mirror ball by
  :func:`bubblefit.capture.ball.find_ball`), large enough, inside the frame.
- ``saturation``: no clipped pixel inside the bubble or the ball (in the darkest exposure for
  brackets; paper sec. 3.2: clipped highlights lose the relative brightness of the sky).
- ``brackets``: enough exposures, spanning enough stops, with gaps no wider than allowed
  (Debevec & Malik 1997: every radiance must be well exposed in some exposure).
"""


from __future__ import annotations

import os
import tomllib
from pathlib import Path

from ..errors import InputError
from ..io.images import Image, read_image
from .checks import (
    check_ball,
    check_bracket_registration,
    check_brackets,
    check_difference_pairs,
    check_frame_saturation,
    check_metadata,
    match_roles,
)
from .report import FAIL, PASS, WARN, CaptureReport, CheckResult, format_table

__all__ = ["CaptureReport", "CheckResult", "protocols_dir", "list_protocols", "load_protocol", "check_capture", "format_table"]


# --------------------------------------------------------------------------------------
# Specs
# --------------------------------------------------------------------------------------


def protocols_dir() -> Path:
    """The folder of protocol specs: ``$BUBBLEFIT_PROTOCOLS`` if set, else the repository's
    ``capture_protocols/`` beside the package."""
    env = os.environ.get("BUBBLEFIT_PROTOCOLS")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "capture_protocols"


def list_protocols() -> list[str]:
    """Names of the protocols whose TOML specs are in :func:`protocols_dir`."""
    folder = protocols_dir()
    return sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []


def load_protocol(name_or_path: str | os.PathLike) -> dict:
    """Load a protocol spec (TOML, parsed with :mod:`tomllib`).

    Args:
        name_or_path: a protocol name (``transmission``, ``envmap``, ``bubble``, or any spec
            in :func:`protocols_dir`) or the path of a ``.toml`` spec.

    Returns:
        The spec as a dict, with ``name`` filled in and ``files`` a list of role tables.

    Raises:
        InputError: unknown protocol, unreadable or invalid TOML, or a spec without files.
    """
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith(".toml") or path.is_file()):
        path = protocols_dir() / f"{text}.toml"
        if not path.is_file():
            known = ", ".join(list_protocols()) or "none found in " + str(protocols_dir())
            raise InputError(f"unknown capture protocol {text!r} (known: {known})")
    if not path.is_file():
        raise InputError(f"protocol spec not found: {path}")
    try:
        spec = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read protocol spec {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"protocol spec {path} is not valid TOML: {exc}") from None
    spec.setdefault("name", path.stem)
    roles = spec.get("files")
    if not isinstance(roles, list) or not roles or not all(isinstance(r, dict) and "role" in r for r in roles):
        raise InputError(f"protocol spec {path} must list its files as [[files]] tables with a 'role'")
    for r in roles:
        pats = r.get("pattern", f"{r['role']}*")
        pats = [pats] if isinstance(pats, str) else pats
        if not isinstance(pats, list) or not pats or not all(isinstance(p, str) and p for p in pats):
            raise InputError(f"protocol spec {path}: the pattern of role {r['role']!r} must be a glob or a list of globs")
        r["patterns"] = pats
        r["pattern"] = " or ".join(pats)
        r.setdefault("min_count", 1)
        r.setdefault("max_count", r["min_count"] if r["min_count"] > 0 else 1)
    for section in ("metadata", "checks"):
        if section in spec and not isinstance(spec[section], dict):
            raise InputError(f"protocol spec {path}: [{section}] must be a table")
    spec["_path"] = str(path)
    return spec



def check_capture(folder: str | os.PathLike, protocol: str | os.PathLike | dict) -> CaptureReport:
    """Check a capture folder against a protocol.

    Parameters
    ----------
    folder
        The folder holding the capture's image files.
    protocol
        A protocol name, a spec path, or a spec dict from :func:`load_protocol`.

    Returns
    -------
    CaptureReport
        ``report.passed`` is False when any check failed.

    Raises
    ------
    InputError
        The folder is missing or holds no images, or the protocol is unknown.
    """
    spec = protocol if isinstance(protocol, dict) else load_protocol(protocol)
    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"capture folder not found: {folder}")
    if not folder.is_dir():
        raise InputError(f"expected a capture folder, got a file: {folder}")
    report = CaptureReport(protocol=spec["name"], folder=str(folder))
    roles = match_roles(folder, spec, report)
    if roles is None:
        return report
    imgs = _read_images(roles, report)
    if imgs is None or not _check_sizes(spec, imgs, report):
        return report
    check_metadata(spec, imgs, report)
    kind = spec.get("checks", {}).get("subject", "none")
    if kind == "difference" and spec.get("checks", {}).get("pair"):
        check_difference_pairs(spec, roles, imgs, report)
    elif kind == "ball":
        times = check_brackets(spec, imgs, report)
        check_bracket_registration(spec, imgs, times, report)
        check_ball(spec, imgs, times, report)
    else:
        check_frame_saturation(spec, imgs, report)
    return report


def _read_images(roles: dict[str, list[Path]], report: CaptureReport) -> dict[str, Image] | None:
    """Read every matched file (``readable`` check); None when one cannot be read."""
    imgs: dict[str, Image] = {}
    unreadable = []
    for paths in roles.values():
        for p in paths:
            try:
                imgs[p.name] = read_image(p)
            except InputError as exc:
                unreadable.append(str(exc))
    if unreadable:
        report.add("readable", FAIL, "; ".join(unreadable[:3]))
        return None
    report.add("readable", PASS, f"{len(imgs)} image(s) read")
    return imgs


def _check_sizes(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> bool:
    """``same_size`` (False when the sizes differ) and ``bit_depth`` (a warning)."""
    sizes = {n: im.shape for n, im in imgs.items()}
    if len(set(sizes.values())) > 1:
        desc = ", ".join(f"{n}: {w}x{h}" for n, (h, w) in list(sizes.items())[:4])
        report.add("same_size", FAIL, f"images differ in size ({desc}): do not crop or resize")
        return False
    h, w = next(iter(sizes.values()))
    report.add("same_size", PASS, f"all {w}x{h}")
    min_bits = int(spec.get("checks", {}).get("min_bit_depth", 8))
    low = [n for n, im in imgs.items() if im.bit_depth < min_bits]
    if low:
        report.add("bit_depth", WARN, f"{len(low)} file(s) at 8 bits ({', '.join(low[:3])}); "
                                      f"{min_bits}-bit TIFF/PNG or EXR from RAW keeps more of the range")
    return True
