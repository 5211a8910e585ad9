"""Score bubblefit on the independent validation set (photos bubblefit did not render).

For every case folder under data/ (or the names given; --quick for a small subset) this
runs bubblefit through its command line exactly as a user would (`python -m bubblefit
fit ...` / `calibrate ...`), reads the JSON it writes and compares it with the case's
truth.json. The capture's illuminant (truth.json ``illuminant``: D65 for the reference
renderer, E for Cycles) is passed as ``--illuminant``, as a user states their camera's;
a Blender Cycles photo's floating bubble is fitted with ``--film-rgb clamped`` (each film's
colour formed as Cycles' thin film forms it) unless ``--spectral-film`` is given.
It prints a table and writes results.csv, results.json and validation.png to
--out (default experiments/results/validation/).

Run it with the project's venv from the repository root:

    PYTHONPATH=. python experiments/validation/validate.py [--quick] [CASE ...]
    PYTHONPATH=. python experiments/validation/validate.py --part test --out experiments/validation/results/test

The cases are split (split.toml, docs/validation-split.md) into a development part, on
which constants and rules of bubblefit were chosen, and a test part never used for a
choice; every row carries its part and results.md summarises each part on its own.
Coverage: a fitted thickness (constant, drainage top and bottom) is covered when it lies
within 3 of its stated standard errors of the truth; a map's pixels likewise with the
map's per-pixel standard errors (PREFIX_thickness_stderr.exr).

Targets (from the validation issue; nothing here is tuned to them):
  constant thickness within 5 nm; drainage ends within 20 nm (top) / 30 nm (bottom) and
  within 3 standard errors; maps: median error <= 15 nm, >= 90 % of the inner disc within
  15 nm, no order hops; negatives: refused or `ok: false`; calibrate: t within its stated
  interval (or within 0.002).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import vio  # noqa: E402

REPO = os.path.normpath(os.path.join(HERE, "..", ".."))
DATA = os.path.join(HERE, "data")
DEFAULT_OUT = os.path.join(REPO, "experiments", "results", "validation")
QUICK = ["ref_const300_courtyard_ortho", "cal_box_256x192", "neg_nobubble_courtyard"]
INNER = 0.8           # inner disc: within 0.8 r of the true centre
COVER_NM = 15.0       # coverage tolerance
HOP_NM = 100.0        # a jump between neighbours larger than this where the truth is smooth
SMOOTH_NM = 20.0      # ... and the truth changes by less than this
TOL = {"constant": 5.0, "top": 20.0, "bottom": 30.0, "se": 3.0, "median": 15.0, "coverage": 0.90, "t_cal": 0.002}


SPLIT_FILE = os.path.join(HERE, "split.toml")
PARTS = ("development", "test")
COVER_SE = 3.0        # coverage: within this many stated standard errors
#: Where each fit's JSON and images go (``--runs``; None: OUT/runs).
RUNS_DIR: list[str] = []


def load_split(path: str = SPLIT_FILE) -> dict[str, dict]:
    """``{case: {"part": ..., "reason": ...}}`` from split.toml (empty when it is absent)."""
    import tomllib

    if not os.path.exists(path):
        return {}
    with open(path, "rb") as fh:
        cases = tomllib.load(fh).get("cases", {})
    bad = {c: v.get("part") for c, v in cases.items() if v.get("part") not in PARTS}
    if bad:
        raise SystemExit(f"split.toml: part must be one of {PARTS}: {bad}")
    return cases


def part_of(case: str, split: dict | None = None) -> str:
    """The case's part in split.toml, or "unassigned"."""
    split = load_split() if split is None else split
    if case.startswith("xcal_ref_const300"):    # ref_const300's photo with another framing's calibration
        case = "ref_const300_courtyard_ortho"
    return split.get(case.split(":")[0], {}).get("part", "unassigned")


#: Whether the Blender Cycles cases' maps are read at their texel centres (``--envmap-convention
#: texel-centre``), as Blender rendered them; ``--mitsuba-rows`` reads them on bubblefit's
#: default rows instead (the scores before the option existed).
CYCLES_TEXEL_CENTRES = True
#: Whether the Blender Cycles cases are fitted with the film coloured as Cycles colours it
#: (``--film-rgb clamped``); ``--spectral-film`` fits them with the spectral film instead.
CYCLES_FILM_RGB = True


def runs_dir(out_dir: str) -> str:
    return RUNS_DIR[0] if RUNS_DIR else os.path.join(out_dir, "runs")


def list_cases() -> list[str]:
    out = []
    for n in sorted(os.listdir(DATA)):
        if os.path.isfile(os.path.join(DATA, n, "truth.json")):
            out.append(n)
    return out


def load_truth(case: str) -> dict:
    with open(os.path.join(DATA, case, "truth.json")) as fh:
        return json.load(fh)


FIT_TIMEOUT = 900.0
#: Arguments added to every `bubblefit fit` (``--fit-args``), e.g. ``--model physical``.
EXTRA_FIT_ARGS: list[str] = []
#: Thickness models to run (``--only``; empty: every fit a case lists).
ONLY_FITS: list[str] = []


