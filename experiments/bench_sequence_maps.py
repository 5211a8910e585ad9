"""``fit-sequence --maps`` on independent frames: frames per second once warm, and each map scored.

A draining film photographed frame after frame, rendered by the validation set's
independent reference renderer (``validation/reference_renderer.py``: exact Airy film
per polarisation, 8 internal bounces; ``--ss`` x ``--ss`` samples per pixel), orthographic
over the sunset map's backdrop with a background photo, Poisson-Gaussian noise, 8-bit
sRGB: frame ``k``'s profile thins as ``top = 250 - 10 k``, ``bottom = 1000 - 20 k`` nm
(exponent 1.2). The frames, their true maps and the background go to ``--out``/frames
(rendered once, kept; experiments/results/ is not tracked).

The fits run as ``bubblefit fit-sequence FRAMES --thickness map --maps --workers 0`` does
(its own argument parser and options, ``--fov 0 --illuminant D65`` as validate.py states
these photos' view and white; ``--fit-args`` adds more), in this process, twice: a first
pass that compiles (on the compilation cache as found), then a warm pass (``--force``).
Each frame's wall seconds are its record's ``fit_time_s``; the pass's CPU seconds
(``time.process_time``: every thread of the process) are shared out over its frames by
their wall seconds (a chunk's records arrive together when it ends), and each frame's own
CPU seconds are taken around its fit (``own_cpu_s``; ``warm_after_first_own``), which a
change of load within the pass does not share out. The first frame of a
pass runs the global search, the others start from their neighbour. Frames per second
once warm are the warm pass's frames after the first, per wall second and per CPU second
(frames per second per core). Mitsuba 3 (256x256 thin dielectric, 64 spp) and ``python -c "import numpy"`` are
timed in the same run, with the 1-minute load average. Every map is scored against its
truth as validate.py scores a map (median error <= 15 nm, >= 90 % of the inner disc within
15 nm, no order hops). Writes ``bench_sequence_maps.json`` to ``--out``.

    PYTHONPATH=. python experiments/bench_sequence_maps.py --frames 8 --size 96 \
        --mitsuba-python .venv/bin/python
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "validation"))
sys.path.insert(0, str(HERE))


def profile_at(k: int) -> tuple[float, float, float]:
    """(top, bottom, exponent) of frame k's drainage profile, nm."""
    return 250.0 - 10.0 * k, 1000.0 - 20.0 * k, 1.2


def render_frames(folder: Path, n: int, size: int, ss: int, seed: int = 21) -> dict:
    """Render the frames with the independent reference renderer (module docstring)."""
    import reference_renderer as rr
    import vio

    folder.mkdir(parents=True, exist_ok=True)
    meta_path = folder / "frames.json"
    want = {"frames": n, "size": size, "ss": ss, "seed": seed}
    if meta_path.exists():
        meta = json.loads(meta_path.read_text())
        if meta.get("spec") == want:
            return meta
    env = vio.read_image(os.path.join(vio.ENVMAPS, "sunset.exr"))[..., :3]
    sp = rr.spectral_setup("D65", 2.0)
    cam = rr.Camera("ortho", size, size, disc=(0.52 * size, 0.5 * size, 0.4 * size))
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    bg, _ = rr.render(cam, None, env, sp, background="backdrop", ss=ss)
    imgs, maps = [], []
    for k in range(n):
        top, bottom, expo = profile_at(k)
        bubble = rr.Bubble(thickness=rr.Thickness("drainage", top_nm=top, bottom_nm=bottom, exponent=expo))
        img, tmap = rr.render(cam, bubble, env, sp, background="backdrop", ss=ss)
        imgs.append(img)
        maps.append(tmap)
    exposure = 0.9 / float(np.percentile(imgs[0], 99.5))  # one camera setting for the whole sequence
    for k, (img, tmap) in enumerate(zip(imgs, maps)):
        vio.write_png8(str(folder / f"frame_{k:04d}.png"), None,
                       vio.add_noise_and_quantise(img * exposure, rng, 4000.0, 3.0))
        vio.write_exr(str(folder / f"truth_{k:04d}.exr"), tmap.astype(np.float32))
    vio.write_png8(str(folder / "background.png"), None, vio.add_noise_and_quantise(bg * exposure, rng, 4000.0, 3.0))
    cx, cy, r = cam.disc
    meta = {"spec": want, "disc": {"cx": cx, "cy": cy, "r": r}, "exposure": exposure,
            "render_s": round(time.perf_counter() - t0, 1),
            "renderer": rr.VERSION, "profiles": [profile_at(k) for k in range(n)]}
    meta_path.write_text(json.dumps(meta, indent=1))
    return meta


