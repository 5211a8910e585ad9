"""Wall and CPU seconds of a fit's stages, by wrapping the functions that run them, and of one
local solve's render, Jacobian and LM run: the
helpers of ``experiments/profile_sequence_maps.py`` and ``experiments/profile_map_photo.py``."""
import time
from collections import defaultdict

import numpy as np

#: label -> [wall s, CPU s (``time.process_time``, every thread), calls]
T = defaultdict(lambda: [0.0, 0.0, 0])


def add(label, t0, c0):
    """Add the wall and CPU seconds since ``t0``, ``c0`` and one call to ``T[label]``."""
    e = T[label]
    e[0] += time.perf_counter() - t0
    e[1] += time.process_time() - c0
    e[2] += 1


def wrap(mod, name, label=None):
    """Replace ``mod.name`` by a function that adds its wall and CPU seconds to ``T[label]``."""
    f = getattr(mod, name)
    label = label or name

    def g(*a, **k):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return f(*a, **k)
        finally:
            add(label, t0, c0)
    setattr(mod, name, g)


def keep_solves(fit_module) -> list:
    """Replace ``fit_module.solve_local`` by a function that appends each local solve's
    arguments (``args``, ``kwargs``) and a ``row`` (pixels, level shape, free parameters, LM
    steps, final cost, wall and CPU seconds) to the returned list."""
    solves = []
    solve_local = fit_module.solve_local

    def kept(*a, **k):
        t0, c0 = time.perf_counter(), time.process_time()
        sol = solve_local(*a, **k)
        lev = a[0]
        solves.append({"args": a, "kwargs": k, "row": {
            "pixels": int(lev.mask.sum()), "shape": list(lev.mask.shape), "free": list(a[1].free),
            "steps": int(sol.steps), "cost": float(sol.cost), "wall_s": round(time.perf_counter() - t0, 3),
            "cpu_s": round(time.process_time() - c0, 3)}})
        return sol
    fit_module.solve_local = kept
    return solves


def timed_solver(stored_solver):
    """``stored_solver`` (:func:`bubblefit.inverse._local.stored_solver`) whose solves each
    add one LM run, its outputs brought to the host, to ``T``."""

    def stored(*key):
        s = stored_solver(*key)

        def run(*a):
            t0, c0 = time.perf_counter(), time.process_time()
            out = [np.asarray(x) for x in s(*a)]
            add("solver program (one LM run)", t0, c0)
            return out
        return run
    return stored


def solve_costs(a, k, stored_solver) -> dict:
    """One local solve (``solve_local``'s positional ``a`` and keyword ``k`` arguments) taken
    apart: wall and CPU seconds of a render of its fitted pixels (the residual), of its
    Jacobian by groups and of its LM run (``stored_solver``'s program), at its start, each the
    median of 3 calls after the first (which compiles or loads)."""
    import jax
    import jax.numpy as jnp

    import bubblefit.inverse._programs as P
    from bubblefit.inverse._lm import JACOBIANS

    lev, table, solver, vals, env_ = a[:5]
    max_steps = a[5] if len(a) > 5 else k.get("max_steps")
    settings = k.get("settings", P.SolveSettings())
    key, args, _ = P.solve_program(lev, table, solver, vals, env_, max_steps, settings)
    _, resid = P.solver(*key)
    z = jnp.asarray(table.unconstrained(vals), jnp.float32)
    jac = jax.jit(JACOBIANS["groups"](resid, table))
    run_ = stored_solver(*key)
    out = {"fitted_pixels": int(lev.mask.sum()), "free": list(table.free),
           "groups": [list(g) for g in table.jacobian_groups]}
    for name, fn in (("render", lambda: resid(z, args)), ("jacobian_groups", lambda: jac(z, args)),
                     ("lm_run", lambda: run_(z, args))):
        jax.block_until_ready(fn())
        t = []
        for _ in range(3):
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn())
            t.append((time.perf_counter() - t0, time.process_time() - c0))
        out[name] = {"wall_s": round(float(np.median([x for x, _ in t])), 3),
                     "cpu_s": round(float(np.median([y for _, y in t])), 3)}
    return out
