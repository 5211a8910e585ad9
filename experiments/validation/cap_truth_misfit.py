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
  image (no film at all: how the renderers agree on the map alone).

If more rays per pixel remove a misfit, the pixel's footprint (sampling) causes it; if
not, the light paths or the map's reading do. ``--texel-centres`` reads the map with its
rows at ``v = (i + 1/2) / h`` (Blender's equirectangular texel centres) instead of
bubblefit's ``v = i / (h - 1)`` (:func:`bubblefit.lighting.envmap.lookup_uv`, Mitsuba's
rows), in this script only. Run from the repository root:

    PYTHONPATH=. .venv/bin/python experiments/validation/cap_truth_misfit.py CASE [...] [--rays 4 16 64]
        [--texel-centres] [--json OUT]
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
from bubblefit.model.cap_render import _trace, render_cap
from bubblefit.model.cap_scene import load_cap_scene
from bubblefit.model.render import Params
from bubblefit.model.scene import read_envmap

HERE = os.path.dirname(os.path.abspath(__file__))
FLOOR, OUTLIER = 0.03, 30.0


def lookup_uv_texel_centres(pixels, u, v):
    """Bilinear lookup at (u, v) with texel ``(i, j)`` centred at ``((j + 1/2) / w, (i + 1/2) / h)``
    (Blender's equirectangular image texture); columns wrap, rows clamp."""
    h, w = pixels.shape[0], pixels.shape[1]
    x = u * w - 0.5
    y = jnp.clip(v * h - 0.5, 0.0, h - 1.0)
    x0 = jnp.floor(x)
    y0 = jnp.clip(jnp.floor(y), 0, max(h - 2, 0))
    fx, fy = (x - x0)[..., None], jnp.clip(y - y0, 0.0, 1.0)[..., None]
    x0i = x0.astype(jnp.int32) % w
    x1i, y0i = (x0i + 1) % w, y0.astype(jnp.int32)
    y1i = jnp.minimum(y0i + 1, h - 1)
    top = pixels[y0i, x0i] * (1 - fx) + pixels[y0i, x1i] * fx
    bot = pixels[y1i, x0i] * (1 - fx) + pixels[y1i, x1i] * fx
    return top * (1 - fy) + bot * fy


def classes(cfg, shape) -> dict:
    h, w = shape
    direct, mirrored = fitted_pixels(cfg)
    rr, cc = np.mgrid[0:h, 0:w]
    _, _, weight, _, on, rear = _trace(cfg, Params.make(), jnp.asarray(rr.ravel(), jnp.float32),
                                       jnp.asarray(cc.ravel(), jnp.float32))
    rear = np.asarray(rear).reshape(h, w)
    near = ndi.binary_dilation(np.asarray(on).reshape(h, w), iterations=2)
    liquid = (np.asarray(weight) < 1.0).reshape(h, w) & ~near
    return {"rear above": direct & rear, "foot": direct & ~rear, "mirrored": mirrored, "liquid beside": liquid}


def case_misfit(case: str, rays=(4, 16, 64)) -> dict:
    cdir = os.path.join(HERE, "data", case)
    truth = json.load(open(os.path.join(cdir, "truth.json")))
    scene = load_cap_scene(os.path.join(cdir, "scene.toml"))
    env = read_envmap(scene.envmap, scale=scene.env_scale)
    photo = read_image(os.path.join(cdir, "photo.png"), dtype=np.float64).pixels[..., :3]
    kind = truth["fits"][0]
    th = truth["thickness_nm"] if kind == "constant" else [truth["top_nm"], truth["bottom_nm"], truth["exponent"]]
    parts = classes(cap_config(scene, kind), photo.shape[:2])
    fit = parts["rear above"] | parts["foot"] | parts["mirrored"]
    sigma_img = noise_sigma(photo, 2e-3, 2e-4, 8)
    out = {"case": case, "rays": {}}
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
                                     "share_of_fit_chi2": float(chi[sel].sum() / total) if name != "liquid beside" else None}
        out["rays"][str(spp)] = row
        print(case, spp, json.dumps({k: v for k, v in row.items() if k != "by_class"}), flush=True)
        for name, v in row["by_class"].items():
            print("   ", name, v, flush=True)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--rays", type=int, nargs="+", default=[4, 16, 64])
    ap.add_argument("--texel-centres", action="store_true")
    ap.add_argument("--json")
    a = ap.parse_args()
    if a.texel_centres:
        import bubblefit.lighting.envmap as envmap

        envmap.lookup_uv = lookup_uv_texel_centres
    rows = [case_misfit(c, tuple(a.rays)) for c in a.cases]
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
