"""Measurements a capture check rests on: metadata, exposure ratio, registration, clipping.

See ``docs/design.md``, "Capture protocols".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..io.images import Image
from .registration import phase_correlate

__all__ = ["METADATA_ALIASES", "Registration", "metadata_value", "registration_shift", "measure_shift", "subject_region", "background_ratio", "exposure_ratio",
           "difference_mask", "saturated_mask"]

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

def metadata_value(image: Image, name: str):
    """The value of a canonical metadata name (see :data:`METADATA_ALIASES`), or None."""
    for key in METADATA_ALIASES.get(name, (name,)):
        if key in image.metadata:
            return image.metadata[key]
    return None


def fmt_value(name: str, value) -> str:
    if name == "exposure_time" and isinstance(value, (int, float)) and 0 < value < 1:
        return f"1/{1 / value:.4g} s"
    unit = _UNITS.get(name)
    return f"{value:g} {unit}" if unit and isinstance(value, (int, float)) else f"{value}"


def same_value(a, b, rel: float = 2e-3) -> bool:
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
    return phase_correlate(lb, la)


def exposure_ratio(a: np.ndarray, b: np.ndarray, *, lo: float = 0.01, hi: float = 0.9,
                   exclude: np.ndarray | None = None) -> np.ndarray:
    """Per-channel median of ``b / a`` over pixels well exposed in both, (3,) array.

    With the subject (``exclude``, (H, W) bool) left out, the median measures the
    background: equal ratios away from 1 mean the exposure changed, unequal ratios that
    the white balance did. Returns NaNs when too few pixels are usable.
    """
    ok = np.all((a > lo) & (a < hi) & (b > lo) & (b < hi), axis=-1)
    if exclude is not None:
        ok &= ~exclude
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


def saturated_mask(im: Image, clip: float = 0.98) -> np.ndarray:
    """(H, W) bool: pixels clipped in ``im`` (the file's own flags for 8/16-bit codes, none
    for float files, else any channel at or above ``clip``)."""
    if im.bit_depth in (8, 16) and im.saturated is not None:
        return im.saturated
    if im.linear_file and im.bit_depth == 32:
        return np.zeros(im.shape, dtype=bool)  # float files do not clip at a code value
    return np.any(im.pixels >= clip, axis=-1)


@dataclass(frozen=True)
class Registration:
    """A camera shift between two frames, and how well it is established.

    Attributes
    ----------
    dx, dy
        ``b`` is ``a`` moved by this much, pixels (0, 0 when no shift is established).
    clear
        True when the shift is established: the frames agree without a shift, or the
        shift found explains their disagreement (see :func:`measure_shift`).
    mismatch
        Fraction of the comparable pixels, outside the subject, that differ unshifted.
    mismatch_shifted
        The same after undoing the shift found by phase correlation.
    """

    dx: float
    dy: float
    clear: bool
    mismatch: float
    mismatch_shifted: float

    @property
    def shift(self) -> float:
        return math.hypot(self.dx, self.dy)


def _compact_blob(stats: np.ndarray, shape: tuple[int, int]) -> int | None:
    """Label of the largest connected region if it is compact (fills at least half its
    bounding box, as a bubble does) and does not span the frame from edge to edge (as the
    differences of a moved texture do); else None."""
    if len(stats) <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h, area = stats[k]
    spans = (x == 0 and x + w >= shape[1]) or (y == 0 and y + h >= shape[0])
    return k if area >= 0.5 * w * h and not spans else None


def subject_region(a: np.ndarray, b: np.ndarray, *, ratio=None, tol: float = 0.04) -> np.ndarray:
    """(H, W) bool: the largest region where ``b`` differs from ``a`` (:func:`difference_mask`),
    grown by a tenth of its size, when it is a compact blob (:func:`_compact_blob`); else
    nothing."""
    m = difference_mask(a, b, ratio=ratio, tol=tol)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    k = _compact_blob(stats, m.shape)
    if k is None:
        return np.zeros(m.shape, dtype=bool)
    w, h = stats[k, cv2.CC_STAT_WIDTH], stats[k, cv2.CC_STAT_HEIGHT]
    grow = 2 * max(1, int(0.1 * max(w, h))) + 1
    return cv2.dilate((labels == k).astype(np.uint8), np.ones((grow, grow), np.uint8)).astype(bool)


def background_ratio(a: np.ndarray, b: np.ndarray, *, tol: float = 0.04) -> np.ndarray | None:
    """:func:`exposure_ratio` of the background: measured once, then again without the
    subject's region (:func:`subject_region`); None when too few pixels are usable."""
    first = exposure_ratio(a, b)
    if not np.all(np.isfinite(first)):
        return None
    ratio = exposure_ratio(a, b, exclude=subject_region(a, b, ratio=first, tol=tol))
    return ratio if np.all(np.isfinite(ratio)) else None


