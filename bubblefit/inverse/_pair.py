"""Does the background photo belong to the photo? Checks made before a fit starts.

A fit with a background photo models each pixel on the film as
``photo = T(theta) background + reflected light`` (eq. 11; the physical model's
``T_0 T_1 L_b`` plus its reflections), and every pixel off the bubble as the background
itself. Two consequences are tested here, on the fit's level, before any solve:

- **Conservation** (:func:`transmission_floor`, :func:`darkening`): a film transmits at
  least ``1 - R_max`` of the light of each polarisation, ``R_max`` the largest Airy
  reflectance of one film over every thickness (:func:`~bubblefit.optics.film.airy_at_phase`),
  and the reflections only add light. So over the bubble the photo's luminance is at least
  ``T_min(theta)`` times the background's, up to noise. Luminance, not each channel: the
  sRGB of a saturated interference colour has negative components that the file clips to
  0, while CIE Y is a positive weighting of the spectrum. A photo darker than that over a
  share of the bubble cannot hold a film over that background: the files are swapped
  (the other order then satisfies the bound), or they do not show one view.
- **Same view** (:func:`outside_mismatch`): off the bubble the two photos agree within
  their noise, once a per-channel exposure ratio is taken out.

Which data the thresholds were checked on is said at each constant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage as ndi

from ..errors import InputError

__all__ = ["PairCheck", "check_pair", "judge_pair", "frame_mismatch", "transmission_floor",
           "darkening", "outside_mismatch", "N_FILM_MAX", "LUMINANCE", "DARK_Z", "DARK_SHARE", "SAME_VIEW_Z",
           "SAME_VIEW_SHARE", "FRAME_SHARE"]

#: Linear sRGB (Rec. 709) weights of CIE Y (IEC 61966-2-1).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

#: Largest refractive index of a soap film the floor allows: water 1.33, glycerol 1.47.
N_FILM_MAX = 1.5

#: Largest ``sin(theta)`` (orthographic: radius over the disc's) the conservation test
#: uses: away from the rim, where a disc found a pixel or two off would mix in the
#: background, and where ``T_min`` is still 0.67.
MAX_SIN = 0.8

#: A pixel violates the floor when its luminance is this many standard deviations below
#: it: a Gaussian deviation this large has a chance of 2.9e-7.
DARK_Z = 5.0

#: Share of the tested pixels that must violate the floor before the pair is refused (and
#: at least :data:`DARK_MIN_PIXELS`): with Gaussian noise a right pair has none (2.9e-7 of
#: them), so one percent leaves room for specks, dust and a misjudged noise model. Checked
#: (not chosen) on the 23 photo/background pairs of experiments/validation, development and
#: test parts, and the demo's: no right pair had a pixel past the bound (the nearest at
#: -2.3 standard deviations); the swapped pairs had 0-99 % (docs/safety.md has the table).
DARK_SHARE = 0.01
DARK_MIN_PIXELS = 10

#: Off the bubble, a pixel differs when a channel is this many standard deviations (noise
#: plus :data:`SAME_VIEW_TOLERANCE` of the value) from the exposure-scaled background.
SAME_VIEW_Z = 5.0
#: Relative difference allowed off the bubble besides the noise: JPEG compression and a
#: drift of the white balance between the shots.
SAME_VIEW_TOLERANCE = 0.02
#: Share of the pixels off the bubble that must differ for the background to be of another
#: scene: most of the view. On the same 24 right pairs no pixel off the bubble differed;
#: eleven photos given another case's background differed over 66-100 % (docs/safety.md).
SAME_VIEW_SHARE = 0.5
#: Largest exposure ratio between the shots the same-view test takes out (one stop): the
#: fit takes the background photo's radiance as it is, so a pair further apart cannot be
#: explained either.
EXPOSURE_RANGE = 2.0
#: Share of the whole frame that must differ, when no bubble was found, for the message to
#: name another view: a bubble changes only the pixels it covers.
FRAME_SHARE = 0.9
#: Fewest usable pixels off the bubble for the same-view test (a bubble that fills the
#: frame leaves none, and the test is skipped).
SAME_VIEW_MIN_PIXELS = 100


@lru_cache(maxsize=4)
def _floor_table(n_max: float) -> tuple[np.ndarray, np.ndarray]:
    from ..optics.film import airy_at_phase

    cos = np.linspace(0.0, 1.0, 201)
    delta = np.linspace(0.0, 2.0 * math.pi, 721)[:, None]
    r_max = np.asarray(airy_at_phase(delta, n_max, cos[None, :])).max(axis=0)  # (cos, 2)
    return cos, np.mean((1.0 - r_max) ** 2, axis=-1)


def transmission_floor(cos: np.ndarray, n_max: float = N_FILM_MAX) -> np.ndarray:
    """The least share of unpolarised light two films (a bubble's front and rear, met at
    the same angle) transmit at incidence cosine ``cos``, over every thickness and every
    index up to ``n_max``: ``T_min = mean over s, p of (1 - R_max)^2``, ``R_max`` the
    largest Airy reflectance of one film (no absorption, ``T = 1 - R``).

    References
    ----------
    Born & Wolf, *Principles of Optics*, sec. 7.6.1 (Airy's formulae for a film);
    paper eq. (11) (the background behind the bubble).
    """
    grid, floor = _floor_table(float(n_max))
    return np.interp(np.clip(cos, 0.0, 1.0), grid, floor)


def _luminance(rgb: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return rgb @ LUMINANCE, (sigma**2) @ LUMINANCE**2


def darkening(photo, background, sigma, bg_sigma, cos, tested, gain: float = 1.0) -> tuple[float, int, float]:
    """``(share, count, least)``: the share and count of the ``tested`` pixels where the photo's luminance lies more
    than :data:`DARK_Z` standard deviations below ``gain * T_min(theta)`` times the
    background's (:func:`transmission_floor`): light a film cannot have absorbed.
    ``gain`` is the photo's exposure over the background's (1 when unknown); ``least`` is
    the lowest deviation from the floor, in standard deviations (the margin of a pair
    that passes)."""
    n = int(np.count_nonzero(tested))
    if n == 0:
        return 0.0, 0, float("nan")
    yp, vp = _luminance(photo[tested], sigma[tested])
    yb, vb = _luminance(background[tested], bg_sigma[tested])
    floor = gain * transmission_floor(cos[tested])
    z = (yp - floor * yb) / np.sqrt(np.maximum(vp + floor**2 * vb, 1e-30))
    count = int(np.count_nonzero(z < -DARK_Z))
    return count / n, count, float(z.min())


def outside_mismatch(photo, background, sigma, bg_sigma, off) -> tuple[float, int, np.ndarray]:
    """``(share, pixels, ratio)``: the share of the ``off`` pixels (off the bubble, usable)
    where a channel of the photo differs from ``ratio`` times the background by more than
    :data:`SAME_VIEW_Z` standard deviations (noise and :data:`SAME_VIEW_TOLERANCE`), with
    ``ratio`` the per-channel median of photo over background there (an exposure or white
    balance change between the shots)."""
    n = int(np.count_nonzero(off))
    if n == 0:
        return 0.0, 0, np.ones(3)
    p, b = photo[off], background[off]
    lit = np.all(b > 4.0 * bg_sigma[off], axis=-1)
    ratio = np.median(p[lit] / b[lit], axis=0) if lit.sum() >= 10 else np.ones(3)
    ratio = np.clip(ratio, 1.0 / EXPOSURE_RANGE, EXPOSURE_RANGE)
    var = sigma[off] ** 2 + ratio**2 * bg_sigma[off] ** 2 + (SAME_VIEW_TOLERANCE * np.abs(p)) ** 2
    z = np.abs(p - ratio * b) / np.sqrt(np.maximum(var, 1e-30))
    return float(np.mean(np.any(z > SAME_VIEW_Z, axis=-1))), n, ratio


@dataclass(frozen=True)
class PairCheck:
    """What the background photo says about the pairing (:func:`check_pair`).

    Attributes
    ----------
    dark_share, dark_share_swapped : float
        Share of the bubble's tested pixels darker than a film can make them
        (:func:`darkening`), as given and with the two photos exchanged.
    tested : int
        Pixels on the bubble tested.
    outside_share : float
        Share of the pixels off the bubble that differ (:func:`outside_mismatch`); NaN
        when fewer than :data:`SAME_VIEW_MIN_PIXELS` were usable.
    outside_pixels : int
    gain : float
        The photo's luminance exposure over the background's, off the bubble (1 when
        not measured).
    least_z : float
        The lowest deviation of a tested pixel from the floor, in standard deviations.
    """

    dark_share: float
    dark_share_swapped: float
    tested: int
    outside_share: float
    outside_pixels: int
    gain: float
    least_z: float = float("nan")

    @property
    def swap_possible(self) -> bool:
        """The photos exchanged would pass the conservation test too: it cannot tell the
        order, so a failed fit may still come from a swap."""
        return self.dark_share_swapped < DARK_SHARE

    def refusal(self) -> str | None:
        """The one line that refuses the pair, or None."""
        if self.outside_pixels >= SAME_VIEW_MIN_PIXELS and self.outside_share > SAME_VIEW_SHARE:
            return (f"the background photo does not show the photo's view: off the bubble {self.outside_share:.0%} of "
                    f"{self.outside_pixels} pixels differ beyond noise and exposure (it must be the same view, "
                    "from the same camera position, without the bubble)")
        if self.dark_share >= DARK_SHARE and round(self.dark_share * self.tested) >= DARK_MIN_PIXELS:
            head = (f"the photo is darker than the background photo on {self.dark_share:.0%} of the bubble, by more "
                    "than a film can absorb")
            if self.swap_possible:
                return head + ": the photo and the background look swapped (the photo holds the bubble, " \
                              "--background is the same view without it)"
            return head + ": they are not a photo of a bubble and the same view without it"
        return None


def frame_mismatch(photo, background, sigma, bg_sigma) -> float:
    """:func:`outside_mismatch`'s share over the whole frame (finite pixels): the share of a
    pair that differs beyond noise and exposure, when no bubble tells where to look."""
    usable = np.all(np.isfinite(photo) & np.isfinite(background), axis=-1)
    return outside_mismatch(photo, background, sigma, bg_sigma, usable)[0]


def _block_var(a: np.ndarray, k: int, h: int, w: int) -> np.ndarray:
    if k == 1:
        return a[:h, :w]
    return a[: h * k, : w * k].reshape(h, k, w, k, *a.shape[2:]).mean(axis=(1, 3)) / (k * k)


def judge_pair(photo, background, sigma, bg_sigma, usable, inside, cos) -> PairCheck:
    """The :class:`PairCheck` of a photo and its background photo, (h, w, 3) linear with
    their noise standard deviations ``sigma`` and ``bg_sigma``: ``usable`` (h, w) pixels
    unclipped and finite in both, ``inside`` (h, w) the pixels on the bubble and ``cos``
    (h, w) the incidence cosine on its front film there. The conservation test uses the
    bubble's pixels with ``sin(theta) <= MAX_SIN``; the same-view test the usable pixels
    farther than 15 % of the radius (at least 2 pixels) from the bubble."""
    photo, background = np.asarray(photo, np.float64), np.asarray(background, np.float64)
    inside = np.asarray(inside, bool)
    radius = math.sqrt(max(inside.sum(), 1) / math.pi)
    off = ~ndi.binary_dilation(inside, iterations=max(2, int(round(0.15 * radius)))) & usable
    share, n_off, _ = outside_mismatch(photo, background, sigma, bg_sigma, off)
    gain = 1.0
    if n_off >= SAME_VIEW_MIN_PIXELS:
        yp, yb = photo[off] @ LUMINANCE, background[off] @ LUMINANCE
        lit = yb > 4.0 * np.sqrt((bg_sigma[off] ** 2) @ LUMINANCE**2)
        if lit.sum() >= 10:
            gain = float(np.clip(np.median(yp[lit] / yb[lit]), 1.0 / EXPOSURE_RANGE, EXPOSURE_RANGE))
    cos = np.asarray(cos, np.float64)
    tested = inside & usable & (cos >= math.sqrt(1.0 - MAX_SIN**2))
    dark, _, least = darkening(photo, background, sigma, bg_sigma, cos, tested, gain)
    dark_swapped, _, _ = darkening(background, photo, bg_sigma, sigma, cos, tested, 1.0 / gain)
    return PairCheck(dark, dark_swapped, int(tested.sum()), share if n_off >= SAME_VIEW_MIN_PIXELS else float("nan"),
                     n_off, gain, least)


def check_pair(frame, lev) -> PairCheck | None:
    """:func:`judge_pair` on a fit's analysed ``frame``
    (:class:`~bubblefit.inverse._observation.Frame`) at its fit level ``lev``
    (:class:`~bubblefit.inverse._observation.Level`: the photo, the background, the film's
    geometry), None without a background photo; raises :class:`InputError` with the
    check's :meth:`~PairCheck.refusal` when the pair is refused."""
    if lev.bg is None or frame.background is None:
        return None
    k = lev.k
    h, w = lev.y.shape[:2]
    sigma = np.sqrt(_block_var(frame.sigma**2, k, h, w))
    bgs = frame.bg_sigma if frame.bg_sigma is not None else frame.sigma
    bg_sigma = np.sqrt(_block_var(bgs**2, k, h, w))
    y, bg = lev.y.astype(np.float64), lev.bg.astype(np.float64)
    sat = frame.saturated[: h * k, : w * k].reshape(h, k, w, k).any(axis=(1, 3)) if k > 1 else frame.saturated[:h, :w]
    usable = ~sat & np.all(np.isfinite(y) & np.isfinite(bg), axis=-1)
    check = judge_pair(y, bg, sigma, bg_sigma, usable, lev.inside, lev.cos)
    why = check.refusal()
    if why is not None:
        raise InputError(why)
    return check
