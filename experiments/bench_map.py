"""Where a photo fit's time goes on the independent validation photos, and the map's costs.

``--profile CASE[:THICKNESS] ...`` fits validation photos (experiments/validation/data/)
in one process as ``bubblefit fit`` does (the photo and background PNGs, the case's map,
illuminant and thickness model; ``--model``, default ``auto``), twice: a first call (on
whatever JAX's compilation cache holds) and a warm one. Every stage of
:func:`~bubblefit.inverse.fit.fit_photo` is timed by wrapping it (set-up, search, local
solve, standard errors, the map and, inside it, each pyramid level's candidate costs and
its iterated conditional modes, the final render), per model of ``auto``. A stage's time
includes the stages it calls. ``python -c "import numpy"`` is timed in the same run and the
1-minute load average is written beside each call. Writes ``profile_physical.json``.

    PYTHONPATH=. python experiments/bench_map.py --profile ref_drain_lin_courtyard_ortho:map \
        cyc_const500_courtyard_ortho:constant [--out experiments/results]

``--map-only CASE ...`` times the map stage alone (:func:`bubblefit.inverse._maps.fit_map`)
on a validation photo, from the case's drainage fit (``--model``'s, run once and kept in
``--out``/map_starts.json; ``--start truth``: the true profile, exposure and roughness), with the map's ways taking turns in one process
(``--repeats`` rounds): ``render-grid`` (every level's candidates as whole renders, the
finest level on a 2 nm grid with iterated conditional modes), ``traced-grid`` (the rays
traced once per level, the same grid) and ``traced-newton`` (the rays traced once, the
finest level by per-pixel Gauss-Newton), each scored against the case's true map as
validate.py scores it. Writes ``map_stage.json``.

    PYTHONPATH=. python experiments/bench_map.py --map-only ref_drain_lin_courtyard_ortho --repeats 2

``--whole CASE[:THICKNESS] ...`` runs ``bubblefit fit`` as validate.py does (``--fit-args``,
default ``--model physical``; scored against the truth), a first process on the
compilation cache as found and ``--repeats`` more, each followed by Mitsuba 3 (256x256,
64 spp, ``--mitsuba-python``, default ``.venv-render/bin/python``) and ``python -c "import
numpy"``. Writes ``whole_process_maps.json``.

``--staged CASE[:THICKNESS] ...`` profiles ``bubblefit fit`` (the default ``auto`` model, or
``--fit-args``) and ``bubblefit render`` (256x256, physical, defaults, over the sunset map
clamped as the validation photos use it) as whole processes with a warm compilation cache
(``--repeats`` runs after a first that may compile): the stage lines the command prints
with ``BUBBLEFIT_VERBOSE=1`` (disc and effects, global search, local fit, standard errors
with the map and the final render, per model of ``auto``), the process's wall and CPU
(user + sys) seconds, and, in turns with each, Mitsuba 3 (256x256, 64 spp) and ``python -c
"import numpy"`` with their own wall and CPU seconds and the 1-minute load average.
Writes ``whole_process_stages.json``.

    PYTHONPATH=. python experiments/bench_map.py --staged ref_const380_sunset_ortho:constant \
        ref_drain_exp12_sunset_ortho_offc:map --mitsuba-python .venv/bin/python --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = HERE / "validation" / "data"
sys.path.insert(0, str(HERE))
from bench_fit import numpy_yardstick  # noqa: E402  (python -c "import numpy", median seconds)


def load_case(case: str):
    """Photo, map, background and FitOptions keywords of one validation case, as the CLI reads them."""
    from bubblefit.cli.fit import load_envmap
    from bubblefit.inverse.fit import NoiseSettings
    from bubblefit.io.images import read_image

    d = DATA / case
    truth = json.loads((d / "truth.json").read_text())
    photo = read_image(str(d / "photo.png"), dtype=np.float32)
    bg = read_image(str(d / "background.png"), dtype=np.float32).pixels
    env = load_envmap(str(DATA / truth["envmap"]))
    kw = dict(noise=NoiseSettings(bits=int(photo.bit_depth)))
    if truth.get("illuminant") in ("D65", "E", "A"):
        kw["illuminant"] = truth["illuminant"]
    return photo, env, bg, kw, truth



def case_options(case: str, thickness: str, model: str = "auto"):
    """:func:`load_case` with the FitOptions of ``bubblefit fit --thickness THICKNESS --model
    MODEL`` as the staged runs call it: an orthographic case's view stated (``--fov 0``, as
    validate.py states it). Returns photo, map, background, options and truth."""
    from bubblefit.capture.view import resolve_view
    from bubblefit.inverse.fit import FitOptions

    photo, env, bg, kw, truth = load_case(case)
    if truth.get("camera", {}).get("type") == "orthographic":
        kw["view"] = resolve_view(fov_deg=0, width=photo.pixels.shape[1], height=photo.pixels.shape[0])
    return photo, env, bg, FitOptions(thickness=thickness, model=model, **kw), truth

#: ``XLA_FLAGS`` before this process's :func:`bubblefit.io.jaxcache.jax_setup` (which may add
#: to it), for the commands that ``--staged`` runs.
_XLA_FLAGS: str | None = None

#: (label, module, attribute) of the functions timed.
TIMED = (("setup", "bubblefit.inverse.fit", "setup"), ("search", "bubblefit.inverse.fit", "_searched_start"),
         ("local solve", "bubblefit.inverse.fit", "solve_local"), ("judge (std errors)", "bubblefit.inverse.fit", "_judge"),
         ("map", "bubblefit.inverse.fit", "fit_map"),
         ("final render", "bubblefit.inverse.fit", "render_bubble"),
         ("map: level", "bubblefit.inverse._maps", "_level_map"), ("map: ICM", "bubblefit.inverse._maps", "_icm"),
         ("map: newton", "bubblefit.inverse._maps", "refine"))


def profile(cases: list[str], model: str, out: Path):
    import importlib

    from bubblefit.inverse.fit import FitOptions, fit_photo
    import bubblefit.inverse.fit as fit_module

    spent = {}
    current = {"model": "-"}

    def timed(label, fn):
        def call(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                key = f"{current['model']}: {label}"
                spent[key] = spent.get(key, 0.0) + time.perf_counter() - t0
        return call

    # which model a nested fit_photo runs (auto runs paper, then physical)
    inner = fit_module.fit_photo

    def tagged(photo, env, *, options=FitOptions(), **k):
        prev = current["model"]
        if options.model != "auto":
            current["model"] = options.model
        try:
            return inner(photo, env, options=options, **k)
        finally:
            current["model"] = prev

    originals = []
    for label, mod, name in TIMED:
        m = importlib.import_module(mod)
        originals.append((m, name, getattr(m, name)))
        setattr(m, name, timed(label, getattr(m, name)))
    originals.append((fit_module, "fit_photo", inner))
    fit_module.fit_photo = tagged
    # the candidate costs of the map's levels, whichever class computes them
    import bubblefit.inverse._maps as maps_module
    for cls_name in ("RenderCosts", "_PaperCosts", "TracedCosts"):
        cls = getattr(maps_module, cls_name, None)
        if cls is not None:
            originals.append((cls, "__call__", cls.__call__))
            cls.__call__ = timed(f"map: costs {cls_name}", cls.__call__)
    from bubblefit.inverse import TracedCosts
    originals.append((TracedCosts, "slopes", TracedCosts.slopes))
    TracedCosts.slopes = timed("map: newton slopes (jvp)", TracedCosts.slopes)
    rows = []
    try:
        numpy_s = numpy_yardstick()
        for spec in cases:
            case, _, thick = spec.partition(":")
            photo, env, bg, kw, truth = load_case(case)
            thick = thick or truth.get("fits", ["constant"])[0]
            opts = FitOptions(thickness=thick, model=model, **kw)
            for run in ("first", "warm"):
                spent.clear()
                load = os.getloadavg()[0]
                t0, c0 = time.perf_counter(), os.times()
                res = tagged(photo.pixels, env, options=opts, background=bg, saturated=photo.saturated)
                c1 = os.times()
                row = {"case": f"{case}:{thick}", "size": list(photo.pixels.shape[:2]), "model": model, "run": run,
                       "total_s": round(time.perf_counter() - t0, 3),
                       "cpu_s": round(c1.user + c1.system - c0.user - c0.system, 2), "load1": round(load, 2),
                       "kept_model": res.model, "ok": bool(res.ok)}
                row["stages_s"] = {k: round(v, 3) for k, v in sorted(spent.items())}
                print(json.dumps(row), flush=True)
                rows.append(row)
        numpy_s = 0.5 * (numpy_s + numpy_yardstick())
    finally:
        for obj, name, fn in originals:
            setattr(obj, name, fn)
    summary = {"numpy_import_s": round(numpy_s, 3), "calls": rows,
               "note": "a stage's seconds include the stages it calls; 'map: level' includes the map's "
                       "candidate costs and ICM; first = on the compilation cache as found"}
    out.mkdir(parents=True, exist_ok=True)
    path = out / "profile_physical.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.setdefault("runs", []).append(summary)
    path.write_text(json.dumps(old, indent=1))
    print(f"wrote {path}")


def map_only(cases: list[str], model: str, out: Path, repeats: int, ways: list[str], start: str = "fit"):
    """The map stage alone, its ways taking turns (module docstring)."""
    sys.path.insert(0, str(HERE / "validation"))
    import validate
    import vio
    from bubblefit.inverse import _maps
    from bubblefit.inverse import TracedCosts, setup
    from bubblefit.inverse.fit import FitOptions, fit_photo

    out.mkdir(parents=True, exist_ok=True)
    starts_path = out / "map_starts.json"
    starts = json.loads(starts_path.read_text()) if starts_path.exists() else {}
    rows = []
    numpy_s = numpy_yardstick()
    for case in cases:
        photo, env, bg, kw, truth = load_case(case)
        key = f"{case}:{model}"
        if start == "truth":  # the renderer's own drainage profile, exposure and roughness
            th = truth["thickness"]
            starts[key] = {"params": {"top_nm": th["top_nm"], "bottom_nm": th["bottom_nm"],
                                      "exponent": th["exponent"], "exposure": truth["exposure"],
                                      "roughness": max(truth.get("roughness", 0.0), 1e-3),
                                      "rotation_deg": truth.get("rotation_deg", 0.0)}}
        elif key not in starts:
            t0 = time.perf_counter()
            res = fit_photo(photo.pixels, env, options=FitOptions(thickness="drainage", model=model, **kw),
                            background=bg, saturated=photo.saturated)
            starts[key] = {"params": {k: float(v) for k, v in res.params.items() if np.isfinite(v)},
                           "seconds": round(time.perf_counter() - t0, 1), "load1": os.getloadavg()[0]}
            starts_path.write_text(json.dumps(starts, indent=1))
        opts = FitOptions(thickness="map", model=model, **kw)
        st = setup(photo.pixels, env, opts, bg, starts[key]["params"], None, photo.saturated)
        vals = dict(st.vals)
        prof = (vals["top_nm"], vals["bottom_nm"], vals["exponent"])
        full = st.level(1, opts, st.map_cfg)
        true_map = vio.read_image(str(DATA / case / "thickness_true.exr"))[..., 0]
        settings = {"render-grid": (_maps.RenderCosts, "grid"), "traced-grid": (TracedCosts, "grid"),
                    "traced-newton": (TracedCosts, "newton")}
        for rep in range(repeats):
            for way in ways:
                cls, fine = settings[way]
                old = (_maps.TracedCosts, _maps.FINE_SOLVE)
                _maps.TracedCosts, _maps.FINE_SOLVE = cls, fine
                try:
                    load = os.getloadavg()[0]
                    t0 = time.perf_counter()
                    dmap, emap, sound = _maps.fit_map(full, st.table, vals, prof, opts, env,
                                                      make_level=lambda k: st.level(k, opts, st.map_cfg))
                    sec = time.perf_counter() - t0
                finally:
                    _maps.TracedCosts, _maps.FINE_SOLVE = old
                m = np.where(full.inside, dmap, np.nan)
                row = {"case": case, "model": model, "way": way, "round": rep, "seconds": round(sec, 2),
                       "load1": round(load, 2), "sound": sound, "start": start, "size": list(full.mask.shape),
                       **{k: (round(v, 3) if isinstance(v, float) else v)
                          for k, v in validate.map_metrics(m, true_map, truth["disc"]).items()}}
                print(json.dumps(row), flush=True)
                rows.append(row)
    numpy_s = 0.5 * (numpy_s + numpy_yardstick())
    path = out / "map_stage.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.setdefault("runs", []).append({"numpy_import_s": round(numpy_s, 3), "rows": rows})
    path.write_text(json.dumps(old, indent=1))
    print(f"numpy import {numpy_s:.3f} s; wrote {path}")


def whole_process(cases: list[str], fit_args: list[str], out: Path, repeats: int, mitsuba_python: str):
    """``bubblefit fit`` of validation cases as validate.py runs them (scored against the
    truth), taking turns with Mitsuba 3 (256x256 thin dielectric sphere, 64 spp, the
    script of ``bench_effects.py``) and ``python -c "import numpy"``; the first fit of
    each case is on the compilation cache as found, ``--repeats`` more follow."""
    import tempfile

    sys.path.insert(0, str(HERE / "validation"))
    sys.path.insert(0, str(HERE))
    import validate
    from bench_effects import MAPS, MITSUBA_SCRIPT

    validate.EXTRA_FIT_ARGS[:] = fit_args
    rows = []

    def mitsuba() -> float | None:
        if not Path(mitsuba_python).exists():
            return None
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            subprocess.run([mitsuba_python, "-c", MITSUBA_SCRIPT, "256", str(MAPS / "sunrise.exr"),
                            str(Path(tmp) / "m.exr")], check=True, capture_output=True)
            return time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as tmp:
        for spec in cases:
            case, _, thick = spec.partition(":")
            for rep in range(repeats + 1):
                load = os.getloadavg()[0]
                r = validate.run_fit(case, thick or "map", tmp)
                row = {"case": spec, "fit_args": fit_args, "run": "first" if rep == 0 else "warm",
                       "fit_s": r.get("wall_s"), "load1": round(load, 2), "rc": r.get("rc"), "pass": r.get("pass"),
                       **{k: r.get(k) for k in ("map_median_nm", "map_coverage", "order_hops", "thickness_err_nm",
                                                "top_err_nm", "bottom_err_nm", "message") if r.get(k) is not None}}
                row["mitsuba_s"] = mitsuba()
                row["numpy_s"] = numpy_yardstick(1)
                if row["mitsuba_s"] and row["fit_s"]:
                    row["fit_over_mitsuba"] = round(row["fit_s"] / row["mitsuba_s"], 2)
                print(json.dumps(row), flush=True)
                rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "whole_process_maps.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.setdefault("runs", []).append(rows)
    path.write_text(json.dumps(old, indent=1))
    print(f"wrote {path}")


def _timed_process(cmd: list[str], env: dict | None = None, cwd: str | None = None) -> dict:
    """Wall and CPU (user + sys, the children's rusage) seconds of one process, its stderr
    and the 1-minute load average when it started."""
    import resource

    load = os.getloadavg()[0]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL, cwd=cwd)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
    return {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3), "load1": round(load, 2), "rc": p.returncode,
            "stderr": p.stderr}


#: A ``bubblefit`` process whose stages (bubblefit.progress.stage) also record their CPU
#: seconds (``time.process_time``: every thread of the process, XLA's included) and the
#: process's CPU before its first stage (interpreter start, imports, argument parsing); the
#: records go to stderr as one ``STAGES_JSON`` line.
STAGE_CLOCK = r"""
import contextlib, json, sys, time
import bubblefit.progress as progress
inner, rec = progress.stage, []

@contextlib.contextmanager
def stage(name, **k):
    depth, t0, c0 = progress._DEPTH, time.perf_counter(), time.process_time()
    rec.append(None)
    i = len(rec) - 1
    try:
        with inner(name, **k):
            yield
    finally:
        rec[i] = (depth, name, round(time.perf_counter() - t0, 3), round(time.process_time() - c0, 3))

progress.stage = stage

def report():
    print("STAGES_JSON " + json.dumps({"stages": [r for r in rec if r], "cpu_s": time.process_time()}), file=sys.stderr)

import atexit
atexit.register(report)  # the process's last words, however the command ends it
from bubblefit.cli import main
sys.exit(main())  # as the ``bubblefit`` script calls it: the command line is sys.argv[1:]
"""


def _stage_lines(stderr: str) -> list:
    """``[(depth, name, wall seconds, CPU seconds)]`` of a :data:`STAGE_CLOCK` process."""
    for line in stderr.splitlines():
        if line.startswith("STAGES_JSON "):
            return json.loads(line[len("STAGES_JSON "):])["stages"]
    return []


def staged(cases: list[str], fit_args: list[str], out: Path, repeats: int, mitsuba_python: str,
           code: list[str] | None = None, render: bool = True):
    """Whole-process stage profile of ``bubblefit fit`` and ``bubblefit render`` beside
    Mitsuba 3 and ``python -c "import numpy"`` (module docstring, ``--staged``); with
    several ``code`` folders (checkouts of the package), each run of a job takes its turn
    in each of them."""
    import tempfile

    sys.path.insert(0, str(HERE))
    from bench_effects import MAPS, MITSUBA_SCRIPT

    code = code or [str(HERE.parent)]
    envs = [dict(os.environ, BUBBLEFIT_VERBOSE="1", PYTHONPATH=c) for c in code]
    for env in envs:
        # XLA_FLAGS as this script found it: its own jax_setup may have added flags that each
        # checkout's command sets (or not) for itself
        env.pop("XLA_FLAGS", None)
        if _XLA_FLAGS is not None:
            env["XLA_FLAGS"] = _XLA_FLAGS
        env.pop("BUBBLEFIT_QUIET", None)
        # an installed package's modules are byte-compiled: without this every process
        # would compile the package's sources again (1.3 s of a loaded render's 23 s)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        mitsuba = [mitsuba_python, "-c", MITSUBA_SCRIPT, "256", str(MAPS / "sunrise.exr"), str(tmp / "m.exr")]
        numpy_cmd = [sys.executable, "-c", "import numpy"]
        scene = tmp / "bubble.toml"
        scene.write_text(f'[camera]\nwidth = 256\nheight = 256\n[lighting]\nenvmap = "{DATA / "envmaps" / "sunset.exr"}"\n'
                         '[effects]\nmodel = "physical"\n')
        jobs = []
        for spec in cases:
            case, _, thick = spec.partition(":")
            d = DATA / case
            truth = json.loads((d / "truth.json").read_text())
            thick = thick or truth.get("fits", ["constant"])[0]
            args = ["fit", str(d / "photo.png"), "--envmap", str(DATA / truth["envmap"]), "--background",
                    str(d / "background.png"), "--thickness", thick, "--json", str(tmp / "fit.json"),
                    "-o", str(tmp / "fit")]
            fa = list(truth.get("fit_args", []))
            args += [str(d / a) if a.endswith((".toml", ".json")) else a for a in fa]
            if truth.get("camera", {}).get("type") == "orthographic" and not {"--scene", "--fov"} & set(fa):
                args += ["--fov", "0"]  # as validate.py states an orthographic photo's view
            if truth.get("illuminant") in ("D65", "E", "A"):
                args += ["--illuminant", truth["illuminant"]]
            jobs.append((f"fit {case}:{thick}", [sys.executable, "-c", STAGE_CLOCK, *args, *fit_args]))
        if render:
            jobs.append(("render 256x256 physical sunset", [sys.executable, "-c", STAGE_CLOCK, "render", str(scene),
                                                             "-o", str(tmp / "b.exr")]))
        for name, cmd in jobs:
            for rep, (c, env) in ((rep, ce) for rep in range(repeats + 1) for ce in zip(code, envs)):
                (tmp / "fit.json").unlink(missing_ok=True)
                r = _timed_process(cmd, env, cwd=str(tmp))  # not the checkout: PYTHONPATH picks the package
                row = {"job": name, "code": c, "run": "first" if rep == 0 else "warm", **{k: r[k] for k in
                       ("wall_s", "cpu_s", "load1", "rc")}, "stages": _stage_lines(r["stderr"])}
                if name.startswith("fit") and (tmp / "fit.json").exists():
                    res = json.loads((tmp / "fit.json").read_text())
                    row["result"] = {k: res.get(k) for k in ("ok", "message")}
                    row["result"]["params"] = {k: v for k, v in res.get("params", {}).items()
                                               if k in ("thickness_nm", "top_nm", "bottom_nm", "exponent")}
                if r["rc"] != 0:
                    row["error"] = r["stderr"].strip().splitlines()[-1:]
                if Path(mitsuba_python).exists():
                    m = _timed_process(mitsuba)
                    row["mitsuba"] = {k: m[k] for k in ("wall_s", "cpu_s", "load1")}
                    row["ratio_wall"] = round(row["wall_s"] / m["wall_s"], 2)
                    row["ratio_cpu"] = round(row["cpu_s"] / max(m["cpu_s"], 1e-3), 2)
                n = _timed_process(numpy_cmd)
                row["numpy"] = {k: n[k] for k in ("wall_s", "cpu_s")}
                row["ratio_numpy_cpu"] = round(row["cpu_s"] / max(n["cpu_s"], 1e-3), 1)
                print(json.dumps({k: v for k, v in row.items() if k != "stages"}), flush=True)
                for depth, stage_name, sec, cpu in row["stages"]:
                    print(f"    {'  ' * depth}{stage_name}: {sec:.2f} s wall, {cpu:.2f} s CPU", flush=True)
                rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "whole_process_stages.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.setdefault("runs", []).append({"fit_args": fit_args, "rows": rows})
    path.write_text(json.dumps(old, indent=1))
    print(f"wrote {path}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", nargs="+", metavar="CASE[:THICKNESS]")
    ap.add_argument("--map-only", nargs="+", metavar="CASE")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--whole", nargs="+", metavar="CASE[:THICKNESS]", help="bubblefit fit as a process (see above)")
    ap.add_argument("--staged", nargs="+", metavar="CASE[:THICKNESS]", help="stages of whole processes (see above)")
    ap.add_argument("--code", default=None, help="--staged: comma-separated package folders taking turns")
    ap.add_argument("--no-render", action="store_true", help="--staged: fits only")
    ap.add_argument("--fit-args", default=None,
                    help="--whole, --staged: extra bubblefit fit arguments (--whole: default --model physical)")
    ap.add_argument("--mitsuba-python", default=str(HERE.parent / ".venv-render" / "bin" / "python"))
    ap.add_argument("--start", choices=("fit", "truth"), default="fit",
                    help="--map-only: start the map from the case's drainage fit or its true profile")
    ap.add_argument("--ways", default="render-grid,traced-grid,traced-newton")
    ap.add_argument("--model", default="auto")
    ap.add_argument("--out", default=str(HERE / "results"))
    ap.add_argument("--data", help="another folder of cases with its envmaps/ (validation/make_reference.py "
                    "--size's 320x320 photos)")
    a = ap.parse_args(argv)
    if a.data:
        global DATA
        DATA = Path(a.data).resolve()
    from bubblefit.io.jaxcache import jax_setup

    global _XLA_FLAGS
    _XLA_FLAGS = os.environ.get("XLA_FLAGS")
    jax_setup()  # the persistent compilation cache of the command line (BUBBLEFIT_CACHE_DIR)
    if a.staged:
        staged(a.staged, (a.fit_args or "").split(), Path(a.out), a.repeats, a.mitsuba_python,
               a.code.split(",") if a.code else None, not a.no_render)
    elif a.whole:
        whole_process(a.whole, (a.fit_args if a.fit_args is not None else "--model physical").split(), Path(a.out), a.repeats, a.mitsuba_python)
    elif a.map_only:
        map_only(a.map_only, "physical" if a.model == "auto" else a.model, Path(a.out), a.repeats,
                 a.ways.split(","), a.start)
    elif a.profile:
        profile(a.profile, a.model, Path(a.out))
    else:
        ap.error("give --profile, --map-only, --whole or --staged")


if __name__ == "__main__":
    main()
