"""Benchmark of :func:`bubblefit.inverse.fit.fit_photo`: accuracy and warm time.

Renders a bubble photo with known parameters in the shipped courtyard map (with noise
and 8-bit sRGB quantisation), fits it (constant thickness, then a per-pixel map), and
records the first (compiling) and the warm wall time and the errors. Writes
``bench_fit.json``, ``bench_fit.csv`` and ``bench_fit.png`` to ``--out``.

``--profile-solver`` instead times the pieces of one Levenberg-Marquardt step on the
photo's fit level, for the paper and the physical model: a render, ``jax.jacfwd``, and
what optimistix' own ``LevenbergMarquardt`` does per step (``jax.linearize`` plus one
tangent at a trial point, plus materialising the linearisation for its QR solve), and
the whole local solve with bubblefit's solver (Jacobian at accepted points only,
statistical stop) against optimistix' solver from the same start. Writes
``solver_profile.json`` and ``.csv``.

``--whole-process`` times ``bubblefit fit`` as a user runs it (the photo and its
background written as 8-bit PNGs, the shipped courtyard map, ``--thickness constant``,
each model on a photo that model rendered): a first process on an empty compilation
cache, a second on the warm one, and a third on the warm cache with the bubble framed
otherwise (a user's next photo), and the physical model on the paper photo (warm),
against ``python -c "import numpy"`` and Mitsuba 3 (the thin dielectric sphere of
``bench_effects.py``, 256x256, 64 spp; ``--mitsuba-python``) in the same run. Writes
``whole_process.json``.

    python experiments/bench_fit.py [--quick] [--size 256] [--out experiments/results/bench_fit]
    python experiments/bench_fit.py --profile-solver [--size 160]
    python experiments/bench_fit.py --whole-process [--size 320]
    python experiments/bench_fit.py --background-compile [--size 320] [--repeats 5]
    python experiments/bench_fit.py --compile-profile [--size 320]
    python experiments/bench_fit.py --stages [--size 320] [--repeats 5] [--empty-cache]

``--compile-profile`` compiles, in one process with JAX's persistent cache off, the
pieces of each model's final solve program on the photo's fit level (the residual, its
``jax.jacfwd``, its Jacobian by groups of parameters, its Jacobian by columns with the
render's primal shared, the whole Levenberg-Marquardt solve) and records the seconds to
lower and to compile each, the lines of its optimised HLO and its warm run time (the
pieces taking turns, ``--repeats`` rounds): where a first fit's compile time goes, and
what each way to the Jacobian costs to compile against what it costs per call. Writes
``compile_profile.json`` and ``compile_profile.png``.

``--stages`` times the stages of :func:`~bubblefit.inverse.fit.fit_photo` in one process
(the constant-thickness paper fit, the disc found, not given): finding the disc, the rest
of the set-up, the global search (its candidate solves included), the final solve, and
the standard errors with the final render; a first call (on whatever the compilation
cache holds) and ``--repeats`` warm calls, against ``python -c "import numpy"`` timed in
the same run. Writes ``stages.json`` and ``stages.png``; with ``--empty-cache`` JAX's
persistent cache is off, so that the first call compiles every program it needs (but those
that rendered the photo in the same process), and the files are
``stages_empty_cache.json`` and ``.png``.

``--background-compile`` measures what compiling the final solve and the final render in
a background thread during the global search saves (:meth:`bubblefit.io.executables.Stored.prepare`):
``bubblefit fit`` on an empty compilation cache, per model, in pairs (the background
compile on, then off; the pairs one after the other so that the machine's load hits both
alike), and the paired differences. Writes ``background_compile.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import time
from pathlib import Path

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="64 px images, one repeat")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--env-height", type=int, default=128, help="height the map is downsampled to")
    ap.add_argument("--samples", type=int, default=0, help="spectral samples of the fit (0: auto)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-map", action="store_true")
    ap.add_argument("--profile-solver", action="store_true", help="time the pieces of an LM step (see above)")
    ap.add_argument("--models", default="paper,physical", help="models for --profile-solver, --whole-process")
    ap.add_argument("--whole-process", action="store_true", help="time bubblefit fit as processes (see above)")
    ap.add_argument("--compile-profile", action="store_true", help="compile times of the solve's pieces (see above)")
    ap.add_argument("--stages", action="store_true", help="seconds per stage of an in-process fit (see above)")
    ap.add_argument("--empty-cache", action="store_true", help="--stages with JAX's persistent cache off")
    ap.add_argument("--background-compile", action="store_true",
                    help="empty-cache fits with and without the background compile, in pairs (see above)")
    ap.add_argument("--mitsuba-python", default=None, help="python with mitsuba 3 (default: bench_effects')")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_fit"))
    args = ap.parse_args()
    import jax

    if args.compile_profile or args.empty_cache:  # every program compiled afresh (decided at the first compile)
        jax.config.update("jax_enable_compilation_cache", False)
    else:
        cache = os.environ.get("BUBBLEFIT_CACHE_DIR", str(Path(__file__).resolve().parent.parent / ".jax_cache"))
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

    from scipy import ndimage as ndi

    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.io.images import read_image, srgb_decode, srgb_encode
    from bubblefit.model.scene import Scene, render_scene, shipped_envmap

    n = 64 if args.quick else args.size
    repeats = 1 if args.quick else args.repeats
    args.whole_process |= args.background_compile
    if args.whole_process:  # the map exactly as the command line reads it
        from bubblefit.cli.fit import load_envmap

        env = load_envmap(str(shipped_envmap("courtyard")))
    else:
        px = read_image(shipped_envmap("courtyard")).pixels
        while px.shape[0] > args.env_height:
            px = downsample(px)
        env = EnvMap.from_array(px)
    rng = np.random.default_rng(0)
    disc = (n / 2, n / 2, 0.42 * n)
    bg = ndi.gaussian_filter(rng.uniform(0.15, 0.6, (n, n, 3)), (n / 20, n / 20, 0))
    q = lambda im: srgb_decode(np.round(srgb_encode(im + rng.normal(0, 0.003, im.shape)) * 255) / 255)
    truth = {"t": 0.97, "roughness": 0.08, "thickness_nm": 720.0}
    scene = Scene.from_dict({"camera": {"width": n, "height": n, "disc": list(disc)}, "bubble": truth,
                             "lighting": {"envmap": "x.exr"}, "effects": {"transmission_tint": True}})
    photo = q(render_scene(scene, bg, env=env))
    effects = (("spectral", {"method": "uniform", "samples": args.samples}),) if args.samples else ()
    if args.whole_process:
        # The same bubble framed otherwise (disc moved by 1 % of the photo, 5 % smaller): a
        # user's next photo, which the warm cache may not serve.
        bg_photo = q(bg)  # drawn before the second photo's noise: the first pair as before
        moved = (disc[0] + 0.01 * n, disc[1] - 0.006 * n, 0.95 * disc[2])
        other = Scene.from_dict({"camera": {"width": n, "height": n, "disc": list(moved)}, "bubble": truth,
                                 "lighting": {"envmap": "x.exr"}, "effects": {"transmission_tint": True}})
        photo2 = q(render_scene(other, bg, env=env))
        # Each model fits a photo it explains: the physical model's photo is rendered by it
        # (the paper photo as well, as one more row: it does not explain that one).
        photos = {"paper": (photo, photo2)}
        if "physical" in args.models.split(","):
            phys = lambda d: Scene.from_dict({"camera": {"width": n, "height": n, "disc": list(d)}, "bubble": truth,
                                              "lighting": {"envmap": "x.exr"}, "effects": {"model": "physical"}})
            photos["physical"] = (q(render_scene(phys(disc), bg, env=env)), q(render_scene(phys(moved), bg, env=env)))
        if args.background_compile:
            return background_compile(photos, bg_photo, Path(args.out), args.models.split(","), args.repeats)
        return whole_process(photos, bg_photo, Path(args.out), args.models.split(","), args.mitsuba_python)
    if args.compile_profile:
        return compile_profile(photo, env, q(bg), Path(args.out), args.models.split(","), max(args.repeats, 3))
    if args.stages:
        return stages(photo, env, q(bg), Path(args.out), max(args.repeats, 1),
                      "stages_empty_cache" if args.empty_cache else "stages")
    if args.profile_solver:
        return profile_solver(photo, env, q(bg), truth, Path(args.out), args.models.split(","))
    rows = []
    for kind in ("constant",) + (() if args.no_map else ("map",)):
        opts = FitOptions(thickness=kind, disc=disc, parameters=starts(t=0.965, roughness=0.04), effects=effects,
                              model="paper", view=ORTHOGRAPHIC)
        for rep in range(repeats + 1):
            t0 = time.perf_counter()
            res = fit_photo(photo, env, options=opts, background=q(bg))
            wall = time.perf_counter() - t0
            row = {"kind": kind, "size": n, "run": "first" if rep == 0 else "warm", "time_s": round(wall, 3),
                   "converged": res.converged, "iterations": res.iterations,
                   "thickness_err_nm": round(abs(res.params["thickness_nm"] - truth["thickness_nm"]), 3),
                   "thickness_stderr_nm": res.stderr.get("thickness_nm"),
                   "t_err": round(abs(res.params["t"] - truth["t"]), 5),
                   "roughness_rel_err": round(abs(res.params["roughness"] / truth["roughness"] - 1), 4),
                   "residual_rms": res.residual_rms}
            if kind == "map":
                m = res.thickness_map
                used = np.isfinite(res.thickness_stderr_map)
                row["map_median_err_nm"] = float(np.median(np.abs(m[used] - truth["thickness_nm"])))
            print(json.dumps(row))
            rows.append(row)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_fit.json").write_text(json.dumps(rows, indent=2))
    keys = sorted({k for r in rows for k in r})
    with open(out / "bench_fit.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3))
    labels = [f"{r['kind']}\n{r['run']}" for r in rows]
    ax.bar(range(len(rows)), [r["time_s"] for r in rows])
    ax.set_xticks(range(len(rows)), labels, fontsize=7)
    ax.set_ylabel("wall time (s)")
    ax.set_title(f"fit_photo, {n}x{n}")
    fig.tight_layout()
    fig.savefig(out / "bench_fit.png", dpi=100)
    print(f"wrote {out}/bench_fit.json, .csv, .png")


def _clock(fn, *a, repeats=3):
    """(first call, median of ``repeats`` warm calls) in seconds (``accuracy_vs_time.timed``)."""
    from accuracy_vs_time import timed

    _, warm, extra = timed(lambda: fn(*a), repeats)
    return warm + extra, warm


def profile_solver(photo, env, bg, truth, out: Path, models=("paper", "physical")):
    """The pieces of one LM step and the whole local solve, per model (module docstring)."""
    import jax
    import jax.numpy as jnp
    import lineax as lx
    import optimistix as optx

    from bubblefit.inverse import _lm, _programs, _setup
    from bubblefit.inverse.fit import FitOptions
    from bubblefit.model.render import render

    rows = []
    for model in models:
        opts = FitOptions(model=model)
        init = {"thickness_nm": truth["thickness_nm"] + 6.0, "roughness": 0.05}
        st = _setup.setup(photo, env, opts, bg, init, None, None)
        lev, table = st.lev_fit, st.table
        fixed = _programs.held_values(table, st.vals)
        args = (fixed, env, None if lev.bg is None else jnp.asarray(lev.bg), jnp.asarray(lev.y), jnp.asarray(lev.w))
        z0 = jnp.asarray(table.unconstrained(st.vals), jnp.float32)

        def resid(z, a):
            fx, e, b, y, w = a
            img = render(table.render_params(table.values(z, fx)), lev.cfg, e, b)
            return _lm.robust((img - y) * w, float(opts.solver.robust_scale)).reshape(-1)

        def lin_tangent(z, a):
            f, lin = jax.linearize(lambda u: resid(u, a), z)
            return f, lin(jnp.ones_like(z))

        def lin_matrix(z, a):
            f, lin = jax.linearize(lambda u: resid(u, a), z)
            return f, lx.FunctionLinearOperator(lin, jax.eval_shape(lambda: z)).as_matrix()

        row = {"model": model, "level": "x".join(map(str, lev.y.shape[:2])), "free": len(table.free)}
        for name, fn in (("render", resid), ("jacfwd", jax.jacfwd(resid)), ("linearize_1_tangent", lin_tangent),
                         ("linearize_as_matrix", lin_matrix)):
            first, warm = _clock(jax.jit(fn), z0, args)
            row[f"{name}_ms"] = round(1000 * warm, 1)
            row[f"{name}_first_s"] = round(first, 2)
        tol = dict(rtol=float(opts.solver.rtol), atol=float(opts.solver.atol))
        for label, lm in (("bubblefit", _lm.LevenbergMarquardt(**tol)), ("optimistix", optx.LevenbergMarquardt(**tol))):
            def run(z, a, lm=lm):
                sol = optx.least_squares(resid, lm, z, a, max_steps=int(opts.solver.max_steps), throw=False)
                return sol.value, sol.stats["num_steps"]

            solve = jax.jit(run)
            first, warm = _clock(solve, z0, args, repeats=1)
            z, steps = solve(z0, args)
            vals = table.values(z, fixed)
            row[f"solve_{label}_s"] = round(warm, 2)
            row[f"solve_{label}_first_s"] = round(first, 2)
            row[f"solve_{label}_steps"] = int(steps)
            row[f"solve_{label}_thickness_nm"] = round(float(vals["thickness_nm"]), 3)
        row["solve_speedup"] = round(row["solve_optimistix_s"] / row["solve_bubblefit_s"], 2)
        print(json.dumps(row), flush=True)
        rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    (out / "solver_profile.json").write_text(json.dumps(rows, indent=2))
    with open(out / "solver_profile.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot_solver_profile(rows, out)
    print(f"wrote {out}/solver_profile.json, .csv, .png")


def compile_profile(photo, env, bg, out: Path, models=("paper", "physical"), repeats: int = 10):
    """Lowering and compile seconds, optimised HLO lines and warm run milliseconds of the
    pieces of each model's final solve program (module docstring), and the largest
    difference of each Jacobian from ``jax.jacfwd``'s relative to its largest entry. The
    warm runs take turns (one call of each piece per round, ``repeats`` rounds), so that
    the machine's load hits every piece alike; the median and the minimum are recorded."""
    import jax

    from bubblefit.inverse import _lm, _programs, _setup
    from bubblefit.inverse.fit import FitOptions

    rows = []
    for model in models:
        opts = FitOptions(model=model)
        st = _setup.setup(photo, env, opts, bg, None, None, None)
        key, a, _ = _programs.solve_program(st.lev_fit, st.table, opts.solver, st.vals, env, None,
                                             _programs.FINAL_SOLVE)
        solve, resid = _programs.solver.__wrapped__(*key)  # fresh jitted functions, compiled here
        z0 = st.table.unconstrained(st.vals)
        groups = st.table.jacobian_groups
        row = {"model": model, "free": len(st.table.free), "groups": len(groups), "pixels": int(a[3].size // 3)}
        pieces = (("residual", resid), ("jacfwd", jax.jit(jax.jacfwd(resid))),
                  ("jacobian_by_groups", jax.jit(lambda z, a: _lm.column_jacobian(resid, groups, z, a))),
                  ("jacobian_by_columns", jax.jit(lambda z, a: _lm.columns_linearized(resid, z, a))),
                  ("solve", solve))
        compiled = {}
        for name, fn in pieces:
            t0 = time.perf_counter()
            lowered = fn.lower(z0, a)
            t1 = time.perf_counter()
            compiled[name] = lowered.compile()
            t2 = time.perf_counter()
            row[f"{name}_lower_s"] = round(t1 - t0, 2)
            row[f"{name}_compile_s"] = round(t2 - t1, 2)
            row[f"{name}_hlo_lines"] = len(compiled[name].as_text().splitlines())
        ref = np.asarray(compiled["jacfwd"](z0, a))
        for name in ("jacobian_by_groups", "jacobian_by_columns"):
            diff = np.max(np.abs(np.asarray(compiled[name](z0, a)) - ref)) / np.max(np.abs(ref))
            row[f"{name}_max_rel_diff"] = float(f"{diff:.2g}")
            if not diff < 1e-3:  # float32 rounding is 1e-5 of the largest entry; more is a wrong Jacobian
                raise SystemExit(f"{model}: {name} differs from jax.jacfwd by {diff:.2g} of its largest entry")
        seconds = {name: [] for name in compiled}
        for _ in range(repeats):
            for name, fn in compiled.items():
                t0 = time.perf_counter()
                jax.block_until_ready(fn(z0, a))
                seconds[name].append(time.perf_counter() - t0)
        for name, s in seconds.items():
            row[f"{name}_run_ms"] = round(1000 * float(np.median(s)), 1)
            row[f"{name}_run_min_ms"] = round(1000 * float(np.min(s)), 1)
        print(json.dumps(row), flush=True)
        rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compile_profile.json").write_text(json.dumps(rows, indent=2))
    plot_compile_profile(rows, out)
    print(f"wrote {out}/compile_profile.json, .png")


def plot_compile_profile(rows, out: Path):
    """Compile seconds against warm run milliseconds of each way to compute the Jacobian,
    per model: the trade :func:`compile_profile` measures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for row, marker in zip(rows, "os^"):
        for name, label in (("jacfwd", "jax.jacfwd"), ("jacobian_by_groups", "by groups (search, warm starts)"),
                            ("jacobian_by_columns", "by columns, primal shared (final solve)")):
            x, y = row[f"{name}_compile_s"], row[f"{name}_run_ms"]
            ax.plot(x, y, marker, color="k")
            ax.annotate(f"{row['model']}: {label}", (x, y), fontsize=6, xytext=(4, 2), textcoords="offset points")
    ax.margins(x=0.45, y=0.1)
    ax.set_xlabel("compile (s, persistent cache off)")
    ax.set_ylabel("warm run (ms, median)")
    ax.set_title("Jacobian of the final solve's residual", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "compile_profile.png", dpi=110)
    plt.close(fig)


def numpy_yardstick(repeats: int = 3) -> float:
    """Median seconds of ``python -c "import numpy"`` as a process: the start-up yardstick."""
    import subprocess
    import sys

    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import numpy"], check=True)
        seconds.append(time.perf_counter() - t0)
    return float(np.median(seconds))


#: The stages :func:`stages` times: the function of ``bubblefit.inverse.fit`` (or of
#: ``bubblefit.inverse._setup`` for the disc) that each is (the finish: judging the
#: solve and reporting it, both).
STAGES = (("disc", "_setup", "_disc"), ("setup", "fit", "setup"), ("search", "fit", "_searched_start"),
          ("local solve", "fit", "solve_local"), ("finish", "fit", "_judge"), ("finish", "fit", "_report"),
          ("final render", "fit", "render_bubble"))


def stages(photo, env, bg, out: Path, repeats: int, stem: str = "stages"):
    """Seconds per stage of ``fit_photo`` in one process, first and warm calls (module
    docstring). A stage's time includes the stages called inside it: the set-up includes
    finding the disc, the search its candidate solves (which ``local solve`` does not
    count), the finish the final render; the plot's "between stages" is the rest of the
    call (on a first call, tracing the final solve to compile it in the background)."""
    import bubblefit.inverse._setup as setup_module
    import bubblefit.inverse.fit as fit_module
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions

    modules = {"fit": fit_module, "_setup": setup_module}
    spent, depth = {}, {"search": 0}

    def timed(stage, fn):
        def call(*a, **k):
            t0 = time.perf_counter()
            if stage == "search":
                depth["search"] += 1
            try:
                return fn(*a, **k)
            finally:
                if stage == "search":
                    depth["search"] -= 1
                if not (stage == "local solve" and depth["search"]):
                    spent[stage] = spent.get(stage, 0.0) + time.perf_counter() - t0
        return call

    originals = [(modules[m], name, getattr(modules[m], name)) for _, m, name in STAGES]
    for (stage, _, _), (mod, name, fn) in zip(STAGES, originals):
        setattr(mod, name, timed(stage, fn))
    rows = []
    try:
        for i in range(repeats + 1):
            spent.clear()
            t0, c0 = time.perf_counter(), os.times()
            res = fit_module.fit_photo(photo, env, options=FitOptions(thickness="constant", model="paper", view=ORTHOGRAPHIC), background=bg)
            c1 = os.times()
            row = {"run": "first" if i == 0 else "warm", "total_s": round(time.perf_counter() - t0, 4),
                   "cpu_s": round(c1.user + c1.system - c0.user - c0.system, 2)}
            row.update({f"{k}_s": round(v, 4) for k, v in spent.items()})
            row.update(thickness_nm=res.params["thickness_nm"], ok=res.ok, iterations=res.iterations)
            print(json.dumps(row), flush=True)
            rows.append(row)
    finally:
        for mod, name, fn in originals:
            setattr(mod, name, fn)
    warm = [r for r in rows if r["run"] == "warm"]
    keys = [k for k in rows[-1] if k.endswith("_s")]
    summary = {"size": int(photo.shape[0]), "numpy_import_s": numpy_yardstick(),
               "warm_median": {k: float(np.median([r.get(k, 0.0) for r in warm])) for k in keys}}
    summary["warm_total_over_numpy"] = summary["warm_median"]["total_s"] / summary["numpy_import_s"]
    print(json.dumps(summary, indent=1))
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.json").write_text(json.dumps({"calls": rows, **summary}, indent=2))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # the stages that do not contain one another: disc, rest of the set-up, search, final solve, finish
    parts = (("disc", lambda r: r.get("disc_s", 0.0)),
             ("rest of set-up", lambda r: r.get("setup_s", 0.0) - r.get("disc_s", 0.0)),
             ("search", lambda r: r.get("search_s", 0.0)), ("final solve", lambda r: r.get("local solve_s", 0.0)),
             ("final render", lambda r: r.get("final render_s", 0.0)),
             ("errors, rest", lambda r: r.get("finish_s", 0.0) - r.get("final render_s", 0.0)),
             ("between stages", lambda r: r["total_s"] - r.get("setup_s", 0.0) - r.get("search_s", 0.0)
              - r.get("local solve_s", 0.0) - r.get("finish_s", 0.0)))
    bars = {"first call": rows[0], "warm (median)": summary["warm_median"]}
    fig, axes = plt.subplots(len(bars), 1, figsize=(6.5, 3.2))
    for ax, (label, row) in zip(axes, bars.items()):
        left = 0.0
        for i, (name, get) in enumerate(parts):
            v = get(row)
            ax.barh(0, v, left=left, color=f"C{i}", label=name)
            left += v
        ax.text(row["total_s"], 0, f" {row['total_s']:.2f} s", va="center", fontsize=8)
        ax.set_xlim(0, 1.15 * row["total_s"])
        ax.set_yticks([0], [label])
    axes[-1].set_xlabel("seconds")
    axes[0].set_title(f"fit_photo in one process, {photo.shape[0]} px, constant thickness "
                      f"(python -c 'import numpy': {summary['numpy_import_s']:.2f} s)", fontsize=8)
    axes[0].legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.35), frameon=False)
    fig.tight_layout()
    fig.savefig(out / f"{stem}.png", dpi=110)
    print(f"wrote {out}/{stem}.json, {stem}.png")


def plot_solver_profile(rows, out: Path):
    """Bars: the pieces of a step (left) and the whole solve per solver (right), per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.2))
    pieces = ("render", "jacfwd", "linearize_1_tangent", "linearize_as_matrix")
    x = np.arange(len(pieces))
    for i, r in enumerate(rows):
        ax1.bar(x + 0.4 * i, [r[f"{p}_ms"] for p in pieces], 0.4, label=r["model"])
        ax2.bar(np.arange(2) + 0.4 * i, [r["solve_bubblefit_s"], r["solve_optimistix_s"]], 0.4, label=r["model"])
        for j, k in enumerate(("bubblefit", "optimistix")):
            ax2.text(j + 0.4 * i, r[f"solve_{k}_s"], f"{r[f'solve_{k}_steps']} steps", ha="center", va="bottom",
                     fontsize=7)
    ax1.set_xticks(x + 0.2, ["render", "jacfwd", "linearize\n+1 tangent", "linearize\n+materialise"], fontsize=7)
    ax1.set_ylabel("ms per call (warm)")
    ax1.set_title(f"pieces of an LM step, {rows[0]['level']} level", fontsize=9)
    ax2.set_xticks([0.2, 1.2], ["bubblefit LM", "optimistix LM"], fontsize=8)
    ax2.set_ylabel("local solve (s, warm)")
    ax2.set_title("whole local solve, same start", fontsize=9)
    for ax in (ax1, ax2):
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "solver_profile.png", dpi=110)