def _cli(args: list[str], timeout: float | None = None) -> tuple[int, str, float]:
    env = dict(os.environ)
    env["PYTHONPATH"] = REPO + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    timeout = timeout or FIT_TIMEOUT
    t0 = time.time()
    try:
        p = subprocess.run([sys.executable, "-m", "bubblefit", *args], cwd=REPO, env=env, capture_output=True,
                           text=True, timeout=timeout, stdin=subprocess.DEVNULL)
        rc, err = p.returncode, (p.stderr.strip().splitlines() or [""])[-1]
    except subprocess.TimeoutExpired:
        rc, err = 124, f"timed out after {timeout:.0f} s"
    return rc, err, time.time() - t0


def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def disc_error(found: dict | None, true: dict | None):
    """(centre distance, radius difference) in pixels, or (None, None)."""
    if not found or not true:
        return None, None
    try:
        dc = math.hypot(float(found["cx"]) - true["cx"], float(found["cy"]) - true["cy"])
        return dc, float(found["r"]) - true["r"]
    except (KeyError, TypeError, ValueError):
        return None, None


def map_metrics(fit_map: np.ndarray, true_map: np.ndarray, disc: dict) -> dict:
    """Median / 90th-percentile absolute error, coverage and order hops over the inner disc."""
    h, w = true_map.shape
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    inner = (xx - disc["cx"]) ** 2 + (yy - disc["cy"]) ** 2 <= (INNER * disc["r"]) ** 2
    inner &= np.isfinite(true_map)
    err = np.abs(fit_map - true_map)
    valid = inner & np.isfinite(fit_map)
    n = int(inner.sum())
    e = err[valid]
    hops = 0
    for ax in (0, 1):
        df = np.abs(np.diff(fit_map, axis=ax))
        dt = np.abs(np.diff(true_map, axis=ax))
        both = (inner[1:, :] & inner[:-1, :]) if ax == 0 else (inner[:, 1:] & inner[:, :-1])
        hops += int(np.sum(both & (dt < SMOOTH_NM) & np.nan_to_num(df > HOP_NM, nan=False)))
    return {"map_pixels": n,
            "map_median_nm": float(np.median(e)) if e.size else None,
            "map_p90_nm": float(np.percentile(e, 90)) if e.size else None,
            "map_coverage": float(np.sum(e <= COVER_NM) / n) if n else None,
            "map_missing": float(1 - valid.sum() / n) if n else None,
            "order_hops": hops}


def _scene_camera(cdir: str, fit_args: list) -> bool:
    """Whether the case's fit arguments name a scene file with a ``[camera]`` table."""
    import tomllib

    scenes = [a for a in fit_args if a.endswith(".toml")]
    for name in scenes:
        with open(os.path.join(cdir, name), "rb") as fh:
            if "camera" in tomllib.load(fh):
                return True
    return False


def run_fit(case: str, model: str, out_dir: str, calibration: str | None = None, tag: str | None = None,
            disc_given: bool = False) -> dict:
    """Fit one case with one thickness model through the CLI and score it."""
    truth = load_truth(case)
    cdir = os.path.join(DATA, case)
    runs = runs_dir(out_dir)
    os.makedirs(runs, exist_ok=True)
    name = tag or (f"{case}:{model}" + (":disc given" if disc_given else ""))
    stem = os.path.join(runs, name.replace(":", "_").replace(" ", "_"))
    js = stem + ".json"
    if os.path.exists(js):
        os.remove(js)
    args = ["fit", os.path.join(cdir, "photo.png"), "--envmap", os.path.join(DATA, truth["envmap"]),
            "--background", os.path.join(cdir, "background.png"), "--thickness", model, "--json", js, "-o", stem]
    fa = list(truth.get("fit_args", []))
    args += [os.path.join(cdir, a) if a.endswith((".toml", ".json")) else a for a in fa]
    if truth.get("camera", {}).get("type") == "orthographic" and "--fov" not in fa and not _scene_camera(cdir, fa):
        # an orthographic photo is fitted with its view stated, as a user who knows the
        # camera states it (--fov 0), also beside a scene file that does not describe the
        # camera; the perspective photos name theirs in scene.toml, and the *_nocam cases
        # are fitted without one on purpose
        args += ["--fov", "0"]
    if truth.get("illuminant") in ("D65", "E", "A"):
        # the white the renderer (or camera) integrated under is part of the capture, as the
        # environment map is: Cycles converts its spectra under E
        args += ["--illuminant", truth["illuminant"]]
    if str(truth.get("renderer", "")).startswith("Blender"):
        # Blender's Environment Texture reads its texels at their centres, (i + 1/2) / H:
        # the map's convention is part of the capture, as its file is
        args += ["--envmap-convention", "texel-centre" if CYCLES_TEXEL_CENTRES else "mitsuba"]
        if CYCLES_FILM_RGB:
            # Cycles' thin film clamps each film's RGB reflectance to [0, 1] before its
            # bounces: how the renderer formed the film's colour is part of the capture
            args += ["--film-rgb", "clamped"]
    if (disc_given or truth.get("disc_given")) and truth.get("disc"):
        d = truth["disc"]
        args += ["--disc", f"{d['cx']},{d['cy']},{d['r']}"]
    if calibration:
        args += ["--calibration", calibration]
    args += EXTRA_FIT_ARGS
    rc, err, wall = _cli(args)
    row = {"case": name, "kind": truth.get("kind"), "model": model, "renderer": truth.get("renderer_version",
           truth.get("renderer", "")).split(",")[0], "rc": rc, "wall_s": round(wall, 1)}
    res = None
    if os.path.exists(js):
        with open(js) as fh:
            res = json.load(fh)
    if rc != 0 or res is None:
        row["refused"] = True
        row["message"] = err
    else:
        row["refused"] = False
    row.update(score_fit(res, truth, model, stem))
    row["pass"] = judge(row, truth, model)
    row["part"] = part_of(case)
    row.update(coverage(row))
    return row


