"""Transmission fraction t from photographs with and without the bubble (paper, sec. 3.3).

A bubble sits on a matte black dish inside a matte black box in front of a checkered
background. A fixed camera takes one photograph without the bubble (``before``) and one
with it (``after``). Background light crosses four film/air interfaces, so inside the
bubble ``after / before = t^4`` (paper, sec. 3.3), with t the per-interface transmission
fraction that the paper's eq. (14) ties to the reflectances, ``r_d + r_s = 1 - t``.

The pipeline of :func:`calibrate`, one pure function per step:

1. :func:`register_translation`: the camera shift between the shots, by phase correlation
   (Kuglin & Hines 1975) refined by ECC (Evangelidis & Psarakis 2008, via OpenCV), with
   the bubble masked out on the second pass. A low correlation means two different scenes.
2. :func:`usable_mask`: pixels whose ratio is reliable: lit (not the black squares, the box
   or the dish), unsaturated in both shots, away from the checker edges (where a residual
   sub-pixel misregistration changes the ratio).
3. :func:`detect_bubble`: the bubble, from the smoothed ratio image (normalised
   convolution, Knutsson & Westin 1993), thresholded against its own noise, its largest
   connected region and an algebraic circle fit to its rim (Kasa 1976).
4. :func:`fit_disc_profile`: a sub-pixel refinement of the circle by least squares on the
   ratio of every usable pixel around the rim, with a radial profile that bridges the
   paper's constant ``t^4`` (``beta = 0``) and the Fresnel film of the ``physical`` variant
   (``beta = 1``): ``q(rho) = L_in (1 - beta (1 - S(rho)))`` inside, ``L_out`` outside.
5. :func:`robust_ratio` and :func:`block_bootstrap_ratio`: t from the pixels well inside
   the bubble (``rho <= inner_fraction``) by an iteratively reweighted (Huber 1964) ratio
   of sums, normalised by the same ratio outside the bubble (exposure drift between the
   shots), with a 95% interval from a block bootstrap (Kunsch 1989), which stays honest
   when neighbouring pixels are correlated (interpolation, demosaicing, JPEG).
6. The refractive index: with the Fresnel film of the ``physical`` variant a ray through
   the disc at normalised radius ``rho`` meets both films at ``sin(theta) = rho``
   (orthographic camera), and ``after/before = mean_pol T_pol(theta)^2`` with
   ``T_pol = 1 - 2 R1 / (1 + R1)`` (incoherent lossless film, Born & Wolf 7.6). At the
   centre ``t^4 = mean_pol T_pol(0)^2`` fixes ``n``. When the rim fall-off is measured
   well enough to confirm that model, t is the normal-incidence value (interior pixels
   divided by the model's angular factor ``S(rho) = g(rho) / g(0)``) and ``n_film`` is
   reported with the interval of t mapped through that monotone relation.

All images are linear RGB arrays (H, W, 3). Circles given to and returned by
:func:`calibrate` (and the ``--circle`` option, and the JSON) use the convention of
:class:`bubblefit.model.geometry.OrthographicCamera`: x right, y down, the image's top-left
corner at (0, 0), so the centre of pixel (row i, column j) is (j + 1/2, i + 1/2). The
lower-level functions below work in array coordinates, where that centre is (j, i).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.images import Image, atomic_path, read_image, srgb_decode, srgb_encode, write_image

__all__ = [
    "CalibrationResult",
    "calibrate",
    "load_pair",
    "register_translation",
    "shift_image",
    "usable_mask",
    "detect_bubble",
    "kasa_circle_fit",
    "fit_disc_profile",
    "fresnel_film_ratio",
    "fresnel_shape",
    "n_from_t4",
    "robust_ratio",
    "block_bootstrap_ratio",
    "write_debug_image",
    "save_json",
]

#: Refractive index used for the shape of the angular fall-off before n is known.
DEFAULT_N = 1.4


# --------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------


@dataclass
class CalibrationResult:
    """What :func:`calibrate` measured.

    Attributes:
        t: per-interface transmission fraction (all channels together).
        t_rgb: t per channel (R, G, B).
        t4: ``t**4``, the measured after/before ratio inside the bubble.
        t_ci95, t_rgb_ci95, t4_ci95: 95% intervals (block bootstrap).
        bubble: ``{"cx", "cy", "r"}`` in pixels of the ``after`` image (pixel centres at
            +1/2, as :class:`bubblefit.model.geometry.OrthographicCamera`).
        bubble_source: ``"detected"`` or ``"given"``.
        pixels_used: pixels that entered the estimate of t.
        shift_px: ``[dx, dy]``, where a point of ``before`` lies in ``after``, minus where
            it lay in ``before`` (camera shift in pixels).
        registration_cc: ECC correlation coefficient outside the bubble after alignment.
        exposure_ratio: after/before ratio of the background outside the bubble (1 when
            the exposure did not change); t is normalised by it when ``exposure_corrected``.
        radial: the radial fit (``beta``, its standard error, ``model`` = ``"fresnel"``,
            ``"constant"`` or ``"undetermined"``, ...).
        n_film, n_film_stderr, n_film_ci95: refractive index of the film when determined,
            else ``None``.
        warnings: things the user should know, one sentence each.
        maps: arrays for the debug image (not written to JSON): ``ratio`` (H, W),
            ``used`` (H, W) bool, ``rim`` (H, W) bool, ``after`` (H, W, 3).
    """

    t: float
    t_rgb: list[float]
    t4: float
    t_ci95: list[float]
    t_rgb_ci95: list[list[float]]
    t4_ci95: list[float]
    bubble: dict[str, float]
    bubble_source: str
    pixels_used: int
    shift_px: list[float]
    registration_cc: float
    exposure_ratio: float
    exposure_corrected: bool
    radial: dict[str, Any]
    n_film: float | None = None
    n_film_stderr: float | None = None
    n_film_ci95: list[float] | None = None
    t_fresnel_corrected: bool = False
    inner_fraction: float = 0.6
    warnings: list[str] = field(default_factory=list)
    inputs: dict[str, str] = field(default_factory=dict)
    maps: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict[str, Any]:
        """The result as a JSON-ready dict (DESIGN.md keys first, extra keys after)."""
        out: dict[str, Any] = {
            "t": _r(self.t),
            "t_rgb": [_r(v) for v in self.t_rgb],
            "t4": _r(self.t4),
            "t_ci95": [_r(v) for v in self.t_ci95],
            "bubble": {k: _r(v, 3) for k, v in self.bubble.items()},
            "pixels_used": int(self.pixels_used),
            "warnings": list(self.warnings),
            "t_rgb_ci95": [[_r(a), _r(b)] for a, b in self.t_rgb_ci95],
            "t4_ci95": [_r(v) for v in self.t4_ci95],
            "bubble_source": self.bubble_source,
            "shift_px": [_r(v, 3) for v in self.shift_px],
            "registration_cc": _r(self.registration_cc, 5),
            "exposure_ratio": _r(self.exposure_ratio),
            "exposure_corrected": bool(self.exposure_corrected),
            "t_fresnel_corrected": bool(self.t_fresnel_corrected),
            "inner_fraction": self.inner_fraction,
            "radial_fit": {k: (_r(v) if isinstance(v, float) else v) for k, v in self.radial.items()},
        }
        if self.n_film is not None:
            out["n_film"] = _r(self.n_film, 5)
            out["n_film_stderr"] = _r(self.n_film_stderr, 5)
            out["n_film_ci95"] = [_r(v, 5) for v in self.n_film_ci95]
        if self.inputs:
            out["inputs"] = dict(self.inputs)
        return out

    def summary(self) -> str:
        """A short human-readable summary (a few lines)."""
        lo, hi = self.t_ci95
        b = self.bubble
        lines = [
            f"t = {self.t:.4f}  (95% CI {lo:.4f} .. {hi:.4f}),  t^4 = {self.t4:.4f}",
            "t_rgb = " + ", ".join(f"{v:.4f}" for v in self.t_rgb),
            f"bubble ({self.bubble_source}): centre ({b['cx']:.1f}, {b['cy']:.1f}) px, "
            f"radius {b['r']:.1f} px; {self.pixels_used} pixels used",
            f"camera shift ({self.shift_px[0]:+.2f}, {self.shift_px[1]:+.2f}) px, "
            f"exposure ratio {self.exposure_ratio:.4f}",
        ]
        if self.n_film is not None:
            lines.append(f"n_film = {self.n_film:.3f} +/- {self.n_film_stderr:.3f} (Fresnel film fit over radius)")
        for w in self.warnings:
            lines.append(f"warning: {w}")
        return "\n".join(lines)


def _r(v, digits: int = 6):
    return None if v is None else round(float(v), digits)


# --------------------------------------------------------------------------------------
# Input
# --------------------------------------------------------------------------------------


def _as_image(x: Image | np.ndarray | str | os.PathLike, name: str) -> Image:
    if isinstance(x, Image):
        return x
    if isinstance(x, np.ndarray):
        arr = np.asarray(x, dtype=np.float64)
        if arr.ndim == 2:
            arr = np.repeat(arr[:, :, None], 3, axis=2)
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise InputError(f"{name}: expected an (H, W, 3) image array, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: the image array has NaN or Inf values")
        return Image(pixels=arr, path=name, saturated=np.zeros(arr.shape[:2], bool))
    return read_image(x)


def _channels(img: Image) -> int:
    if img.was_gray:
        return 2 if img.alpha_dropped else 1
    return 4 if img.alpha_dropped else 3


def load_pair(before, after) -> tuple[Image, Image]:
    """Read and check a before/after pair.

    Parameters
    ----------
    before, after : path, :class:`~bubblefit.io.images.Image` or (H, W, 3) array
        Files are read with OpenImageIO and decoded to linear radiance
        (:func:`bubblefit.io.images.read_image`).

    Returns
    -------
    (Image, Image)

    Raises
    ------
    InputError
        A file cannot be read, or the two images differ in size or channel count.
    """
    b = _as_image(before, "before")
    a = _as_image(after, "after")
    nb, na = os.path.basename(b.path) or "before", os.path.basename(a.path) or "after"
    if b.shape != a.shape:
        raise InputError(
            f"{nb} is {b.shape[1]}x{b.shape[0]} but {na} is {a.shape[1]}x{a.shape[0]} pixels: "
            "the two photographs must come from the same fixed camera"
        )
    cb, ca = _channels(b), _channels(a)
    if cb != ca:
        raise InputError(f"{nb} has {cb} channel(s) but {na} has {ca}: the two photographs must be of the same kind")
    return b, a


# --------------------------------------------------------------------------------------
# Registration
# --------------------------------------------------------------------------------------


def _reg_view(gray: np.ndarray) -> np.ndarray:
    """A linear gray image scaled to about [0, 1] (float32) for OpenCV.

    Linear, not sRGB-encoded: a camera integrates linear light over each pixel, so only
    the linear image of a shifted scene is the shifted image (a non-linear transfer curve
    distorts partially covered edge pixels and biases a sub-pixel shift).
    """
    scale = float(np.percentile(gray, 99.5)) or 1.0
    return np.clip(gray / scale, 0.0, 2.0).astype(np.float32)


def register_translation(
    reference: np.ndarray, moving: np.ndarray, mask: np.ndarray | None = None, init: tuple[float, float] | None = None
) -> tuple[tuple[float, float], float]:
    """Sub-pixel translation between two gray images.

    Phase correlation (Kuglin & Hines 1975, ``cv2.phaseCorrelate`` with a Hann window)
    gives the integer-accurate shift, which ECC (Evangelidis & Psarakis 2008,
    ``cv2.findTransformECC`` with ``MOTION_TRANSLATION``) refines.

    Parameters
    ----------
    reference, moving : (H, W) float arrays
        Linear gray images (e.g. ``after`` and ``before``).
    mask : (H, W) bool, optional
        Pixels of ``moving`` that may be used by ECC (e.g. outside the bubble).
    init : (dx, dy), optional
        Initial shift; phase correlation is skipped when given.

    Returns
    -------
    (dx, dy), cc
        ``reference(x, y) ~ moving(x - dx, y - dy)``: a feature at (x, y) in ``moving``
        appears at (x + dx, y + dy) in ``reference``. ``cc`` is ECC's correlation
        coefficient (1 for identical images up to gain and offset); 0 if ECC failed.
    """
    import cv2

    ref = _reg_view(reference)
    mov = _reg_view(moving)
    if init is None:
        win = cv2.createHanningWindow(ref.shape[::-1], cv2.CV_32F)
        (dx, dy), _resp = cv2.phaseCorrelate(mov, ref, win)
    else:
        dx, dy = init
    warp = np.array([[1, 0, -dx], [0, 1, -dy]], dtype=np.float32)
    m = None if mask is None else (mask.astype(np.uint8) * 255)
    try:
        cc, warp = cv2.findTransformECC(
            ref, mov, warp, cv2.MOTION_TRANSLATION,
            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-7), m, 5,
        )
    except cv2.error:
        return (float(dx), float(dy)), 0.0
    return (float(-warp[0, 2]), float(-warp[1, 2])), float(cc)


def shift_image(img: np.ndarray, shift: tuple[float, float], *, order: str = "linear") -> np.ndarray:
    """Translate an image by ``shift = (dx, dy)`` pixels: ``out(x, y) = img(x - dx, y - dy)``.

    Bilinear (``order="linear"``) or nearest (``"nearest"``, for masks) interpolation;
    pixels that come from outside the image are 0 (False for masks).
    """
    import cv2

    dx, dy = shift
    if abs(dx) < 1e-9 and abs(dy) < 1e-9:
        return img.copy()
    h, w = img.shape[:2]
    warp = np.array([[1, 0, dx], [0, 1, dy]], dtype=np.float64)
    flag = cv2.INTER_NEAREST if order == "nearest" else cv2.INTER_LINEAR
    src = img.astype(np.uint8) if img.dtype == bool else img.astype(np.float32)
    out = cv2.warpAffine(src, warp, (w, h), flags=flag, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if img.dtype == bool:
        return out.astype(bool)
    return out.astype(np.float64)


# --------------------------------------------------------------------------------------
# Usable pixels
# --------------------------------------------------------------------------------------


def usable_mask(
    before: np.ndarray, after: np.ndarray, saturated: np.ndarray, *, dark_fraction: float = 0.2,
    edge_threshold: float = 0.12, edge_margin: int = 1,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Pixels whose after/before ratio is reliable.

    Parameters
    ----------
    before, after : (H, W) float arrays
        Registered linear gray images.
    saturated : (H, W) bool
        Pixels at the maximum code value in either shot.
    dark_fraction : float
        Pixels of ``before`` darker than this fraction of its 99th percentile are too dark
        for a stable ratio (the black checker squares, the box, the dish).
    edge_threshold, edge_margin : float, int
        Pixels where the relative gradient of the smoothed ``before`` exceeds the
        threshold (checker edges), grown by ``edge_margin`` pixels, are excluded: a
        residual sub-pixel misregistration changes their ratio.

    Returns
    -------
    usable : (H, W) bool
    parts : dict of (H, W) bool masks ``lit``, ``saturated``, ``edge`` (for reports).
    """
    from scipy import ndimage as ndi

    level = float(np.percentile(before, 99.0))
    lit = before > dark_fraction * level if level > 0 else np.zeros(before.shape, bool)
    sm = ndi.gaussian_filter(before, 1.0)
    grad = np.hypot(ndi.sobel(sm, 0), ndi.sobel(sm, 1)) / 8.0
    edge = grad > edge_threshold * np.maximum(sm, 1e-6 * level)  # scale-free: any exposure
    edge &= sm > 0.5 * dark_fraction * level
    if edge_margin > 0:
        edge = ndi.binary_dilation(edge, iterations=edge_margin)
    sat = ndi.binary_dilation(saturated, iterations=1) if saturated.any() else saturated
    usable = lit & ~sat & ~edge & (after >= 0)
    return usable, {"lit": lit, "saturated": sat, "edge": edge}


