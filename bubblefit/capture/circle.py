"""Circles in images: the algebraic circle fit and the bubble of a dark-box pair.

:func:`kasa_circle_fit` is the one least-squares circle through points (Kasa 1976) of
the package. :func:`detect_bubble` finds the bubble of a dark-box pair as the largest
darkened disc of the after/before ratio; :func:`detect_disc`, the simpler of the two disc
detectors (:func:`bubblefit.capture.disc.find_disc` is the robust one), finds it in a photo
from that or from the strongest circle of its edges. Array coordinates: the centre of pixel
(row i, column j) is (j, i). See ``docs/design.md`` (capture).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy import ndimage as ndi

from ..errors import InputError
from .ratio import usable_mask

__all__ = ["kasa_circle_fit", "detect_bubble", "detect_disc"]


def kasa_circle_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Algebraic least-squares circle through points (Kasa 1976).

    Solves ``x^2 + y^2 + D x + E y + F = 0`` for ``D, E, F`` in the least-squares sense;
    the centre is ``(-D/2, -E/2)`` and ``r^2 = cx^2 + cy^2 - F``.

    Parameters
    ----------
    x, y : (N,) float
        Point coordinates, N >= 3, not all on one line.

    Returns
    -------
    (cx, cy, r)

    Raises
    ------
    InputError
        Fewer than 3 points, or points that lie on no circle (``r^2 <= 0`` or not finite).

    References
    ----------
    I. Kasa, "A circle fitting procedure and its error analysis", IEEE Trans. Instrum.
    Meas. 25(1), 8-14, 1976.
    """
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    if x.size < 3:
        raise InputError("cannot fit a circle to fewer than 3 edge points")
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    rhs = -(x * x + y * y)
    (D, E, F), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    cx, cy = -D / 2.0, -E / 2.0
    r2 = cx * cx + cy * cy - F
    if not np.isfinite(r2) or r2 <= 0:
        raise InputError("edge points do not lie on a circle")
    return float(cx), float(cy), float(math.sqrt(r2))


def _smoothed_ratio(before: np.ndarray, after: np.ndarray, usable: np.ndarray, sigma: float):
    """Normalised convolution (Knutsson & Westin 1993) of after/before over usable pixels."""
    q = np.where(usable, after / np.where(usable, before, 1.0), 0.0)
    w = usable.astype(float)
    num = ndi.gaussian_filter(q * w, sigma)
    den = ndi.gaussian_filter(w, sigma)
    defined = den > 0.15
    qs = np.where(defined, num / np.maximum(den, 1e-12), np.nan)
    return qs, defined


def _background_level(vals: np.ndarray) -> float:
    """The ratio of the unchanged background: the brightest well-populated histogram peak.

    The bubble only darkens the background in a dark box, so the background is the
    peak with the largest ratio among those at least 20% as high as the highest one;
    this holds even when the bubble covers most of the lit area (a median would not).
    """
    lo, hi = np.percentile(vals, [0.5, 99.5])
    if hi - lo < 1e-6:
        return float(np.median(vals))
    nbins = int(np.clip((hi - lo) / 0.0025, 20, 400))
    hist, edges = np.histogram(vals, bins=nbins, range=(lo, hi))
    hs = ndi.gaussian_filter1d(hist.astype(float), 1.5)
    peaks = [i for i in range(nbins) if hs[i] >= hs[max(i - 1, 0)] and hs[i] >= hs[min(i + 1, nbins - 1)]]
    peaks = [i for i in peaks if hs[i] >= 0.2 * hs.max()]
    i = max(peaks)
    centre = 0.5 * (edges[i] + edges[i + 1])
    near = np.abs(vals - centre) < 2.0 * (edges[1] - edges[0]) + 0.01 * abs(centre)
    return float(np.median(vals[near])) if near.any() else float(centre)


