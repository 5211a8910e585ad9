"""The sun's glints of the Mitsuba thick-film photo (mts_thick_sunrise_ortho): where they
land and how much light they hold, in bubblefit's render and in Mitsuba's at 256 samples
per pixel (the photo's seed and scene; the photo itself takes 32768 samples, make_mitsuba.py)
and at more samples.

Mitsuba's path tracer picks reflection or transmission at each film with the slab's
probabilities (``thindielectric``), so a path that reaches the sun after internal
bounces is sampled with the probability of its branch choices and carries the sun's
whole radiance divided by the samples: at 256 samples one such sample adds about
``L_sun * exposure / 256`` (about 80 here in the photo's linear units, where 1 clips), and a
pixel whose expected value is a few times the clip level holds 0, 1 or 2 of them.
For each glint (connected pixels where bubblefit's render exceeds 3, grown by 3 pixels)
this prints the light above the local median (sum), its centroid and its peak for
bubblefit (pixel footprint; 16 rays per pixel) at the true disc and exposure, and for
Mitsuba at 256 samples (the photo's seed) and at SPP samples (another seed).

    PYTHONPATH=. .venv/bin/python experiments/validation/glint_samples.py OUT.json [SPP]
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys

import numpy as np
from scipy import ndimage as ndi

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import make_mitsuba as mm  # noqa: E402

from bubblefit.io.images import read_image  # noqa: E402
from bubblefit.model.render import render  # noqa: E402
from bubblefit.model.scene import Scene, read_envmap  # noqa: E402

CASE = "mts_thick_sunrise_ortho"
D = os.path.join(HERE, "data")


def mitsuba(spp, seed, truth):
    """make_mitsuba.make_mts's photo render (before its sensor noise), times the photo's exposure."""
    w, h = truth["camera"]["width"], truth["camera"]["height"]
    cxp, cyp, rp = truth["camera"]["disc"]
    cam = mm.ortho_sensor(w, h, ((w / 2 - cxp) / rp, -(h / 2 - cyp) / rp), w / (2 * rp), spp, seed=seed)
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 24}, "sensor": cam,
             "env": mm.envmap_emitter("sunrise"), "bubble": mm.bubble()}
    return mm.render(scene) * truth["exposure"]


def bubblefit(truth, **kw):
    """bubblefit's physical thick film (no interference, 8 bounces, mirror) at the true disc and exposure."""
    bg = read_image(os.path.join(D, CASE, "background.png")).pixels
    env_path = os.path.join(D, truth["envmap"])
    sc = Scene.from_dict({"camera": {"type": "orthographic", "width": truth["camera"]["width"], "height": truth["camera"]["height"],
                                     "disc": truth["camera"]["disc"]},
                          "bubble": {"roughness": 0.0, "r_d": 0.0, "r_s": 0.03, "n_film": 1.4, "thickness_nm": 500.0},
                          "lighting": {"envmap": env_path},
                          "effects": {"model": "physical", "interference": "off", "filtering": "mirror", "diffuse": False,
                                      "bounces": 8, "front_reflection": True, "rear_reflection": True, "transmission": True}})
    env = read_envmap(env_path)
    cfg, _ = sc.config(env, background=bg)
    cfg = dataclasses.replace(cfg, effects=dataclasses.replace(cfg.effects, background="photo"), **kw)
    p = dataclasses.replace(sc.params(), exposure=np.float32(truth["exposure"]))
    return np.asarray(render(p, cfg, env, bg), np.float64)


def main(out, spp=4096):
    """Render both, split bubblefit's render into glints and write each glint's sums and centroids to ``out``."""
    truth = json.load(open(os.path.join(D, CASE, "truth.json")))
    imgs = {"bubblefit_footprint": bubblefit(truth, pixel_footprint=True),
            "bubblefit_16rays": bubblefit(truth, pixel_footprint=False, samples_per_pixel=16),
            "mitsuba_256_photo": mitsuba(256, 3, truth), f"mitsuba_{spp}": mitsuba(spp, 11, truth)}
    photo = read_image(os.path.join(D, CASE, "photo.png")).pixels
    g = {k: v[..., 1] for k, v in imgs.items()}
    bf = g["bubblefit_footprint"]
    h, w = bf.shape
    cx, cy, r = truth["camera"]["disc"]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    inside = np.hypot(jj - cx, ii - cy) < 0.985 * r
    base = ndi.median_filter(bf, 9)
    lab, n = ndi.label(ndi.binary_dilation((bf > 3.0) & inside, np.ones((3, 3), bool)))
    rows = []
    for k in range(1, n + 1):
        reg = ndi.binary_dilation(lab == k, np.ones((3, 3), bool), iterations=2) & inside
        row = {"pixels": int(reg.sum()), "photo_clipped": int((photo[reg].max(-1) >= 1.0).sum())}
        for name, img in g.items():
            e = np.clip(img - base, 0, None) * reg
            s = float(e.sum())
            row[name] = {"sum": round(s, 1), "peak": round(float(img[reg].max()), 2),
                         "centroid_xy": [round(float((e * jj).sum() / s), 2), round(float((e * ii).sum() / s), 2)] if s > 0 else None}
        rows.append(row)
    rows.sort(key=lambda x: -x["bubblefit_footprint"]["sum"])
    sun = float(np.asarray(read_envmap(os.path.join(D, truth["envmap"])).pixels)[..., 1].max())
    quantum = sun * truth["exposure"] / 256  # one sample that reaches the sun's texel, green
    res = {"what": __doc__.split("\n\n")[0].replace("\n", " "), "case": CASE, "spp": spp, "sun_sample_at_256_spp": quantum, "glints": rows}
    json.dump(res, open(out, "w"), indent=1)
    for row in rows:
        print(json.dumps(row))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 4096)