def _mismatch(a: np.ndarray, b: np.ndarray, valid: np.ndarray, tol: float, ratio) -> float:
    """Fraction of ``valid`` pixels where ``b`` differs from ``a`` (:func:`difference_mask`),
    not counting a compact blob (:func:`_compact_blob`): a subject such as a bubble, not a
    misregistration, whose differences follow the scene's edges."""
    m = difference_mask(a, b, ratio=ratio, tol=tol) & valid
    area = float(m.sum())
    _, _, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    k = _compact_blob(stats, m.shape)
    if k is not None:
        area -= float(stats[k, cv2.CC_STAT_AREA])
    return area / max(float(valid.sum()), 1.0)


def _shifted(b: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``b`` moved back by (dx, dy): ``out(x) = b(x + d)``, bilinear, edges replicated."""
    m = np.float32([[1, 0, -dx], [0, 1, -dy]])
    h, w = b.shape[:2]
    return cv2.warpAffine(b.astype(np.float32), m, (w, h), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


def measure_shift(a: np.ndarray, b: np.ndarray, *, scale_b: float = 1.0, tol: float = 0.04,
                  clipped_a: np.ndarray | None = None, clipped_b: np.ndarray | None = None,
                  agree: float = 0.05, channel_px: float = 0.5) -> Registration:
    """The camera shift between two frames of one scene, reported only when it is clear.

    Phase correlation finds the peak of a correlation whether or not the frames moved: on
    a pair where a large bubble appears, or where the scene itself changed, its peak can
    sit tens of pixels away. So the shift is tested as a hypothesis: the frames are
    compared pixel by pixel (:func:`difference_mask` at ``tol``, after removing the
    background's exposure ratio, over pixels above 1% and unclipped in both, the subject's
    compact region left out). Where at most ``agree`` of them differ
    unshifted, the camera did not move: (0, 0). Otherwise the shift from
    :func:`registration_shift` counts only when the three colour channels, registered
    apart, agree within ``channel_px`` and undoing it halves the mismatch.

    Parameters
    ----------
    a, b
        (H, W, 3) linear frames of one size; ``b * scale_b`` has ``a``'s exposure.
    clipped_a, clipped_b
        (H, W) bool, pixels clipped in each frame (:func:`saturated_mask`), not compared.

    Returns
    -------
    Registration

    References
    ----------
    Kuglin & Hines 1975, "The phase correlation image alignment method".
    """
    b = b * scale_b
    valid = np.max(a, axis=-1) > 0.01  # darker pixels are mostly noise and quantisation
    for clip in (clipped_a, clipped_b):
        if clip is not None:
            valid &= ~np.asarray(clip, dtype=bool)
    ratio = background_ratio(a, b, tol=tol)
    m0 = _mismatch(a, b, valid, tol, ratio)
    if m0 <= agree:
        return Registration(0.0, 0.0, True, m0, m0)
    dx, dy = registration_shift(a, b)
    per_channel = [registration_shift(np.repeat(a[..., c:c + 1], 3, -1), np.repeat(b[..., c:c + 1], 3, -1))
                   for c in range(3)]
    spread = max(math.hypot(cx - dx, cy - dy) for cx, cy in per_channel)
    bs = _shifted(b, dx, dy)
    if clipped_b is not None:
        valid = valid & (_shifted(np.repeat(clipped_b[..., None], 3, -1).astype(np.float64), dx, dy)[..., 0] < 0.5)
    m1 = _mismatch(a, bs, valid, tol, ratio)
    if spread <= channel_px and m1 <= 0.5 * m0:
        return Registration(dx, dy, True, m0, m1)
    return Registration(0.0, 0.0, False, m0, m1)
