"""Which disc a fit uses: the one given, a calibration's (only when it belongs to this
photo), or the one found (:func:`resolve_disc`).

The detectors live in :mod:`bubblefit.capture.disc` (the robust :func:`~bubblefit.capture.disc.find_disc`,
the contrast against a background photo) and :mod:`bubblefit.capture.circle` (the simpler
:func:`~bubblefit.capture.circle.detect_disc`); :func:`find_bubble` chooses between their discs.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ._observation import block_mean, noise_sigma
from ._options import FitOptions
from ..capture.circle import detect_disc
from ..capture.disc import NO_BUBBLE_CONTRAST, NO_BUBBLE_SPREAD, Disc, bubble_contrast, change_spread, find_disc
from ..errors import InputError

__all__ = ["Disc", "find_bubble", "bubble_contrast", "resolve_disc", "detect_disc", "NO_BUBBLE_CONTRAST",
           "DISC_AGREEMENT"]

#: A calibration's disc agrees with the photo's when centre and radius are within this
#: fraction of the radius of the disc found in the photo.
DISC_AGREEMENT = 0.1


def find_bubble(photo: np.ndarray, background: np.ndarray | None = None, *,
                sigma: np.ndarray | None = None) -> Disc:
    """The bubble's :class:`~bubblefit.capture.disc.Disc` in ``photo`` (linear (H, W, 3)).

    :func:`~bubblefit.capture.disc.find_disc`'s disc; where it refuses a rim it cannot see
    clearly (small photos, dim rims), :func:`~bubblefit.capture.circle.detect_disc`'s, with a
    note saying so. With a background photo, a disc that does not differ from it
    (:func:`~bubblefit.capture.disc.bubble_contrast` below
    :data:`~bubblefit.capture.disc.NO_BUBBLE_CONTRAST`) is not a bubble. ``sigma`` (H, W, 3)
    is the photo's noise (default: :func:`~bubblefit.inverse._observation.noise_sigma` of an
    8-bit file with the fit's default noise).
    """
    d = find_disc(photo, background, sigma=sigma)
    note = ""
    if d.found:
        cx, cy, r = float(d.cx), float(d.cy), float(d.r)
    else:
        # With a background photo the contrast check below still refuses a photo without
        # a bubble.
        try:
            cx, cy, r = detect_disc(photo, background)
        except InputError:
            return Disc(float("nan"), float("nan"), float("nan"), found=False, contrast=float(d.contrast),
                        reason=d.reason or "no bubble found in the photo")
        note = (f"the bubble's rim is not clear ({d.reason}); the disc comes from the simpler detector: "
                "check it, or give --disc")
    contrast = float("nan")
    if background is not None:
        sig = sigma if sigma is not None else noise_sigma(photo, 2e-3, 2e-4, 8)
        contrast = bubble_contrast(photo, background, sig, (cx, cy, r))
        if contrast < NO_BUBBLE_CONTRAST and change_spread(photo, background, sig) < NO_BUBBLE_SPREAD:
            return Disc(float(cx), float(cy), float(r), found=False, contrast=contrast,
                        reason=f"no bubble: the photo matches the background photo within its noise "
                               f"(contrast {contrast:.2f} noise units on the best disc)")
    return Disc(float(cx), float(cy), float(r), found=True, contrast=contrast, reason=note)


def _detect(photo, background, opts: FitOptions) -> Disc:
    """:func:`find_bubble` on a copy block-averaged to at most ``opts.analysis_size`` pixels."""
    k = max(1, math.ceil(max(photo.shape[:2]) / opts.analysis_size))
    small = block_mean(photo, k) if k > 1 else photo
    bsmall = None if background is None else (block_mean(background, k) if k > 1 else background)
    sigma = np.sqrt(np.maximum(noise_sigma(photo if k == 1 else small, opts.noise_read, opts.noise_shot,
                                           opts.bits) ** 2 / (k * k), 1e-30))
    d = find_bubble(small, bsmall, sigma=sigma)
    if k == 1 or not d.found:
        return d
    return replace(d, cx=d.cx * k, cy=d.cy * k, r=d.r * k)


def _no_bubble(found: Disc) -> str:
    """The one line that refuses a photo in which the disc detector
    (:func:`~bubblefit.capture.disc.find_disc`) found no bubble: fitting a disc it did not
    find (the simpler detector's guess) measured films that were not there."""
    why = found.reason if not found.found else "no rim of a bubble is clear in the photo"
    return f"{why}; give the bubble's disc (--disc CX,CY,R) or a scene file with its camera to fit it anyway"


def _agrees(a, b) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) <= DISC_AGREEMENT * b[2] and abs(a[2] - b[2]) <= DISC_AGREEMENT * b[2]


def resolve_disc(photo, background, opts: FitOptions, given=None) -> tuple[tuple, list]:
    """:func:`_resolve_disc`; where it finds no bubble in a pair that differs over most of
    the frame (:func:`~bubblefit.inverse._pair.frame_mismatch` above
    :data:`~bubblefit.inverse._pair.FRAME_SHARE`), the line says that the background photo
    does not show the photo's view."""
    try:
        return _resolve_disc(photo, background, opts, given)
    except InputError as exc:
        if background is None:
            raise
        from ._pair import FRAME_SHARE, frame_mismatch

        k = max(1, math.ceil(max(photo.shape[:2]) / opts.analysis_size))
        p, b = (block_mean(photo, k), block_mean(background, k)) if k > 1 else (photo, background)
        sig = lambda a: noise_sigma(a, opts.noise_read, opts.noise_shot, opts.bits) / k
        share = frame_mismatch(np.asarray(p, np.float64), np.asarray(b, np.float64), sig(p), sig(b))
        if share <= FRAME_SHARE:
            raise
        raise InputError(f"no bubble found, and the background photo differs from the photo beyond noise and "
                         f"exposure over {share:.0%} of the frame: it does not show the photo's view (if the bubble "
                         "fills the frame, give --disc CX,CY,R)") from exc


def _resolve_disc(photo, background, opts: FitOptions, given=None) -> tuple[tuple, list]:
    """``(disc, warnings)``: the disc a fit uses (``opts``: a ``FitOptions``).

    ``given`` (the options' or the scene's disc) is used as it is. A calibration's disc
    (``opts.calibration_disc``) is used only when the photo has the calibration frame's
    size (``opts.calibration_size``, when known) and agrees with the photo: the disc
    found in it is the same (:data:`DISC_AGREEMENT`) or, with a background photo, the
    calibration's disc outlines the change between the pair at least as well
    (:func:`bubble_contrast`, within 20%); otherwise the disc found is used and a warning
    says why. With neither, the disc is found; a photo whose rim
    :func:`~bubblefit.capture.disc.find_disc` does not find (no bubble, or only the simpler
    detector's guess) raises :class:`InputError` (:func:`_no_bubble`).
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
        if not found.found or found.reason:
            raise InputError(_no_bubble(found))
        return (found.cx, found.cy, found.r), []
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