# --------------------------------------------------------------------------------------
# Bubble detection
# --------------------------------------------------------------------------------------


def kasa_circle_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Algebraic least-squares circle through points (Kasa 1976).

    Solves ``x^2 + y^2 + D x + E y + F = 0`` in the least-squares sense.

    Returns
    -------
    (cx, cy, r)
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    rhs = -(x * x + y * y)
    (D, E, F), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    cx, cy = -D / 2.0, -E / 2.0
    r = math.sqrt(max(cx * cx + cy * cy - F, 0.0))
    return float(cx), float(cy), float(r)


def _smoothed_ratio(before: np.ndarray, after: np.ndarray, usable: np.ndarray, sigma: float):
    """Normalised convolution (Knutsson & Westin 1993) of after/before over usable pixels."""
    from scipy import ndimage as ndi

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
    from scipy import ndimage as ndi

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
    from scipy import ndimage as ndi

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
            c2 = kasa_circle_fit(xx[keep], yy[keep])
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


# --------------------------------------------------------------------------------------
# Fresnel film model (physical variant)
# --------------------------------------------------------------------------------------


def fresnel_film_ratio(rho: np.ndarray, n: float) -> np.ndarray:
    """after/before through both films of the ``physical`` variant, incoherent film.

    ``mean_pol T_pol(theta)^2`` with ``sin(theta) = rho`` (orthographic camera) and
    ``T_pol = 1 - 2 R1 / (1 + R1)`` (:func:`bubblefit.optics.film.incoherent_reflectance`,
    Born & Wolf 7.6); polarisations are carried separately through both films and
    averaged at the end.

    Parameters
    ----------
    rho : array
        Distance from the disc centre over its radius, in [0, 1].
    n : float
        Refractive index of the film.
    """
    import jax

    from ..optics.film import incoherent_reflectance

    rho = np.clip(np.asarray(rho, float), 0.0, 1.0)
    cos_i = np.sqrt(1.0 - rho * rho)
    with jax.enable_x64(True):  # double precision: n is inverted from this to 1e-10
        tp = 1.0 - np.asarray(incoherent_reflectance(cos_i, float(n)), dtype=np.float64)
    return np.mean(tp * tp, axis=-1)


