"""Where a validation fit's photo-level misfit sits against the photo's clipped pixels, and
what censoring more of their neighbours would leave.

For a fit's JSON (with its ``_render.exr``) and its case, each pixel's chi^2 with the 3 %
floor, ``sum_c (y - m)^2 / (sigma^2 + (0.03 y)^2)`` with the fit's noise model
(``noise_sigma``: read 2e-3, shot 2e-4, 8-bit), over the pixels ``ok`` reads (inside 0.96
of the fit's disc, outside the clipped pixels grown by a cross, the fit's rule before
its 3 x 3 block), split by the Euclidean distance to the
nearest clipped pixel (any channel at 0.995, the fit's level): 1.41 (the diagonal
neighbours), 2, up to 3, 3-5, 5-10 and beyond. Then the reduced chi^2 and outliers of the same render with the clipped pixels grown by
the cross, by the 3 x 3 block (``saturation_mask`` now), and by discs of radius 2 and 3 px;
and the light each of the render's glints holds in the render and in the photo.

    PYTHONPATH=. .venv/bin/python experiments/validation/clip_censoring.py [--data DIR] FIT.json CASE [FIT.json CASE ...]

--data reads the cases from another folder of cases (as validate.py's --data) instead of data/.
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np
from scipy import ndimage as ndi

from bubblefit.inverse import noise_sigma, saturation_mask
from bubblefit.io.images import read_image

D = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
LEVEL = 0.995


def _load(fit_json: str, case: str):
    """``(fit, photo, render, (jj, ii) pixel centres, disc)`` of a fit's JSON and its case."""
    res = json.load(open(fit_json))
    truth = json.load(open(os.path.join(D, case, "truth.json")))
    photo = read_image(os.path.join(D, case, "photo.png")).pixels
    model = read_image(res["outputs"]["render"]).pixels[..., :3]
    h, w = photo.shape[:2]
    return res, photo, model, np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), res.get("disc") or truth["disc"]


def analyse(fit_json: str, case: str) -> dict:
    """The split of ``fit_json``'s photo-level chi^2 by distance to the clipped pixels."""
    res, photo, model, (jj, ii), disc = _load(fit_json, case)
    rho = np.hypot(jj - disc["cx"], ii - disc["cy"]) / disc["r"]
    clipped = np.max(photo, -1) >= LEVEL
    sigma = noise_sigma(photo, 2e-3, 2e-4, 8)
    chi = np.sum((photo - model) ** 2 / (sigma**2 + (0.03 * np.clip(photo, 0, None)) ** 2), axis=-1)
    dist = ndi.distance_transform_edt(~clipped)

    def score(censored):
        """Reduced chi^2 with the floor, pixels and outliers inside 0.96 r outside ``censored``."""
        u = (rho < 0.96) & ~censored
        return {"reduced_chi2_floor": round(float(chi[u].sum() / max(3 * u.sum() - 3, 1)), 2), "pixels": int(u.sum()),
                "outliers_pct": round(float(100 * (u & (chi > 30)).sum() / max(u.sum(), 1)), 2)}

    cross = ndi.binary_dilation(clipped) if clipped.any() else clipped
    used = (rho < 0.96) & ~cross  # the bands cover every pixel the cross leaves
    total = chi[used].sum()
    bands = {}
    for name, lo, hi in [("1.41", 1.0, 1.5), ("2", 1.5, 2.01), ("2.2-3", 2.01, 3.01), ("3-5", 3.01, 5.01), ("5-10", 5.01, 10.0),
                         ("over 10", 10.0, np.inf)]:
        m = used & (dist > lo) & (dist <= hi)
        bands[name] = {"pixels": int(m.sum()), "chi2_share_pct": round(float(100 * chi[m].sum() / total), 1),
                       "outliers": int((m & (chi > 30)).sum())}
    return {"fit": os.path.basename(fit_json), "case": case, "fit_reduced_chi2_floor": res.get("reduced_chi2_floor"),
            "fit_outlier_fraction": res.get("outlier_fraction"), "clipped": int(clipped.sum()),
            "saturation_mask_now": score(saturation_mask(photo, LEVEL, None)), "by_distance_to_clipped_px": bands,
            "cross": score(cross),
            "block_3x3": score(ndi.binary_dilation(clipped, np.ones((3, 3), bool)) if clipped.any() else clipped),
            "disc_r2": score(dist <= 2.01), "disc_r3": score(dist <= 3.01)}


def glints(fit_json: str, case: str) -> list[dict]:
    """The fitted render's glints (connected pixels over the clip level inside 0.96 r,
    grown by 3 px) with the light each holds above its 9 x 9 median, in the render and in
    the photo, and how many of the photo's pixels there are clipped."""
    res, photo, model, (jj, ii), disc = _load(fit_json, case)
    inside = np.hypot(jj - disc["cx"], ii - disc["cy"]) < 0.96 * disc["r"]
    m, p = model.max(-1), photo.max(-1)
    em, ep = np.clip(m - ndi.median_filter(m, 9), 0, None), np.clip(p - ndi.median_filter(p, 9), 0, None)
    lab, n = ndi.label(ndi.binary_dilation((m > 1.0) & inside, np.ones((3, 3), bool)))
    out = []
    for k in range(1, n + 1):
        reg = ndi.binary_dilation(lab == k, np.ones((3, 3), bool), iterations=2) & inside
        s = float(em[reg].sum())
        out.append({"centroid_xy": [round(float((em * jj)[reg].sum() / s), 1), round(float((em * ii)[reg].sum() / s), 1)],
                    "pixels": int(reg.sum()), "model_sum": round(s, 2), "model_peak": round(float(m[reg].max()), 2),
                    "photo_sum": round(float(ep[reg].sum()), 2), "photo_clipped": int((p[reg] >= LEVEL).sum())})
    return sorted(out, key=lambda g: -g["model_sum"])


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["--data"]:
        if len(args) < 2 or not os.path.isdir(args[1]):
            sys.exit(f"clip_censoring.py: --data needs a folder of cases, got {args[1:2]}")
        D, args = os.path.abspath(args[1]), args[2:]
    if not args or len(args) % 2:
        sys.exit("clip_censoring.py: give pairs FIT.json CASE")
    for fit_json, case in zip(args[0::2], args[1::2]):
        row = analyse(fit_json, case)
        row["glints"] = glints(fit_json, case)
        print(json.dumps(row))
