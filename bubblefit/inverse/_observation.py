"""The observation: what the fit sees of the photo.

The photo's noise (:func:`noise_sigma`), its clipped pixels (:func:`saturation_mask`),
the frame the fit analyses (:func:`analysis_frame`: a large photo cropped to the bubble
and block-averaged, so memory is bounded by the fit's size), and the photo
block-averaged to the resolution a stage of the fit runs at, with its weights and the
film's geometry (:class:`Level`). The bubble's disc is chosen in :mod:`._disc`.

Compiled programs see a level padded (:func:`padded`): its rows and columns rounded up to
a few sizes, its camera replaced by the padded size's canonical one and the disc passed
as data, so that one program serves every photo whose level pads to that size, wherever
the bubble lies in it (a user's next photo does not compile again).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import jax.numpy as jnp
import numpy as np
from scipy import ndimage as ndi

from ._options import FitOptions
from ..errors import InputError
from ..io.images import srgb_encode, srgb_slope
from ..model.geometry import OrthographicCamera, canonical_frame, front_hits
from ..model.render import RenderConfig

__all__ = ["Level", "Frame", "noise_sigma", "saturation_mask", "make_level", "film_geometry",
           "block_mean", "analysis_frame", "Padded", "padded", "unpadded",
           "padded_size", "Pixels", "fitted_pixels"]


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


def saturation_mask(photo: np.ndarray, level: float, given: np.ndarray | None) -> np.ndarray:
    """(H, W) clipped pixels: any channel at or above ``level`` (for files whose maximum
    is 1), or in ``given``, dilated by one pixel (a clipped pixel's neighbours bleed)."""
    H, W = photo.shape[:2]
    sat = (np.max(photo, axis=-1) >= level) if np.nanmax(photo) <= 1.0 + 1e-6 else np.zeros((H, W), bool)
    if given is not None:
        if np.shape(given) != (H, W):
            raise InputError(f"the saturation mask is {np.shape(given)}, the photo is {W}x{H}")
        sat = sat | np.asarray(given, bool)
    return ndi.binary_dilation(sat) if sat.any() else sat


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

    A photo whose larger side is at most ``opts.analysis_size`` (or without a disc, i.e.
    a perspective camera) is used whole. A larger one is cropped to 1.15 radii around
    the disc and block-averaged by ``k`` so that the crop's larger side is at most
    ``analysis_size``: the noise variance of a block mean is the mean variance over
    ``k^2``, and a block with a clipped pixel is clipped.
    """
    H, W = photo.shape[:2]
    if disc is None or max(H, W) <= opts.analysis_size:
        sigma = noise_sigma(photo, opts.noise_read, opts.noise_shot, opts.bits)
        bgs = None if background is None else noise_sigma(background, opts.noise_read, opts.noise_shot, opts.bits)
        return Frame(0, 0, 1, photo, background, sigma, saturated, disc, bgs)
    cx, cy, r = disc
    half = 1.15 * r
    x0, x1 = max(0, int(math.floor(cx - half))), min(W, int(math.ceil(cx + half)))
    y0, y1 = max(0, int(math.floor(cy - half))), min(H, int(math.ceil(cy + half)))
    if x1 - x0 < 8 or y1 - y0 < 8:
        raise InputError(f"the bubble's disc {disc} lies outside the {W}x{H} photo")
    k = max(1, math.ceil(max(x1 - x0, y1 - y0) / opts.analysis_size))
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
        var = noise_sigma(band, opts.noise_read, opts.noise_shot, opts.bits) ** 2
        sigma[i:i + rows] = np.sqrt(block_mean(var, k) / (k * k))
        if bg is not None:
            bband = np.asarray(background[a:b, x0:x1], np.float64)
            bg[i:i + rows] = block_mean(bband, k)
            bvar = noise_sigma(bband, opts.noise_read, opts.noise_shot, opts.bits) ** 2
            bgs[i:i + rows] = np.sqrt(block_mean(bvar, k) / (k * k))
    sat = _block(saturated[y0:y1, x0:x1], k, h, w, how="any")
    return Frame(x0, y0, k, small, bg, sigma, sat, ((cx - x0) / k, (cy - y0) / k, r / k), bgs)


def _camera_at(camera, k: int, h: int, w: int):
    if isinstance(camera, OrthographicCamera):
        cx, cy, r = camera.disc()
        return OrthographicCamera(w, h, cx / k, cy / k, r / k)
    return replace(camera, width=w, height=h)


def film_geometry(cfg: RenderConfig):
    """``(inside, cos, height)`` (h, w) of the front film under each pixel of ``cfg``'s camera."""
    h, w = cfg.shape
    inside, cos, local0 = front_hits(cfg.camera, tuple(cfg.center), float(cfg.radius))
    return np.asarray(inside).reshape(h, w), np.asarray(cos).reshape(h, w), np.asarray(local0)[:, 1].reshape(h, w)


def make_level(k, base_cfg, photo, sigma, bg, saturated, rim: float, bg_sigma=None) -> Level:
    """The :class:`Level` ``k`` times smaller than ``photo`` (block means; variances of the
    mean; a block with a clipped pixel is dropped), fitting pixels with ``rho < rim``;
    ``bg_sigma`` is the background photo's noise (as ``sigma``)."""
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
    bgsk = None if bg is None or bg_sigma is None else np.sqrt(_block(bg_sigma**2, k, h, w) / (k * k)).astype(np.float32)
    return Level(k, cfg, np.nan_to_num(y).astype(np.float32), wts.astype(np.float32), bgk, mask, inside, cos, height,
                 bgsk)


# ---------------------------------------------------------------------------------------
# A level as compiled programs see it
# ---------------------------------------------------------------------------------------

#: The finest step of the padded sizes (:func:`padded_size`).
BUCKET = 16


def padded_size(n: int) -> int:
    """``n`` rounded up to a multiple of ``max(BUCKET, 2^(bits(n) - 4))``: steps of 16 up to
    255 pixels, then an eighth to a sixteenth of the size (at most 12.5 % padding), so a
    few programs serve every photo size."""
    step = max(BUCKET, 1 << max(0, int(n).bit_length() - 4))
    return -(-int(n) // step) * step


@dataclass
class Padded:
    """A level padded at its bottom and right (:func:`padded`): the canonical
    configuration, the photo, weights and background (jnp, float32; weight 0 in the
    padding), and ``base``, the shift that moves the canonical disc onto the level's."""

    cfg: RenderConfig
    y: jnp.ndarray
    w: jnp.ndarray
    bg: jnp.ndarray | None
    base: np.ndarray
    #: the background photo's noise standard deviation, padded like ``bg`` (None without one)
    bg_sigma: jnp.ndarray | None = None


def padded(lev: Level) -> Padded:
    """``lev`` as compiled programs see it. An orthographic level is padded to
    :func:`padded_size` rows and columns and takes the canonical camera of that size
    (:func:`~bubblefit.model.geometry.canonical_frame`); a perspective one, whose rays
    depend on its size, is passed as it is (``base`` the identity)."""
    f32 = lambda a: None if a is None else jnp.asarray(a, jnp.float32)
    if not isinstance(lev.cfg.camera, OrthographicCamera):
        return Padded(lev.cfg, f32(lev.y), f32(lev.w), f32(lev.bg), np.asarray([0.0, 0.0, 1.0], np.float32),
                      f32(lev.bg_sigma))
    h, w = lev.y.shape[:2]
    hb, wb = padded_size(h), padded_size(w)
    camera, base = canonical_frame(lev.cfg.camera, hb, wb)
    pad = lambda a: None if a is None else f32(np.pad(a, ((0, hb - h), (0, wb - w), (0, 0))))
    return Padded(replace(lev.cfg, camera=camera), pad(lev.y), pad(lev.w), pad(lev.bg), base, pad(lev.bg_sigma))


def unpadded(lev: Level, a) -> np.ndarray:
    """``a``, an image ``(hb, wb, ...)`` of :func:`padded`'s level, on ``lev``'s own pixels
    (numpy, ``(h, w, ...)``): the padding at the bottom and right dropped."""
    h, w = lev.y.shape[:2]
    return np.asarray(a)[:h, :w]


@dataclass
class Pixels:
    """The fitted pixels of a padded level (:func:`fitted_pixels`): ``rows``, ``cols``,
    ``idx`` (steps, chunk) in the padded image, as :func:`~bubblefit.model.render.render_pixels`
    reads them, the photo ``y`` and weights ``w`` (steps chunk, 3) there (weight 0 on the
    entries that pad the list), and ``flat``, the pixels' flat indices in the level."""

    padded: Padded
    rows: jnp.ndarray
    cols: jnp.ndarray
    idx: jnp.ndarray
    y: jnp.ndarray
    w: jnp.ndarray
    flat: np.ndarray

    def scatter(self, lev: Level, a) -> np.ndarray:
        """``a`` (numpy), a flat residual ``(steps chunk 3, ...)`` over this list, as the
        flat residual ``(h w 3, ...)`` of ``lev`` (0 at the pixels not fitted)."""
        a = np.asarray(a)
        h, w = lev.y.shape[:2]
        out = np.zeros((h * w, 3, *a.shape[1:]), a.dtype)
        out[self.flat] = a.reshape(-1, 3, *a.shape[1:])[: self.flat.size]
        return out.reshape(h * w * 3, *a.shape[1:])


#: Lengths of a fitted-pixel list per octave (:func:`pixel_bucket`).
BUCKETS_PER_OCTAVE = 4


def pixel_bucket(n: int) -> int:
    """The length a list of ``n`` fitted pixels is padded to: the next of
    :data:`BUCKETS_PER_OCTAVE` lengths per octave, ``2^k (1 + j / BUCKETS_PER_OCTAVE)``
    (at least 64). A disc a few percent larger or smaller mostly shares its programs, and
    the padding costs at most a quarter of the list (a power of two cost up to all of it:
    2104 pixels rendered as 4096)."""
    n = max(int(n), 64)
    top = 1 << (n - 1).bit_length()
    step = (top // 2) // BUCKETS_PER_OCTAVE
    return min(top, -(-n // step) * step)


def fitted_pixels(lev: Level, chunk: int, mask: np.ndarray | None = None, *, whole_chunks: bool = False) -> Pixels:
    """The pixels of ``lev`` a fit compares (its mask, or ``mask``), listed in the padded level
    (:func:`padded`): their count rounded up to :func:`pixel_bucket`, or with
    ``whole_chunks`` to a multiple of ``chunk``, the list padded by repeating its last pixel
    with weight 0, and split into chunks of at most ``chunk``.
    A solve renders these alone: on a disc that fills 55 % of its level, about half the
    pixels of the padded image."""
    pad = padded(lev)
    w, wb = lev.y.shape[1], pad.cfg.shape[1]
    flat = np.flatnonzero((lev.mask if mask is None else mask).reshape(-1))
    if whole_chunks:  # a program per chunk serves every count
        n = max(1, -(-flat.size // chunk)) * chunk
    else:
        n = pixel_bucket(flat.size)
    steps = -(-n // chunk)
    size = -(-n // steps)  # equal chunks of at most ``chunk``: the list stays about n long
    take = np.minimum(np.arange(steps * size), max(flat.size - 1, 0))
    rows, cols = np.divmod(flat[take], w)
    keep = (np.arange(steps * size) < flat.size)[:, None]
    y = np.where(keep, lev.y.reshape(-1, 3)[flat[take]], 0.0)
    wt = np.where(keep, lev.w.reshape(-1, 3)[flat[take]], 0.0)
    i32 = lambda a: jnp.asarray(a.reshape(steps, size), jnp.int32)
    return Pixels(pad, i32(rows), i32(cols), i32(rows * wb + cols), jnp.asarray(y, jnp.float32),
                  jnp.asarray(wt, jnp.float32), flat)
