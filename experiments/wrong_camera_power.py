"""How far from the model is a photo taken by one camera and fitted with another's calibrated response?

The Nikon D5100's response is calibrated from a draining film's colours (as
experiments/calibrated_camera.py does: 81 thicknesses 0-2000 nm, Airy reflectance, 0.5 %
noise, ``fit_response``); 48 px photos of constant films are rendered with the Nikon's or
the Sigma SD Merrill's sensitivities (tests/helpers.py's film_photo) and fitted with that
Nikon CSV. For each photo the fit runs twice: on the photo with its noise and on the same
render without noise. Printed per fit:

``lambda``: the noise-free photo's chi^2 at its fit (the fit's own noise model, the
parameters re-solved) plain and with the response's stated errors marginalised
(:func:`bubblefit.inverse.response_error.marginal_chi2`). This is the non-centrality of
the wrong camera's deviation from everything the model and the stated response can
produce: the most powerful test of the model against this one alternative (Neyman-Pearson,
the alternative known) rejects at level ``alpha`` with power ``Phi(sqrt(lambda) - z_alpha)``
(``z_1e-3`` = 3.09), and a test that does not know the alternative has less. A lambda far
below 9.5 means no statistic derived from the noise and the stated errors can reject the
photo at the fit's false-alarm rate.

Where that deviation lies: the plain chi^2 split into its chromatic part (orthogonal to
each pixel's rendered colour, in the whitened space) and the rest, on the inner disc that
the colour check tests (``cos > INNER_COS``) and on the rim. The statistics on the noisy
photo: the fit's colour check (6 x 6 cells, the model-error
floors, the response's errors marginalised), the same with the floors off and with 2 x 2
and 8 x 8 cells (what coherence the binning gains or loses), the marginal chi^2 per
degree of freedom of the whole fit, and the neighbour-difference noise ratio
(:func:`~bubblefit.inverse.colour_check.neighbour_scale`, unclamped: how pessimistic the
noise model is for these photos). No threshold is chosen here.

Usage: ``PYTHONPATH=. python experiments/wrong_camera_power.py [--thickness 300,800,1500]
[--cameras "Nikon 5100 (NPL)|Sigma SDMerill (NPL)"] [--draws N] [--json OUT]``
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
from helpers import FILM_PHOTO_DISC as DISC, film_noise, film_photo  # noqa: E402
from calibrated_camera import CAMERA, airy, sensitivities  # noqa: E402  (the same calibration)


def main():
    import bubblefit.inverse.fit as fitmod
    from bubblefit.capture.camera_calibration import fit_response
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.colour_check import INNER_COS, colour_check, neighbour_scale
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse.response_error import response_error, solve_marginal_chi2
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    ap = argparse.ArgumentParser()
    ap.add_argument("--thickness", default="300,800,1500")
    ap.add_argument("--cameras", default=f"{CAMERA}|Sigma SDMerill (NPL)")
    ap.add_argument("--draws", type=int, default=1, help="noise draws per photo (the first also fitted noise-free)")
    ap.add_argument("--json")
    a = ap.parse_args()
    rng = np.random.default_rng(5)  # calibrated_camera.py's seed: the same film CSV
    d = np.linspace(0.0, 2000.0, 81)
    spectra = airy(d)
    y = spectra @ sensitivities(CAMERA)
    y = y * (1 + 0.005 * rng.normal(size=y.shape))
    path = os.path.join(tempfile.mkdtemp(), "film.csv")
    with open(path, "w") as fh:
        fh.write(fit_response([("film", spectra, y)]).csv_text())
    px = read_image("bubblefit/data/courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    env = EnvMap.from_array(px)

    seen = {}
    gram, judge = fitmod.solve_response_gram, fitmod.judge_colours

    def spy_gram(response, illuminant, n_film, lev, sol, robust_scale, *model):
        err = response_error(response, illuminant, n_film)
        seen["marginal"] = solve_marginal_chi2(err, lev, sol, robust_scale, *model)
        seen["plain"] = solve_marginal_chi2(None, lev, sol, robust_scale, *model)
        seen["pixels"] = int(np.count_nonzero(lev.w))
        return gram(response, illuminant, n_film, lev, sol, robust_scale, *model)

    def spy_judge(ok, warnings, photo, render, mask, cos, sigma, model_error=0.0, explained=True, decide=True,
                  response_jac=None):
        use = np.asarray(mask, bool) & (np.asarray(cos) > INNER_COS)
        seen["colour"] = {}
        for name, kw in (("default", {}), ("no_floor", dict(floor=0.0, chroma_floor=0.0)),
                         ("grid2", dict(grid=2)), ("grid8", dict(grid=8)),
                         ("no_response_errors", dict(response_jac=None))):
            args = dict(model_error=model_error, response_jac=response_jac)
            args.update(kw)
            c = colour_check(photo, render, use, sigma, **args)
            seen["colour"][name] = None if c is None else [c.chi2_per_dof, c.threshold_per_dof]
        var = np.asarray(sigma, np.float64) ** 2 * np.ones_like(photo)
        # where the deviation lies: each fitted pixel's whitened squared residual, split
        # into its chromatic part (orthogonal to the rendered colour) and the rest, on the
        # tested inner disc and the rim
        e = (np.asarray(photo, np.float64) - np.asarray(render, np.float64)) / np.sqrt(var)
        u = np.asarray(render, np.float64) / np.sqrt(var)
        u = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
        along = np.sum(e * u, axis=-1) ** 2
        tot = np.sum(e * e, axis=-1)
        m = np.asarray(mask, bool) & np.all(np.isfinite(e), axis=-1)
        inner = m & (np.asarray(cos) > INNER_COS)
        rim = m & ~inner
        seen["split"] = {"inner_chroma": float(np.sum((tot - along)[inner])), "inner_brightness": float(np.sum(along[inner])),
                         "rim_chroma": float(np.sum((tot - along)[rim])), "rim_brightness": float(np.sum(along[rim]))}
        seen["neighbour_scale"] = neighbour_scale(np.asarray(photo, np.float64), np.asarray(render, np.float64),
                                                  var, use)
        return judge(ok, warnings, photo, render, mask, cos, sigma, model_error, explained, decide, response_jac)

    fitmod.solve_response_gram, fitmod.judge_colours = spy_gram, spy_judge
    rows = []
    for camera in a.cameras.split("|"):
        for k, t in enumerate(float(x) for x in a.thickness.split(",")):
            clean, bg = film_photo(env, t, 31 + k, camera, "E", noise=False)
            fits = []
            for j in range(a.draws):
                rng_n = np.random.default_rng(1000 + k + 100 * j)
                fits.append((f"noisy {j}" if j else "noisy", film_noise(clean, rng_n), film_noise(bg, rng_n)))
            fits.insert(1, ("noise-free", clean, bg))
            for label, photo, back in fits:
                seen.clear()
                t0 = time.perf_counter()
                r = fit_photo(photo, env, background=back, options=FitOptions(
                    disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=path,
                    illuminant="E", view=ORTHOGRAPHIC))
                pix = seen.get("pixels", 1)
                row = dict(photo_camera=camera, truth=t, photo=label, thickness=r.params["thickness_nm"], ok=r.ok,
                           chi2_plain=seen["plain"][0], chi2_marginal=seen["marginal"][1], pixels=pix,
                           reduced_chi2=r.reduced_chi2, colour=seen.get("colour"),
                           neighbour_scale=seen.get("neighbour_scale"), split=seen.get("split"), order=r.order_check,
                           time_s=time.perf_counter() - t0)
                rows.append(row)
                col = row["colour"] or {}
                print(f"{camera[:5]} {t:6.0f} {label:10s} -> {row['thickness']:7.1f} nm ok={r.ok!s:5} "
                      f"chi2 plain {row['chi2_plain']:8.1f} marginal {row['chi2_marginal']:8.1f} over {pix} values; "
                      f"colour " + " ".join(f"{n}={v[0]:.3f}/{v[1]:.3f}" for n, v in col.items() if v) +
                      f"; neighbour scale {row['neighbour_scale']:.3f}; chi2 split " +
                      " ".join(f"{n}={v:.1f}" for n, v in (row["split"] or {}).items()) +
                      f" ({row['time_s']:.0f} s)", flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
