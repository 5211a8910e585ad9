"""The local solver (:class:`bubblefit.inverse._lm_solver.LevenbergMarquardt`) against
independent least-squares codes: MINPACK's Levenberg-Marquardt (through
``scipy.optimize.least_squares``), optimistix' own ``LevenbergMarquardt``, and the normal
equations of a linear problem."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from scipy.optimize import least_squares

from bubblefit.inverse import LevenbergMarquardt, column_jacobian, scaled_decrement


def _solve(fn, z0, solver, max_steps=200):
    sol = optx.least_squares(fn, solver, jnp.asarray(z0, jnp.float32), max_steps=max_steps, throw=False)
    return np.asarray(sol.value, np.float64), int(sol.stats["num_steps"]), sol.result


def _rosenbrock(z, args=None):
    return jnp.stack([10.0 * (z[1] - z[0] ** 2), 1.0 - z[0]])


def _decay_problem():
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 4.0, 60)
    y = 2.5 * np.exp(-1.3 * x) + 0.4 + rng.normal(0.0, 0.02, x.size)

    sigma = 0.02  # whitened, as the fit's residual is: chi2_nu ~ 1

    def fn(z, args=None):
        return (z[0] * jnp.exp(-z[1] * jnp.asarray(x, jnp.float32)) + z[2] - jnp.asarray(y, jnp.float32)) / sigma

    def fn_np(z):
        return (z[0] * np.exp(-z[1] * x) + z[2] - y) / sigma

    return fn, fn_np


def test_rosenbrock_reaches_the_minimum_like_optimistix():
    # The classic start (-1.2, 1) needs rejected steps along the curved valley.
    mine, steps, result = _solve(_rosenbrock, [-1.2, 1.0], LevenbergMarquardt(rtol=1e-6, atol=1e-8,
                                                                            max_rejections=None,
                                                                            decrement_tolerance=None))
    theirs, their_steps, _ = _solve(_rosenbrock, [-1.2, 1.0], optx.LevenbergMarquardt(rtol=1e-6, atol=1e-8))
    assert result == optx.RESULTS.successful
    np.testing.assert_allclose(mine, [1.0, 1.0], atol=1e-4)
    np.testing.assert_allclose(mine, theirs, atol=1e-4)
    # the same trust region and damped step: the same iterates, so (up to float32
    # rounding near the end) the same number of steps
    assert abs(steps - their_steps) <= 2, (steps, their_steps)


def test_exponential_decay_matches_minpack():
    fn, fn_np = _decay_problem()
    z0 = [1.0, 0.5, 0.0]
    mine, _, result = _solve(fn, z0, LevenbergMarquardt(rtol=1e-7, atol=1e-9, max_rejections=None,
                                                        decrement_tolerance=None))
    ref = least_squares(fn_np, z0, method="lm", xtol=1e-12, ftol=1e-12).x
    assert result == optx.RESULTS.successful
    np.testing.assert_allclose(mine, ref, rtol=2e-4, atol=2e-4)


def test_decrement_stop_is_within_its_tolerance_of_the_optimum():
    """With the statistical stop on, the solve ends where the step left is at most
    ``decrement_tolerance`` squared standard errors, and the parameters are then within
    sqrt(tolerance) standard errors of MINPACK's optimum."""
    fn, fn_np = _decay_problem()
    z0 = [1.0, 0.5, 0.0]
    tol = 0.04
    mine, steps, result = _solve(fn, z0, LevenbergMarquardt(rtol=1e-7, atol=1e-9, decrement_tolerance=tol))
    _, all_steps, _ = _solve(fn, z0, LevenbergMarquardt(rtol=1e-7, atol=1e-9, decrement_tolerance=None,
                                                        max_rejections=None))
    assert result == optx.RESULTS.successful and steps <= all_steps
    ref = least_squares(fn_np, z0, method="lm", xtol=1e-12, ftol=1e-12)
    chi2_nu = np.sum(ref.fun**2) / (ref.fun.size - 3)
    se = np.sqrt(np.diag(np.linalg.inv(ref.jac.T @ ref.jac)) * max(chi2_nu, 1.0))
    # a squared Mahalanobis length <= tol bounds each coordinate by sqrt(tol) errors
    # (plus float32 rounding of the renders' stand-in)
    assert np.all(np.abs(mine - ref.x) <= (np.sqrt(tol) + 0.05) * se), (mine - ref.x) / se


