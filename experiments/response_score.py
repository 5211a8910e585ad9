"""The colour check's score test along smooth changes of the camera response: its law on
right-camera photos and its power on another camera's.

For each case of experiments/camera_mismatch.py saved with ``--arrays DIR`` (the fit's
photo, render, mask, cosine, noise sigma, CSV), the photo's noise is drawn ``--draws``
times again (tests/helpers.py's film_noise on the noise-free render, the generator seeded
``--seed``) and each draw is tested against the render the fit kept (not refitted), as
``camera_mismatch.py --redraw`` does, by each member of the colour check's union
(bubblefit.inverse.colour_check._tests): the grid's cells split by the optical path
(``cells``), the path's bins over the film (``path``) and the score test along ``3 K``
smooth relative changes of the response, the thickness profiled out (``response``,
bubblefit.inverse.response_error.response_score_cells, ``K`` = ``--degree``), each at a
third of 1e-3. Also the noise-free photo's score statistic (its non-centrality: the
model's own error on a right camera's photo, the wrong response's reach on another's).

Recorded per case and member: the statistic's degrees of freedom, its mean over the draws,
its quantiles, how many draws exceed its share's threshold, and the union's verdict
(flagged of N) with and without the score test (the latter at half of 1e-3 per member, as
the check stands without it).

``--drainage [NAMES]`` instead fits experiments/colour_check_null.py's draining films (and
a pale thick one, :data:`PALE_DRAINAGE`) with the drainage profile, once each (kept in
``--arrays``), and redraws their noise the same way: the score test's nuisances are then
the profile's parameters.

``--val CASES`` instead fits validation development cases (other renderers, the right
camera) as experiments/colour_check_null.py's ``--cases val`` does, keeping what the fit
hands the colour check and the response's Jacobian, and tests each fit's own photo: the
model's error between renderers against the score test.

Usage: ``PYTHONPATH=. python experiments/response_score.py --arrays /tmp/mm --cases
"Sigma:Nikon:film:1500,Nikon:Nikon:film:1500" --draws 200 [--degree 4] [--json OUT]``;
``PYTHONPATH=. python experiments/response_score.py --arrays DIR --val ref_const300_courtyard_ortho``;
``PYTHONPATH=. python experiments/response_score.py --arrays DIR --drainage --draws 200``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
sys.path.insert(0, os.path.dirname(__file__))
from camera_mismatch import CAMERAS, SEEDS, save  # noqa: E402
from calibrated_camera import courtyard  # noqa: E402
from helpers import film_noise, film_photo, kept_per_pixels  # noqa: E402

FALSE_ALARM = 1e-3


def run(case: str, folder: str, draws: int, degree: int, seed: int, env) -> dict:
    """The members' statistics on ``draws`` noise draws of ``case`` and on its noise-free photo."""
    from scipy.special import chdtri

    from bubblefit.inverse.colour_check import GRID, INNER_COS, _tests
    from bubblefit.inverse.response_error import response_cells, response_score_cells
    from bubblefit.optics.film import optical_path

    photo_cam, _, _, t = case.split(":")
    z = np.load(os.path.join(folder, case.replace(":", "_") + ".npz"))
    cos, n, d = z["cos"], float(z["n_film"]), float(z["thickness"])
    use = z["mask"].astype(bool) & (cos > INNER_COS)
    csv = str(z["csv"])
    jac = response_cells(csv, "E", n, z["render"], z["background"], d, cos)
    jac = None if jac is None else kept_per_pixels(jac)
    score = kept_per_pixels(response_score_cells(csv, "E", n, z["render"], z["background"], d, cos, degree))
    path = np.asarray(optical_path(d, n, np.clip(cos, 0.0, 1.0)))
    clean, _ = film_photo(env, float(t), SEEDS[float(t)], CAMERAS[photo_cam], "E", noise=False)

    def members(photo, with_score=True):
        return _tests(photo, z["render"], use, z["sigma"], model_error=None, floor=0.002, chroma_floor=0.01, grid=GRID,
                      false_alarm=FALSE_ALARM, response_jac=jac, path=path, path_bin=None, pooled=True,
                      score_jac=score if with_score else None)

    t0 = time.process_time()
    free = {c.partition: c for c in members(clean)}["response"]
    rng = np.random.default_rng(seed)
    rows, old = [], []
    for _ in range(draws):
        photo = film_noise(clean, rng)
        rows.append(members(photo))
        old.append(members(photo, with_score=False))
    cpu = time.process_time() - t0
    out = {"case": case, "thickness": d, "degree": degree, "draws": draws, "seed": seed, "cpu_s": cpu,
           "noise_free_response_chi2": free.chi2_per_dof * free.dof}
    return summary(out, rows, old)


