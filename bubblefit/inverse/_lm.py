"""Levenberg-Marquardt for the fit's local solves, and its convergence measures.

LM rather than Gauss-Newton because the starting points from the global search are only
close, and its trust-region damping keeps steps inside one colour fringe of the
thickness; rather than Dogleg because with few parameters its damped solve is as cheap
and it needs no separate trust-region geometry. The Jacobian is forward-mode (few
parameters, many residuals), its columns computed by the part of the render their
parameters reach (:func:`column_jacobian`) or, in the fit's final solve, one by one with
the render shared (:func:`columns_linearized`). The residual is whitened and robust
(:func:`robust`). This module holds the numerics only: the programs that run them are
built in :mod:`._programs`, the solve that asks for them is :mod:`._local`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from ._parameters import PARAMETERS, forward, plausible_box

__all__ = ["DenseDampedNewtonDescent", "LevenbergMarquardt", "column_jacobian", "columns_linearized", "JACOBIANS",
           "scaled_decrement", "damped_step_length", "gauss_newton_decrement", "presses_bound", "robust", "MAX_REJECTIONS",
           "STOP_DECREMENT", "ROBUST_ASYMPTOTE"]


#: ``|r| / scale`` beyond which :func:`robust` takes its asymptote: far below the square
#: root of float32's largest value (1.8e19), where ``(r / scale)^2`` overflows, and far
#: above where the asymptote differs from the exact value in float32 (``1 / a``).
ROBUST_ASYMPTOTE = 1e15


def robust(r, scale):
    """Pseudo-Huber residual ``sign(r) sqrt(2 rho(r))``, written to stay smooth at 0.

    Beyond :data:`ROBUST_ASYMPTOTE` it is ``sign(r) sqrt(2 scale |r|)``, the same to
    float32's precision; the exact form's ``(r / scale)^2`` overflows there and made a
    render that diverged (residuals of 5e19) read as a residual of 0, a perfect fit. Each
    form sees only the values it is used for, so that values and gradients stay finite.

    References
    ----------
    Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., appendix A6.8 (pseudo-Huber cost).
    """
    far = jnp.abs(r) > ROBUST_ASYMPTOTE * scale
    near_r = jnp.where(far, 0.0, r)
    far_r = jnp.where(far, r, ROBUST_ASYMPTOTE * scale)
    x2 = (near_r / scale) ** 2
    near = near_r * jnp.sqrt(2.0 / (jnp.sqrt(1.0 + x2) + 1.0))
    return jnp.where(far, jnp.sign(far_r) * jnp.sqrt(2.0 * scale) * jnp.sqrt(jnp.abs(far_r)), near)


#: Consecutive rejected steps after which the solve stops at its last accepted point
#: (:class:`LevenbergMarquardt`).
MAX_REJECTIONS = 6


#: The solve stops at an accepted point whose Gauss-Newton step left is at most this
#: squared length in the fit's covariance (:func:`scaled_decrement`; 0.04: a fifth of a
#: standard error, which widens no error bar by more than 2 %). Below it float32 renders
#: do not resolve the cost: on experiments/validation's ref_const300 (physical model; a development case, split.toml)
#: the solve met 0.026 at its 11th step, then spent 21 steps of a Jacobian's cost each
#: (20 of them rejected, the cost moving by 4e-6 of itself) to stop at 0.108.
STOP_DECREMENT = 0.04


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


def column_jacobian(resid: Callable, groups: tuple, z, args) -> Float[Array, "m n"]:
    """The Jacobian of ``resid(z, args)`` (M,) in ``z`` (N,), forward mode, one group of
    columns at a time: ``groups`` are tuples of indices into ``z`` (each index once,
    :attr:`~bubblefit.inverse._parameters.ParameterTable.jacobian_groups`), the parameters
    outside a group held as constants while its columns are computed.

    ``jax.jacfwd`` pushes all N tangents through every operation that any parameter
    reaches: the thickness's tangent through the map's filtered lookups, the roughness's
    through the film's spectra, and the terms' linear weights (``t``, the split, the
    exposure) through both. Here ``resid`` sees ``z`` as a tuple of scalars, so that a
    group's tangents are symbolic zeros wherever its parameters do not reach and each group
    costs only the part of the render downstream of it (XLA merges the groups' copies of the
    primal). On the 64x64 sequence frames of ``experiments/bench_sequence.py`` (paper
    model; the weights, the roughness and the thickness free) the Jacobian took 22-27 ms
    against 53-65 ms on one core, equal within 6e-5 of 48; the two solves of a fit take
    about 1.4 s longer to compile than with ``jax.jacfwd`` (3.6 s with a column for each
    of the five parameters, for the same speed).
    """
    zs = tuple(z[i] for i in range(z.shape[0]))
    columns = {}
    for group in groups:
        jac = jax.jacfwd(_along(resid, zs, group, args))(jnp.stack([zs[i] for i in group]))
        for k, i in enumerate(group):
            columns[i] = jac[:, k]
    return jnp.stack([columns[i] for i in range(len(zs))], axis=-1)


def columns_linearized(resid: Callable, z, args) -> Float[Array, "m n"]:
    """The Jacobian of ``resid(z, args)`` (M,) in ``z`` (N,) one column at a time, each
    the tangent of a :func:`jax.linearize` along its parameter alone (``resid`` sees ``z``
    as a tuple of scalars, as in :func:`column_jacobian`, so that a column's tangent reaches
    only the part of the render downstream of its parameter). The linearisations' primal
    parts are one computation, which XLA merges: the render runs once, and a parameter
    whose tangent crosses the map's filtered lookups (the roughness, the disc) costs about
    one render more, the others less.

    The fit's final solve uses it (:func:`solve_local` with ``jacobian="columns"``): on
    the 80x80 level of a 320x320 photo (8 parameters) the Jacobian took 80 ms against
    119 ms by groups and the solve 0.36 s against 0.50 s, the same thickness to the last
    bit (39 ms against 66 ms since the filtered lookups work per vector component, 5.5 s
    against 4.2 s to compile alone); its longer compile runs in the background during the
    global search (an empty cache's first fit 22.4 and 20.8 s against 22.4 and 19.9 s by
    groups). The search's
    own solve and a warm-started fit's, compiled on the critical path, keep the groups
    (``experiments/bench_fit.py --compile-profile``; ``bubblefit.inverse._programs.FINAL_JACOBIAN``).
    """
    zs = tuple(z[i] for i in range(z.shape[0]))
    columns = []
    for i in range(len(zs)):
        _, tangent = jax.linearize(_along(resid, zs, (i,), args), zs[i][None])
        columns.append(tangent(jnp.ones((1,), zs[i].dtype)))
    return jnp.stack(columns, axis=-1)


def _along(resid: Callable, zs: tuple, group: tuple, args) -> Callable:
    """``resid`` as a function of the parameters ``group`` (indices into ``zs``, their
    values stacked in that order), the others held at ``zs``: the function whose forward
    derivative is the group's columns (:func:`column_jacobian`, :func:`columns_linearized`)."""
    def along(sub):
        full = list(zs)
        for k, i in enumerate(group):
            full[i] = sub[k]
        return resid(tuple(full), args)

    return along


