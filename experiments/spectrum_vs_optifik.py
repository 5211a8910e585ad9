"""bubblefit fit-spectrum against optifik on the same synthetic spectrometer readings.

optifik (Ziapkoff, Boulogne, Salonen & Rio, Eur. Phys. J. E 49, 4 (2026); on PyPI) is
the field's tool: fringe extrema ("min-max", a linear fit of the extrema's ``n/lambda``
against their index) for films with fringes, Scheludko's intensity formula for thin ones.
bubblefit does not depend on it; it is run here in its own virtual environment, in a
subprocess (``--optifik-python``, default ``.venv-optifik/bin/python``).

The readings are synthesised by numpy code in this file (Airy reflectance of a film in
air with the soap-solution index law, under a halogen-like lamp, convolved with the
spectrometer's resolution, with stray light, a dark offset and noise), over thicknesses
from 80 nm (order 0) to 10 um and conditions: clean, noisy, very noisy, stray light and
dark offset, coarse resolution, a steep cold lamp, and a reference reading given.
optifik's pipeline is the one its documentation shows: Savitzky-Golay smoothing, then
min-max when at least four extrema are found, else Scheludko with the order searched,
else Scheludko at order 0 with the dark as the void intensity. Both get the true index
law, and, when a reference is given, optifik reads ``(I - dark) / (ref - dark)``.

A result *fails* when it is missing or off by more than max(10 nm, 2%). For bubblefit
the failures are split into flagged (``ok: false``, the user is told) and silent.
Prints a table, writes ``experiments/results/spectrum_vs_optifik.{csv,json,png}``.

Usage: ``PYTHONPATH=. python experiments/spectrum_vs_optifik.py [--seeds 3] [--quick]``
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
THICKNESSES = (80.0, 150.0, 300.0, 600.0, 1200.0, 2500.0, 5000.0, 10000.0)
CONDITIONS = {
    # name: noise (of the peak), stray (of the peak), dark offset, resolution FWHM nm, lamp T (K), reference
    "clean": dict(noise=0.002, stray=0.0, dark=0.0, fwhm=0.5, temperature=3000.0, reference=False),
    "noisy": dict(noise=0.01, stray=0.0, dark=0.0, fwhm=0.5, temperature=3000.0, reference=False),
    "very_noisy": dict(noise=0.04, stray=0.0, dark=0.0, fwhm=0.5, temperature=3000.0, reference=False),
    "stray_dark": dict(noise=0.01, stray=0.15, dark=0.05, fwhm=0.5, temperature=3000.0, reference=False),
    "resolution_3nm": dict(noise=0.01, stray=0.0, dark=0.0, fwhm=3.0, temperature=3000.0, reference=False),
    "cold_lamp": dict(noise=0.01, stray=0.02, dark=0.02, fwhm=1.0, temperature=2200.0, reference=False),
    "with_reference": dict(noise=0.01, stray=0.02, dark=0.02, fwhm=1.0, temperature=3000.0, reference=True),
}


def soap_index(lam):
    return 1.324188 + 3102.06 / lam**2


def airy(d, lam, n):
    """Airy reflectance of a lossless film in air at normal incidence (Born & Wolf 7.6(13))."""
    r1 = ((n - 1.0) / (n + 1.0)) ** 2
    f = 4.0 * r1 / (1.0 - r1) ** 2
    s = np.sin(2.0 * np.pi * n * d / lam) ** 2
    return f * s / (1.0 + f * s)


def lamp(lam, temperature):
    """Planck's law at ``temperature`` times a Gaussian spectrometer response, peak 1."""
    h, c, k = 6.62607e-34, 2.99792e8, 1.380649e-23
    m = lam * 1e-9
    v = 1.0 / (m**5 * (np.exp(h * c / (m * k * temperature)) - 1.0)) * np.exp(-0.5 * ((lam - 600.0) / 150.0) ** 2)
    return v / v.max()


