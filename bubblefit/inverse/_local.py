"""The local solve: Levenberg-Marquardt on the whitened, robust residual.

LM rather than Gauss-Newton because the starting points from the global search are only
close, and its trust-region damping keeps steps inside one colour fringe of the
thickness; rather than Dogleg because with few parameters its damped solve is as cheap
and it needs no separate trust-region geometry. The Jacobian is forward-mode (few
parameters, many residuals). Compiled solvers are cached per static configuration
(camera, effects, parameter table), so a sequence of photos with the same size and disc
compiles once.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ._observation import Level
from ._parameters import PARAMETERS, ParameterTable, forward, value_and_slope
from ..model.render import RenderConfig, render

__all__ = ["LocalSolution", "LevenbergMarquardt", "gauss_newton_decrement", "remaining_step", "robust", "solver",
           "batched_solver", "reporter", "solve_local", "cost", "solution_from"]


def robust(r, scale):
    """Pseudo-Huber residual ``sign(r) sqrt(2 rho(r))``, written to stay smooth at 0.

    References
    ----------
    Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., appendix A6.8 (pseudo-Huber cost).
    """
    x2 = (r / scale) ** 2
    return r * jnp.sqrt(2.0 / (jnp.sqrt(1.0 + x2) + 1.0))


@dataclass
class LocalSolution:
    """One Levenberg-Marquardt solve.

    Attributes
    ----------
    values : dict
        All parameter values (floats) at the solution.
    z : np.ndarray
        Unconstrained coordinates of the free parameters.
    successful : bool
        The solver met its tolerances.
    max_steps_reached : bool
        It stopped at its step limit.
    steps : int
        Steps taken.
    residual : np.ndarray
        Whitened robust residual vector at ``z``.
    jacobian : np.ndarray
        Its Jacobian with respect to ``z``.
    fixed : dict
        The held values (jnp) the solve ran with.
    """

    values: dict
    z: np.ndarray
    successful: bool
    max_steps_reached: bool
    steps: int
    residual: np.ndarray
    jacobian: np.ndarray
    fixed: dict

    @property
    def cost(self) -> float:
        return cost(self.residual)


def cost(r) -> float:
    """Sum of squares of a residual vector."""
    return float(np.sum(r * r))


#: Consecutive rejected steps after which the solve stops at its last accepted point
#: (:class:`LevenbergMarquardt`).
MAX_REJECTIONS = 6
#: A solve is near its optimum when the Gauss-Newton step left from its end has a squared
#: length of at most this in the fit's covariance (half a standard error).
DECREMENT_TOLERANCE = 0.25
#: Fresh starts of a solve that stopped on rejections before that (:func:`solve_local`).
MAX_RESTARTS = 3


def _quiet(**kwargs):
    return None


class LevenbergMarquardt(optx.AbstractGaussNewton):
    """optimistix' Levenberg-Marquardt (damped Newton descent, classical trust region,
    QR solve, Cauchy termination) that also stops after ``max_rejections`` rejected
    steps in a row (None: optimistix' own rule alone).

    Near the optimum a float32 render changes its loss by more than the quadratic model
    predicts for tiny steps, so every proposal is rejected and the trust region shrinks
    by 4 per step until the Cauchy test is met: 20-35 steps of about a second each on
    the photos of ``experiments/validation``, none of which moves the fit. After six
    rejections (a region 4096 times smaller) the solve stops at its last accepted
    point; how far that point is from the optimum is measured afterwards from its
    Gauss-Newton decrement (:func:`remaining_step`), which decides a restart
    (:func:`solve_local`) and a note in the fit's message.
    """

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: optx.DampedNewtonDescent = optx.DampedNewtonDescent(linear_solver=lx.QR())
    search: optx.ClassicalTrustRegion = optx.ClassicalTrustRegion()
    verbose: Callable = _quiet
    max_rejections: int | None = MAX_REJECTIONS

    def terminate(self, fn, y, args, options, state, tags):
        if self.max_rejections is None:
            return state.terminate, state.result
        stalled = state.num_steps_since_acceptance >= self.max_rejections
        return state.terminate | stalled, state.result


def gauss_newton_decrement(r, jac) -> float:
    """``r^T J (J^T J)^-1 J^T r``: how much an undamped Gauss-Newton step from here would
    lower the sum of squares ``r^T r`` (the whitened chi^2), by the local quadratic model.
    Zero at an optimum; in units of chi^2, so ``decrement / max(1, chi2_nu)`` is the
    squared Mahalanobis length of the remaining step in the fit's own covariance."""
    r = np.asarray(r, np.float64)
    jac = np.asarray(jac, np.float64)
    if jac.size == 0:
        return 0.0
    g = jac.T @ r
    try:
        return float(g @ np.linalg.solve(jac.T @ jac, g))
    except np.linalg.LinAlgError:
        return float("nan")


def remaining_step(sol: LocalSolution, chi2_nu: float, free: tuple) -> float:
    """The squared length, in the fit's covariance, of the Gauss-Newton step left from
    ``sol`` (:func:`gauss_newton_decrement` over
    ``max(1, chi2_nu)``), with the bounds of the parameters' domains as active
    constraints: a parameter within one standard error of a finite bound (``r_d`` at 0)
    whose step points at it is left out, since the step would take it beyond."""
    jac, r = sol.jacobian, sol.residual
    keep = list(range(jac.shape[1]))
    if free and jac.size:
        try:
            a_inv = np.linalg.inv(jac.T @ jac)
        except np.linalg.LinAlgError:
            return float("nan")
        step = -a_inv @ (jac.T @ r)
        se_z = np.sqrt(np.abs(np.diag(a_inv)) * max(1.0, chi2_nu))
        for i, name in enumerate(free):
            v, slope = value_and_slope(name, sol.z[i])
            for b in PARAMETERS[name].bounds:
                toward = np.sign(slope * step[i]) == np.sign(b - v)
                if math.isfinite(b) and toward and abs(v - b) <= abs(slope) * se_z[i]:
                    keep.remove(i)
                    break
    return gauss_newton_decrement(r, jac[:, keep]) / max(1.0, chi2_nu)


@functools.lru_cache(maxsize=64)
def solver(cfg: RenderConfig, table: ParameterTable, robust_scale: float, max_steps: int, rtol: float, atol: float,
           max_rejections: int | None = MAX_REJECTIONS):
    """Jitted ``solve(z0, args) -> (z, ok, maxed, steps, residual, J)`` and ``resid``.

    ``args = (fixed, env, background, photo, weights)``; the residual is
    ``robust((render - photo) * weights)`` flattened.
    """

    def resid(z, args):
        fixed, env, bg, y, w = args
        img = render(table.render_params(table.values(z, fixed)), cfg, env, bg)
        return robust((img - y) * w, robust_scale).reshape(-1)

    lm = LevenbergMarquardt(rtol=rtol, atol=atol, max_rejections=max_rejections)

    @jax.jit
    def solve(z0, args):
        sol = optx.least_squares(resid, lm, z0, args, max_steps=max_steps, throw=False)
        z = sol.value
        r = resid(z, args)
        jac = jax.jacfwd(resid)(z, args)
        maxed = (sol.result == optx.RESULTS.max_steps_reached) | (
            sol.result == optx.RESULTS.nonlinear_max_steps_reached)
        return (z, sol.result == optx.RESULTS.successful, maxed, sol.stats["num_steps"], r, jac)

    return solve, jax.jit(resid)


@functools.lru_cache(maxsize=16)
def batched_solver(*key):
    """:func:`solver`'s ``solve`` vmapped over frames: ``z0``, ``y`` and ``w`` carry a
    leading frame axis; the fixed values, the map and the background are shared."""
    solve, _ = solver(*key)
    return jax.jit(jax.vmap(solve, in_axes=(0, (None, None, None, 0, 0))))


@functools.lru_cache(maxsize=64)
def reporter(table: ParameterTable):
    """Jitted ``(z, fixed) -> reported values`` and its Jacobian (for the delta method)."""
    def rep(z, fixed):
        return table.reported(table.values(z, fixed))

    return jax.jit(rep), jax.jit(jax.jacfwd(rep))


def solution_from(table: ParameterTable, vals: dict, z, ok, maxed, steps, r, jac, fixed) -> LocalSolution:
    """A :class:`LocalSolution` from a solver's raw outputs (numpy, float64)."""
    z = np.asarray(z, np.float64)
    new = dict(vals)
    for i, n in enumerate(table.free):
        new[n] = float(forward(n, z[i]))
    return LocalSolution(new, z, bool(ok), bool(maxed), int(steps), np.asarray(r, np.float64),
                         np.asarray(jac, np.float64), fixed)


def solve_local(lev: Level, table: ParameterTable, opts, vals: dict, env, max_steps=None,
                stall: bool = True) -> LocalSolution:
    """Levenberg-Marquardt from ``vals`` on ``lev`` (``opts``: a ``FitOptions``); with
    ``stall`` it stops after :data:`MAX_REJECTIONS` rejections and restarts while far from
    the optimum, without it runs optimistix' own stopping rule alone (warm starts)."""
    solve, _ = solver(lev.cfg, table, float(opts.robust_scale), int(max_steps or opts.max_steps),
                      float(opts.rtol), float(opts.atol), MAX_REJECTIONS if stall else None)
    fixed = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k not in table.free}
    args = (fixed, env, None if lev.bg is None else jnp.asarray(lev.bg), jnp.asarray(lev.y), jnp.asarray(lev.w))
    sol = solution_from(table, vals, *solve(table.unconstrained(vals), args), fixed)
    # A solve stopped by rejections early on (a trust region still far too large) starts
    # afresh from where it stopped, with a fresh trust region, up to MAX_RESTARTS times.
    dof = max(int(np.count_nonzero(lev.w)) - len(table.free), 1)
    steps = sol.steps
    for _ in range(MAX_RESTARTS if stall else 0):
        if not (sol.successful and remaining_step(sol, sol.cost / dof, table.free) > DECREMENT_TOLERANCE):
            break
        nxt = solution_from(table, sol.values, *solve(jnp.asarray(sol.z, jnp.float32), args), fixed)
        steps += nxt.steps
        if not np.isfinite(nxt.cost) or nxt.cost > sol.cost:
            break
        sol = nxt
    sol.steps = steps
    return sol
