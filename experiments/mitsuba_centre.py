"""Where the disc centre differs from Mitsuba 3's thin dielectric sphere, term by term.

A sphere (radius 1) with Mitsuba's ``thindielectric`` BSDF (n = 1.4, no interference) in a
map whose sun is clamped (so that Monte Carlo converges), seen by an orthographic camera
(disc radius 0.4 of the width), is rendered by Mitsuba's path tracer and by bubblefit's
``physical`` model with an incoherent film (the thick-film limit, ``2 R1/(1 + R1)`` per
film, which is what ``thindielectric`` sums: Born & Wolf 7.6).

The bisection uses the path length: Mitsuba with ``max_depth = 2`` returns the front
reflection alone, ``3`` adds the background through both films, ``4`` the first internal
bounce, ``64`` every bounce (Russian roulette off). bubblefit renders the same sums by
switching its terms (``front_reflection``, ``transmission``, ``bounces``), and once with
its default bubble, whose Ward diffuse term ``r_d E / pi`` (eq. 2, ``r_d`` from eq. 14 with
``f = 0.3``) a thin dielectric does not have.

Mitsuba's own noise is measured, not assumed: each Mitsuba image is the mean of two renders
with different seeds, and half their difference is its standard error per pixel. The
reported ``bias_rms`` is ``sqrt(max(0, rms^2 - noise^2))``.

    .venv/bin/python experiments/mitsuba_centre.py [--size 128] [--spp 4096] [--clamp 20]

Writes ``experiments/results/mitsuba_centre.json`` and ``mitsuba_centre.png``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MAPS = Path("/work/shared/data/envmaps")
N_FILM = 1.4
#: The disc's radius as a fraction of the image width: bubblefit's orthographic default.
DISC_FRACTION = 0.4

MITSUBA = r'''
import json, sys
import numpy as np
import mitsuba as mi
mi.set_variant("scalar_rgb")
c = json.loads(sys.argv[1])
T = mi.ScalarTransform4f
hw = 0.5 / c["disc_fraction"]          # half the image width in units of the sphere's radius
for job in c["jobs"]:
    scene = mi.load_dict({"type": "scene",
        "integrator": {"type": "path", "max_depth": job["max_depth"], "rr_depth": 1000},
        "sensor": {"type": "orthographic",
                   "to_world": T().look_at(origin=[0, 0, 10], target=[0, 0, 0], up=[0, 1, 0]) @ T().scale([hw, hw, 1]),
                   "film": {"type": "hdrfilm", "width": c["size"], "height": c["size"],
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": job["spp"], "seed": job["seed"]}},
        "emitter": {"type": "envmap", "filename": c["envmap"]},
        "bubble": {"type": "sphere", "center": [0, 0, 0], "radius": 1.0,
                   "bsdf": {"type": "thindielectric", "int_ior": c["n"], "ext_ior": 1.0}}})
    np.save(job["out"], np.array(mi.render(scene), dtype=np.float64)[..., :3])
print(mi.__version__)
'''

#: bubblefit's variants: name -> (bubble table, effects table). Every one renders the
#: physical model with an incoherent (thick) film and a mirror-smooth surface.
BF_VARIANTS = {
    "default_bubble": ({}, {}),
    "all_terms": ({"r_d": 0.0, "r_s": 0.0}, {"diffuse": False}),
    "front": ({"r_d": 0.0, "r_s": 0.0}, {"diffuse": False, "rear_reflection": False, "transmission": False}),
    "front_transmission": ({"r_d": 0.0, "r_s": 0.0}, {"diffuse": False, "rear_reflection": False}),
    "bounce1": ({"r_d": 0.0, "r_s": 0.0}, {"diffuse": False, "bounces": 1}),
}
#: Which Mitsuba path length each bubblefit variant is compared with.
PAIRS = [("default_bubble", 64), ("all_terms", 64), ("front", 2), ("front_transmission", 3), ("bounce1", 4)]


def clamp_map(name: str, clamp: float, out: Path) -> Path:
    """The map with every channel clipped at ``clamp`` (and at 0 below), written as EXR."""
    from bubblefit.io.images import read_image, write_image

    px = read_image(MAPS / f"{name}.exr", linear=True).pixels[..., :3]
    path = out / f"{name}_clamp{clamp:g}.exr"
    write_image(path, np.clip(px, 0.0, clamp).astype(np.float32))
    return path


def render_bubblefit(envmap: Path, size: int, spp: int, bubble: dict, effects: dict) -> np.ndarray:
    """bubblefit's physical render of the scene (linear, (H, W, 3))."""
    from bubblefit.model.scene import Scene, render_scene

    data = {"camera": {"type": "orthographic", "width": size, "height": size, "samples_per_pixel": spp},
            "bubble": {"roughness": 0.0, "n_film": N_FILM, **bubble},
            "lighting": {"envmap": str(envmap), "background": "envmap"},
            "effects": {"model": "physical", "interference": "incoherent", "bounces": 8, **effects}}
    return np.asarray(render_scene(Scene.from_dict(data)), dtype=np.float64)