def coverage(row: dict) -> dict:
    """How many of the row's fitted thicknesses lie within COVER_SE stated standard errors.

    Counts the constant thickness and the drainage ends (a map counts once: covered when
    at least TOL["coverage"] of its inner disc is within COVER_SE of its per-pixel errors).
    """
    zs = [row.get(k) for k in ("d_err_se", "top_err_se", "bottom_err_se")]
    n = sum(z is not None for z in zs)
    k = sum(z is not None and abs(z) <= COVER_SE for z in zs)
    c3 = row.get("map_cover_3se")
    if c3 is not None:
        n += 1
        k += c3 >= TOL["coverage"]
    return {"cov_n": n, "cov_in": k} if n else {}


def score_fit(res: dict | None, truth: dict, model: str, stem: str) -> dict:
    out = {}
    if res is None:
        return out
    p, se = res.get("params", {}) or {}, res.get("stderr", {}) or {}
    out["ok"] = res.get("ok")
    out["converged"] = res.get("converged")
    out["reduced_chi2"] = _num(res.get("reduced_chi2"))
    out["chi2_floor"] = _num(res.get("reduced_chi2_floor"))
    out["chi2_inliers"] = _num(res.get("reduced_chi2_inliers"))
    out["outliers"] = _num(res.get("outlier_fraction"))
    out["model_kept"] = res.get("model")
    out["time_s"] = _num(res.get("time_s"))
    out["warnings"] = "; ".join(res.get("warnings", []) or [])[:400]
    t_true = truth.get("t")
    if _num(p.get("t")) is not None and t_true is not None and _t_fitted(res):
        out["t"] = _num(p["t"])
        out["t_err"] = out["t"] - t_true
        s_t = _num(se.get("t"))
        out["t_err_se"] = out["t_err"] / s_t if s_t else None
    out["roughness"] = _num(p.get("roughness"))
    dc, dr = disc_error(res.get("disc"), truth.get("disc"))
    out["disc_dc_px"], out["disc_dr_px"] = dc, dr
    th = truth.get("thickness", {})
    if truth.get("kind") == "negative":
        return out
    if model == "constant" and th.get("profile") == "constant":
        d, s = _num(p.get("thickness_nm")), _num(se.get("thickness_nm"))
        if d is not None:
            out["thickness_nm"] = d
            out["d_err_nm"] = d - th["thickness_nm"]
            out["d_err_se"] = out["d_err_nm"] / s if s else None
    if model == "drainage" and th.get("profile", "").startswith("drainage"):
        for k in ("top_nm", "bottom_nm"):
            v, s = _num(p.get(k)), _num(se.get(k))
            if v is not None:
                key = k.split("_")[0]
                out[f"{key}_nm"] = v
                out[f"{key}_err_nm"] = v - th[k]
                out[f"{key}_err_se"] = out[f"{key}_err_nm"] / s if s else None
        out["exponent"] = _num(p.get("exponent"))
    tm_path = stem + "_thickness.exr"
    true_path = os.path.join(DATA, truth["case"] if truth.get("kind") != "negative" else truth.get("source_case", ""),
                             "thickness_true.exr")
    if model in ("map", "drainage") and os.path.exists(tm_path) and os.path.exists(true_path):
        fit_map = vio.read_image(tm_path)[..., 0]
        true_map = vio.read_image(true_path)[..., 0]
        if fit_map.shape == true_map.shape:
            out.update(map_metrics(fit_map, true_map, truth["disc"]))
            se_path = stem + "_thickness_stderr.exr"
            if os.path.exists(se_path):
                se_map = vio.read_image(se_path)[..., 0]
                if se_map.shape == true_map.shape:
                    out.update(map_se_metrics(fit_map, se_map, true_map, truth["disc"]))
    return out


