"""The uncertainty of a fit: covariance and standard errors of the reported parameters.

``cov_z = max(1, chi2_nu) c (J^T J)^-1`` in the solver's unconstrained coordinates at
the optimum (``J`` the Jacobian of the whitened robust residual, ``chi2_nu`` the reduced
chi^2 of the plain whitened residual ``(render - photo) / sigma``), propagated to the
reported parameters by the Jacobian ``G`` of the transform: ``cov = G cov_z G^T`` (the
delta method).

Two factors widen the errors of a fit that does not explain the photo within its noise
(a model error, which the noise alone would not show), and never narrow them below the
noise's:

- ``max(1, chi2_nu)``, the Birge ratio squared (Bevington & Robinson, *Data Reduction
  and Error Analysis*, 3rd ed., sec. 8.3; Press et al., *Numerical Recipes*, 3rd ed.,
  sec. 15.6): the residual's actual scatter instead of the noise model's;
- ``c = prod over x, y of (1 + rho) / (1 - rho)``, ``rho`` the residual's correlation
  between neighbouring pixels (clipped to [0, 0.95]): a model error is smooth over the
  image, so neighbouring pixels do not bring independent information; ``c`` is the
  variance inflation of a mean of AR(1)-correlated samples in each direction, i.e. the
  pixels per independent sample (Bayley & Hammersley, J. R. Stat. Soc. Suppl. 8(2),
  1946, "effective number of independent observations"). Pure noise gives ``c = 1``.

:func:`misfit` also gives the reduced chi^2 with a model-error floor: each pixel's noise
variance plus ``(model_error * photo)^2``, by which ``ok`` judges whether the photo is
explained.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ._local import LocalSolution, reporter
from ._observation import Level
from ._parameters import ParameterTable

__all__ = ["Uncertainty", "uncertainty"]


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
    s2 : float
        The reduced chi^2 of the whitened residual (noise only).
    chi2_floor : float
        The reduced chi^2 with the model-error floor.
    finite : bool
        False when ``J^T J`` is singular (some parameter the photo does not constrain).
    """

    reported: dict
    stderr: dict
    names: tuple
    covariance: np.ndarray
    s2: float
    chi2_floor: float
    inflation: float
    finite: bool


def plain_residual(r_robust, scale: float):
    """Invert the pseudo-Huber residual of :func:`bubblefit.inverse._local.robust`:
    ``r^2 = s^2 ((1 + r_rob^2 / (2 s^2))^2 - 1)``, with the sign of ``r_rob``."""
    r_robust = np.asarray(r_robust, np.float64)
    x2 = (1.0 + r_robust**2 / (2.0 * scale**2)) ** 2 - 1.0
    return np.sign(r_robust) * scale * np.sqrt(np.maximum(x2, 0.0))


def misfit(sol: LocalSolution, lev: Level, robust_scale: float, model_error: float, n_free: int):
    """``(chi2_nu, chi2_floor, c)`` of ``sol`` on ``lev``: the reduced chi^2 of the whitened
    residual, the same with each pixel's variance ``sigma^2 + (model_error * y)^2``, and
    the correlation inflation ``c`` of the module docstring."""
    r = plain_residual(sol.residual, robust_scale).reshape(lev.y.shape)
    w = lev.w.astype(np.float64)
    used = w > 0
    dof = max(int(used.sum()) - n_free, 1)
    chi2 = float(np.sum(r[used] ** 2)) / dof
    var = 1.0 / w[used] ** 2
    lin2 = r[used] ** 2 * var  # squared residual in linear units
    floor = float(np.sum(lin2 / (var + (model_error * np.clip(lev.y[used], 0, None)) ** 2))) / dof
    return chi2, floor, _correlation_inflation(r, used)


def _correlation_inflation(r: np.ndarray, used: np.ndarray) -> float:
    """``prod (1 + rho) / (1 - rho)`` over the two image axes (module docstring)."""
    if r.ndim != 3:
        return 1.0
    z = np.where(used, r, 0.0).mean(axis=-1)
    u = used.all(axis=-1)
    out = 1.0
    for ax in (0, 1):
        a = np.take(z, range(z.shape[ax] - 1), axis=ax)
        b = np.take(z, range(1, z.shape[ax]), axis=ax)
        both = np.take(u, range(u.shape[ax] - 1), axis=ax) & np.take(u, range(1, u.shape[ax]), axis=ax)
        if both.sum() < 20:
            continue
        a, b = a[both] - a[both].mean(), b[both] - b[both].mean()
        rho = float(np.sum(a * b) / max(math.sqrt(float(np.sum(a * a) * np.sum(b * b))), 1e-30))
        rho = min(max(rho, 0.0), 0.95)
        out *= (1.0 + rho) / (1.0 - rho)
    return out


def _held_keys(table: ParameterTable) -> set:
    """Reported keys without a standard error: the held parameters (``f``, and ``r_d``,
    ``r_s`` with ``t`` held too, for a held split)."""
    held = {n for n, _ in table.held if n not in table.free}
    keys = set(held)
    if "split" in held:  # f = r_d / r_s is then fixed; r_d and r_s still move with t
        keys.add("f")
        if "t" not in table.free:
            keys |= {"r_d", "r_s"}
    return keys


def uncertainty(sol: LocalSolution, table: ParameterTable, lev: Level, robust_scale: float,
                model_error: float) -> Uncertainty:
    """Standard errors and covariance of the reported parameters at ``sol`` on ``lev`` (the
    delta method, widened by ``max(1, chi2_nu)``; module docstring)."""
    s2, chi2_floor, inflation = misfit(sol, lev, robust_scale, model_error, len(table.free))
    rep, rep_jac = reporter(table)
    zj = jnp.asarray(sol.z, jnp.float32)
    reported = {k: float(v) for k, v in rep(zj, sol.fixed).items()}
    stderr = {k: None for k in reported}
    finite = True
    names, cov = (), np.zeros((0, 0))
    if table.free:
        jac = sol.jacobian
        try:
            cov_z = max(1.0, s2) * inflation * np.linalg.inv(jac.T @ jac)
            if not np.all(np.isfinite(cov_z)) or np.any(np.diag(cov_z) < 0):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            cov_z = np.full((len(table.free), len(table.free)), np.nan)
            finite = False
        gmat = {k: np.asarray(g, np.float64).reshape(-1) for k, g in rep_jac(zj, sol.fixed).items()}
        drop = _held_keys(table)
        names = tuple(k for k in reported if k not in drop)
        g = np.stack([gmat[k] for k in names]) if names else np.zeros((0, len(table.free)))
        cov = g @ cov_z @ g.T
        for i, key in enumerate(names):
            var = cov[i, i]
            stderr[key] = float(math.sqrt(var)) if np.isfinite(var) and var >= 0 else float("nan")
    return Uncertainty(reported, stderr, names, cov, s2, chi2_floor, inflation, finite)
