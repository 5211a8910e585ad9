"""Where the time of a ``bubblefit`` command goes: start-up, imports, tracing, compiling,
persistent-cache loads and host transfers (issue "fast enough to use interactively").

Measured in one run, whole processes, medians of ``--repeat`` calls:

1. the yardstick ``python -c "import numpy"``;
2. ``bubblefit --help``, ``bubblefit CMD --help`` for every command, ``--version`` and an
   argument error, each as a ratio to the yardstick (the goal: within 3x);
3. the import of each heavy library alone (JAX, OpenImageIO, colour-science, OpenCV,
   Dask distributed, SciPy, Matplotlib) and of the modules each command's ``run`` loads;
4. a small ``render`` and ``chart`` (and, without ``--quick``, a 48x48 ``fit``) run in a
   child process that records JAX's own monitoring events: tracing to a jaxpr, lowering
   to MLIR, XLA compiles, persistent-cache retrievals, and the time spent copying results
   to the host, with an empty and with a warm compilation cache.

Prints a table and writes ``profile_startup.json`` and ``profile_startup.png`` under
``--out`` (default ``experiments/results/profile_startup``).

    python experiments/profile_startup.py [--quick] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PY = sys.executable
COMMANDS = ("render", "chart", "envmap", "check-capture", "calibrate", "fit", "fit-sequence", "demo")
LIBRARIES = {"jax": "import jax", "OpenImageIO": "import OpenImageIO", "colour": "import colour",
             "cv2": "import cv2", "distributed": "import distributed", "scipy": "import scipy.optimize",
             "matplotlib": "import matplotlib.pyplot"}
RUN_IMPORTS = {  # what each command's run imports before it does any work
    "render": "import bubblefit.model.scene, bubblefit.io.images",
    "chart": "import bubblefit.optics.chart, bubblefit.io.images, matplotlib.pyplot",
    "envmap": "import bubblefit.capture.probe, bubblefit.io.images",
    "calibrate": "import bubblefit.capture.calibrate",
    "check-capture": "import bubblefit.capture.protocols",
    "fit": "import bubblefit.inverse.fit, bubblefit.model.scene",
    "fit-sequence": "import bubblefit.inverse.sequence, distributed",
}


def _env(cache: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.setdefault("JAX_PLATFORMS", "cpu")
    if cache:
        env["BUBBLEFIT_CACHE_DIR"] = cache
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
    return env


def wall(argv: list[str], repeat: int, env=None) -> float:
    """Median wall time of a whole process, seconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env or _env(), cwd=ROOT)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


# ------------------------------------------------------------------------------------------
# the child: one command in this process, JAX's monitoring events summed
# ------------------------------------------------------------------------------------------
EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
    "/jax/compilation_cache/cache_retrieval_time_sec": "cache_load_s",
}


def child(argv: list[str]) -> None:
    """Run ``bubblefit argv`` here and print one JSON line: imports, JAX events, transfers."""
    t_start = time.perf_counter()
    sums = {v: 0.0 for v in EVENTS.values()} | {"compiles": 0, "cache_hits": 0, "transfer_s": 0.0, "transfers": 0}
    from bubblefit.io.jaxcache import jax_setup

    jax_setup()
    t0 = time.perf_counter()
    import jax
    import numpy as np

    import_jax_s = time.perf_counter() - t0

    def on_duration(event, duration, **_):
        key = EVENTS.get(event)
        if key:
            sums[key] += duration
            sums["compiles"] += key == "compile_s"

    def on_event(event, **_):
        sums["cache_hits"] += event == "/jax/compilation_cache/cache_hits"

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(on_event)
    real_asarray = np.asarray

    def timed_asarray(a, *args, **kw):  # device -> host copies of JAX arrays
        if isinstance(a, jax.Array):
            t = time.perf_counter()
            out = real_asarray(jax.device_get(a), *args, **kw)
            sums["transfer_s"] += time.perf_counter() - t
            sums["transfers"] += 1
            return out
        return real_asarray(a, *args, **kw)

    np.asarray = timed_asarray
    from bubblefit.cli import main

    t0 = time.perf_counter()
    exec(RUN_IMPORTS.get(argv[0], "pass"))  # the command's own imports, timed apart from its work
    run_imports_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    rc = main(argv)
    run_s = time.perf_counter() - t0
    np.asarray = real_asarray
    mods = ("jax", "OpenImageIO", "colour", "cv2", "distributed", "scipy", "matplotlib")
    print("PROFILE " + json.dumps(dict(sums, rc=rc, import_jax_s=import_jax_s, run_imports_s=run_imports_s,
                                       run_s=run_s,
                                       total_s=time.perf_counter() - t_start,
                                       loaded=[m for m in mods if m in sys.modules])))