def fresnel_shape(rho: np.ndarray, n: float = DEFAULT_N) -> np.ndarray:
    """Angular factor ``S(rho) = ratio(rho) / ratio(0)`` of :func:`fresnel_film_ratio`.

    Nearly independent of n (0.80 at rho = 0.9 for n = 1.33 .. 1.45); 0 at the rim.
    Evaluated by interpolation in a fine table.
    """
    grid = np.linspace(0.0, 1.0, 2001)
    table = fresnel_film_ratio(grid, n)
    table = table / table[0]
    return np.interp(np.clip(rho, 0.0, 1.0), grid, table)


def n_from_t4(t4: float, lo: float = 1.0 + 1e-6, hi: float = 3.0) -> float:
    """The film index whose normal-incidence transmission through both films is ``t4``.

    Inverts ``t4 = mean_pol (1 - R_film(0))^2`` (lossless incoherent film), which decreases
    monotonically with n. Returns ``nan`` when ``t4`` is out of range (>= 1 or too low).
    """
    from scipy.optimize import brentq

    def f(n):
        return float(fresnel_film_ratio(np.array(0.0), n)) - t4

    if not (f(hi) < 0 < f(lo)):
        return float("nan")
    return float(brentq(f, lo, hi, xtol=1e-10))


# --------------------------------------------------------------------------------------
# Disc fit
# --------------------------------------------------------------------------------------


