"""Benchmark of sequence fitting (:mod:`bubblefit.inverse.sequence`): frames per second.

A synthetic drainage sequence (constant film, ``d(t) = d0 exp(-t / tau)``, paper model,
shot/read noise, 8-bit sRGB PNG files) is fitted in several ways:

- ``process``: one process, no Dask, warm starts (each frame starts from the previous one);
- ``process_cold``: one process, every frame runs the global thickness search;
- ``process_batch4``, ``process_batch8``: one process, warm starts, frames fitted 4 or 8
  at a time in one vmapped solve (:func:`bubblefit.inverse.fit.fit_batch`);
- ``cluster``: a Dask cluster (local, ``--workers`` processes, or ``--scheduler``), warm starts,
  the frames cut into one chunk per worker;
- ``cluster_cold``: the same without warm starts;
- ``cluster_cold_1``: no warm starts and one frame per task (no batching of frames per task).

Every worker (and this process) compiles the fit once before the clock starts, so the
numbers are steady-state frames per second; the cluster's start-up time is reported on
its own. Also reported: the RMS error of the fitted thickness against the truth.

Writes ``bench_sequence.json``, ``bench_sequence.csv`` and ``bench_sequence.png`` to ``--out``.

    python experiments/bench_sequence.py --quick
    python experiments/bench_sequence.py --frames 64 --size 96 --scheduler tcp://host:8786 --out /shared/bench

With ``--scheduler`` the frames are written under ``--out``, which the workers must see at
the same path (a shared file system), and the workers need bubblefit installed.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

D0 = 900.0  # nm, thickness of the first frame
TAU_FRAMES = 40.0  # d = D0 exp(-k / TAU_FRAMES): ~2.5 % (~20 nm) thinner each frame


def make_sequence(folder: Path, n: int, size: int, seed: int = 0):
    """Write ``n`` PNG frames of a draining film; return (EnvMap, env pixels, times, true thickness)."""
    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.io.images import read_image, write_image
    from bubblefit.model.render import render
    from bubblefit.model.scene import Scene, shipped_envmap

    px = read_image(shipped_envmap("courtyard")).pixels
    while px.shape[0] > 64:
        px = downsample(px)
    # exposed so that the background straight behind the bubble (-z) reads 0.5, not clipped
    view = EnvMap.from_array(px).lookup(np.asarray([[0.0, 0.0, -1.0]], np.float32))
    env = EnvMap.from_array(px * (0.5 / float(np.max(view))))
    folder.mkdir(parents=True, exist_ok=True)
    r = 0.42 * size
    disc = [size / 2, size / 2, r]
    # the map is also the background seen through the bubble (what a fit without a
    # background photo assumes); the film tints it (as fits assume by default)
    base = {"camera": {"width": size, "height": size, "disc": disc},
            "lighting": {"envmap": str(shipped_envmap("courtyard"))},
            "bubble": {"t": 0.972, "roughness": 0.015}, "effects": {"model": "paper", "transmission_tint": True}}
    cfg, _ = Scene.from_dict(dict(base, bubble=dict(base["bubble"], thickness_nm=D0))).config(env)
    rng = np.random.default_rng(seed)
    times, truth = [], []
    for k in range(n):
        d = D0 * np.exp(-k / TAU_FRAMES)
        p = Scene.from_dict(dict(base, bubble=dict(base["bubble"], thickness_nm=float(d)))).params()
        img = np.asarray(render(p, cfg, env), np.float64)
        sigma = np.sqrt(0.01**2 * np.clip(img, 0, None) + 0.002**2)
        write_image(folder / f"frame_{k:05d}.png", np.clip(img + rng.normal(size=img.shape) * sigma, 0, 1))
        times.append(float(k))
        truth.append(d)
    return env, tuple(disc), np.asarray(times), np.asarray(truth)


def _warm_worker(frame: str, env, options):
    """Compile the fit in this process (one frame, global search and a warm start)."""
    from bubblefit.inverse.fit import fit_photo
    from bubblefit.io.images import read_image

    photo = read_image(frame).pixels
    res = fit_photo(photo, env, options=options)
    fit_photo(photo, env, options=options, init=res.params)
    return os.getpid()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a short sequence (8 frames of 48x48)")
    ap.add_argument("--frames", type=int, default=None, help="frames in the sequence (default 24; quick 8)")
    ap.add_argument("--size", type=int, default=None, help="frame width and height in pixels (default 64; quick 48)")
    ap.add_argument("--workers", type=int, default=2, help="local cluster size (default 2)")
    ap.add_argument("--scheduler", default=None, help="an existing Dask scheduler instead of a local cluster")
    ap.add_argument("--out", default="experiments/results/bench_sequence", help="output folder")
    ap.add_argument("--skip", default="", help="comma-separated configurations to skip")
    ap.add_argument("--keep", action="store_true", help="keep the frames and the runs' folders under --out")
    args = ap.parse_args(argv)
    n = args.frames or (8 if args.quick else 24)
    size = args.size or (48 if args.quick else 64)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}

    from distributed import Client, LocalCluster

    from bubblefit.inverse.fit import FitOptions

    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import local_env
    from bubblefit.inverse.sequence import SequenceOptions as Seq, fit_sequence

    t0 = time.perf_counter()
    frames = out / "frames"
    env, disc, times, truth = make_sequence(frames, n, size)
    print(f"{n} frames of {size}x{size} rendered in {time.perf_counter() - t0:.1f} s", flush=True)
    options = FitOptions(disc=disc, thickness_range=(300.0, 1300.0), model="paper", view=ORTHOGRAPHIC)
    first = str(sorted(frames.iterdir())[0])

    rows = []

    def record(name, res, workers, chunk, warm, setup_s=0.0):
        d = res.column("thickness_nm")
        rms = float(np.sqrt(np.nanmean((d - truth) ** 2)))
        row = {"config": name, "workers": workers, "chunk_size": chunk, "warm_start": warm, "frames": res.fitted,
               "elapsed_s": res.elapsed_s, "fps": res.fps, "setup_s": setup_s, "failed": res.failed,
               "thickness_rms_nm": rms,
               "converged": int(sum(1 for r in res.records if r.get("converged")))}
        rows.append(row)
        print(f"{name:16s} workers={workers} chunk={chunk:3d} warm={warm!s:5s} {res.fitted} frames in "
              f"{res.elapsed_s:7.2f} s = {res.fps:6.3f} frames/s  thickness RMS {rms:.2f} nm", flush=True)

    # -- one process ---------------------------------------------------------------------------
    if not {"process", "process_cold"} <= skip:
        t = time.perf_counter()
        _warm_worker(first, env, options)
        print(f"compile in this process: {time.perf_counter() - t:.1f} s", flush=True)
    for name, warm, batch in (("process", True, 1), ("process_cold", False, 1), ("process_batch4", True, 4),
                              ("process_batch8", True, 8)):
        if name in skip:
            continue
        if batch > 1:  # compile the batched solver before the clock starts
            fit_sequence([str(f) for f in sorted(frames.iterdir())[: batch + 2]], env, out / "runs" / "compile",
                         options, Seq(workers=0, chunk_size=batch + 2, force=True, batch=batch, progress=False))
        res = fit_sequence(frames, env, out / "runs" / name, options,
                           Seq(workers=0, chunk_size=n, force=True, warm_start=warm, progress=True, batch=batch))
        record(name, res, 0, n, warm)

    # -- a Dask cluster ------------------------------------------------------------------------
    cluster_configs = [c for c in ("cluster", "cluster_cold", "cluster_cold_1") if c not in skip]
    if cluster_configs:
        t = time.perf_counter()
        cluster = None
        if args.scheduler:
            client = Client(args.scheduler)
        else:
            cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", env=local_env(), silence_logs=40)
            client = Client(cluster)
        n_workers = len(client.scheduler_info()["workers"])
        start_s = time.perf_counter() - t
        t = time.perf_counter()
        client.run(_warm_worker, first, env, options)
        warm_s = time.perf_counter() - t
        print(f"cluster of {n_workers} workers started in {start_s:.1f} s, compiled in {warm_s:.1f} s", flush=True)
        per = max(1, -(-n // n_workers))
        for name, warm, chunk in (("cluster", True, per), ("cluster_cold", False, per), ("cluster_cold_1", False, 1)):
            if name not in cluster_configs:
                continue
            res = fit_sequence(frames, env, out / "runs" / name, options,
                               Seq(scheduler=client, chunk_size=chunk, force=True, warm_start=warm, progress=True))
            record(name, res, res.workers, chunk, warm, start_s + warm_s)
        client.close()
        if cluster is not None:
            cluster.close()

    by = {r["config"]: r for r in rows}
    speedups = {}
    if "process" in by and "process_cold" in by:
        speedups["warm_start_one_process"] = by["process"]["fps"] / by["process_cold"]["fps"]
    if "cluster" in by and "cluster_cold" in by:
        speedups["warm_start_cluster"] = by["cluster"]["fps"] / by["cluster_cold"]["fps"]
    for b in (4, 8):
        if f"process_batch{b}" in by and "process" in by:
            speedups[f"vectorised_batch{b}_one_process"] = by[f"process_batch{b}"]["fps"] / by["process"]["fps"]
    if "cluster_cold" in by and "cluster_cold_1" in by:
        speedups["frame_batches_per_task"] = by["cluster_cold"]["fps"] / by["cluster_cold_1"]["fps"]
    if "cluster" in by and "process" in by:
        speedups["cluster_over_process"] = by["cluster"]["fps"] / by["process"]["fps"]
    for k, v in speedups.items():
        print(f"speed-up {k}: {v:.2f}x")

    meta = {"frames": n, "size": size, "cpu_count": os.cpu_count(), "python": sys.version.split()[0],
            "platform": platform.platform(), "load_avg": os.getloadavg(), "scheduler": args.scheduler or "local",
            "options": repr(options)}
    (out / "bench_sequence.json").write_text(json.dumps({"meta": meta, "rows": rows, "speedups": speedups},
                                                        indent=1) + "\n")
    with open(out / "bench_sequence.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["config"])
        w.writeheader()
        w.writerows(rows)
    if rows:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3.5), dpi=120)
        names = [r["config"] for r in rows]
        ax.bar(names, [r["fps"] for r in rows], color=["C0" if r["warm_start"] else "C1" for r in rows])
        for i, r in enumerate(rows):
            ax.text(i, r["fps"], f"{r['fps']:.2f}", ha="center", va="bottom", fontsize=8)
        ax.set_ylabel("frames per second")
        ax.set_title(f"{n} frames of {size}x{size}, {os.cpu_count()} cores (blue: warm starts)")
        fig.tight_layout()
        fig.savefig(out / "bench_sequence.png")
    if not args.keep:
        import shutil

        shutil.rmtree(frames, ignore_errors=True)
        shutil.rmtree(out / "runs", ignore_errors=True)
    print(f"wrote {out / 'bench_sequence.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
