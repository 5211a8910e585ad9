"""A camera the fit is not told, calibrated inside the fit (``fit --calibrate-camera``).

Renders 48 px photos of a draining film (200 nm at the top to 1500 nm at the bottom,
linear profile) seen by a measured camera under a lamp (colour-science's ``Nikon 5100
(NPL)`` and ``Sigma SDMerill (NPL)`` sensitivities, illuminant E, D65 or A), adds read and
shot noise and 8-bit sRGB or 16-bit linear quantisation (tests/helpers.py's film_photo),
and fits each with the default sRGB/D65 response and ``calibrate_camera=True``. Prints,
per photo, the stated response's fit (its thickness profile and ``ok``) and the
self-calibrated one: the largest thickness error over the film's heights (against the
rendered profile), the standard errors of top and bottom, the rank test and ``ok``.

Usage: ``PYTHONPATH=. python experiments/self_calibration.py [--cases "Nikon 5100 (NPL)/E/8,..."] [--json OUT]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import FILM_PHOTO_DISC as DISC, film_photo  # noqa: E402  (the camera tests' one builder)

PROFILE = (200.0, 1500.0, 1.0)
CASES = "Nikon 5100 (NPL)/E/8,Sigma SDMerill (NPL)/E/8,Nikon 5100 (NPL)/D65/16,Nikon 5100 (NPL)/E/8/600"


def profile_error(params: dict, truth=PROFILE) -> float:
    """Largest |fitted - true| thickness (nm) of the drainage profile over heights -1..1."""
    y = np.linspace(-1.0, 1.0, 201)
    x = (1.0 - y) / 2.0

    def prof(top, bottom, e):
        return top + (bottom - top) * x**e

    return float(np.max(np.abs(prof(params["top_nm"], params["bottom_nm"], params["exponent"]) - prof(*truth))))


def main():
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, NoiseSettings, fit_photo
    from bubblefit.inverse import starts
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=CASES, help="camera/illuminant/bits[/constant film nm], comma-separated "
                                                   "(without a thickness, the draining film PROFILE)")
    ap.add_argument("--json")
    a = ap.parse_args()
    px = read_image("bubblefit/data/courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    env = EnvMap.from_array(px)
    rows = []
    for k, case in enumerate(a.cases.split(",")):
        cam, ill, bits, *const = case.split("/")
        truth = float(const[0]) if const else PROFILE
        photo, bg = film_photo(env, truth, 41 + k, cam, ill, quantised=int(bits))
        t0 = time.perf_counter()
        opts = FitOptions(disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", view=ORTHOGRAPHIC,
                          thickness="constant" if const else "drainage", calibrate_camera=True,
                          noise=NoiseSettings(bits=8 if bits == "8" else None))
        r = fit_photo(photo, env, options=opts, background=bg)
        cal = r.camera_calibration
        first = cal["stated_response_fit"]
        keys = ("thickness_nm",) if const else ("top_nm", "bottom_nm", "exponent")

        def error(p):
            return abs(p["thickness_nm"] - truth) if const else profile_error(p)

        row = dict(camera=cam, illuminant=ill, bits=int(bits), truth=truth,
                   stated=dict(params={k: first["params"][k] for k in keys}, ok=first["ok"],
                               max_error_nm=error(first["params"]), colour_check=first["colour_check"]),
                   calibrated=dict(params={k: r.params[k] for k in keys}, stderr={k: r.stderr[k] for k in keys},
                                   ok=r.ok, max_error_nm=error(r.params), reduced_chi2=r.reduced_chi2,
                                   colour_check=r.colour_check, rank=cal["rank"], warnings=r.warnings),
                   time_s=time.perf_counter() - t0)
        rows.append(row)
        c, s = row["calibrated"], row["stated"]
        fitted = " ".join(f"{k} {c['params'][k]:.1f}+-{c['stderr'][k]:.1f}" for k in keys)
        print(f"{cam} / {ill} / {bits}-bit / {truth}: stated sRGB ok={s['ok']} max err {s['max_error_nm']:.0f} nm; "
              f"calibrated {fitted} max err {c['max_error_nm']:.1f} nm ok={c['ok']} chi2={c['reduced_chi2']:.2f} "
              f"rank {c['rank']['rank']}/{c['rank']['parameters']} response share {c['rank']['response_floor']:.3g} "
              f"(floor {c['rank']['floor']:.3g}) ({row['time_s']:.0f} s)", flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
