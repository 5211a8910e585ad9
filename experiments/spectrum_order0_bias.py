"""Where the order-0 readings of optifik's ``spectraVictor2`` get their bias under a held lamp.

The known order-0 readings (stated 124 -> 82 nm) read with the lamp and stray light held
from the order-1 readings that can be read alone (films of 186-243 nm, earlier in the
series) come out 2-5 % thicker than stated; ``bubblefit fit-spectrum`` reads them instead
with the series' own first maximum (:mod:`bubblefit.inverse._first_maximum`), and the
``fit-spectrum defaults`` row of the record is that reading. This experiment measures what
moves the held lamp's bias, on the readings themselves:

- the stated values' own method: the interferometric (Scheludko) reading of a draining
  film, ``Delta = (I - I_min) / (I_max - I_min)`` with ``I_max(lambda)`` the brightest the
  film reflects at each wavelength as it thins through the first maximum of ``R`` (the
  maximum over the series' readings from ``T12563`` on) and ``I_min`` the void reading or
  the black film (the series' last reading); ``Delta = R / R_max`` for a lossless film
  (Scheludko 1967; optifik's ``_Delta``; the Airy reflectance of
  :func:`bubblefit.inverse.spectrum.film_reflectance`);
- bubblefit's held lamp and stray light (from a ``fit-spectrum --json`` of the series):
  ``L R_max + S`` against the measured ``I_max``, and each reading read with that lamp
  scaled, or with the stray light replaced by the black film's reading;
- ``fit-spectrum`` runs with the stray light's tilt held at zero (``--background-terms 0``),
  a constant index, or the window >= 450 nm, given as further JSON files.

The readings are optifik's (GPL-3.0; not redistributed): pass its ``data`` folder.

Usage: ``python experiments/spectrum_order0_bias.py DATA_DIR BASE.json [LABEL=RUN.json ...]``
where ``BASE.json`` is ``bubblefit fit-spectrum --n-film soap --series-by one --json`` of
order-1 readings of 180 nm or more followed by the 34 known order-0 readings (run in
``DATA_DIR/spectraVictor2``). Writes ``experiments/results/spectrum_order0_bias.json``.
"""

from __future__ import annotations

import glob
import json
import os
import sys

import numpy as np
import yaml
from numpy.polynomial import legendre
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from bubblefit.inverse.spectrum import film_reflectance
from bubblefit.optics import dispersion


def stated(folder):
    """The stated thicknesses (nm) of the known order-0 readings (optifik's ``known_value*.yaml``)."""
    out = {}
    for name in ("known_value.yaml", "known_value_large_tol.yaml"):
        out.update(yaml.safe_load(open(os.path.join(folder, "order0", name))))
    return out


def summary(err):
    """Median signed and absolute relative error, and the range (as in ``spectrum_real.py``)."""
    e = np.asarray(err)
    return {"median_signed": float(np.median(e)), "median_abs": float(np.median(np.abs(e))),
            "min": float(e.min()), "max": float(e.max()), "n": int(len(e))}


def read(lam, n, y, lamp, stray):
    """The thickness (nm) at which ``lamp R(d) + stray`` fits ``y`` best (least squares; ``R`` the
    Airy reflectance, Born & Wolf 7.6(13), via :func:`bubblefit.inverse.spectrum.film_reflectance`)."""
    def res(p):
        return lamp * film_reflectance(np.array([p[0]]), lam, n)[0] + stray - y
    return min((least_squares(res, [d0]) for d0 in (70.0, 100.0, 130.0)), key=lambda s: s.cost).x[0]


