"""Levenberg-Marquardt for the few-parameter models of a flat film (Newton's rings, drainage).

A dense damped Gauss-Newton loop in numpy around a compiled residual and Jacobian: a
handful of parameters against every film pixel's three channels, so each step solves a
small normal system. The damping is Marquardt's (scaled by the diagonal of ``J^T J``);
it shrinks after an accepted step and grows until a step lowers the cost.

References
----------
D. W. Marquardt, "An algorithm for least-squares estimation of nonlinear parameters",
J. SIAM 11, 431-441 (1963).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ._censored import censored_residual

__all__ = ["ModelFit", "levenberg_marquardt", "fit_colours"]


@dataclass
class ModelFit:
    """A few-parameter film model fitted to the colours: its parameters and standard errors
    (by name), the thickness and its standard error at each film pixel (nm), the model's
    colours there, the exposure, and the largest widening of an error over the noise's."""

    params: dict
    stderr: dict
    thickness: np.ndarray
    thickness_stderr: np.ndarray
    model: np.ndarray
    gain: float
    stderr_scale: float = 1.0
    #: each parameter's standard error from a calibrated response's errors alone (in
    #: ``stderr``), or None where the response is taken as exact or it is not computed
    stderr_camera: dict | None = None


def levenberg_marquardt(resid: Callable, jac: Callable, theta, iters: int = 40, rel_stop: float = 1e-9):
    """Minimise ``|resid(theta)|^2`` from ``theta``; returns ``(theta, residual, cost)``.

    Stops when no damping up to ``4^12`` times the start lowers the cost, or when a step
    lowers it by less than ``rel_stop`` of itself.
    """
    theta = jnp.asarray(theta)
    lam = 1e-3
    r = resid(theta)
    cost = float(r @ r)
    for _ in range(iters):
        J = np.asarray(jac(theta), np.float64)
        g = J.T @ np.asarray(r, np.float64)
        H = J.T @ J
        improved = small = False
        for _ in range(12):
            step = np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), -g)
            cand = theta + jnp.asarray(step, theta.dtype)
            rc = resid(cand)
            cc = float(rc @ rc)
            if cc < cost:
                theta, r, improved = cand, rc, True
                small = cost - cc < rel_stop * cost
                cost = cc
                lam = max(lam / 3.0, 1e-9)
                break
            lam *= 4.0
        if not improved or small:
            break
    return theta, r, cost


def fit_colours(model: Callable, obs, sigma: float, high, theta, iters: int = 40):
    """Fit ``model(theta)`` (P, 3) to the colours ``obs`` (P, 3): the censored residual
    (:func:`._censored.censored_residual`) whitened by the noise ``sigma``, minimised by
    :func:`levenberg_marquardt`; returns ``(theta, residual, cost, jacobian)`` at the optimum."""

    def resid(t):
        return (censored_residual(obs, model(t), high) / sigma).ravel()

    rj = jax.jit(resid)
    jac = jax.jit(jax.jacfwd(resid))
    theta, r, cost = levenberg_marquardt(rj, jac, theta, iters)
    return theta, np.asarray(r, np.float64), cost, np.asarray(jac(theta), np.float64)
