"""Where a thickness-map fit of one photo spends its time, stage by stage, in one process.

Fits a validation photo (``--data`` folder of cases, default experiments/validation/data)
as ``bubblefit fit PHOTO --thickness map`` does (the case's map, background photo,
illuminant and view, default ``auto``) ``--runs`` times in one process (the first loads
or compiles the programs, the later ones are warm), with wall and CPU seconds
(``time.process_time``, every thread) of each stage: the set-up, each local solve (its LM
runs and steps), the standard errors, the map (each pyramid level's candidate costs, the
finest level's per-pixel Gauss-Newton and its slope passes) and the final render. Then
the physical model's local solve is taken apart (``costs``): a render of its fitted
pixels, its Jacobian by groups and its LM run, timed alone at the solve's start, and the
map is scored against the case's true thickness as ``validate.py`` scores it.

    PYTHONPATH=. python experiments/profile_map_photo.py --data experiments/results/photos320 \
        ref_drain_exp12_sunset_ortho_offc_320 OUT.json [--runs 2]
"""
import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "validation"))
sys.path.insert(0, str(HERE))

from bubblefit.io.jaxcache import jax_setup

jax_setup()

import numpy as np

import bubblefit.inverse.fit as F
import bubblefit.inverse._maps as M
import bubblefit.inverse._map_pixels as MP
import bubblefit.inverse._local as L

from stage_timer import T, keep_solves, solve_costs, timed_solver, wrap  # noqa: E402

SOLVES = keep_solves(F)
#: (module or class, attribute, label) of the functions timed
TIMED = [(F, n, n) for n in ("setup", "_searched_start", "_judge", "fit_map", "render_bubble", "_report")]
TIMED += [(M, n, "maps." + n) for n in ("_level_map", "refine", "_icm")]
TIMED += [(MP.TracedCosts, "__init__", "TracedCosts.init"), (MP.TracedCosts, "__call__", "TracedCosts.call (candidate costs)"),
          (MP.TracedCosts, "slopes", "TracedCosts.slopes (Gauss-Newton pass)")]
for owner, name, label in TIMED:
    wrap(owner, name, label)
_stored = L.stored_solver
L.stored_solver = timed_solver(_stored)

import bench_map  # noqa: E402
import validate  # noqa: E402
from bubblefit.inverse.fit import fit_photo  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("out")
    ap.add_argument("--data", default=None)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--model", default="auto")
    ap.add_argument("--no-costs", action="store_true")
    a = ap.parse_args()
    if a.data:
        bench_map.DATA = Path(a.data).resolve()
    photo, env, bg, opts, truth = bench_map.case_options(a.case, "map", a.model)
    true_map = None
    tpath = bench_map.DATA / a.case / "thickness_true.exr"
    if tpath.exists():
        import vio
        true_map = vio.read_image(str(tpath))[..., 0]
    rows = []
    for run in range(a.runs):
        T.clear()
        SOLVES.clear()
        t0, c0 = time.perf_counter(), time.process_time()
        r = fit_photo(photo.pixels, env, options=opts, background=bg)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        tmap = getattr(r, "thickness_map", None)
        score = None
        if tmap is not None and true_map is not None:
            score = validate.map_metrics(np.asarray(tmap, np.float64), true_map, truth["disc"])
        row = {"run": run, "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "model": getattr(r, "model", None),
               "ok": bool(r.ok), "params": {k: round(float(v), 3) for k, v in r.params.items() if v is not None},
               "stderr": {k: round(float(v), 4) for k, v in r.stderr.items() if v is not None},
               "solves": [s["row"] for s in SOLVES],
               "stages": {k: [round(v[0], 2), round(v[1], 2), v[2]] for k, v in
                          sorted(T.items(), key=lambda kv: -kv[1][1])},
               "map": score}
        print(json.dumps(row), flush=True)
        rows.append(row)
    result = {"case": a.case, "runs": rows}
    if not a.no_costs and SOLVES:
        result["costs"] = [dict(s["row"], **solve_costs(s["args"], s["kwargs"], _stored)) for s in SOLVES[-1:]]
        print(json.dumps(result["costs"]), flush=True)
    Path(a.out).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
