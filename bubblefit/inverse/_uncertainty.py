"""The uncertainty of a fit: covariance and standard errors of the reported parameters.

``cov_z = s^2 (J^T J)^-1`` in the solver's unconstrained coordinates at the optimum
(``J`` the Jacobian of the whitened residual, ``s^2`` the residual variance per degree of
freedom), propagated to the reported parameters by the Jacobian ``G`` of the transform:
``cov = G cov_z G^T`` (the delta method).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ._local import LocalSolution, cost, reporter
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
        Residual variance per degree of freedom (the reduced chi^2 of the whitened residual).
    finite : bool
        False when ``J^T J`` is singular (some parameter the photo does not constrain).
    """

    reported: dict
    stderr: dict
    names: tuple
    covariance: np.ndarray
    s2: float
    finite: bool


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


def uncertainty(sol: LocalSolution, table: ParameterTable, n_residuals: int) -> Uncertainty:
    """Standard errors and covariance of the reported parameters at ``sol`` (delta method).

    ``n_residuals`` is the number of data residuals (pixels x channels); the degrees of
    freedom are that less the free parameters.
    """
    dof = max(n_residuals - len(table.free), 1)
    s2 = cost(sol.residual) / dof
    rep, rep_jac = reporter(table)
    zj = jnp.asarray(sol.z, jnp.float32)
    reported = {k: float(v) for k, v in rep(zj, sol.fixed).items()}
    stderr = {k: None for k in reported}
    finite = True
    names, cov = (), np.zeros((0, 0))
    if table.free:
        jac = sol.jacobian
        try:
            cov_z = s2 * np.linalg.inv(jac.T @ jac)
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
    return Uncertainty(reported, stderr, names, cov, s2, finite)