def map_se_metrics(fit_map, se_map, true_map, disc) -> dict:
    """Share of the inner disc whose map error is within COVER_SE of the pixel's stated error."""
    h, w = true_map.shape
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    inner = (xx - disc["cx"]) ** 2 + (yy - disc["cy"]) ** 2 <= (INNER * disc["r"]) ** 2
    inner &= np.isfinite(true_map)
    ok = inner & np.isfinite(fit_map) & np.isfinite(se_map) & (se_map > 0)
    n = int(inner.sum())
    if not n:
        return {}
    z = np.abs(fit_map - true_map)[ok] / se_map[ok]
    return {"map_cover_3se": float(np.sum(z <= COVER_SE) / n),
            "map_median_se_nm": float(np.median(se_map[ok])) if ok.any() else None}


def _t_err_se_ci(row: dict) -> float | None:
    """t's error in standard errors read from its two-sided 95 % interval (normal: the
    half-width is 1.96 standard errors)."""
    lo, hi, e = row.get("t_ci_lo"), row.get("t_ci_hi"), row.get("t_err")
    if lo is None or hi is None or e is None or not hi > lo:
        return None
    return e / ((hi - lo) / (2 * 1.959964))


def _t_fitted(res: dict) -> bool:
    """Whether the fit estimated t: the physical model derives transmission from n_film
    (Fresnel) and reports t at its start value with the role "unused"."""
    roles = {q.get("name"): q.get("role") for q in res.get("parameters", []) or []}
    return roles.get("t", "fitted") == "fitted"


def _rescore_t(out_dir: str, row: dict) -> None:
    """t, its error and its error in stated standard errors from the fit's JSON under
    ``out_dir``/runs (rows scored before those columns existed); t is dropped where the fit
    did not estimate it."""
    js = os.path.join(out_dir, "runs", row["case"].replace(":", "_").replace(" ", "_") + ".json")
    if not os.path.isfile(js):
        return
    with open(js) as fh:
        res = json.load(fh)
    if not _t_fitted(res):
        row["t"] = row["t_err"] = row["t_err_se"] = None
        return
    s_t = _num((res.get("stderr") or {}).get("t"))
    row["t_err_se"] = row["t_err"] / s_t if s_t else None


def judge(row: dict, truth: dict, model: str):
    """True / False against the issue's targets, None where no target applies."""
    if truth.get("kind") == "negative":
        return bool(row.get("refused") or row.get("ok") is False)
    if row.get("refused"):
        return False
    th = truth.get("thickness", {}).get("profile")
    if model == "constant" and th == "constant":
        e = row.get("d_err_nm")
        return e is not None and abs(e) <= TOL["constant"]
    if model == "drainage" and th == "drainage":
        vals = [row.get(k) for k in ("top_err_nm", "bottom_err_nm", "top_err_se", "bottom_err_se")]
        if any(v is None for v in vals[:2]):
            return False
        ok = abs(vals[0]) <= TOL["top"] and abs(vals[1]) <= TOL["bottom"]
        return ok and all(v is not None and abs(v) <= TOL["se"] for v in vals[2:])
    if model == "map":
        m, c = row.get("map_median_nm"), row.get("map_coverage")
        return m is not None and c is not None and m <= TOL["median"] and c >= TOL["coverage"] and row.get("order_hops") == 0
    return None


def run_calibration(case: str, out_dir: str) -> dict:
    truth = load_truth(case)
    cdir = os.path.join(DATA, case)
    runs = runs_dir(out_dir)
    os.makedirs(runs, exist_ok=True)
    js = os.path.join(runs, f"{case}_calibrate.json")
    if os.path.exists(js):
        os.remove(js)
    rc, err, wall = _cli(["calibrate", os.path.join(cdir, "before.png"), os.path.join(cdir, "after.png"),
                          "--json", js, "--debug-image", js.replace(".json", ".png"), "-q"])
    row = {"case": f"{case}:calibrate", "kind": "calibration", "model": "calibrate", "renderer": "mitsuba",
           "rc": rc, "wall_s": round(wall, 1), "refused": rc != 0}
    if rc != 0 or not os.path.exists(js):
        row["message"] = err
        row["pass"] = False
        return row
    with open(js) as fh:
        res = json.load(fh)
    t = _num(res.get("t"))
    ci = res.get("t_ci95")
    row["t"] = t
    row["t_err"] = t - truth["t"] if t is not None else None
    row["ok"] = res.get("ok")
    row["warnings"] = "; ".join(res.get("warnings", []) or [])[:200]
    inside = None
    if isinstance(ci, (list, tuple)) and len(ci) == 2 and t is not None:
        row["t_ci_lo"], row["t_ci_hi"] = float(ci[0]), float(ci[1])
        inside = ci[0] <= truth["t"] <= ci[1]
        row["t_err_se"] = _t_err_se_ci(row)
    row["t_in_ci"] = inside
    dc, dr = disc_error(res.get("bubble") or res.get("disc"), truth.get("disc"))
    row["disc_dc_px"], row["disc_dr_px"] = dc, dr
    row["pass"] = bool(inside) or (row["t_err"] is not None and abs(row["t_err"]) <= TOL["t_cal"])
    row["part"] = part_of(case)
    row["calibration_json"] = js
    return row


PROBES = os.path.join(REPO, "tests", "data", "probes")


