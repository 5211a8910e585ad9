"""A photo taken by one camera, fitted with another's response: is the fit caught?

Renders 48 px photos of a constant film under illuminant E seen by a measured camera
(colour-science's ``Nikon 5100 (NPL)`` or ``Sigma SDMerill (NPL)``), adds read and shot
noise and 8-bit sRGB quantisation (tests/helpers.py's film_photo), fits each with the right
response and with wrong ones (sRGB/D65, the other camera), and prints the thickness, the
fit's verdict and the colour check (bubblefit.inverse.colour_check).

Usage: ``PYTHONPATH=. python experiments/wrong_camera.py [--thickness 600,1300] [--json OUT]``
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


def main():
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    ap = argparse.ArgumentParser()
    ap.add_argument("--thickness", default="600,1300")
    ap.add_argument("--camera", default="Nikon 5100 (NPL)")
    ap.add_argument("--responses", default="Nikon 5100 (NPL)|srgb|Sigma SDMerill (NPL)")
    ap.add_argument("--json")
    ap.add_argument("--arrays", help="also save each fit's photo, render and disc to this .npz")
    a = ap.parse_args()
    px = read_image("bubblefit/data/courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    env = EnvMap.from_array(px)
    rows, arrays = [], {}
    for k, d in enumerate(float(x) for x in a.thickness.split(",")):
        photo, bg = film_photo(env, d, 11 + k, a.camera, "E")
        for resp in a.responses.split("|"):
            ill = "D65" if resp == "srgb" else "E"
            t0 = time.perf_counter()
            r = fit_photo(photo, env, options=FitOptions(disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", view=ORTHOGRAPHIC,
                                                         camera_response=resp, illuminant=ill), background=bg)
            j = r.to_json()
            row = dict(truth=d, response=resp, thickness=r.params["thickness_nm"], ok=r.ok,
                       chi2=r.reduced_chi2, colour=j.get("colour_check"), time_s=time.perf_counter() - t0,
                       warnings=r.warnings)
            rows.append(row)
            arrays[f"{d:.0f}_{resp}" + "_photo"] = photo
            arrays[f"{d:.0f}_{resp}" + "_render"] = r.render
            arrays[f"{d:.0f}_{resp}" + "_disc"] = np.asarray(r.disc)
            print(f"{d:7.0f} {resp:22s} -> {row['thickness']:8.1f} nm ok={r.ok!s:5} chi2={r.reduced_chi2:6.2f} "
                  f"colour={row['colour']} ({row['time_s']:.0f} s)", flush=True)
    if a.arrays:
        np.savez_compressed(a.arrays, **arrays)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
