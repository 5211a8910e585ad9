"""Capture protocols: machine-readable specs and the checks ``bubblefit check-capture`` runs.

Each protocol of ``capture_protocols/`` is a Markdown document for the person with the
camera and a TOML spec (read with :mod:`tomllib`) naming the files, the metadata and the
checks it requires. :func:`check_capture` reads the images of a folder with OpenImageIO
(:func:`bubblefit.io.images.read_image`), runs the checks the spec asks for and returns one
:class:`CheckResult` per check, each with a reason a person can act on.

The checks and what they implement:

- ``files``: every role of the spec (e.g. ``before`` / ``after``) matches the required
  number of files (case-insensitive glob on the file name).
- ``readable``, ``same_size``: each file reads; all have the same pixel size.
- ``bit_depth``: files below the spec's ``min_bit_depth`` give a warning.
- ``metadata``: the EXIF attributes the spec requires are present.
- ``locked``: the listed attributes (exposure time, aperture, ISO, white balance, focal
  length) are equal across the files that must share them.
- ``white_balance``: EXIF WhiteBalance is manual (1), not auto (0) (EXIF 2.3, tag 0xA403).
- ``photometric``: the pair shows the same background with the same exposure and white
  balance: the per-channel median ratio of the pair over well-exposed pixels is within the
  tolerance of 1 (a changed exposure scales all channels, a changed white balance does not).
- ``registration``: the translation between the pair, by phase correlation of the log
  luminance (Kuglin & Hines 1975, OpenCV ``phaseCorrelate``), is below the limit.
- ``subject``: the bubble is found where the pair differs (or the mirror ball by
  :func:`bubblefit.capture.probe.find_ball`), large enough, inside the frame.
- ``saturation``: no clipped pixel inside the bubble or the ball (in the darkest exposure for
  brackets; paper sec. 3.2: clipped highlights lose the relative brightness of the sky).
- ``brackets``: enough exposures, spanning enough stops, with gaps no wider than allowed
  (Debevec & Malik 1997: every radiance must be well exposed in some exposure).
"""

from __future__ import annotations

import fnmatch
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..io.images import Image, read_image

__all__ = [
    "CheckResult",
    "CaptureReport",
    "IMAGE_EXTENSIONS",
    "METADATA_ALIASES",
    "protocols_dir",
    "list_protocols",
    "load_protocol",
    "check_capture",
    "format_table",
    "metadata_value",
    "registration_shift",
    "exposure_ratio",
    "difference_mask",
]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr")

# Canonical metadata names used by the specs -> attribute names OpenImageIO reports
# (EXIF 2.3 renamed ISOSpeedRatings to PhotographicSensitivity; OIIO uses both).
METADATA_ALIASES = {
    "exposure_time": ("ExposureTime", "Exif:ExposureTime"),
    "f_number": ("FNumber", "Exif:FNumber"),
    "iso": ("Exif:PhotographicSensitivity", "Exif:ISOSpeedRatings", "ISOSpeedRatings"),
    "white_balance": ("Exif:WhiteBalance", "WhiteBalance"),
    "focal_length": ("Exif:FocalLength", "FocalLength"),
    "exposure_mode": ("Exif:ExposureMode",),
}

_UNITS = {"exposure_time": "s", "focal_length": "mm"}

PASS, FAIL, WARN, SKIP = "PASS", "FAIL", "WARN", "SKIP"


@dataclass
class CheckResult:
    """One row of the report: ``check`` name, ``status`` (PASS/FAIL/WARN/SKIP), ``reason``."""

    check: str
    status: str
    reason: str

    def as_dict(self) -> dict:
        return {"check": self.check, "status": self.status, "reason": self.reason}


@dataclass
class CaptureReport:
    """All check results of one capture folder.

    Attributes:
        protocol: the protocol's name.
        folder: the folder checked.
        results: the :class:`CheckResult` rows, in the order they ran.
        files: role -> list of file names matched.
        measurements: numbers measured on the way (shift in pixels, stops, ...).
    """

    protocol: str
    folder: str
    results: list[CheckResult] = field(default_factory=list)
    files: dict = field(default_factory=dict)
    measurements: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """True when no check failed (warnings do not fail a capture)."""
        return not any(r.status == FAIL for r in self.results)

    def failed(self) -> list[CheckResult]:
        return [r for r in self.results if r.status == FAIL]

    def add(self, check: str, status: str, reason: str) -> None:
        self.results.append(CheckResult(check, status, reason))

    def as_dict(self) -> dict:
        return {
            "protocol": self.protocol,
            "folder": self.folder,
            "passed": self.passed,
            "results": [r.as_dict() for r in self.results],
            "files": self.files,
            "measurements": self.measurements,
        }


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
        r.setdefault("pattern", f"{r['role']}*")
        r.setdefault("min_count", 1)
        r.setdefault("max_count", r["min_count"] if r["min_count"] > 0 else 1)
    for section in ("metadata", "checks"):
        if section in spec and not isinstance(spec[section], dict):
            raise InputError(f"protocol spec {path}: [{section}] must be a table")
    spec["_path"] = str(path)
    return spec