def summary(out: dict, rows: list, old: list) -> dict:
    """``out`` with each member's law over the draws (``rows``: each draw's members;
    ``old``: the same without the score test) and the union's verdicts; printed."""
    from scipy.special import chdtri

    case, degree, draws, cpu = out["case"], out["degree"], out["draws"], out["cpu_s"]
    out["members"] = {}
    for name in ("cells", "path", "response"):
        got = [next(c for c in r if c.partition == name) for r in rows]
        dof = got[0].dof
        stat = np.array([c.chi2_per_dof * c.dof for c in got])
        out["members"][name] = {
            "dof": dof, "mean": float(stat.mean()), "quantiles_50_90_99": [float(q) for q in np.quantile(stat, [.5, .9, .99])],
            "threshold": float(got[0].threshold_per_dof * dof), "flagged": int(sum(not c.consistent for c in got)),
            "over_chi2_q90": int(np.sum(stat > chdtri(dof, 0.1))), "over_chi2_q99": int(np.sum(stat > chdtri(dof, 0.01))),
            "statistic_lowest": float(stat.min()), "statistic_largest": float(stat.max())}
    out["union_flagged"] = int(sum(not all(c.consistent for c in r) for r in rows))
    out["union_without_score_flagged"] = int(sum(not all(c.consistent for c in r) for r in old))
    out = json.loads(json.dumps(out), parse_float=lambda v: round(float(v), 4))
    s = out["members"]["response"]
    print(f"{case:24s} K={degree} dof {s['dof']:2d}: noise-free {out['noise_free_response_chi2']:8.1f}; draws mean "
          f"{s['mean']:7.1f} (q50/90/99 {' '.join(f'{q:.1f}' for q in s['quantiles_50_90_99'])}), over chi2 q90 "
          f"{s['over_chi2_q90']}, q99 {s['over_chi2_q99']}, flagged {s['flagged']}/{draws}; cells {out['members']['cells']['flagged']}, "
          f"path {out['members']['path']['flagged']}; union {out['union_flagged']} (without score, at 1/2 each: "
          f"{out['union_without_score_flagged']}) [{cpu:.0f} s CPU]", flush=True)
    return out


#: A pale thick draining film (1200 -> 1600 nm, the Nikon under E, 8-bit), fitted with the
#: right response and wrong ones: where a wrong camera's hue error is smallest (as
#: colour_check_null.py's ``DRAINAGE``: profile, seed, camera, lamp, codes, responses).
PALE_DRAINAGE = (((1200.0, 1600.0, 1.0), 53, "Nikon 5100 (NPL)", "E", 8,
                  ("Nikon 5100 (NPL)", "srgb", "Sigma SDMerill (NPL)")),)