def test_short_rejected_steps_stop_the_solve():
    """Near the optimum a float32 render's rounding makes the cost rise for any step, and
    every trial is rejected: a residual ripple the Jacobian does not see (amplitude 0.03 of
    a whitened residual, a cost change of order 0.03 * 2 * sqrt(60) ~ 0.5, far above the
    0.04 that a step of a fifth of a standard error lowers it by) stands in for it. With the step rule
    (``step_tolerance``) the solve stops at the first rejection whose next trial is a fifth
    of a standard error long, in fewer steps than the six rejections in a row, at a point
    within a fifth of a standard error (plus the ripple's own pull) of MINPACK's optimum."""
    fn0, fn_np = _decay_problem()
    fn = lambda z, args=None: fn0(z) + jax.lax.stop_gradient(0.03 * jnp.sin(1e5 * z[0] + jnp.arange(60.0)))
    z0 = [1.0, 0.5, 0.0]
    tol = 0.04
    mine, steps, result = _solve(fn, z0, LevenbergMarquardt(rtol=1e-7, atol=1e-9, decrement_tolerance=None,
                                                            step_tolerance=tol))
    _, rejections_only, _ = _solve(fn, z0, LevenbergMarquardt(rtol=1e-7, atol=1e-9, decrement_tolerance=None,
                                                              step_tolerance=None))
    assert result == optx.RESULTS.successful and steps < rejections_only, (steps, rejections_only)
    ref = least_squares(fn_np, z0, method="lm", xtol=1e-12, ftol=1e-12)
    se = np.sqrt(np.diag(np.linalg.inv(ref.jac.T @ ref.jac)) * max(np.sum(ref.fun**2) / (ref.fun.size - 3), 1.0))
    assert np.all(np.abs(mine - ref.x) <= (np.sqrt(tol) + 0.05) * se), (mine - ref.x) / se


def test_linear_problem_reaches_the_normal_equations():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 4)).astype(np.float32)
    b = rng.normal(size=200).astype(np.float32)  # unit noise: chi2_nu ~ 1
    fn = lambda z, args=None: jnp.asarray(a) @ z - jnp.asarray(b)
    best = np.linalg.lstsq(a.astype(np.float64), b.astype(np.float64), rcond=None)[0]
    se = np.sqrt(np.diag(np.linalg.inv(a.T.astype(np.float64) @ a)))
    full, cauchy_steps, result = _solve(fn, np.zeros(4), LevenbergMarquardt(rtol=1e-6, atol=1e-8,
                                                                           decrement_tolerance=None,
                                                                           max_rejections=None))
    assert result == optx.RESULTS.successful
    np.testing.assert_allclose(full, best, atol=1e-4)
    # the statistical stop ends earlier, within a fifth of a standard error
    early, steps, result = _solve(fn, np.zeros(4), LevenbergMarquardt(rtol=1e-6, atol=1e-8))
    assert result == optx.RESULTS.successful and steps < cauchy_steps
    assert np.all(np.abs(early - best) <= 0.2 * se + 1e-5), (early - best) / se


@functools.partial(jax.jit, static_argnames="free")
def _decrement_and_steps(r, jac, z=None, free=()):
    """The descent's factors of ``(r, jac)`` (float32), the scaled decrement
    (:func:`scaled_decrement`) there, and the steps for a step size of 1e12 and of 0, in
    one compiled program."""
    import lineax as lx

    from bubblefit.inverse import DenseDampedNewtonDescent

    f_info = optx.FunctionInfo.ResidualJac(r, lx.MatrixLinearOperator(jac))
    desc = DenseDampedNewtonDescent()
    dense = desc.query(jnp.zeros(3), f_info, desc.init(jnp.zeros(3), f_info))
    decrement = scaled_decrement(dense, r) if z is None else scaled_decrement(dense, r, z, free)
    return decrement, desc.step(jnp.asarray(1e12, jnp.float32), dense)[0], desc.step(jnp.asarray(0.0, jnp.float32), dense)[0]