# --------------------------------------------------------------------------------------
# Measurements
# --------------------------------------------------------------------------------------


def metadata_value(image: Image, name: str):
    """The value of a canonical metadata name (see :data:`METADATA_ALIASES`), or None."""
    for key in METADATA_ALIASES.get(name, (name,)):
        if key in image.metadata:
            return image.metadata[key]
    return None


def _fmt_value(name: str, value) -> str:
    if name == "exposure_time" and isinstance(value, (int, float)) and 0 < value < 1:
        return f"1/{1 / value:.4g} s"
    unit = _UNITS.get(name)
    return f"{value:g} {unit}" if unit and isinstance(value, (int, float)) else f"{value}"


def _same(a, b, rel: float = 2e-3) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(float(a), float(b), rel_tol=rel, abs_tol=1e-12)
    return a == b


def _log_lum(pixels: np.ndarray, scale: float = 1.0) -> np.ndarray:
    lum = pixels[..., 0] * 0.2126 + pixels[..., 1] * 0.7152 + pixels[..., 2] * 0.0722
    return np.log(np.maximum(lum * scale, 1e-4)).astype(np.float32)


def registration_shift(a: np.ndarray, b: np.ndarray, *, scale_b: float = 1.0) -> tuple[float, float]:
    """Translation (dx, dy) in pixels that best aligns ``b`` with ``a``.

    Phase correlation (Kuglin & Hines 1975, "The phase correlation image alignment
    method"; OpenCV ``phaseCorrelate`` with a Hann window) of the log luminance, so that
    exposures of different length (``scale_b`` brings ``b`` to ``a``'s exposure) compare.

    Args:
        a, b: (H, W, 3) linear images of the same size.
        scale_b: factor applied to ``b`` before the comparison.

    Returns:
        ``(dx, dy)``: ``b`` is ``a`` moved by this much.
    """
    la, lb = _log_lum(a), _log_lum(b, scale_b)
    la -= la.mean()
    lb -= lb.mean()
    win = cv2.createHanningWindow(la.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(la, lb, win)
    return float(dx), float(dy)


def exposure_ratio(a: np.ndarray, b: np.ndarray, *, lo: float = 0.01, hi: float = 0.9) -> np.ndarray:
    """Per-channel median of ``b / a`` over pixels well exposed in both, (3,) array.

    A bubble covers a minority of the frame, so the median measures the background: equal
    ratios away from 1 mean the exposure changed, unequal ratios that the white balance did.
    Returns NaNs when too few pixels are usable.
    """
    ok = np.all((a > lo) & (a < hi) & (b > lo) & (b < hi), axis=-1)
    if ok.sum() < 50:
        return np.full(3, np.nan)
    return np.median(b[ok] / a[ok], axis=0)


def difference_mask(before: np.ndarray, after: np.ndarray, *, ratio=None, tol: float = 0.04) -> np.ndarray:
    """Pixels where ``after`` differs from ``before`` by more than ``tol`` (relative), after
    removing a global per-channel ``ratio``; light blur and a morphological opening remove
    noise and isolated pixels. Returns an (H, W) bool mask (the bubble in a transmission pair)."""
    r = np.ones(3) if ratio is None or not np.all(np.isfinite(ratio)) else np.asarray(ratio)
    a = cv2.GaussianBlur(before.astype(np.float32), (0, 0), 1.0)
    b = cv2.GaussianBlur((after / r).astype(np.float32), (0, 0), 1.0)
    rel = np.max(np.abs(b - a) / (np.abs(a) + 0.02), axis=-1)
    m = (rel > tol).astype(np.uint8)
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    return m.astype(bool)


# --------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------


def _match_roles(folder: Path, spec: dict, report: CaptureReport) -> dict[str, list[Path]] | None:
    names = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    images = [p for p in names if p.suffix.lower() in IMAGE_EXTENSIONS]
    if not images:
        raise InputError(f"no images in {folder} (looked for {', '.join(IMAGE_EXTENSIONS)})")
    roles: dict[str, list[Path]] = {}
    problems = []
    taken: set[Path] = set()
    for r in spec["files"]:
        pat = str(r["pattern"]).lower()
        hits = [p for p in images if fnmatch.fnmatch(p.name.lower(), pat) and p not in taken]
        taken.update(hits)
        roles[r["role"]] = hits
        lo, hi = int(r["min_count"]), int(r["max_count"])
        if len(hits) < lo:
            problems.append(f"missing {r['role']!r} image ({lo} needed, file names {r['pattern']})"
                            if len(hits) == 0 else
                            f"{len(hits)} {r['role']!r} image(s), at least {lo} needed ({r['pattern']})")
        elif hi >= 0 and len(hits) > hi:
            problems.append(f"{len(hits)} {r['role']!r} images, at most {hi} expected ({r['pattern']})")
    report.files = {k: [p.name for p in v] for k, v in roles.items()}
    extra = [p.name for p in images if p not in taken]
    if problems:
        report.add("files", FAIL, "; ".join(problems))
        return None
    msg = ", ".join(f"{k}: {len(v)}" for k, v in roles.items())
    if extra:
        report.add("files", WARN, f"{msg}; ignored {len(extra)} file(s) matching no role: {', '.join(extra[:4])}")
    else:
        report.add("files", PASS, msg)
    return roles


def _check_metadata(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> None:
    meta = spec.get("metadata", {})
    required = list(meta.get("required", []))
    recommended = list(meta.get("recommended", []))
    missing_req, missing_rec = [], []
    for name, im in imgs.items():
        for key in required:
            if metadata_value(im, key) is None:
                missing_req.append(f"{name}: {key}")
        for key in recommended:
            if metadata_value(im, key) is None:
                missing_rec.append(f"{name}: {key}")
    if missing_req:
        report.add("metadata", FAIL, "missing required metadata (" + "; ".join(missing_req[:6]) + ")")
    elif missing_rec:
        report.add("metadata", WARN, "not recorded, so not checked: " + "; ".join(missing_rec[:6]))
    elif required or recommended:
        report.add("metadata", PASS, "present: " + ", ".join(required + recommended))

    locked = list(meta.get("locked", []))
    if locked and len(imgs) > 1:
        changed, unknown = [], []
        for key in locked:
            vals = {n: metadata_value(im, key) for n, im in imgs.items()}
            known = {n: v for n, v in vals.items() if v is not None}
            if len(known) < len(vals):
                unknown.append(key)
            if len(known) >= 2:
                ref_name, ref = next(iter(known.items()))
                for n, v in known.items():
                    if not _same(ref, v):
                        changed.append(f"{key} differs ({ref_name}: {_fmt_value(key, ref)}, {n}: {_fmt_value(key, v)})")
                        break
        if changed:
            report.add("locked", FAIL, "; ".join(changed) + " - lock the camera in manual mode")
        elif unknown:
            report.add("locked", WARN, "cannot check, not recorded in every file: " + ", ".join(unknown))
        else:
            report.add("locked", PASS, "equal in all files: " + ", ".join(locked))

    if meta.get("manual_white_balance", False):
        autos = [n for n, im in imgs.items() if metadata_value(im, "white_balance") == 0]
        unknown = [n for n, im in imgs.items() if metadata_value(im, "white_balance") is None]
        if autos:
            report.add("white_balance", FAIL, f"auto white balance in {', '.join(autos[:4])}: set a fixed (manual) white balance")
        elif unknown:
            report.add("white_balance", WARN, f"white balance not recorded in {', '.join(unknown[:4])}")
        else:
            report.add("white_balance", PASS, "manual white balance in every file")


def _check_pair(spec: dict, a: Image, b: Image, an: str, bn: str, report: CaptureReport,
                *, scale_b: float = 1.0) -> tuple[np.ndarray | None, bool]:
    """Photometric and registration checks of a pair; returns (ratio, registered)."""
    checks = spec.get("checks", {})
    ratio = None
    tol = checks.get("photometric_tolerance")
    if tol is not None:
        ratio = exposure_ratio(a.pixels, b.pixels * scale_b)
        report.measurements["background_ratio_rgb"] = [float(x) for x in ratio]
        if not np.all(np.isfinite(ratio)):
            report.add("photometric", WARN, f"too few well-exposed background pixels to compare {an} and {bn}")
        else:
            dev = np.abs(ratio - 1.0)
            spread = float(ratio.max() / ratio.min() - 1.0)
            if spread > tol:
                report.add("photometric", FAIL,
                           f"white balance changed between {an} and {bn}: background R,G,B ratios "
                           f"{ratio[0]:.3f}, {ratio[1]:.3f}, {ratio[2]:.3f}")
            elif dev.max() > tol:
                stops = math.log2(float(np.mean(ratio)))
                report.add("photometric", FAIL,
                           f"exposure changed between {an} and {bn}: background {float(np.mean(ratio)):.3f}x "
                           f"({stops:+.2f} stops)")
            else:
                report.add("photometric", PASS, f"background matches within {100 * dev.max():.1f}% per channel")
    lim = checks.get("registration_max_px")
    registered = True
    if lim is not None:
        dx, dy = registration_shift(a.pixels, b.pixels, scale_b=scale_b)
        shift = math.hypot(dx, dy)
        report.measurements.setdefault("shift_px", {})[f"{an}->{bn}"] = [dx, dy]
        if shift > lim:
            registered = False
            report.add("registration", FAIL,
                       f"{bn} is shifted by ({dx:+.1f}, {dy:+.1f}) px from {an} (limit {lim:g} px): "
                       "the camera moved; use a tripod and a remote release")
        else:
            report.add("registration", PASS, f"{bn} within {shift:.2f} px of {an}")
    return ratio, registered


def _saturated(im: Image, clip: float = 0.98) -> np.ndarray:
    if im.bit_depth in (8, 16) and im.saturated is not None:
        return im.saturated
    if im.linear_file and im.bit_depth == 32:
        return np.zeros(im.shape, dtype=bool)  # float files do not clip at a code value
    return np.any(im.pixels >= clip, axis=-1)


def _check_difference_subject(spec: dict, before: Image, after: Image, bn: str, an: str,
                              ratio, report: CaptureReport, subject: str = "bubble") -> None:
    checks = spec.get("checks", {})
    mask = difference_mask(before.pixels, after.pixels, ratio=ratio,
                           tol=float(checks.get("difference_tolerance", 0.04)))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        report.add("subject", FAIL, f"{an} does not differ from {bn}: no {subject} found")
        return
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    region = labels == big
    x, y, w, h, area = stats[big]
    diam = float(max(w, h))
    report.measurements[f"{subject}_bbox_px"] = [int(x), int(y), int(w), int(h)]
    min_d = float(checks.get("min_subject_diameter_px", 0))
    H, W = region.shape
    touches = x == 0 or y == 0 or x + w >= W or y + h >= H
    if diam < min_d:
        report.add("subject", FAIL, f"the {subject} is {diam:.0f} px across, at least {min_d:.0f} px needed: move closer or zoom in")
    elif touches and checks.get("subject_inside_frame", True):
        report.add("subject", FAIL, f"the {subject} touches the frame's edge: frame it whole")
    else:
        report.add("subject", PASS, f"{subject} found, {diam:.0f} px across at ({x + w / 2:.0f}, {y + h / 2:.0f})")
    region = cv2.dilate(region.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    max_frac = float(checks.get("max_saturated_fraction", 0.0))
    bad = []
    for name, im in ((bn, before), (an, after)):
        sat = _saturated(im) & region
        frac = sat.sum() / max(region.sum(), 1)
        if sat.any() and frac > max_frac:
            bad.append(f"{int(sat.sum())} saturated pixel(s) inside the {subject} in {name}")
    if bad:
        report.add("saturation", FAIL, "; ".join(bad) + ": shorten the exposure")
    else:
        report.add("saturation", PASS, f"no saturated pixels inside the {subject}")


def _check_brackets(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> list[tuple[str, float]] | None:
    br = spec.get("checks", {}).get("brackets")
    if br is None:
        return None
    times, missing = [], []
    for n, im in imgs.items():
        t = metadata_value(im, "exposure_time")
        if isinstance(t, (int, float)) and t > 0:
            times.append((n, float(t)))
        else:
            missing.append(n)
    if missing:
        report.add("brackets", FAIL, f"no ExposureTime in {', '.join(missing[:4])}: cannot merge the brackets")
        return None
    times.sort(key=lambda x: x[1])
    tv = np.array([t for _, t in times])
    n_min = int(br.get("min_exposures", 3))
    span = float(np.log2(tv.max() / tv.min())) if tv.size else 0.0
    steps = np.diff(np.log2(tv)) if tv.size > 1 else np.array([])
    report.measurements["bracket_stops"] = span
    report.measurements["exposure_times_s"] = [t for _, t in times]
    problems = []
    if tv.size < n_min:
        problems.append(f"{tv.size} exposure(s), at least {n_min} needed")
    if span < float(br.get("min_span_stops", 8)):
        problems.append(f"brackets span {span:.1f} stops, at least {br.get('min_span_stops', 8):g} needed")
    if steps.size and steps.max() > float(br.get("max_step_stops", 3)):
        problems.append(f"a {steps.max():.1f}-stop gap between exposures (at most {br.get('max_step_stops', 3):g})")
    if steps.size and np.any(steps < 0.05):
        problems.append("two exposures have the same exposure time")
    if problems:
        report.add("brackets", FAIL, "; ".join(problems))
    else:
        report.add("brackets", PASS, f"{tv.size} exposures spanning {span:.1f} stops, largest step {steps.max() if steps.size else 0:.1f}")
    return times


def _check_ball(spec: dict, imgs: dict[str, Image], times, report: CaptureReport) -> None:
    from .probe import ball_mask, find_ball, merge_exposures

    checks = spec.get("checks", {})
    names = list(imgs)
    if times:
        order = [n for n, _ in times]
        tv = [t for _, t in times]
        merged = merge_exposures([imgs[n].pixels for n in order], tv,
                                 saturated=[_saturated(imgs[n]) for n in order]).radiance
    else:
        order = names
        merged = imgs[names[0]].pixels
    try:
        circle = find_ball(merged)
    except InputError as exc:
        report.add("subject", FAIL, f"no mirror ball found ({exc})")
        return
    report.measurements["ball"] = circle.as_dict()
    h, w = merged.shape[:2]
    min_r = float(checks.get("min_ball_radius_px", 0))
    inside = (circle.cx - circle.r >= 0 and circle.cy - circle.r >= 0
              and circle.cx + circle.r <= w and circle.cy + circle.r <= h)
    if circle.r < min_r:
        report.add("subject", FAIL, f"the ball's radius is {circle.r:.0f} px, at least {min_r:.0f} px needed: zoom in")
    elif not inside:
        report.add("subject", FAIL, "the ball is cut by the frame's edge: frame it whole")
    else:
        report.add("subject", PASS, f"mirror ball at ({circle.cx:.1f}, {circle.cy:.1f}), radius {circle.r:.1f} px")
    mask = ball_mask((h, w), circle, shrink=1.0)
    darkest = order[0]
    sat = _saturated(imgs[darkest]) & mask
    max_frac = float(checks.get("max_saturated_fraction", 0.0))
    if sat.any() and sat.sum() / max(mask.sum(), 1) > max_frac:
        what = "the darkest exposure" if len(order) > 1 else "the probe"
        report.add("saturation", FAIL, f"{what} ({darkest}) has {int(sat.sum())} saturated pixel(s) inside the ball: "
                                       "add a shorter exposure (or an ND filter) for the sun and lamps")
    else:
        report.add("saturation", PASS, f"no saturated pixels inside the ball in {darkest}")


def check_capture(folder: str | os.PathLike, protocol: str | os.PathLike | dict) -> CaptureReport:
    """Check a capture folder against a protocol.

    Args:
        folder: the folder holding the capture's image files.
        protocol: a protocol name, a spec path, or a spec dict from :func:`load_protocol`.

    Returns:
        A :class:`CaptureReport`; ``report.passed`` is False when any check failed.

    Raises:
        InputError: the folder is missing or holds no images, or the protocol is unknown.
    """
    spec = protocol if isinstance(protocol, dict) else load_protocol(protocol)
    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"capture folder not found: {folder}")
    if not folder.is_dir():
        raise InputError(f"expected a capture folder, got a file: {folder}")
    report = CaptureReport(protocol=spec["name"], folder=str(folder))
    roles = _match_roles(folder, spec, report)
    if roles is None:
        return report
    imgs: dict[str, Image] = {}
    role_of: dict[str, str] = {}
    unreadable = []
    for role, paths in roles.items():
        for p in paths:
            try:
                imgs[p.name] = read_image(p)
                role_of[p.name] = role
            except InputError as exc:
                unreadable.append(str(exc))
    if unreadable:
        report.add("readable", FAIL, "; ".join(unreadable[:3]))
        return report
    report.add("readable", PASS, f"{len(imgs)} image(s) read")
    sizes = {n: im.shape for n, im in imgs.items()}
    if len(set(sizes.values())) > 1:
        desc = ", ".join(f"{n}: {w}x{h}" for n, (h, w) in list(sizes.items())[:4])
        report.add("same_size", FAIL, f"images differ in size ({desc}): do not crop or resize")
        return report
    h, w = next(iter(sizes.values()))
    report.add("same_size", PASS, f"all {w}x{h}")
    min_bits = int(spec.get("checks", {}).get("min_bit_depth", 8))
    low = [n for n, im in imgs.items() if im.bit_depth < min_bits]
    if low:
        report.add("bit_depth", WARN, f"{len(low)} file(s) at 8 bits ({', '.join(low[:3])}); "
                                      f"{min_bits}-bit TIFF/PNG or EXR from RAW keeps more of the range")
    _check_metadata(spec, imgs, report)

    kind = spec.get("checks", {}).get("subject", "none")
    pair = spec.get("checks", {}).get("pair")
    if kind == "difference" and pair:
        ra, rb = pair
        if roles.get(ra) and roles.get(rb):
            an = roles[ra][0].name
            for p in roles[rb]:
                bn = p.name
                ratio, registered = _check_pair(spec, imgs[an], imgs[bn], an, bn, report)
                if registered:
                    _check_difference_subject(spec, imgs[an], imgs[bn], an, bn, ratio, report,
                                              subject=spec.get("checks", {}).get("subject_name", "bubble"))
                else:
                    report.add("subject", SKIP, f"{bn} not checked: the pair is not registered")
        else:
            report.add("subject", SKIP, f"no {ra!r} image: the {spec.get('checks', {}).get('subject_name', 'bubble')} "
                                        "cannot be located nor checked for saturation")
            _check_frame_saturation(spec, imgs, report)
    elif kind == "ball":
        times = _check_brackets(spec, imgs, report)
        if times and len(times) > 1 and spec.get("checks", {}).get("registration_max_px") is not None:
            # consecutive brackets must show the same scene at the same place
            lim = float(spec["checks"]["registration_max_px"])
            worst = (0.0, "")
            for (n0, t0), (n1, t1) in zip(times[:-1], times[1:]):
                dx, dy = registration_shift(imgs[n0].pixels, imgs[n1].pixels, scale_b=t0 / t1)
                report.measurements.setdefault("shift_px", {})[f"{n0}->{n1}"] = [dx, dy]
                if math.hypot(dx, dy) > worst[0]:
                    worst = (math.hypot(dx, dy), f"{n1} is shifted by ({dx:+.1f}, {dy:+.1f}) px from {n0}")
            if worst[0] > lim:
                report.add("registration", FAIL, f"{worst[1]} (limit {lim:g} px): the camera moved between brackets")
            else:
                report.add("registration", PASS, f"brackets within {worst[0]:.2f} px of each other")
        _check_ball(spec, imgs, times, report)
    else:
        _check_frame_saturation(spec, imgs, report)
    return report


def _check_frame_saturation(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> None:
    lim = spec.get("checks", {}).get("max_frame_saturated_fraction")
    if lim is None:
        return
    bad = []
    for n, im in imgs.items():
        frac = float(_saturated(im).mean())
        if frac > float(lim):
            bad.append(f"{n}: {100 * frac:.1f}% of pixels saturated")
    if bad:
        report.add("saturation", FAIL, "; ".join(bad[:4]) + f" (at most {100 * float(lim):.1f}%)")
    else:
        report.add("saturation", PASS, f"at most {100 * float(lim):.1f}% of any frame saturated")


def format_table(report: CaptureReport) -> str:
    """The report as a plain-text table: check, status, reason; then a verdict line."""
    rows = [(r.check, r.status, r.reason) for r in report.results]
    w0 = max([len("check")] + [len(r[0]) for r in rows])
    lines = [f"capture {report.folder} against protocol {report.protocol!r}", "",
             f"{'check':<{w0}}  status  reason"]
    lines.append(f"{'-' * w0}  ------  {'-' * 40}")
    for c, s, why in rows:
        lines.append(f"{c:<{w0}}  {s:<6}  {why}")
    n_fail = len(report.failed())
    lines.append("")
    lines.append("PASS" if report.passed else f"FAIL: {n_fail} check(s) failed")
    return "\n".join(lines)