def drainage(folder: str, draws: int, degree: int, seed: int, only: str | None = None) -> list:
    """Fit experiments/colour_check_null.py's draining films (its ``DRAINAGE``: Nikon photos
    fitted with the drainage profile through the right response and wrong ones) and
    :data:`PALE_DRAINAGE` (``only``: a comma list of their names), keeping what the fit hands the colour check and the score
    test (the spy on ``response_score_cells`` keeps its arguments, the profile's nuisance
    included); then draw each photo's noise ``draws`` times again on its noise-free render
    (tests/helpers.py's film_noise) and test each draw against the render the fit kept (not
    refitted) by every member of the union, as :func:`run` does for constant films."""
    import bubblefit.inverse.fit as fitmod
    from colour_check_null import DRAINAGE, Recorder, _env, _fit_case

    from bubblefit.inverse.colour_check import GRID, INNER_COS, _tests
    from bubblefit.inverse.response_error import response_cells, response_score_cells
    from bubblefit.optics.film import optical_path

    os.makedirs(folder, exist_ok=True)
    env, _ = _env()
    rows = []
    for prof, s, cam, ill, bits, responses in DRAINAGE + PALE_DRAINAGE:
        clean, _ = film_photo(env, prof, s, cam, ill, quantised=bits, noise=False)
        for resp in responses:
            name = f"drain{prof[0]:.0f}-{prof[1]:.0f}s{s}_{cam.split()[0].lower()}{ill}{bits}_as_{resp.split()[0].lower()}"
            if only and name not in only.split(","):
                continue
            kept = os.path.join(folder, name + "_score.npz")
            if not os.path.exists(kept):
                seen = {}

                def spy(response, illuminant, n_film, render, background, thickness, cos, degree=4, nuisance=None):
                    seen.update(response=response, illuminant=illuminant, n_film=n_film, background=background,
                                thickness=thickness, nuisance=nuisance)
                    return response_score_cells(response, illuminant, n_film, render, background, thickness, cos,
                                                degree, nuisance)

                photo, bg = film_photo(env, prof, s, cam, ill, quantised=bits)
                fitmod.response_score_cells, rec = spy, Recorder()
                try:
                    r, fitted, dt = _fit_case(folder, rec, name, photo, bg, env, resp, bits, thickness="drainage")
                finally:
                    fitmod.response_score_cells = response_score_cells
                rec.save(folder, name, resp == cam, dict(truth=list(prof), thickness=fitted, ok=r.ok,
                                                         chi2=r.reduced_chi2, time_s=dt), kept=r.colour_check)
                print(name, fitted, r.ok, r.colour_check, f"{dt:.0f} s", flush=True)
                np.savez_compressed(kept, fitted=np.asarray(fitted), fit_s=dt,
                                    **{k: np.asarray(v) for k, v in seen.items() if v is not None})
            seen = dict(np.load(kept))
            z = np.load(os.path.join(folder, name + ".npz"))
            response, n = str(seen["response"]), float(seen["n_film"])
            background = seen.get("background")
            cos = z["cos"]
            use = z["mask"].astype(bool) & (cos > INNER_COS)
            path = np.asarray(optical_path(seen["thickness"], n, np.clip(cos, 0.0, 1.0)))
            jac = response_cells(response, str(seen["illuminant"]), n, z["render"], background, seen["thickness"], cos)
            jac = None if jac is None else kept_per_pixels(jac)
            score = kept_per_pixels(response_score_cells(response, str(seen["illuminant"]), n, z["render"], background,
                                              seen["thickness"], cos, degree, seen.get("nuisance")))

            def members(photo, with_score=True):
                return _tests(photo, z["render"], use, z["sigma"], model_error=float(z["model_error"]), floor=0.002,
                              chroma_floor=0.01, grid=GRID, false_alarm=FALSE_ALARM, response_jac=jac, path=path,
                              path_bin=None, pooled=True, score_jac=score if with_score else None)

            t0 = time.process_time()
            free = {c.partition: c for c in members(clean)}.get("response")
            own = {c.partition: c for c in members(z["photo"])}.get("response")
            rng = np.random.default_rng(seed)
            got, old = [], []
            for _ in range(draws):
                photo = film_noise(clean, rng, bits)
                got.append(members(photo))
                old.append(members(photo, with_score=False))
            out = {"case": name, "truth": list(prof), "fitted": [float(v) for v in seen["fitted"]],
                   "fit_s": float(seen["fit_s"]), "degree": degree, "draws": draws, "seed": seed,
                   "cpu_s": time.process_time() - t0,
                   "nuisance_columns": int(np.shape(seen["nuisance"])[-1]) if "nuisance" in seen else None,
                   "noise_free_response_chi2": None if free is None else free.chi2_per_dof * free.dof,
                   "own_photo_response_chi2": None if own is None else own.chi2_per_dof * own.dof}
            rows.append(summary(out, got, old))
    if only and len(rows) < len(only.split(",")):
        raise SystemExit(f"response_score.py: --drainage names a film it does not make (made: "
                         f"{', '.join(r['case'] for r in rows) or 'none'})")
    return rows