def whole_process(photos: dict, bg, out: Path, models, mitsuba_python=None):
    """Whole-process seconds of ``bubblefit fit`` per model on that model's photo
    (``photos[model]``: the photo and the bubble framed otherwise), cold and warm cache,
    then the framed-otherwise photo on the warm cache, the physical model on the paper
    photo (which it does not explain) warm, and the yardsticks of the same run (module
    docstring)."""
    import subprocess
    import sys
    import tempfile

    from bench_effects import MAPS, MITSUBA_PYTHON, MITSUBA_SCRIPT

    from bubblefit.io.images import write_image

    here = Path(__file__).resolve().parent
    mitsuba_python = mitsuba_python or MITSUBA_PYTHON
    rows = {"size": int(photos["paper"][0].shape[0])}

    def clock(cmd, env=None):
        t0 = time.perf_counter()
        done = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"{' '.join(map(str, cmd))} failed: {done.stderr.strip().splitlines()[-1:]}")
        return time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_image(tmp / "bg.png", np.clip(bg, 0, 1), bit_depth=8)
        rows["numpy_import_s"] = numpy_yardstick()

        def fit(model, photo, name, env):
            write_image(tmp / f"{name}.png", np.clip(photo, 0, 1), bit_depth=8)
            seconds = clock([sys.executable, "-m", "bubblefit", *_fit_args(tmp, name, model)], env)
            return seconds, json.loads((tmp / f"{name}.json").read_text())

        for model in models:
            env = dict(os.environ, BUBBLEFIT_CACHE_DIR=str(tmp / f"cache-{model}"), JAX_PLATFORMS="cpu",
                       PYTHONPATH=str(here.parent))
            first, other = photos[model]
            rows[f"fit_{model}_cold_s"], _ = fit(model, first, f"{model}-photo", env)
            rows[f"fit_{model}_warm_s"], res = fit(model, first, f"{model}-photo", env)
            rows[f"fit_{model}_new_framing_s"], _ = fit(model, other, f"{model}-other", env)
            rows[f"fit_{model}_thickness_nm"] = res["params"]["thickness_nm"]
            rows[f"fit_{model}_iterations"] = res["iterations"]
            rows[f"fit_{model}_ok"] = res["ok"]
            if model == "physical":
                rows["fit_physical_on_paper_photo_warm_s"], res = fit(model, photos["paper"][0], "mismatch", env)
                rows["fit_physical_on_paper_photo_ok"] = res["ok"]
        if Path(mitsuba_python).exists():
            rows["mitsuba_64spp_s"] = clock([mitsuba_python, "-c", MITSUBA_SCRIPT, "256", str(MAPS / "sunrise.exr"),
                                             str(tmp / "m.exr")])
    if "fit_paper_warm_s" in rows and "fit_physical_warm_s" in rows:  # the "physical within 2x of paper"
        rows["physical_over_paper_warm"] = rows["fit_physical_warm_s"] / rows["fit_paper_warm_s"]
    for k in [k for k in rows if k.startswith("fit_") and k.endswith(("_cold_s", "_warm_s", "_framing_s"))]:
        rows[k[:-2] + "_over_numpy"] = rows[k] / rows["numpy_import_s"]
        if "mitsuba_64spp_s" in rows:
            rows[k[:-2] + "_over_mitsuba"] = rows[k] / rows["mitsuba_64spp_s"]
    print(json.dumps(rows, indent=1))
    out.mkdir(parents=True, exist_ok=True)
    (out / "whole_process.json").write_text(json.dumps(rows, indent=2))
    print(f"wrote {out}/whole_process.json")