def run_probe(stem: str, out_dir: str) -> dict:
    """`bubblefit envmap` on one mirror-ball probe: ball found vs true, map vs the true map."""
    with open(os.path.join(PROBES, "probes_truth.json")) as fh:
        truth = json.load(fh)
    pt = truth["probes"][stem]
    runs = os.path.join(out_dir, "runs")
    os.makedirs(runs, exist_ok=True)
    rows = []
    files = pt.get("files", [stem + ".png"])
    jobs = [(f, False) for f in files] + ([(files[0], True)] if pt["ball"] is not None else [])
    for f, given in jobs:
        out = os.path.join(runs, f"probe_{f.replace('.', '_')}" + ("_given" if given else ""))
        js = out + ".json"
        if os.path.exists(js):
            os.remove(js)
        args = ["envmap", os.path.join(PROBES, f), "-o", out + ".exr", "--json", js, "--mask", out + "_mask.png"]
        if pt.get("camera", {}).get("type") == "perspective":
            args += ["--distance", str(pt["camera"]["distance_radii"])]
        if given:
            b = pt["ball"]
            args += ["--ball", f"{b['cx']},{b['cy']},{b['r']}"]
        rc, err, wall = _cli(args, timeout=600)
        row = {"case": f"probe:{f}" + (":ball given" if given else ""), "kind": "probe", "model": "envmap", "renderer": "mitsuba", "rc": rc,
               "wall_s": round(wall, 1), "refused": rc != 0 or not os.path.exists(js)}
        if row["refused"]:
            row["message"] = err
            row["pass"] = pt["ball"] is None
            rows.append(row)
            continue
        with open(js) as fh:
            res = json.load(fh)
        if pt["ball"] is None:
            row["pass"] = False
            row["message"] = "found a ball in pure noise"
            rows.append(row)
            continue
        dc, dr = disc_error(res.get("ball"), pt["ball"])
        row["disc_dc_px"], row["disc_dr_px"] = dc, dr
        # map error: recovered map (camera frame) against the true map, texels the ball sampled
        try:
            rec = vio.read_image(out + ".exr")[..., :3]
            true = vio.read_image(os.path.join(REPO, truth["envmap"]))[..., :3]
            mask = vio.read_image(out + "_mask.png")[..., 0] > 0.5
            k = rec.shape[0] // true.shape[0]
            if k >= 1 and rec.shape[0] == k * true.shape[0]:
                rec = rec.reshape(true.shape[0], k, true.shape[1], k, 3).mean((1, 3))
                mask = mask.reshape(true.shape[0], k, true.shape[1], k).all((1, 3))
                scale = 1.0 if f.endswith(".exr") else pt["png_exposure"]
                lum = lambda a: a @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
                lr, lt = lum(rec) / scale, lum(true)
                good = mask & (lt > 1e-3) & (lr > 0) & (lum(rec) < 0.95)
                if good.any():
                    row["map_log_err_median"] = float(np.median(np.abs(np.log(lr[good] / lt[good]))))
                    row["map_texels"] = int(good.sum())
        except Exception as e:  # noqa: BLE001
            row["message"] = f"map not compared: {e}"
        row["pass"] = dc is not None and dc <= 2.0 and abs(dr) <= 2.0
        if given:  # the unwrap alone: no target, reported (the error includes the 120-px ball's blur)
            row["pass"] = None
        rows.append(row)
    return rows


