"""A photo taken by one camera, fitted with a response calibrated on another: the verdict.

The responses are calibrated as experiments/calibrated_camera.py does (colour-science's
sensitivities under illuminant E, 0.5 % noise, the random generator seeded 5 and drawn for
the chart first, then the film: ``--source chart,film`` there, so the Nikon's CSVs are the
ones of experiments/results/calibrated_camera*.json), for the Nikon D5100 and the Sigma SD
Merrill. 48 px photos of constant films (tests/helpers.py's film_photo, seed ``31 + k`` for
the ``k``-th of 300, 600, 1000, 1300, 1500 nm as there) are rendered by one camera and
fitted with a CSV of either. Printed per case: truth, thickness, standard error, ``ok``,
the reasons (the colour check's statistic and the order test's difference).

``--arrays DIR`` saves each fit's photo, render, fitted mask, cosine, noise sigma and the
inputs of the response's Jacobian. ``--redraw N`` then fits nothing: for each case it draws
the photo's noise ``N`` times again (tests/helpers.py's film_noise on the noise-free render)
and tests each draw against the render the fit kept (not refitted: a refit absorbs a little
of each draw), with the fit's colour check (its cells split by the optical path and the
path's bins pooled over the film, ``pooled``) and with the grid's cells alone (``path``
None): how often each flags the case; ``--refit lowest:K`` (or ``first:K``) then fits the
draws the check passes first (or the first ``K``) again, to ``--refit-json``.

Usage: ``PYTHONPATH=. python experiments/camera_mismatch.py --cases "Sigma:Nikon:film:1500,Nikon:Nikon:film:1500"
[--json OUT] [--arrays DIR] [--redraw N]``; a case is ``photo camera:calibrated camera:source:thickness``.
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
sys.path.insert(0, os.path.dirname(__file__))
from helpers import FILM_PHOTO_DISC as DISC, film_photo  # noqa: E402
from calibrated_camera import airy, courtyard, sensitivities  # noqa: E402  (the same calibration)

CAMERAS = {"Nikon": "Nikon 5100 (NPL)", "Sigma": "Sigma SDMerill (NPL)",
           "sRGB": "srgb"}  # sRGB: the CIE 1931 observer through the sRGB matrix, photos only
SEEDS = {300.0: 31, 600.0: 32, 1000.0: 33, 1300.0: 34, 1500.0: 35}


def calibrate(camera: str, folder: str) -> dict:
    """``{source: csv path}``: calibrated_camera.py's chart and film calibrations of ``camera``."""
    from bubblefit.capture.camera_calibration import chart_reflectances, fit_response

    rng = np.random.default_rng(5)
    sens = sensitivities(CAMERAS[camera])
    _, refl = chart_reflectances()
    out = {}
    for source, spectra in (("chart", refl), ("film", airy(np.linspace(0.0, 2000.0, 81)))):
        y = spectra @ sens
        y = y * (1 + 0.005 * rng.normal(size=y.shape))
        path = os.path.join(folder, f"{camera}_{source}.csv")
        if not os.path.exists(path):
            with open(path, "w") as fh:
                fh.write(fit_response([(source, spectra, y)]).csv_text())
        out[source] = path
    return out


def redraw(case: str, folder: str, draws: int, env) -> dict:
    """The colour check on ``draws`` new noise draws of ``case``'s photo against its saved fit."""
    from helpers import film_noise
    from bubblefit.inverse.colour_check import INNER_COS, colour_check
    from bubblefit.inverse.response_error import response_cells
    from bubblefit.optics.film import optical_path

    photo_cam, _, _, t = case.split(":")
    z = np.load(os.path.join(folder, case.replace(":", "_") + ".npz"))
    cos, n, d = z["cos"], float(z["n_film"]), float(z["thickness"])
    use = z["mask"].astype(bool) & (cos > INNER_COS)
    jac = response_cells(str(z["csv"]), "E", n, z["render"], z["background"], d, cos)
    memo = {}

    def cached(ys, xs):  # the cells repeat between draws
        key = (ys.tobytes(), xs.tobytes())
        if key not in memo:
            memo[key] = jac(ys, xs)
        return memo[key]

    path = np.asarray(optical_path(d, n, np.clip(cos, 0.0, 1.0)))
    clean, _ = film_photo(env, float(t), SEEDS[float(t)], CAMERAS[photo_cam], "E", noise=False)
    rng = np.random.default_rng(2000)
    out = {"case": case, "thickness": d, "cells": {}, "grid": [], "path": []}
    for _ in range(draws):
        photo = film_noise(clean, rng)
        for name, kw in (("grid", {}), ("path", {"path": path, "pooled": True})):
            c = colour_check(photo, z["render"], use, z["sigma"], response_jac=None if jac is None else cached, **kw)
            out[name].append(c.chi2_per_dof / c.threshold_per_dof)
            out["cells"][name] = c.cells
    for name in ("grid", "path"):
        v = np.array(out[name])
        out[name + "_flagged"] = int(np.sum(v > 1.0))
        print(f"{case:28s} {name:5s} ({out['cells'][name]} cells): statistic / threshold median {np.median(v):.3f}, "
              f"range {v.min():.3f}-{v.max():.3f}, flagged {int(np.sum(v > 1.0))} of {draws}", flush=True)
    return out


