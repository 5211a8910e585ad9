"""Levenberg-Marquardt's trust-region solver for the fit's local solves, on optimistix.

The solver classes (:class:`LevenbergMarquardt`, its damped Newton step
:class:`DenseDampedNewtonDescent`) subclass optimistix' own, so this module imports
optimistix, equinox and lineax (about 0.25 s of CPU together): a solve's program that the
executable store holds runs without tracing them, so only a compile imports this module
(:func:`bubblefit.inverse._programs.solver`). The numerics the solver and the fit share
(the robust residual, the Jacobians by columns, the convergence measures) are in
:mod:`._lm`, which names these classes too.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from ._lm import MAX_REJECTIONS, STOP_DECREMENT, damped_step_length, scaled_decrement
from ._parameters import plausible_box

__all__ = ["DenseDampedNewtonDescent", "LevenbergMarquardt"]


def _quiet(**kwargs):
    return None


class _DenseState(eqx.Module):
    """The accepted point's Jacobian as ``J = Q R``: ``R`` (n, n) and ``Q^T r`` (n,)."""

    r_factor: Float[Array, "n n"]
    qt_residual: Float[Array, " n"]


class DenseDampedNewtonDescent(optx.AbstractDescent):
    """The damped Newton (Levenberg-Marquardt) step ``-(J^T J + lambda I)^-1 J^T r`` with
    ``lambda = 1 / step_size`` (optimistix' ``DampedNewtonDescent``), from a Jacobian
    materialised and QR-factored once per accepted point.

    optimistix' own descent hands lineax a matrix-free operator, which its QR solve
    materialises again at every trial step size, one forward-mode tangent per parameter
    through the whole render: a rejected step cost a Jacobian. Here :meth:`query` (called
    at accepted points only) forms ``J = Q R`` and every :meth:`step` solves the small
    ``[R; sqrt(lambda) I] delta = [Q^T r; 0]`` (2n x n), the same least-squares problem as
    ``[J; sqrt(lambda) I] delta = [r; 0]`` since ``Q``'s columns are orthonormal: the
    factor-once, damp-many scheme of MINPACK's ``lmpar``/``qrsolv``.

    References
    ----------
    J. J. Moré, "The Levenberg-Marquardt algorithm: implementation and theory",
    *Numerical Analysis*, Lecture Notes in Mathematics 630 (1978), 105-116.
    """

    def init(self, y, f_info_struct) -> _DenseState:
        n = jnp.size(y)
        return _DenseState(jnp.zeros((n, n), jnp.result_type(y)), jnp.zeros((n,), jnp.result_type(y)))

    def query(self, y, f_info, state) -> _DenseState:
        jac = f_info.jac.as_matrix()
        q, r_factor = jnp.linalg.qr(jac)
        return _DenseState(r_factor, q.T @ jnp.ravel(f_info.residual))

    def step(self, step_size, state: _DenseState):
        n = state.qt_residual.shape[0]
        dtype = state.qt_residual.dtype
        # step_size -> 0 is infinite damping, the zero step (optimistix' convention)
        pred = step_size > jnp.finfo(dtype).eps
        lam = 1.0 / jnp.where(pred, step_size, 1.0)
        a = jnp.concatenate([state.r_factor, jnp.sqrt(lam) * jnp.eye(n, dtype=dtype)])
        b = jnp.concatenate([state.qt_residual, jnp.zeros((n,), dtype)])
        q2, r2 = jnp.linalg.qr(a)
        delta = jax.scipy.linalg.solve_triangular(r2, q2.T @ b, lower=False)
        ok = jnp.all(jnp.isfinite(delta))
        step = jnp.where(pred & ok, -delta, 0.0)
        return step, optx.RESULTS.where(ok | ~pred, optx.RESULTS.successful, optx.RESULTS.singular)


class _LMState(eqx.Module):
    """:class:`LevenbergMarquardt`'s state (the fields of optimistix' Gauss-Newton state)."""

    first_step: Bool[Array, ""]
    y_eval: Array
    search_state: Any
    f_info: optx.FunctionInfo.ResidualJac
    descent_state: _DenseState
    terminate: Bool[Array, ""]
    result: optx.RESULTS
    num_steps: Int[Array, ""]
    num_accepted_steps: Int[Array, ""]
    num_steps_since_acceptance: Int[Array, ""]