#: ``bubblefit fit`` with the background compile of the fit's last programs turned off.
_NO_BACKGROUND = ("import sys, bubblefit.inverse._programs as f; f.prepare_local = f.prepare_render_bubble = "
                  "lambda *a, **k: None; from bubblefit.cli import main; sys.exit(main(sys.argv[1:]))")


def _fit_args(tmp: Path, name: str, model: str) -> list:
    """``bubblefit fit``'s arguments for the photo ``tmp/NAME.png`` over ``tmp/bg.png`` in the
    shipped courtyard map, constant thickness, the JSON to ``tmp/NAME.json``."""
    from bubblefit.model.scene import shipped_envmap

    return ["fit", str(tmp / f"{name}.png"), "--envmap", str(shipped_envmap("courtyard")), "--background",
            str(tmp / "bg.png"), "--thickness", "constant", "--model", model, "--json", str(tmp / f"{name}.json"),
            "-o", str(tmp / name)]


def background_compile(photos: dict, bg, out: Path, models, repeats: int):
    """Seconds of ``bubblefit fit`` on an empty cache with the background compile on and
    off, in ``repeats`` pairs per model (module docstring)."""
    import subprocess
    import sys
    import tempfile

    from bubblefit.io.images import write_image

    here = Path(__file__).resolve().parent
    rows = {"size": int(photos["paper"][0].shape[0]), "pairs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_image(tmp / "bg.png", np.clip(bg, 0, 1), bit_depth=8)
        for model in models:
            write_image(tmp / f"{model}.png", np.clip(photos[model][0], 0, 1), bit_depth=8)
            fit = _fit_args(tmp, model, model)
            pairs = []
            for k in range(repeats):
                pair = {}
                for how, head in (("on", ["-m", "bubblefit"]), ("off", ["-c", _NO_BACKGROUND])):
                    cache = tmp / f"cache-{model}-{k}-{how}"
                    env = dict(os.environ, BUBBLEFIT_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu",
                               PYTHONPATH=str(here.parent))
                    t0 = time.perf_counter()
                    done = subprocess.run([sys.executable, *head, *fit], env=env, capture_output=True, text=True)
                    if done.returncode != 0:
                        raise SystemExit(f"bubblefit fit failed: {done.stderr.strip().splitlines()[-1:]}")
                    pair[how] = time.perf_counter() - t0
                    pair[f"{how}_thickness_nm"] = json.loads((tmp / f"{model}.json").read_text())["params"]["thickness_nm"]
                print(model, json.dumps({k: round(v, 3) for k, v in pair.items()}), flush=True)
                pairs.append(pair)
            diff = np.array([p["off"] - p["on"] for p in pairs])
            rows["pairs"][model] = pairs
            rows[f"{model}_on_median_s"] = float(np.median([p["on"] for p in pairs]))
            rows[f"{model}_off_median_s"] = float(np.median([p["off"] for p in pairs]))
            rows[f"{model}_saved_mean_s"] = float(diff.mean())
            rows[f"{model}_saved_stderr_s"] = float(diff.std(ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else None
    print(json.dumps({k: v for k, v in rows.items() if k != "pairs"}, indent=1))
    out.mkdir(parents=True, exist_ok=True)
    (out / "background_compile.json").write_text(json.dumps(rows, indent=2))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3))
    for i, model in enumerate(models):
        for p in rows["pairs"][model]:
            ax.plot([2 * i, 2 * i + 1], [p["off"], p["on"]], "o-", color=f"C{i}", alpha=0.7)
    ax.set_xticks(range(2 * len(models)), [f"{m}\n{how}" for m in models for how in ("off", "on")], fontsize=8)
    ax.set_ylabel("empty-cache fit, whole process (s)")
    ax.set_title("background compile of the last programs, paired runs")
    fig.tight_layout()
    fig.savefig(out / "background_compile.png", dpi=100)
    print(f"wrote {out}/background_compile.json, .png")


if __name__ == "__main__":
    main()
