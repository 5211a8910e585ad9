"""Finding a mirror ball in a photograph: candidate circles, then its sub-pixel outline.

The ball's outline is the circle that separates the reflection from the background
(paper sec. 3.2; see ``docs/design.md``, "Light probes"). :func:`find_ball` takes circle
candidates from Hough voting (:mod:`bubblefit.capture.edges`), refines each
(:func:`refine_circle` locates the edge along rays from its centre to sub-pixel accuracy
and fits a circle to those positions, :func:`fit_circle`, Kasa 1976), and accepts the best
only when most of its rim shows a clear edge on the circle, more than chance gives
(:func:`bubblefit.capture.edges.rim_support`).

Image positions are continuous, with pixel ``(row i, column j)`` centred at
``(x, y) = (j + 1/2, i + 1/2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from .circle import kasa_circle_fit
from .edges import gradient_noise, gradients, hough_circles, rim_support

__all__ = ["Circle", "RimEvidence", "find_ball", "ball_evidence", "refine_circle", "fit_circle", "ball_mask"]


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


def _log_luminance(pixels: np.ndarray) -> np.ndarray:
    """Log luminance, floored at 1e-3 of the 99.5th percentile.

    A mirror ball's outline shows in log luminance whatever the exposure, in a single
    photograph as in an HDR merge; the floor keeps the noise of black pixels from
    dominating the gradients.
    """
    lum = np.maximum(_luminance(pixels), 0.0)
    top = float(np.percentile(lum, 99.5))
    floor = max(1e-3 * top, 1e-12)
    return np.log(lum + floor).astype(np.float32)


def fit_circle(x: np.ndarray, y: np.ndarray) -> Circle:
    """Least-squares (Kasa) circle through points, as a :class:`Circle`:
    :func:`bubblefit.capture.circle.kasa_circle_fit`, the package's one circle fit."""
    return Circle(*kasa_circle_fit(x, y))


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


@dataclass(frozen=True)
class RimEvidence:
    """How clearly a circle is a mirror ball's outline (see :func:`rim_support`).

    Attributes
    ----------
    circle
        The circle judged.
    support
        Fraction of the rim with a sharp edge on the circle (:func:`bubblefit.capture.edges.rim_support`).
    chance
        The 95th percentile of the support that circles of the same size placed at random
        in the same image reach: what texture alone gives.
    """

    circle: Circle
    support: float
    chance: float


def _outermost_rim(pixels: np.ndarray, gx, gy, noise: float, guess: Circle) -> Circle:
    """The ball's outline from a candidate circle, sub-pixel.

    The candidate is refined to the strongest nearby edge, then circles concentric with it
    are scanned outward to 1.35 times its radius: the outline is the outermost radius where
    the rim support (:func:`bubblefit.capture.edges.rim_support`, 0.5 px band) has a local maximum of at least 3/4
    of the best one (details of the reflection crowd just inside a mirror ball's rim and may
    be sharper than the outline itself; the background outside it is not concentric). A
    last refinement in a band of 2.5 px locates that edge.
    """
    c1 = refine_circle(pixels, guess, search=0.1)
    radii = np.arange(0.9 * c1.r, 1.35 * c1.r, 0.5)
    sup = np.array([rim_support(gx, gy, noise, Circle(c1.cx, c1.cy, r), band=0.5) for r in radii])
    peak = np.zeros(sup.shape, dtype=bool)  # a plateau's first point counts as its peak
    peak[1:-1] = (sup[1:-1] > sup[:-2]) & (sup[1:-1] >= sup[2:])
    good = np.nonzero(peak & (sup >= max(0.75 * sup.max(), 0.4)))[0]
    r_out = float(radii[good[-1]]) if good.size else c1.r
    return refine_circle(pixels, Circle(c1.cx, c1.cy, r_out), search=max(2.5 / r_out, 0.03), outermost=True)


def _chance_support(gx, gy, noise: float, found: Circle, *, trials: int = 48) -> float:
    """95th percentile of :func:`bubblefit.capture.edges.rim_support` for circles of about
    ``found``'s size placed at random in the image, their centres at least a quarter radius
    from its centre: the support that texture alone gives here (a fixed seed: the same image
    gives the same answer)."""
    rng = np.random.default_rng(0)
    h, w = gx.shape
    r = found.r
    out = []
    for _ in range(trials):
        cx = rng.uniform(min(r, w / 2), max(w - r, w / 2))
        cy = rng.uniform(min(r, h / 2), max(h - r, h / 2))
        if np.hypot(cx - found.cx, cy - found.cy) >= 0.25 * r:
            out.append(rim_support(gx, gy, noise, Circle(cx, cy, r * rng.uniform(0.8, 1.2))))
    return float(np.percentile(out, 95)) if out else 0.0