def profile_command(argv: list[str], cache: str) -> dict:
    """A child run of ``argv`` with the persistent cache in ``cache``: its JSON line and wall time."""
    t0 = time.perf_counter()
    r = subprocess.run([PY, __file__, "--child", *argv], capture_output=True, text=True, env=_env(cache), cwd=ROOT)
    wall_s = time.perf_counter() - t0
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("PROFILE ")]
    if not lines:
        return {"error": (r.stderr.strip().splitlines() or ["no output"])[-1], "wall_s": wall_s}
    out = json.loads(lines[-1][len("PROFILE "):])
    out["wall_s"] = wall_s
    out["other_s"] = out["run_s"] - sum(out[k] for k in ("trace_s", "lower_s", "compile_s", "cache_load_s",
                                                         "transfer_s"))
    return out


def _inputs(tmp: Path) -> dict:
    """A small scene (64x64, shipped map) and, for the fit, a 48x48 photo rendered from it."""
    scene = tmp / "scene.toml"
    scene.write_text('[camera]\nwidth = 64\nheight = 64\n\n[bubble]\nthickness_nm = 600.0\nroughness = 0.02\n\n'
                     '[lighting]\nenvmap = "courtyard.exr"\n')
    fit_scene = tmp / "fit_scene.toml"
    fit_scene.write_text('[camera]\nwidth = 48\nheight = 48\ndisc = [24.0, 24.0, 20.0]\n\n[bubble]\n'
                         'thickness_nm = 600.0\nroughness = 0.02\n\n[lighting]\nenvmap = "courtyard.exr"\n')
    return {"scene": scene, "fit_scene": fit_scene}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="calls per start-up measurement (median) [3]")
    ap.add_argument("--quick", action="store_true", help="skip the fit profile")
    ap.add_argument("--startup-only", action="store_true", help="only the start-up ratios (no imports, no profiles)")
    ap.add_argument("--out", default=str(HERE / "results" / "profile_startup"))
    ap.add_argument("--child", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        child(args.child)
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    bf = [PY, "-m", "bubblefit"]
    numpy_s = wall([PY, "-c", "import numpy"], args.repeat)
    startup = {"bubblefit --help": wall(bf + ["--help"], args.repeat),
               "bubblefit --version": wall(bf + ["--version"], args.repeat),
               "bubblefit fit (missing arguments)": wall(bf + ["fit"], args.repeat)}
    for cmd in COMMANDS:
        startup[f"bubblefit {cmd} --help"] = wall(bf + [cmd, "--help"], args.repeat)
    libraries, run_imports, profiles = {}, {}, {}
    if not args.startup_only:
        libraries = {name: wall([PY, "-c", code], args.repeat) - numpy_s for name, code in LIBRARIES.items()}
        run_imports = {cmd: wall([PY, "-c", code], args.repeat) for cmd, code in RUN_IMPORTS.items()}
    with tempfile.TemporaryDirectory(prefix="bf_profile_") as tmpdir:
        tmp = Path(tmpdir)
        files = _inputs(tmp)
        jobs = {} if args.startup_only else {
            "render 64x64": ["render", str(files["scene"]), "-o", str(tmp / "r.exr")],
            "chart 0:3000:5": ["chart", "-o", str(tmp / "c.png"), "--csv", str(tmp / "c.csv")]}
        if not (args.quick or args.startup_only):
            subprocess.run([PY, "-m", "bubblefit", "render", str(files["fit_scene"]), "-o", str(tmp / "photo.exr")],
                           env=_env(str(tmp / "cache_photo")), cwd=ROOT, capture_output=True)
            jobs["fit 48x48 constant"] = ["fit", str(tmp / "photo.exr"), "--envmap",
                                          str(ROOT / "bubblefit" / "data" / "courtyard.exr"), "--disc", "24,24,20",
                                          "--json", str(tmp / "fit.json")]
        for name, argv in jobs.items():
            cache = str(tmp / ("cache_" + name.split()[0]))
            profiles[name] = {"empty cache": profile_command(argv, cache), "warm cache": profile_command(argv, cache)}

    result = {"python": sys.version.split()[0], "cpus": os.cpu_count(), "repeat": args.repeat,
              "numpy_import_s": numpy_s,
              "startup_s": startup, "startup_ratio_to_numpy": {k: v / numpy_s for k, v in startup.items()},
              "library_import_s_beyond_numpy": libraries, "run_imports_s": run_imports, "profiles": profiles}
    _report(result)
    from bubblefit.io.atomic import write_json

    write_json(out / "profile_startup.json", result)
    _plot(result, out / "profile_startup.png")
    print(f"wrote {out / 'profile_startup.json'} and {out / 'profile_startup.png'}")


def _report(r: dict) -> None:
    print(f"yardstick: python -c 'import numpy' {r['numpy_import_s']:.3f} s")
    for k, v in r["startup_s"].items():
        print(f"  {k:40s} {v:6.3f} s  {r['startup_ratio_to_numpy'][k]:5.2f}x")
    print("heavy imports (beyond numpy):")
    for k, v in r["library_import_s_beyond_numpy"].items():
        print(f"  {k:40s} {v:6.3f} s")
    print("imports of each command's run (whole process):")
    for k, v in r["run_imports_s"].items():
        print(f"  {k:40s} {v:6.3f} s")
    for name, runs in r["profiles"].items():
        for cache, p in runs.items():
            if "error" in p:
                print(f"{name} ({cache}): failed: {p['error']}")
                continue
            print(f"{name} ({cache}): wall {p['wall_s']:.2f} s = start+imports {p['wall_s'] - p['run_s']:.2f} "
                  f"(jax {p['import_jax_s']:.2f}, the command's modules {p['run_imports_s']:.2f}) + run "
                  f"{p['run_s']:.2f} (trace {p['trace_s']:.2f}, lower {p['lower_s']:.2f}, compile {p['compile_s']:.2f}"
                  f" in {p['compiles']}, cache loads {p['cache_load_s']:.2f} in {p['cache_hits']}, host transfers "
                  f"{p['transfer_s']:.3f} in {p['transfers']}, rest {p['other_s']:.2f})")


def _plot(r: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5), dpi=100)
    names = list(r["startup_ratio_to_numpy"])
    a.barh(names, [r["startup_ratio_to_numpy"][n] for n in names], color="tab:blue")
    a.axvline(3.0, color="red", lw=1, label="goal: 3x")
    a.set_xlabel('wall time / python -c "import numpy"')
    a.legend(fontsize=8)
    parts = ("trace_s", "lower_s", "compile_s", "cache_load_s", "transfer_s", "other_s")
    rows = [(f"{n}\n{c}", p) for n, runs in r["profiles"].items() for c, p in runs.items() if "error" not in p]
    b.barh([n for n, _ in rows], [p["wall_s"] - p["run_s"] for _, p in rows], label="start + imports",
           color="0.6")
    left = [p["wall_s"] - p["run_s"] for _, p in rows]
    for part in parts:
        vals = [max(p[part], 0.0) for _, p in rows]
        b.barh([n for n, _ in rows], vals, left=left, label=part[:-2].replace("_", " "))
        left = [x + v for x, v in zip(left, vals)]
    b.set_xlabel("seconds")
    b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()
