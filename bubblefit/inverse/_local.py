"""The local solve: Levenberg-Marquardt (:mod:`._lm`) from a start to the nearest optimum
of the whitened, robust residual, restarted while it stops far from it (:func:`solve_local`),
and what its solution says (:class:`LocalSolution`, :func:`remaining_step`). The compiled
solve is asked of :mod:`._programs`.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ._lm import STOP_DECREMENT, gauss_newton_decrement, presses_bound
from ._observation import Level
from ._parameters import ParameterTable, value_and_slope
from ._options import SolverSettings
from ._programs import Pixels, SolvePixels, SolveSettings, solve_program, stored_solver

__all__ = ["LocalSolution", "remaining_step", "solve_local", "cost", "solution_from", "improves", "restart_moved",
           "DECREMENT_TOLERANCE", "MAX_RESTARTS"]


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


#: A solve is near its optimum when the Gauss-Newton step left from its end has a squared
#: length of at most this in the fit's covariance (half a standard error).
DECREMENT_TOLERANCE = 0.25
#: Fresh starts of a solve that stopped on rejections before that (:func:`solve_local`).
MAX_RESTARTS = 3
def remaining_step(sol: LocalSolution, chi2_nu: float, free: tuple) -> float:
    """The squared length, in the fit's covariance, of the Gauss-Newton step left from
    ``sol`` (:func:`gauss_newton_decrement` over
    ``max(1, chi2_nu)``), with the bounds of the parameters' domains as active
    constraints: a parameter within one standard error of a finite bound (``r_d`` at 0)
    whose step points at it is left out, since the step would take it beyond, and so is
    one whose step away from it reaches beyond its coordinate's linearisation while within
    one standard error: a move the data do not resolve from the bound (a roughness at
    the mirror; :func:`~bubblefit.inverse._lm.presses_bound`)."""
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
            if presses_bound(name, v, slope, step[i], se_z[i], np.sign):
                keep.remove(i)
    return gauss_newton_decrement(r, jac[:, keep]) / max(1.0, chi2_nu)


def restart_moved(start: LocalSolution, end: LocalSolution, chi2_nu: float) -> bool:
    """Whether a fresh start of a solve (:func:`solve_local`) moved it from ``start`` to
    ``end`` by more than :data:`~bubblefit.inverse._lm.STOP_DECREMENT` in squared length
    in the fit's covariance at ``end``: ``|J dz|^2 / max(1, chi2_nu)``, which bounds the
    square of every parameter's move in its own standard errors (Bard, *Nonlinear
    Parameter Estimation*, 1974, ch. 7; the length
    :func:`~bubblefit.inverse._lm.damped_step_length` gives a trial step in the solve).
    A move within it is a fifth of a standard error at most, the resolution at which the
    solve itself stops (:class:`~bubblefit.inverse._lm_solver.LevenbergMarquardt`): on
    the 320x320 constant photo of docs/speed.md the physical solve's two fresh starts
    moved every parameter by under 0.009 of its standard error in all and left the same
    step (0.647 against 0.646 in squared length, :func:`remaining_step`)."""
    dz = np.asarray(end.z, np.float64) - np.asarray(start.z, np.float64)
    if not np.any(dz):
        return False
    jac = np.asarray(end.jacobian, np.float64)
    length = float(np.sum((jac @ dz) ** 2)) / max(1.0, float(chi2_nu))
    return not length <= STOP_DECREMENT


def solution_from(table: ParameterTable, vals: dict, z, ok, maxed, steps, r, jac, fixed,
                  lev: Level | None = None, pixels: Pixels | SolvePixels | None = None) -> LocalSolution:
    """A :class:`LocalSolution` from a solver's raw outputs (numpy, float64); with ``lev``
    and ``pixels`` (one list, or a solve's blocks in parts), the residual and Jacobian over its fitted
    pixels as the level's flat residual."""
    z = np.asarray(z, np.float64)
    if lev is not None:
        r, jac = pixels.scatter(lev, r), pixels.scatter(lev, jac)
    new = dict(vals)
    for i, n in enumerate(table.free):
        new[n] = value_and_slope(n, z[i])[0]
    return LocalSolution(new, z, bool(ok), bool(maxed), int(steps), np.asarray(r, np.float64),
                         np.asarray(jac, np.float64), fixed)


def improves(restart: LocalSolution, sol: LocalSolution) -> bool:
    """Whether a fresh start from ``sol``'s end (:func:`solve_local`) is kept: it met its
    tolerances or ran out of steps (a search's solve, limited to a few steps, often does
    while still descending), with a finite cost no larger than ``sol``'s. A solve that
    failed is not kept whatever its cost: the point it reports is not one it vouches for
    (on a rotated map's photo a failed restart, whose render had diverged and whose
    residual then read as zeros before :func:`robust` took its asymptote, turned a
    converged physical fit into a failed one with chi^2 0)."""
    ended = bool(restart.successful) or bool(restart.max_steps_reached)
    return ended and bool(np.isfinite(restart.cost)) and restart.cost <= sol.cost


def solve_local(lev: Level, table: ParameterTable, solver: SolverSettings, vals: dict, env,
                max_steps: int | None = None, settings: SolveSettings = SolveSettings()) -> LocalSolution:
    """Levenberg-Marquardt from ``vals`` on ``lev``, with ``solver``'s tolerances, robust scale
    and step limit (``max_steps`` instead, when given). With ``settings.stall`` it stops after
    :data:`~bubblefit.inverse._lm.MAX_REJECTIONS` rejections and restarts while far from
    the optimum, without it runs optimistix' own stopping rule alone;
    ``settings`` also says how its Jacobian is computed and how XLA compiles its program
    (:class:`~bubblefit.inverse._programs.SolveSettings`)."""
    stall = settings.stall
    key, args, px = solve_program(lev, table, solver, vals, env, max_steps, settings)
    solve, fixed = stored_solver(*key), args[0]
    sol = solution_from(table, vals, *solve(table.unconstrained(vals), args), fixed, lev, px)
    # A solve stopped by rejections early on (a trust region still far too large) starts
    # afresh from where it stopped, with a fresh trust region, up to MAX_RESTARTS times;
    # not again after a fresh start that moved the fit by at most a fifth of a standard
    # error (:func:`restart_moved`): one that accepted no step would be repeated exactly
    # (the program is deterministic: on the 320x320 sunset photo of docs/speed.md two such
    # repeats were 14 of the physical solve's 33 steps), and one that moved less has met
    # the float32 render's resolution along the step left, which the next start meets too.
    dof = max(int(np.count_nonzero(lev.w)) - len(table.free), 1)
    steps = sol.steps
    for _ in range(MAX_RESTARTS if stall else 0):
        if not (sol.successful and remaining_step(sol, sol.cost / dof, table.free) > DECREMENT_TOLERANCE):
            break
        nxt = solution_from(table, sol.values, *solve(jnp.asarray(sol.z, jnp.float32), args), fixed, lev, px)
        steps += nxt.steps
        if not improves(nxt, sol):
            break
        moved = restart_moved(sol, nxt, nxt.cost / dof)
        sol = nxt
        if not moved:
            break
    sol.steps = steps
    return sol