def ball_evidence(pixels: np.ndarray, *, min_radius_frac: float = 0.08, max_side: int = 256,
                  candidates: int = 10) -> RimEvidence | None:
    """The most convincing mirror-ball outline in a photograph, with its evidence.

    Steps: circle candidates by gradient-directed Hough voting on the log luminance of a
    copy at most ``max_side`` pixels wide (:func:`bubblefit.capture.edges.hough_circles`);
    each refined to its outermost concentric edge at full resolution
    (:func:`_outermost_rim`); the one with the longest supported rim (support times radius,
    among those with support of at least 1/2) is kept and compared with what random circles
    reach (:class:`RimEvidence`). Returns None when no candidate has half its rim supported.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim not in (2, 3) or min(pixels.shape[:2]) < 16:
        raise InputError(f"image too small to hold a mirror ball: {pixels.shape}")
    if not np.all(np.isfinite(pixels)):
        raise InputError("the probe has NaN or infinite pixels")
    img = _log_luminance(pixels)
    h, w = img.shape
    scale = min(1.0, max_side / max(h, w))
    small = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))),
                       interpolation=cv2.INTER_AREA) if scale < 1 else img
    side = min(small.shape)
    r_min, r_max = max(4, int(min_radius_frac * side)), int(0.5 * side * 1.05) + 2
    found = hough_circles(*gradients(small, 1.0), r_min, r_max, count=candidates)
    gx, gy = gradients(img, 0.7)
    noise = gradient_noise(img, 0.7)
    best: tuple[float, Circle] | None = None
    for cx, cy, r in found:
        try:
            circ = _outermost_rim(pixels, gx, gy, noise, Circle(cx / scale, cy / scale, r / scale))
        except InputError:
            continue
        s = rim_support(gx, gy, noise, circ)
        if s >= 0.5 and (best is None or s * circ.r > best[0] * best[1].r):
            best = (s, circ)
    if best is None:
        return None
    return RimEvidence(best[1], best[0], _chance_support(gx, gy, noise, best[1]))


def find_ball(pixels: np.ndarray, *, min_support: float = 0.75, min_radius_frac: float = 0.08) -> Circle:
    """Find the mirror ball (the largest circle with a clear outline) in a photograph.

    :func:`ball_evidence` proposes the best outline; it is accepted when at least
    ``min_support`` of its rim shows a sharp edge on the circle and that is at least 0.1
    more than random circles of its size reach in the same image (so that a texture of
    small circles, or pure noise, is not taken for a ball). Works in log luminance, on
    8-bit photographs and linear float (EXR, HDR) merges alike.

    A perfect mirror's outline is invisible wherever the ball reflects the same thing that
    is seen beside it (its rim reflects what lies straight behind it): a ball in front of a
    plain backdrop that also fills the rim's reflection has no visible outline there, and
    is refused rather than replaced by the edge of the backdrop's reflection inside it.

    Parameters
    ----------
    pixels
        (H, W, 3) or (H, W) linear image (a single exposure or an HDR merge).
    min_support
        Fraction of the rim that must show the outline.
    min_radius_frac
        Smallest ball radius to look for, as a fraction of the shorter side.

    Returns
    -------
    Circle
        The ball's outline, sub-pixel.

    Raises
    ------
    InputError
        No clear mirror-ball outline.

    References
    ----------
    Kimme, Ballard & Sklansky 1975 (Hough voting); Kasa 1976 (circle fit); Immerkaer 1996
    (noise); see ``docs/design.md``, "Light probes".
    """
    ev = ball_evidence(pixels, min_radius_frac=min_radius_frac)
    hint = "(give the ball's circle with --ball CX,CY,R)"
    if ev is None:
        raise InputError(f"no mirror ball found: no circle has half its rim on a clear edge {hint}")
    if ev.support < min_support or ev.support < ev.chance + 0.1:
        c = ev.circle
        raise InputError(
            f"no clear mirror-ball outline: the best circle ({c.cx:.1f}, {c.cy:.1f}, r {c.r:.1f} px) has a "
            f"clear edge on {100 * ev.support:.0f}% of its rim (random circles here: {100 * ev.chance:.0f}%; "
            f"{100 * min_support:.0f}% needed) {hint}"
        )
    return ev.circle


def ball_mask(shape: tuple[int, int], circle: Circle, *, shrink: float = 0.0) -> np.ndarray:
    """Pixels whose centres lie inside ``circle`` (radius reduced by ``shrink`` pixels).

    Returns:
        (H, W) bool mask.
    """
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    return np.hypot(xx + 0.5 - circle.cx, yy + 0.5 - circle.cy) < circle.r - shrink