#: How a solve computes its Jacobian: by groups of parameters (:func:`column_jacobian`,
#: shorter to compile) or by columns (:func:`columns_linearized`, faster to run).
JACOBIANS = {"groups": lambda resid, table: functools.partial(column_jacobian, resid, table.jacobian_groups),
             "columns": lambda resid, table: functools.partial(columns_linearized, resid)}


def scaled_decrement(dense: _DenseState, residual, z=None, free: tuple = ()) -> Float[Array, ""]:
    """The Gauss-Newton decrement ``r^T J (J^T J)^-1 J^T r = |Q^T r|^2`` of an accepted
    point (:class:`DenseDampedNewtonDescent`'s factors) over ``max(1, chi2_nu)``, the
    reduced chi^2 counted over the residual's non-zero entries (pixels outside the fit
    have weight 0): the squared length of the step left, in the fit's own covariance.

    With the point ``z`` and the names ``free`` of its parameters, the bounds are active
    constraints as in :func:`remaining_step` (:func:`presses_bound`): a parameter within
    one standard error of a finite bound whose step points at it, or reaches beyond its
    coordinate's linearisation away from it while within one standard error, is left
    out, and the decrement is the projection of ``Q^T r`` on the columns of ``R`` left (a
    roughness at the mirror, its step pointing below zero or asking for thousands in
    ``z`` within its noise, no longer keeps the solve from stopping). From the QR factors, in
    the solve's own precision.
    """
    r = jnp.ravel(residual)
    n = dense.qt_residual.shape[0]
    scale = _chi2_scale(r, n)
    if not free:
        return jnp.sum(dense.qt_residual**2) / scale
    rinv = jax.scipy.linalg.solve_triangular(dense.r_factor, jnp.eye(n, dtype=r.dtype), lower=False)
    step = -rinv @ dense.qt_residual
    se_z = jnp.sqrt(jnp.sum(rinv**2, axis=1) * scale)  # sqrt(diag((J^T J)^-1) max(1, chi2_nu))
    keep = []
    for i, name in enumerate(free):
        v, slope = jax.jvp(functools.partial(forward, name), (z[i],), (jnp.ones_like(z[i]),))
        keep.append(~jnp.asarray(presses_bound(name, v, slope, step[i], se_z[i], jnp.sign)))
    keep = jnp.stack(keep)
    order = jnp.argsort(~keep, stable=True)  # the columns kept first, the dropped ones zero after them
    q2, _ = jnp.linalg.qr(jnp.where(keep, dense.r_factor, 0.0)[:, order])
    proj = q2.T @ dense.qt_residual
    return jnp.sum(jnp.where(jnp.arange(n) < jnp.sum(keep), proj**2, 0.0)) / scale


