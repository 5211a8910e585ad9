"""Measurements a capture check rests on: metadata, exposure ratio, registration, clipping.

See ``docs/design.md``, "Capture protocols".
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..io.images import Image

__all__ = ["METADATA_ALIASES", "metadata_value", "registration_shift", "exposure_ratio",
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


def saturated_mask(im: Image, clip: float = 0.98) -> np.ndarray:
    """(H, W) bool: pixels clipped in ``im`` (the file's own flags for 8/16-bit codes, none
    for float files, else any channel at or above ``clip``)."""
    if im.bit_depth in (8, 16) and im.saturated is not None:
        return im.saturated
    if im.linear_file and im.bit_depth == 32:
        return np.zeros(im.shape, dtype=bool)  # float files do not clip at a code value
    return np.any(im.pixels >= clip, axis=-1)
