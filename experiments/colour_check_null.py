"""The colour check's statistic on fits with the right camera response and with wrong ones.

Runs fits whose camera response is known to be right (the demo's drainage photo, the
validation set's development cases, the RAW/TIFF photos of tests/test_cameras.py, the
48 px constant and draining films of tests/helpers.py's film_photo fitted with the
response they were taken with, and the Nikon's films fitted with a response calibrated
from a film or a chart) and wrong (Nikon films fitted as sRGB/D65 or as the Sigma, Sigma
films as sRGB/D65 or as the Nikon), records what the fit hands the colour check
(:func:`bubblefit.inverse.colour_check.judge_colours`: photo, render, mask, cosine of
incidence, the noise model's sigma) to an ``.npz`` per case, and prints the check's
statistic, its threshold and its verdict.

Usage: ``PYTHONPATH=. python experiments/colour_check_null.py --out DIR
[--cases films,drainage,sigma,raw,demo,val,calibrated,maps]``; ``--table [--json OUT]``
recomputes the table from the saved arrays (no fitting); ``--null DRAWS [--json OUT]``
draws the noise of the right-camera synthetic photos again (:func:`null_draws`).
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
#: development cases of experiments/validation/split.toml: the constant films, and the
#: draining films fitted with the drainage profile (5-13 minutes each on two shared cores)
VAL_CASES = ("ref_const300_courtyard_ortho", "cyc_const500_courtyard_ortho", "ref_const450_interior_ortho",
             "ref_const1200_night_ortho_offc", "ref_const620_sunrise_persp", "ref_drain_exp15_studio_persp",
             "ref_drain_lin_courtyard_ortho", "cyc_drain_lin_sunrise_persp", "ref_drain_lin_city_ortho_offc")
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
            path = rest[3] if len(rest) > 3 else None  # the film's optical path (splits the cells)
            self.calls.append((dict(photo=np.asarray(photo), render=np.asarray(render), mask=np.asarray(mask),
                                    cos=np.asarray(cos), sigma=np.asarray(sigma), model_error=float(model_error),
                                    **({} if path is None else {"path": np.asarray(path)})),
                               out[2]))
            return out

        fit.judge_colours = wrapped

    def save(self, out, name, right: bool, extra: dict, kept: dict | None = None):
        """Save the call whose record is ``kept`` (the fit's reported ``colour_check``: a fit
        without a stated view tries two and keeps one), else the last; then forget them."""
        pick = [(a, rec) for a, rec in self.calls if kept and rec and rec.get("chi2_per_dof") == kept.get("chi2_per_dof")]
        arrs, record = pick[-1] if pick else (self.calls[-1] if self.calls else ({}, None))
        self.calls = []
        np.savez_compressed(os.path.join(out, f"{name}.npz"), **arrs)
        with open(os.path.join(out, f"{name}.json"), "w") as fh:
            # the fit's own record: a calibrated response's errors (response_errors) enter only there
            json.dump(dict(name=name, right=right, fit_record=record, **extra), fh, indent=1, default=float)


def _env():
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import EnvMap, downsample

    px = read_image("bubblefit/data/courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    return EnvMap.from_array(px), px


def run_films(out, rec, thicknesses, responses, camera=NIKON, seed0=11, name="film{d:.0f}_{resp}"):
    """Constant films taken by ``camera`` under E (8-bit), each fitted with every response."""
    from helpers import film_photo

    env, _ = _env()
    for k, d in enumerate(thicknesses):
        photo, bg = film_photo(env, d, seed0 + k, camera, "E")
        for resp in responses:
            case = name.format(d=d, resp=resp.split()[0].lower())
            if os.path.exists(os.path.join(out, case + ".json")):
                continue
            r, fitted, dt = _fit_case(out, rec, case, photo, bg, env, resp, 8)
            rec.save(out, case, resp == camera, dict(truth=d, thickness=fitted[0], ok=r.ok, chi2=r.reduced_chi2,
                                                    time_s=dt))
            print(case, fitted, r.ok, r.colour_check, f"{dt:.0f} s", flush=True)


#: Draining films (top, bottom, exponent) and the photos' seed, camera, lamp and codes:
#: two Nikon photos under E fitted with the right response and wrong ones, and the two
#: photos of experiments/self_calibration.py (seeds 41 and 42) fitted as sRGB/D65.
DRAINAGE = (((200.0, 1500.0, 1.0), 51, NIKON, "E", 8, (NIKON, "srgb", SIGMA)),
            ((300.0, 1000.0, 1.0), 52, NIKON, "E", 8, (NIKON, "srgb", SIGMA)),
            ((200.0, 1500.0, 1.0), 41, NIKON, "E", 8, ("srgb",)),
            ((200.0, 1500.0, 1.0), 42, NIKON, "D65", 16, ("srgb",)))

#: Constant films taken by the Sigma under E, fitted with its own response and wrong ones.
SIGMA_FILMS = ((600.0, 1300.0), (SIGMA, NIKON, "srgb"))


def _fit_case(out, rec, name, photo, bg, env, resp, bits, **kw):
    from helpers import FILM_PHOTO_DISC as DISC

    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.fit import FitOptions, NoiseSettings, fit_photo

    t0 = time.perf_counter()
    r = fit_photo(photo, env, background=bg, options=FitOptions(
        disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", view=ORTHOGRAPHIC, camera_response=resp,
        illuminant="D65" if resp == "srgb" else "E", noise=NoiseSettings(bits=8 if bits == 8 else None), **kw))
    keys = ("top_nm", "bottom_nm", "exponent") if kw.get("thickness") in ("drainage", "map") else ("thickness_nm",)
    fitted = [r.params[k] for k in keys]
    return r, fitted, time.perf_counter() - t0


def run_drainage(out, rec, cases=DRAINAGE, thickness="drainage"):
    """Draining films (:data:`DRAINAGE`) fitted with the drainage profile (``thickness``
    ``"map"``: with a thickness map over it) through the right response and wrong ones."""
    from helpers import film_photo

    env, _ = _env()
    for prof, seed, cam, ill, bits, responses in cases:
        photo, bg = film_photo(env, prof, seed, cam, ill, quantised=bits)
        for resp in responses:
            name = f"{'map' if thickness == 'map' else 'drain'}{prof[0]:.0f}-{prof[1]:.0f}s{seed}_{cam.split()[0].lower()}{ill}{bits}_as_{resp.split()[0].lower()}"
            if os.path.exists(os.path.join(out, name + ".json")):
                continue
            r, fitted, dt = _fit_case(out, rec, name, photo, bg, env, resp, bits, thickness=thickness)
            rec.save(out, name, resp == cam, dict(truth=list(prof), thickness=fitted, ok=r.ok, chi2=r.reduced_chi2,
                                                   warnings=r.warnings, time_s=dt))
            print(name, fitted, r.ok, r.colour_check, f"{dt:.0f} s", flush=True)


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


def null_sources():
    """The right-camera cases whose photo :func:`helpers.film_photo` rebuilds noise-free:
    ``{case: (thickness, seed, camera, lamp, quantised)}``."""
    src = {f"film{d:.0f}_nikon": (d, 11 + k, NIKON, "E", True) for k, d in enumerate(THICKNESSES)}
    for prof, seed, cam, ill, bits, _ in DRAINAGE:
        src[f"drain{prof[0]:.0f}-{prof[1]:.0f}s{seed}_{cam.split()[0].lower()}{ill}{bits}_as_{cam.split()[0].lower()}"] = (
            prof, seed, cam, ill, bits)
    for k, d in enumerate(SIGMA_FILMS[0]):
        src[f"sigmafilm{d:.0f}_as_sigma"] = (d, 61 + k, SIGMA, "E", True)
    src["raw_exr"] = (700.0, 3, "srgb", "D65", False)
    return src


def null_draws(out, draws: int, seed: int = 2024):
    """The statistic's law on right-camera fits: each rebuildable case's noise-free photo
    gets ``draws`` new draws of its noise (:func:`helpers.film_noise`) and is tested
    against the render its fit kept (the fit is not repeated: a refit would absorb part of
    each draw, so the rates are upper bounds), with the fit's noise model and mask.
    Returns one row per case: mean, 99th and 99.9th percentile of the statistic per
    degree of freedom, the alarms at the check's threshold, and their one-sided 95 %
    upper bound (Clopper-Pearson)."""
    from helpers import film_noise, film_photo
    from scipy.stats import beta

    from bubblefit.inverse.colour_check import INNER_COS, colour_check

    env, _ = _env()
    rng = np.random.default_rng(seed)
    rows = []
    for case, (thickness, s, cam, ill, quantised) in null_sources().items():
        path = os.path.join(out, case + ".npz")
        if not os.path.exists(path):
            continue
        meta = json.load(open(os.path.join(out, case + ".json")))
        if np.max(np.abs(np.atleast_1d(np.subtract(meta["thickness"], thickness)))[:2]) > 25.0:
            print(f"{case:44s} left out: its fit is an order off ({meta['thickness']})", flush=True)
            continue  # the right camera, but the fit an interference order off: flagged rightly
        arr = np.load(path)
        clean, _ = film_photo(env, thickness, s, cam, ill, quantised=quantised, noise=False)
        mask = arr["mask"] & (arr["cos"] > INNER_COS)
        values, alarms, thr = [], 0, None
        for _ in range(draws):
            c = colour_check(film_noise(clean, rng, quantised), arr["render"], mask, arr["sigma"],
                             model_error=float(arr["model_error"]) if "model_error" in arr else 0.03)
            values.append(c.chi2_per_dof)
            alarms += not c.consistent
            thr = c.threshold_per_dof
        v = np.asarray(values)
        upper = float(beta.ppf(0.95, alarms + 1, draws - alarms))
        rows.append(dict(case=case, draws=draws, mean=float(v.mean()), q99=float(np.quantile(v, 0.99)),
                         q999=float(np.quantile(v, 0.999)), max=float(v.max()), threshold=thr, alarms=alarms,
                         rate_upper95=upper))
        print(f"{case:44s} mean {v.mean():.3f} q99 {rows[-1]['q99']:.3f} q999 {rows[-1]['q999']:.3f} max {v.max():.3f} "
              f"thr {thr:.3f} alarms {alarms}/{draws} (rate < {upper:.2g})", flush=True)
    return rows


def kind(meta) -> str:
    """``right``: the response the photo was taken with, the fit in the right order;
    ``order off``: that response, the fit more than 25 nm from the truth (flagged rightly);
    ``calibrated``: a response calibrated from a film or a chart (approximate);
    ``wrong``: another camera's response or another lamp."""
    if meta["name"].startswith("cal"):
        return "calibrated"
    if not meta["right"]:
        return "wrong"
    truth, fitted = meta.get("truth"), meta.get("thickness")
    if truth is None or fitted is None:
        return "right"
    off = np.max(np.abs(np.atleast_1d(np.subtract(fitted, truth)))[:2])
    return "right" if off <= 25.0 else "order off"


