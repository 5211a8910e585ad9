"""The after/before ratio of a dark-box pair: usable pixels, a robust ratio, its interval.

Inside the bubble ``after / before = t^4`` (paper, sec. 3.3). :func:`usable_mask` keeps
the pixels whose ratio is reliable, :func:`robust_ratio` estimates the ratio over them
without the biases of per-pixel ratios, and :func:`block_bootstrap_ratio` gives its
interval by resampling pixel blocks, which stays honest when neighbouring pixels are
correlated (interpolation, demosaicing, JPEG). See ``docs/design.md`` (calibration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from .profile import fresnel_shape

__all__ = ["usable_mask", "robust_ratio", "block_bootstrap_ratio", "block_sums", "ChannelRatio", "channel_ratios",
           "with_gray", "model_error", "ratio_interval"]


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


def block_sums(ids: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-block sums of (N, C) values grouped by block id."""
    _, inv = np.unique(ids, return_inverse=True)
    out = np.zeros((inv.max() + 1, values.shape[1]))
    np.add.at(out, inv, values)
    return out


@dataclass(frozen=True)
class ChannelRatio:
    """The robust after/before ratios (:func:`channel_ratios`): (4,) for R, G, B, gray,
    and the per-block weighted sums the bootstrap resamples."""

    k: np.ndarray
    a_blocks: np.ndarray
    b_blocks: np.ndarray


def channel_ratios(after: np.ndarray, before: np.ndarray, block_ids: np.ndarray) -> ChannelRatio:
    """:func:`robust_ratio` of (N, 4) after and before values per column, with block sums."""
    k = np.empty(4)
    wa = np.empty_like(after)
    wb = np.empty_like(before)
    for c in range(4):
        k[c], wc = robust_ratio(after[:, c], before[:, c])
        wa[:, c], wb[:, c] = wc * after[:, c], wc * before[:, c]
    return ChannelRatio(k, block_sums(block_ids, wa), block_sums(block_ids, wb))


def with_gray(px: np.ndarray, gray: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """(N, 4): the R, G, B values of the selected pixels and their gray value."""
    return np.concatenate([px[sel], gray[sel][:, None]], axis=1)


def model_error(
    a_in: np.ndarray, b_in: np.ndarray, corr: np.ndarray, rho: np.ndarray, bid: np.ndarray, k_out: np.ndarray,
    t4_all: np.ndarray, model: str, n_shape: float,
) -> np.ndarray:
    """Standard deviation of ``t^4`` from the model, per channel (R, G, B, gray).

    Half the spread between two estimates that the model says should agree, in
    quadrature: the inner and the outer half of the pixels used (by radius), each with
    the chosen angular correction; and, when the rim fall-off confirms neither radial
    model (``"other"``, ``"undetermined"``), the estimate with the other model (the
    Fresnel film's angular factor, or none). A renderer or a film that follows neither
    model exactly moves t by about that much; the bootstrap alone sees only the noise.
    See ``docs/design.md`` (calibration, interval).
    """
    split = rho <= np.median(rho)
    parts = []
    for sel in (split, ~split):
        parts.append(channel_ratios(a_in[sel] / corr[sel, None], b_in[sel], bid[sel]).k / k_out)
    spread = (parts[0] - parts[1]) ** 2
    if model in ("other", "undetermined"):
        alt = np.ones_like(corr) if not np.all(corr == 1.0) else fresnel_shape(rho, n_shape)
        spread = spread + (channel_ratios(a_in / alt[:, None], b_in, bid).k / k_out - t4_all) ** 2
    return 0.5 * np.sqrt(spread)


def ratio_interval(
    inside: ChannelRatio, outside: ChannelRatio | None, t4_all: np.ndarray, n_boot: int, rng, model_sd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """95% interval of ``t^4`` per channel: block bootstrap of the inside over the outside
    ratio, its spread corrected by ``sqrt(n / (n - 1))`` for the number of blocks, each
    half widened in quadrature by ``1.96`` times the model error (:func:`model_error`)."""
    boot = block_bootstrap_ratio(inside.a_blocks, inside.b_blocks, n_boot=n_boot, rng=rng)
    if outside is not None:
        boot = boot / block_bootstrap_ratio(outside.a_blocks, outside.b_blocks, n_boot=n_boot, rng=rng)
    nbi = inside.a_blocks.shape[0]
    infl = math.sqrt(nbi / max(nbi - 1, 1))
    boot = t4_all + (boot - np.mean(boot, axis=0)) * infl
    lo4, hi4 = np.percentile(boot, [2.5, 97.5], axis=0)
    m = 1.959964 * model_sd
    return t4_all - np.hypot(t4_all - lo4, m), t4_all + np.hypot(hi4 - t4_all, m)