def radius_map(size: int) -> np.ndarray:
    """Each pixel centre's distance from the disc centre in units of the disc radius."""
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    return np.hypot(xx - size / 2, yy - size / 2) / (DISC_FRACTION * size)


def compare(ours: np.ndarray, m0: np.ndarray, m1: np.ndarray, rho: np.ndarray) -> dict:
    """Per region: ratio of means per channel, per-pixel relative RMS, Mitsuba's noise and
    the bias left after the noise, with and without the sun's glints (the brightest 2 % of
    the half disc's pixels in Mitsuba)."""
    ref = 0.5 * (m0 + m1)
    noise = 0.5 * np.abs(m0 - m1) / np.maximum(ref, 1e-12)
    rel = (ours - ref) / np.maximum(ref, 1e-12)
    lum = ref.mean(-1)
    glint = lum > np.percentile(lum[rho < 0.5], 98)
    out = {}
    for name, sel in {"half_disc": rho < 0.5, "inner_disc": rho < 0.9, "outside": rho > 1.05}.items():
        row = {}
        for tag, m in (("all", sel), ("without_glints", sel & ~glint)):
            rms = float(np.sqrt(np.mean(rel[m] ** 2)))
            nrms = float(np.sqrt(np.mean(noise[m] ** 2)))
            row[tag] = {"pixels": int(m.sum()), "rel_rms": rms, "mitsuba_noise_rms": nrms,
                        "bias_rms": float(np.sqrt(max(0.0, rms**2 - nrms**2))),
                        "ratio_of_means": (ours[m].mean(0) / ref[m].mean(0)).tolist()}
        out[name] = row
    return out


def slab_centre(n: float) -> dict:
    """The centre pixel's weights at normal incidence, closed form: a film reflects
    ``R = 2 R1/(1 + R1)`` (R1 Fresnel's ``((n-1)/(n+1))^2``), transmits ``T = 1 - R``; the
    light from behind the camera weighs ``R + T^2 R/(1 - R^2)``, the background ``T^2/(1 - R^2)``."""
    r1 = ((n - 1) / (n + 1)) ** 2
    r = 2 * r1 / (1 + r1)
    t = 1 - r
    return {"R1": r1, "R_film": r, "front_weight": r + t * t * r / (1 - r * r), "back_weight": t * t / (1 - r * r)}


