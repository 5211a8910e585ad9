"""The observation: what the fit sees of the photo.

The photo's noise (:func:`noise_sigma`), its clipped pixels (:func:`saturation_mask`),
the frame the fit analyses (:func:`analysis_frame`: a large photo cropped to the bubble
and block-averaged, so memory is bounded by the fit's size), and the photo
block-averaged to the resolution a stage of the fit runs at, with its weights and the
film's geometry (:class:`Level`), and which disc the fit uses (:func:`resolve_disc`: the
one given, a calibration's when it belongs to this photo, or the one
:func:`bubblefit.capture.disc.find_disc` finds, :func:`find_bubble`). How compiled
programs see a level (padded to a few sizes) is :mod:`._programs`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage as ndi

from ._options import FitOptions
from ._pair import FRAME_SHARE, frame_mismatch
from ..capture.circle import detect_disc
from ..capture.disc import NO_BUBBLE_CONTRAST, NO_BUBBLE_SPREAD, Disc, bubble_contrast, change_spread, find_disc
from ..errors import InputError
from ..io.images import srgb_encode, srgb_slope
from ..model.geometry import DivergentCamera, OrthographicCamera, front_hits
from ..model.render import RenderConfig

__all__ = ["Level", "Frame", "noise_sigma", "saturation_mask", "make_level", "film_geometry",
           "block_mean", "analysis_frame", "Disc", "find_bubble", "resolve_disc", "DISC_AGREEMENT"]


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
        slope = srgb_slope(srgb_encode(i))
        var = var + (slope / (2**bits - 1)) ** 2 / 12.0
    return np.sqrt(var)


#: The pixels a clipped photosite spoils: its 3 x 3 block. Bilinear demosaicking fills a
#: Bayer mosaic's missing red and blue from the diagonal neighbours as well as the
#: row's and column's (the kernel ``[[1, 2, 1], [2, 4, 2], [1, 2, 1]] / 4``; Gunturk et
#: al., "Demosaicking: color filter array interpolation", IEEE Signal Processing
#: Magazine 22(1), 2005), so a clipped photosite leaves a wrong value in each of its
#: eight neighbours.
CLIP_NEIGHBOURS = np.ones((3, 3), bool)


def saturation_mask(photo: np.ndarray, level: float, given: np.ndarray | None) -> np.ndarray:
    """(H, W) clipped pixels: any channel at or above ``level`` (for files whose maximum
    is 1), or in ``given`` (a reader's pixels at the file's white level, or whose own RAW
    photosite reached it: :attr:`bubblefit.io.images.Image.saturated`), grown once by
    :data:`CLIP_NEIGHBOURS`: a demosaic spreads a clipped photosite into its eight
    neighbours, the diagonal ones included."""
    H, W = photo.shape[:2]
    sat = (np.max(photo, axis=-1) >= level) if np.nanmax(photo) <= 1.0 + 1e-6 else np.zeros((H, W), bool)
    if given is not None:
        if np.shape(given) != (H, W):
            raise InputError(f"the saturation mask is {np.shape(given)}, the photo is {W}x{H}")
        sat = sat | np.asarray(given, bool)
    return ndi.binary_dilation(sat, structure=CLIP_NEIGHBOURS) if sat.any() else sat


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
    #: (h, w, 3) the background photo's noise standard deviation, None without one
    bg_sigma: np.ndarray | None = None


def _block(a: np.ndarray, k: int, h: int, w: int, how="mean"):
    if k == 1:
        return a
    b = a[: h * k, : w * k].reshape(h, k, w, k, *a.shape[2:])
    return b.mean(axis=(1, 3)) if how == "mean" else b.any(axis=(1, 3))


def block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """``a`` (H, W, ...) averaged over blocks of ``k`` x ``k`` pixels (the remainder dropped)."""
    return _block(a, k, a.shape[0] // k, a.shape[1] // k)


@dataclass
class Frame:
    """The part of the photo a fit analyses: from pixel ``(x0, y0)`` in blocks of ``k``.

    ``photo``, ``background``, ``sigma`` and ``saturated`` are in that frame; ``disc`` is
    the bubble's disc in it (``to_photo`` maps a disc back to the photo's pixels).
    """

    x0: int
    y0: int
    k: int
    photo: np.ndarray
    background: np.ndarray | None
    sigma: np.ndarray
    saturated: np.ndarray
    disc: tuple | None
    #: the background photo's noise standard deviation (as ``sigma``), None without one
    bg_sigma: np.ndarray | None = None

    @property
    def whole(self) -> bool:
        return self.x0 == 0 and self.y0 == 0 and self.k == 1

    def to_photo(self, disc):
        """A disc ``(cx, cy, r)`` of this frame in the photo's pixels."""
        if disc is None:
            return None
        cx, cy, r = disc
        return (self.x0 + cx * self.k, self.y0 + cy * self.k, r * self.k)