def test_scaled_decrement_is_the_gauss_newton_drop():
    from bubblefit.inverse import gauss_newton_decrement

    rng = np.random.default_rng(1)
    jac = rng.normal(size=(500, 3))
    r = rng.normal(size=500) * 2.0  # chi2_nu ~ 4: the decrement is divided by it
    decrement, step, step0 = _decrement_and_steps(jnp.asarray(r, jnp.float32), jnp.asarray(jac, jnp.float32))
    chi2_nu = np.sum(r**2) / (r.size - 3)
    want = gauss_newton_decrement(r, jac) / chi2_nu
    assert float(decrement) == pytest.approx(want, rel=1e-3)
    # the undamped step (step size -> inf) is the Gauss-Newton step
    gn = -np.linalg.solve(jac.T @ jac, jac.T @ r)
    np.testing.assert_allclose(np.asarray(step), gn, rtol=1e-3, atol=1e-5)
    # infinite damping (step size 0) is the zero step
    assert np.all(np.asarray(step0) == 0.0)


#: The bounded decrement's cases: the third free parameter, its value, the scale of its
#: column (0.02: a standard error ``se`` in ``z`` of 2.6 or more, within one of its bound
#: for either coordinate; 1.0: about 0.05, well measured), its Gauss-Newton step in units
#: of ``se`` (so its significance), and whether it is left out.
BOUND_CASES = (
    # a roughness (log, bound 0) at 1e-4: a step toward zero; a step away of 0.6 se,
    # dz >= 1.6, beyond the reach |slope dz| < v of its first-order model and not resolved
    # from the bound; a step away of 0.2 se, dz about 0.5, within that reach; a step away
    # of 3 se, one the data ask for; a well-measured roughness either way
    ("roughness", 1e-4, 0.02, -0.5, True), ("roughness", 1e-4, 0.02, 0.6, True),
    ("roughness", 1e-4, 0.02, 0.2, False), ("roughness", 1e-4, 0.02, 3.0, False),
    ("roughness", 1e-4, 1.0, -0.5, False), ("roughness", 1e-4, 1.0, 3.0, False),
    # a specular share (logistic, bounds 0 and 1) driven to 1 - 1e-6: a step back of 3 se
    # (dz about -8, beyond the reach |slope dz| < 1 - v of its first-order model, and one
    # the data ask for); one of 0.6 se, not resolved from the bound; one toward 1
    ("split", 1 - 1e-6, 0.02, -3.0, False), ("split", 1 - 1e-6, 0.02, -0.6, True),
    ("split", 1 - 1e-6, 0.02, 0.5, True),
)


@pytest.mark.parametrize("name, value, col, k, dropped", BOUND_CASES)
def test_bounded_decrement_drops_a_parameter_pressing_on_its_bound(name, value, col, k, dropped):
    """With the parameters' names and point, the in-solve decrement treats the bounds as
    remaining_step (numpy, float64) does: a parameter within one standard error of a
    bound whose Gauss-Newton step points at the bound, or reaches away from it beyond its
    coordinate's first-order model while within one standard error, is left out, and the
    decrement is then that of the other columns; a well-measured parameter, a step within
    the first-order model, or a step of several standard errors away (the data ask for
    it, however far it reaches) keeps it. The residual is built with an exact
    Gauss-Newton step, so each case's step is the one named."""
    from bubblefit.inverse import gauss_newton_decrement
    from bubblefit.inverse import LocalSolution, remaining_step
    from bubblefit.inverse import inverse

    rng = np.random.default_rng(5)
    base_jac = rng.normal(size=(400, 3))
    base = rng.normal(size=400)
    free = ("thickness_nm", "t", name)
    z = np.array([inverse("thickness_nm", 700.0), inverse("t", 0.97), inverse(name, value)])
    jac = base_jac * np.array([1.0, 1.0, col])
    # the parameter's standard error in z without the factor max(1, chi2_nu) >= 1, which
    # the residual below keeps under 1.1 (its steps add at most 3^2 to a chi^2 of ~397)
    se0 = np.sqrt(np.linalg.inv(jac.T @ jac)[2, 2])
    # a residual whose Gauss-Newton step is exactly (0.1, -0.2, k se0): the part of
    # ``base`` outside the columns' span, less the columns times that step
    step = np.array([0.1, -0.2, k * se0])
    r = base - jac @ np.linalg.lstsq(jac, base, rcond=None)[0] - jac @ step
    got = float(_decrement_and_steps(jnp.asarray(r, jnp.float32), jnp.asarray(jac, jnp.float32),
                                     jnp.asarray(z, jnp.float32), free)[0])
    chi2_nu = np.sum(r**2) / (r.size - 3)
    assert chi2_nu < 1.1
    want = remaining_step(LocalSolution({}, z, True, False, 1, r, jac, {}), chi2_nu, free)
    # float32 factors of a column scaled by 0.02: the decrement to a few parts in 1e3
    assert got == pytest.approx(want, rel=2e-3, abs=1e-6)
    full = gauss_newton_decrement(r, jac) / max(1.0, chi2_nu)
    if dropped:
        others = gauss_newton_decrement(r, jac[:, :2]) / max(1.0, chi2_nu)
        assert want == pytest.approx(others, rel=1e-9)
        # the parameter's share of the full decrement, k^2 / max(1, chi2_nu) >= 0.22, is gone
        assert full - got > 0.2
    else:
        assert got == pytest.approx(full, rel=2e-3)


