"""Finding the bubble's disc for a fit, and checking a calibration's disc against the photo.

:func:`find_bubble` is the fit's one entry point to disc detection; it has the interface
of ``bubblefit.capture.disc.find_disc`` (a colleague's robust detector), so switching to
it is one line. :func:`resolve_disc` decides which disc a fit uses: the one given, a
calibration's (only when it belongs to this photo), or the one found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._observation import block_mean, detect_disc, noise_sigma
from ..errors import InputError

try:  # the robust detector of bubblefit.capture.disc, where it is installed
    from ..capture.disc import find_disc as _find_disc
except ImportError:  # until then: today's detector (detect_disc)
    _find_disc = None

__all__ = ["Disc", "find_bubble", "bubble_contrast", "resolve_disc", "NO_BUBBLE_CONTRAST", "DISC_AGREEMENT"]

#: A photo whose pixels on the disc differ from the background photo's by less than this
#: many times the pair's noise (robust RMS, relative to the same outside the disc) has no
#: bubble in it. Pure noise gives 1; any bubble transmits t^4 of the background and adds
#: its reflection, many noise units on every pixel.
NO_BUBBLE_CONTRAST = 2.0
#: A calibration's disc agrees with the photo's when centre and radius are within this
#: fraction of the radius of the disc found in the photo.
DISC_AGREEMENT = 0.1


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


def find_bubble(photo: np.ndarray, background: np.ndarray | None = None, *,
                sigma: np.ndarray | None = None) -> Disc:
    """The bubble's :class:`Disc` in ``photo`` (linear (H, W, 3)).

    ``bubblefit.capture.disc.find_disc`` where it is installed, else
    :func:`bubblefit.inverse._observation.detect_disc`; with a background photo, a disc
    that does not differ from it (:func:`bubble_contrast` below
    :data:`NO_BUBBLE_CONTRAST`) is not a bubble. ``sigma`` (H, W, 3) is the photo's
    noise (default: :func:`noise_sigma` of an 8-bit file with the fit's default noise).
    """
    if _find_disc is not None:
        d = _find_disc(photo, background, sigma=sigma)
        note = ""
        if d.found:
            cx, cy, r = float(d.cx), float(d.cy), float(d.r)
        else:
            # The robust detector refuses rims it cannot see clearly (small photos, dim
            # rims); the fit then takes the simpler detector's disc and says so. With a
            # background photo the contrast check below still refuses a photo without
            # a bubble.
            try:
                cx, cy, r = detect_disc(photo, background)
            except InputError:
                return Disc(float("nan"), float("nan"), float("nan"), found=False, contrast=float(d.contrast),
                            reason=d.reason or "no bubble found in the photo")
            note = (f"the bubble's rim is not clear ({d.reason}); the disc comes from the simpler detector: "
                    "check it, or give --disc")
    else:
        note = ""
        try:
            cx, cy, r = detect_disc(photo, background)
        except InputError as exc:
            return Disc(float("nan"), float("nan"), float("nan"), found=False, reason=str(exc))
    contrast = float("nan")
    if background is not None:
        sig = sigma if sigma is not None else noise_sigma(photo, 2e-3, 2e-4, 8)
        contrast = bubble_contrast(photo, background, sig, (cx, cy, r))
        if contrast < NO_BUBBLE_CONTRAST and change_spread(photo, background, sig) < NO_BUBBLE_SPREAD:
            return Disc(float(cx), float(cy), float(r), found=False, contrast=contrast,
                        reason=f"no bubble: the photo matches the background photo within its noise "
                               f"(contrast {contrast:.2f} noise units on the best disc)")
    return Disc(float(cx), float(cy), float(r), contrast=contrast, reason=note)


def _detect(photo, background, opts) -> Disc:
    """:func:`find_bubble` on a copy block-averaged to at most ``opts.analysis_size`` pixels."""
    k = max(1, math.ceil(max(photo.shape[:2]) / opts.analysis_size))
    small = block_mean(photo, k) if k > 1 else photo
    bsmall = None if background is None else (block_mean(background, k) if k > 1 else background)
    sigma = np.sqrt(np.maximum(noise_sigma(photo if k == 1 else small, opts.noise_read, opts.noise_shot,
                                           opts.bits) ** 2 / (k * k), 1e-30))
    d = find_bubble(small, bsmall, sigma=sigma)
    if k == 1 or not d.found:
        return d
    return Disc(d.cx * k, d.cy * k, d.r * k, True, d.contrast, d.reason)


def _agrees(a, b) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) <= DISC_AGREEMENT * b[2] and abs(a[2] - b[2]) <= DISC_AGREEMENT * b[2]


def resolve_disc(photo, background, opts, given=None) -> tuple[tuple, list]:
    """``(disc, warnings)``: the disc a fit uses (``opts``: a ``FitOptions``).

    ``given`` (the options' or the scene's disc) is used as it is. A calibration's disc
    (``opts.calibration_disc``) is used only when the photo has the calibration frame's
    size (``opts.calibration_size``, when known) and agrees with the photo: the disc
    found in it is the same (:data:`DISC_AGREEMENT`) or, with a background photo, the
    calibration's disc outlines the change between the pair at least as well
    (:func:`bubble_contrast`, within 20%); otherwise the disc found is used and a warning
    says why. With neither, the disc is found; no bubble raises :class:`InputError`.
    """
    if given is not None:
        return tuple(float(v) for v in given), []
    H, W = photo.shape[:2]
    cal = opts.calibration_disc
    if cal is not None and opts.calibration_size is not None and tuple(opts.calibration_size) != (W, H):
        found = _detect(photo, background, opts)
        if not found.found:
            raise InputError(found.reason)
        cw, ch = opts.calibration_size
        return (found.cx, found.cy, found.r), [
            f"the calibration's disc was found in a {cw}x{ch} frame and the photo is {W}x{H}: "
            f"used the disc found in the photo instead"]
    found = _detect(photo, background, opts)
    if cal is None:
        if not found.found:
            raise InputError(found.reason)
        return (found.cx, found.cy, found.r), [found.reason] if found.reason else []
    if not found.found:
        if found.contrast == found.contrast:  # a background photo says: no bubble
            raise InputError(found.reason)
        return tuple(cal), ["the calibration's disc could not be checked against the photo (no disc found in it)"]
    if _agrees(cal, (found.cx, found.cy, found.r)):
        return tuple(cal), []
    if background is not None and opts.calibration_size is not None:
        # same frame size, another disc found: the pair says which outlines the bubble
        sig = noise_sigma(photo, opts.noise_read, opts.noise_shot, opts.bits)
        c_cal = bubble_contrast(photo, background, sig, cal)
        c_found = bubble_contrast(photo, background, sig, (found.cx, found.cy, found.r))
        if c_cal >= 0.8 * c_found:
            return tuple(cal), []
    return (found.cx, found.cy, found.r), [
        "the calibration's disc ({:.1f}, {:.1f}, r {:.1f}) disagrees with the bubble found in the photo "
        "({:.1f}, {:.1f}, r {:.1f}): used the one found".format(*cal, found.cx, found.cy, found.r)]
