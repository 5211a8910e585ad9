"""Finding a mirror ball in a photograph: a rough circle, then its sub-pixel outline.

The ball's outline is the circle that separates the reflection from the background
(paper sec. 3.2; see ``docs/design.md``, "Light probes"). :func:`find_ball` finds a rough
circle with a Hough transform, :func:`refine_circle` locates the edge along rays from its
centre to sub-pixel accuracy and fits a circle to those positions (:func:`fit_circle`,
Kasa 1976), and :func:`rim_contrast` says how clearly the circle separates two regions.

Image positions are continuous, with pixel ``(row i, column j)`` centred at
``(x, y) = (j + 1/2, i + 1/2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["Circle", "find_ball", "refine_circle", "fit_circle", "ball_mask", "rim_contrast"]


@dataclass(frozen=True)
class Circle:
    """A circle in continuous image coordinates (pixel (i, j) centred at (j + 1/2, i + 1/2)).

    Attributes:
        cx, cy: centre in pixels (x to the right, y down).
        r: radius in pixels.
    """

    cx: float
    cy: float
    r: float

    def as_dict(self) -> dict:
        return {"cx": float(self.cx), "cy": float(self.cy), "r": float(self.r)}


def _luminance(pixels: np.ndarray) -> np.ndarray:
    """Rec. 709 relative luminance of a linear (H, W, 3) image (ITU-R BT.709)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim == 2:
        return pixels
    return pixels[..., 0] * 0.2126 + pixels[..., 1] * 0.7152 + pixels[..., 2] * 0.0722


def _log_image(pixels: np.ndarray) -> np.ndarray:
    """Log luminance scaled to [0, 1], robust to the image's dynamic range.

    Edges of a mirror ball are visible in log luminance whatever the exposure, which makes
    the Hough transform work on HDR merges as well as on single photographs.
    """
    lum = _luminance(pixels)
    pos = lum[lum > 0]
    floor = np.percentile(pos, 1) if pos.size else 1e-6
    floor = max(float(floor), 1e-8)
    log = np.log(np.maximum(lum, floor))
    lo, hi = np.percentile(log, [0.5, 99.5])
    if hi - lo < 1e-9:
        return np.zeros_like(log)
    return np.clip((log - lo) / (hi - lo), 0.0, 1.0)