def run_film(case: str, out_dir: str, fit: str | None = None) -> dict:
    """Fit a flat film, a gap (reference_films.py, make_films_cycles.py) or a bubble on a dish
    (make_films_cycles.py cyc_cap_*) through the CLI and score it.

    ``fit``: the thickness model (``--thickness``; the case's first by default). Pass: a
    constant within TOL["constant"]; drainage ends within TOL["se"] standard errors; a
    map (and the map a profile gives) with median error <= 15 nm, >= 90 % of the film
    within 15 nm and no order hops; for Newton's rings also R within 1 % and the gap
    within 5 % (5 nm at the contact) up to 1.5 um."""
    truth = load_truth(case)
    fit = fit or truth["fits"][0]
    cdir = os.path.join(DATA, case)
    runs = os.path.join(out_dir, "runs")
    os.makedirs(runs, exist_ok=True)
    prefix = os.path.join(runs, f"{case}_{fit}")
    args = [a if a != "scene.toml" else os.path.join(cdir, "scene.toml") for a in truth["fit_args"]]
    if fit in ("constant", "drainage", "map"):
        args += ["--thickness", fit]
    if "cap" in truth and str(truth.get("renderer", "")).startswith("Blender"):
        # the dish scenes state their maps' convention; --mitsuba-rows overrides it
        args += ["--envmap-convention", "texel-centre" if CYCLES_TEXEL_CENTRES else "mitsuba"]
    rc, err, wall = _cli(["fit", os.path.join(cdir, "photo.png"), *args, "-o", prefix, "--json", prefix + ".json"])
    row = {"case": f"{case}:{fit}", "kind": "film", "wall_s": round(wall, 1), "part": part_of(case)}
    if rc != 0:
        row.update({"pass": False, "message": err})
        return row
    with open(prefix + ".json") as fh:
        res = json.load(fh)
    import vio

    fit_map = vio.read_image(prefix + "_thickness.exr")[..., 0]
    true_map = vio.read_image(os.path.join(cdir, "thickness_true.exr"))[..., 0]
    h, w = true_map.shape
    m = map_metrics(fit_map, true_map, {"cx": w / 2, "cy": h / 2, "r": 10 * (h + w) / INNER})
    row.update(m, ok=res.get("ok"), reduced_chi2=res.get("reduced_chi2"), chi2_floor=res.get("reduced_chi2_floor"),
               chi2_inliers=res.get("reduced_chi2_inliers"), outliers=res.get("outlier_fraction"))
    p, se = res.get("params", {}), res.get("stderr", {})
    if fit == "constant":
        e = p["thickness_nm"] - truth["thickness_nm"]
        row.update(d_err_nm=e, d_err_se=e / se["thickness_nm"])
        good = abs(e) <= TOL["constant"]
    elif fit == "drainage":
        for end in ("top", "bottom"):
            e = p[f"{end}_nm"] - truth[f"{end}_nm"]
            row.update({f"{end}_err_nm": e, f"{end}_err_se": e / se[f"{end}_nm"]})
        good = all(abs(row[f"{k}_err_se"]) <= TOL["se"] for k in ("top", "bottom"))
        good = good and m["map_median_nm"] <= TOL["median"] and m["map_coverage"] >= TOL["coverage"]
    else:
        good = (m["map_median_nm"] is not None and m["map_median_nm"] <= TOL["median"]
                and m["map_coverage"] >= TOL["coverage"] and m["order_hops"] == 0)
    if "radius_mm" in truth:
        r_err = res["params"]["radius_mm"] / truth["radius_mm"] - 1
        near = true_map <= 1500.0
        gap_ok = bool(np.all(np.abs(fit_map - true_map)[near] <= np.maximum(0.05 * true_map[near], 5.0)))
        row.update(radius_err_rel=r_err, gap_within_5pct=gap_ok)
        good = good and abs(r_err) < 0.01 and gap_ok
    row["pass"] = bool(good and res.get("ok"))
    return row


def jobs_for(case: str) -> list[tuple]:
    truth = load_truth(case)
    if truth.get("kind") == "calibration":
        return [("cal", case)]
    if truth.get("kind") == "film":
        return [("film", case, m) for m in truth.get("fits", ["map"]) if not ONLY_FITS or m in ONLY_FITS]
    return [("fit", case, m) for m in truth.get("fits", ["constant"]) if not ONLY_FITS or m in ONLY_FITS]


COLUMNS = ["case", "part", "pass", "ok", "converged", "refused", "d_err_nm", "d_err_se", "top_err_nm", "top_err_se",
           "bottom_err_nm", "bottom_err_se", "map_median_nm", "map_p90_nm", "map_coverage", "map_cover_3se", "order_hops", "t",
           "t_err", "t_err_se", "t_in_ci", "disc_dc_px", "disc_dr_px", "model_kept", "reduced_chi2", "chi2_floor", "chi2_inliers",
           "outliers", "map_log_err_median", "time_s", "wall_s"]
SHORT = {"d_err_nm": "d err", "d_err_se": "d/se", "top_err_nm": "top err", "top_err_se": "top/se",
         "bottom_err_nm": "bot err", "bottom_err_se": "bot/se", "map_median_nm": "map med", "map_p90_nm": "map p90",
         "map_coverage": "cover", "map_cover_3se": "map in 3se", "order_hops": "hops", "t_err_se": "t/se", "t_in_ci": "t in CI", "disc_dc_px": "disc dc",
         "disc_dr_px": "disc dr", "model_kept": "model", "reduced_chi2": "chi2r", "chi2_floor": "chi2 floor",
         "chi2_inliers": "chi2 in", "outliers": "outl", "map_log_err_median": "probe |log|", "converged": "conv", "refused": "refused"}


def fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4f}" if abs(v) < 1.5 else f"{v:.1f}"
    return str(v)


