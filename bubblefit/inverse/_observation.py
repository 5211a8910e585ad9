"""The observation: what the fit sees of the photo.

The photo's noise (:func:`noise_sigma`), its clipped pixels (:func:`saturation_mask`),
the bubble's disc (:func:`find_bubble`), and the photo block-averaged to the resolution
a stage of the fit runs at, with its weights and the film's geometry (:class:`Level`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import jax.numpy as jnp
import numpy as np
from scipy import ndimage as ndi

from ..capture.calibrate import detect_bubble, usable_mask
from ..errors import InputError
from ..model.geometry import OrthographicCamera, intersect_sphere
from ..model.render import RenderConfig

__all__ = ["Disc", "Level", "noise_sigma", "saturation_mask", "detect_disc", "find_bubble", "make_level",
           "film_geometry"]


def noise_sigma(photo: np.ndarray, read: float, shot: float, bits: int | None) -> np.ndarray:
    """Per-pixel noise standard deviation (H, W, 3) of a linear photo.

    ``sigma^2 = read^2 + shot * I + q^2``: read noise, shot noise proportional to the
    signal, and, for an integer sRGB file of ``bits`` bits, the quantisation error
    ``q = (dI/dV) / (2^bits - 1) / sqrt(12)`` of one code value ``V`` mapped to linear.

    References
    ----------
    IEC 61966-2-1 (sRGB transfer function and its slope).
    """
    i = np.clip(photo, 0.0, None)
    var = read**2 + shot * i
    if bits:
        lin = np.clip(i, 0.0, 1.0)
        v = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055)
        slope = np.where(v <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((v + 0.055) / 1.055) ** 1.4)
        var = var + (slope / (2**bits - 1)) ** 2 / 12.0
    return np.sqrt(var)


def saturation_mask(photo: np.ndarray, level: float, given: np.ndarray | None) -> np.ndarray:
    """(H, W) clipped pixels: any channel at or above ``level`` (for files whose maximum
    is 1), or in ``given``, dilated by one pixel (a clipped pixel's neighbours bleed)."""
    H, W = photo.shape[:2]
    sat = (np.max(photo, axis=-1) >= level) if photo.max() <= 1.0 + 1e-6 else np.zeros((H, W), bool)
    if given is not None:
        if np.shape(given) != (H, W):
            raise InputError(f"the saturation mask is {np.shape(given)}, the photo is {W}x{H}")
        sat = sat | np.asarray(given, bool)
    return ndi.binary_dilation(sat) if sat.any() else sat


@dataclass(frozen=True)
class Disc:
    """The bubble's disc in the photo: centre ``(cx, cy)`` and radius ``r`` in pixels
    (pixel centres at +1/2, as in :class:`~bubblefit.model.geometry.OrthographicCamera`).

    ``found`` is False when no bubble was found (``reason`` says why); ``contrast`` is
    how strongly the disc stands out, in noise units (NaN when not measured).
    """

    cx: float
    cy: float
    r: float
    found: bool = True
    contrast: float = float("nan")
    reason: str = ""


def detect_disc(photo: np.ndarray, background: np.ndarray | None = None) -> tuple[float, float, float]:
    """Find the bubble's disc ``(cx, cy, r)`` in pixels.

    With a background photo: :func:`bubblefit.capture.calibrate.detect_bubble` on the pair (the
    bubble is where the two differ). Without: the strongest circle of the photo's edges
    (OpenCV's Hough gradient on the sRGB-encoded grey image), which finds the rim that a
    bubble's Fresnel brightening outlines.

    References
    ----------
    Yuen et al., "Comparative study of Hough transform methods for circle finding",
    Image and Vision Computing 8(1), 1990 (the gradient method OpenCV implements).
    """
    gray = np.mean(np.clip(photo, 0, None), axis=-1)
    if background is not None:
        bgray = np.mean(np.clip(background, 0, None), axis=-1)
        sat = (np.max(photo, axis=-1) >= 0.999) | (np.max(background, axis=-1) >= 0.999)
        try:
            usable, _ = usable_mask(bgray, gray, sat)
            return detect_bubble(bgray, gray, usable)
        except InputError:
            pass  # a dark background: fall back to the edges of the photo alone
    h, w = gray.shape
    enc = np.clip(gray / max(np.percentile(gray, 99.5), 1e-6), 0, 1) ** (1 / 2.2)
    img = cv2.GaussianBlur((enc * 255).astype(np.uint8), (5, 5), 1.2)
    circles = cv2.HoughCircles(img, cv2.HOUGH_GRADIENT, dp=1, minDist=max(h, w),
                               param1=60, param2=20, minRadius=max(4, min(h, w) // 10),
                               maxRadius=min(h, w) // 2 + 2)
    if circles is None:
        raise InputError("no bubble found in the photo; give its disc (--disc CX,CY,R) or a background photo")
    cx, cy, r = (float(v) for v in circles[0, 0])
    return cx, cy, r


def find_bubble(photo: np.ndarray, background: np.ndarray | None = None, *,
                sigma: np.ndarray | None = None) -> Disc:
    """The bubble's :class:`Disc` in ``photo`` (the fit's one entry point to disc detection).

    Has the interface of ``bubblefit.capture.disc.find_disc``; until that lands it wraps
    :func:`detect_disc` (``sigma`` unused) and reports a failure as ``found=False``.
    """
    try:
        cx, cy, r = detect_disc(photo, background)
    except InputError as exc:
        return Disc(float("nan"), float("nan"), float("nan"), found=False, reason=str(exc))
    return Disc(float(cx), float(cy), float(r))


@dataclass
class Level:
    """The photo, weights and geometry at one resolution (``k`` times smaller)."""

    k: int
    cfg: RenderConfig
    y: np.ndarray  # (h, w, 3)
    w: np.ndarray  # (h, w, 3) 1 / sigma inside the mask, 0 outside
    bg: np.ndarray | None
    mask: np.ndarray  # (h, w) fitted pixels
    inside: np.ndarray  # (h, w) pixels on the bubble
    cos: np.ndarray  # (h, w) incidence cosine on the film
    height: np.ndarray  # (h, w) front film point's height over the radius


def _block(a: np.ndarray, k: int, h: int, w: int, how="mean"):
    if k == 1:
        return a
    b = a[: h * k, : w * k].reshape(h, k, w, k, *a.shape[2:])
    return b.mean(axis=(1, 3)) if how == "mean" else b.any(axis=(1, 3))


def _camera_at(camera, k: int, h: int, w: int):
    if isinstance(camera, OrthographicCamera):
        cx, cy, r = camera.disc()
        return OrthographicCamera(w, h, cx / k, cy / k, r / k)
    return replace(camera, width=w, height=h)


def film_geometry(cfg: RenderConfig):
    """``(inside, cos, height)`` (h, w) of the front film under each pixel of ``cfg``'s camera."""
    h, w = cfg.shape
    rows, cols = np.mgrid[0:h, 0:w]
    o, d = cfg.camera.rays(jnp.asarray(rows.reshape(-1), jnp.float32), jnp.asarray(cols.reshape(-1), jnp.float32),
                           cfg.center, cfg.radius)
    hits = intersect_sphere(o, d, cfg.center, cfg.radius)
    cos = np.asarray(hits.cos).reshape(h, w)
    inside = np.asarray(hits.inside).reshape(h, w)
    height = np.asarray(hits.local0[:, 1]).reshape(h, w)
    return inside, cos, height


def make_level(k, base_cfg, photo, sigma, bg, saturated, rim: float) -> Level:
    """The :class:`Level` ``k`` times smaller than ``photo`` (block means; variances of the
    mean; a block with a clipped pixel is dropped), fitting pixels with ``rho < rim``."""
    H, W = photo.shape[:2]
    h, w = H // k, W // k
    cfg = replace(base_cfg, camera=_camera_at(base_cfg.camera, k, h, w))
    inside, cos, height = film_geometry(cfg)
    cos_min = math.sqrt(max(0.0, 1.0 - rim**2))
    y = _block(photo, k, h, w)
    var = _block(sigma**2, k, h, w) / (k * k)
    sat = _block(saturated, k, h, w, how="any")
    mask = inside & (cos > cos_min) & ~sat & np.all(np.isfinite(y), axis=-1)
    wts = np.where(mask[..., None], 1.0 / np.sqrt(var), 0.0)
    bgk = None if bg is None else _block(bg, k, h, w).astype(np.float32)
    return Level(k, cfg, np.nan_to_num(y).astype(np.float32), wts.astype(np.float32), bgk, mask, inside, cos, height)