def yardsticks(mitsuba_python: str) -> dict:
    """Mitsuba 3 (256x256, 64 spp) and ``python -c "import numpy"``: wall and CPU seconds."""
    from bench_effects import MAPS, MITSUBA_SCRIPT
    from bench_map import _timed_process

    out = {}
    if Path(mitsuba_python).exists():
        with tempfile.TemporaryDirectory() as tmp:
            m = _timed_process([mitsuba_python, "-c", MITSUBA_SCRIPT, "256", str(MAPS / "sunrise.exr"),
                                str(Path(tmp) / "m.exr")])
        out["mitsuba"] = {k: m[k] for k in ("wall_s", "cpu_s", "load1")}
    n = _timed_process([sys.executable, "-c", "import numpy"])
    out["numpy"] = {k: n[k] for k in ("wall_s", "cpu_s")}
    return out


def run_pass(argv: list[str], out: Path, frames_limit: int | None = None) -> list[dict]:
    """One ``fit-sequence`` pass in this process (its first ``frames_limit`` frames, default
    all); per frame: wall and CPU seconds since the last record."""
    from bubblefit.cli import build_parser
    from bubblefit.cli.fit import build_fit_options, load_envmap
    from bubblefit.cli.fit_sequence import frame_bits
    from bubblefit.cli.view_options import sequence_view
    from bubblefit.inverse.sequence import SequenceOptions, discover_frames, fit_sequence
    from bubblefit.io.images import read_image

    args = build_parser().parse_args(["fit-sequence", *argv, "-o", str(out)])
    frames = discover_frames(args.frames, fps=args.fps)[:frames_limit]
    options = build_fit_options(args, None, frame_bits(frames), sequence_view(args, frames))
    env = load_envmap(args.envmap)
    background = read_image(args.background).pixels
    rows = []
    clock = [time.perf_counter(), time.process_time()]

    def on_record(rec):
        w, c = time.perf_counter(), time.process_time()
        # a chunk's records arrive together when it ends: a frame's own wall time is its
        # record's fit_time_s; wall_s and cpu_s are the time since the last record
        rows.append({"frame": rec.get("frame"), "fit_time_s": round(float(rec.get("fit_time_s", float("nan"))), 3),
                     "wall_s": round(w - clock[0], 3), "cpu_s": round(c - clock[1], 3),
                     "warm_start": rec.get("warm_start"), "fit_ok": rec.get("fit_ok"),
                     "converged": rec.get("converged"), "model": rec.get("model"),
                     "model_kept": rec.get("model_kept"), "fallback": rec.get("fallback"),
                     "message": rec.get("message", "")[:200]})
        clock[:] = [w, c]

    import bubblefit.inverse.fit as fit_module

    own, plain = [], fit_module.fit_photo

    def timed(*a, **k):
        # each frame's own CPU seconds (every thread of the process), the frames fitted in turn
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            return plain(*a, **k)
        finally:
            own.append((time.process_time() - c0, time.perf_counter() - w0))

    seq = SequenceOptions(workers=0, chunk_size=len(frames), force=True, maps=True, progress=False)
    fit_module.fit_photo = timed  # the executor resolves the fit by name at each frame
    try:
        fit_sequence(frames, env, args.output, options, seq, background=background, on_record=on_record)
    finally:
        fit_module.fit_photo = plain
    if len(own) == len(rows):  # one fit a frame (a frame fitted twice is not split)
        for row, (cpu, wall) in zip(rows, own):
            row["own_cpu_s"], row["own_wall_s"] = round(cpu, 3), round(wall, 3)
    return rows