def main(argv):
    """Measure each suspect (see the module) and write the record."""
    data, base, runs = argv[0], argv[1], argv[2:]
    folder = os.path.join(data, "spectraVictor2")
    known = stated(folder)
    files = sorted(glob.glob(os.path.join(folder, "order1", "*.xy")))
    seen = {os.path.basename(f) for f in files}
    files += [f for f in sorted(glob.glob(os.path.join(folder, "order0", "*.xy"))) if os.path.basename(f) not in seen]
    lam_all = np.loadtxt(files[0], delimiter=",")[:, 0]
    y_all = np.array([np.loadtxt(f, delimiter=",")[:, 1] for f in files])
    keep = (lam_all >= 450.0) & np.all(np.isfinite(y_all), axis=0)  # optifik's window
    lam = lam_all[keep]
    y = savgol_filter(y_all[:, keep], 11, 3, axis=1)  # optifik's smoothing
    n = dispersion.refractive_index("soap", lam)
    late = [i for i, f in enumerate(files) if os.path.basename(f) >= "T12563.xy"]
    i_max = y[late].max(axis=0)
    void = np.loadtxt(os.path.join(folder, "void.xy"), delimiter=",")
    zero = {"void": np.interp(lam, void[:, 0], void[:, 1]), "black film": y[-1]}
    r_max = np.max(film_reflectance(np.linspace(60.0, 160.0, 2001), lam, n), axis=0)  # R at the first maximum
    where = {os.path.basename(f): i for i, f in enumerate(files)}  # T14143 is in both folders
    names = sorted(known)
    out = {"readings": len(names)}
    for label, z in zero.items():
        err = [read(lam, n, y[where[k]], (i_max - z) / r_max, z) / known[k] - 1 for k in names]
        out[f"envelope method, zero = {label}"] = summary(err)
    sl = json.load(open(base))["shared_lamp"]
    lo, hi = sl["wavenumber_range_per_nm"]
    u = 2.0 * (1.0 / lam - lo) / (hi - lo) - 1.0
    lamp = legendre.legvander(u, len(sl["coefficients"]) - 1) @ np.array(sl["coefficients"])
    stray = legendre.legvander(u, len(sl["stray_coefficients"]) - 1) @ np.array(sl["stray_coefficients"])
    at = [450, 500, 550, 600, 650, 700, 750, 790]
    idx = [int(np.argmin(np.abs(lam - w))) for w in at]
    out["held lamp and stray light vs the readings"] = {
        "wavelength_nm": at,
        "measured first maximum I_max": [round(float(i_max[k]), 4) for k in idx],
        "held L R_max + S": [round(float(lamp[k] * r_max[k] + stray[k]), 4) for k in idx],
        "held stray light S": [round(float(stray[k]), 4) for k in idx],
        "black film (last reading)": [round(float(y[-1][k]), 4) for k in idx],
        "void reading": [round(float(zero["void"][k]), 4) for k in idx],
    }
    mins = {}
    for name in sl["pinning"]:
        k = where[os.path.basename(name)]
        j = int(np.argmin(y[k]))
        mins[name] = {"minimum": round(float(y[k][j]), 4), "at_nm": round(float(lam[j]), 1),
                      "held S there": round(float(stray[j]), 4)}
    out["pinning readings' fringe minimum (R = 0 there)"] = mins
    for label, lmp, s in (("held lamp and stray light (series' lamp of all pins)", lamp, stray),
                          ("held lamp x 1.08, held stray light", 1.08 * lamp, stray),
                          ("held lamp, stray light = black film", lamp, y[-1]),
                          ("envelope lamp (I_max - S) / R_max, held stray light", (i_max - stray) / r_max, stray)):
        out[label] = summary([read(lam, n, y[where[k]], lmp, s) / known[k] - 1 for k in names])
    for spec in [f"fit-spectrum defaults={base}"] + runs:
        label, path = spec.split("=", 1)
        res = [r for r in json.load(open(path))["spectra"] if r["file"].startswith("order0/") and os.path.basename(r["file"]) in known]
        s = summary([r["thickness_nm"] / known[os.path.basename(r["file"])] - 1 for r in res]) if res else {}
        s["ok"] = sum(bool(r["ok"]) for r in res)
        out[label] = s
    os.makedirs("experiments/results", exist_ok=True)
    with open("experiments/results/spectrum_order0_bias.json", "w") as f:
        json.dump(out, f, indent=1)
    for k, v in out.items():
        if isinstance(v, dict) and "median_signed" in v:
            print(f"{k:60s} median {v['median_signed']:+.2%} (|.| {v['median_abs']:.2%}), {v['min']:+.1%}..{v['max']:+.1%}"
                  + (f", ok {v['ok']}" if "ok" in v else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