def table(rows: list[dict], markdown: bool = False) -> str:
    cols = COLUMNS
    head = [SHORT.get(c, c) for c in cols]
    body = [[fmt(r.get(c)) for c in cols] for r in rows]
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in cols) + "|"]
        lines += ["| " + " | ".join(b) + " |" for b in body]
        return "\n".join(lines)
    w = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w[i]) for i, h in enumerate(head))]
    lines += ["  ".join(b[i].ljust(w[i]) for i in range(len(cols))) for b in body]
    return "\n".join(lines)


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, vals, colors = [], [], []
    for r in rows:
        v = None
        if r.get("d_err_nm") is not None:
            v = abs(r["d_err_nm"]) / TOL["constant"]
        elif r.get("top_err_nm") is not None:
            v = max(abs(r["top_err_nm"]) / TOL["top"], abs(r.get("bottom_err_nm") or 0) / TOL["bottom"])
        elif r.get("map_median_nm") is not None:
            v = r["map_median_nm"] / TOL["median"]
        elif r.get("kind") == "calibration" and r.get("t_err") is not None:
            v = abs(r["t_err"]) / TOL["t_cal"]
        elif r.get("kind") == "negative":
            v = 0.0 if r.get("pass") else 2.0
        names.append(r["case"])
        vals.append(np.nan if v is None else min(v, 10.0))
        colors.append("tab:green" if r.get("pass") else ("tab:red" if r.get("pass") is False else "tab:gray"))
    fig, ax = plt.subplots(figsize=(8, 0.32 * len(rows) + 1.2))
    y = np.arange(len(rows))
    ax.barh(y, vals, color=colors)
    ax.axvline(1.0, color="k", lw=1, ls="--")
    ax.set_yticks(y, names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("|error| / target tolerance (capped at 10; negatives: 0 caught, 2 missed)")
    ax.set_title("bubblefit on the independent validation set")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summarise(rows: list[dict]) -> list[dict]:
    """Per part: fits, targets met, `ok` on the positives, coverage within COVER_SE."""
    out = []
    for part in PARTS + ("unassigned",):
        rs = [r for r in rows if r.get("part") == part]
        if not rs:
            continue
        judged = [r for r in rs if r.get("pass") is not None]
        pos = [r for r in rs if r.get("kind") == "positive"]
        cal = [r for r in rs if r.get("kind") == "calibration"]
        explained = [r for r in pos if r.get("ok") is True and (r.get("chi2_floor") or math.inf) <= 3.0]
        out.append({"part": part, "fits": len(rs), "judged": len(judged),
                    "pass": sum(bool(r.get("pass")) for r in judged),
                    "positives": len(pos), "ok": sum(r.get("ok") is True for r in pos),
                    "explained": len(explained),
                    "cov_n": sum(r.get("cov_n", 0) for r in rs), "cov_in": sum(r.get("cov_in", 0) for r in rs),
                    "t_n": sum(r.get("t_err_se") is not None for r in pos + cal),
                    "t_in": sum(r.get("t_err_se") is not None and abs(r["t_err_se"]) <= COVER_SE for r in pos + cal),
                    "negatives": sum(r.get("kind") == "negative" for r in rs),
                    "negatives_caught": sum(r.get("kind") == "negative" and bool(r.get("pass")) for r in rs)})
    return out


def summary_table(summary: list[dict]) -> str:
    lines = ["| part | fits | targets met | positives ok | thicknesses within 3 SE | t within 3 SE | negatives caught |",
             "|---|---|---|---|---|---|---|"]
    for s in summary:
        t_cov = f"{s['t_in']} / {s['t_n']}" if s.get("t_n") else "-"
        lines.append(f"| {s['part']} | {s['fits']} | {s['pass']} / {s['judged']} | {s['ok']} / {s['positives']} | "
                     f"{s['cov_in']} / {s['cov_n']} | {t_cov} | {s['negatives_caught']} / {s['negatives']} |")
    return "\n".join(lines)


def write_outputs(rows: list[dict], out: str) -> None:
    with open(os.path.join(out, "results.csv"), "w", newline="") as fh:
        keys = COLUMNS + sorted({k for r in rows for k in r} - set(COLUMNS))
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        for r in rows:
            wr.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
    split = load_split()
    for r in rows:
        r.setdefault("part", part_of(r["case"], split))
    summary = summarise(rows)
    vio.save_json(os.path.join(out, "results.json"), {"tolerances": TOL, "inner_disc_fraction": INNER,
                                                      "coverage_nm": COVER_NM, "coverage_se": COVER_SE,
                                                      "hop_nm": HOP_NM, "summary": summary, "rows": rows})
    with open(os.path.join(out, "results.md"), "w") as fh:
        fh.write("## Summary per part (split.toml)\n\n" + summary_table(summary) + "\n")
        for part in PARTS + ("unassigned",):
            rs = [r for r in rows if r.get("part") == part]
            if rs:
                fh.write(f"\n## {part}\n\n" + table(rs, markdown=True) + "\n")
    plot(rows, os.path.join(out, "validation.png"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*", help="case folders under data/ (default: all)")
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    ap.add_argument("--out", default=DEFAULT_OUT)
    ap.add_argument("--probes", action="store_true", help="also run `bubblefit envmap` on tests/data/probes/")
    ap.add_argument("--probes-only", action="store_true", help="only the probes")
    ap.add_argument("--merge", nargs="+", metavar="DIR",
                    help="no runs: merge the results.json of earlier runs (first one wins per row) into --out")
    ap.add_argument("--disc-given", action="store_true",
                    help="hand bubblefit the true disc (--disc) in orthographic cases: separates detection from fitting")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds allowed per bubblefit command [900]")
    ap.add_argument("--fit-args", default="", help="extra arguments for every `bubblefit fit`, e.g. '--model physical'")
    ap.add_argument("--only", default="", help="comma-separated thickness models to run, e.g. 'drainage'")
    ap.add_argument("--no-cross", action="store_true", help="skip the fit that is handed another framing's calibration")
    ap.add_argument("--data", help="another folder of cases (and its envmaps/), e.g. make_reference.py --size's; "
                    "its cases are in no part of the split")
    ap.add_argument("--mitsuba-rows", action="store_true",
                    help="read the Blender cases' maps on bubblefit's default rows, not at their texel centres")
    ap.add_argument("--spectral-film", action="store_true",
                    help="fit the Blender cases' films with the spectral film, not clamped as Cycles colours them")
    ap.add_argument("--part", choices=PARTS, help="only the cases of this part of split.toml")
    ap.add_argument("--runs", help="folder for each fit's JSON and images [OUT/runs]")
    a = ap.parse_args(argv)
    EXTRA_FIT_ARGS[:] = a.fit_args.split()
    RUNS_DIR[:] = [a.runs] if a.runs else []
    ONLY_FITS[:] = [m for m in a.only.split(",") if m]
    global FIT_TIMEOUT, DATA, CYCLES_TEXEL_CENTRES, CYCLES_FILM_RGB
    FIT_TIMEOUT = a.timeout
    CYCLES_TEXEL_CENTRES = not a.mitsuba_rows
    CYCLES_FILM_RGB = not a.spectral_film
    if a.data:
        DATA = os.path.abspath(a.data)
    if a.merge:
        rows, seen = [], set()
        missing = [d for d in a.merge if not os.path.isfile(os.path.join(d, "results.json"))]
        if missing:
            print(f"validate.py: no results.json in {', '.join(missing)}", file=sys.stderr)
            return 2
        for d in a.merge:
            with open(os.path.join(d, "results.json")) as fh:
                for r in json.load(fh)["rows"]:
                    if r["case"] not in seen:
                        seen.add(r["case"])
                        if r.get("kind") == "probe" and r["case"].endswith("ball given"):
                            r["pass"] = None      # the unwrap alone has no target
                        if "cov_n" not in r:
                            r.update(coverage(r))
                        if r.get("t_err") is not None and r.get("t_err_se") is None:
                            if r.get("kind") == "calibration":
                                r["t_err_se"] = _t_err_se_ci(r)
                            else:
                                _rescore_t(d, r)
                        rows.append(r)
        os.makedirs(a.out, exist_ok=True)
        write_outputs(rows, a.out)
        print(table(rows))
        return 0
    cases = [] if a.probes_only else (a.cases or (QUICK if a.quick else list_cases()))
    if a.part:
        split = load_split()
        cases = [c for c in cases if part_of(c, split) == a.part]
    os.makedirs(a.out, exist_ok=True)
    rows = []
    if a.probes or a.probes_only:
        with open(os.path.join(PROBES, "probes_truth.json")) as fh:
            for stem in json.load(fh)["probes"]:
                for row in run_probe(stem, a.out):
                    rows.append(row)
                    print(f"{row['case']}: pass={fmt(row.get('pass'))} ball dc={fmt(row.get('disc_dc_px'))} "
                          f"dr={fmt(row.get('disc_dr_px'))} map |log| median={fmt(row.get('map_log_err_median'))}"
                          + (f" [{row.get('message')}]" if row.get("message") else ""), flush=True)
    for case in cases:
        if case not in list_cases():
            print(f"unknown case {case}", file=sys.stderr)
            return 2
        for job in jobs_for(case):
            if job[0] == "cal":
                row = run_calibration(job[1], a.out)
            elif job[0] == "film":
                row = run_film(job[1], a.out, job[2])
            else:
                given = a.disc_given and load_truth(job[1]).get("camera", {}).get("type") == "orthographic"
                row = run_fit(job[1], job[2], a.out, disc_given=given)
            rows.append(row)
            write_outputs(rows, a.out)
            print(f"{row['case']}: pass={fmt(row.get('pass'))} ok={fmt(row.get('ok'))} wall {row['wall_s']} s"
                  + (f" [{row.get('message')}]" if row.get("message") else ""), flush=True)
    # a fit handed the calibration of another framing (512x384) must not reuse its disc
    cal_rows = {r["case"].split(":")[0]: r for r in rows if r.get("kind") == "calibration"}
    if not a.no_cross and "cal_box_512x384_offc" in cal_rows and "ref_const300_courtyard_ortho" in cases \
            and cal_rows["cal_box_512x384_offc"].get("calibration_json"):
        row = run_fit("ref_const300_courtyard_ortho", "constant", a.out,
                      calibration=cal_rows["cal_box_512x384_offc"]["calibration_json"],
                      tag="xcal_ref_const300_with_cal512:constant")
        row["kind"] = "cross-calibration"
        rows.append(row)
        print(f"{row['case']}: pass={fmt(row.get('pass'))} disc dc={fmt(row.get('disc_dc_px'))}", flush=True)
    write_outputs(rows, a.out)
    print()
    print(table(rows))
    print()
    print(summary_table(summarise(rows)))
    print(f"\nwrote {a.out}/results.csv, results.json, results.md, validation.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
