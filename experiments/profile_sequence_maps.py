"""Where a warm-started frame of ``fit-sequence --maps`` spends its time, stage by stage.

Takes the frames and finished records of ``experiments/bench_sequence_maps.py`` (its
``--out``: ``frames_<size>/`` and ``run/frames/``): the first ``first_done`` frames are
read as finished (their results are the warm start, as a rerun's finished frames are),
and the next ``n_new`` frames are fitted in this process as ``fit-sequence`` fits them
(:func:`bubblefit.inverse._executors.fit_chunk`), with wall and CPU seconds
(``time.process_time``, every thread) kept for each stage: the set-up, the local solve
(and the compiled LM run inside it), the standard errors, the map (its levels' costs and
the finest level's Gauss-Newton), the final render and the checks. Each frame's
iterations, values and map score (as validate.py scores a map) go with it. The first
new frame of a process loads the compiled programs; the later ones are the warm frames.

    PYTHONPATH=. python experiments/profile_sequence_maps.py \
        experiments/results/bench_sequence_maps/run experiments/results/bench_sequence_maps/frames_96 2 3 OUT.json [costs]

With ``costs``, the last frame's solve is then taken apart (:func:`costs`): a render of
its fitted pixels, its Jacobian by groups and its LM run, timed alone.
"""
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "validation"))

from bubblefit.io.jaxcache import jax_setup

jax_setup()

import numpy as np

import bubblefit.inverse.fit as F
import bubblefit.inverse._maps as M
import bubblefit.inverse._map_pixels as MP
import bubblefit.inverse._local as L

from stage_timer import T, solve_costs, timed_solver, wrap  # noqa: E402

LAST_SOLVE = {}
_solve_local = F.solve_local


def _kept_solve_local(*a, **k):
    """solve_local, its arguments kept for the costs of its programs (``costs``)."""
    LAST_SOLVE.update(args=a, kwargs=k)
    return _solve_local(*a, **k)


F.solve_local = _kept_solve_local
for n in ("setup", "solve_local", "_judge", "fit_map", "render_bubble", "judge_colours", "response_cells",
          "_exposure_doubts", "_map_camera_stderr", "_warm_order", "_checked_warm_start", "_report", "carried_map", "_start_one"):
    if hasattr(F, n):
        wrap(F, n)
for n in ("_level_map", "refine", "profile_map", "profile_from_map"):
    wrap(M, n, "maps." + n)
import bubblefit.inverse._carried as C  # noqa: E402

for n in ("carried_map", "fit_map", "render_bubble", "exposure_step", "map_misfit", "profile_from_map"):
    wrap(C, n, "carried." + n)
if hasattr(F, "_carried_map_fit"):
    wrap(F, "_carried_map_fit")
wrap(MP.TracedCosts, "__init__", "TracedCosts.init")
wrap(MP.TracedCosts, "__call__", "TracedCosts.call")
wrap(MP.TracedCosts, "slopes", "TracedCosts.slopes")
wrap(L, "remaining_step", "local.remaining_step")
_stored = L.stored_solver
L.stored_solver = timed_solver(_stored)

from bubblefit.cli import build_parser
from bubblefit.cli.fit import build_fit_options, load_envmap
from bubblefit.cli.fit_sequence import frame_bits
from bubblefit.cli.view_options import sequence_view
from bubblefit.inverse.sequence import discover_frames
from bubblefit.inverse._executors import fit_chunk
from bubblefit.inverse._plan import fix_disc
from bubblefit.io.images import read_image
from bubblefit.io.jaxcache import jax_settings
import validate
import vio

run, frames_dir, n_done, n_new = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
meta = json.loads((frames_dir / "frames.json").read_text())
truth_env = str(Path(validate.DATA) / "envmaps" / "sunset.exr")
argv = [*sorted(str(p) for p in frames_dir.glob("frame_*.png")), "--envmap", truth_env, "--background",
        str(frames_dir / "background.png"), "--thickness", "map", "--maps", "--fov", "0", "--illuminant", "D65",
        "--workers", "0", "-o", str(Path(tempfile.mkdtemp()) / "out")]
args = build_parser().parse_args(["fit-sequence", *argv])
frames = discover_frames(args.frames, fps=args.fps)[:n_done + n_new]
options = build_fit_options(args, None, frame_bits(frames), sequence_view(args, frames))
env = load_envmap(args.envmap)
background = read_image(args.background).pixels
options = fix_disc(options, frames, background, None)
todo = []
for ref in frames:
    if ref.index < n_done:
        todo.append((ref, json.loads((run / "frames" / f"frame_{ref.index:06d}.json").read_text())))
    else:
        todo.append((ref, None))
rows = []
for i in range(n_done, n_done + n_new):
    T.clear()
    t0, c0 = time.perf_counter(), time.process_time()
    recs = fit_chunk(todo[:i + 1], env, options, background, None, jax_settings(), True)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rec = recs[-1]
    tmap = rec.get("_thickness_map")
    truth = vio.read_image(str(frames_dir / f"truth_{i:04d}.exr"))[..., 0]
    score = validate.map_metrics(np.asarray(tmap, np.float64), truth, meta["disc"]) if tmap is not None else None
    row = {"frame": i, "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "iterations": rec.get("iterations"),
           "model": rec.get("model"), "model_kept": rec.get("model_kept"), "fallback": rec.get("fallback"),
           "message": rec.get("message", "")[:300], "chi2_floor": rec.get("chi2_floor"),
           "params": {k: round(v, 3) for k, v in rec.get("params", {}).items()},
           "disc": (rec.get("init") or {}).get("disc"),
           "stages": {k: [round(v[0], 2), round(v[1], 2), v[2]] for k, v in sorted(T.items(), key=lambda kv: -kv[1][0])},
           "map": score}
    print(json.dumps(row), flush=True)
    rows.append(row)
    rec.pop("_thickness_map", None)
    todo[i] = (todo[i][0], rec)


def costs() -> dict:
    """The last frame's solve: a render of its fitted pixels, its Jacobian by groups and its
    LM run, timed alone (:func:`stage_timer.solve_costs`)."""
    return solve_costs(LAST_SOLVE["args"], LAST_SOLVE["kwargs"], _stored)


result = {"frames": rows}
if len(sys.argv) > 6 and sys.argv[6] == "costs":
    result["costs"] = costs()
    print(json.dumps(result["costs"]), flush=True)
if len(sys.argv) > 5:
    Path(sys.argv[5]).write_text(json.dumps(result, indent=1))
