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
from collections import defaultdict
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

T = defaultdict(lambda: [0.0, 0.0, 0])


def wrap(mod, name, label=None):
    """Replace ``mod.name`` by a function that adds its wall and CPU seconds to ``T[label]``."""
    f = getattr(mod, name)
    label = label or name

    def g(*a, **k):
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return f(*a, **k)
        finally:
            e = T[label]
            e[0] += time.perf_counter() - t0
            e[1] += time.process_time() - c0
            e[2] += 1
    setattr(mod, name, g)


LAST_SOLVE = {}
_solve_local = F.solve_local


def _kept_solve_local(*a, **k):
    """solve_local, its arguments kept for the costs of its programs (``costs``)."""
    LAST_SOLVE.update(args=a, kwargs=k)
    return _solve_local(*a, **k)


F.solve_local = _kept_solve_local
for n in ("setup", "solve_local", "_judge", "fit_map", "render_bubble", "judge_colours", "response_cells",
          "_exposure_doubts", "_map_camera_stderr", "_warm_order", "_checked_warm_start", "_report"):
    if hasattr(F, n):
        wrap(F, n)
for n in ("_level_map", "refine", "profile_map"):
    wrap(M, n, "maps." + n)
wrap(MP.TracedCosts, "__init__", "TracedCosts.init")
wrap(MP.TracedCosts, "__call__", "TracedCosts.call")
wrap(MP.TracedCosts, "slopes", "TracedCosts.slopes")
wrap(L, "remaining_step", "local.remaining_step")
_stored = L.stored_solver


def stored(*key):
    """The stored solve, each LM run timed (its outputs brought to the host)."""
    s = _stored(*key)

    def run(*a):
        t0, c0 = time.perf_counter(), time.process_time()
        out = s(*a)
        out = [np.asarray(x) for x in out]
        e = T["solver program (one LM run)"]
        e[0] += time.perf_counter() - t0
        e[1] += time.process_time() - c0
        e[2] += 1
        return out
    return run


L.stored_solver = stored

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
    """The last frame's solve: wall and CPU seconds of one render of its fitted pixels (the
    residual), of its Jacobian by groups, and of its stored LM run, each the median of 3
    calls after the first (which compiles or loads)."""
    import jax
    import jax.numpy as jnp

    import bubblefit.inverse._programs as P
    from bubblefit.inverse._lm import JACOBIANS

    lev, table, solver, vals, env_ = LAST_SOLVE["args"][:5]
    max_steps = LAST_SOLVE["args"][5] if len(LAST_SOLVE["args"]) > 5 else LAST_SOLVE["kwargs"].get("max_steps")
    settings = LAST_SOLVE["kwargs"].get("settings", P.SolveSettings())
    key, args, px = P.solve_program(lev, table, solver, vals, env_, max_steps, settings)
    _, resid = P.solver(*key)
    z = jnp.asarray(table.unconstrained(vals), jnp.float32)
    jac = jax.jit(JACOBIANS["groups"](resid, table))
    run_ = _stored(*key)
    out = {"fitted_pixels": int(lev.mask.sum()), "free": list(table.free), "groups": table.jacobian_groups}
    for name, fn in (("render", lambda: resid(z, args)), ("jacobian_groups", lambda: jac(z, args)),
                     ("lm_run", lambda: run_(z, args))):
        jax.block_until_ready(fn())
        t = []
        for _ in range(3):
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn())
            t.append((time.perf_counter() - t0, time.process_time() - c0))
        out[name] = {"wall_s": round(float(np.median([a for a, _ in t])), 3),
                     "cpu_s": round(float(np.median([b for _, b in t])), 3)}
    return out


result = {"frames": rows}
if len(sys.argv) > 6 and sys.argv[6] == "costs":
    result["costs"] = costs()
    print(json.dumps(result["costs"]), flush=True)
if len(sys.argv) > 5:
    Path(sys.argv[5]).write_text(json.dumps(result, indent=1))