def test_a_saturated_share_comes_back_from_its_bound():
    """A specular share started at 1 - 1e-6 (where the start's inverse transform clamps
    it; the logistic's slope there is 1e-6) with its gain, the demo's pair of correlated
    weights: the projected solve starts it at the end of its plausible range, where the
    slope is 1e-3, and reaches MINPACK's optimum within the decrement stop's fifth of a
    standard error; without the projection the share's column of the Jacobian vanishes
    and the solve stops beside the bound, the gain off by many standard errors."""
    from bubblefit.inverse import inverse, plausible_box

    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 1.0, 80)
    a, b, sigma = 1.0 + np.cos(6.0 * x), 0.5 + x, 0.01
    y = 2.0 * (0.77 * a + 0.23 * b) + rng.normal(0.0, sigma, x.size)
    a32, b32, y32 = (jnp.asarray(v, jnp.float32) for v in (a, b, y))

    def fn(z, args=None):
        s, g = jax.nn.sigmoid(z[0]), jnp.exp(z[1])
        return (g * (s * a32 + (1.0 - s) * b32) - y32) / sigma

    model = lambda v: (v[1] * (v[0] * a + (1.0 - v[0]) * b) - y) / sigma
    ref = least_squares(model, [0.5, 1.0], method="lm", xtol=1e-12, ftol=1e-12)
    se = np.sqrt(np.diag(np.linalg.inv(ref.jac.T @ ref.jac)) * max(np.sum(ref.fun**2) / (x.size - 2), 1.0))
    free = ("split", "exposure")
    z0 = [inverse("split", 1.0), inverse("exposure", 1.0)]
    solver = LevenbergMarquardt(rtol=1e-5, atol=1e-6, free=free)
    z, _, result = _solve(fn, z0, solver)
    got = np.array([1.0 / (1.0 + np.exp(-z[0])), np.exp(z[1])])
    assert result == optx.RESULTS.successful
    assert z0[0] > plausible_box(free)[1][0]  # the start lies beyond the box
    # within sqrt(0.04) standard errors of the optimum, plus float32's share
    assert np.all(np.abs(got - ref.x) <= (np.sqrt(0.04) + 0.05) * se), (got - ref.x) / se

    class Unprojected(LevenbergMarquardt):
        def project(self, y):
            return y

    z, _, _ = _solve(fn, z0, Unprojected(rtol=1e-5, atol=1e-6, free=free))
    assert abs(np.exp(z[1]) - ref.x[1]) > 10 * se[1]  # the stall the projection removes


