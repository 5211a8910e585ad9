"""How many of Cycles' samples of one dish-bubble pixel follow one specular path to the sun,
and what Russian roulette does to them.

For a ``cyc_cap_*`` case, a pixel and a path name of ``cap_glint_paths.py`` (``R``/``T`` at
the film, ``L`` at the liquid), each of the pixel's SS x SS rays (the same camera and
scene as ``cap_glint_paths.py``: numpy and ``reference_renderer.py`` only) is followed
along that path and its events are weighed as Cycles 5.0 samples them:

* the film (Principled BSDF, IOR 1, Transmission 1, roughness 0: the GGX glass closure with
  the thin film, ``closure/bsdf_microfacet.h`` ``bsdf_microfacet_sample``): the RGB film
  reflectance ``F`` (``saturate`` of the s/p mean of the Airy sum integrated under E to
  linear Rec.709, ``cycles_rim.film_series``) at the thickness of the case's profile at
  the hit; reflection is CHOSEN with probability ``p = mean(F)`` and weighted ``F / p``,
  transmission with ``1 - p`` and weighted ``(1 - F) / (1 - p)``: the path's throughput
  stays near 1 and its rarity is in the choices;
* the liquid (Principled BSDF, IOR 1.333, black base, opaque: a reflective GGX closure with
  the real Fresnel, no transmission lobe): reflection with probability 1, weight the
  unpolarised Fresnel reflectance ``F_L`` (the throughput falls to ``F_L``);
* Russian roulette (``integrator/path_state.h`` ``path_state_continuation_probability``):
  after the first bounce (``min_light_bounces`` 0, Blender's default, which
  ``make_cycles.reset`` keeps) a path continues with probability
  ``min(sqrt(max(throughput)), 1)``.

Printed: per event the mean incidence cosine, film thickness and ``F``; the share ``q`` of
one Cycles sample of the pixel that reaches the sun along the path (the ray's geometry
times the product of choice and roulette probabilities, averaged over the pixel's rays),
the expected number of the 256 samples that do, the chance that none does,
``(1 - q)^256``, and the expected linear pixel value the path adds (the sun's radiance
times the weights, over the pixel), against the photo's pixel and its 5 x 5 median.

    PYTHONPATH=. .venv/bin/python experiments/validation/cap_path_weights.py CASE ROW COL PATH [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import cap_glint_paths as cg  # noqa: E402
import cycles_rim as cr  # noqa: E402
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402

SPP = 256
SS = 16


def film_rgb(spec, n, d_nm, cos_i):
    """Cycles' RGB film reflectance, ``saturate`` of the s/p mean integrated to Rec.709."""
    r = cr.film_series(n, d_nm, np.abs(cos_i), spec.lam, 3)        # (M, K)
    return np.clip(r @ spec.weights.T, 0.0, 1.0)


def liquid_f(n, cos_i):
    """Unpolarised Fresnel reflectance of air to the liquid (``fresnel_dielectric``)."""
    rs, rp, _ = rr.fresnel_r01(n, np.abs(cos_i))
    return 0.5 * (rs * rs + rp * rp)


