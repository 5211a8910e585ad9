"""Do a calibrated response's stated errors cover the colours it gets wrong?

The development cameras' measured sensitivities (colour-science's ``Nikon 5100 (NPL)`` and
``Sigma SDMerill (NPL)``) under illuminant E see the ColorChecker's 24 patches or a
draining film (81 thicknesses over 0-2000 nm), with 0.5 % noise per value (numpy, independent
of bubblefit). ``fit_response`` turns each draw into a response CSV; the colours of films of
40 thicknesses over 50-2000 nm (Airy reflectance at normal incidence, n = 1.33, white
balanced) predicted with it are compared with those the true sensitivities give, in units
of the standard deviation the CSV's stated errors propagate to
(:meth:`bubblefit.inverse.response_error.ResponseError.jacobian`). Honest errors give z of
unit RMS, about 95 % of |z| under 1.96 and a median |z| of 0.67.

Usage: ``PYTHONPATH=. python experiments/chart_calibration_error.py [--draws 8] [--json OUT]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from calibrated_camera import airy, sensitivities  # noqa: E402  (the same numpy film and cameras)

CAMERAS = ("Nikon 5100 (NPL)", "Sigma SDMerill (NPL)")


def main():
    from bubblefit.capture.camera_calibration import chart_reflectances, fit_response
    from bubblefit.inverse.response_error import response_error

    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--json")
    a = ap.parse_args()
    _, chart = chart_reflectances()
    sources = {"chart": chart, "film": airy(np.linspace(0.0, 2000.0, 81))}
    held = np.linspace(50.0, 2000.0, 40)
    refl = airy(held)
    tmp = tempfile.mkdtemp()
    out = []
    for source, spectra in sources.items():
        for cam in CAMERAS:
            sens = sensitivities(cam)
            truth = refl @ sens / sens.sum(axis=0)
            zs, errs = [], []
            for seed in range(a.draws):
                y = spectra @ sens * (1 + 0.005 * np.random.default_rng(seed).normal(size=(len(spectra), 3)))
                path = os.path.join(tmp, f"{source}-{cam[:5]}-{seed}.csv")  # one name per response: the readers cache
                with open(path, "w") as fh:
                    fh.write(fit_response([(source, spectra, y)]).csv_text())
                err = response_error(path, "E", 1.33)
                pred = refl @ err.density / err.density.sum(axis=0)
                sd = np.sqrt(np.sum(err.jacobian(pred, None, held, np.ones_like(held)) ** 2, axis=-1))
                zs.append((pred - truth) / sd)
                errs.append(np.abs(pred - truth) / truth.mean(axis=0))
            z, e = np.concatenate(zs), np.concatenate(errs)
            row = dict(source=source, camera=cam, rms_z=np.sqrt(np.mean(z**2, axis=0)).tolist(),
                       within_1_96=np.mean(np.abs(z) < 1.96, axis=0).tolist(),
                       median_abs_z=np.median(np.abs(z), axis=0).tolist(),
                       median_colour_error=np.median(e, axis=0).tolist())
            out.append(row)
            print(f"{source:5s} {cam:22s} rms z {np.round(row['rms_z'], 2)} within 1.96: "
                  f"{np.round(row['within_1_96'], 2)} median |z| {np.round(row['median_abs_z'], 2)} "
                  f"median colour error {np.round(row['median_colour_error'], 3)}", flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
