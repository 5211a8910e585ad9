"""The colour check's statistic on fits with the right camera response and with wrong ones.

Runs fits whose camera response is known to be right (the demo's drainage photo, the
validation set's development cases, the RAW/TIFF photos of tests/test_cameras.py, the
48 px films of experiments/wrong_camera.py fitted with the Nikon's response, and the same
fitted with a response calibrated from a film) and wrong (those films fitted as sRGB/D65 or
as the Sigma), records what the fit hands the colour check
(:func:`bubblefit.inverse.colour_check.judge_colours`: photo, render, mask, cosine of
incidence, the noise model's sigma) to an ``.npz`` per case, and prints the check's
statistic, its threshold and its verdict.

Usage: ``PYTHONPATH=. python experiments/colour_check_null.py --out DIR [--cases demo,val,raw,films,calibrated]``
and ``--table [--json OUT]`` to recompute the table from the saved arrays (no fitting).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))

VAL = os.path.join(os.path.dirname(__file__), "validation", "data")
#: development cases of experiments/validation/split.toml with a constant film (the cheap ones)
VAL_CASES = ("ref_const300_courtyard_ortho", "cyc_const500_courtyard_ortho", "ref_const450_interior_ortho",
             "ref_const1200_night_ortho_offc", "ref_const620_sunrise_persp")
THICKNESSES = (300.0, 600.0, 1000.0, 1300.0, 1500.0)
NIKON, SIGMA = "Nikon 5100 (NPL)", "Sigma SDMerill (NPL)"


class Recorder:
    """Wraps ``bubblefit.inverse.fit.judge_colours``; keeps the last call's arrays."""

    def __init__(self):
        import bubblefit.inverse.fit as fit

        self.calls = []
        self._orig = fit.judge_colours

        def wrapped(ok, warnings, photo, render, mask, cos, sigma, model_error=0.0, *rest):
            out = self._orig(ok, warnings, photo, render, mask, cos, sigma, model_error, *rest)
            self.calls.append((dict(photo=np.asarray(photo), render=np.asarray(render), mask=np.asarray(mask),
                                    cos=np.asarray(cos), sigma=np.asarray(sigma), model_error=float(model_error)),
                               out[2]))
            return out

        fit.judge_colours = wrapped

    def save(self, out, name, right: bool, extra: dict, kept: dict | None = None):
        """Save the call whose record is ``kept`` (the fit's reported ``colour_check``: a fit
        without a stated view tries two and keeps one), else the last; then forget them."""
        pick = [a for a, rec in self.calls if kept and rec and rec.get("chi2_per_dof") == kept.get("chi2_per_dof")]
        arrs = pick[-1] if pick else (self.calls[-1][0] if self.calls else {})
        self.calls = []
        np.savez_compressed(os.path.join(out, f"{name}.npz"), **arrs)
        with open(os.path.join(out, f"{name}.json"), "w") as fh:
            json.dump(dict(name=name, right=right, **extra), fh, indent=1, default=float)


