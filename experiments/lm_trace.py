"""Every step of each local solve of one ``bubblefit fit`` process: the trial point's cost,
the trust region's damping, accepted or rejected, the cost the quadratic model predicted,
each free parameter's step in units of its standard error at the solve's end, and which
parameters press a bound (:func:`bubblefit.inverse._lm.presses_bound`).

Runs the command line in this process with the solves' compiled programs
(:func:`bubblefit.inverse._programs.stored_solver`) wrapped: each call runs as the fit
runs it, and then again step by step, eagerly, with the same
:class:`~bubblefit.inverse._lm_solver.LevenbergMarquardt` (its ``init``, ``step`` and
``terminate``; Moré 1978), whose steps are recorded. The fit's own output is unchanged.
Writes ``TRACE`` (JSON, one entry per solve call; default ``lm_trace.json``):

    TRACE=trace.json PYTHONPATH=. python experiments/lm_trace.py fit PHOTO --envmap ... \\
        --thickness constant --json fit.json -o fit --fov 0 --illuminant D65
"""

import json
import os
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bubblefit.inverse._local as local_module
from bubblefit.cli import main
from bubblefit.inverse._lm import JACOBIANS, damped_step_length, presses_bound, scaled_decrement
from bubblefit.inverse._lm_solver import LevenbergMarquardt
from bubblefit.inverse._parameters import value_and_slope
from bubblefit.inverse._programs import solver

_stored_solver = local_module.stored_solver
TRACE = []


def _se_and_step(jac, r, n):
    """The Gauss-Newton step and the standard errors (in ``z``) at a point (numpy, float64)."""
    jac, r = np.asarray(jac, np.float64), np.asarray(r, np.float64).ravel()
    a_inv = np.linalg.inv(jac.T @ jac)
    dof = max(int(np.count_nonzero(r)) - n, 1)
    chi2 = max(1.0, float(r @ r) / dof)
    return -a_inv @ (jac.T @ r), np.sqrt(np.abs(np.diag(a_inv)) * chi2), float(r @ r) / dof


def trace(key, z0, args):
    """The steps of the solve ``solver(*key)`` from ``z0``, run eagerly."""
    cfg, table, robust_scale, max_steps, rtol, atol, max_rejections, jacobian, _ = key
    _, resid = solver(*key)
    lm = LevenbergMarquardt(rtol=rtol, atol=atol, max_rejections=max_rejections, free=table.free,
                            jacobian=JACOBIANS[jacobian](resid, table))
    fn = lambda z, a: (resid(z, a), None)  # noqa: E731
    f_struct = jax.eval_shape(lambda z: resid(z, args), z0)
    state = lm.init(fn, z0, args, {}, f_struct, None, frozenset())
    step = eqx.filter_jit(lambda y, s: lm.step(fn, y, args, {}, s, frozenset())[:2])
    term = eqx.filter_jit(lambda y, s: lm.terminate(fn, y, args, {}, s, frozenset())[0])
    extra = eqx.filter_jit(lambda y, s: (
        scaled_decrement(s.descent_state, s.f_info.residual, y, table.free),
        scaled_decrement(s.descent_state, s.f_info.residual),
        damped_step_length(s.descent_state, s.f_info.residual, s.y_eval - y)))
    y = z0
    rows, points = [], []
    for k in range(max_steps):
        t0 = time.process_time()
        y_eval = np.asarray(state.y_eval)
        y, state = step(y, state)
        accept = bool(np.array_equal(np.asarray(y), y_eval)) if k else True
        loss = float(0.5 * jnp.sum(resid(jnp.asarray(y_eval), args) ** 2))
        dec, dec_free, short = (float(v) for v in extra(y, state))
        done = bool(term(y, state))
        rows.append({"step": k, "accepted": accept, "cost": 2 * loss,
                     "damping": float(1.0 / state.search_state.step_size), "cauchy": bool(state.terminate),
                     "decrement_bounds": dec, "decrement": dec_free, "next_step_length": short,
                     "since_accept": int(state.num_steps_since_acceptance), "cpu": time.process_time() - t0})
        if accept:
            points.append((k, np.asarray(y, np.float64), np.asarray(state.f_info.residual),
                           np.asarray(state.f_info.jac.as_matrix())))
        if done:
            break
    # each accepted step in units of the standard errors at the solve's end, and the bounds
    n = len(table.free)
    _, se_end, chi2_end = _se_and_step(points[-1][3], points[-1][2], n)
    prev = np.asarray(z0, np.float64)
    for k, z, r, jac in points:
        gn, se, chi2 = _se_and_step(jac, r, n)
        rows[k]["move_se"] = {name: float((z[i] - prev[i]) / se_end[i]) for i, name in enumerate(table.free)}
        rows[k]["gn_step_se"] = {name: float(gn[i] / se[i]) for i, name in enumerate(table.free)}
        rows[k]["held"] = [name for i, name in enumerate(table.free)
                           if presses_bound(name, *value_and_slope(name, z[i]), gn[i], se[i], np.sign)]
        rows[k]["values"] = {name: value_and_slope(name, z[i])[0] for i, name in enumerate(table.free)}
        rows[k]["chi2nu"] = chi2
        prev = z
    return {"pixels": int(np.count_nonzero(np.asarray(args[5]))), "free": list(table.free), "max_steps": max_steps,
            "rejections_rule": max_rejections, "jacobian": jacobian, "se_end_z": se_end.tolist(),
            "chi2nu_end": chi2_end, "steps": rows}


def _traced(*key):
    """:func:`~bubblefit.inverse._programs.stored_solver`, each call's steps traced too."""
    solve = _stored_solver(*key)

    def run(z0, args):
        out = solve(z0, args)
        t0 = time.process_time()
        rec = trace(key, z0, args)
        rec["steps_fit"] = int(out[3])
        rec["z_fit"] = np.asarray(out[0], np.float64).tolist()
        rec["trace_cpu"] = time.process_time() - t0
        TRACE.append(rec)
        print("TRACED", len(rec["steps"]), "steps (the fit's:", rec["steps_fit"], ")", file=sys.stderr, flush=True)
        return out

    return run


if __name__ == "__main__":
    local_module.stored_solver = _traced
    try:
        code = main(sys.argv[1:])
    finally:
        with open(os.environ.get("TRACE", "lm_trace.json"), "w") as fh:
            json.dump(TRACE, fh, indent=1, default=float)
    sys.exit(code)