def _chi2_scale(r, n: int):
    """``max(1, chi2_nu)`` of the flat residual ``r`` with ``n`` free parameters, counted
    over its non-zero entries (pixels outside the fit have weight 0): the factor that turns
    ``J^T J`` into the inverse covariance of the fit's parameters (:func:`scaled_decrement`)."""
    dof = jnp.maximum(jnp.sum(r != 0) - n, 1)
    return jnp.maximum(jnp.sum(r * r) / dof, 1.0)


def damped_step_length(dense: _DenseState, residual, step) -> Float[Array, ""]:
    """The squared length of ``step`` (in ``z``) in the fit's own covariance at an accepted
    point (:class:`DenseDampedNewtonDescent`'s factors, its residual ``residual``):
    ``|J step|^2 / max(1, chi2_nu) = |R step|^2 / max(1, chi2_nu)``, its squared Mahalanobis
    length, which bounds the square of every parameter's move in its own standard errors
    (Bard, *Nonlinear Parameter Estimation*, 1974, ch. 7: the confidence region
    ``dz^T J^T J dz / s^2``). The stopping rule of :class:`LevenbergMarquardt` reads it
    for the trust region's next trial step after a rejection."""
    r = jnp.ravel(residual)
    return jnp.sum((dense.r_factor @ step) ** 2) / _chi2_scale(r, dense.qt_residual.shape[0])


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


def presses_bound(name: str, v, slope, step, se, sign=np.sign):
    """Whether parameter ``name`` at value ``v`` (``slope = d v / d z``) is an active
    constraint of the Gauss-Newton ``step`` (in ``z``): within ``se`` (one standard error
    in ``z``) of a finite bound, with a step that points at the bound, or a step away from
    it that reaches beyond its coordinate's linearisation, ``|slope step| > |v - b|``,
    while it is no longer than one standard error, ``|step| <= se``.

    The coordinates that keep a value off its bound (log, softplus, logistic;
    :data:`~bubblefit.inverse._parameters.PARAMETERS`) are exponential in ``z`` there, so
    the first-order model ``v + slope dz`` from which the step is computed holds only
    while ``|slope dz| < |v - b|``. Beyond it the step's length says nothing the solve can
    act on, and its significance ``|dz| / se`` (the same in every coordinate to first
    order: ``|slope dz| / |slope se|``, the step in the value's own standard errors)
    tells whether the data ask for it at all: a mirror's roughness at 1.8e-5 asks for
    ``dz`` of about 6300 at 0.83 standard errors, a move the data do not resolve from
    the bound, whose decrement kept the solve going for steps that moved the fit by less
    than a fifth of a standard error; a specular share driven to ``1 - 1e-6`` whose step
    back (to 0.74 at first order) is 34 standard errors is a move the data demand, and
    the solve that keeps it reaches it. The rule of :func:`remaining_step` (numpy,
    float64) and of :func:`scaled_decrement` (jnp, in the solve; ``sign`` is ``jnp.sign``
    there).

    References
    ----------
    J. Nocedal & S. J. Wright, *Numerical Optimization*, 2nd ed. (2006), ch. 16.6 (active
    constraints at bounds) and ch. 4 (a model's step is trusted only where the model
    holds); Y. Bard, *Nonlinear Parameter Estimation* (1974), ch. 7 (a parameter's
    standard error from ``(J^T J)^-1``).
    """
    out = False
    for b in PARAMETERS[name].bounds:
        if math.isfinite(b):
            toward = sign(slope * step) == sign(b - v)
            unresolved = (abs(slope * step) > abs(v - b)) & (abs(step) <= se)
            out = out | ((toward | unresolved) & (abs(v - b) <= abs(slope) * se))
    return out
