"""Where a dish bubble's photo and bubblefit's render at the true parameters disagree.

For a ``cyc_cap_*`` case this renders the cap (:func:`bubblefit.model.cap_render.render_cap`,
the fit's settings) at the truth's thickness with 2 x 2, 4 x 4 and 8 x 8 rays per pixel,
takes the least-squares exposure over the fit's pixels (clipped channels left out), and
reports the reduced chi^2 with the 3 % model-error floor (the fit's noise model,
:func:`bubblefit.inverse.cap_fit._misfit`), split by what each pixel shows:

- ``rear above``: the cap seen directly, its rear hit above the liquid;
- ``foot``: the cap seen directly, the ray meeting the liquid inside the cap's foot;
- ``mirrored``: the cap's mirror image in the liquid;
- ``liquid beside``: the liquid reflecting the map, at least 2 px from the cap and its
  image (no film at all: how the renderers agree on the map alone);
- ``beyond the liquid's edge``: rays that meet bubblefit's (unbounded) liquid outside the
  Blender scene's 120 x 120 water plane (``make_films_cycles.liquid_plane``, half-size
  :data:`LIQUID_HALF`): Blender shows the map's lower half there, not its reflection
  (a strip along the top of a photo taken at a low angle). Left out of ``liquid beside``.

If more rays per pixel remove a misfit, the pixel's footprint (sampling) causes it; if
not, the light paths or the map's reading do. The map is read in the convention the
scene file states (``[environment] convention``, :data:`bubblefit.lighting.envmap.CONVENTIONS`:
the Blender cases say ``texel-centre``, rows at ``v = (i + 1/2) / h``); ``--convention``
overrides it (``mitsuba``: rows at ``v = i / (h - 1)``, bubblefit's default).

``liquid_by_incidence`` (first ray count only) splits the liquid beside the bubble into
five equal-count bands of the camera ray's angle of incidence on the liquid and gives the
median and quartiles of photo / (true exposure x model) in each: a liquid whose Fresnel
reflectance differed from the renderer's would drift with the angle (air to water: 2 %
at normal incidence, 35 % at 80 degrees). Run from the repository root:

    PYTHONPATH=. .venv/bin/python experiments/validation/cap_truth_misfit.py CASE [...] [--rays 4 16 64]
        [--convention mitsuba|texel-centre] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os

import jax.numpy as jnp
import numpy as np
from scipy import ndimage as ndi

from bubblefit.inverse import noise_sigma
from bubblefit.inverse._censored import censored_residual
from bubblefit.inverse.cap_fit import _misfit, _params, cap_config, fitted_pixels
from bubblefit.io.images import read_image
from bubblefit.lighting.envmap import CONVENTIONS
from bubblefit.model.cap_render import _trace, render_cap
from bubblefit.model.cap_scene import load_cap_scene
from bubblefit.model.render import Params, _camera_rays
from bubblefit.model.scene import read_envmap

HERE = os.path.dirname(os.path.abspath(__file__))
FLOOR, OUTLIER = 0.03, 30.0
#: Half the side of the Blender dish scenes' water plane (make_films_cycles.liquid_plane).
LIQUID_HALF = 60.0


def classes(cfg, shape) -> dict:
    h, w = shape
    direct, mirrored = fitted_pixels(cfg)
    rr, cc = np.mgrid[0:h, 0:w]
    _, _, weight, _, on, rear = _trace(cfg, Params.make(), jnp.asarray(rr.ravel(), jnp.float32),
                                       jnp.asarray(cc.ravel(), jnp.float32))
    rear = np.asarray(rear).reshape(h, w)
    near = ndi.binary_dilation(np.asarray(on).reshape(h, w), iterations=2)
    o, d = _camera_rays(cfg.render, Params.make(), jnp.asarray(rr.ravel(), jnp.float32), jnp.asarray(cc.ravel(), jnp.float32))
    o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
    s = (cfg.plane_y - o[:, 1]) / np.where(d[:, 1] < 0, d[:, 1], -1.0)
    q = o + np.maximum(s, 0.0)[:, None] * d
    edge = (np.maximum(np.abs(q[:, 0]), np.abs(q[:, 2])) > LIQUID_HALF).reshape(h, w)
    liquid = (np.asarray(weight) < 1.0).reshape(h, w) & ~near
    return {"rear above": direct & rear, "foot": direct & ~rear, "mirrored": mirrored, "liquid beside": liquid & ~edge,
            "beyond the liquid's edge": liquid & edge}


def liquid_by_incidence(cfg, photo, img, exposure, liquid, bands=5) -> list:
    """Photo / (exposure x model) on the liquid beside the bubble (unclipped, model above 2 %
    of full scale) in ``bands`` equal-count bands of the angle of incidence on the liquid."""
    h, w = photo.shape[:2]
    rr, cc = np.mgrid[0:h, 0:w]
    _, d = _camera_rays(cfg.render, Params.make(), jnp.asarray(rr.ravel() + 0.5, jnp.float32),
                        jnp.asarray(cc.ravel() + 0.5, jnp.float32))
    angle = np.degrees(np.arccos(np.abs(np.asarray(d, np.float64)[:, 1]))).reshape(h, w)
    sel = liquid & (photo.max(-1) < 1.0) & (exposure * img.sum(-1) > 0.02)
    ratio, a = photo[sel].sum(-1) / (exposure * img[sel].sum(-1)), angle[sel]
    edges = np.quantile(a, np.linspace(0.0, 1.0, bands + 1))
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = (a >= lo) & (a <= hi)
        q25, q50, q75 = np.percentile(ratio[s], [25, 50, 75])
        out.append({"degrees": [round(float(lo), 1), round(float(hi), 1)], "pixels": int(s.sum()),
                    "median": float(q50), "quartiles": [float(q25), float(q75)]})
    return out


def case_misfit(case: str, rays=(4, 16, 64), convention: str = "scene") -> dict:
    cdir = os.path.join(HERE, "data", case)
    truth = json.load(open(os.path.join(cdir, "truth.json")))
    scene = load_cap_scene(os.path.join(cdir, "scene.toml"))
    convention = scene.env_convention if convention == "scene" else convention
    env = read_envmap(scene.envmap, scale=scene.env_scale, convention=convention)
    photo = read_image(os.path.join(cdir, "photo.png"), dtype=np.float64).pixels[..., :3]
    kind = truth["fits"][0]
    th = truth["thickness_nm"] if kind == "constant" else [truth["top_nm"], truth["bottom_nm"], truth["exponent"]]
    parts = classes(cap_config(scene, kind), photo.shape[:2])
    fit = parts["rear above"] | parts["foot"] | parts["mirrored"]
    sigma_img = noise_sigma(photo, 2e-3, 2e-4, 8)
    out = {"case": case, "envmap_convention": convention, "rays": {}}
    for spp in rays:
        img = np.asarray(render_cap(_params(scene, jnp.asarray(th, jnp.float32), 1.0),
                                    cap_config(scene, kind, samples_per_pixel=spp), env), np.float64)
        y, m, s = photo[fit], img[fit], sigma_img[fit]
        seen = y < 1.0
        g = float(np.sum(y * m * seen / s**2) / np.sum(m * m * seen / s**2))
        mf = _misfit(censored_residual(y, g * m, 1.0, np), s, y, FLOOR, 2)
        res = censored_residual(photo, g * img, 1.0, np)
        chi = np.sum(res**2 / (sigma_img**2 + (FLOOR * photo) ** 2), axis=-1)
        total = float(chi[fit].sum())
        row = {"exposure": g, "exposure_true": truth["exposure"], "chi2_floor": mf.chi2_floor,
               "chi2_rest": mf.chi2_inliers, "outliers": mf.outliers,
               "largest_pixel_share": float(chi[fit].max() / total), "by_class": {}}
        for name, sel in parts.items():
            n = int(sel.sum())
            row["by_class"][name] = {"pixels": n, "chi2_floor": float(chi[sel].sum() / (3 * max(n, 1))),
                                     "outliers": float((chi[sel] > OUTLIER).mean()) if n else None,
                                     "share_of_fit_chi2": float(chi[sel].sum() / total) if name in
                                     ("rear above", "foot", "mirrored") else None}
        out["rays"][str(spp)] = row
        if "liquid_by_incidence" not in out:
            out["liquid_by_incidence"] = liquid_by_incidence(cap_config(scene, kind), photo, img, truth["exposure"],
                                                             parts["liquid beside"])
            print("    liquid by incidence", out["liquid_by_incidence"], flush=True)
        print(case, spp, json.dumps({k: v for k, v in row.items() if k != "by_class"}), flush=True)
        for name, v in row["by_class"].items():
            print("   ", name, v, flush=True)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--rays", type=int, nargs="+", default=[4, 16, 64])
    ap.add_argument("--convention", choices=("scene", *CONVENTIONS), default="scene",
                    help="where the map's texel rows sit [the scene file's]")
    ap.add_argument("--json")
    a = ap.parse_args()
    rows = [case_misfit(c, tuple(a.rays), a.convention) for c in a.cases]
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
