"""Where a validation fit's misfit sits: each fitted pixel's chi^2 with the model-error floor
(as ``bubblefit.inverse._uncertainty.misfit`` forms it) split by what the pixel shows.

For one fit's JSON (written by validate.py with its ``_render.exr``) and the case's photo
this recomputes every pixel's chi^2 with the floor, ``sum_c (y - m)^2 / (sigma^2 +
(0.03 y)^2)`` with the fit's noise model (``noise_sigma``: read 2e-3, shot 2e-4, 8-bit
quantisation), over the pixels the fit used (inside 0.96 of the disc, no clipped channel
within a pixel; block means when the fit's last level is k times smaller than the photo), and splits the pixels whose chi^2 exceeds 30 (outliers) by cause:

- ``glint``: within 2 px (of the photo) of a pixel whose photo or model is brighter than 5 times the
  disc's median (the sun's or a lamp's reflection);
- ``rim``: beyond 0.85 of the radius (the films at grazing incidence);
- ``other``.

It also reports the clipped pixels the fit left out and the figure without the glint
pixels. Run from the repository root:

    PYTHONPATH=. .venv/bin/python experiments/validation/outlier_causes.py FIT.json CASE [...]
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np
from scipy import ndimage as ndi

from bubblefit.inverse import noise_sigma, saturation_mask
from bubblefit.io.images import read_image

HERE = os.path.dirname(os.path.abspath(__file__))
OUTLIER = 30.0


def causes(fit_json: str, case: str) -> dict:
    res = json.load(open(fit_json))
    truth = json.load(open(os.path.join(HERE, "data", case, "truth.json")))
    photo = read_image(os.path.join(HERE, "data", case, "photo.png")).pixels
    model = read_image(res["outputs"]["render"]).pixels
    disc = res.get("disc") or truth["disc"]
    h, w = photo.shape[:2]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rho = np.hypot(jj - disc["cx"], ii - disc["cy"]) / disc["r"]
    sat = saturation_mask(photo, 1.0, None)
    sigma = noise_sigma(photo, 2e-3, 2e-4, 8)
    # the fit scores its last level, k times smaller than the photo (block means)
    k = max(1, int(round(np.sqrt(np.sum((rho < 0.96) & ~sat) / max(res["pixels_used"], 1)))))
    if k > 1:
        hk, wk = h // k, w // k
        block = lambda a: a[:hk * k, :wk * k].reshape(hk, k, wk, k, *a.shape[2:]).mean(axis=(1, 3))
        photo, model = block(photo), block(model)
        sigma = np.sqrt(block(sigma**2) / (k * k))
        sat = block(sat.astype(float)) > 0
        rho = block(rho)
    used = (rho < 0.96) & ~sat
    floor = float(res.get("model_error_floor") or 0.03)
    chi = np.sum((photo - model) ** 2 / (sigma**2 + (floor * np.clip(photo, 0, None)) ** 2), axis=-1)
    bright_level = 5.0 * np.median(np.max(photo, axis=-1)[rho < 0.96])
    bright = (np.max(photo, axis=-1) > bright_level) | (np.max(model, axis=-1) > bright_level) | sat
    glint = ndi.binary_dilation(bright & (rho < 1.0), iterations=max(1, 2 // k))
    out = used & (chi > OUTLIER)
    dof = max(int(used.sum()) * 3, 1)
    keep = used & ~glint
    return {
        "fit": os.path.basename(fit_json), "level": k, "chi2_floor": float(chi[used].sum() / dof),
        "outliers_pct": 100.0 * float(out.sum()) / max(int(used.sum()), 1),
        "outliers_glint": int((out & glint).sum()), "outliers_rim": int((out & ~glint & (rho > 0.85)).sum()),
        "outliers_other": int((out & ~glint & (rho <= 0.85)).sum()),
        "share_of_chi2_in_glint_pct": 100.0 * float(chi[used & glint].sum() / max(chi[used].sum(), 1e-30)),
        "glint_pixels": int((used & glint).sum()), "clipped_pixels_left_out": int((sat & (rho < 0.96)).sum()),
        "chi2_floor_without_glint": float(chi[keep].sum() / max(int(keep.sum()) * 3, 1)),
        "roughness": res["params"].get("roughness"),
    }


if __name__ == "__main__":
    args = sys.argv[1:]
    for fit_json, case in zip(args[0::2], args[1::2]):
        print(json.dumps(causes(fit_json, case)))
