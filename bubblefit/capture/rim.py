"""The rim of a circle in an image: samples along rays, support, and the sub-pixel rim.

:func:`rim_support` scores a circle by the fraction of its rim, sampled along rays
from its centre, where the evidence (a change map, or the smoothed photo) jumps across
it by several noise units; :func:`refine_rim` moves the circle onto the sub-pixel rim
points (the steepest point of each ray's profile) with the algebraic circle fit, and
:func:`roundness` says how much of the rim actually lies on the circle. Array
coordinates: pixel centres at integers. Used by :func:`bubblefit.capture.disc.find_disc`;
see ``docs/design.md`` (disc detection).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from scipy import ndimage as ndi

from ..errors import InputError
from .circle import kasa_circle_fit

__all__ = ["Evidence", "bilinear", "rim_support", "rim_blur", "change_beyond", "refine_rim", "roundness", "N_RAYS",
           "MIN_JUMP", "BEYOND_GAP", "BEYOND_BLURS", "BEYOND_ARC", "BEYOND_LEVEL", "BEYOND_LEAK",
           "TEXTURE_FACTOR"]

#: What the rim is seen in: a change map against a background photo, or the photo's edges.
Evidence = Literal["change", "edges"]

#: Rays around a circle when its rim is scored or refined.
N_RAYS = 256
#: Smallest jump across the rim, in noise units, for a ray to support a circle.
MIN_JUMP = 4.0
#: Patch beyond a circle where the change map says whether the change goes on
#: (:func:`change_beyond`): 3 px deep and ``BEYOND_ARC`` px along the circle, from
#: ``BEYOND_GAP`` px or ``BEYOND_BLURS`` rim widths outside it, whichever is further
#: (a step blurred by a Gaussian keeps 3e-5 of its jump 4 standard deviations out: a
#: bright rim's tail is not film beyond it). Where nothing changed, the map is the norm of
#: three smoothed noise channels (a chi distribution, mean 1.60) and the patch's mean is
#: 1.59 with a standard deviation of 0.25: above ``BEYOND_LEVEL`` at 0.2 % of the rim
#: (white noise, 4608 rays on circles of radius 10 to 160 px).
BEYOND_GAP = 5.0
BEYOND_BLURS = 4.0
BEYOND_ARC = 8.0
BEYOND_LEVEL = 2.5
#: Share of a rim's jump taken off the patch's mean all the same: a thin bright rim (a
#: Fresnel line) falls more steeply than its jump says, so its width is underestimated;
#: 0.007 is the mean 5-8 px out of ``1 - Phi(d / 2.5)``, a step blurred by 2.5 px in all.
BEYOND_LEAK = 0.007
#: Without a background photo, the rim's step or line must exceed this many times the
#: median of the same evidence at other radii along the ray (the texture) to support it.
TEXTURE_FACTOR = 2.0


# --------------------------------------------------------------------------------------
# Rays
# --------------------------------------------------------------------------------------


def _rays(fields: np.ndarray, circle, offsets: np.ndarray, n_rays: int = N_RAYS):
    """Samples of (C, H, W) fields along rays at radii ``r + offsets`` (array coordinates).

    Returns (C, n_rays, S) bilinear samples and the (n_rays,) mask of rays whose samples
    all lie inside the image.
    """
    cx, cy, r = circle
    th = np.linspace(0.0, 2.0 * math.pi, n_rays, endpoint=False)
    rad = np.maximum(r + offsets[None, :], 0.0)
    x = cx + np.cos(th)[:, None] * rad
    y = cy + np.sin(th)[:, None] * rad
    h, w = fields.shape[1:]
    inside = np.all((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1), axis=1)
    return bilinear(fields, y, x), inside


def bilinear(fields: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(C, *x.shape) bilinear samples of (C, H, W) fields at array coordinates ``(y, x)``,
    the nearest edge's value beyond the image (``scipy.ndimage.map_coordinates`` with
    ``order=1, mode="nearest"``, a fifth of its time on 7424 points)."""
    c, h, w = fields.shape
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    x0 = np.minimum(x.astype(np.intp), max(w - 2, 0))
    y0 = np.minimum(y.astype(np.intp), max(h - 2, 0))
    fx, fy = x - x0, y - y0
    flat = fields.reshape(c, -1)
    i = y0 * w + x0
    dx, dy = min(1, w - 1), (h > 1) * w
    top = flat[:, i] * (1.0 - fx) + flat[:, i + dx] * fx
    bottom = flat[:, i + dy] * (1.0 - fx) + flat[:, i + dy + dx] * fx
    return top * (1.0 - fy) + bottom * fy


#: Offsets (px) along each ray at which a change map is read across a circle.
_BAND_OFFSETS = np.arange(-6.0, 8.01, 0.5)


