"""A camera the fit was not told: calibrated from a reference film or a chart, then fitted.

The colours of a draining film (0-2000 nm, Airy reflectance at normal incidence, n = 1.33)
and of the ColorChecker's 24 patches, seen by colour-science's ``Nikon 5100 (NPL)`` under
illuminant E with 0.5 % noise, are synthesised here with numpy (independent of bubblefit).
``bubblefit.capture.camera_calibration.fit_response`` turns each into a response CSV;
48 px photos of constant films rendered with the Nikon's sensitivities (noise, 8-bit sRGB
quantisation: tests/helpers.py's film_photo) are fitted with that CSV and illuminant E.
Prints the thickness error, its standard error and the camera response's share of it
(``stderr_camera``), the order test (``order_check``: the neighbouring order's chi^2 above
the best's with the response's errors marginalised, and without) and the verdict per photo.

``--photo-camera`` renders the photos with another camera than the one calibrated (a wrong
calibrated response, which the fit should not call ok); ``--keep DIR`` keeps the CSVs.

Usage: ``PYTHONPATH=. python experiments/calibrated_camera.py [--thickness 300,800,1500] [--source film,chart]
[--photo-camera "Sigma SDMerill (NPL)"] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from helpers import FILM_PHOTO_DISC as DISC, film_photo  # noqa: E402  (the camera tests' one builder)

LAM = np.arange(380.0, 781.0)
CAMERA = "Nikon 5100 (NPL)"


def sensitivities(name):
    import colour

    ms = colour.MSDS_CAMERA_SENSITIVITIES[name]
    return np.stack([np.interp(LAM, ms.wavelengths, ms.values[:, c], left=0, right=0) for c in range(3)], axis=1)


def airy(d, n=1.33):
    r = (1 - n) / (1 + n)
    f = 4 * r * r / (1 - r * r) ** 2
    s2 = np.sin(2 * np.pi * n * np.asarray(d, float)[:, None] / LAM) ** 2
    return f * s2 / (1 + f * s2)


def courtyard():
    """The courtyard map shipped with bubblefit, halved down to 64 rows: the photos' light."""
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    px = read_image("bubblefit/data/courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    return EnvMap.from_array(px)


def main():
    from bubblefit.capture.camera_calibration import chart_reflectances, fit_response
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts

    ap = argparse.ArgumentParser()
    ap.add_argument("--thickness", default="300,800,1500")
    ap.add_argument("--source", default="film,chart")
    ap.add_argument("--json")
    ap.add_argument("--arrays", help="also save each fit's photo, render and disc to this .npz")
    ap.add_argument("--photo-camera", default=CAMERA, help="the camera the photos are rendered with")
    ap.add_argument("--keep", help="write the calibrated CSVs to this folder")
    a = ap.parse_args()
    rng = np.random.default_rng(5)
    sens = sensitivities(CAMERA)
    d = np.linspace(0.0, 2000.0, 81)
    _, refl = chart_reflectances()
    data = {"film": airy(d), "chart": refl}
    env = courtyard()
    tmp = a.keep or tempfile.mkdtemp()
    os.makedirs(tmp, exist_ok=True)
    rows, arrays = [], {}
    for source in a.source.split(","):
        spectra = data[source]
        y = spectra @ sens
        y = y * (1 + 0.005 * rng.normal(size=y.shape))
        cal = fit_response([(source, spectra, y)])
        path = os.path.join(tmp, f"{source}.csv")
        with open(path, "w") as fh:
            fh.write(cal.csv_text())
        for k, t in enumerate(float(x) for x in a.thickness.split(",")):
            photo, bg = film_photo(env, t, 31 + k, a.photo_camera, "E")
            t0 = time.perf_counter()
            r = fit_photo(photo, env, background=bg, options=FitOptions(
                disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=path, illuminant="E",
                view=ORTHOGRAPHIC))
            row = dict(source=source, photo_camera=a.photo_camera, truth=t, thickness=r.params["thickness_nm"],
                       stderr=r.stderr.get("thickness_nm"), ok=r.ok,
                       stderr_camera=(r.stderr_camera or {}).get("thickness_nm"), chi2=r.reduced_chi2,
                       colour=r.colour_check, order=r.order_check, warnings=r.warnings,
                       time_s=time.perf_counter() - t0)
            rows.append(row)
            arrays[f"{source}_{t:.0f}" + "_photo"] = photo
            arrays[f"{source}_{t:.0f}" + "_render"] = r.render
            arrays[f"{source}_{t:.0f}" + "_disc"] = np.asarray(r.disc)
            se = row["stderr"] or float("nan")
            print(f"{source:6s} {t:6.0f} -> {row['thickness']:8.1f} nm (error {row['thickness'] - t:+6.1f}, "
                  f"SE {se:.1f} of which camera {row['stderr_camera'] or 0:.1f}, {(row['thickness'] - t) / se:+.1f} SE) "
                  f"ok={r.ok!s:5} "
                  f"chi2={r.reduced_chi2:5.2f} colour chi2/dof={(r.colour_check or {}).get('chi2_per_dof')} "
                  f"order: alternative {(r.order_check or {}).get('alternative_nm')} nm, delta chi2 "
                  f"{(r.order_check or {}).get('delta_chi2')} (plain {(r.order_check or {}).get('delta_chi2_plain')}) "
                  f"({row['time_s']:.0f} s)", flush=True)
    if a.arrays:
        np.savez_compressed(a.arrays, **arrays)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
