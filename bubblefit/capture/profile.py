"""The radial profile of the after/before ratio across the bubble's disc.

A real film transmits less at oblique incidence (Fresnel), so the ratio falls toward the
rim. :func:`fresnel_film_ratio` is that ratio through both films of the ``physical``
variant, :func:`fresnel_shape` its angular factor, :func:`n_from_t4` the index that a
centre ratio implies, and :func:`fit_disc_profile` the least-squares fit of the ratio
image around the disc that refines the circle and measures how much of the Fresnel
fall-off the photo shows. See ``docs/design.md`` (calibration).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from ..optics.film import incoherent_reflectance

__all__ = ["DEFAULT_N", "fresnel_film_ratio", "fresnel_shape", "n_from_t4", "fit_disc_profile"]

#: Refractive index used for the shape of the angular fall-off before n is known.
DEFAULT_N = 1.4


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
    def f(n):
        return float(fresnel_film_ratio(np.array(0.0), n)) - t4

    if not (f(hi) < 0 < f(lo)):
        return float("nan")
    from scipy.optimize import brentq  # imported where used: a fit never needs it (0.17 s)

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
    cx0, cy0, r0 = circle
    h, w = before.shape
    yy, xx = np.mgrid[0:h, 0:w]
    d0 = np.hypot(xx - cx0, yy - cy0)
    ys, xs = np.nonzero(usable & (d0 < band * r0 + 2))
    if ys.size > max_pixels:
        pick = np.random.default_rng(seed).choice(ys.size, max_pixels, replace=False)
        ys, xs = ys[pick], xs[pick]
    if ys.size < 20:  # nothing to fit (e.g. a given circle over the black box)
        return _no_profile(circle, ys.size)
    b = before[ys, xs]
    q = after[ys, xs] / b
    wgt = b / np.median(b)
    grid = np.linspace(0.0, 1.0, 2001)
    table = fresnel_shape(grid, n)
    inside0 = d0[ys, xs] < 0.8 * r0
    outside0 = d0[ys, xs] > 1.1 * r0 + 1
    L_in0 = float(np.median(q[inside0])) if inside0.any() else 0.9
    L_out0 = float(np.median(q[outside0])) if outside0.any() else 1.0

    def resid(p, width):
        cx, cy, r = (cx0, cy0, r0) if fix_geometry else p[:3]
        L_in, L_out, beta = p[-3:]
        d = np.hypot(xs - cx, ys - cy)
        cov = _logistic((r - d) / width)
        s = np.interp(np.minimum(d / r, 1.0), grid, table)
        return (q - (L_out * (1.0 - cov) + cov * L_in * (1.0 - beta * (1.0 - s)))) * wgt

    p0 = [L_in0, L_out0, 0.5] if fix_geometry else [cx0, cy0, r0, L_in0, L_out0, 0.5]
    sol = _solve_profile(resid, p0, r0, fix_geometry)
    res = resid(sol.x, _EDGE)
    sigma = 1.4826 * float(np.median(np.abs(res - np.median(res)))) or 1e-12
    vif = _block_vif(res, xs, ys, w, block)
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * sigma**2 * vif
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        se = np.full(len(sol.x), np.inf)
    names = _PROFILE_NAMES[3:] if fix_geometry else _PROFILE_NAMES
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


#: Parameters of the radial profile, in the order of the solver's vector.
_PROFILE_NAMES = ("cx", "cy", "r", "L_in", "L_out", "beta")
#: Width of the logistic edge of the final fit, pixels (about one pixel, 10% to 90%).
_EDGE = 0.45


def _no_profile(circle: tuple[float, float, float], n_pixels: int) -> dict[str, Any]:
    """The result of :func:`fit_disc_profile` when too few pixels can be fitted."""
    out: dict[str, Any] = dict(zip(_PROFILE_NAMES, [*(float(v) for v in circle), float("nan"), float("nan"), 0.0]))
    out.update({f"{k}_stderr": float("inf") for k in _PROFILE_NAMES})
    out.update(n_pixels=int(n_pixels), n_rim_pixels=0, noise=float("nan"), vif=1.0, success=False)
    return out


def _solve_profile(resid, p0: list[float], r0: float, fix_geometry: bool):
    """Robust trust-region least squares of ``resid(p, width)``, coarse to fine.

    With a free circle: nine starts around the initial centre on a blurred edge (a wide
    basin of attraction), the best one refined on ever sharper edges; all starts see the
    same pixels, so their costs compare. Soft-L1 loss scaled to the residuals' MAD.
    """
    from scipy.optimize import least_squares

    def solve(p_start, width):
        r_init = resid(p_start, width)
        scale = 1.4826 * float(np.median(np.abs(r_init - np.median(r_init)))) or 1e-3
        return least_squares(lambda p: resid(p, width), p_start, loss="soft_l1", f_scale=3.0 * scale,
                             x_scale="jac", method="trf", tr_solver="lsmr")

    if fix_geometry:
        return solve(p0, _EDGE)
    best = None
    for ox, oy in [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)]:
        start = list(p0)
        start[0] += 0.25 * r0 * ox
        start[1] += 0.25 * r0 * oy
        sol = solve(start, 3.0)
        cost = float(np.sum(resid(sol.x, 3.0) ** 2))
        if best is None or cost < best[0]:
            best = (cost, sol.x)
    p0 = best[1]
    for width in (1.2, _EDGE):
        sol = solve(p0, width)
        p0 = sol.x
    return sol


def _block_vif(res: np.ndarray, xs: np.ndarray, ys: np.ndarray, w: int, block: int) -> float:
    """Variance inflation of correlated neighbours: variance of block means times block size
    over the pixel variance, clipped to [1, 25] (1 when too few full blocks)."""
    bid = (ys // block) * (w // block + 1) + xs // block
    _, inv, counts = np.unique(bid, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=res)
    full = counts >= block * block // 2
    if full.sum() <= 10:
        return 1.0
    bm = sums[full] / counts[full]
    vif = float(np.var(bm) * np.mean(counts[full]) / max(np.var(res), 1e-300))
    return float(np.clip(vif, 1.0, 25.0))
