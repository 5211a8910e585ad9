"""Finding the bubble's disc in a photograph, with or without a photo of the background.

A bubble far from the camera is a disc ``(cx, cy, r)`` in the image (the
``orthographic`` camera of ``docs/design.md``; a sphere seen in perspective is a disc to
well under a pixel near the optical axis). :func:`find_disc` finds it in three steps:

1. **Evidence.** With a background photo: the colour difference ``photo - background``
   in noise units, smoothed a little (:func:`change_map`); the bubble is where the two
   differ, and its silhouette is the outer edge of that difference. Without one: the
   smoothed photo itself, whose rim shows as a colour step or a thin bright (or dark)
   line where the film's Fresnel reflection and interference bands start abruptly.
2. **Candidates and their rim support.** Circles from the changed region (its convex
   hull) and from OpenCV's circular Hough transform (Yuen et al. 1990), run on a copy of
   at most :data:`HOUGH_SIZE` pixels on its short side; each is scored
   by the fraction of its rim, sampled along rays from its centre, where the evidence
   jumps across the circle by ``MIN_JUMP`` noise units (and, without a background, by
   ``TEXTURE_FACTOR`` times the texture at other radii along the same ray)
   (:func:`bubblefit.capture.rim.rim_support`). With a background photo the disc that
   explains most of the changed pixels wins (a highlight inside the bubble is a small
   supported circle too).
3. **Sub-pixel rim and roundness.** Along each supported ray the rim is the steepest
   point of the evidence's outer flank (the 50% point of a blurred, antialiased step),
   located by a parabola through the three samples around it; the algebraic circle fit
   (:func:`bubblefit.capture.circle.kasa_circle_fit`) through those points, with
   rejection of outlying rays, gives the disc (:func:`bubblefit.capture.rim.refine_rim`).
   A disc counts as found only when its rim is supported on ``MIN_SUPPORT`` of its
   length (``MIN_SUPPORT_EDGES`` without a background, where texture can line up with
   part of a circle by chance) and the rim points lie on the circle there
   (:func:`bubblefit.capture.rim.roundness`; a square's edge does not). Without a
   background, up to ``ROUND_TRIES`` supported circles are tried in rank order.

Coordinates of :class:`Disc` follow :class:`bubblefit.model.geometry.OrthographicCamera`:
x right, y down, the image's top-left corner at (0, 0), pixel centres at +1/2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage as ndi

from ..errors import InputError
from .rim import MIN_JUMP, Evidence, change_beyond, refine_rim, rim_support, roundness

__all__ = ["Disc", "find_disc", "change_map", "bubble_contrast", "change_spread", "MIN_SUPPORT", "MIN_SUPPORT_EDGES",
           "MAX_BEYOND", "MIN_RADIUS", "NO_BUBBLE_CONTRAST", "NO_BUBBLE_SPREAD"]

#: Fraction of the rim that must be supported for a disc to count as found, with a
#: background photo (the difference must end on the circle) and without one (a stricter
#: bar: texture can line up with part of a circle by chance).
MIN_SUPPORT = 0.5
MIN_SUPPORT_EDGES = 0.7
#: Largest fraction of a disc's rim beyond which the change may go on, with a background
#: photo (:func:`bubblefit.capture.rim.change_beyond`). Outside its outline a bubble is
#: its background photo: noise alone leaves 0.2 % of the rim (``BEYOND_LEVEL``), and the
#: rest is for something else that changed against the bubble (a wand, a hair). A circle
#: nested in the bubble (a fringe, the edge of a reflection or of the transmitted
#: background) has the film beyond about two thirds of its rim (the demo's scene with the
#: bright wall behind the bubble, ``experiments/disc_detection.py --demo-sizes``); the
#: outlines of the validation set have at most 0.8 %.
MAX_BEYOND = 0.05
#: Smallest disc radius searched, pixels.
MIN_RADIUS = 4.0
#: Short side, in pixels, of the copy the Hough transform searches. Its cost grows with
#: about the fourth power of the image's size (every edge pixel votes along its gradient
#: over the whole radius range, and every centre above threshold ranks all edge pixels):
#: on the change map of a 320x320 photo whose bubble fills half of it, resampled, 5 ms
#: at 160 px, 0.23 s at 320 and 3.8 s at 640. Its circles only seed the rim search, which
#: works on the full-resolution evidence (``experiments/disc_detection.py --scales 1,2,3
#: --hough-sizes 200,0``).
HOUGH_SIZE = 200
#: Supported circles, best ranked first, whose roundness is checked before none is found
#: (without a background photo).
ROUND_TRIES = 3


@dataclass(frozen=True)
class Disc:
    """A disc in an image: centre ``(cx, cy)`` and radius ``r`` in pixels.

    Attributes
    ----------
    cx, cy, r : float
        Pixel centres at +1/2 (:class:`bubblefit.model.geometry.OrthographicCamera`);
        NaN when not found.
    found : bool
        Whether a disc whose rim is mostly supported by the evidence was found.
    contrast : float
        Median jump of the evidence across the rim, in noise units.
    support : float
        Fraction of the rim (rays inside the image) where the jump exceeds ``MIN_JUMP``
        (at least ``MIN_SUPPORT`` with a background photo, ``MIN_SUPPORT_EDGES`` without).
    reason : str
        Why no disc was found (empty when found).
    """

    cx: float
    cy: float
    r: float
    found: bool
    contrast: float = 0.0
    support: float = 0.0
    reason: str = ""

    def refusal(self) -> str:
        """Why a fit must not use this detection: the detector's ``reason`` when no disc
        was found, else (a disc kept with a doubt noted in ``reason``, e.g. only the
        simpler detector's guess) that no rim is clear. Fitting a disc the evidence does
        not support measures films that are not there."""
        return self.reason if not self.found else "no rim of a bubble is clear in the photo"

    def to_json(self) -> dict[str, float]:
        """``{"cx", "cy", "r"}`` in pixels (the ``disc`` of the command line's JSON)."""
        return {"cx": round(float(self.cx), 3), "cy": round(float(self.cy), 3), "r": round(float(self.r), 3)}


# --------------------------------------------------------------------------------------
# Evidence
# --------------------------------------------------------------------------------------


def _rgb(x: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise InputError(f"{name}: expected an (H, W) or (H, W, 3) image, got shape {a.shape}")
    a = a[:, :, :3] if a.shape[2] >= 3 else np.repeat(a, 3, axis=2)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name}: the image has NaN or Inf values")
    return a


def _encode(x: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance to a perceptual scale (gamma 1/2.2 of ``x / scale``), where the
    shot noise and the 8-bit quantisation of sRGB files are nearly uniform."""
    return np.clip(x / scale, 0.0, None) ** (1.0 / 2.2)


def _neighbour_noise(x: np.ndarray) -> float:
    """Robust per-pixel noise of (H, W, C) images: MAD of horizontal neighbour differences
    over sqrt(2) (texture raises it, so it is an upper bound on textured images)."""
    d = (x[:, 1:] - x[:, :-1]).ravel()
    s = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)
    return max(s, 1e-12)


def change_map(photo: np.ndarray, background: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
    """How much ``photo`` differs from ``background`` per pixel, in noise units.

    The colour difference ``z_c`` is smoothed by a Gaussian of one pixel and its norm over
    the three channels is divided by its own noise level, estimated from the quietest
    quarter of the image (for a chi distribution with three degrees of freedom the 25th
    percentile is 1.10 times the per-channel standard deviation; the bubble must cover
    less than three quarters of the frame).

    Parameters
    ----------
    photo, background : (H, W, 3) float
        Linear images of the same fixed camera.
    sigma : (H, W) or (H, W, 3) float, optional
        Per-pixel noise standard deviation of the photo (linear); then ``z_c`` is the
        linear difference over ``sqrt(2) sigma``. Otherwise the noise is taken as uniform
        on a perceptual scale (:func:`_encode`, as for shot noise and 8-bit sRGB files)
        and carried back to linear at the background's level.

    Returns
    -------
    (H, W) float, about 1 where nothing changed.
    """
    if sigma is not None:
        s = np.broadcast_to(np.asarray(sigma, float)[..., None] if np.ndim(sigma) == 2 else sigma, photo.shape)
        z = (photo - background) / np.maximum(math.sqrt(2.0) * s, 1e-12)
    else:
        # linear difference over the noise of a perceptual scale carried back to linear
        # (d lin / d enc ~ (x / scale)^(1.2 / 2.2)) at the smoothed background's level:
        # linear, so a partly covered rim pixel is its coverage's mix (no gamma bias)
        scale = max(float(np.percentile(background, 99.5)), float(np.percentile(photo, 99.5)), 1e-12)
        level = np.stack([ndi.gaussian_filter(background[..., c], 2.0) for c in range(3)], axis=-1)
        z = (photo - background) / (np.clip(level / scale, 1e-3, None) ** (1.2 / 2.2) * scale)
    zs = np.stack([ndi.gaussian_filter(z[..., c], 1.0) for c in range(3)], axis=-1)
    m = np.sqrt(np.sum(zs * zs, axis=-1))
    return m / max(float(np.percentile(m, 25.0)) / 1.10, 1e-12)


def _edge_fields(photo: np.ndarray) -> tuple[np.ndarray, float]:
    """(3, H, W) perceptual photo smoothed by one pixel, and the scale of its steps.

    The scale is the larger of the noise of a step (:func:`_jumps`) and half the 75th
    percentile of the photo's own 3-pixel colour steps: on a textured background a rim
    must stand out from the texture, not only from the noise.
    """
    enc = _encode(photo, max(float(np.percentile(photo, 99.5)), 1e-12))
    fields = np.stack([ndi.gaussian_filter(enc[..., c], 1.0) for c in range(3)])
    return fields, _neighbour_noise(enc) / (2.0 * math.sqrt(math.pi)) * math.sqrt(1.5)


# --------------------------------------------------------------------------------------
# Candidates
# --------------------------------------------------------------------------------------


def _region_candidates(change: np.ndarray, r_max: float) -> list[tuple[float, float, float]]:
    """Circles of the largest regions where the photo differs from the background.

    Pixels more than ``MIN_JUMP`` noise units changed, closed over small gaps (a dim patch
    of the film), largest components; each gives the circle of its convex hull's area
    and centroid and the smallest circle enclosing it.
    """
    mask = (change > MIN_JUMP).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    out = []
    order = np.argsort(stats[1:, cv2.CC_STAT_AREA])[::-1][:3] + 1
    for k in order:
        if stats[k, cv2.CC_STAT_AREA] < math.pi * MIN_RADIUS**2:
            continue
        ys, xs = np.nonzero(labels == k)
        hull = cv2.convexHull(np.stack([xs, ys], axis=1).astype(np.float32))
        mom = cv2.moments(hull)
        if mom["m00"] > 0:
            r = math.sqrt(mom["m00"] / math.pi)
            out.append((mom["m10"] / mom["m00"], mom["m01"] / mom["m00"], r))
        (ex, ey), er = cv2.minEnclosingCircle(hull)
        out.append((float(ex), float(ey), float(er)))
    return [c for c in out if MIN_RADIUS <= c[2] <= r_max]


def _hough_candidates(gray01: np.ndarray, r_min: float, r_max: float, n: int = 24) -> list[tuple[float, float, float]]:
    """The strongest circles of OpenCV's gradient Hough transform on an image in [0, 1],
    searched on a copy whose short side is at most :data:`HOUGH_SIZE` (area-averaged), in
    the image's array coordinates."""
    h, w = gray01.shape
    s = min(1.0, HOUGH_SIZE / min(h, w))
    work = np.clip(gray01, 0, 1).astype(np.float32)
    if s < 1.0:
        work = cv2.resize(work, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
        sy, sx = work.shape[0] / h, work.shape[1] / w
    else:
        sy = sx = 1.0
    img = cv2.GaussianBlur((work * 255).astype(np.uint8), (0, 0), 1.5)
    circles = cv2.HoughCircles(img, cv2.HOUGH_GRADIENT, dp=1, minDist=4, param1=40, param2=12,
                               minRadius=max(1, int(r_min * min(sx, sy))),
                               maxRadius=int(math.ceil(r_max * max(sx, sy))))
    if circles is None:
        return []
    # a working pixel i covers the image's pixels [i / s, (i + 1) / s): centre at (i + 1/2) / s - 1/2
    return [(float((x + 0.5) / sx - 0.5), float((y + 0.5) / sy - 0.5), float(r / math.sqrt(sx * sy)))
            for x, y, r in circles[0, :n]]


def _local_search(score, circle) -> tuple[tuple[float, float, float], float, float]:
    """Best (support, contrast) circle on a small grid around a candidate (steps of r/20,
    then r/50); ``score`` maps a circle to its :func:`rim_support`."""
    best = (circle, *score(circle))
    for step in (max(1.0, 0.05 * circle[2]), max(0.5, 0.02 * circle[2])):
        improved = True
        while improved:
            improved = False
            cx, cy, r = best[0]
            for dx, dy, dr in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
                c = (cx + dx * step, cy + dy * step, r + dr * step)
                if c[2] < MIN_RADIUS:
                    continue
                sup, con = score(c)
                if (sup, con) > best[1:]:
                    best, improved = (c, sup, con), True
    return best


def _scorer(fields, mode: Evidence, noise: float):
    """:func:`rim_support` of a circle, each circle (to 1e-6 px) scored once: the grid
    searches around nearby candidates, and a step back to where one came from, revisit
    circles."""
    seen: dict = {}

    def score(c):
        key = tuple(round(float(v), 6) for v in c)
        if key not in seen:
            seen[key] = rim_support(fields, c, mode, noise)
        return seen[key]

    return score


# --------------------------------------------------------------------------------------
# The disc
# --------------------------------------------------------------------------------------


def _rank(found, changed_xy: tuple[np.ndarray, np.ndarray] | None) -> tuple:
    """Order of candidate circles: rim mostly supported first; then, with a background
    photo, the share of all changed pixels (their ``(xs, ys)``) the disc explains (a
    highlight inside the bubble is a small supported circle too); then support and
    contrast."""
    (cx, cy, r), support, contrast = found
    explained = 0.0
    if changed_xy is not None:
        xs, ys = changed_xy
        explained = float(np.mean(np.hypot(xs - cx, ys - cy) <= r + 3)) if xs.size else 0.0
    return (support >= (MIN_SUPPORT if changed_xy is not None else MIN_SUPPORT_EDGES), round(explained, 2), support,
            contrast)


def _nested(beyond: float) -> str:
    """The reason a supported circle beyond which the change goes on is not the outline."""
    return (f"no circle outlines the bubble: the change goes on beyond the best supported circle on "
            f"{100 * beyond:.0f}% of its rim (need at most {100 * MAX_BEYOND:.0f}%), so it is an edge inside "
            "the bubble and the outline's rim is too faint to find")


def _not_found(reason: str, contrast: float = 0.0, support: float = 0.0) -> Disc:
    nan = float("nan")
    return Disc(nan, nan, nan, False, contrast, support, reason)


def find_disc(photo: np.ndarray, background: np.ndarray | None = None, *, sigma: np.ndarray | None = None) -> Disc:
    """Find the bubble's disc in a photograph.

    Parameters
    ----------
    photo : (H, W, 3) float
        Linear image with the bubble.
    background : (H, W, 3) float, optional
        Linear image of the same view without the bubble (same camera and exposure).
    sigma : (H, W) or (H, W, 3) float, optional
        Per-pixel noise standard deviation of ``photo`` (linear), if known; otherwise
        estimated from the images.

    Returns
    -------
    Disc
        ``found`` is False, with the ``reason`` in words, when the photo matches the
        background within its noise, or when no circle's rim is mostly supported.

    References
    ----------
    I. Kasa, IEEE Trans. Instrum. Meas. 25(1), 1976 (circle fit); H. K. Yuen, J. Princen,
    J. Illingworth and J. Kittler, "Comparative study of Hough transform methods for circle
    finding", Image Vision Comput. 8(1), 1990. See ``docs/design.md`` (disc detection).
    """
    p = _rgb(photo, "photo")
    h, w = p.shape[:2]
    if min(h, w) < 4 * MIN_RADIUS:
        return _not_found(f"the photo is {w}x{h} pixels: too small to find a bubble in")
    r_max = 0.5 * math.hypot(h, w)
    if background is not None:
        b = _rgb(background, "background")
        if b.shape != p.shape:
            raise InputError(f"the background is {b.shape[1]}x{b.shape[0]} but the photo {w}x{h} pixels")
        change = change_map(p, b, sigma)
        if float(np.mean(change > MIN_JUMP)) < math.pi * MIN_RADIUS**2 / (h * w):
            return _not_found("the photo matches the background within its noise: no bubble")
        fields, mode, noise = change[None], "change", 1.0
        cands = _region_candidates(change, r_max)
        cands += _hough_candidates(np.clip(change / (4 * MIN_JUMP), 0, 1), MIN_RADIUS, min(h, w) / 2 * 1.1)
    else:
        fields, noise = _edge_fields(p)
        mode = "edges"
        gray = np.mean(fields, axis=0)
        cands = _hough_candidates(gray / max(float(gray.max()), 1e-12), max(MIN_RADIUS, min(h, w) / 20),
                                  min(h, w) / 2 * 1.1)
    if not cands:
        return _not_found("nothing round differs from the background" if mode == "change"
                          else "no circular edge in the photo")
    score = _scorer(fields, mode, noise)
    scored = sorted(((score(c), c) for c in cands), reverse=True)
    found = [_local_search(score, c) for _, c in scored[:6]]
    changed_xy = np.nonzero(change > MIN_JUMP)[::-1] if mode == "change" else None
    ranked = sorted(found, key=lambda f: _rank(f, changed_xy), reverse=True)
    need = MIN_SUPPORT if mode == "change" else MIN_SUPPORT_EDGES
    what = "differs from the background" if mode == "change" else "has a rim"
    circle, support, contrast = ranked[0]
    if support < need:
        return _not_found(
            f"nothing round {what}: the best circle's rim is supported on {100 * support:.0f}% of its length "
            f"(need {100 * need:.0f}%)", contrast, support)
    # Without a background photo, the best-ranked supported circle whose edge is round: a
    # wider circle can collect support from the texture's edges along most rays and still
    # not be the rim. (With one, the best circle explains the change; another one would be
    # a highlight inside the bubble.)
    tried, first = [], None
    for circle, support, contrast in ranked[:1 if mode == "change" else ROUND_TRIES]:
        if support < need:
            break
        if any(max(abs(circle[0] - t[0]), abs(circle[1] - t[1]), abs(circle[2] - t[2])) <= max(1.0, 0.02 * t[2])
               for t in tried):
            continue
        tried.append(circle)
        refined = refine_rim(fields, circle, mode, noise)
        sup2, con2 = rim_support(fields, refined, mode, noise)
        if sup2 >= need:
            circle, support, contrast = refined, sup2, con2
        round_ = roundness(fields, circle, mode, noise)
        if round_ >= need:
            # with a background photo, the outline: nothing changed beyond it
            beyond = change_beyond(fields, circle) if mode == "change" else 0.0
            if beyond > MAX_BEYOND:
                return _not_found(_nested(beyond), contrast, support)
            cx, cy, r = circle
            return Disc(cx + 0.5, cy + 0.5, r, True, contrast, support, "")
        first = first or (round_, contrast, support)
    round_, contrast, support = first
    return _not_found(f"nothing round {what}: its edge follows the best circle on only {100 * round_:.0f}% of the rim "
                      f"(need {100 * need:.0f}%)", contrast, support)


# --------------------------------------------------------------------------------------
# Is it a bubble: the disc against the background photo
# --------------------------------------------------------------------------------------


#: A photo whose pixels on the disc differ from the background photo's by less than this
#: many times the pair's noise (robust RMS, relative to the same outside the disc) has no
#: bubble in it. Pure noise gives 1; any bubble transmits t^4 of the background and adds
#: its reflection, many noise units on every pixel.
NO_BUBBLE_CONTRAST = 2.0


#: A photo without a bubble differs from its background photo by noise alone, so the 99th
#: percentile of the per-pixel ``z^2`` (mean over channels) is about 4.8 times its median
#: (chi^2 with 3 degrees of freedom, over 3); any bubble that covers a percent of the photo
#: lifts it far above :data:`NO_BUBBLE_SPREAD`. Both this and :data:`NO_BUBBLE_CONTRAST`
#: must say "noise" before a photo is refused, so a wrong disc never refuses a real bubble.
NO_BUBBLE_SPREAD = 10.0


def change_spread(photo, background, sigma) -> float:
    """``p99 / median`` of the per-pixel ``z^2 = ((photo - background) / (sqrt(2) sigma))^2``
    (mean over channels) over the whole photo: about 4.8 for noise alone, whatever the
    noise model's scale."""
    z2 = np.mean(((photo - background) / (math.sqrt(2.0) * np.maximum(sigma, 1e-12))) ** 2, axis=-1)
    med = float(np.median(z2))
    return float(np.percentile(z2, 99)) / max(med, 1e-12)


def bubble_contrast(photo, background, sigma, disc) -> float:
    """How strongly the disc differs from the background photo, in noise units.

    ``z = (photo - background) / (sqrt(2) sigma)`` (both photos carry noise ``sigma``);
    the contrast is ``sqrt(median(z^2) on the disc / median(z^2) off it)`` (off the disc
    the pair differs only by noise; the ratio cancels an error in the noise model's
    scale), or the former alone when the disc fills the photo.
    """
    cx, cy, r = disc
    h, w = photo.shape[:2]
    ii, jj = np.mgrid[0:h, 0:w]
    rho2 = ((jj + 0.5 - cx) ** 2 + (ii + 0.5 - cy) ** 2) / max(r, 1e-9) ** 2
    z2 = np.mean(((photo - background) / (math.sqrt(2.0) * np.maximum(sigma, 1e-12))) ** 2, axis=-1)
    inside, outside = rho2 < 0.8**2, rho2 > 1.2**2
    if inside.sum() < 4:
        return float("nan")
    ref = float(np.median(z2[outside])) if outside.sum() > 50 else 1.0
    return float(math.sqrt(float(np.median(z2[inside])) / max(ref, 1e-12)))