def refit(case: str, csv: str, which: str, record: dict, env) -> list:
    """Fit again (as :func:`main` does) the noise draws of ``case`` that :func:`redraw`
    drew (the same generator, seeded 2000): ``which`` ``lowest:K``, the ``K`` with the
    lowest fit's-check statistic in ``record`` (those the check passes first), or
    ``first:K``, the first ``K``. A refit absorbs a little of each draw: the fit's own
    verdict and thickness on the photos the redraws only tested."""
    from helpers import film_noise
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.fit import FitOptions, fit_photo

    photo_cam, _, _, t = case.split(":")
    t = float(t)
    how, k = which.split(":")
    idx = list(range(int(k))) if how == "first" else [int(i) for i in np.argsort(record["path"])[:int(k)]]
    clean, _ = film_photo(env, t, SEEDS[t], CAMERAS[photo_cam], "E", noise=False)
    _, bg = film_photo(env, t, SEEDS[t], CAMERAS[photo_cam], "E")
    rng = np.random.default_rng(2000)
    draws = [film_noise(clean, rng) for _ in range(max(idx) + 1)]
    rows = []
    for i in idx:
        r = fit_photo(draws[i], env, background=bg, options=FitOptions(
            disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=csv,
            illuminant="E", view=ORTHOGRAPHIC))
        col, order = r.colour_check or {}, r.order_check or {}
        rows.append(dict(case=case, draw=i, redraw_statistic=record["path"][i], truth=t,
                         thickness=r.params["thickness_nm"], stderr=r.stderr.get("thickness_nm"),
                         stderr_camera=(r.stderr_camera or {}).get("thickness_nm"), ok=r.ok, colour=col, order=order))
        print(f"{case:28s} draw {i:3d} -> {rows[-1]['thickness']:7.1f} nm (SE {rows[-1]['stderr']:.2f}) ok={r.ok!s:5} "
              f"colour {col.get('chi2_per_dof', float('nan')):.2f}/{col.get('threshold_per_dof', float('nan')):.2f} "
              f"({col.get('partition')}) order {order.get('delta_chi2', float('nan')):.1f}", flush=True)
    return rows


def main():
    import bubblefit.inverse.fit as fitmod
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.fit import FitOptions, fit_photo

    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="Sigma:Nikon:film:1500,Nikon:Nikon:film:1500,Nikon:Sigma:film:1500")
    ap.add_argument("--json")
    ap.add_argument("--arrays", help="save each fit's colour-check inputs to DIR/<case>.npz")
    ap.add_argument("--csv-dir", help="keep the calibrated CSVs here")
    ap.add_argument("--redraw", type=int, default=0, help="noise draws per case against the saved fits (--arrays)")
    ap.add_argument("--refit", help="with --redraw: fit again its draws 'lowest:K' (the K the check passes first) "
                    "or 'first:K'; written to --refit-json")
    ap.add_argument("--refit-json")
    a = ap.parse_args()
    env = courtyard()
    folder = a.csv_dir or tempfile.mkdtemp()
    os.makedirs(folder, exist_ok=True)
    if a.arrays:
        os.makedirs(a.arrays, exist_ok=True)
    if a.redraw:
        records = [redraw(case, a.arrays, a.redraw, env) for case in a.cases.split(",")]
        save(records, a.json)
        if a.refit:
            save([row for rec in records for row in refit(rec["case"], calibrate(rec["case"].split(":")[1], folder)[
                rec["case"].split(":")[2]], a.refit, rec, env)], a.refit_json)
        return None
    seen = {}
    judge = fitmod.judge_colours

    def spy(ok, warnings, photo, render, mask, cos, sigma, *args, **kw):
        seen.update(photo=np.asarray(photo), render=np.asarray(render), mask=np.asarray(mask), cos=np.asarray(cos),
                    sigma=np.asarray(sigma) * np.ones_like(np.asarray(photo)))
        return judge(ok, warnings, photo, render, mask, cos, sigma, *args, **kw)

    fitmod.judge_colours = spy
    rows = []
    for case in a.cases.split(","):
        photo_cam, csv_cam, source, t = case.split(":")
        t = float(t)
        csv = calibrate(csv_cam, folder)[source]
        photo, bg = film_photo(env, t, SEEDS[t], CAMERAS[photo_cam], "E")
        seen.clear()
        t0 = time.perf_counter()
        r = fit_photo(photo, env, background=bg, options=FitOptions(
            disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=csv,
            illuminant="E", view=ORTHOGRAPHIC))
        row = dict(case=case, photo_camera=CAMERAS[photo_cam], calibrated_camera=CAMERAS[csv_cam], source=source,
                   truth=t, thickness=r.params["thickness_nm"], stderr=r.stderr.get("thickness_nm"),
                   stderr_camera=(r.stderr_camera or {}).get("thickness_nm"), ok=r.ok, reduced_chi2=r.reduced_chi2,
                   colour=r.colour_check, order=r.order_check, warnings=r.warnings,
                   time_s=time.perf_counter() - t0)
        rows.append(row)
        if a.arrays:
            np.savez_compressed(os.path.join(a.arrays, case.replace(":", "_") + ".npz"), csv=csv,
                                background=bg, n_film=r.params["n_film"], thickness=r.params["thickness_nm"], **seen)
        se = row["stderr"] or float("nan")
        col, order = r.colour_check or {}, r.order_check or {}
        print(f"{case:28s} -> {row['thickness']:7.1f} nm ({row['thickness'] - t:+6.1f}, SE {se:.1f}, "
              f"{(row['thickness'] - t) / se:+.1f} SE) ok={r.ok!s:5} colour {col.get('chi2_per_dof', float('nan')):.2f}"
              f"/{col.get('threshold_per_dof', float('nan')):.2f} (cells {col.get('cells')}) order "
              f"{order.get('delta_chi2', float('nan')):.1f} ({row['time_s']:.0f} s)", flush=True)
    save(rows, a.json)


def save(rows: list, path: str | None):
    """Write ``rows`` as JSON to ``path`` (nothing when None)."""
    if path:
        with open(path, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