def synth(d, cond, seed, lo=400.0, hi=800.0, step=0.5):
    rng = np.random.default_rng(seed)
    lam = np.arange(lo, hi + 1e-9, step)
    fine = np.arange(lo - 15.0, hi + 15.0, 0.02)
    s = lamp(fine, cond["temperature"]) * airy(d, fine, soap_index(fine))
    sig = cond["fwhm"] / 2.35482
    m = int(5 * sig / 0.02)
    g = np.exp(-0.5 * (np.arange(-m, m + 1) * 0.02 / sig) ** 2)
    s = np.convolve(s, g / g.sum(), mode="same")
    y = np.interp(lam, fine, s)
    peak = y.max()
    y = y + cond["stray"] * peak + cond["dark"] + cond["noise"] * peak * rng.standard_normal(lam.shape)
    ref = lamp(lam, cond["temperature"]) + cond["dark"] + 0.002 * rng.standard_normal(lam.shape)
    return lam, y, ref, np.full_like(lam, cond["dark"])


def optifik_worker(inp: str, out: str) -> None:
    """Runs inside optifik's environment: thickness (or NaN) for each spectrum of ``inp``."""
    import warnings

    import optifik.analysis as an
    import optifik.minmax as mm
    import optifik.scheludko as sch

    warnings.simplefilter("ignore")
    data = np.load(inp)
    res = []
    for i in range(len(data["d"])):
        lam, y, dark = data["lam"][i], data["y"][i], data["dark"][i]
        sig = y - dark
        if data["use_ref"][i]:
            sig = sig / np.maximum(data["ref"][i] - dark, 1e-6)
        sig = sig / np.max(sig)
        n = soap_index(lam)
        t0 = time.perf_counter()
        thick, method = np.nan, "none"
        try:
            sm = an.smooth_intensities(sig)
            pmin, pmax = an.finds_peak(lam, sm, min_peak_prominence=0.02)
            if len(pmin) + len(pmax) >= 4:
                thick, method = float(mm.thickness_from_minmax(lam, sm, n, min_peak_prominence=0.02).thickness), "minmax"
            else:
                try:
                    start, stop = sch.get_default_start_stop_wavelengths(lam, sm, n, min_peak_prominence=0.02)
                    r = sch.thickness_from_scheludko(lam, sm, n, wavelength_start=start, wavelength_stop=stop)
                    thick, method = float(r.thickness), "scheludko"
                except Exception:
                    void = np.zeros_like(sm)
                    r = sch.thickness_from_scheludko(lam, sm, n, interference_order=0, intensities_void=void)
                    thick, method = float(r.thickness), "scheludko0"
        except Exception as exc:  # noqa: BLE001 - a failure of the peer is a data point
            method = f"error: {type(exc).__name__}"
        res.append({"thickness_nm": thick, "method": method, "time_s": time.perf_counter() - t0})
    Path(out).write_text(json.dumps(res))


def run_optifik(cases, python: str) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        inp, out = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.json")
        np.savez(inp, d=[c["d"] for c in cases], lam=np.stack([c["lam"] for c in cases]),
                 y=np.stack([c["y"] for c in cases]), ref=np.stack([c["ref"] for c in cases]),
                 dark=np.stack([c["dark"] for c in cases]), use_ref=[c["use_ref"] for c in cases])
        subprocess.run([python, __file__, "--optifik-worker", inp, out], check=True)
        return json.loads(Path(out).read_text())


def run_bubblefit(case) -> dict:
    from bubblefit.inverse.spectrum import fit_spectrum
    from bubblefit.io.spectra import Spectrum

    lam = case["lam"]
    ref = Spectrum(lam, case["ref"]) if case["use_ref"] else None
    t0 = time.perf_counter()
    r = fit_spectrum(Spectrum(lam, case["y"]), dark=Spectrum(lam, case["dark"]), reference=ref)
    return {"thickness_nm": r.thickness_nm, "stderr": r.thickness_nm_stderr, "ok": r.ok,
            "time_s": time.perf_counter() - t0, "reasons": r.reasons}


def failed(d, est) -> bool:
    return not np.isfinite(est) or abs(est - d) > max(10.0, 0.02 * d)