def analysis_frame(photo, background, saturated, disc, opts: FitOptions) -> Frame:
    """The :class:`Frame` a fit analyses (``opts``: a ``FitOptions``).

    A photo whose larger side is at most ``opts.sizes.analysis`` (or without a disc, i.e.
    a perspective camera) is used whole. A larger one is cropped to 1.15 radii around
    the disc and block-averaged by ``k`` so that the crop's larger side is at most
    ``opts.sizes.analysis``: the noise variance of a block mean is the mean variance over
    ``k^2``, and a block with a clipped pixel is clipped.
    """
    H, W = photo.shape[:2]
    if disc is None or max(H, W) <= opts.sizes.analysis:
        sigma = noise_sigma(photo, opts.noise.read, opts.noise.shot, opts.noise.bits)
        bgs = None if background is None else noise_sigma(background, opts.noise.read, opts.noise.shot, opts.noise.bits)
        return Frame(0, 0, 1, photo, background, sigma, saturated, disc, bgs)
    cx, cy, r = disc
    half = 1.15 * r
    x0, x1 = max(0, int(math.floor(cx - half))), min(W, int(math.ceil(cx + half)))
    y0, y1 = max(0, int(math.floor(cy - half))), min(H, int(math.ceil(cy + half)))
    if x1 - x0 < 8 or y1 - y0 < 8:
        raise InputError(f"the bubble's disc {disc} lies outside the {W}x{H} photo")
    k = max(1, math.ceil(max(x1 - x0, y1 - y0) / opts.sizes.analysis))
    h, w = (y1 - y0) // k, (x1 - x0) // k
    y1, x1 = y0 + h * k, x0 + w * k
    # block-averaged band by band, so that no temporary is larger than a band of the crop
    small, sigma, bg = np.empty((h, w, 3)), np.empty((h, w, 3)), None if background is None else np.empty((h, w, 3))
    bgs = None if background is None else np.empty((h, w, 3))
    rows = max(1, 2**20 // max(1, 3 * k * k * w))  # output rows per band (~1M values in flight)
    for i in range(0, h, rows):
        a, b = y0 + i * k, y0 + min(h, i + rows) * k
        band = np.asarray(photo[a:b, x0:x1], np.float64)
        small[i:i + rows] = block_mean(band, k)
        var = noise_sigma(band, opts.noise.read, opts.noise.shot, opts.noise.bits) ** 2
        sigma[i:i + rows] = np.sqrt(block_mean(var, k) / (k * k))
        if bg is not None:
            bband = np.asarray(background[a:b, x0:x1], np.float64)
            bg[i:i + rows] = block_mean(bband, k)
            bvar = noise_sigma(bband, opts.noise.read, opts.noise.shot, opts.noise.bits) ** 2
            bgs[i:i + rows] = np.sqrt(block_mean(bvar, k) / (k * k))
    sat = _block(saturated[y0:y1, x0:x1], k, h, w, how="any")
    return Frame(x0, y0, k, small, bg, sigma, sat, ((cx - x0) / k, (cy - y0) / k, r / k), bgs)


def _camera_at(camera, k: int, h: int, w: int):
    if isinstance(camera, (OrthographicCamera, DivergentCamera)):
        cx, cy, r = camera.disc()
        return type(camera)(w, h, cx / k, cy / k, r / k)
    return replace(camera, width=w, height=h)


def film_geometry(cfg: RenderConfig, view: float = 0.0):
    """``(inside, cos, height)`` (h, w) of the front film under each pixel of ``cfg``'s camera
    (a divergent camera's through the view ``view``, :attr:`~bubblefit.model.render.Params.view`)."""
    h, w = cfg.shape
    inside, cos, local0 = front_hits(cfg.camera, tuple(cfg.center), float(cfg.radius), view)
    return np.asarray(inside).reshape(h, w), np.asarray(cos).reshape(h, w), np.asarray(local0)[:, 1].reshape(h, w)


def make_level(k, base_cfg, photo, sigma, bg, saturated, rim: float, bg_sigma=None, view: float = 0.0) -> Level:
    """The :class:`Level` ``k`` times smaller than ``photo`` (block means; variances of the
    mean; a block with a clipped pixel is dropped), fitting pixels with ``rho < rim``;
    ``bg_sigma`` is the background photo's noise (as ``sigma``)."""
    H, W = photo.shape[:2]
    h, w = H // k, W // k
    cfg = replace(base_cfg, camera=_camera_at(base_cfg.camera, k, h, w))
    inside, cos, height = film_geometry(cfg, view)
    cos_min = math.sqrt(max(0.0, 1.0 - rim**2))
    y = _block(photo, k, h, w)
    var = _block(sigma**2, k, h, w) / (k * k)
    sat = _block(saturated, k, h, w, how="any")
    mask = inside & (cos > cos_min) & ~sat & np.all(np.isfinite(y), axis=-1)
    wts = np.where(mask[..., None], 1.0 / np.sqrt(var), 0.0)
    bgk = None if bg is None else _block(bg, k, h, w).astype(np.float32)
    bgsk = None if bg is None or bg_sigma is None else np.sqrt(_block(bg_sigma**2, k, h, w) / (k * k)).astype(np.float32)
    return Level(k, cfg, np.nan_to_num(y).astype(np.float32), wts.astype(np.float32), bgk, mask, inside, cos, height,
                 bgsk)


# ---------------------------------------------------------------------------------------
# Which disc a fit uses
# ---------------------------------------------------------------------------------------

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
    is the photo's noise (default: :func:`noise_sigma` of an
    8-bit file with the fit's default noise).
    """
    sig = sigma if sigma is not None or background is None else noise_sigma(photo, 2e-3, 2e-4, 8)
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
        contrast = bubble_contrast(photo, background, sig, (cx, cy, r))
        if contrast < NO_BUBBLE_CONTRAST and change_spread(photo, background, sig) < NO_BUBBLE_SPREAD:
            return Disc(float(cx), float(cy), float(r), found=False, contrast=contrast,
                        reason=f"no bubble: the photo matches the background photo within its noise "
                               f"(contrast {contrast:.2f} noise units on the best disc)")
    return Disc(float(cx), float(cy), float(r), found=True, contrast=contrast, reason=note)


def _detect(photo, background, opts: FitOptions) -> Disc:
    """:func:`find_bubble` on a copy block-averaged to at most ``opts.sizes.analysis`` pixels."""
    k = max(1, math.ceil(max(photo.shape[:2]) / opts.sizes.analysis))
    small = block_mean(photo, k) if k > 1 else photo
    bsmall = None if background is None else (block_mean(background, k) if k > 1 else background)
    sigma = np.sqrt(np.maximum(noise_sigma(photo if k == 1 else small, opts.noise.read, opts.noise.shot,
                                           opts.noise.bits) ** 2 / (k * k), 1e-30))
    d = find_bubble(small, bsmall, sigma=sigma)
    if k == 1 or not d.found:
        return d
    return replace(d, cx=d.cx * k, cy=d.cy * k, r=d.r * k)


#: What a photo refused for want of a disc may give instead.
GIVE_DISC = "give the bubble's disc (--disc CX,CY,R) or a scene file with its camera to fit it anyway"


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
        k = max(1, math.ceil(max(photo.shape[:2]) / opts.sizes.analysis))
        p, b = (block_mean(photo, k), block_mean(background, k)) if k > 1 else (photo, background)
        sig = lambda a: noise_sigma(a, opts.noise.read, opts.noise.shot, opts.noise.bits) / k  # noqa: E731
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
    says why; a disc that only the simpler detector guessed (a ``reason`` noted) never
    replaces it. With neither, the disc is found; a photo whose rim
    :func:`~bubblefit.capture.disc.find_disc` does not find (no bubble, or only the simpler
    detector's guess) raises :class:`InputError` (:meth:`~bubblefit.capture.disc.Disc.refusal`
    and :data:`GIVE_DISC`).
    """
    if given is not None:
        return tuple(float(v) for v in given), []
    H, W = photo.shape[:2]
    cal = opts.calibration_disc
    other_frame = cal is not None and opts.calibration_size is not None and tuple(opts.calibration_size) != (W, H)
    # the noise that weighs the calibration's disc against the one found (same frame, a pair)
    sig = (noise_sigma(photo, opts.noise.read, opts.noise.shot, opts.noise.bits)
           if cal is not None and background is not None and opts.calibration_size is not None and not other_frame
           else None)
    found = _detect(photo, background, opts)
    if other_frame:
        if not found.found:
            raise InputError(found.reason)
        if found.reason:  # only the simpler detector's guess
            raise InputError(f"{found.refusal()}; {GIVE_DISC}")
        cw, ch = opts.calibration_size
        return (found.cx, found.cy, found.r), [
            f"the calibration's disc was found in a {cw}x{ch} frame and the photo is {W}x{H}: "
            f"used the disc found in the photo instead"]
    if cal is None:
        if not found.found or found.reason:
            raise InputError(f"{found.refusal()}; {GIVE_DISC}")
        return (found.cx, found.cy, found.r), []
    if not found.found:
        if found.contrast == found.contrast:  # a background photo says: no bubble
            raise InputError(found.reason)
        return tuple(cal), ["the calibration's disc could not be checked against the photo (no disc found in it)"]
    if found.reason:  # only the simpler detector's guess: it cannot overrule the calibration
        return tuple(cal), ["the calibration's disc could not be checked against the photo (no rim of a bubble is "
                            "clear in it)"]
    if _agrees(cal, (found.cx, found.cy, found.r)):
        return tuple(cal), []
    if sig is not None:
        # same frame size, another disc found: the pair says which outlines the bubble
        c_cal = bubble_contrast(photo, background, sig, cal)
        c_found = bubble_contrast(photo, background, sig, (found.cx, found.cy, found.r))
        if c_cal >= 0.8 * c_found:
            return tuple(cal), []
    return (found.cx, found.cy, found.r), [
        "the calibration's disc ({:.1f}, {:.1f}, r {:.1f}) disagrees with the bubble found in the photo "
        "({:.1f}, {:.1f}, r {:.1f}): used the one found".format(*cal, found.cx, found.cy, found.r)]
