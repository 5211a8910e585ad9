"""Merging a bracket of exposures to one linear radiance image, and camera responses.

Every radiance of the scene must be well exposed in some exposure of the bracket (Debevec &
Malik 1997, "Recovering high dynamic range radiance maps from photographs", SIGGRAPH):
:func:`merge_exposures` combines them with weights that ignore clipped pixels and falls
back to a bound where a pixel is clipped in every exposure (a sun);
:func:`recover_response` recovers a camera's response with OpenCV when it is unknown.
See ``docs/design.md``, "Light probes".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from ..errors import InputError
from ..io.images import srgb_encode

__all__ = ["HdrMerge", "merge_exposures", "file_clip_level", "recover_response", "apply_response", "exposure_stops"]


def file_clip_level(bit_depth: int) -> float:
    """Linear value at which an exposure read from a file of ``bit_depth`` bits counts as
    clipped: just under full scale for 8- and 16-bit codes, never for float files (EXR, HDR,
    float TIFF hold radiance above 1 unclipped)."""
    return 0.98 if bit_depth in (8, 16) else math.inf


def exposure_stops(times: Sequence[float]) -> float:
    """Span of a bracket in stops: ``log2(max time / min time)``."""
    t = np.asarray(times, dtype=np.float64)
    return float(np.log2(t.max() / t.min())) if t.size else 0.0


def recover_response(codes: Sequence[np.ndarray], times: Sequence[float], *, method: str = "debevec",
                     samples: int = 200, smoothness: float = 10.0) -> np.ndarray:
    """Recover a camera's response curve from a bracket of 8-bit exposures (OpenCV).

    ``method="debevec"``: Debevec & Malik 1997, "Recovering high dynamic range radiance maps
    from photographs" (SIGGRAPH), the least-squares solve of their eq. (3) with a smoothness
    term (``cv2.createCalibrateDebevec``). ``method="robertson"``: Robertson, Borman &
    Stevenson 2003, "Estimation-theoretic approach to dynamic range enhancement using
    multiple exposures", J. Electronic Imaging 12(2) (``cv2.createCalibrateRobertson``).

    Args:
        codes: exposures as (H, W, 3) uint8 arrays (the camera's code values, RGB order).
        times: exposure times in seconds, one per exposure.
        method: "debevec" or "robertson".

    Returns:
        (256, 3) float64: relative linear exposure for each code value and channel, made
        monotone and scaled so that the codes 250-255 average 1 (a recovered curve is
        defined only up to scale).
    """
    if len(codes) < 2:
        raise InputError("recovering a response curve needs at least two exposures")
    imgs = []
    for c in codes:
        c = np.asarray(c)
        if c.dtype != np.uint8 or c.ndim != 3 or c.shape[2] != 3:
            raise InputError("response recovery needs 8-bit RGB exposures")
        imgs.append(np.ascontiguousarray(c[..., ::-1]))  # OpenCV works in BGR
    t = np.asarray(times, dtype=np.float32)
    if method == "debevec":
        cal = cv2.createCalibrateDebevec(samples=samples, lambda_=smoothness, random=False)
    elif method == "robertson":
        cal = cv2.createCalibrateRobertson()
    else:
        raise InputError(f"unknown response recovery method {method!r} (debevec, robertson)")
    resp = np.asarray(cal.process(imgs, t), dtype=np.float64).reshape(256, 3)[:, ::-1]
    resp = np.maximum.accumulate(np.maximum(resp, 0.0), axis=0)  # monotone, non-negative
    top = resp[250:].mean()
    return resp / top if top > 0 else resp


def apply_response(codes: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Linearise 8-bit code values with a (256, 3) response table: out[..., c] = response[code, c]."""
    codes = np.asarray(codes)
    return np.stack([response[codes[..., c], c] for c in range(3)], axis=-1)


@dataclass
class HdrMerge:
    """A merged HDR image.

    Attributes:
        radiance: (H, W, 3) linear radiance, in units of (pixel value) / (exposure time).
        clipped: (H, W) bool, pixels clipped in every exposure: there the value is the
            darkest exposure's (a lower bound).
        underexposed: (H, W) bool, pixels below the noise floor in every exposure.
        used: (H, W) int, number of exposures that contributed to each pixel.
    """

    radiance: np.ndarray
    clipped: np.ndarray
    underexposed: np.ndarray
    used: np.ndarray


def merge_exposures(
    images: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    saturated: Sequence[np.ndarray | None] | None = None,
    method: str = "robertson",
    clip_level: float | Sequence[float] = 0.98,
    noise_floor: float | None = None,
) -> HdrMerge:
    """Merge a bracket of linearised exposures into one radiance image.

    Each exposure j gives a radiance estimate ``x_ij / t_j`` where it is neither clipped nor
    lost in noise. ``method="robertson"`` combines them with the maximum-likelihood estimator
    of Robertson, Borman & Stevenson 2003 (J. Electronic Imaging 12(2), eq. 12 with unit
    weights): ``E_i = sum_j w_ij t_j x_ij / sum_j w_ij t_j^2``, which trusts long exposures
    most (their relative quantisation and noise are smallest). ``method="debevec"`` averages
    log radiance with Debevec & Malik 1997's hat weights (their eq. 6), the hat measured on
    the sRGB-encoded value.

    Clipping. A clipped pixel says only "at least 1 / t_j"; any weight it gets pulls a sun
    (clipped in all exposures but the darkest) below its radiance. OpenCV's triangle weights
    are small but not zero at code 255; with OpenCV 5.0 and the sRGB response given,
    ``cv2.createMergeDebevec`` nevertheless recovered such a sun within 0.3% on our
    synthetic 12-stop brackets, but it needs 8-bit input, a 256-entry response and cannot
    report which pixels were clipped everywhere. Here a pixel gets weight 0 in an exposure
    where any channel reaches ``clip_level`` (linear) or where the file flagged it
    saturated, so the sun comes only from the exposures that did not clip it; this works
    for 8-bit, 16-bit and float inputs alike. A pixel clipped in *every* exposure falls back to the darkest
    exposure's value (a lower bound) and is reported in ``clipped``; one below
    ``noise_floor`` in every exposure falls back to the longest exposure and is reported in
    ``underexposed``.

    Args:
        images: exposures as (H, W, 3) linear arrays in [0, 1] (response already applied,
            e.g. by :func:`bubblefit.io.images.read_image` or :func:`apply_response`).
        times: exposure time of each image, seconds (only ratios matter).
        saturated: optional (H, W) bool masks of clipped pixels, one per image.
        method: "robertson" (default) or "debevec".
        clip_level: linear value at or above which a channel counts as clipped, one for all
            exposures or one per exposure (``math.inf`` for a float file, which does not clip
            at a code value: :func:`file_clip_level`).
        noise_floor: linear value below which an exposure's pixel (robertson: all its
            channels; debevec: that channel) is not trusted. Default 1e-3 for robertson,
            whose ``t_j^2`` weights already discount short exposures, and 2e-2 for debevec,
            whose log average amplifies the quantisation error of small values (measured on
            8-bit sRGB brackets 2 stops apart: max error 16% with 1e-3, 3% with 2e-2).

    Returns:
        An :class:`HdrMerge`.
    """
    t = _checked_times(images, times, method)
    levels = np.broadcast_to(np.asarray(clip_level, dtype=np.float64), (len(images),))
    if saturated is None:
        saturated = [None] * len(images)
    if noise_floor is None:
        noise_floor = 1e-3 if method == "robertson" else 2e-2
    h, w = np.shape(images[0])[:2]
    num = np.zeros((h, w, 3))
    den = np.zeros((h, w, 1 if method == "robertson" else 3))
    used = np.zeros((h, w), dtype=np.int32)
    for j, (im, tj) in enumerate(zip(images, t)):
        x = np.clip(np.asarray(im, dtype=np.float64), 0.0, None)
        clip = _clipped(x, saturated[j], levels[j])
        ok = ~clip & (np.max(x, axis=-1) >= noise_floor)
        if method == "robertson":
            wj = ok[..., None] * 1.0
            num += wj * tj * x
            den += wj * tj * tj
        else:
            zenc = srgb_encode(x)
            hat = np.minimum(zenc, 1.0 - zenc)
            wj = ok[..., None] * hat * (x >= noise_floor)
            num += wj * (np.log(np.maximum(x, 1e-12)) - math.log(tj))
            den += wj
        used += ok
    none = used == 0
    if method == "robertson":
        rad = num / np.maximum(den, 1e-300)
    else:
        rad = np.exp(num / np.maximum(den, 1e-300))
    fallback, unclipped_any = _fallback(images, t, saturated, levels)
    rad = np.where(none[..., None] | (den <= 0), fallback, rad)
    return HdrMerge(radiance=rad, clipped=none & ~unclipped_any, underexposed=none & unclipped_any, used=used)


def _checked_times(images: Sequence[np.ndarray], times: Sequence[float], method: str) -> np.ndarray:
    """The exposure times as an array, after checking the bracket is one that can merge."""
    if len(images) == 0:
        raise InputError("no exposures to merge")
    if len(times) != len(images):
        raise InputError(f"{len(images)} exposures but {len(times)} exposure times")
    t = np.asarray(times, dtype=np.float64)
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise InputError(f"exposure times must be positive, got {list(times)}")
    shape = np.shape(images[0])
    for im in images:
        if np.shape(im) != shape:
            raise InputError(f"exposures differ in size: {shape[:2]} and {np.shape(im)[:2]}")
    if len(shape) != 3 or shape[2] != 3:
        raise InputError(f"exposures must be (H, W, 3), got {shape}")
    if method not in ("robertson", "debevec"):
        raise InputError(f"unknown merge method {method!r} (robertson, debevec)")
    return t


def _clipped(x: np.ndarray, saturated: np.ndarray | None, clip_level: float) -> np.ndarray:
    """(H, W) bool: a channel at or above ``clip_level``, or flagged saturated by the file."""
    clip = np.any(x >= clip_level, axis=-1)
    if saturated is not None:
        clip |= np.asarray(saturated, dtype=bool)
    return clip


def _fallback(images, t: np.ndarray, saturated, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radiance where no exposure was trusted: the longest exposure that is not clipped
    (the pixel is dark everywhere), else the darkest exposure (clipped everywhere, a lower
    bound). Returns it with the (H, W) mask of pixels unclipped in some exposure."""
    fallback = None
    unclipped_any = np.zeros(np.shape(images[0])[:2], dtype=bool)
    for j in np.argsort(t):
        x = np.clip(np.asarray(images[j], dtype=np.float64), 0.0, None)
        clip = _clipped(x, saturated[j], levels[j])
        est = x / t[j]
        fallback = est if fallback is None else np.where(~clip[..., None], est, fallback)
        unclipped_any |= ~clip
    return fallback, unclipped_any
