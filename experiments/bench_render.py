"""Benchmark of the forward model: warm render time and peak memory.

Measures (numbers go into the issue notes):
  * compile time and warm time of a 256x256 bubble in the 1024x512 courtyard map with
    interference at 30 spectral samples, ``paper`` and ``physical`` models;
  * peak resident memory (resource.getrusage ru_maxrss) of a 1024x1024 render at 100
    spectral samples, in a fresh subprocess so that nothing else counts.
Writes ``bench_render.json`` and ``bench_render.png`` under ``--out`` (default
experiments/results/bench_render). ``--quick`` uses 128x128 and 256x256 at 30 samples.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

HERE = Path(__file__).resolve().parent


def _setup(model, size, samples, nodes=4):
    import jax.numpy as jnp

    from bubblefit.model.effects import Effects
    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.lighting.filtering import FilterConfig
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.io.images import read_image
    from bubblefit.model.render import Params, RenderConfig
    from bubblefit.model.scene import shipped_envmap
    from bubblefit.optics.spectral import spectral_basis

    env = EnvMap.from_array(read_image(shipped_envmap("courtyard")).pixels)
    fx = Effects(model=model, interference="two_beam" if model == "paper" else "airy",
                 filtering=FilterConfig("mipmap", nodes=nodes), spectral=spectral_basis("uniform", samples),
                 diffuse=True, bounces=1 if model == "paper" else 2)
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(size, size))
    p = Params.make(t=0.972, roughness=0.05, thickness=600.0, dtype=jnp.float32)
    return p, cfg, env


def time_render(model, size, samples, repeats=5):
    import jax

    from bubblefit.model.render import render

    p, cfg, env = _setup(model, size, samples)
    t0 = time.perf_counter()
    jax.block_until_ready(render(p, cfg, env))
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(render(p, cfg, env))
        times.append(time.perf_counter() - t0)
    return {"model": model, "size": size, "samples": samples, "first_call_s": first,
            "compile_s": first - min(times), "warm_s": min(times), "warm_median_s": sorted(times)[len(times) // 2]}


def _memory_child(model, size, samples):
    import resource

    import jax

    from bubblefit.model.render import render

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    p, cfg, env = _setup(model, size, samples)
    t0 = time.perf_counter()
    img = jax.block_until_ready(render(p, cfg, env))
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    print(json.dumps({"model": model, "size": size, "samples": samples, "peak_rss_mb": peak / 1024,
                      "rss_before_setup_mb": before / 1024, "render_s": wall, "finite": bool(jax.numpy.isfinite(img).all())}))


def peak_memory(model, size, samples):
    out = subprocess.run([sys.executable, __file__, "--child", model, str(size), str(samples)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results" / "bench_render"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _memory_child(args.child[0], int(args.child[1]), int(args.child[2]))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = [128] if args.quick else [64, 128, 256]
    timing = [time_render(m, s, 30) for m in ("paper", "physical") for s in sizes]
    for r in timing:
        print(f"{r['model']:9s} {r['size']}x{r['size']} 30 samples: compile {r['compile_s']:.2f} s, warm {r['warm_s']:.3f} s")
    mem_size, mem_samples = (256, 30) if args.quick else (1024, 100)
    memory = [peak_memory(m, mem_size, mem_samples) for m in ("paper", "physical")]
    for r in memory:
        print(f"{r['model']:9s} {r['size']}x{r['size']} {r['samples']} samples: peak RSS {r['peak_rss_mb']:.0f} MB, "
              f"{r['render_s']:.1f} s (incl. compile)")
    result = {"cpu_count": os.cpu_count(), "timing": timing, "memory": memory}
    from bubblefit.cli.common import write_json

    write_json(str(out / "bench_render.json"), result)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    for m in ("paper", "physical"):
        rows = [r for r in timing if r["model"] == m]
        ax[0].plot([r["size"] ** 2 for r in rows], [r["warm_s"] for r in rows], "o-", label=m)
    ax[0].set_xscale("log"), ax[0].set_yscale("log")
    ax[0].set_xlabel("pixels"), ax[0].set_ylabel("warm render time (s)"), ax[0].legend()
    ax[0].set_title("30 spectral samples, 1024x512 map")
    ax[1].bar([r["model"] for r in memory], [r["peak_rss_mb"] for r in memory])
    ax[1].axhline(2048, color="r", ls="--", label="2 GB target")
    ax[1].set_ylabel("peak RSS (MB)"), ax[1].legend()
    ax[1].set_title(f"{mem_size}x{mem_size}, {mem_samples} samples")
    fig.tight_layout()
    fig.savefig(out / "bench_render.png", dpi=100)
    print(f"wrote {out / 'bench_render.json'} and {out / 'bench_render.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