def figure(path: Path, ref, variants: dict, noise, rho, stats) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bubblefit.io.images import atomic_path

    fig, ax = plt.subplots(2, 3, figsize=(13, 8))
    show = lambda img: np.clip(img / np.percentile(ref, 99.5), 0, 1) ** (1 / 2.2)
    ax[0, 0].imshow(show(ref)); ax[0, 0].set_title("Mitsuba 3 thindielectric (mean of 2 seeds)")
    ax[0, 1].imshow(show(variants["all_terms"])); ax[0, 1].set_title("bubblefit physical, r_d = 0, 16 spp")
    for a, key, title in ((ax[0, 2], "default_bubble", "default bubble (r_d from f = 0.3) / Mitsuba - 1"),
                          (ax[1, 0], "all_terms", "r_d = 0 / Mitsuba - 1")):
        im = a.imshow((variants[key] - ref).mean(-1) / ref.mean(-1), cmap="RdBu_r", vmin=-0.1, vmax=0.1)
        a.set_title(title, fontsize=9)
        fig.colorbar(im, ax=a, fraction=0.046)
    im = ax[1, 1].imshow(noise.mean(-1), cmap="magma", vmin=0, vmax=0.1)
    ax[1, 1].set_title("Mitsuba's own standard error / value", fontsize=9)
    fig.colorbar(im, ax=ax[1, 1], fraction=0.046)
    edges = np.linspace(0, 1.0, 21)
    mid = 0.5 * (edges[1:] + edges[:-1])
    for key in ("default_bubble", "all_terms"):
        prof = [variants[key][(rho >= a) & (rho < b)].sum() / ref[(rho >= a) & (rho < b)].sum()
                for a, b in zip(edges[:-1], edges[1:])]
        ax[1, 2].plot(mid, prof, "o-", label=key)
    ax[1, 2].axhline(1, color="k", lw=0.5)
    ax[1, 2].set_xlabel("radius / disc radius"); ax[1, 2].set_ylabel("ring mean, bubblefit / Mitsuba")
    ax[1, 2].legend(fontsize=8)
    for a in ax.flat[:5]:
        a.set_xticks([]); a.set_yticks([])
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="experiments/mitsuba_centre.py", description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--spp", type=int, default=4096, help="Mitsuba's samples per pixel, full render (two seeds)")
    p.add_argument("--term-spp", type=int, default=1024, help="Mitsuba's samples per pixel of the truncated paths")
    p.add_argument("--bf-spp", type=int, default=16, help="bubblefit's rays per pixel (a square)")
    p.add_argument("--map", default="sunrise")
    p.add_argument("--clamp", type=float, default=20.0, help="clip the map's radiance at this value")
    p.add_argument("--mitsuba-python", default=str(ROOT / ".venv-render" / "bin" / "python"))
    p.add_argument("--out", default=str(HERE / "results"))
    a = p.parse_args(argv)
    from bubblefit.io.atomic import write_json
    from bubblefit.io.jaxcache import jax_setup

    jax_setup()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if not Path(a.mitsuba_python).exists():
        print(f"error: no Mitsuba python at {a.mitsuba_python}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        envmap = clamp_map(a.map, a.clamp, tmp)
        jobs = [{"max_depth": d, "spp": (a.spp if d == 64 else a.term_spp) // 2, "seed": s,
                 "out": str(tmp / f"m{d}_{s}.npy")} for d in (64, 2, 3, 4) for s in (0, 1)]
        cfg = {"size": a.size, "envmap": str(envmap), "n": N_FILM, "disc_fraction": DISC_FRACTION, "jobs": jobs}
        run = subprocess.run([a.mitsuba_python, "-c", MITSUBA, json.dumps(cfg)], capture_output=True, text=True)
        if run.returncode != 0:
            print(run.stderr[-2000:], file=sys.stderr)
            return 1
        version = run.stdout.strip().splitlines()[-1]
        mits = {d: (np.load(tmp / f"m{d}_0.npy"), np.load(tmp / f"m{d}_1.npy")) for d in (64, 2, 3, 4)}
        t_mitsuba = time.perf_counter() - t0
        variants = {k: render_bubblefit(envmap, a.size, a.bf_spp, b, e) for k, (b, e) in BF_VARIANTS.items()}
    rho = radius_map(a.size)
    results = {}
    for key, depth in PAIRS:
        results[f"{key}_vs_depth{depth}"] = compare(variants[key], *mits[depth], rho)
        r = results[f"{key}_vs_depth{depth}"]["half_disc"]
        print(f"{key:>20} vs max_depth {depth:2d}: half disc rel RMS {100 * r['all']['rel_rms']:.2f} % "
              f"(Mitsuba noise {100 * r['all']['mitsuba_noise_rms']:.2f} %, bias {100 * r['all']['bias_rms']:.2f} %), "
              f"without glints bias {100 * r['without_glints']['bias_rms']:.2f} %, ratio of means "
              f"{np.round(r['all']['ratio_of_means'], 4).tolist()}", flush=True)
    ref = 0.5 * (mits[64][0] + mits[64][1])
    noise = 0.5 * np.abs(mits[64][0] - mits[64][1]) / np.maximum(ref, 1e-12)
    centre = slab_centre(N_FILM)
    meta = {"mitsuba": version, "size": a.size, "mitsuba_spp": a.spp, "mitsuba_term_spp": a.term_spp,
            "bubblefit_spp": a.bf_spp, "map": a.map, "clamp": a.clamp, "n_film": N_FILM,
            "disc_radius_px": DISC_FRACTION * a.size, "seconds": round(time.perf_counter() - t0, 1),
            "mitsuba_seconds": round(t_mitsuba, 1), "variants": {k: {"bubble": b, "effects": e} for k, (b, e) in BF_VARIANTS.items()},
            "closed_form_centre": centre}
    write_json(out / "mitsuba_centre.json", {"meta": meta, "comparisons": results})
    figure(out / "mitsuba_centre.png", ref, variants, noise, rho, results)
    print(f"wrote {out / 'mitsuba_centre.json'} and .png in {meta['seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