def _change_bands(fields: np.ndarray, circle) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per ray, the mean of a change map 1.5-6 px inside the circle and 3-8 px outside it
    (noise units), the mask of rays inside the image, and the map along each ray at
    :data:`_BAND_OFFSETS`."""
    s, ok = _rays(fields, circle, _BAND_OFFSETS)
    return s[0][:, _BAND_OFFSETS <= -1.5].mean(axis=1), s[0][:, _BAND_OFFSETS >= 3].mean(axis=1), ok, s[0]


def rim_blur(fields: np.ndarray, circle) -> float:
    """Width (standard deviation, px) of a circle's rim in a change map: the median, over
    the rays whose jump (:func:`_change_bands`) exceeds ``MIN_JUMP``, of the jump over
    ``sqrt(2 pi)`` times the steepest fall within 3 px of the circle (a step blurred by a
    Gaussian of standard deviation ``s`` falls at most by ``jump / (sqrt(2 pi) s)`` per
    pixel); 1 px (the change map's own smoothing) where no ray has such a jump."""
    inner, outer, ok, along = _change_bands(fields, circle)
    jump = inner - outer
    fall = np.max(-np.gradient(along, 0.5, axis=1)[:, np.abs(_BAND_OFFSETS) <= 3.0], axis=1)
    use = ok & (jump > MIN_JUMP) & (fall > 0)
    if not use.any():
        return 1.0
    return float(np.median(jump[use] / (math.sqrt(2.0 * math.pi) * fall[use])))


def change_beyond(fields: np.ndarray, circle) -> float:
    """Fraction of a circle's rim beyond which the change goes on: rays inside the image
    where the change map's mean over a patch 3 px deep and ``BEYOND_ARC`` px along the
    circle, from ``BEYOND_GAP`` px or ``BEYOND_BLURS`` rim widths (:func:`rim_blur`) outside
    it, whichever is further (where the rim's own blurred step has faded), less
    ``BEYOND_LEAK`` times its mean 1.5-6 px inside, exceeds ``BEYOND_LEVEL``.

    Outside a bubble's outline the photo is its background photo, so on the outline this
    is the noise's share but for what else changed against the bubble; a circle nested in
    the bubble (an interference fringe, the edge of a reflection or of the background's
    transmitted image) has the film beyond it.

    Parameters
    ----------
    fields : (1, H, W) float
        The change map (:func:`bubblefit.capture.disc.change_map`, noise units).
    circle : (cx, cy, r)
        Array coordinates (pixel centres at integers).
    """
    gap = max(BEYOND_GAP, BEYOND_BLURS * rim_blur(fields, circle))
    s, ok = _rays(fields, circle, np.concatenate([np.arange(-6.0, -1.49, 0.5), np.arange(gap, gap + 3.01, 0.5)]))
    if not ok.any():
        return 0.0
    inner, outer = s[0][:, :10].mean(axis=1), s[0][:, 10:].mean(axis=1)
    outer = outer - BEYOND_LEAK * np.maximum(inner, 0.0)  # a bright rim's tail is not film beyond it
    k = max(1, int(round(BEYOND_ARC / (2.0 * math.pi * max(circle[2], 1e-9) / outer.size))))
    box = np.ones(k)
    wrap = lambda a: np.concatenate([a[-k:], a, a[:k]])  # noqa: E731  (the rim is closed)
    total = np.convolve(wrap(np.where(ok, outer, 0.0)), box, mode="same")[k:-k]
    count = np.convolve(wrap(ok.astype(float)), box, mode="same")[k:-k]
    patch = total / np.maximum(count, 1.0)
    return float(np.mean(patch[ok] > BEYOND_LEVEL))


def _jumps(fields: np.ndarray, circle, mode: Evidence, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Per ray, the jump of the evidence across the circle in noise units, and validity.

    Change map: mean over 1.5-6 px inside minus mean over 3-8 px outside (the difference
    must end at the rim). Edges: within 2 px of the circle, the larger of the colour step
    across it (means over 2 px on either side) and the colour of a thin line on it (the
    bright or dark rim of a film seen edge-on, against the mean of both sides), over the
    scale of such steps in the photo.
    """
    if mode == "change":
        inner, outer, ok, _ = _change_bands(fields, circle)
        # the difference must end at the rim: at least half of it gone outside
        return np.where(outer < 0.5 * inner, inner - outer, 0.0), ok
    span = max(8.0, 0.3 * circle[2])
    off = np.arange(-span, span + 0.01, 0.5)
    s, ok = _rays(fields, circle, off)

    def band(a, b):  # (3, rays, centres): mean over offsets [centre + a, centre + b]
        k = np.ones(int(round(2 * (b - a))) + 1) / (int(round(2 * (b - a))) + 1)
        m = ndi.convolve1d(s, k, axis=2, mode="nearest")
        return np.roll(m, -int(round(a + b)), axis=2)  # centred at centre + (a + b) / 2

    inner, ring, outer = band(-4.0, -2.0), band(-1.0, 0.0), band(1.0, 3.0)
    step = np.sqrt(np.sum((outer - inner) ** 2, axis=0))
    line = np.sqrt(np.sum((ring - 0.5 * (inner + outer)) ** 2, axis=0))
    m = np.maximum(step, line)  # (rays, offsets): rim evidence at each radius
    near = np.abs(off) <= 2.0
    at_rim = m[:, near].max(axis=1)
    # a rim stands out from the texture at other radii along the same ray
    best = np.minimum(at_rim / noise, at_rim / np.maximum(np.median(m[:, ~near], axis=1), 1e-12) * MIN_JUMP / TEXTURE_FACTOR)
    return best, ok


def rim_support(fields: np.ndarray, circle, mode: Evidence, noise: float = 1.0) -> tuple[float, float]:
    """Fraction of a circle's rim supported by the evidence, and the median jump there.

    Parameters
    ----------
    fields : (C, H, W) float
        The evidence: ``change_map`` (C = 1, noise units) or the smoothed photo (C = 3).
    circle : (cx, cy, r)
        Array coordinates (pixel centres at integers).
    mode : "change" or "edges"
    noise : float
        Scale of a colour step (edges, :func:`_edge_fields`).

    Returns
    -------
    support : fraction of the rays inside the image whose jump exceeds ``MIN_JUMP``.
    contrast : median jump over the rays inside the image, in noise units.
    """
    jump, ok = _jumps(fields, circle, mode, noise)
    if ok.sum() < 0.25 * ok.size:
        return 0.0, 0.0
    j = jump[ok]
    return float(np.mean(j > MIN_JUMP)), float(np.median(j))


# --------------------------------------------------------------------------------------
# Sub-pixel rim
# --------------------------------------------------------------------------------------


def _rim_points(fields: np.ndarray, circle, mode: Evidence, window: float, noise: float):
    """Per ray, the sub-pixel radius of the steepest point of the evidence near the circle.

    Change map: the steepest fall of the difference outward (its outer edge). Edges: the
    outermost colour-gradient peak at least half as strong as the strongest. A parabola through the three samples around the
    extreme gives the sub-pixel position. Returns (x, y) arrays of the rim points.
    """
    off = np.arange(-window, window + 0.01, 0.5)
    s, ok = _rays(fields, circle, off)
    grad = np.gradient(s, 0.5, axis=2)
    if mode == "change":
        strength = -grad[0]
        i = np.argmax(strength, axis=1)
    else:  # the outermost strong colour gradient: the outer flank of a thin bright rim
        strength = np.sqrt(np.sum(grad * grad, axis=0))
        peak = (strength >= np.roll(strength, 1, axis=1)) & (strength >= np.roll(strength, -1, axis=1))
        strong = peak & (strength >= 0.5 * strength.max(axis=1, keepdims=True))
        i = off.size - 1 - np.argmax(strong[:, ::-1], axis=1)
    i = np.clip(i, 1, off.size - 2)
    a = np.take_along_axis(strength, (i - 1)[:, None], 1)[:, 0]
    b = np.take_along_axis(strength, i[:, None], 1)[:, 0]
    c = np.take_along_axis(strength, (i + 1)[:, None], 1)[:, 0]
    den = a - 2 * b + c
    frac = np.where(den < 0, 0.5 * (a - c) / np.where(den < 0, den, -1.0), 0.0)
    rad = circle[2] + off[i] + 0.5 * np.clip(frac, -1, 1)
    th = np.linspace(0.0, 2.0 * math.pi, N_RAYS, endpoint=False)
    jump, _ = _jumps(fields, circle, mode, noise)
    keep = ok & (b > 0) & (jump > MIN_JUMP)  # rays where the rim is seen
    return circle[0] + rad[keep] * np.cos(th[keep]), circle[1] + rad[keep] * np.sin(th[keep])


def roundness(fields: np.ndarray, circle, mode: Evidence, noise: float) -> float:
    """Fraction of the rays inside the image whose sub-pixel rim point lies within
    ``1 + 0.01 r`` pixels of the circle (a square's edge meets its circle on few rays)."""
    x, y = _rim_points(fields, circle, mode, 4.0, noise)
    _, ok = _rays(fields, circle, np.zeros(1))
    if not ok.any():
        return 0.0
    dev = np.abs(np.hypot(x - circle[0], y - circle[1]) - circle[2])
    return float(np.sum(dev < 1.0 + 0.01 * circle[2]) / ok.sum())


def refine_rim(fields: np.ndarray, circle, mode: Evidence, noise: float) -> tuple[float, float, float]:
    """Algebraic circle through the rim points of the supported rays, outlying rays
    rejected, three passes on ever narrower windows."""
    for window in (6.0, 3.0, 2.0):
        x, y = _rim_points(fields, circle, mode, window, noise)
        if x.size < 12:
            break
        keep = np.ones(x.size, bool)
        for _ in range(4):
            try:
                cx, cy, r = kasa_circle_fit(x[keep], y[keep])
            except InputError:
                return circle
            dev = np.hypot(x - cx, y - cy) - r
            mad = 1.4826 * float(np.median(np.abs(dev[keep]))) + 0.1
            new = np.abs(dev) < 3.0 * mad
            if new.sum() < 12 or np.array_equal(new, keep):
                break
            keep = new
        reach = max(0.2 * circle[2], window)
        if math.hypot(cx - circle[0], cy - circle[1]) > reach or abs(r - circle[2]) > reach:
            break  # the rim points ran off to another edge: keep the scored circle
        circle = (cx, cy, r)
    return circle
