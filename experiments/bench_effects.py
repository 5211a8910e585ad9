"""Benchmark of ``[effects]`` = auto: what each scene skips, the time it saves, and the error.

For a set of scenes that each need a different subset of the model (a dark-box
calibration, a point light in a dark room, a mirror bubble in an environment, a thick
film, a rough film, the full physical model), every scene is rendered twice with the same
parameters: with its effects on ``auto`` and with everything on
(:func:`bubblefit.model.effects.all_on_settings`: every term, converged spectral integration,
mipmap filtering, diffuse, all internal bounces). Per scene it records the compile time
(first call minus a warm call), the warm median of a few calls, the largest absolute
pixel difference ``max |auto - all-on|`` (linear radiance) against the tolerance, and the
effects ``auto`` skipped.

    python experiments/bench_effects.py [--out DIR] [--quick] [--size N] [--repeats R]

Writes ``bench_effects.json``, ``bench_effects.csv`` and ``bench_effects.png`` (bar chart
of warm time per scene) to ``--out`` (default ``experiments/results/bench_effects``).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

#: Scene names, each needing a different subset of the model.
SCENE_NAMES = ("dark_box", "point_light", "mirror_bubble", "thick_film", "rough_film", "full_model")


def checkerboard(h: int, w: int, squares: int = 8, lo: float = 0.05, hi: float = 0.8) -> np.ndarray:
    """An (h, w, 3) linear checkerboard photo (the dark box's background card)."""
    ii, jj = np.meshgrid(np.arange(h) * squares // h, np.arange(w) * squares // w, indexing="ij")
    val = np.where((ii + jj) % 2 == 0, hi, lo)
    tint = np.array([1.0, 0.9, 0.8])
    return val[..., None] * tint


def scene_set(size: int = 64) -> dict:
    """The benchmark's scenes as ``name -> (scene table dict, background photo or None, map name)``.

    ``map name`` is ``None`` (no environment) or a shipped map (``courtyard``). Every
    scene's ``[effects]`` is empty (all ``auto``); :func:`all_on` makes the reference.
    """
    cam = {"width": size, "height": size}
    return {
        # Calibration in a dark box: no light on the film, a checkerboard behind it.
        "dark_box": ({"camera": cam, "bubble": {"t": 0.972, "thickness_nm": 600.0},
                      "lighting": {}, "effects": {}}, checkerboard(size, size), None),
        # A dark room lit by one distant light (eq. 3): no map, no background.
        "point_light": ({"camera": cam, "bubble": {"t": 0.96, "roughness": 0.08, "thickness_nm": 400.0},
                         "lighting": {"background": "black",
                                      "point_lights": [{"direction": [0.5, 0.6, 1.0], "radiance": [0.5, 0.5, 0.5]}]},
                         "effects": {}}, None, None),
        # A mirror-smooth bubble without diffuse term (f = 0: r_d = 0) in the courtyard.
        "mirror_bubble": ({"camera": cam, "bubble": {"t": 0.972, "roughness": 1e-7, "f": 0.0, "thickness_nm": 450.0},
                           "lighting": {"envmap": "courtyard.exr"}, "effects": {}}, None, "courtyard"),
        # A thick (12 um) film under a dim sky (the courtyard at 1/5): colours average out.
        "thick_film": ({"camera": cam, "bubble": {"t": 0.972, "roughness": 0.03, "thickness_nm": 12000.0},
                        "lighting": {"envmap": "courtyard.exr", "scale": 0.2}, "effects": {}}, None, "courtyard"),
        # A rough film (paper model, everything but bounces).
        "rough_film": ({"camera": cam, "bubble": {"t": 0.972, "roughness": 0.15, "thickness_nm": 350.0},
                        "lighting": {"envmap": "courtyard.exr"}, "effects": {}}, None, "courtyard"),
        # The full physical model: Airy film, drainage profile, internal bounces, light and map.
        "full_model": ({"camera": cam,
                        "bubble": {"t": 0.95, "roughness": 0.02,
                                   "thickness": {"profile": "drainage", "top_nm": 150.0, "bottom_nm": 900.0,
                                                 "exponent": 1.5}},
                        "lighting": {"envmap": "courtyard.exr",
                                     "point_lights": [{"direction": [-0.4, 0.8, 1.0], "radiance": [0.3, 0.3, 0.3]}]},
                        "effects": {"model": "physical"}}, None, "courtyard"),
    }


def all_on(data: dict) -> dict:
    """A copy of scene ``data`` with its ``[effects]`` replaced by the all-on table."""
    from bubblefit.model.effects import all_on_settings

    eff = data.get("effects", {})
    return dict(data, effects=all_on_settings(eff.get("model", "paper"), eff))


def load_map(name: str | None, height: int, scale: float = 1.0):
    """The shipped map ``name`` downsampled (power preserving) to ``height`` rows and
    multiplied by ``scale``, as an EnvMap."""
    if name is None:
        return None
    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.io.images import read_image
    from bubblefit.model.scene import shipped_envmap

    px = read_image(shipped_envmap(name)).pixels
    while px.shape[0] > height:
        px = downsample(px)
    return EnvMap.from_array(px * scale)


def prepare(data: dict, background, env):
    """(params, RenderConfig, decisions, background array) of a scene, as render_scene does."""
    from bubblefit.model.scene import Scene

    if background is not None:
        data = dict(data, lighting=dict(data.get("lighting", {}), background="photo"))
    scene = Scene.from_dict(data)
    cfg, decisions = scene.config(env, background)
    bg = None if background is None else np.asarray(background, dtype=np.float64)
    return scene.params(), cfg, decisions, bg


def time_render(params, cfg, env, bg, repeats: int):
    """(compile_s, warm median s, image) of :func:`bubblefit.model.render.render`."""
    import jax

    from bubblefit.model.render import render

    t0 = time.perf_counter()
    img = jax.block_until_ready(render(params, cfg, env, bg))
    first = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        img = jax.block_until_ready(render(params, cfg, env, bg))
        warm.append(time.perf_counter() - t0)
    med = statistics.median(warm)
    return max(first - med, 0.0), med, np.asarray(img, dtype=np.float64)


def run(size: int, map_height: int, repeats: int, names=SCENE_NAMES) -> list[dict]:
    """Benchmark every scene of :func:`scene_set`; one result dict per scene."""
    import jax

    scenes = scene_set(size)
    maps = {}
    rows = []
    for name in names:
        data, bg, mapname = scenes[name]
        key = (mapname, float(data["lighting"].get("scale", 1.0)))
        if key not in maps:
            maps[key] = load_map(mapname, map_height, key[1])
        env = maps[key]
        jax.clear_caches()  # each scene's compile time measured from scratch
        p_a, cfg_a, dec, bg_a = prepare(data, bg, env)
        p_r, cfg_r, _, bg_r = prepare(all_on(data), bg, env)
        ca, wa, img_a = time_render(p_a, cfg_a, env, bg_a, repeats)
        cr, wr, img_r = time_render(p_r, cfg_r, env, bg_r, repeats)
        diff = float(np.max(np.abs(img_a - img_r)))
        tol = float(data.get("effects", {}).get("tolerance", 1e-3))
        # Effects that apply to the scene's model and that auto turned off.
        na = {"fresnel", "thickness_field", "internal_bounces"} if cfg_a.effects.model == "paper" else {"thickness_field"}
        skipped = [d.effect + (f"[{d.setting}]" if d.setting else "") for d in dec
                   if not d.simulated and d.effect not in na]
        rows.append({"scene": name, "auto_warm_s": wa, "all_on_warm_s": wr, "speedup": wr / max(wa, 1e-12),
                     "auto_compile_s": ca, "all_on_compile_s": cr, "max_abs_diff": diff, "tolerance": tol,
                     "within_tolerance": diff < tol, "peak_radiance": float(np.max(img_r)),
                     "skipped": skipped,
                     "decisions": [{"effect": d.effect, "simulated": d.simulated, "setting": d.setting,
                                    "reason": d.reason} for d in dec]})
        print(f"{name:<14} auto {wa * 1e3:8.1f} ms  all-on {wr * 1e3:8.1f} ms  x{wr / max(wa, 1e-12):5.1f}  "
              f"compile {ca:5.1f}/{cr:5.1f} s  max|diff| {diff:.2e} (tol {tol:g})  skipped: {', '.join(skipped)}",
              flush=True)
    return rows


def write_outputs(rows: list[dict], out: Path, meta: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bubblefit.cli.common import write_json
    from bubblefit.io.images import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "bench_effects.json", {"meta": meta, "scenes": rows})
    cols = ["scene", "auto_warm_s", "all_on_warm_s", "speedup", "auto_compile_s", "all_on_compile_s",
            "max_abs_diff", "tolerance", "within_tolerance", "skipped"]
    with atomic_path(out / "bench_effects.csv") as tmp:
        with open(tmp, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(cols)
            for r in rows:
                wr.writerow([";".join(r[c]) if c == "skipped" else r[c] for c in cols])
    fig, ax = plt.subplots(figsize=(8, 4))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["all_on_warm_s"] * 1e3 for r in rows], 0.4, label="all on")
    ax.bar(x + 0.2, [r["auto_warm_s"] * 1e3 for r in rows], 0.4, label="auto")
    ax.set_xticks(x, [r["scene"] for r in rows], rotation=20)
    ax.set_ylabel("warm render time (ms, median)")
    ax.set_yscale("log")
    ax.set_title(f"effects auto vs all on ({meta['size']}x{meta['size']}, map {meta['map_height']}x{2 * meta['map_height']})")
    ax.legend()
    fig.tight_layout()
    with atomic_path(out / "bench_effects.png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def markdown_table(rows: list[dict]) -> str:
    lines = ["| scene | skipped by auto | auto (ms) | all on (ms) | speed-up | compile auto / all on (s) | max abs diff |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {', '.join(r['skipped'])} | {r['auto_warm_s'] * 1e3:.1f} | "
                     f"{r['all_on_warm_s'] * 1e3:.1f} | {r['speedup']:.1f}x | {r['auto_compile_s']:.1f} / "
                     f"{r['all_on_compile_s']:.1f} | {r['max_abs_diff']:.1e} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="experiments/bench_effects.py", description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(HERE / "results" / "bench_effects"), help="output folder (default: %(default)s)")
    p.add_argument("--size", type=int, default=None, help="image size in pixels (default 128; 64 with --quick)")
    p.add_argument("--map-height", type=int, default=None, help="environment map rows (default 128; 64 with --quick)")
    p.add_argument("--repeats", type=int, default=None, help="warm calls per render (default 5; 2 with --quick)")
    p.add_argument("--quick", action="store_true", help="small images and maps, for a smoke test")
    p.add_argument("--scenes", default=",".join(SCENE_NAMES), help="comma-separated subset of the scenes")
    args = p.parse_args(argv)
    import os

    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import jax

    size = args.size or (64 if args.quick else 128)
    mh = args.map_height or (64 if args.quick else 128)
    repeats = args.repeats or (2 if args.quick else 5)
    names = [n for n in args.scenes.split(",") if n]
    for n in names:
        if n not in SCENE_NAMES:
            p.error(f"unknown scene {n!r} (known: {', '.join(SCENE_NAMES)})")
    rows = run(size, mh, repeats, names)
    meta = {"size": size, "map_height": mh, "repeats": repeats, "backend": jax.default_backend(),
            "device": str(jax.devices()[0]), "dtype": "float32"}
    write_outputs(rows, Path(args.out), meta)
    print(markdown_table(rows))
    print(f"wrote {args.out}/bench_effects.json, .csv, .png")
    return 0 if all(r["within_tolerance"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
