"""The uncertainty of a fit: covariance and standard errors of the reported parameters.

``cov_z = max(1, chi2_nu) c (J^T J)^-1`` in the solver's unconstrained coordinates at
the optimum (``J`` the Jacobian of the whitened robust residual, ``chi2_nu`` the reduced
chi^2 of the plain whitened residual ``(render - photo) / sigma``), propagated to the
reported parameters by the Jacobian ``G`` of the transform: ``cov = G cov_z G^T`` (the
delta method).

Two estimates widen the errors of a fit that does not explain the photo within its noise
(a model error, which the noise alone would not show); each parameter gets the larger:

- ``max(1, chi2_nu) (J^T J)^-1``, the Birge ratio (Bevington & Robinson, *Data Reduction
  and Error Analysis*, 3rd ed., sec. 8.3; Press et al., *Numerical Recipes*, 3rd ed.,
  sec. 15.6): the residual's actual scatter instead of the noise model's; it never
  narrows the errors below the noise's;
- the cluster-robust sandwich ``A^-1 (sum_b g_b g_b^T) A^-1``, ``A = J^T J``, ``g_b`` the
  gradient ``J_b^T r_b`` of block ``b`` of :data:`BLOCKS_PER_RADIUS`-th of the disc's
  radius (Liang & Zeger, Biometrika 73(1), 1986): a model error is smooth over the image,
  so neighbouring pixels are not independent evidence; the sandwich measures how much
  the misfit in each block actually pulls each parameter, so a smooth misfit that a
  parameter's Jacobian does not see does not widen its error.

The correlations are the sandwich's; ``stderr_scale`` reports the largest widening.

A calibrated camera response's own errors (:mod:`bubblefit.inverse.response_error`) are a
third term, added to the widened covariance: ``(J^T J)^-1 G_R (J^T J)^-1`` with ``G_R``
from :func:`~bubblefit.inverse.response_error.response_gram`. Its share of each reported
standard error is ``camera_stderr`` (JSON ``stderr_camera``).

Neither estimate sees a model error that a parameter absorbs: a forward model that is off
by a smooth, thickness-like amount moves the fitted thickness and leaves no residual.
Against three renderers that share no code with bubblefit (``experiments/validation``'s development cases ref_const300, ref_const620, ref_const1200, ref_const450, cyc_const500)
the constant films came out 0.1-1.1 nm from the truth, RMS 0.6 nm, while the estimates
above said 0.1-0.2 nm. That scatter is added in quadrature to the variance of every
thickness (``JudgeSettings.thickness_model_error_nm``): a Type B uncertainty, evaluated from
other information than the data at hand (JCGM 100:2008, the GUM, sec. 4.3), independent
between the thickness keys.

A refined disc has a Type B error of its own (``FitOptions.disc_model_error`` per centre
coordinate and in the radius, in radii: the renderers' discs against the fit's), and every
parameter the photo ties to the disc inherits it: with the disc moved by ``dd`` and held,
the others' optimum moves by ``S dd``, ``S = A^-1[:, disc] (A^-1[disc, disc])^-1``
(:func:`disc_type_b`). A drainage profile's top, read where the film meets the rim, gets
the most: on the development case ref_drain_lin_city_ortho_offc (split.toml; a 52 px disc
fitted on 3 x 3 block means) the disc's 0.2 % adds 1.45 nm to the top's 0.97 nm. There the
refined radius was 0.175 px (0.34 %) short and the top 4.2 nm high; with the true disc held
the top came within 1.2 nm, and with 2 x 2 rays per pixel of the solve's level (each pixel
a block mean of the photo, rendered by one ray at its centre) within 0.9 nm, the radius
0.05 px short (experiments/results/disc_type_b/drainage_top.json).

:func:`misfit` also gives the reduced chi^2 with a model-error floor: each pixel's noise
variance plus ``(model_error * photo)^2``, by which ``ok`` judges whether the photo is
explained, and splits it between the pixels the model explains and the outliers: pixels
whose chi^2 with the floor, summed over the three channels, exceeds :data:`OUTLIER_CHI2`
(a chance of 1.4e-6 per pixel for chi^2 with 3 degrees of freedom, so a photo the model
explains has essentially none). Outliers are local features the forward model lacks:
the glint of a sun or a studio lamp, which one ray per pixel point-samples while the
camera integrates it over the pixel; dust; a clipped highlight's halo. A handful of them
carries almost all of the plain reduced chi^2 (on a Blender Cycles photo of a draining
film in a sunrise map, development case cyc_drain_lin_sunrise_persp, 1 % of the pixels held 99.6 % of it with the true profile fitted):
the verdict's warning says when a misfit is local (:mod:`bubblefit.inverse._verdict`), and
``model = "auto"`` compares its models by the capped figure. The error bars and ``ok``
still use every pixel.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ._censored import censored_residual
from ._local import LocalSolution
from ._observation import Level
from ._parameters import DISC_PARAMETERS, PARAMETERS, ParameterTable, value_and_slope
from ._programs import reporter

__all__ = ["Uncertainty", "uncertainty", "Misfit", "misfit", "photo_misfit", "held_keys", "OUTLIER_CHI2", "widened",
           "widened_over_film",
           "correlation_area", "disc_type_b"]

#: A pixel whose chi^2 with the model-error floor, summed over its three channels, exceeds
#: this is an outlier: P(chi^2_3 > 30) = 1.4e-6 (module docstring).
OUTLIER_CHI2 = 30.0


@dataclass
class Uncertainty:
    """Reported values, their standard errors and covariance.

    Attributes
    ----------
    reported : dict
        Reported values (floats).
    stderr : dict
        Standard error per reported key (None where held, NaN where not constrained).
    names : tuple
        Keys of ``covariance``'s rows (the reported values that were fitted).
    covariance : np.ndarray
        Their covariance.
    misfit : Misfit
        How well the solve explains its level: reduced chi^2 (noise only, with the
        model-error floor, over the pixels that are not outliers, capped) and the
        outliers' share.
    scale : float
        The largest factor a standard error was widened by over the noise-only one.
    finite : bool
        False when ``J^T J`` is singular (some parameter the photo does not constrain).
    camera_stderr : dict or None
        The standard error each fitted reported value has from the camera response's
        stated errors alone (None: the response is taken as exact).
    """

    reported: dict
    stderr: dict
    names: tuple
    covariance: np.ndarray
    misfit: Misfit
    scale: float
    finite: bool
    camera_stderr: dict | None = None


def plain_residual(r_robust, scale: float):
    """Invert the pseudo-Huber residual of :func:`bubblefit.inverse._local.robust`:
    ``r^2 = s^2 ((1 + r_rob^2 / (2 s^2))^2 - 1)``, with the sign of ``r_rob``."""
    r_robust = np.asarray(r_robust, np.float64)
    x2 = (1.0 + r_robust**2 / (2.0 * scale**2)) ** 2 - 1.0
    return np.sign(r_robust) * scale * np.sqrt(np.maximum(x2, 0.0))


@dataclass
class Misfit:
    """How well a solve explains its level (:func:`misfit`)."""

    chi2_nu: float       # reduced chi^2 of the whitened residual (noise only)
    chi2_floor: float    # the same with each pixel's variance sigma^2 + (model_error y)^2
    chi2_inliers: float  # chi2_floor over the pixels that are not outliers
    outliers: float      # fraction of the fitted pixels that are outliers (OUTLIER_CHI2)
    chi2_capped: float   # chi2_floor with each pixel's share capped at OUTLIER_CHI2
    correlation_area: float = 1.0  # data per independent datum of the floor-whitened residual


def misfit(sol: LocalSolution, lev: Level, robust_scale: float, model_error: float, n_free: int) -> Misfit:
    """The :class:`Misfit` of ``sol`` on ``lev``: reduced chi^2 of the whitened residual,
    with each pixel's variance ``sigma^2 + (model_error * y)^2``, that split between
    outlier pixels (:data:`OUTLIER_CHI2`) and the rest, and the same with each pixel's
    share capped at :data:`OUTLIER_CHI2` (a truncated quadratic loss: no pixel moves it by
    more than an outlier's worth; ``auto`` compares models by it). The degrees of freedom
    of the inliers are their count less the free parameters, as for the whole."""
    return residual_misfit(plain_residual(sol.residual, robust_scale).reshape(lev.y.shape), lev, model_error, n_free)


def photo_misfit(lev: Level, render: np.ndarray, model_error: float, n_free: int,
                 correlation: bool = True) -> Misfit:
    """The :class:`Misfit` of ``render`` (h, w, 3) on ``lev`` with ``n_free`` fitted
    values: its residual censored where the sensor clipped at black
    (:func:`~bubblefit.inverse._censored.censored_residual`, as the solves read it) and
    whitened by each pixel's noise. On the level of block size 1 this is the misfit of the
    photo as the camera took it, each of its pixels integrated over its own footprint,
    which ``ok`` reads: a solve on a block-averaged level sees each block's noise divided
    by the block's side, so a model error below a pixel's noise (the box a pixel's
    footprint is read as) can weigh there several times what it weighs in the photo.
    ``correlation``: measure the residual's correlation area (as :func:`residual_misfit`)."""
    r = np.asarray(censored_residual(lev.y, render, np.inf, np), np.float64)
    return residual_misfit(np.where(lev.w > 0, r * lev.w, 0.0), lev, model_error, n_free, correlation)


def residual_misfit(r: np.ndarray, lev: Level, model_error: float, n_free: int, correlation: bool = True) -> Misfit:
    """The :class:`Misfit` (:func:`misfit`) of a whitened plain residual ``r`` (h, w, 3) on ``lev``
    with ``n_free`` fitted values; ``correlation`` False leaves its correlation area
    unmeasured (NaN: an FFT of twice the level's size per channel pair, 4.6 s of CPU at
    1024 x 1024, for a figure nothing reads)."""
    w = lev.w.astype(np.float64)
    used = w > 0
    dof = max(int(used.sum()) - n_free, 1)
    chi2 = float(np.sum(r[used] ** 2)) / dof
    var = 1.0 / np.where(used, w, 1.0) ** 2
    lin2 = r**2 * var  # squared residual in linear units
    per = np.where(used, lin2 / (var + (model_error * np.clip(lev.y, 0, None)) ** 2), 0.0)
    floor = float(np.sum(per)) / dof
    pix = np.any(used, axis=-1)
    chi_pix = per.sum(axis=-1)[pix]  # (P,) per fitted pixel, over its channels
    bad = chi_pix > OUTLIER_CHI2
    channels = used[pix].sum(axis=-1)
    dof_in = max(int(channels[~bad].sum()) - n_free, 1)
    inliers = float(np.sum(chi_pix[~bad])) / dof_in
    capped = float(np.sum(np.minimum(chi_pix, OUTLIER_CHI2))) / dof
    area = float("nan")
    if correlation:
        whitened = np.where(used, np.sqrt(lin2 / (var + (model_error * np.clip(lev.y, 0, None)) ** 2)) * np.sign(r), 0.0)
        area, _ = correlation_area(whitened, used)
    return Misfit(chi2, floor, inliers, float(np.mean(bad)) if bad.size else 0.0, capped, area)


def _correlations(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``(c, c, 2h, 2w)``: the mean product ``<x_a(p) x_b(p + lag)>`` over the pairs of
    used pixels ``m`` at each lag (FFT with zero padding; wrapped lags, 0 where no pair;
    the pair counts :func:`_pair_counts`)."""
    h, w, _ = x.shape
    fx = np.fft.rfft2(x, s=(2 * h, 2 * w), axes=(0, 1))
    prod = np.fft.irfft2(np.conj(fx)[..., :, None] * fx[..., None, :], s=(2 * h, 2 * w), axes=(0, 1))
    pairs = _pair_counts(m.shape, np.packbits(np.asarray(m, bool)).tobytes())
    return np.moveaxis(np.where(pairs > 0.5, prod / np.maximum(pairs, 1.0), 0.0), (2, 3), (0, 1))


#: Bytes of pair counts :func:`_pair_counts` keeps between calls (the most recent masks
#: first): a 96 px sequence frame's mask takes 2.7 MB, a 320 px photo's 29 MB, a
#: 1024 x 1024 map's 300 MB, which is counted afresh at each call rather than held.
PAIR_CACHE_BYTES = 128 * 2**20
_PAIRS: collections.OrderedDict = collections.OrderedDict()


def _pair_counts(shape: tuple, packed: bytes) -> np.ndarray:
    """``(2h, 2w, c, c)``: the number of pairs of used entries ``(a at p, b at p + lag)`` at
    each lag of the mask (``shape`` (h, w, c), its entries packed by ``np.packbits``), the
    autocorrelation of the mask by FFT with zero padding (Wiener-Khinchin), rounded to
    whole pairs. It depends on the mask alone, so the residuals of one mask (a sequence's
    frames that hold the disc, a frame's two misfits) count its pairs once: the counts of
    the latest masks are kept (read-only) up to :data:`PAIR_CACHE_BYTES` in all."""
    key = (tuple(shape), packed)
    if key in _PAIRS:
        _PAIRS.move_to_end(key)
        return _PAIRS[key]
    h, w, _ = shape
    m = np.unpackbits(np.frombuffer(packed, np.uint8), count=int(np.prod(shape))).reshape(shape).astype(np.float64)
    fm = np.fft.rfft2(m, s=(2 * h, 2 * w), axes=(0, 1))
    pairs = np.rint(np.fft.irfft2(np.conj(fm)[..., :, None] * fm[..., None, :], s=(2 * h, 2 * w), axes=(0, 1)))
    pairs.flags.writeable = False
    if pairs.nbytes <= PAIR_CACHE_BYTES:
        _PAIRS[key] = pairs
        while sum(v.nbytes for v in _PAIRS.values()) > PAIR_CACHE_BYTES:
            _PAIRS.popitem(last=False)
    return pairs


def correlation_area(field: np.ndarray, used: np.ndarray) -> tuple[float, int]:
    """``(A, K)``: the correlation area of a residual image ``field`` ``(h, w, c)`` over the
    entries ``used``, in data (pixels times channels) per independent datum, and the
    radius ``K`` (pixels) of the lags summed. A chi^2 over ``n`` correlated data carries
    the information of ``n / A`` independent ones (the effective number of independent
    observations, Bayley and Hammersley 1946), so a Delta chi^2 interval read from it is
    ``sqrt(A)`` too narrow.

    ``A = sum_lag R(lag)``, ``R = (1/c) sum_{a,b} rho_ab``: the autocorrelation (each
    channel's mean removed, normalised by the channels' variances; the cross-channel
    terms count a misfit shared by the channels) summed over lags, which is the variance
    of a mean of ``n`` data times ``n / sigma^2``; 1 for independent data. The sample
    autocorrelation of a field whose mean was removed sums to about 0 over all lags, so
    the sum is truncated: over rings of integer radius ``k`` about lag 0, up to the first
    ring whose sum is not positive (Geyer's initial positive sequence, in 2-D rings), at
    most a quarter of the shorter side.

    References
    ----------
    G. V. Bayley and J. M. Hammersley, J. R. Statist. Soc. Suppl. 8(2), 184 (1946) (the
    effective number of independent observations of an autocorrelated series);
    C. J. Geyer, Statist. Sci. 7(4), 473 (1992), sec. 3.3 (the initial positive sequence
    estimator); M. S. Bartlett, J. R. Statist. Soc. Suppl. 8(1), 27 (1946) (sampling
    variance of the sample autocorrelation).
    """
    x = np.asarray(field, np.float64)
    m = np.asarray(used, bool) & np.isfinite(x)
    if x.ndim == 2:
        x, m = x[..., None], m[..., None]
    if m.sum() < 16:
        return 1.0, 0
    mean = np.array([x[..., i][m[..., i]].mean() if m[..., i].any() else 0.0 for i in range(x.shape[-1])])
    x = np.where(m, x - mean, 0.0)
    cor = _correlations(x, m.astype(np.float64))
    c = x.shape[-1]
    var = np.array([cor[i, i, 0, 0] for i in range(c)])
    ok = var > 0
    if not ok.any():
        return 1.0, 0
    norm = np.sqrt(np.outer(np.where(ok, var, 1.0), np.where(ok, var, 1.0)))
    rho = np.where(np.outer(ok, ok)[..., None, None], cor / norm[..., None, None], 0.0)
    big = rho.sum(axis=(0, 1)) / int(ok.sum())  # R(lag), wrapped
    h2, w2 = big.shape
    dy = np.minimum(np.arange(h2), h2 - np.arange(h2))[:, None]
    dx = np.minimum(np.arange(w2), w2 - np.arange(w2))[None, :]
    ring = np.rint(np.hypot(dy, dx)).astype(int)
    area = float(big[0, 0])
    kmax = max(1, min(x.shape[:2]) // 4)
    k = 1
    while k <= kmax:
        s = float(big[ring == k].sum())
        if not s > 0:
            break
        area += s
        k += 1
    return area, k - 1


def _cluster_sandwich(jac: np.ndarray, r: np.ndarray, shape: tuple, block: int) -> np.ndarray:
    """``sum_b g_b g_b^T`` over square blocks of ``block`` pixels (``jac`` (N, p), ``r`` (N,)
    in the (h, w, 3) layout of ``shape``), with the small-sample factor ``n_b / (n_b - p)``."""
    h, w = shape[:2]
    p = jac.shape[1]
    g = (jac * r[:, None]).reshape(h, w, -1, p).sum(axis=2)  # (h, w, p) per-pixel gradients
    hb, wb = -(-h // block), -(-w // block)
    pad = np.zeros((hb * block, wb * block, p))
    pad[:h, :w] = g
    gb = pad.reshape(hb, block, wb, block, p).sum(axis=(1, 3)).reshape(-1, p)
    gb = gb[np.any(gb != 0, axis=1)]
    nb = len(gb)
    return gb.T @ gb * (nb / max(nb - p, 1)) if nb > p else np.full((p, p), np.nan)


def held_keys(table: ParameterTable) -> set:
    """Reported keys without a standard error: the held parameters (``f``, and ``r_d``,
    ``r_s`` with ``t`` held too, for a held split)."""
    held = {n for n, _ in table.held if n not in table.free}
    keys = set(held)
    if "split" in held:  # f = r_d / r_s is then fixed; r_d and r_s still move with t
        keys.add("f")
        if "t" not in table.free:
            keys |= {"r_d", "r_s"}
    return keys - set(table.free)


#: Blocks of the cluster-robust sandwich: this many per disc radius (at least 3 pixels).
BLOCKS_PER_RADIUS = 6


def _widest(cov_birge: np.ndarray, a_inv: np.ndarray, jac, r, lev: Level):
    """Each parameter's larger variance of the Birge and sandwich estimates, with the
    sandwich's correlations; and the largest widening over the noise-only errors."""
    return widened(cov_birge, a_inv, jac, r, lev.y.shape, sandwich_block(lev))


def sandwich_block(lev: Level) -> int:
    """Side in pixels of the cluster sandwich's square blocks on ``lev``: the disc's radius
    over :data:`BLOCKS_PER_RADIUS`, at least 3 (module docstring)."""
    radius = float(lev.cfg.camera.disc()[2]) if hasattr(lev.cfg.camera, "disc") else min(lev.mask.shape[:2]) / 2
    return max(3, int(round(radius / BLOCKS_PER_RADIUS)))


def widened(cov_birge: np.ndarray, a_inv: np.ndarray, jac, r, shape: tuple, block: int):
    """Each parameter's larger variance of the Birge estimate ``cov_birge`` and the cluster
    sandwich over square blocks of ``block`` pixels (``jac``, ``r`` in the (h, w, 3)
    layout of ``shape``), with the sandwich's correlations; and the largest widening over
    the noise-only errors ``a_inv`` (module docstring). A parameter the residual does not
    depend on (a zero column of ``jac``: ``a_inv`` a pseudo-inverse with a zero diagonal
    there) keeps its zero variance."""
    sand = a_inv @ _cluster_sandwich(jac, r, shape, block) @ a_inv
    d_a, d_b, d_s = np.diag(a_inv), np.diag(cov_birge), np.diag(sand)
    live = d_a > 0
    if not live.any():
        return cov_birge, 1.0
    if not (np.all(np.isfinite(sand)) and np.all(d_s[live] > 0)):
        return cov_birge, float(np.sqrt(np.max(d_b[live] / d_a[live])))
    var = np.where(live, np.maximum(d_b, d_s), 0.0)
    sd = np.sqrt(np.where(live, d_s, 1.0))
    corr = np.where(np.outer(live, live), sand / np.outer(sd, sd), 0.0)
    cov = corr * np.sqrt(np.outer(var, var))
    return cov, float(np.sqrt(np.max(var[live] / d_a[live])))


#: Blocks of the cluster sandwich across a flat film's smaller extent in pixels: 12, as the
#: bubble's :data:`BLOCKS_PER_RADIUS` per disc radius.
BLOCKS_ACROSS = 12


def widened_over_film(cov_birge: np.ndarray, a_inv: np.ndarray, jac: np.ndarray, r: np.ndarray, pixels: np.ndarray,
                      shape: tuple) -> tuple[np.ndarray, float]:
    """:func:`widened` for a fit of a flat film's pixels: ``jac`` (3P, p) and ``r`` (3P,)
    hold the three channels of the pixels at the flat indices ``pixels`` (P,) of an image
    of ``shape`` (H, W), in that order; the sandwich's blocks are the film's smaller extent
    in pixels over :data:`BLOCKS_ACROSS` (at least 3)."""
    h, w = shape[:2]
    p = jac.shape[1]
    full_j = np.zeros((h * w, 3, p))
    full_r = np.zeros((h * w, 3))
    full_j[pixels] = np.asarray(jac).reshape(-1, 3, p)
    full_r[pixels] = np.asarray(r).reshape(-1, 3)
    rows, cols = np.divmod(np.asarray(pixels), w)
    block = max(3, int(round(min(np.ptp(rows) + 1, np.ptp(cols) + 1) / BLOCKS_ACROSS)))
    return widened(cov_birge, a_inv, full_j.reshape(-1, p), full_r.ravel(), (h, w, 3), block)


def disc_type_b(a_inv: np.ndarray, free: tuple, z, model_error: float) -> np.ndarray:
    """The covariance (p, p) in the solver's coordinates ``z`` that a refined disc's Type B
    error adds: ``S B S^T``, ``B`` the disc's ``model_error^2`` (in radii, per coordinate,
    independent) in its ``z``, ``S = A^-1[:, disc] (A^-1[disc, disc])^-1`` the move of every
    parameter's optimum per move of the disc held there (for ``A = J^T J``, the Schur
    complement: ``-A_pp^-1 A_pd``, the disc's own rows the identity), so that the disc gets
    ``model_error^2`` and each other parameter what it inherits (module docstring). Zeros
    when no disc parameter is free.

    References
    ----------
    JCGM 100:2008 (GUM), sec. 5.1.2 (the law of propagation of uncertainty) and 4.3 (Type B);
    Y. Bard, *Nonlinear Parameter Estimation* (1974), sec. 7-5 (the conditional estimate of
    parameters with others held).
    """
    p = a_inv.shape[0]
    idx = [i for i, n in enumerate(free) if n in DISC_PARAMETERS]
    if not idx or not model_error > 0:
        return np.zeros((p, p))
    s = a_inv[:, idx] @ np.linalg.inv(a_inv[np.ix_(idx, idx)])
    slope = np.array([value_and_slope(free[i], float(z[i]))[1] for i in idx])
    return s @ np.diag((float(model_error) / slope) ** 2) @ s.T


def uncertainty(sol: LocalSolution, table: ParameterTable, lev: Level, robust_scale: float,
                model_error: float, thickness_model_error_nm: float = 0.0,
                response_gram: np.ndarray | None = None, disc_model_error: float = 0.0) -> Uncertainty:
    """Standard errors and covariance of the reported parameters at ``sol`` on ``lev`` (the
    delta method, widened for misfit, plus ``thickness_model_error_nm`` squared on every
    thickness's variance, plus the camera response's term from ``response_gram``, (p, p) in
    the solver's coordinates, plus a refined disc's ``disc_model_error`` carried into every
    parameter, :func:`disc_type_b`; module docstring)."""
    fit = misfit(sol, lev, robust_scale, model_error, len(table.free))
    s2 = fit.chi2_nu  # the Birge ratio's square
    scale = 1.0
    rep, rep_jac = reporter(table)
    zj = jnp.asarray(sol.z, jnp.float32)
    reported = {k: float(v) for k, v in rep(zj, sol.fixed).items()}
    stderr = {k: None for k in reported}
    finite = True
    names, cov = (), np.zeros((0, 0))
    camera = None
    if table.free:
        jac = sol.jacobian
        try:
            a_inv = np.linalg.inv(jac.T @ jac)
            cov_z = max(1.0, s2) * a_inv
            if not np.all(np.isfinite(cov_z)) or np.any(np.diag(cov_z) < 0):
                raise np.linalg.LinAlgError
            cov_z, scale = _widest(cov_z, a_inv, jac, sol.residual, lev)
            cov_z = cov_z + disc_type_b(a_inv, table.free, sol.z, disc_model_error)
        except np.linalg.LinAlgError:
            cov_z = np.full((len(table.free), len(table.free)), np.nan)
            finite = False
        cam_z = None if response_gram is None or not finite else a_inv @ response_gram @ a_inv
        if cam_z is not None:
            cov_z = cov_z + cam_z
        gmat = {k: np.asarray(g, np.float64).reshape(-1) for k, g in rep_jac(zj, sol.fixed).items()}
        drop = held_keys(table)
        names = tuple(k for k in reported if k not in drop)
        g = np.stack([gmat[k] for k in names]) if names else np.zeros((0, len(table.free)))
        cov = g @ cov_z @ g.T
        nm = [i for i, k in enumerate(names) if k in PARAMETERS and PARAMETERS[k].unit == "nm"]
        cov[nm, nm] += float(thickness_model_error_nm) ** 2
        for i, key in enumerate(names):
            var = cov[i, i]
            stderr[key] = float(math.sqrt(var)) if np.isfinite(var) and var >= 0 else float("nan")
        if cam_z is not None:
            cam_var = np.diag(g @ cam_z @ g.T)
            camera = {k: float(math.sqrt(max(v, 0.0))) for k, v in zip(names, cam_var)}
    return Uncertainty(reported, stderr, names, cov, fit, scale, finite, camera)