def score(out: Path, frames: Path, meta: dict) -> list[dict]:
    import validate
    import vio

    rows = []
    for k in range(meta["spec"]["frames"]):
        fit = vio.read_image(str(out / "maps" / f"frame_{k:06d}_thickness.exr"))[..., 0]
        true = vio.read_image(str(frames / f"truth_{k:04d}.exr"))[..., 0]
        m = validate.map_metrics(fit, true, meta["disc"])
        m["meets"] = bool(m["map_median_nm"] is not None and m["map_median_nm"] <= validate.TOL["median"]
                          and m["map_coverage"] >= validate.TOL["coverage"] and m["order_hops"] == 0)
        rows.append({"frame": k, **{a: (round(b, 3) if isinstance(b, float) else b) for a, b in m.items()}})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--ss", type=int, default=2, help="samples per pixel side of the reference renderer (default 2)")
    ap.add_argument("--fit-args", default="", help="more fit-sequence arguments, e.g. '--model physical'")
    ap.add_argument("--compile-frames", type=int, default=None,
                    help="frames of the first pass, which compiles (default all; 2 compile both a searched "
                         "and a warm-started frame's programs)")
    ap.add_argument("--mitsuba-python", default=str(HERE.parent / ".venv-render" / "bin" / "python"))
    ap.add_argument("--out", default=str(HERE / "results" / "bench_sequence_maps"))
    a = ap.parse_args(argv)
    from bubblefit.io.jaxcache import jax_setup

    jax_setup()
    out = Path(a.out)
    frames = out / f"frames_{a.size}"
    meta = render_frames(frames, a.frames, a.size, a.ss)
    import validate

    truth_env = os.path.join(validate.DATA, "envmaps", "sunset.exr")
    argv_fit = [*sorted(str(p) for p in frames.glob("frame_*.png")), "--envmap", truth_env,
                "--background", str(frames / "background.png"), "--thickness", "map", "--maps",
                "--fov", "0", "--illuminant", "D65", "--workers", "0", *a.fit_args.split()]
    result = {"frames": meta, "fit_args": a.fit_args, "compile_frames": a.compile_frames, "passes": {}}
    for name in ("first", "warm"):
        before = yardsticks(a.mitsuba_python)
        load = os.getloadavg()[0]
        rows = run_pass(argv_fit, out / "run", a.compile_frames if name == "first" else None)
        result["passes"][name] = {"load1": round(load, 2), "frames": rows, "yardsticks": before,
                                  "load1_after": round(os.getloadavg()[0], 2),
                                  "yardsticks_after": yardsticks(a.mitsuba_python)}
        print(name, json.dumps({"load1": load, "wall_s": [r["wall_s"] for r in rows],
                                "cpu_s": [r["cpu_s"] for r in rows]}), flush=True)
    rows = result["passes"]["warm"]["frames"]
    if len(rows) > 1:
        # the pass's CPU seconds shared out by each frame's wall time (one process, in turn)
        wall_all, cpu_all = sum(r["wall_s"] for r in rows), sum(r["cpu_s"] for r in rows)
        fit_all = sum(r["fit_time_s"] for r in rows)
        after = sum(r["fit_time_s"] for r in rows[1:])
        cpu_after = cpu_all * after / fit_all
        if all("own_cpu_s" in r for r in rows[1:]):
            own = sum(r["own_cpu_s"] for r in rows[1:])
            result["warm_after_first_own"] = {"fps_per_cpu_second": round((len(rows) - 1) / own, 4),
                                              "cpu_s_per_frame": round(own / (len(rows) - 1), 3),
                                              "cpu_s": [r["own_cpu_s"] for r in rows[1:]]}
        result["warm_after_first"] = {"frames": len(rows) - 1, "fps_wall": round((len(rows) - 1) / after, 4),
                                      "fps_per_cpu_second": round((len(rows) - 1) / cpu_after, 4),
                                      "fit_wall_s_per_frame": round(after / (len(rows) - 1), 2),
                                      "cpu_s_per_frame": round(cpu_after / (len(rows) - 1), 2),
                                      "pass_wall_s": round(wall_all, 1), "pass_cpu_s": round(cpu_all, 1)}
    result["maps"] = score(out / "run", frames, meta)
    result["all_maps_meet_targets"] = all(r["meets"] for r in result["maps"])
    print(json.dumps({k: result[k] for k in ("warm_after_first", "warm_after_first_own", "all_maps_meet_targets")
                      if k in result}))
    for r in result["maps"]:
        print(json.dumps(r))
    path = out / "bench_sequence_maps.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.setdefault("runs", []).append(result)
    path.write_text(json.dumps(old, indent=1))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
