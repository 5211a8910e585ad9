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


def numpy_yardstick(repeats: int = 3) -> float:
    """Median seconds of ``python -c "import numpy"`` (a fresh process)."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import numpy"], check=True)
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def load_case(case: str):
    """Photo, map, background and FitOptions keywords of one validation case, as the CLI reads them."""
    from bubblefit.cli.fit import load_envmap
    from bubblefit.io.images import read_image

    d = DATA / case
    truth = json.loads((d / "truth.json").read_text())
    photo = read_image(str(d / "photo.png"), dtype=np.float32)
    bg = read_image(str(d / "background.png"), dtype=np.float32).pixels
    env = load_envmap(str(DATA / truth["envmap"]))
    kw = dict(bits=int(photo.bit_depth))
    if truth.get("illuminant") in ("D65", "E", "A"):
        kw["illuminant"] = truth["illuminant"]
    return photo, env, bg, kw, truth


#: (label, module, attribute) of the functions timed.
TIMED = (("setup", "bubblefit.inverse.fit", "setup"), ("search", "bubblefit.inverse.fit", "_searched_start"),
         ("local solve", "bubblefit.inverse.fit", "solve_local"), ("judge (std errors)", "bubblefit.inverse.fit", "_judge"),
         ("map", "bubblefit.inverse.fit", "fit_map"), ("final render (map)", "bubblefit.inverse.fit", "render_level"),
         ("final render", "bubblefit.inverse.fit", "render_bubble"),
         ("map: level", "bubblefit.inverse._maps", "_level_map"), ("map: ICM", "bubblefit.inverse._maps", "_icm"))


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
    for cls_name in ("_RenderCosts", "_PaperCosts", "_TracedCosts"):
        cls = getattr(maps_module, cls_name, None)
        if cls is not None:
            originals.append((cls, "__call__", cls.__call__))
            cls.__call__ = timed(f"map: costs {cls_name}", cls.__call__)
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", nargs="+", metavar="CASE[:THICKNESS]", required=True)
    ap.add_argument("--model", default="auto")
    ap.add_argument("--out", default=str(HERE / "results"))
    a = ap.parse_args(argv)
    profile(a.profile, a.model, Path(a.out))


if __name__ == "__main__":
    main()