def fit_circle(x: np.ndarray, y: np.ndarray) -> Circle:
    """Least-squares circle through points (Kasa 1976, "A circle fitting procedure and its
    error analysis", IEEE Trans. Instrum. Meas. 25(1)).

    Solves ``x^2 + y^2 + D x + E y + F = 0`` in the least-squares sense.

    Args:
        x, y: (N,) point coordinates, N >= 3, not collinear.

    Returns:
        The fitted :class:`Circle`.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.size < 3:
        raise InputError("cannot fit a circle to fewer than 3 edge points")
    a = np.stack([x, y, np.ones_like(x)], axis=1)
    b = -(x * x + y * y)
    (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = -d / 2, -e / 2
    r2 = cx * cx + cy * cy - f
    if not np.isfinite(r2) or r2 <= 0:
        raise InputError("edge points do not lie on a circle")
    return Circle(float(cx), float(cy), float(math.sqrt(r2)))


def refine_circle(
    pixels: np.ndarray,
    guess: Circle,
    *,
    search: float = 0.15,
    n_rays: int = 360,
    smooth: float = 0.7,
    outermost: bool = False,
    min_inliers: float = 0.0,
) -> Circle:
    """Refine a circle to sub-pixel accuracy from the radial edge profile.

    Along ``n_rays`` rays from the guessed centre, the position of the strongest luminance
    step (linear luminance clipped at its 99th percentile, so that a mixed edge pixel is
    located without the bias a log scale would give and a sun cannot dominate) between ``(1 - search) r`` and ``(1 + search) r`` is located to sub-pixel accuracy
    (parabola through the gradient peak); a circle is fitted to those positions with
    :func:`fit_circle` (Kasa 1976), twice, dropping positions more than 3 robust standard
    deviations (at least 1 px) from the first fit.

    Args:
        pixels: (H, W, 3) or (H, W) linear image.
        guess: a rough circle (e.g. from the Hough transform).
        search: half-width of the search band, as a fraction of the radius.
        n_rays: number of rays.
        smooth: Gaussian blur (pixels) applied before differentiating.
        outermost: take the outermost edge at least half as strong as the ray's strongest
            instead of the strongest (the ball's silhouette is its outermost edge; details
            of the reflection crowd just inside the rim).
        min_inliers: fraction of the rays whose edge must lie within 1 px of the fitted
            circle; below it an :class:`InputError` says no clear edge was found.

    Returns:
        The refined :class:`Circle`.
    """
    px, py, ok = _rim_edges(pixels, guess, search=search, n_rays=n_rays, smooth=smooth, outermost=outermost)
    if ok.sum() < max(12, n_rays // 8):
        raise InputError("cannot locate the mirror ball's edge (too little contrast at its rim)")
    circ = _robust_circle(px, py, ok, min_points=max(12, n_rays // 8))
    res = np.hypot(px - circ.cx, py - circ.cy) - circ.r
    inliers = float(np.mean(ok & (np.abs(res) < 1.0)))
    if inliers < min_inliers:
        raise InputError(
            f"no clear mirror-ball edge: only {100 * inliers:.0f}% of the rim lies on one circle "
            "(give the ball's circle with --ball CX,CY,R)"
        )
    return circ


def _rim_edges(pixels: np.ndarray, guess: Circle, *, search: float, n_rays: int, smooth: float,
               outermost: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel edge position along each of ``n_rays`` rays from ``guess``'s centre.

    Returns ``(x, y, ok)``: (n_rays,) edge positions and whether each ray found one.
    """
    lum = _luminance(pixels)
    top = float(np.percentile(lum, 99.0))
    img = (np.clip(lum / top, 0.0, 1.0) if top > 0 else lum).astype(np.float32)
    if smooth > 0:
        img = cv2.GaussianBlur(img, (0, 0), smooth)
    step = 0.25
    radii = np.arange((1 - search) * guess.r, (1 + search) * guess.r + step, step)
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    xs = guess.cx + radii[None, :] * ca - 0.5  # cv2.remap samples pixel centres at integers
    ys = guess.cy + radii[None, :] * sa - 0.5
    h, w = img.shape
    inside = (xs >= 0) & (xs <= w - 1) & (ys >= 0) & (ys <= h - 1)
    prof = cv2.remap(img, xs.astype(np.float32), ys.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    grad = np.abs(np.gradient(prof.astype(np.float64), step, axis=1))
    grad[~inside] = 0.0
    if outermost:
        # the silhouette is the outermost strong edge: take the last local maximum that
        # reaches half of the ray's strongest gradient
        gmax = grad.max(axis=1, keepdims=True)
        peak = np.zeros_like(grad, dtype=bool)
        peak[:, 1:-1] = (grad[:, 1:-1] >= grad[:, :-2]) & (grad[:, 1:-1] > grad[:, 2:])
        peak &= grad >= 0.5 * gmax
        k = np.where(peak.any(axis=1), radii.size - 1 - np.argmax(peak[:, ::-1], axis=1), np.argmax(grad, axis=1))
    else:
        k = np.argmax(grad, axis=1)
    ok = (k > 0) & (k < radii.size - 1) & inside.all(axis=1)
    rows = np.arange(n_rays)
    kc = np.clip(k, 1, radii.size - 2)
    g0, g1, g2 = grad[rows, kc - 1], grad[rows, kc], grad[rows, kc + 1]
    denom = g0 - 2 * g1 + g2
    off = np.where(np.abs(denom) > 1e-12, 0.5 * (g0 - g2) / np.where(denom == 0, 1, denom), 0.0)
    rad = radii[kc] + np.clip(off, -1, 1) * step
    ok &= grad[rows, kc] > 0.2 * np.median(grad[rows, kc][ok]) if ok.any() else ok
    return guess.cx + rad * ca[:, 0], guess.cy + rad * sa[:, 0], ok


def _robust_circle(px: np.ndarray, py: np.ndarray, ok: np.ndarray, *, min_points: int) -> Circle:
    """:func:`fit_circle` to the ``ok`` points, refitted twice without the points more than
    3 robust standard deviations (at least 1 px) from the previous fit."""
    circ = fit_circle(px[ok], py[ok])
    for _ in range(2):
        res = np.hypot(px - circ.cx, py - circ.cy) - circ.r
        mad = 1.4826 * np.median(np.abs(res[ok])) if ok.any() else 1.0
        keep = ok & (np.abs(res) < max(3 * mad, 1.0))
        if keep.sum() < min_points:
            break
        circ = fit_circle(px[keep], py[keep])
    return circ


def find_ball(
    pixels: np.ndarray, *, min_radius_frac: float = 0.08, max_side: int = 800, min_contrast: float = 0.05
) -> Circle:
    """Find the mirror ball (the largest clear circle) in a photograph.

    A Hough transform for circles (Yuen et al. 1990, "Comparative study of Hough transform
    methods for circle finding", as implemented by OpenCV's ``HoughCircles``) on the log
    luminance gives a rough circle; :func:`refine_circle` makes it sub-pixel accurate.

    Args:
        pixels: (H, W, 3) linear image (a single exposure or an HDR merge).
        min_radius_frac: smallest ball radius to look for, as a fraction of the shorter side.
        max_side: the Hough transform runs on a copy at most this many pixels wide.
        min_contrast: smallest accepted :func:`rim_contrast` (log luminance step at the rim).

    Returns:
        The ball's :class:`Circle`.

    Raises:
        InputError: no circle was found.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim not in (2, 3) or min(pixels.shape[:2]) < 16:
        raise InputError(f"image too small to hold a mirror ball: {pixels.shape}")
    img = _log_image(pixels)
    h, w = img.shape
    scale = min(1.0, max_side / max(h, w))
    small = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA) \
        if scale < 1 else img
    small8 = np.round(small * 255).astype(np.uint8)
    small8 = cv2.GaussianBlur(small8, (0, 0), 1.5)
    side = min(small8.shape)
    rmin = max(4, int(min_radius_frac * side))
    rmax = int(0.5 * side * 1.05) + 2
    circles = None
    for p2 in (0.9, 0.8, 0.7, 0.6, 0.5):
        circles = cv2.HoughCircles(small8, cv2.HOUGH_GRADIENT_ALT, dp=1.0, minDist=side,
                                   param1=60, param2=p2, minRadius=rmin, maxRadius=rmax)
        if circles is not None and len(circles):
            break
    if circles is None or not len(circles):
        for p2 in (60, 40, 25):
            circles = cv2.HoughCircles(small8, cv2.HOUGH_GRADIENT, dp=1.5, minDist=side,
                                       param1=80, param2=p2, minRadius=rmin, maxRadius=rmax)
            if circles is not None and len(circles):
                break
    if circles is None or not len(circles):
        raise InputError("no mirror ball found in the image (give its circle with --ball CX,CY,R)")
    c = np.asarray(circles).reshape(-1, 3)
    c = c[0]  # OpenCV lists the best-supported circle first
    guess = Circle((c[0] + 0.5) / scale, (c[1] + 0.5) / scale, c[2] / scale)
    circ = refine_circle(pixels, guess)
    # second pass in a narrow band: interior edges near the rim cannot compete; most of
    # the rim must then lie on one circle (noise or clutter does not)
    circ = refine_circle(pixels, circ, search=max(2.0 / circ.r, 0.03), outermost=True, min_inliers=0.5)
    contrast = rim_contrast(pixels, circ)
    if contrast < min_contrast:
        raise InputError(
            f"no mirror ball found: the best circle's rim has {100 * contrast:.1f}% contrast "
            "(give the ball's circle with --ball CX,CY,R)"
        )
    return circ


def rim_contrast(pixels: np.ndarray, circle: Circle, *, offset: float = 2.0, n_rays: int = 180) -> float:
    """Median over the rim of ``|log L(r + offset) - log L(r - offset)|`` (luminance just
    outside vs. just inside the circle): how clearly the circle separates two regions.
    A mirror ball shows tens of percent; noise or a flat wall shows a fraction of one."""
    lum = np.maximum(_luminance(pixels), 1e-8).astype(np.float32)
    lum = cv2.GaussianBlur(lum, (0, 0), 0.7)
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    vals = []
    for rr in (circle.r + offset, max(circle.r - offset, 1.0)):
        xs = (circle.cx + rr * np.cos(ang) - 0.5).astype(np.float32)[None, :]
        ys = (circle.cy + rr * np.sin(ang) - 0.5).astype(np.float32)[None, :]
        vals.append(cv2.remap(lum, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0])
    return float(np.median(np.abs(np.log(vals[0] / vals[1]))))


def ball_mask(shape: tuple[int, int], circle: Circle, *, shrink: float = 0.0) -> np.ndarray:
    """Pixels whose centres lie inside ``circle`` (radius reduced by ``shrink`` pixels).

    Returns:
        (H, W) bool mask.
    """
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    return np.hypot(xx + 0.5 - circle.cx, yy + 0.5 - circle.cy) < circle.r - shrink