def summarise(rows):
    table = {}
    for cond in CONDITIONS:
        sub = [r for r in rows if r["condition"] == cond]
        if not sub:
            continue
        bf_fail = [failed(r["d"], r["bf"]) for r in sub]
        of_fail = [failed(r["d"], r["of"]) for r in sub]
        silent = [f and r["bf_ok"] for f, r in zip(bf_fail, sub)]
        ok_err = [abs(r["bf"] - r["d"]) for r, f in zip(sub, bf_fail) if not f]
        of_err = [abs(r["of"] - r["d"]) for r, f in zip(sub, of_fail) if not f]
        table[cond] = {
            "cases": len(sub),
            "bubblefit_fail_rate": float(np.mean(bf_fail)), "bubblefit_silent_fail_rate": float(np.mean(silent)),
            "bubblefit_flagged_rate": float(np.mean([not r["bf_ok"] for r in sub])),
            "bubblefit_median_abs_err_nm": float(np.median(ok_err)) if ok_err else float("nan"),
            "optifik_fail_rate": float(np.mean(of_fail)),
            "optifik_median_abs_err_nm": float(np.median(of_err)) if of_err else float("nan"),
        }
    return table


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    for k, (key, label, marker) in enumerate([("bf", "bubblefit", "o"), ("of", "optifik", "x")]):
        d = np.array([r["d"] for r in rows])
        e = np.array([abs(r[key] - r["d"]) if np.isfinite(r[key]) else np.nan for r in rows])
        jitter = d * (1 + 0.04 * (k - 0.5))
        ax[0].loglog(jitter, np.maximum(e, 1e-3), marker, ms=4, alpha=0.6, label=label)
    ax[0].axhline(10, color="k", lw=0.5, ls="--")
    ax[0].set_xlabel("true thickness (nm)")
    ax[0].set_ylabel("|error| (nm); missing = not shown")
    ax[0].legend()
    table = summarise(rows)
    names = list(table)
    x = np.arange(len(names))
    ax[1].bar(x - 0.2, [table[c]["bubblefit_silent_fail_rate"] for c in names], 0.2, label="bubblefit silent fail")
    ax[1].bar(x, [table[c]["bubblefit_fail_rate"] for c in names], 0.2, label="bubblefit fail (incl. flagged)")
    ax[1].bar(x + 0.2, [table[c]["optifik_fail_rate"] for c in names], 0.2, label="optifik fail")
    ax[1].set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    ax[1].set_ylabel("failure rate")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="one seed, four thicknesses")
    ap.add_argument("--optifik-python", default=".venv-optifik/bin/python")
    ap.add_argument("--optifik-worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.optifik_worker:
        return optifik_worker(*args.optifik_worker)
    thicknesses = THICKNESSES[::2] if args.quick else THICKNESSES
    seeds = 1 if args.quick else args.seeds
    cases = []
    for cname, cond in CONDITIONS.items():
        for d in thicknesses:
            for s in range(seeds):
                lam, y, ref, dark = synth(d, cond, seed=1000 * s + int(d))
                cases.append(dict(condition=cname, d=d, seed=s, lam=lam, y=y, ref=ref, dark=dark,
                                  use_ref=cond["reference"]))
    of = run_optifik(cases, args.optifik_python)
    rows = []
    for c, o in zip(cases, of):
        b = run_bubblefit(c)
        rows.append({"condition": c["condition"], "d": c["d"], "seed": c["seed"], "bf": b["thickness_nm"],
                     "bf_stderr": b["stderr"], "bf_ok": b["ok"], "bf_time_s": b["time_s"],
                     "bf_reasons": " | ".join(b["reasons"]), "of": o["thickness_nm"], "of_method": o["method"],
                     "of_time_s": o["time_s"]})
        print(f"{c['condition']:>15} d={c['d']:7.0f}  bubblefit {b['thickness_nm']:9.2f} +- {b['stderr']:.2g} "
              f"ok={b['ok']!s:5}  optifik {o['thickness_nm']:9.2f} ({o['method']})", flush=True)
    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / "spectrum_vs_optifik.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    table = summarise(rows)
    (RESULTS / "spectrum_vs_optifik.json").write_text(json.dumps({"summary": table, "rows": rows}, indent=1))
    plot(rows, RESULTS / "spectrum_vs_optifik.png")
    print(f"\n{'condition':>15} {'bf fail':>8} {'bf silent':>9} {'bf med err':>10} {'of fail':>8} {'of med err':>10}")
    for cname, t in table.items():
        print(f"{cname:>15} {t['bubblefit_fail_rate']:8.2f} {t['bubblefit_silent_fail_rate']:9.2f} "
              f"{t['bubblefit_median_abs_err_nm']:10.3f} {t['optifik_fail_rate']:8.2f} {t['optifik_median_abs_err_nm']:10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