def detect_bubble(
    before: np.ndarray, after: np.ndarray, usable: np.ndarray, *, min_pixels: int | None = None,
    sigma: float = 2.0,
) -> tuple[float, float, float]:
    """Find the bubble as the largest darkened disc of the ratio image.

    The ratio after/before is smoothed over usable pixels (normalised convolution) and
    compared with the background's level (the brightest well-populated mode of its
    histogram); pixels darker by 6 noise standard deviations (at least 1.5%) are grouped
    across the dark checker squares and the largest group is kept. Its moments give a
    first circle (centroid, ``r^2 = 2 <d^2>``), refined by :func:`kasa_circle_fit` on the
    rim points at the 50% level of the edge, with rejection of stray points.
    :func:`fit_disc_profile` refines the result to sub-pixel accuracy.

    Parameters
    ----------
    before, after : (H, W) float
        Registered linear gray images.
    usable : (H, W) bool
        From :func:`usable_mask`.
    min_pixels : int, optional
        Smallest bubble area in pixels (default: max(50, 2e-4 of the image)).

    Returns
    -------
    (cx, cy, r) in pixels.

    Raises
    ------
    InputError
        ``"no bubble found: ..."`` when the images differ in too few pixels.
    """
    h, w = before.shape
    if min_pixels is None:
        min_pixels = max(50, int(2e-4 * h * w))
    qs, defined = _smoothed_ratio(before, after, usable, sigma)
    vals = qs[defined]
    if vals.size < min_pixels:
        raise InputError(
            f"no bubble found: only {vals.size} pixels are lit and unsaturated in both images "
            "(is the checkered background visible and correctly exposed?)"
        )
    level = _background_level(vals)
    if not level > 0:
        raise InputError("no bubble found: the second image is black where the first is lit "
                         "(are both files the right ones, and exposed the same?)")
    # noise of the smoothed ratio: per-pixel noise (from the high-pass residual, hardly
    # touched by the bubble's edge) times the noise gain of the Gaussian (1 / (2 sqrt(pi) sigma)),
    # doubled for the holes left by unusable pixels
    q = after[usable] / before[usable]
    hp = q - qs[usable]
    hp = hp[np.isfinite(hp)]
    pix_noise = 1.4826 * float(np.median(np.abs(hp - np.median(hp)))) if hp.size else 0.0
    noise = 2.0 * pix_noise / (2.0 * math.sqrt(math.pi) * sigma)
    thr = max(0.015 * level, 6.0 * noise)
    cand = np.zeros_like(defined)
    cand[defined] = (level - qs[defined]) > thr
    n_diff = int(cand.sum())
    if n_diff < min_pixels:
        raise InputError(
            f"no bubble found: the images differ in fewer than {min_pixels} pixels "
            f"({n_diff} pixels are darker by more than {100 * thr / level:.1f}% in the second image)"
        )
    # group the changed pixels across the unusable (dark, edge) pixels of the checkerboard
    # and keep the largest group
    gap = np.ones((3, 3), bool)
    labels, n = ndi.label(ndi.binary_dilation(cand, gap, iterations=8))
    counts = np.bincount(labels[cand], minlength=n + 1)
    counts[0] = 0
    k = int(np.argmax(counts))
    if counts[k] < min_pixels:
        raise InputError(
            f"no bubble found: the images differ in fewer than {min_pixels} connected pixels "
            f"(largest changed region: {int(counts[k])} pixels)"
        )
    main = cand & (labels == k)
    ys, xs = np.nonzero(main)
    # moments of the changed pixels: for points spread evenly over a disc, the centroid is
    # its centre and the mean squared distance from it is r^2 / 2
    cx, cy = float(xs.mean()), float(ys.mean())
    r = math.sqrt(2.0 * float(np.mean((xs - cx) ** 2 + (ys - cy) ** 2)))
    # refine with an algebraic fit to the rim (Kasa 1976): changed pixels next to measured
    # unchanged ones, after re-thresholding half-way between the background and the
    # bubble's own level (the 50% point of the smoothed edge)
    half = 0.5 * (level + float(np.median(qs[main])))
    near = np.hypot(*np.mgrid[0:h, 0:w][::-1] - np.array([cx, cy])[:, None, None]) < 1.5 * r + 3
    cand2 = defined & near & (qs < half)
    rim = cand2 & ndi.binary_dilation(defined & near & ~cand2, gap)
    yy, xx = np.nonzero(rim)
    if xx.size >= 10:
        keep = np.abs(np.hypot(xx - cx, yy - cy) - r) < 0.3 * r
        for _ in range(5):  # Kasa fit with rejection of stray rim points
            if keep.sum() < 10:
                break
            try:
                c2 = kasa_circle_fit(xx[keep], yy[keep])
            except InputError:
                break
            if not (np.isfinite(c2[2]) and 0.75 * r < c2[2] < 1.33 * r and math.hypot(c2[0] - cx, c2[1] - cy) < 0.3 * r):
                break
            cx, cy, r = c2
            dev = np.hypot(xx - cx, yy - cy) - r
            mad = 1.4826 * float(np.median(np.abs(dev[keep]))) + 0.5
            new_keep = np.abs(dev) < 3.0 * mad
            if np.array_equal(new_keep, keep):
                break
            keep = new_keep
    # the changed pixels' centres lie about half a pixel inside the rim
    return cx, cy, r + 0.5


def detect_disc(photo: np.ndarray, background: np.ndarray | None = None) -> tuple[float, float, float]:
    """Find the bubble's disc ``(cx, cy, r)`` in pixels.

    With a background photo: :func:`detect_bubble` on the pair (the
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
