"""Benchmark of :func:`bubblefit.inverse.fit.fit_photo`: accuracy and warm time.

Renders a bubble photo with known parameters in the shipped courtyard map (with noise
and 8-bit sRGB quantisation), fits it (constant thickness, then a per-pixel map), and
records the first (compiling) and the warm wall time and the errors. Writes
``bench_fit.json``, ``bench_fit.csv`` and ``bench_fit.png`` to ``--out``.

    python experiments/bench_fit.py [--quick] [--size 256] [--out experiments/results/bench_fit]
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
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_fit"))
    args = ap.parse_args()
    import jax

    cache = os.environ.get("BUBBLEFIT_CACHE_DIR", str(Path(__file__).resolve().parent.parent / ".jax_cache"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

    from scipy import ndimage as ndi

    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.io.images import read_image, srgb_decode, srgb_encode
    from bubblefit.model.scene import Scene, render_scene, shipped_envmap

    n = 64 if args.quick else args.size
    repeats = 1 if args.quick else args.repeats
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
    rows = []
    for kind in ("constant",) + (() if args.no_map else ("map",)):
        opts = FitOptions(thickness=kind, disc=disc, t_init=0.965, roughness_init=0.04, effects=effects)
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


if __name__ == "__main__":
    main()