def _logistic(x):
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def fit_disc_profile(
    before: np.ndarray, after: np.ndarray, usable: np.ndarray, circle: tuple[float, float, float], *,
    fix_geometry: bool = False, n: float = DEFAULT_N, band: float = 1.6, max_pixels: int = 200_000,
    block: int = 4, seed: int = 0,
) -> dict[str, Any]:
    """Least-squares fit of the ratio image around the bubble.

    Model of the after/before ratio ``q`` at distance ``d`` from ``(cx, cy)``:
    ``q = L_out (1 - c) + c L_in (1 - beta (1 - S(d / r)))``, with ``c`` the pixel's
    coverage by the disc (a logistic edge one pixel wide) and ``S`` the angular factor of
    the Fresnel film (:func:`fresnel_shape`): ``beta = 1`` is the ``physical`` variant,
    ``beta = 0`` the paper's constant ``t^4``. Residuals ``(q - model) before`` (so that
    the noise is roughly uniform), soft-L1 loss (robust to outliers), scipy's trust-region
    least squares. Standard errors from the Gauss-Newton covariance, inflated by the
    variance inflation of 4x4-pixel blocks of residuals (correlated neighbours).

    Parameters
    ----------
    before, after : (H, W) float
        Registered linear gray images.
    usable : (H, W) bool
    circle : (cx, cy, r)
        Initial circle in pixels.
    fix_geometry : bool
        Keep the circle as given (``--circle``) and fit only ``L_in, L_out, beta``.
    n : float
        Index used for the shape ``S``.
    band : float
        Pixels up to ``band * r`` from the centre enter the fit.

    Returns
    -------
    dict with ``cx, cy, r, L_in, L_out, beta`` and ``*_stderr``, ``noise`` (robust std of
    the ratio residuals at the median brightness), ``n_pixels``, ``n_rim_pixels`` (usable
    pixels at rho in [0.75, 0.97]), ``vif``.
    """
    from scipy.optimize import least_squares

    cx0, cy0, r0 = circle
    h, w = before.shape
    yy, xx = np.mgrid[0:h, 0:w]
    d0 = np.hypot(xx - cx0, yy - cy0)
    sel = usable & (d0 < band * r0 + 2)
    ys, xs = np.nonzero(sel)
    if ys.size > max_pixels:
        pick = np.random.default_rng(seed).choice(ys.size, max_pixels, replace=False)
        ys, xs = ys[pick], xs[pick]
    if ys.size < 20:  # nothing to fit (e.g. a given circle over the black box)
        names = ["cx", "cy", "r", "L_in", "L_out", "beta"]
        out = dict(zip(names, [float(cx0), float(cy0), float(r0), float("nan"), float("nan"), 0.0]))
        out.update({f"{k}_stderr": float("inf") for k in names})
        out.update(n_pixels=int(ys.size), n_rim_pixels=0, noise=float("nan"), vif=1.0, success=False)
        return out
    b = before[ys, xs]
    q = after[ys, xs] / b
    wgt = b / np.median(b)
    grid = np.linspace(0.0, 1.0, 2001)
    table = fresnel_shape(grid, n)

    inside0 = d0[ys, xs] < 0.8 * r0
    outside0 = d0[ys, xs] > 1.1 * r0 + 1
    L_in0 = float(np.median(q[inside0])) if inside0.any() else 0.9
    L_out0 = float(np.median(q[outside0])) if outside0.any() else 1.0

    def model(p):
        if fix_geometry:
            cx, cy, r = cx0, cy0, r0
            L_in, L_out, beta = p
        else:
            cx, cy, r, L_in, L_out, beta = p
        d = np.hypot(xs - cx, ys - cy)
        cov = _logistic((r - d) / edge[0])
        s = np.interp(np.minimum(d / r, 1.0), grid, table)
        return L_out * (1.0 - cov) + cov * L_in * (1.0 - beta * (1.0 - s))

    p0 = [L_in0, L_out0, 0.5] if fix_geometry else [cx0, cy0, r0, L_in0, L_out0, 0.5]
    edge = [0.45]

    def resid(p):
        return (q - model(p)) * wgt

    def solve(p_start, width):
        edge[0] = width
        r_init = resid(p_start)
        scale = 1.4826 * float(np.median(np.abs(r_init - np.median(r_init)))) or 1e-3
        return least_squares(resid, p_start, loss="soft_l1", f_scale=3.0 * scale, x_scale="jac",
                             method="trf", tr_solver="lsmr")

    if fix_geometry:
        sol = solve(p0, 0.45)
    else:
        # multi-start on a blurred edge (a wide basin of attraction), the best start refined
        # coarse to fine; all starts see the same pixels, so their costs compare
        best = None
        for ox, oy in [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)]:
            start = list(p0)
            start[0] += 0.25 * r0 * ox
            start[1] += 0.25 * r0 * oy
            sol = solve(start, 3.0)
            cost = float(np.sum(resid(sol.x) ** 2))
            if best is None or cost < best[0]:
                best = (cost, sol.x)
        p0 = best[1]
        for width in (1.2, 0.45):
            sol = solve(p0, width)
            p0 = sol.x
    res = resid(sol.x)
    sigma = 1.4826 * float(np.median(np.abs(res - np.median(res)))) or 1e-12
    # variance inflation from correlated neighbours: block means vs pixel variance
    bid = (ys // block) * (w // block + 1) + xs // block
    _, inv, counts = np.unique(bid, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=res)
    full = counts >= block * block // 2
    if full.sum() > 10:
        bm = sums[full] / counts[full]
        vif = float(np.var(bm) * np.mean(counts[full]) / max(np.var(res), 1e-300))
        vif = float(np.clip(vif, 1.0, 25.0))
    else:
        vif = 1.0
    J = sol.jac
    try:
        cov = np.linalg.inv(J.T @ J) * sigma**2 * vif
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        se = np.full(len(sol.x), np.inf)
    names = ["L_in", "L_out", "beta"] if fix_geometry else ["cx", "cy", "r", "L_in", "L_out", "beta"]
    out: dict[str, Any] = {k: float(v) for k, v in zip(names, sol.x)}
    out.update({f"{k}_stderr": float(v) for k, v in zip(names, se)})
    if fix_geometry:
        out.update(cx=float(cx0), cy=float(cy0), r=float(r0), cx_stderr=0.0, cy_stderr=0.0, r_stderr=0.0)
    rho = np.hypot(xs - out["cx"], ys - out["cy"]) / out["r"]
    out["n_pixels"] = int(xs.size)
    out["n_rim_pixels"] = int(np.sum((rho >= 0.75) & (rho <= 0.97)))
    out["noise"] = float(sigma)
    out["vif"] = vif
    out["success"] = bool(sol.success)
    return out


# --------------------------------------------------------------------------------------
# Robust ratio and its interval
# --------------------------------------------------------------------------------------


def robust_ratio(a: np.ndarray, b: np.ndarray, *, c: float = 2.5, iterations: int = 10) -> tuple[float, np.ndarray]:
    """Robust ratio ``k`` of ``a ~ k b`` over pixels, and the weights that give it.

    Iteratively reweighted ratio of sums ``k = sum(w a) / sum(w b)`` with Huber weights
    (Huber 1964) on the residuals ``a - k b`` scaled by their median absolute deviation.
    A ratio of sums has no attenuation bias from the noise of ``b`` (unlike regression
    through the origin) and no skew bias (unlike the mean of per-pixel ratios).

    Parameters
    ----------
    a, b : (N,) float
        After and before values of the same pixels (b > 0).

    Returns
    -------
    k : float
    w : (N,) float weights in [0, 1] (0 for gross outliers).
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    k = float(np.median(a / b))
    w = np.ones_like(a)
    for _ in range(iterations):
        res = a - k * b
        s = 1.4826 * float(np.median(np.abs(res - np.median(res))))
        if s <= 0:
            break
        u = np.abs(res) / (c * s)
        w = np.where(u <= 1.0, 1.0, 1.0 / np.maximum(u, 1e-12))
        w[np.abs(res) > 10.0 * s] = 0.0  # a gross outlier (dust, a reflection)
        k_new = float(np.sum(w * a) / np.sum(w * b))
        if abs(k_new - k) < 1e-10 * abs(k):
            k = k_new
            break
        k = k_new
    return k, w


def block_bootstrap_ratio(
    a_blocks: np.ndarray, b_blocks: np.ndarray, *, n_boot: int = 2000, rng: np.random.Generator | None = None
) -> np.ndarray:
    """Bootstrap replicates of ``sum(a) / sum(b)`` resampling whole pixel blocks (Kunsch 1989).

    Parameters
    ----------
    a_blocks, b_blocks : (n_blocks, C) float
        Per-block weighted sums of after and before values for C series (channels).

    Returns
    -------
    (n_boot, C) float: the ratio of each resample.
    """
    rng = rng or np.random.default_rng(0)
    nb = a_blocks.shape[0]
    counts = rng.multinomial(nb, np.full(nb, 1.0 / nb), size=n_boot).astype(float)
    return (counts @ a_blocks) / (counts @ b_blocks)


def _block_sums(ids: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-block sums of (N, C) values grouped by block id."""
    _, inv = np.unique(ids, return_inverse=True)
    out = np.zeros((inv.max() + 1, values.shape[1]))
    np.add.at(out, inv, values)
    return out


# --------------------------------------------------------------------------------------
# The whole calibration
# --------------------------------------------------------------------------------------


def _gray(px: np.ndarray) -> np.ndarray:
    return px.sum(axis=2)


def calibrate(
    before, after, circle: tuple[float, float, float] | None = None, *,
    inner_fraction: float = 0.6, exposure_correction: bool = True, max_shift: float | None = None,
    min_cc: float = 0.7, n_boot: int = 2000, seed: int = 0, min_pixels: int = 50,
) -> CalibrationResult:
    """Measure the transmission fraction t from photographs without and with the bubble.

    Parameters
    ----------
    before, after : path, :class:`~bubblefit.io.images.Image` or (H, W, 3) linear array
        The shot without and with the bubble, same fixed camera.
    circle : (cx, cy, r), optional
        The bubble in pixels of ``after`` (pixel centres at +1/2, the convention of
        :class:`bubblefit.model.geometry.OrthographicCamera`); detected when not given.
    inner_fraction : float
        t uses pixels within ``inner_fraction * r`` of the centre (and at least 3 pixels
        inside the rim), away from the oblique rim.
    exposure_correction : bool
        Divide by the after/before ratio of the background outside the bubble.
    max_shift : float, optional
        Largest camera shift accepted, pixels (default: max(8, 10% of the smaller side)).
    min_cc : float
        Smallest ECC correlation for the two shots to count as the same scene.
    n_boot : int
        Bootstrap resamples for the intervals.
    seed : int
        Seed of the bootstrap (results are reproducible).
    min_pixels : int
        Fewest usable pixels inside the bubble.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError
        Unreadable or mismatched files, saturated or black images, two different scenes, no
        bubble, or too few usable pixels inside it; the message is one line.
    """
    img_b, img_a = load_pair(before, after)
    nb = os.path.basename(img_b.path) or "before"
    na = os.path.basename(img_a.path) or "after"
    warnings: list[str] = []
    pb, pa = img_b.pixels, img_a.pixels
    h, w = img_b.shape
    gb, ga = _gray(pb), _gray(pa)
    sat_b = img_b.saturated if img_b.saturated is not None else np.zeros((h, w), bool)
    sat_a = img_a.saturated if img_a.saturated is not None else np.zeros((h, w), bool)

    # --- exposure sanity: black or saturated shots
    for name, g, sat in ((nb, gb, sat_b), (na, ga, sat_a)):
        level = float(np.percentile(g, 99.0))
        if level <= 0:
            raise InputError(f"{name} is black: nothing to measure (check the exposure and the lighting)")
        lit = g > 0.2 * level
        frac = float(sat[lit].mean()) if lit.any() else 0.0
        if frac > 0.5:
            raise InputError(
                f"{name} is saturated: {100 * frac:.0f}% of its lit pixels are at the maximum code value "
                "(reduce the exposure and retake both shots)"
            )
    if img_b.bit_depth != img_a.bit_depth:
        warnings.append(f"the shots have different bit depths ({img_b.bit_depth} and {img_a.bit_depth})")
    if img_b.linear_file != img_a.linear_file:
        warnings.append("one shot is linear and the other sRGB-encoded; check that both come from the same pipeline")

    # --- registration, pass 1 (whole image)
    if max_shift is None:
        max_shift = max(8.0, 0.1 * min(h, w))
    given = circle is not None
    mask1 = None
    if given:
        cx, cy, r = (float(v) for v in circle)
        if not (np.isfinite([cx, cy, r]).all() and r > 0):
            raise InputError(f"circle: need a finite centre and a positive radius, got {circle}")
        if not (-r < cx < w + r and -r < cy < h + r):
            raise InputError(f"circle: the centre ({cx:g}, {cy:g}) is outside the {w}x{h} image")
        cx, cy = cx - 0.5, cy - 0.5  # to array coordinates
        circle = (cx, cy, r)
        yy, xx = np.mgrid[0:h, 0:w]
        mask1 = np.hypot(xx - cx, yy - cy) > 1.2 * r + 3
    shift, cc = register_translation(ga, gb, mask=mask1)
    if cc < min_cc or max(abs(shift[0]), abs(shift[1])) > max_shift:
        if cc < min_cc:
            raise InputError(
                f"{nb} and {na} do not show the same scene: correlation {cc:.2f} after registration "
                f"(need at least {min_cc:.2f}); the camera and background must not change between shots"
            )
        raise InputError(
            f"the camera moved by ({shift[0]:.1f}, {shift[1]:.1f}) pixels between {nb} and {na}; "
            f"calibration needs a fixed camera (at most {max_shift:.0f} pixels)"
        )
    gb_r = shift_image(gb, shift)
    sat = shift_image(sat_b, shift, order="nearest") | sat_a
    valid_src = shift_image(np.ones((h, w), bool), shift, order="nearest")
    usable, parts = usable_mask(gb_r, ga, sat)
    usable &= valid_src

    # --- bubble
    if not given:
        circle = detect_bubble(gb_r, ga, usable)
    cx, cy, r = circle
    if r < 4:
        raise InputError(f"the bubble is too small in the image (radius {r:.1f} pixels); move the camera closer")

    # --- registration, pass 2 (background only)
    yy, xx = np.mgrid[0:h, 0:w]
    outside_mask = np.hypot(xx - cx, yy - cy) > 1.2 * r + 3
    if outside_mask.mean() > 0.05:
        shift2, cc2 = register_translation(ga, gb, mask=outside_mask, init=shift)
        if cc2 > 0 and math.hypot(shift2[0] - shift[0], shift2[1] - shift[1]) < 3:
            shift, cc = shift2, cc2
            gb_r = shift_image(gb, shift)
            sat = shift_image(sat_b, shift, order="nearest") | sat_a
            usable, parts = usable_mask(gb_r, ga, sat)
            usable &= valid_src
    if cc < 0.9:
        warnings.append(f"low correlation between the shots outside the bubble ({cc:.3f}): did the scene change?")

    # --- radial profile and circle refinement
    prof = fit_disc_profile(gb_r, ga, usable, (cx, cy, r), fix_geometry=given, seed=seed)
    if not given:
        if prof["success"] and math.hypot(prof["cx"] - cx, prof["cy"] - cy) < 0.5 * r and 0.5 * r < prof["r"] < 1.5 * r:
            cx, cy, r = prof["cx"], prof["cy"], prof["r"]
        else:
            warnings.append("the circle refinement did not converge near the detected circle; using the detection")
    d = np.hypot(xx - cx, yy - cy)
    rho = d / r
    beta, beta_se = prof["beta"], prof["beta_stderr"]
    determined = prof["n_rim_pixels"] >= 100 and beta_se <= 0.2
    if determined and abs(beta - 1.0) <= max(3 * beta_se, 0.15):
        radial_model = "fresnel"
    elif determined and abs(beta) <= max(3 * beta_se, 0.15):
        radial_model = "constant"
    elif determined:
        radial_model = "other"
    else:
        radial_model = "undetermined"

    # --- pixels for t
    inner = (rho <= inner_fraction) & (d <= r - 3)
    used = usable & inner
    n_inner = int(inner.sum())
    n_used = int(used.sum())
    if n_used < min_pixels:
        n_sat = int((inner & sat).sum())
        n_dark = int((inner & ~parts["lit"]).sum())
        raise InputError(
            f"too few usable pixels inside the bubble ({n_used} of {n_inner}, need {min_pixels}): "
            f"{n_sat} saturated, {n_dark} too dark; adjust the exposure or use a larger bubble"
        )
    outer = usable & (d >= 1.2 * r + 3)

    # per-channel values, registered
    pb_r = np.stack([shift_image(pb[..., c], shift) for c in range(3)], axis=-1)
    rng = np.random.default_rng(seed)
    block = int(np.clip(min(h, w) // 64, 4, 16))
    bid = (yy // block) * (w // block + 1) + xx // block

    corr = np.ones(n_used)
    fresnel_corrected = False
    n_shape = DEFAULT_N

    def estimate(corr_in):
        a_in = np.concatenate([pa[used], ga[used][:, None]], axis=1) / corr_in[:, None]
        b_in = np.concatenate([pb_r[used], gb_r[used][:, None]], axis=1)
        k_in = np.empty(4)
        wa_in = np.empty_like(a_in)
        wb_in = np.empty_like(b_in)
        for c in range(4):
            k_in[c], wc = robust_ratio(a_in[:, c], b_in[:, c])
            wa_in[:, c], wb_in[:, c] = wc * a_in[:, c], wc * b_in[:, c]
        return k_in, _block_sums(bid[used], wa_in), _block_sums(bid[used], wb_in)

    if radial_model in ("fresnel", "undetermined"):
        # physics prior: a real film transmits less at oblique incidence (Fresnel)
        corr = fresnel_shape(rho[used], n_shape)
        fresnel_corrected = True
    k_in, A_in, B_in = estimate(corr)

    exposure = 1.0
    A_out = B_out = None
    exposure_corrected = False
    if exposure_correction and outer.sum() >= 200:
        a_out = np.concatenate([pa[outer], ga[outer][:, None]], axis=1)
        b_out = np.concatenate([pb_r[outer], gb_r[outer][:, None]], axis=1)
        k_out = np.empty(4)
        wa_out = np.empty_like(a_out)
        wb_out = np.empty_like(b_out)
        for c in range(4):
            k_out[c], wc = robust_ratio(a_out[:, c], b_out[:, c])
            wa_out[:, c], wb_out[:, c] = wc * a_out[:, c], wc * b_out[:, c]
        A_out, B_out = _block_sums(bid[outer], wa_out), _block_sums(bid[outer], wb_out)
        exposure = float(k_out[3])
        exposure_corrected = True
        if abs(exposure - 1.0) > 0.02:
            warnings.append(
                f"the exposure changed by {100 * (exposure - 1):+.1f}% between the shots "
                "(measured outside the bubble); t is corrected for it"
            )
    else:
        k_out = np.ones(4)
        if exposure_correction:
            warnings.append("too little background outside the bubble to check the exposure; assumed unchanged")

    t4_all = k_in / k_out
    if np.any(t4_all <= 0):
        raise InputError("no light is transmitted through the bubble region: check the circle and the shots")
    # n and a refined angular correction when the physical model is supported
    if radial_model == "fresnel":
        n_est = n_from_t4(float(t4_all[3]))
        if np.isfinite(n_est) and 1.2 < n_est < 2.0 and abs(n_est - n_shape) > 1e-3:
            n_shape = n_est
            corr = fresnel_shape(rho[used], n_shape)
            k_in, A_in, B_in = estimate(corr)
            t4_all = k_in / k_out

    # bootstrap
    nbi = A_in.shape[0]
    boot_in = block_bootstrap_ratio(A_in, B_in, n_boot=n_boot, rng=rng)
    if A_out is not None:
        boot_out = block_bootstrap_ratio(A_out, B_out, n_boot=n_boot, rng=rng)
    else:
        boot_out = np.ones_like(boot_in)
    boot = boot_in / boot_out
    # small-sample correction of the spread (n / (n - 1))
    infl = math.sqrt(nbi / max(nbi - 1, 1))
    boot = t4_all + (boot - np.mean(boot, axis=0)) * infl
    lo4, hi4 = np.percentile(boot, [2.5, 97.5], axis=0)
    t_all = np.clip(t4_all, 0, None) ** 0.25
    t_lo, t_hi = np.clip(lo4, 0, None) ** 0.25, np.clip(hi4, 0, None) ** 0.25
    if t_all[3] > 1.0:
        warnings.append(f"t > 1 ({t_all[3]:.4f}): the bubble region got brighter; check for reflections or flicker")
    if nbi < 20:
        warnings.append(f"only {nbi} pixel blocks inside the bubble: the interval is approximate")

    # n_film
    n_film = n_se = n_ci = None
    radial = {
        "model": radial_model,
        "beta": float(beta),
        "beta_stderr": float(beta_se),
        "n_rim_pixels": int(prof["n_rim_pixels"]),
        "r_stderr": float(prof["r_stderr"]),
        "noise": float(prof["noise"]),
        "n_shape": float(n_shape),
    }
    if radial_model == "fresnel":
        n_est = n_from_t4(float(t4_all[3]))
        n_a, n_b = n_from_t4(float(hi4[3])), n_from_t4(float(lo4[3]))
        if all(np.isfinite([n_est, n_a, n_b])):
            n_film, n_ci = n_est, [n_a, n_b]
            n_se = (n_b - n_a) / (2 * 1.959964)
            if not (1.30 <= n_film <= 1.50):
                warnings.append(
                    f"n_film = {n_film:.3f} is implausible for a soap film: the film may absorb or scatter, "
                    "or the lighting changed"
                )
        else:
            warnings.append("the ratio at the centre is outside the range of a lossless film; n_film not reported")
    elif radial_model == "constant":
        warnings.append(
            "the ratio does not fall toward the rim as the Fresnel film model predicts (paper's constant t); "
            "n_film not reported"
        )
    elif radial_model == "other":
        warnings.append(
            f"the radial fall-off of the ratio (beta = {beta:.2f} +/- {beta_se:.2f}) matches neither the Fresnel "
            "film (1) nor a constant t (0); n_film not reported"
        )
    else:
        warnings.append(
            "too few pixels near the rim to fit the Fresnel film model (bubble too small in the image or rim "
            "too dark); n_film not reported, t corrected with n = 1.4"
        )

    ratio_map = np.where(usable, ga / np.where(usable, gb_r, 1.0) / k_out[3], np.nan)
    rim = usable & (rho >= 0.75) & (rho <= 0.97)
    return CalibrationResult(
        t=float(t_all[3]),
        t_rgb=[float(v) for v in t_all[:3]],
        t4=float(t4_all[3]),
        t_ci95=[float(t_lo[3]), float(t_hi[3])],
        t_rgb_ci95=[[float(t_lo[c]), float(t_hi[c])] for c in range(3)],
        t4_ci95=[float(lo4[3]), float(hi4[3])],
        bubble={"cx": float(cx) + 0.5, "cy": float(cy) + 0.5, "r": float(r)},
        bubble_source="given" if given else "detected",
        pixels_used=n_used,
        shift_px=[float(shift[0]), float(shift[1])],
        registration_cc=float(cc),
        exposure_ratio=float(k_out[3]),
        exposure_corrected=exposure_corrected,
        radial=radial,
        n_film=n_film,
        n_film_stderr=n_se,
        n_film_ci95=n_ci,
        t_fresnel_corrected=fresnel_corrected,
        inner_fraction=inner_fraction,
        warnings=warnings,
        inputs={"before": img_b.path, "after": img_a.path},
        maps={"ratio": ratio_map, "used": used, "rim": rim, "after": pa},
    )


# --------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------


def save_json(path: str | os.PathLike, result: CalibrationResult) -> None:
    """Write ``result.to_json()`` atomically."""
    import json

    with atomic_path(path) as tmp:
        with open(tmp, "w") as f:
            json.dump(result.to_json(), f, indent=2)
            f.write("\n")


def write_debug_image(path: str | os.PathLike, result: CalibrationResult) -> None:
    """Write a two-panel debug image (atomically).

    Left: the ``after`` shot. Right: the after/before ratio map (gray, from ``t^4 - 0.15``
    to 1.05; unusable pixels dark blue), pixels used for t tinted green, rim pixels of the
    radial fit tinted blue, the bubble circle in red. Small images are enlarged (nearest)
    so the panel is at least 400 pixels wide.
    """
    import cv2

    m = result.maps
    after = m["after"]
    h, w = after.shape[:2]
    scale = max(1, int(math.ceil(400 / max(w, 1))))
    left = srgb_encode(after / max(float(np.percentile(after, 99.5)), 1e-6))
    lo, hi = result.t4 - 0.15, 1.05
    g = np.clip((np.nan_to_num(m["ratio"], nan=lo) - lo) / (hi - lo), 0, 1)
    right = np.repeat(g[..., None], 3, axis=2)
    right[~np.isfinite(m["ratio"])] = (0.05, 0.05, 0.25)
    green = np.array([0.1, 0.9, 0.1])
    blue = np.array([0.2, 0.4, 1.0])
    right[m["used"]] = 0.6 * right[m["used"]] + 0.4 * green
    right[m["rim"]] = 0.6 * right[m["rim"]] + 0.4 * blue
    panel = np.concatenate([left, right], axis=1)
    panel = np.repeat(np.repeat(panel, scale, axis=0), scale, axis=1)
    panel = np.ascontiguousarray((panel * 255).astype(np.uint8))
    b = result.bubble
    sh = 4
    for off in (0, w * scale):
        c = (int(round((b["cx"] * scale + off) * (1 << sh))), int(round(b["cy"] * scale * (1 << sh))))
        cv2.circle(panel, c, int(round(b["r"] * scale * (1 << sh))), (255, 0, 0), 1, cv2.LINE_AA, sh)
        cv2.drawMarker(panel, (c[0] >> sh, c[1] >> sh), (255, 0, 0), cv2.MARKER_CROSS, 7, 1)
    write_image(path, srgb_decode(panel.astype(np.float64) / 255.0))
