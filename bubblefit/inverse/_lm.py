"""Levenberg-Marquardt for the fit's local solves, and its convergence measures.

LM rather than Gauss-Newton because the starting points from the global search are only
close, and its trust-region damping keeps steps inside one colour fringe of the
thickness; rather than Dogleg because with few parameters its damped solve is as cheap
and it needs no separate trust-region geometry. The Jacobian is forward-mode (few
parameters, many residuals), its columns computed by the part of the render their
parameters reach (:func:`column_jacobian`) or, in the fit's final solve, one by one with
the render shared (:func:`columns_linearized`). The residual is whitened and robust
(:func:`robust`). This module holds the numerics only: the programs that run them are
built in :mod:`._programs`, the solve that asks for them is :mod:`._local`; the
trust-region solver itself, which subclasses optimistix' (:class:`~._lm_solver.LevenbergMarquardt`,
:class:`~._lm_solver.DenseDampedNewtonDescent`), is in :mod:`._lm_solver`, imported where a solve is
traced: a process whose solves the executable store holds does not import optimistix,
equinox or lineax (about 0.25 s of CPU).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._parameters import PARAMETERS, forward

__all__ = ["column_jacobian", "columns_linearized", "JACOBIANS",
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
#: (:class:`~._lm_solver.LevenbergMarquardt`).
MAX_REJECTIONS = 6


#: The solve stops at an accepted point whose Gauss-Newton step left is at most this
#: squared length in the fit's covariance (:func:`scaled_decrement`; 0.04: a fifth of a
#: standard error, which widens no error bar by more than 2 %). Below it float32 renders
#: do not resolve the cost: on experiments/validation's ref_const300 (physical model; a development case, split.toml)
#: the solve met 0.026 at its 11th step, then spent 21 steps of a Jacobian's cost each
#: (20 of them rejected, the cost moving by 4e-6 of itself) to stop at 0.108.
STOP_DECREMENT = 0.04


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


def scaled_decrement(dense, residual, z=None, free: tuple = ()) -> Float[Array, ""]:
    """The Gauss-Newton decrement ``r^T J (J^T J)^-1 J^T r = |Q^T r|^2`` of an accepted
    point (:class:`~._lm_solver.DenseDampedNewtonDescent`'s factors) over ``max(1, chi2_nu)``, the
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


def damped_step_length(dense, residual, step) -> Float[Array, ""]:
    """The squared length of ``step`` (in ``z``) in the fit's own covariance at an accepted
    point (:class:`~._lm_solver.DenseDampedNewtonDescent`'s factors, its residual ``residual``):
    ``|J step|^2 / max(1, chi2_nu) = |R step|^2 / max(1, chi2_nu)``, its squared Mahalanobis
    length, which bounds the square of every parameter's move in its own standard errors
    (Bard, *Nonlinear Parameter Estimation*, 1974, ch. 7: the confidence region
    ``dz^T J^T J dz / s^2``). The stopping rule of :class:`~._lm_solver.LevenbergMarquardt` reads it
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
