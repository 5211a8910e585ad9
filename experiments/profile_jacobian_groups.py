"""What each column group of the physical local solve's Jacobian costs, and other ways to form it.

Fits one photo of a folder of cases (``--data``, as ``experiments/bench_map.py`` reads them:
the case's map, background photo and illuminant, no stated view) as ``bubblefit fit`` does
(default ``auto``, ``--thickness``), keeping every local solve's arguments; then takes the
costliest solve (the physical model's local fit) at its start and times, each jitted alone,
median CPU and wall milliseconds of 3 calls after the first, with each program's compile CPU
seconds and HLO instruction count (``--compile final``: compiled with the final solve's
XLA options, :data:`bubblefit.inverse._programs.FINAL_COMPILE`, as the fit compiles it):

- a render of its fitted pixels (the residual);
- each group of :attr:`~bubblefit.inverse._parameters.ParameterTable.jacobian_groups`
  alone (``jax.jacfwd`` of the residual along that group's parameters, the others held);
- the whole Jacobian by those groups (:func:`~bubblefit.inverse._lm.column_jacobian`), by
  other groupings of the same columns, by columns (:func:`~bubblefit.inverse._lm.columns_linearized`)
  and by one ``jax.jacfwd`` of every column, each with its largest difference from the
  groups' Jacobian.

    PYTHONPATH=. python experiments/profile_jacobian_groups.py --data experiments/results/photos320 \\
        ref_const380_sunset_ortho_320 constant OUT.json
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "validation"))
sys.path.insert(0, str(HERE))

from bubblefit.io.jaxcache import jax_setup  # noqa: E402

jax_setup()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import bench_map  # noqa: E402
from stage_timer import keep_solves  # noqa: E402
import bubblefit.inverse._programs as P  # noqa: E402
import bubblefit.inverse.fit as F  # noqa: E402
from bubblefit.inverse._lm import _along, column_jacobian, columns_linearized  # noqa: E402
from bubblefit.inverse._parameters import PARAMETERS  # noqa: E402

SOLVES = keep_solves(F)


#: XLA's compiler options of the timed programs (``--compile``): XLA's defaults, or the
#: final solve's (:data:`bubblefit.inverse._programs.FINAL_COMPILE`).
COMPILE = {"default": (), "final": P.FINAL_COMPILE}
_OPTIONS: list = [()]


def jitted(fn, *args) -> tuple:
    """``fn`` compiled for ``args`` with the chosen compiler options (``--compile``): the
    callable, its compile CPU seconds and its optimized program's HLO instruction count."""
    c0 = time.process_time()
    compiled = jax.jit(fn).lower(*args).compile(compiler_options=dict(_OPTIONS[0]) or None)
    cpu = time.process_time() - c0
    text = compiled.as_text() or ""
    n = sum(1 for line in text.splitlines() if " = " in line and not line.lstrip().startswith(("HloModule", "//")))
    return compiled, {"compile_cpu_s": round(cpu, 2), "hlo_instructions": n}


def timeit(fn) -> dict:
    """CPU seconds of the first call, median wall and CPU milliseconds of the next 3."""
    c0 = time.process_time()
    jax.block_until_ready(fn())
    first = time.process_time() - c0
    t = []
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn())
        t.append((time.perf_counter() - t0, time.process_time() - c0))
    return {"first_cpu_s": round(first, 2), "wall_ms": round(1e3 * float(np.median([x for x, _ in t])), 1),
            "cpu_ms": round(1e3 * float(np.median([y for _, y in t])), 1), "load1": round(os.getloadavg()[0], 2)}


def groupings(table) -> dict:
    """The groupings of the free parameters' columns compared with the table's own."""
    g = {"groups (as the solve does)": table.jacobian_groups}
    free = table.free
    disc = tuple(i for i, n in enumerate(free) if n.startswith("disc_"))
    if disc:
        rest = [grp for grp in table.jacobian_groups if not set(grp) & set(disc)]
        g["disc columns apart"] = tuple(rest) + tuple((i,) for i in disc)
        weights = [grp for grp in table.jacobian_groups if any(PARAMETERS[free[i]].reaches == "weights" for i in grp)]
        others = tuple(i for i in range(len(free)) if not any(i in grp for grp in weights))
        g["one group besides the weights"] = tuple(weights) + (others,)
    return g


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("thickness", choices=("constant", "drainage", "map"))
    ap.add_argument("out")
    ap.add_argument("--data", default=None)
    ap.add_argument("--model", default="auto")
    ap.add_argument("--compile", choices=sorted(COMPILE), default="default",
                    help="XLA's compiler options of the timed programs (final: the final solve's)")
    a = ap.parse_args()
    _OPTIONS[0] = COMPILE[a.compile]
    if a.data:
        bench_map.DATA = Path(a.data).resolve()
    photo, env, bg, opts, _ = bench_map.case_options(a.case, a.thickness, a.model)
    c0 = time.process_time()
    r = F.fit_photo(photo.pixels, env, options=opts, background=bg)
    out = {"case": a.case, "thickness": a.thickness, "fit_cpu_s": round(time.process_time() - c0, 2),
           "model": getattr(r, "model", None), "params": {k: float(v) for k, v in r.params.items() if v is not None},
           "stderr": {k: float(v) for k, v in r.stderr.items() if v is not None},
           "solves": [s["row"] for s in SOLVES]}
    print(json.dumps(out), flush=True)
    s = max(SOLVES, key=lambda s: s["row"]["cpu_s"])
    lev, table, solver, vals, env_ = s["args"][:5]
    max_steps = s["args"][5] if len(s["args"]) > 5 else s["kwargs"].get("max_steps")
    key, args, _ = P.solve_program(lev, table, solver, vals, env_, max_steps, s["kwargs"].get("settings", P.SolveSettings()))
    _, resid = P.solver(*key)
    z = jnp.asarray(table.unconstrained(vals), jnp.float32)
    res = {"solve": s["row"], "groups": [[table.free[i] for i in g] for g in table.jacobian_groups]}
    res["compile"] = a.compile
    rj, info = jitted(resid, z, args)
    res["render"] = dict(timeit(lambda: rj(z, args)), **info)
    for g in table.jacobian_groups:
        f, info = jitted(lambda z, args, g=g: jax.jacfwd(_along(resid, tuple(z[i] for i in range(z.shape[0])), g, args))(
            jnp.stack([z[i] for i in g])), z, args)
        res["group " + ",".join(table.free[i] for i in g)] = dict(timeit(lambda: f(z, args)), **info)
        print(json.dumps(res), flush=True)
    ref = None
    for name, groups in groupings(table).items():
        cj, info = jitted(lambda z, args, groups=groups: column_jacobian(resid, groups, z, args), z, args)
        res[name] = dict(timeit(lambda: cj(z, args)), **info, groups=[[table.free[i] for i in g] for g in groups])
        jac = cj(z, args)
        ref = jac if ref is None else ref
        res[name]["max_abs_diff"] = float(jnp.max(jnp.abs(jac - ref)))
        print(json.dumps(res), flush=True)
    for name, fn in (("columns (columns_linearized)", lambda z, args: columns_linearized(resid, z, args)),
                     ("one jax.jacfwd", lambda z, args: jax.jacfwd(lambda zz: resid(zz, args))(z))):
        f, info = jitted(fn, z, args)
        res[name] = dict(timeit(lambda: f(z, args)), **info)
        res[name]["max_abs_diff"] = float(jnp.max(jnp.abs(f(z, args) - ref)))
        print(json.dumps(res), flush=True)
    out["costs"] = res
    Path(a.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