def validation(cases: list, folder: str, degree: int) -> list:
    """Fit the validation ``cases`` (colour_check_null.py's run_validation) and test each
    fit's photo with every member of the colour check's union, the score test included."""
    import bubblefit.inverse.fit as fitmod
    from colour_check_null import Recorder, run_validation

    from bubblefit.inverse.colour_check import GRID, INNER_COS, _tests
    from bubblefit.inverse.response_error import response_cells, response_score_cells
    from bubblefit.optics.film import optical_path

    os.makedirs(folder, exist_ok=True)
    rows = []
    for case in cases:
        seen = {}

        def spy(response, illuminant, n_film, render, background, thickness, cos, degree=4, nuisance=None):
            seen.update(response=response, illuminant=illuminant, n_film=n_film, background=background,
                        thickness=thickness, nuisance=nuisance)
            return response_score_cells(response, illuminant, n_film, render, background, thickness, cos, degree,
                                        nuisance)

        kept = os.path.join(folder, f"val_{case}_response.npz")
        if not os.path.exists(kept):
            fitmod.response_score_cells = spy
            rec = Recorder()
            try:
                run_validation(folder, rec, [case])
            finally:
                fitmod.response_score_cells = response_score_cells
            if not seen:
                continue
            np.savez_compressed(kept, **{k: np.asarray(v) for k, v in seen.items() if v is not None})
        seen = {k: v for k, v in np.load(kept).items()}
        seen = {"background": None, **seen, "response": str(seen["response"]), "illuminant": str(seen["illuminant"]),
                "n_film": float(seen["n_film"])}
        z = np.load(os.path.join(folder, f"val_{case}.npz"))
        cos = z["cos"]
        path = np.asarray(optical_path(seen["thickness"], seen["n_film"], np.clip(cos, 0.0, 1.0)))
        use = z["mask"].astype(bool) & (cos > INNER_COS)
        jac = response_cells(seen["response"], seen["illuminant"], seen["n_film"], z["render"], seen["background"],
                             seen["thickness"], cos)
        score = response_score_cells(seen["response"], seen["illuminant"], seen["n_film"], z["render"],
                                     seen["background"], seen["thickness"], cos, degree, seen.get("nuisance"))
        got = _tests(z["photo"], z["render"], use, z["sigma"], model_error=float(z["model_error"]), floor=0.002,
                     chroma_floor=0.01, grid=GRID, false_alarm=FALSE_ALARM, response_jac=jac, path=path,
                     path_bin=None, pooled=True, score_jac=score)
        row = {"case": case, "response": str(seen["response"]), "degree": degree,
               "members": {c.partition: {"statistic": c.chi2_per_dof * c.dof, "dof": c.dof,
                                         "threshold": c.threshold_per_dof * c.dof, "consistent": c.consistent,
                                         "noise_scale": c.noise_scale} for c in got}}
        rows.append(row)
        print(case, json.dumps(row["members"]), flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--arrays", required=True, help="camera_mismatch.py --arrays DIR")
    ap.add_argument("--cases", default="Sigma:Nikon:film:1500,Nikon:Nikon:film:1500")
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--degree", default="4", help="Legendre degrees per channel, a comma list")
    ap.add_argument("--seed", type=int, default=2000)
    ap.add_argument("--val", help="validation development cases to fit and test (a comma list)")
    ap.add_argument("--drainage", nargs="?", const="", help="colour_check_null.py's draining films, fitted once "
                    "and redrawn --draws times (optionally a comma list of their names)")
    ap.add_argument("--json")
    a = ap.parse_args()
    if a.val:
        save(validation(a.val.split(","), a.arrays, int(a.degree)), a.json)
        return
    if a.drainage is not None:
        save(drainage(a.arrays, a.draws, int(a.degree), a.seed, a.drainage or None), a.json)
        return
    env = courtyard()
    rows = [run(case, a.arrays, a.draws, int(k), a.seed, env) for k in a.degree.split(",") for case in a.cases.split(",")]
    save(rows, a.json)


if __name__ == "__main__":
    main()