def table(out):
    """Recompute the colour check on every saved case; print and return one row each."""
    from bubblefit.inverse.colour_check import INNER_COS, ColourCheck, colour_check

    rows = []
    for f in sorted(os.listdir(out)):
        if not f.endswith(".json"):
            continue
        meta = json.load(open(os.path.join(out, f)))
        arr = np.load(os.path.join(out, f[:-5] + ".npz"))
        mask = arr["mask"] & (arr["cos"] > INNER_COS)
        me = float(arr["model_error"]) if "model_error" in arr else 0.03  # JudgeSettings.model_error's default
        path = arr["path"] if "path" in arr else None  # cells split by the optical path where saved
        c = colour_check(arr["photo"], arr["render"], mask, arr["sigma"], model_error=me, path=path, pooled=path is not None)
        plain = c.chi2_per_dof  # the response taken as exact
        if (meta.get("fit_record") or {}).get("response_errors"):
            # a calibrated response: the fit's check held its errors (not saved here), so its record stands
            c = ColourCheck(**{k: meta["fit_record"][k] for k in ColourCheck.__dataclass_fields__})
        k = kind(meta)
        rows.append(dict(case=meta["name"], kind=k, right=meta["right"], truth=meta.get("truth"),
                         thickness=meta.get("thickness"), statistic=c.chi2_per_dof, threshold=c.threshold_per_dof,
                         cells=c.cells, partition=c.partition, noise_scale=c.noise_scale, consistent=c.consistent,
                         reduced_chi2=meta.get("chi2"), statistic_response_exact=plain))
        fitted = np.round(np.atleast_1d(meta.get("thickness") if meta.get("thickness") is not None else np.nan), 1)
        print(f"{meta['name']:48s} {k:10s} truth {meta.get('truth')!s:>20} fit {fitted!s:>24} stat "
              f"{c.chi2_per_dof:7.3f} thr {c.threshold_per_dof:5.3f} kappa {c.noise_scale:5.2f} -> "
              f"{'consistent' if c.consistent else 'FLAGGED'}", flush=True)
    for k in ("right", "wrong", "order off", "calibrated"):
        sel = [r for r in rows if r["kind"] == k]
        if sel:
            print(f"{k}: {sum(not r['consistent'] for r in sel)} of {len(sel)} flagged")
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--cases", default="films,drainage,sigma,raw,demo,val,calibrated",
                    help="comma-separated; also maps: the draining films fitted with a thickness map")
    ap.add_argument("--thickness", default=",".join(f"{t:.0f}" for t in THICKNESSES))
    ap.add_argument("--val", default=",".join(VAL_CASES))
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--json", help="with --table or --null: also write the table here")
    ap.add_argument("--null", type=int, metavar="DRAWS",
                    help="draw the noise of the rebuildable right-camera photos this many times (null_draws)")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    if a.null:
        rows = null_draws(a.out, a.null)
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(rows, fh, indent=1)
        return
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
        elif case == "drainage":
            run_drainage(a.out, rec)
        elif case == "maps":
            run_drainage(a.out, rec, thickness="map")
        elif case == "sigma":
            run_films(a.out, rec, *SIGMA_FILMS, camera=SIGMA, seed0=61, name="sigmafilm{d:.0f}_as_{resp}")
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
