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
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ._censored import censored_residual

__all__ = ["ModelFit", "levenberg_marquardt", "fit_colours", "fit_order"]


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
    #: the order test with a calibrated response's errors marginalised (:func:`fit_order`),
    #: or None where the response is taken as exact
    order: object | None = None
    #: the model's own warnings (Newton's rings: a fit that lost the rings)
    warnings: list = field(default_factory=list)
    #: what the fit says that does not make it wrong (Newton's rings: where they alias)
    notes: list = field(default_factory=list)
    #: the film pixels the model was fitted to (P,), or None for all of them
    fitted: np.ndarray | None = None


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


def fit_order(fwd, model: Callable, thickness: Callable, obs, sigma: float, high, fitted: tuple, orders: dict,
              sin2, lo: float, hi: float, iters: int = 40):
    """The order test of :mod:`bubblefit.inverse.order_check` for a few-parameter model
    fitted by :func:`fit_colours`: ``fitted = (theta, residual, cost, jacobian)`` its
    optimum; ``orders`` maps the order parameters' names (:data:`~bubblefit.inverse.order_check.ORDER_PARAMETERS`)
    to their indices in ``theta``; ``thickness(theta)`` the pixels' thicknesses (nm).
    The model is fitted again from each :func:`~bubblefit.inverse.order_check.neighbouring_orders`
    start within ``[lo, hi]``, each candidate scored by its chi^2 with the response's
    errors marginalised and taken as exact (:meth:`PlanarForward.marginal_chi2
    <bubblefit.inverse.planar.PlanarForward.marginal_chi2>`), and the decision made by
    :func:`~bubblefit.inverse.order_check.compare_orders`, seen from the fit's own order.
    None for a response taken as exact."""
    from .order_check import compare_orders, neighbouring_orders

    err = fwd.response_error()
    if err is None:
        return None
    names = tuple(orders)
    theta = np.asarray(fitted[0], np.float64)
    key = lambda t: tuple(float(t[orders[n]]) for n in names)  # noqa: E731
    values = dict(zip(names, key(theta)))
    fits = [fitted]
    for start in neighbouring_orders(values, names, err.n_film, lo, hi):
        t0 = theta.copy()
        for n in names:
            t0[orders[n]] = start[n]
        fits.append(fit_colours(model, obs, sigma, high, jnp.asarray(t0, fitted[0].dtype), iters))
    scored = []
    for t, r, cost, jac in fits:
        colours = np.asarray(model(t), np.float64)
        d = np.asarray(thickness(t), np.float64)
        marg = fwd.marginal_chi2(err, jac, r, colours, d, sin2, sigma)
        plain = fwd.marginal_chi2(None, jac, r, colours, d, sin2, sigma)
        if np.isfinite(cost) and np.all(np.isfinite(marg)):
            k = key(np.asarray(t, np.float64))
            scored.append((k[0] if len(k) == 1 else k, plain[1], marg[1], float(cost)))
    check = compare_orders(scored, err.n_film, len(fitted[1]), len(theta), names)
    own = key(theta)
    return None if check is None else check.at(own[0] if len(own) == 1 else own, err.n_film)