def test_vmapped_solve_matches_one_by_one():
    """fit_batch vmaps the solve over frames: lax.cond turns into a select there, and the
    result must still be each frame's own solve."""
    fn, _ = _decay_problem()
    solver = LevenbergMarquardt(rtol=1e-6, atol=1e-8)

    def one(z0):
        return optx.least_squares(fn, solver, z0, max_steps=100, throw=False).value

    z0s = jnp.asarray([[1.0, 0.5, 0.0], [3.0, 2.0, 0.5]], jnp.float32)
    both = np.asarray(jax.jit(jax.vmap(one))(z0s))
    for i in range(2):
        np.testing.assert_allclose(both[i], np.asarray(jax.jit(one)(z0s[i])), rtol=1e-3, atol=1e-4)


def test_column_jacobian_is_the_derivative():
    """Columns by groups of parameters, against central differences of the float64
    residual, and a solve through them takes the steps of the default ``jax.jacfwd`` one."""
    fn, fn_np = _decay_problem()
    z = np.array([2.2, 1.1, 0.3])
    jacobian = jax.jit(column_jacobian, static_argnums=(0, 1))
    got = np.asarray(jacobian(fn, ((0, 2), (1,)), jnp.asarray(z, jnp.float32), None), np.float64)
    h = 1e-6
    want = np.stack([(fn_np(z + h * e) - fn_np(z - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
    assert got.shape == want.shape == (60, 3)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3 * np.abs(want).max())

    plain = LevenbergMarquardt(rtol=1e-7, atol=1e-9)
    by_column = LevenbergMarquardt(rtol=1e-7, atol=1e-9, jacobian=functools.partial(column_jacobian, fn, ((1,), (0, 2))))
    a, steps_a, result_a = _solve(fn, [1.0, 0.5, 0.0], plain)
    b, steps_b, result_b = _solve(fn, [1.0, 0.5, 0.0], by_column)
    assert result_a == result_b == optx.RESULTS.successful
    assert steps_a == steps_b
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)


def test_a_failed_restart_is_never_kept_and_a_kept_one_does_not_raise_the_cost():
    """``solve_local`` restarts a solve that stopped far from its optimum. A restart that
    failed is dropped even when its reported residual is smaller (a diverged render's
    residual once read as zeros, a cost of 0). One that met its tolerances or ran out of
    steps is kept when its cost is no larger, and dropped when larger or not finite."""
    from bubblefit.inverse import LocalSolution, improves

    def sol(residual, ok=True, maxed=False):
        r = np.asarray(residual, np.float64)
        return LocalSolution({}, np.zeros(2), ok, maxed, 3, r, np.zeros((r.size, 2)), {})

    first = sol([1.0, -2.0, 0.5])
    assert improves(sol([0.5, -1.0, 0.5]), first)
    assert improves(sol([1.0, -2.0, 0.5]), first)
    assert improves(sol([0.5, -1.0, 0.5], ok=False, maxed=True), first)  # out of steps, still descending
    assert not improves(sol([3.0, 0.0, 0.0], ok=False, maxed=True), first)
    assert not improves(sol([0.0, 0.0, 0.0], ok=False), first)
    assert not improves(sol([0.5, -1.0, 0.5], ok=False), first)
    assert not improves(sol([3.0, 0.0, 0.0]), first)
    assert not improves(sol([np.nan, 0.0, 0.0]), first)


def test_robust_residual_is_the_pseudo_huber_residual_up_to_overflow():
    """``robust`` is ``sign(r) sqrt(2 rho(r))`` with the pseudo-Huber ``rho(r) = s^2
    (sqrt(1 + (r/s)^2) - 1)`` (float64 here) from 1e-3 to float32's largest values: a
    diverged render's residual stays large, never 0, and its gradient finite."""
    from bubblefit.inverse import robust

    s = 3.0
    r = np.concatenate([-np.logspace(-3, 38, 200), np.logspace(-3, 38, 200)])
    rho = s * s * (np.sqrt(1.0 + (r / s) ** 2) - 1.0)
    exact = np.sign(r) * np.sqrt(2.0 * rho)
    got = np.asarray(jax.jit(robust, static_argnums=1)(jnp.asarray(r, jnp.float32), s), np.float64)
    np.testing.assert_allclose(got, exact, rtol=2e-6)
    grad = np.asarray(jax.jit(jax.vmap(jax.grad(lambda x: robust(x, s))))(jnp.asarray(r, jnp.float32)))
    assert np.all(np.isfinite(grad)) and np.all(grad > 0)


def _stand_in_local_solve(monkeypatch, solve):
    """``solve_local`` run with ``solve`` ``(z, args) -> (z_end, residual, steps)`` standing
    in for the compiled solve: 2 free parameters on 4 residuals, the Jacobian 10 times the
    identity on the first two (a move of 1 is 10 standard errors), the step left always far
    from the optimum, and rejections allowed to restart it."""
    from types import SimpleNamespace

    import bubblefit.inverse._local as local

    def solution_from(table, vals, z, r, steps, fixed, lev, px):
        return local.LocalSolution({}, z, True, False, steps, r, 10.0 * np.eye(r.size, 2), fixed)

    monkeypatch.setattr(local, "solve_program", lambda *a: (("key",), ({},), None))
    monkeypatch.setattr(local, "stored_solver", lambda *key: solve)
    monkeypatch.setattr(local, "solution_from", solution_from)
    monkeypatch.setattr(local, "remaining_step", lambda sol, chi2, free: 1.0)
    table = SimpleNamespace(unconstrained=lambda v: np.zeros(2), free=("a", "b"))
    return local.solve_local(SimpleNamespace(w=np.ones(4)), table, None, {}, None,
                             settings=SimpleNamespace(stall=True))


@pytest.mark.parametrize("restarts_move", [False, True])
def test_a_restart_that_accepted_no_step_is_not_repeated(monkeypatch, restarts_move):
    """``solve_local`` starts a solve that stopped on rejections far from its optimum
    afresh, up to ``MAX_RESTARTS`` times; once a fresh start accepts no step, the next
    would start from the same point with the same trust region and, the program being
    deterministic, repeat it: it is not run. Restarts that move (here by 10 standard
    errors) are all run. The solve itself is a stand-in here (its steps and end point
    chosen per call)."""
    import bubblefit.inverse._local as local

    calls = []

    def solve(z, args):
        calls.append(np.asarray(z).copy())
        first = len(calls) == 1
        z_end = np.asarray(z, np.float64) + (1.0 if first or restarts_move else 0.0)
        r = np.full(4, 10.0 - len(calls) if first or restarts_move else 10.0 - 1)
        return z_end, r, 12 if first else 7

    sol = _stand_in_local_solve(monkeypatch, solve)  # a move of 1 is 10 standard errors
    runs = 1 + (local.MAX_RESTARTS if restarts_move else 1)
    assert len(calls) == runs
    assert sol.steps == 12 + 7 * (runs - 1)
    assert np.array_equal(sol.z, np.full(2, float(runs if restarts_move else 1)))  # where the last run ended


def test_a_restart_that_moved_the_fit_by_under_a_fifth_of_a_standard_error_is_not_repeated(monkeypatch):
    """A fresh start whose move ``dz`` is at most :data:`~bubblefit.inverse._lm.STOP_DECREMENT`
    in squared length in the fit's covariance, ``|J dz|^2 / max(1, chi2_nu)`` (a fifth of a
    standard error), ends the restarts (:func:`~bubblefit.inverse._local.restart_moved`):
    it has met the resolution at which the solve itself stops. Here ``J`` is 10 times the
    identity on 2 of 4 residuals whose chi2 per degree of freedom is below 1, so a move
    of 0.019 in each parameter is 0.19 standard errors in each, a squared length of 0.072,
    and one of 0.013 is 0.034: the first restart moves 0.019 and is followed by another,
    which moves 0.013 and is the last."""
    from bubblefit.inverse._lm import STOP_DECREMENT

    moves = [1.0, 0.019, 0.013, 0.013]
    calls = []

    def solve(z, args):
        calls.append(np.asarray(z).copy())
        z_end = np.asarray(z, np.float64) + moves[len(calls) - 1]
        return z_end, np.full(4, 0.4 - 0.01 * len(calls)), 5

    sol = _stand_in_local_solve(monkeypatch, solve)
    assert 0.013 ** 2 * 200 < STOP_DECREMENT < 0.019 ** 2 * 200
    assert len(calls) == 3 and sol.steps == 15
    np.testing.assert_allclose(sol.z, np.full(2, 1.0 + 0.019 + 0.013))  # the last restart's end is kept