def _env():
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    px = read_image("bubblefit/data/courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    return EnvMap.from_array(px), px


def run_films(out, rec, thicknesses, responses):
    from helpers import FILM_PHOTO_DISC as DISC, film_photo

    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts

    env, _ = _env()
    for k, d in enumerate(thicknesses):
        photo, bg = film_photo(env, d, 11 + k, NIKON, "E")
        for resp in responses:
            name = f"film{d:.0f}_{resp.split()[0].lower()}"
            if os.path.exists(os.path.join(out, name + ".json")):
                continue
            t0 = time.perf_counter()
            r = fit_photo(photo, env, background=bg, options=FitOptions(
                disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", view=ORTHOGRAPHIC, camera_response=resp,
                illuminant="D65" if resp == "srgb" else "E"))
            rec.save(out, name, resp == NIKON, dict(truth=d, thickness=r.params["thickness_nm"], ok=r.ok,
                                                   chi2=r.reduced_chi2, time_s=time.perf_counter() - t0))
            print(name, r.params["thickness_nm"], r.colour_check, flush=True)


def run_calibrated(out, rec, thicknesses, sources=("film", "chart")):
    """experiments/calibrated_camera.py's fits: a response calibrated from a film or a chart."""
    from calibrated_camera import CAMERA, airy, sensitivities
    from helpers import FILM_PHOTO_DISC as DISC, film_photo

    from bubblefit.capture.camera_calibration import chart_reflectances, fit_response
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts

    env, _ = _env()
    rng = np.random.default_rng(5)
    sens = sensitivities(CAMERA)
    data = {"film": airy(np.linspace(0.0, 2000.0, 81)), "chart": chart_reflectances()[1]}
    tmp = tempfile.mkdtemp()
    for source in sources:
        y = data[source] @ sens
        y = y * (1 + 0.005 * rng.normal(size=y.shape))
        path = os.path.join(tmp, f"{source}.csv")
        with open(path, "w") as fh:
            fh.write(fit_response([(source, data[source], y)]).csv_text())
        for k, t in enumerate(thicknesses):
            name = f"cal{source}{t:.0f}"
            if os.path.exists(os.path.join(out, name + ".json")):
                continue
            photo, bg = film_photo(env, t, 31 + k, CAMERA, "E")
            t0 = time.perf_counter()
            r = fit_photo(photo, env, background=bg, options=FitOptions(
                disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=path, illuminant="E",
                view=ORTHOGRAPHIC))
            good = abs(r.params["thickness_nm"] - t) < 25.0  # the right order: a usable calibration
            rec.save(out, name, good, dict(truth=t, thickness=r.params["thickness_nm"], ok=r.ok, chi2=r.reduced_chi2,
                                           time_s=time.perf_counter() - t0))
            print(name, r.params["thickness_nm"], r.colour_check, flush=True)


def run_demo_case(out, rec, size=96):
    from pathlib import Path

    from bubblefit.demo import run_demo

    name = f"demo{size}"
    if os.path.exists(os.path.join(out, name + ".json")):
        return
    t0 = time.perf_counter()
    res = run_demo(Path(tempfile.mkdtemp()), size=size, seed=0, progress=False)
    fit = res.get("fit") if isinstance(res, dict) else None
    rec.save(out, name, True, dict(time_s=time.perf_counter() - t0, ok=(fit or {}).get("ok")))
    print(name, (fit or {}).get("colour_check"), flush=True)


def run_validation(out, rec, cases):
    from bubblefit.cli import main

    for case in cases:
        name = f"val_{case}"
        if os.path.exists(os.path.join(out, name + ".json")):
            continue
        cdir = os.path.join(VAL, case)
        with open(os.path.join(cdir, "truth.json")) as fh:
            truth = json.load(fh)
        js = os.path.join(tempfile.mkdtemp(), "fit.json")
        args = ["fit", os.path.join(cdir, "photo.png"), "--envmap", os.path.join(VAL, truth["envmap"]),
                "--background", os.path.join(cdir, "background.png"), "--thickness",
                truth.get("fits", ["constant"])[0], "--json", js]
        args += [os.path.join(cdir, a) if a.endswith((".toml", ".json")) else a for a in truth.get("fit_args", [])]
        if truth.get("illuminant") in ("D65", "E", "A"):
            args += ["--illuminant", truth["illuminant"]]
        if truth["camera"]["type"] == "orthographic" and "--fov" not in args and "--scene" not in args:
            args += ["--fov", "0"]  # the view the fit keeps for these photos, without trying a lens too
        t0 = time.perf_counter()
        rc = main(args)
        res = json.load(open(js)) if rc == 0 else {}
        rec.save(out, name, True, dict(truth=truth["thickness"].get("thickness_nm"), rc=rc, model=args[args.index("--thickness") + 1],
                                       thickness=res.get("params", {}).get("thickness_nm"), ok=res.get("ok"),
                                       chi2=res.get("reduced_chi2"), time_s=time.perf_counter() - t0),
                 kept=res.get("colour_check"))
        print(name, res.get("params", {}).get("thickness_nm"), res.get("colour_check"), flush=True)


def run_raw(out, rec):
    """tests/test_cameras.py's linear TIFF and DNG of one 700 nm film (fitted as the EXR)."""
    import tifffile

    from helpers import FILM_PHOTO_DISC as DISC, film_photo
    from test_cameras import _mosaic, _write_dng

    from bubblefit.cli import main
    from bubblefit.io.images import write_image

    env, px = _env()
    tmp = tempfile.mkdtemp()
    photo, bg = film_photo(env, 700.0, 3, quantised=False)
    envfile = os.path.join(tmp, "env.exr")
    write_image(envfile, px, bit_depth=32)
    black, white = 64, 4095
    for nm, arr in (("photo", photo), ("bg", bg)):
        write_image(os.path.join(tmp, f"{nm}.exr"), arr, bit_depth=32)
        codes = np.clip(np.round(arr * (white - black) + black), 0, white)
        tifffile.imwrite(os.path.join(tmp, f"{nm}.tif"), codes.astype(np.uint16), photometric="rgb")
        _write_dng(os.path.join(tmp, f"{nm}.dng"), _mosaic(codes), black, white)
    for kind, flags in (("exr", []), ("tif", ["--encoding", "linear", "--black-level", str(black), "--white-level",
                                              str(white)]), ("dng", ["--raw-white-balance", "none"])):
        name = f"raw_{kind}"
        if os.path.exists(os.path.join(out, name + ".json")):
            continue
        js = os.path.join(tmp, f"{kind}.json")
        rc = main(["fit", os.path.join(tmp, f"photo.{kind}"), "--background", os.path.join(tmp, f"bg.{kind}"),
                   "--envmap", envfile, "--model", "paper", "--disc", ",".join(map(str, DISC)), "--t", "0.968",
                   "--fov", "0", "--json", js, *flags])
        res = json.load(open(js)) if rc == 0 else {}
        rec.save(out, name, True, dict(truth=700.0, thickness=res.get("params", {}).get("thickness_nm"),
                                       ok=res.get("ok"), chi2=res.get("reduced_chi2")), kept=res.get("colour_check"))
        print(name, res.get("params", {}).get("thickness_nm"), res.get("colour_check"), flush=True)


def table(out):
    from bubblefit.inverse.colour_check import INNER_COS, colour_check

    rows = []
    for f in sorted(os.listdir(out)):
        if not f.endswith(".json"):
            continue
        meta = json.load(open(os.path.join(out, f)))
        arr = np.load(os.path.join(out, f[:-5] + ".npz"))
        mask = arr["mask"] & (arr["cos"] > INNER_COS)
        me = float(arr["model_error"]) if "model_error" in arr else 0.03  # JudgeSettings.model_error's default
        c = colour_check(arr["photo"], arr["render"], mask, arr["sigma"], model_error=me)
        rows.append(dict(case=meta["name"], right=meta["right"], truth=meta.get("truth"),
                         thickness=meta.get("thickness"), statistic=c.chi2_per_dof, threshold=c.threshold_per_dof,
                         cells=c.cells, noise_scale=c.noise_scale, consistent=c.consistent))
        print(f"{meta['name']:44s} {'right' if meta['right'] else 'WRONG':5s} truth {meta.get('truth')!s:>7} "
              f"fit {meta.get('thickness') or float('nan'):8.1f}  stat {c.chi2_per_dof:7.3f} thr "
              f"{c.threshold_per_dof:5.3f} cells {c.cells:3d} kappa {c.noise_scale:5.2f} -> "
              f"{'consistent' if c.consistent else 'FLAGGED'}{'' if c.consistent == meta['right'] else '  << WRONG VERDICT'}")
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--cases", default="films,raw,demo,val,calibrated")
    ap.add_argument("--thickness", default=",".join(f"{t:.0f}" for t in THICKNESSES))
    ap.add_argument("--val", default=",".join(VAL_CASES))
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--json", help="with --table: also write the table here")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    if a.table:
        rows = table(a.out)
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(rows, fh, indent=1)
        return
    rec = Recorder()
    ts = [float(x) for x in a.thickness.split(",")]
    for case in a.cases.split(","):
        if case == "films":
            run_films(a.out, rec, ts, (NIKON, "srgb", SIGMA))
        elif case == "calibrated":
            run_calibrated(a.out, rec, ts)
        elif case == "demo":
            run_demo_case(a.out, rec)
        elif case == "val":
            run_validation(a.out, rec, a.val.split(","))
        elif case == "raw":
            run_raw(a.out, rec)


if __name__ == "__main__":
    main()
