"""Benchmark of ``[effects]`` = auto over many scenes: what it skips, the time it saves, and its error.

Every scene is rendered twice with the same parameters: with its effects on ``auto`` and
with everything on (:func:`bubblefit.model.effects.all_on_settings`: every term, the
800-sample reference spectrum, four-node mipmap filtering, diffuse, eight internal
bounces). The scenes span the CC0 maps of ``../shared/data/envmaps`` (else the 256x128 copies of ``experiments/validation/data/envmaps``) (a sunrise with
its sun, a city, a courtyard, a night, a studio, an interior), a dark box and a lamp-lit
dark room; thin to thick films, mirror to rough, both models, point lights.

The promise checked in every scene: in each pixel of the bubble,
``max_c |auto - all-on| <= tolerance (max_c all-on + 0.1 x P99)``, with ``P99`` the 99th
percentile of the all-on bubble's largest channel (the budget of
:func:`bubblefit.model.footprint.pixel_budget`, measured on the all-on image). The table
reports the largest share of that budget any pixel uses.

The issue's target scene (``sunrise_mirror_6um``: a = 5e-4, r_d = 0, 6000 nm, physical)
is also rendered explicitly (Airy, 100 uniform samples, mirror lookup), and with
``--yardstick`` the whole-process time of ``bubblefit render`` at 256x256 (physical,
defaults) is compared with a Mitsuba 3 render of a thin dielectric sphere at 64 spp in the
same run (``.venv-render/bin/python`` or ``--mitsuba-python``).

    python experiments/bench_effects.py [--out DIR] [--quick] [--size N] [--scenes a,b] [--yardstick]

Writes ``bench_effects.json``, ``bench_effects.csv`` and ``bench_effects.png`` to ``--out``
(default ``experiments/results/bench_effects``).
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
_SHARED_MAPS = HERE.parent.parent / "shared" / "data" / "envmaps"
MAPS = Path(os.environ.get("BUBBLEFIT_ENVMAPS", _SHARED_MAPS if _SHARED_MAPS.is_dir()
                           else HERE / "validation" / "data" / "envmaps"))
MITSUBA_PYTHON = ".venv-render/bin/python"
FLOOR = 0.1


def checkerboard(h: int, w: int, squares: int = 8, lo: float = 0.05, hi: float = 0.8) -> np.ndarray:
    """An (h, w, 3) linear checkerboard photo (the dark box's background card)."""
    ii, jj = np.meshgrid(np.arange(h) * squares // h, np.arange(w) * squares // w, indexing="ij")
    val = np.where((ii + jj) % 2 == 0, hi, lo)
    return val[..., None] * np.array([1.0, 0.9, 0.8])


def _scene(size, bubble, lighting, effects):
    return {"camera": {"width": size, "height": size}, "bubble": bubble, "lighting": lighting, "effects": effects}


def scene_set(size: int = 64) -> dict:
    """``name -> (scene dict, background photo or None, map file name or None)``; every
    scene's ``[effects]`` is ``auto`` but for its model."""
    env = lambda name, **kw: dict({"envmap": f"{name}.exr"}, **kw)
    lamp = [{"direction": [0.5, 0.6, 1.0], "radiance": [0.5, 0.5, 0.5]}]
    phys = {"model": "physical"}
    drain = {"profile": "drainage", "top_nm": 150.0, "bottom_nm": 900.0, "exponent": 1.5}
    s = lambda *a: _scene(size, *a)
    return {
        "dark_box": (s({"t": 0.972, "thickness_nm": 600.0}, {}, {}), checkerboard(size, size), None),
        "point_light": (s({"t": 0.96, "roughness": 0.08, "thickness_nm": 400.0},
                          {"background": "black", "point_lights": lamp}, {}), None, None),
        "sunrise_mirror_6um": (s({"roughness": 5e-4, "r_d": 0.0, "thickness_nm": 6000.0}, env("sunrise"), phys),
                               None, "sunrise"),
        "sunrise_paper": (s({"thickness_nm": 500.0}, env("sunrise"), {}), None, "sunrise"),
        "sunrise_physical_drainage": (s({"roughness": 0.02, "thickness": drain}, env("sunrise"), phys),
                                      None, "sunrise"),
        "city_rough": (s({"roughness": 0.15, "thickness_nm": 350.0}, env("city"), {}), None, "city"),
        "courtyard_thick": (s({"roughness": 0.03, "thickness_nm": 12000.0}, env("courtyard", scale=0.2), {}),
                            None, "courtyard"),
        "night_physical_light": (s({"roughness": 0.01, "thickness_nm": 800.0},
                                   env("night", point_lights=lamp), phys), None, "night"),
        "studio_physical": (s({}, env("studio"), phys), None, "studio"),
        "interior_mirror": (s({"roughness": 0.0, "f": 0.0, "thickness_nm": 450.0}, env("interior"), {}),
                            None, "interior"),
    }


SCENE_NAMES = tuple(scene_set(8))
TARGET = "sunrise_mirror_6um"
EXPLICIT = {"interference": "airy", "spectral": {"method": "uniform", "samples": 100}, "filtering": "mirror"}


def all_on(data: dict) -> dict:
    """A copy of scene ``data`` with its ``[effects]`` replaced by the all-on table."""
    from bubblefit.model.effects import all_on_settings

    eff = data.get("effects", {})
    return dict(data, effects=all_on_settings(eff.get("model", "paper"), eff))


def load_map(name: str | None, height: int | None = None, scale: float = 1.0):
    """The CC0 map ``name`` (downsampled, power preserving, to ``height`` rows) times ``scale``."""
    if name is None:
        return None
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    px = read_image(MAPS / f"{name}.exr").pixels
    while height is not None and px.shape[0] > height:
        px = downsample(px)
    return EnvMap.from_array(px * scale)


def prepare(data: dict, background, env):
    """(params, render parts, decisions, background array) of a scene, as render_scene does."""
    from bubblefit.model.scene import Scene

    if background is not None:
        data = dict(data, lighting=dict(data.get("lighting", {}), background="photo"))
    scene = Scene.from_dict(data)
    bg = None if background is None else np.asarray(background, dtype=np.float64)
    parts, decisions = scene.plan(env, bg)
    return scene.params(), parts, decisions, bg


def render_parts(params, parts, env, bg) -> np.ndarray:
    from bubblefit.model.programs import STORED
    from bubblefit.model.regions import render_plan

    return np.asarray(render_plan(params, parts, env, bg, programs=STORED), dtype=np.float64)


def bubble_mask(h: int, w: int) -> np.ndarray:
    """Pixels whose centre lies on the default orthographic camera's disc (every scene here)."""
    from bubblefit.model.geometry import OrthographicCamera

    cx, cy, r = OrthographicCamera(w, h).disc()
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    return (jj - cx) ** 2 + (ii - cy) ** 2 < r * r


def budget_share(img: np.ndarray, ref: np.ndarray, tol: float, noise: np.ndarray | None = None) -> float:
    """Largest ``max_c (|img - ref| - 2 noise) / (tol (max_c ref + FLOOR P99))`` over the
    bubble's pixels, ``P99`` the 99th percentile of ``max_c ref`` there, ``noise`` (H, W, 3)
    the renderer's own float32 reproducibility (:func:`reproducibility`; none: 0)."""
    inside = bubble_mask(*ref.shape[:2])
    lum = ref.max(axis=-1)[inside]
    diff = np.abs(img - ref)
    if noise is not None:
        diff = np.maximum(diff - 2.0 * noise, 0.0)
    diff = diff.max(axis=-1)[inside]
    bright = float(np.percentile(lum, 99.0))
    return float(np.max(diff / (tol * (lum + FLOOR * bright))))


def reproducibility(params, parts, env, bg, ref: np.ndarray) -> np.ndarray:
    """``|ref' - ref|`` (H, W, 3): the all-on image ``ref`` rendered again in chunks of
    :data:`~bubblefit.model.render.MIN_CHUNK` pixels, the size of a small region's chunks.

    Two float32 renders with the same settings, compiled for other chunk sizes, round
    differently; where a mirror sees the edge of a sun (radiance falling by 1e4 over a
    texel) that moves a pixel by a few percent. ``auto`` cannot be held to less than that:
    :func:`budget_share` takes twice this off each difference (auto's image is a third
    such render).
    """
    import dataclasses

    from bubblefit.model.render import MIN_CHUNK

    alt = [(dataclasses.replace(cfg, chunk=MIN_CHUNK), px) for cfg, px in parts]
    return np.abs(render_parts(params, alt, env, bg) - ref)


def _time(fn, repeats: int):
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        warm.append(time.perf_counter() - t0)
    med = statistics.median(warm) if warm else first
    return first, med, out


def run_scene(name, data, bg, env, repeats: int) -> dict:
    from bubblefit.model.auto import DEFAULT_TOLERANCE

    tol = float(data.get("effects", {}).get("tolerance", DEFAULT_TOLERANCE))
    t0 = time.perf_counter()
    p, parts, dec, bgr = prepare(data, bg, env)
    plan_s = time.perf_counter() - t0
    p_r, parts_r, _, bg_r = prepare(all_on(data), bg, env)
    fa, wa, img_a = _time(lambda: render_parts(p, parts, env, bgr), repeats)
    fr, wr, img_r = _time(lambda: render_parts(p_r, parts_r, env, bg_r), repeats)
    share = raw = budget_share(img_a, img_r, tol)
    floor = 0.0
    if raw > 1.0:  # is it auto's choice, or the float32 rounding of two compilations?
        noise = reproducibility(p_r, parts_r, env, bg_r, img_r)
        share, floor = budget_share(img_a, img_r, tol, noise), budget_share(img_r + noise, img_r, tol)
    na = {"fresnel", "thickness_field", "environment", "point_lights", "transmission_tint"}
    skipped = [d.effect + (f"[{d.setting}]" if d.setting else "") for d in dec if not d.simulated and d.effect not in na]
    cheaper = [f"{d.effect}[{d.setting}]" for d in dec if d.simulated and d.setting and d.effect in
               ("spectral", "roughness_filtering", "internal_bounces")]
    row = {"scene": name, "plan_s": plan_s, "auto_warm_s": wa, "all_on_warm_s": wr, "speedup": wr / max(wa, 1e-12),
           "auto_first_s": fa, "all_on_first_s": fr, "budget_share": share, "budget_share_raw": raw,
           "float32_floor": floor, "tolerance": tol,
           "within_tolerance": share <= 1.0, "regions": len(parts),
           "bright_pixels": int(sum(len(px) for _, px in parts[1:])), "skipped": skipped, "chosen": cheaper,
           "decisions": [{"effect": d.effect, "simulated": d.simulated, "setting": d.setting, "reason": d.reason,
                          "budget_used": d.budget_used} for d in dec]}
    if name == TARGET:
        p_e, parts_e, _, bg_e = prepare(dict(data, effects=dict(data["effects"], **EXPLICIT)), bg, env)
        fe, we, img_e = _time(lambda: render_parts(p_e, parts_e, env, bg_e), repeats)
        inside = bubble_mask(*img_e.shape[:2])
        lum = img_e.max(axis=-1)[inside]
        rel = np.abs(img_a - img_e).max(axis=-1)[inside] / np.maximum(lum + FLOOR * np.percentile(lum, 99), 1e-12)
        row.update(explicit_warm_s=we, explicit_first_s=fe, auto_vs_explicit_max_rel=float(rel.max()),
                   auto_vs_explicit_rms_rel=float(np.sqrt(np.mean(rel**2))),
                   auto_over_explicit_time=wa / max(we, 1e-12))
    print(f"{name:<26} auto {wa:7.3f} s  all-on {wr:7.3f} s  x{row['speedup']:5.1f}  plan {plan_s:5.1f} s  "
          f"budget used {share:5.2f} (raw {raw:5.2f}, all-on against itself {floor:4.2f}; tol {tol:g})  skipped: {', '.join(skipped)}  chosen: {', '.join(cheaper)}",
          flush=True)
    return row


MITSUBA_SCRIPT = r'''
import sys, time
import mitsuba as mi
mi.set_variant("scalar_rgb")
size, envmap, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
scene = mi.load_dict({"type": "scene", "integrator": {"type": "path", "max_depth": 10},
    "sensor": {"type": "perspective", "fov": 30, "to_world": mi.ScalarTransform4f.look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
               "film": {"type": "hdrfilm", "width": size, "height": size}, "sampler": {"type": "independent", "sample_count": 64}},
    "emitter": {"type": "envmap", "filename": envmap},
    "bubble": {"type": "sphere", "bsdf": {"type": "thindielectric", "int_ior": 1.4, "ext_ior": 1.0}}})
mi.util.write_bitmap(out, mi.render(scene))
'''


def yardstick(size: int, mitsuba_python: str, repeats: int = 3) -> dict:
    """Whole-process seconds of ``bubblefit render`` (256x256 physical, defaults; a cold and
    then warm persistent compilation cache) and of Mitsuba 3 at 64 spp, in this run: the
    warm runs and Mitsuba's alternate, ``repeats`` of each, and the ratio is of medians."""
    out = {"bubblefit_warm_runs_s": [], "mitsuba_runs_s": []}
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "bubble.toml"
        scene.write_text(f'[camera]\nwidth = {size}\nheight = {size}\n[lighting]\nenvmap = "{MAPS / "sunrise.exr"}"\n'
                         '[effects]\nmodel = "physical"\n')
        env = dict(os.environ, BUBBLEFIT_CACHE_DIR=str(Path(tmp) / "cache"), JAX_PLATFORMS="cpu",
                   PYTHONPATH=str(HERE.parent))

        def clock(cmd, **kw) -> float:
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True, **kw)
            return time.perf_counter() - t0

        bubblefit = [sys.executable, "-m", "bubblefit", "render", str(scene), "-o", str(Path(tmp) / "b.exr")]
        mitsuba = [mitsuba_python, "-c", MITSUBA_SCRIPT, str(size), str(MAPS / "sunrise.exr"), str(Path(tmp) / "m.exr")]
        have_mitsuba = Path(mitsuba_python).exists()
        out["bubblefit_cold_s"] = clock(bubblefit, env=env)
        for _ in range(repeats):
            out["bubblefit_warm_runs_s"].append(clock(bubblefit, env=env))
            if have_mitsuba:
                out["mitsuba_runs_s"].append(clock(mitsuba))
    out["bubblefit_warm_s"] = statistics.median(out["bubblefit_warm_runs_s"])
    if out["mitsuba_runs_s"]:
        out["mitsuba_64spp_s"] = statistics.median(out["mitsuba_runs_s"])
        out["ratio_warm"] = out["bubblefit_warm_s"] / out["mitsuba_64spp_s"]
        out["ratio_cold"] = out["bubblefit_cold_s"] / out["mitsuba_64spp_s"]
    return out


def write_outputs(rows: list[dict], out: Path, meta: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bubblefit.cli.common import write_json
    from bubblefit.io.images import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "bench_effects.json", {"meta": meta, "scenes": rows})
    cols = ["scene", "auto_warm_s", "all_on_warm_s", "speedup", "plan_s", "auto_first_s", "all_on_first_s",
            "budget_share", "budget_share_raw", "float32_floor", "tolerance", "within_tolerance", "regions", "bright_pixels", "skipped", "chosen"]
    with atomic_path(out / "bench_effects.csv") as tmp:
        with open(tmp, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(cols)
            for r in rows:
                wr.writerow([";".join(r[c]) if c in ("skipped", "chosen") else r[c] for c in cols])
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.5))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["all_on_warm_s"] for r in rows], 0.4, label="all on")
    ax.bar(x + 0.2, [r["auto_warm_s"] for r in rows], 0.4, label="auto")
    ax.set_xticks(x, [r["scene"] for r in rows], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("warm render time (s, median)")
    ax.set_yscale("log")
    ax.legend()
    bx.bar(x, [r["budget_share"] for r in rows])
    bx.axhline(1.0, color="k", lw=0.8)
    bx.set_xticks(x, [r["scene"] for r in rows], rotation=60, ha="right", fontsize=7)
    bx.set_ylabel("largest share of a pixel's budget used (<= 1)")
    fig.suptitle(f"effects auto vs all on ({meta['size']}x{meta['size']})")
    fig.tight_layout()
    with atomic_path(out / "bench_effects.png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def markdown_table(rows: list[dict]) -> str:
    lines = ["| scene | skipped | cheaper choice | auto (s) | all on (s) | speed-up | budget used |",
             "|---|---|---|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {', '.join(r['skipped'])} | {', '.join(r['chosen'])} | "
                     f"{r['auto_warm_s']:.3f} | {r['all_on_warm_s']:.3f} | {r['speedup']:.1f}x | "
                     f"{r['budget_share']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="experiments/bench_effects.py", description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(HERE / "results" / "bench_effects"), help="output folder (default: %(default)s)")
    p.add_argument("--size", type=int, default=None, help="image size in pixels (default 128; 48 with --quick)")
    p.add_argument("--target-size", type=int, default=256, help="image size of the target scene (default 256)")
    p.add_argument("--map-height", type=int, default=None, help="downsample the maps to this many rows (default: full)")
    p.add_argument("--repeats", type=int, default=None, help="warm calls per render (default 2; 1 with --quick)")
    p.add_argument("--quick", action="store_true", help="small images, for a smoke test")
    p.add_argument("--scenes", default=",".join(SCENE_NAMES), help="comma-separated subset of the scenes")
    p.add_argument("--yardstick", action="store_true", help="also time bubblefit render against Mitsuba 3 (whole processes)")
    p.add_argument("--mitsuba-python", default=MITSUBA_PYTHON, help="python with mitsuba 3 (default: %(default)s)")
    args = p.parse_args(argv)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import jax

    size = args.size or (48 if args.quick else 128)
    repeats = args.repeats or (1 if args.quick else 2)
    names = [n for n in args.scenes.split(",") if n]
    for n in names:
        if n not in SCENE_NAMES:
            p.error(f"unknown scene {n!r} (known: {', '.join(SCENE_NAMES)})")
    rows, maps = [], {}
    for name in names:
        data, bg, mapname = scene_set(args.target_size if name == TARGET and not args.quick else size)[name]
        key = (mapname, float(data["lighting"].get("scale", 1.0)))
        if key not in maps:
            maps[key] = load_map(mapname, args.map_height, key[1])
        jax.clear_caches()
        rows.append(run_scene(name, data, bg, maps[key], repeats))
    meta = {"size": size, "target_size": args.target_size, "map_height": args.map_height, "repeats": repeats,
            "backend": jax.default_backend(), "cpus": os.cpu_count(), "floor": FLOOR}
    if args.yardstick:
        meta["yardstick"] = yardstick(256, args.mitsuba_python)
        print("yardstick:", meta["yardstick"])
    if not rows:  # --scenes '': the yardstick alone
        from bubblefit.cli.common import write_json

        Path(args.out).mkdir(parents=True, exist_ok=True)
        write_json(Path(args.out) / "yardstick.json", meta)
        print(f"wrote {args.out}/yardstick.json")
        return 0
    write_outputs(rows, Path(args.out), meta)
    print(markdown_table(rows))
    for r in rows:
        if "explicit_warm_s" in r:
            print(f"{r['scene']}: auto {r['auto_warm_s']:.3f} s vs explicit {r['explicit_warm_s']:.3f} s "
                  f"(x{r['auto_over_explicit_time']:.2f}), max rel diff {r['auto_vs_explicit_max_rel']:.4f}, "
                  f"rms {r['auto_vs_explicit_rms_rel']:.4f}")
    print(f"wrote {args.out}/bench_effects.json, .csv, .png")
    return 0 if all(r["within_tolerance"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