def _cauchy(rtol, atol, norm, y, y_diff, f, f_diff):
    """optimistix' Cauchy test: small changes in both ``y`` and ``f``, relative to
    ``atol + rtol |.|``."""
    small = lambda d, x: norm(jnp.abs(d) / (atol + rtol * jnp.abs(x))) < 1
    return small(y_diff, y) & small(f_diff, f)


class LevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt for a flat parameter vector: optimistix' classical trust region
    (``optx.ClassicalTrustRegion``) and Cauchy termination, with the damped Newton step of
    :class:`DenseDampedNewtonDescent` and a dense forward-mode Jacobian (``jax.jacfwd``, or
    ``jacobian`` when given: the fit's solves pass :func:`column_jacobian`) evaluated at
    accepted points only.

    optimistix' own ``LevenbergMarquardt`` linearises (``jax.linearize``) at every trial
    point and materialises the linearisation for its QR solve at every step: on the
    physical model's 80x80 fit, 0.66 s per rejected and 2.0 s per accepted step, against
    0.13 s for a render and 1.3 s for ``jax.jacfwd`` (``experiments/bench_fit.py``
    --profile-solver). Here a trial point costs one render and an accepted one a
    Jacobian; the iterates are the same.

    Every trial point is projected onto the box of the free parameters' plausible ranges
    (:meth:`project`): a logistic or log coordinate stepped far past that range saturates,
    its Jacobian column vanishes, and the solve can neither return nor resolve it (the
    demo's drainage fit took the split from 0.994 to 1 - 1e-7 in one near-Gauss-Newton
    step of its thickness search and kept it there).

    Near the optimum a float32 render changes its loss by more than the quadratic model
    predicts for tiny steps, so every proposal is rejected and the trust region shrinks
    by 4 per step until the Cauchy test is met: 20-35 steps on the photos of
    ``experiments/validation``, none of which moves the fit. Two rules stop it earlier,
    at the last accepted point:

    - its Gauss-Newton step left is under ``decrement_tolerance`` in the fit's own
      covariance (:func:`scaled_decrement`, default :data:`STOP_DECREMENT`; None: off),
      a statistical convergence test: the optimum is within a fifth of a standard error,
      with the parameters' bounds (``free``) as active constraints;
    - ``max_rejections`` rejections in a row once the solve has left its start (a region
      4096 times smaller after six; None: off; before the first move the trust region is
      still shrinking from the undamped step to the start's scale: from a camera gain 2.5
      times off, on a grey film, the first step accepted was the ninth, at a damping of
      6.6e4 against ``J^T J`` = 5.0e4, and six rejections had stopped the solve at its
      start), or, sooner, a rejection after which the next trial step is at most
      ``step_tolerance`` (default :data:`STOP_DECREMENT`) long in the same covariance (:func:`damped_step_length`):
      the trust region no longer lets any parameter move by a fifth of its standard
      error, so the rejections that would follow until ``max_rejections`` cannot move
      the fit by more (on the 320x320 sunset photo of ``docs/speed.md``, physical model,
      the six trial steps after the last accepted point were all rejected, each 0.016 long:
      the decrement left, 0.19, lay along the near-null directions of the roughness and
      r_d at their bounds, which any damping removes). Both
      are rules of the solves that stop on rejections (``max_rejections`` not None). How
      far that point is from the optimum is then measured from its decrement
      (:func:`remaining_step`), which decides a restart (:func:`solve_local`) and a note
      in the fit's message.

    References
    ----------
    J. J. Moré, "The Levenberg-Marquardt algorithm: implementation and theory",
    *Numerical Analysis*, Lecture Notes in Mathematics 630 (1978), 105-116.
    """

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: DenseDampedNewtonDescent = DenseDampedNewtonDescent()
    search: optx.ClassicalTrustRegion = optx.ClassicalTrustRegion()
    verbose: Callable = _quiet
    max_rejections: int | None = MAX_REJECTIONS
    decrement_tolerance: float | None = STOP_DECREMENT
    #: After a rejection, the next trial step's squared length in the fit's covariance
    #: (:func:`damped_step_length`) at or below which the solve stops (None: off; only
    #: with ``max_rejections``).
    step_tolerance: float | None = STOP_DECREMENT
    #: The free parameters' names (:data:`~bubblefit.inverse._parameters.PARAMETERS`), in
    #: ``y``'s order: their bounds constrain the decrement (:func:`scaled_decrement`).
    free: tuple = ()
    #: ``(y, args) -> J`` of the residual ``fn`` (None: ``jax.jacfwd`` of ``fn``); the
    #: solves pass :func:`column_jacobian` of their residual.
    jacobian: Callable | None = None

    def project(self, y):
        """``y`` projected onto the box of the free parameters' plausible ranges
        (:func:`~bubblefit.inverse._parameters.plausible_box`; no box without ``free``):
        every trial point, the start's included, so that no logistic or log coordinate
        saturates where its slope vanishes. The trust region's ratio is taken with the
        projected step (optimistix' ``ClassicalTrustRegion`` reads ``y_eval - y``), the
        projected Levenberg-Marquardt method of Kanzow, Yamashita & Fukushima (2004)."""
        if not self.free:
            return y
        lo, hi = plausible_box(self.free)
        return jnp.clip(y, jnp.asarray(lo, y.dtype), jnp.asarray(hi, y.dtype))

    def init(self, fn, y, args, options, f_struct, aux_struct, tags) -> _LMState:
        f_info = optx.FunctionInfo.ResidualJac(
            jnp.zeros(f_struct.shape, f_struct.dtype),
            lx.MatrixLinearOperator(jnp.zeros((f_struct.size, jnp.size(y)), f_struct.dtype)))
        return _LMState(first_step=jnp.array(True), y_eval=self.project(y), search_state=self.search.init(y, f_info),
                        f_info=f_info, descent_state=self.descent.init(y, f_info), terminate=jnp.array(False),
                        result=optx.RESULTS.successful, num_steps=jnp.array(0), num_accepted_steps=jnp.array(0),
                        num_steps_since_acceptance=jnp.array(0))

    def step(self, fn, y, args, options, state: _LMState, tags):
        residual, aux = fn(state.y_eval, args)
        step_size, accept, search_result, search_state = self.search.step(
            state.first_step, y, state.y_eval, state.f_info, optx.FunctionInfo.Residual(residual),
            state.search_state)

        def accepted():
            if self.jacobian is None:
                jac = jax.jacfwd(lambda z: fn(z, args)[0])(state.y_eval)
            else:
                jac = self.jacobian(state.y_eval, args)
            f_info = optx.FunctionInfo.ResidualJac(residual, lx.MatrixLinearOperator(jac))
            dense = self.descent.query(state.y_eval, f_info, state.descent_state)
            done = _cauchy(self.rtol, self.atol, self.norm, state.y_eval, state.y_eval - y, residual,
                           residual - state.f_info.residual)
            return state.y_eval, f_info, dense, done

        def rejected():
            return y, state.f_info, state.descent_state, jnp.array(False)

        y, f_info, dense, done = jax.lax.cond(accept, accepted, rejected)
        self.verbose(num_steps=("Step", state.num_steps), accepted=("Accepted", accept),
                     loss=("Loss on this step", 0.5 * jnp.sum(residual**2)), step_size=("Step size", step_size))
        y_descent, descent_result = self.descent.step(step_size, dense)
        result = optx.RESULTS.where(search_result == optx.RESULTS.successful, descent_result, search_result)
        new = _LMState(first_step=jnp.array(False), y_eval=self.project(y + y_descent), search_state=search_state,
                       f_info=f_info,
                       descent_state=dense, terminate=done, result=result, num_steps=state.num_steps + 1,
                       num_accepted_steps=state.num_accepted_steps + jnp.where(accept, 1, 0),
                       num_steps_since_acceptance=jnp.where(accept, 0, state.num_steps_since_acceptance + 1))
        return y, new, aux

    def terminate(self, fn, y, args, options, state: _LMState, tags):
        done = state.terminate
        if self.max_rejections is not None:
            # the start is the first accepted point: before a second, rejections are the
            # trust region shrinking to the start's scale, which the step rule bounds
            moved = (state.num_accepted_steps > 1) | (self.step_tolerance is None)
            done = done | (moved & (state.num_steps_since_acceptance >= self.max_rejections))
            if self.step_tolerance is not None:
                short = damped_step_length(state.descent_state, state.f_info.residual, state.y_eval - y)
                done = done | ((state.num_steps_since_acceptance > 0) & (short <= self.step_tolerance))
        if self.decrement_tolerance is not None:
            done = done | ((state.num_accepted_steps > 0)
                           & (scaled_decrement(state.descent_state, state.f_info.residual, y, self.free)
                              <= self.decrement_tolerance))
        return done, state.result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}