def weigh(case: str, row: int, col: int, path: str) -> dict:
    cdir = os.path.join(HERE, "data", case)
    t = json.load(open(os.path.join(cdir, "truth.json")))
    cam_t, cap = t["camera"], t["cap"]
    plane_y, n_film, n_liq = cap["plane_y"], cap["n_film"], cap["liquid_ior"]
    env = vio.read_image(os.path.join(HERE, "data", t["envmap"]))[..., :3]
    lum = env.sum(-1)
    sun = np.where((lum > 0.02 * lum.max())[..., None], env, 0.0)
    cam = rr.Camera("persp", cam_t["width"], cam_t["height"], origin=tuple(cam_t["origin"]),
                    target=tuple(cam_t["target"]), up=tuple(cam_t["up"]), fov_deg=cam_t["fov_deg"])
    off = (np.arange(SS) + 0.5) / SS
    px = (col + off[None, :] + 0 * off[:, None]).reshape(-1)
    py = (row + off[:, None] + 0 * off[None, :]).reshape(-1)
    o, d = cam.rays(px.copy(), py.copy(), np.zeros(3), 1.0)
    spec = rr.spectral_setup("E", 1.0)
    m = len(o)
    alive = np.ones(m, bool)
    prob = np.ones(m)             # probability that one Cycles sample makes these choices
    thr = np.ones((m, 3))         # Cycles' path throughput
    events = []
    for k, c in enumerate(path):
        tt, what = cg.next_hit(o, d, plane_y)
        want = 2 if c == "L" else 1
        alive &= what == want
        p = o + np.where(np.isfinite(tt), tt, 0.0)[:, None] * d
        nrm = p if want == 1 else np.tile([0.0, 1.0, 0.0], (m, 1))
        cos_i = np.sum(-d * nrm, -1)
        refl = d - 2.0 * np.sum(d * nrm, -1)[:, None] * nrm
        if want == 1:
            u = np.clip((1.0 - p[:, 1]) / (1.0 - plane_y), 0.0, 1.0)
            th = t["top_nm"] + (t["bottom_nm"] - t["top_nm"]) * u ** t["exponent"]
            f = np.stack([film_rgb(spec, n_film, th[i], cos_i[i:i + 1])[0] for i in range(m)])
            pr = f.mean(-1)
            choice, w = (pr, f / pr[:, None]) if c == "R" else (1 - pr, (1 - f) / (1 - pr)[:, None])
            d = refl if c == "R" else d
        else:
            th = np.full(m, np.nan)
            f = np.repeat(liquid_f(n_liq, cos_i)[:, None], 3, 1)
            choice, w = np.ones(m), f
            d = refl
        prob = prob * choice
        thr = thr * w
        # roulette after this event's bounce (the bounce counter is k + 1 > min_light_bounces = 0)
        rr_p = np.minimum(np.sqrt(thr.max(-1)), 1.0)
        prob = prob * rr_p
        thr = thr / rr_p[:, None]
        o = p
        a = alive
        events.append({"event": c, "rays": int(a.sum()),
                       "cos_incidence": float(np.abs(cos_i[a]).mean()) if a.any() else None,
                       "thickness_nm": float(np.nanmean(th[a])) if a.any() and want == 1 else None,
                       "reflectance_rgb": [float(v) for v in f[a].mean(0)] if a.any() else None,
                       "choice_probability": float(choice[a].mean()) if a.any() else None,
                       "roulette_continue": float(rr_p[a].mean()) if a.any() else None,
                       "throughput_rgb": [float(v) for v in thr[a].mean(0)] if a.any() else None})
    tt, what = cg.next_hit(o, d, plane_y)
    out = alive & (what == 0)
    s = np.zeros((m, 3))
    s[out] = cg.sun_lookup(sun, d[out], "texel-centre")
    at_sun = s.sum(-1) > 0
    q = float(np.mean(prob * at_sun))
    photo = vio.read_image(os.path.join(cdir, "photo.png"))[..., :3]
    photo = photo / 255.0 if photo.max() > 1.0 else photo
    g = photo[..., 1]
    win = g[max(0, row - 2):row + 3, max(0, col - 2):col + 3]
    value = t["exposure"] * np.mean(thr * s * prob[:, None], 0)     # expected linear pixel value
    rep = {"case": case, "pixel": [row, col], "path": path, "rays": m, "events": events,
           "rays_reaching_sun": float(np.mean(at_sun)), "q_per_sample": q, "spp": SPP,
           "expected_samples": SPP * q, "p_none": float((1 - q) ** SPP),
           "expected_linear_value_rgb": [float(v) for v in value],
           "photo_green_srgb": float(g[row, col]), "photo_local_median_srgb": float(np.median(win))}
    print(json.dumps(rep, indent=1))
    return rep


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("row", type=int)
    ap.add_argument("col", type=int)
    ap.add_argument("path")
    ap.add_argument("--json")
    a = ap.parse_args()
    r = weigh(a.case, a.row, a.col, a.path)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(r, fh, indent=1)
