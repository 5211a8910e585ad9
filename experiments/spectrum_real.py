"""bubblefit fit-spectrum against optifik on real spectrometer readings (optifik's own data).

The readings are the ``.xy`` files (``wavelength_nm,intensity``) of the optifik repository
(https://github.com/sciunto/optifik, folder ``data/``); pass that folder as ``DATA_DIR``.
They are not copied into bubblefit: optifik is GPL-3.0 and its data carry no licence of
their own. Thicknesses are "stated" where optifik's repository gives one for a file (its
``known_value*.yaml`` / ``known_to_fail.yaml`` / ``sample*.yaml`` files and the constants
of its tests); those values are the field's own readings of these spectra (mostly made
with optifik or its predecessor), not an independent truth.

For each stated file both tools get the index optifik's reference uses (the soap law
``1.324188 + 3102.060378/lambda^2``, or 1.33 where the yaml says so) and the wavelengths
>= 450 nm (as optifik's tests load them; non-finite rows dropped). optifik runs, in its own
virtual environment (``--optifik-python``), (a) the method its test or yaml uses for that
group ("ref": min-max linreg or RANSAC, Scheludko with the order searched, Scheludko at
order 0 with the void reading, or FFT) and (b) the automatic pipeline of
``spectrum_vs_optifik.py`` ("auto"). bubblefit runs ``fit_spectrum`` as the CLI does by
default (unknown smooth lamp) and, for the groups whose readings are already divided by
the lamp (``basic``, ``spectraVictor*``: a flat envelope near 1), also as such readings
are meant to be read ("normalised", i.e. ``--normalised``: a 3-term lamp and a tilted
stray light). (Before issue 18 was closed the second run was "flat":
``--reference FLAT --lamp-terms 3``.)

A separate, larger set without stated values: every ``--stride``-th reading of the
``spectraManue/sample3`` time series (n = 1.33), where the thickness drains smoothly;
there the smoothness (median |difference| of consecutive readings) and the agreement of
the tools are reported.

A result *fails* against a stated value when it is missing or off by more than 10 %
(optifik's tests mostly use ``rtol=0.1``). Prints a table, writes
``experiments/results/spectrum_real.{json,png}``.

``--whole-range`` gives bubblefit the whole reading, as ``bubblefit fit-spectrum`` reads it
by default (optifik keeps >= 450 nm: its methods need the clean part); on the Lorene and
Manue readings the first 50 nm are a lamp-divided reading where the lamp is dark, jumping
between 0 and the ceiling.

The column "bubblefit defaults" is ``bubblefit fit-spectrum`` run as a new user runs it, with
no switch but the film's index: each group's files given together (whole readings, the
void reading as ``--dark`` where there is one), so that the command decides whether they
were divided by the lamp, whether they form one series (and reads them with its shared
lamp), and uses their time order (the file names) against jumps to a twin. Each row also
carries the extrema phase test (:mod:`bubblefit.inverse._spectrum_extrema`) of the stated
value and of the defaults' value; a stated value is marked in doubt when it scores worse
than 0.2 where the defaults' value scores better than 0.1.

Usage: ``PYTHONPATH=. python experiments/spectrum_real.py DATA_DIR [--optifik-python PY]
[--stride 25] [--quick] [--groups G1,G2] [--whole-range]``
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
WMIN = 450.0
SOAP = "soap"  # 1.324188 + 3102.060378 / lambda^2, bubblefit's preset of the same law

# group: (folder, yaml files, index, optifik reference method, prominence, lamp-normalised)
GROUPS = {
    "SV1": ("spectraVictor1", ["known_value.yaml"], SOAP, "minmax_linreg", 0.02, True),
    "SV2o0": ("spectraVictor2/order0", ["known_value_large_tol.yaml", "known_to_fail.yaml"], SOAP, "scheludko0", 0.02, True),
    "SV2o1": ("spectraVictor2/order1", ["known_value.yaml", "known_to_fail.yaml"], SOAP, "scheludko", 0.02, True),
    "SV2o2": ("spectraVictor2/order2", ["known_value.yaml"], SOAP, "scheludko", 0.01, True),
    "SV2o3": ("spectraVictor2/order3", ["known_value.yaml"], SOAP, "scheludko", 0.02, True),
    "SV2o4": ("spectraVictor2/order4", ["known_value.yaml"], SOAP, "scheludko", 0.02, True),
    "SV2o5": ("spectraVictor2/order5", ["known_value.yaml"], SOAP, "scheludko", 0.02, True),
    "lorene1": ("spectraLorene/sample1", ["sample1.yaml"], 1.33, "minmax_ransac", 0.02, False),
    "lorene2": ("spectraLorene/sample2", ["sample2.yaml"], 1.33, "fft", 0.02, False),
    "manue3": ("spectraManue/sample3", ["../sample3.yaml"], 1.33, "minmax_ransac", 0.02, False),
}
# the single files of optifik's tests/test_minmax.py, test_scheludko.py and test_fft.py
BASIC = [
    ("basic/000004310.xy", 1338.35, "minmax_linreg", 0.02),
    ("basic/000005253.xy", 777.07, "scheludko", 0.02),
    ("basic/000006544.xy", 495.69, "scheludko", 0.03),
    ("basic/000018918.xy", 115.33, "scheludko0", 0.03),
    ("basic/003582.xy", 3524.51, "fft", 0.02),
]
VOID = {"basic": "basic/void.xy", "SV2o0": "spectraVictor2/void.xy"}
_ENTRY = re.compile(r"^\s*([^#\s:]+\.xy)\s*:\s*([-+0-9.eE]+)\s*$")


def soap_index(lam):
    return 1.324188 + 3102.060378 / lam**2


def stated_values(path: Path) -> dict[str, float]:
    """``name.xy: value`` entries of an optifik yaml (commented-out ones skipped)."""
    out = {}
    for line in path.read_text().splitlines():
        m = _ENTRY.match(line)
        if m:
            out[m.group(1)] = float(m.group(2))
    return out


def load(path: Path, wmin: float = WMIN):
    """Wavelengths >= ``wmin`` and intensities, non-finite rows dropped."""
    lam, y = np.loadtxt(path, delimiter=",", ndmin=2).T
    keep = np.isfinite(lam) & np.isfinite(y) & (lam >= wmin)
    return lam[keep], y[keep]


def build_cases(data: Path, stride: int, quick: bool) -> list[dict]:
    cases = []
    for rel, val, method, prom in BASIC:
        cases.append(dict(group="basic", file=rel, expected=val, n=SOAP, method=method, prom=prom,
                          void=VOID["basic"] if method == "scheludko0" else None, normalised=rel != "basic/003582.xy",
                          thickness_max=15000.0))
    for g, (folder, yamls, n, method, prom, normalised) in GROUPS.items():
        vals = {}
        for y in yamls:
            vals.update(stated_values((data / folder / y).resolve()))
        names = sorted(vals)
        if quick:
            names = names[:: max(1, len(names) // 3)][:3]
        for name in names:
            cases.append(dict(group=g, file=f"{folder}/{name}", expected=vals[name], n=n, method=method, prom=prom,
                              void=VOID.get(g), normalised=normalised,
                              thickness_max=50000.0 if g == "lorene2" else 15000.0))
    files = sorted(p.name for p in (data / "spectraManue/sample3").glob("*.xy"))
    for name in files[:: stride * (4 if quick else 1)]:
        cases.append(dict(group="series_manue3", file=f"spectraManue/sample3/{name}", expected=None, n=1.33,
                          method="minmax_ransac", prom=0.02, void=None, normalised=False, thickness_max=15000.0))
    return cases


# ----------------------------------------------------------------------------- optifik
def optifik_worker(inp: str, out: str) -> None:
    """Runs inside optifik's environment: reference-method and automatic results per case."""
    import warnings

    import optifik.analysis as an
    import optifik.fft as ff
    import optifik.minmax as mm
    import optifik.scheludko as sch

    warnings.simplefilter("ignore")
    spec = json.loads(Path(inp).read_text())
    data = Path(spec["data"])

    def reference(c, lam, sm, n):
        m, prom = c["method"], c["prom"]
        if m.startswith("minmax"):
            kw = dict(min_peak_distance=10) if m == "minmax_ransac" else {}
            return mm.thickness_from_minmax(lam, sm, n, min_peak_prominence=prom, method=m.split("_")[1], **kw).thickness
        if m == "scheludko":
            start, stop = sch.get_default_start_stop_wavelengths(lam, sm, n, min_peak_prominence=prom)
            return sch.thickness_from_scheludko(lam, sm, n, wavelength_start=start, wavelength_stop=stop).thickness
        if m == "scheludko0":
            _, void = load(data / c["void"])
            return sch.thickness_from_scheludko(lam, sm, n, interference_order=0, intensities_void=void).thickness
        if m == "fft":
            return ff.thickness_from_fft(lam, sm, n).thickness
        raise ValueError(m)

    def auto(lam, sm, n):
        # the pipeline of experiments/spectrum_vs_optifik.py, on the reading scaled to peak 1
        pmin, pmax = an.finds_peak(lam, sm, min_peak_prominence=0.02)
        if len(pmin) + len(pmax) >= 4:
            return mm.thickness_from_minmax(lam, sm, n, min_peak_prominence=0.02).thickness, "minmax"
        try:
            start, stop = sch.get_default_start_stop_wavelengths(lam, sm, n, min_peak_prominence=0.02)
            return sch.thickness_from_scheludko(lam, sm, n, wavelength_start=start, wavelength_stop=stop).thickness, "scheludko"
        except Exception:
            r = sch.thickness_from_scheludko(lam, sm, n, interference_order=0, intensities_void=np.zeros_like(sm))
            return r.thickness, "scheludko0"

    res = []
    for c in spec["cases"]:
        lam, y = load(data / c["file"])
        n = soap_index(lam) if c["n"] == SOAP else np.full_like(lam, float(c["n"]))
        sm = an.smooth_intensities(y)
        row = {}
        t0 = time.perf_counter()
        try:
            row["of_ref"] = float(reference(c, lam, sm, n))
        except Exception as exc:  # noqa: BLE001 - a failure of the peer is a data point
            row["of_ref"], row["of_ref_error"] = float("nan"), f"{type(exc).__name__}: {exc}"[:120]
        row["of_ref_time_s"] = time.perf_counter() - t0
        try:
            t, m = auto(lam, sm / np.max(sm), n)
            row["of_auto"], row["of_auto_method"] = float(t), m
        except Exception as exc:  # noqa: BLE001
            row["of_auto"], row["of_auto_method"] = float("nan"), f"error: {type(exc).__name__}"
        res.append(row)
    Path(out).write_text(json.dumps(res))


def run_optifik(cases, data: Path, python: str) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        inp, out = os.path.join(tmp, "in.json"), os.path.join(tmp, "out.json")
        Path(inp).write_text(json.dumps({"data": str(data), "cases": cases}))
        subprocess.run([python, __file__, "--optifik-worker", inp, out], check=True)
        return json.loads(Path(out).read_text())


# ---------------------------------------------------------------------------- bubblefit
def run_bubblefit(c, data: Path, normalised: bool, whole: bool = False) -> dict:
    from bubblefit.inverse.spectrum import SpectrumOptions, fit_spectrum
    from bubblefit.io.spectra import Spectrum

    lam, y = load(data / c["file"], 0.0 if whole else WMIN)
    opts = SpectrumOptions(n_film=c["n"], thickness_range=(0.0, c["thickness_max"]), normalised=normalised)
    ref = None
    t0 = time.perf_counter()
    r = fit_spectrum(Spectrum(lam, y, c["file"]), reference=ref, options=opts)
    return {"t": r.thickness_nm, "stderr": r.thickness_nm_stderr, "ok": bool(r.ok), "time_s": time.perf_counter() - t0,
            "reasons": " | ".join(r.reasons)}


# ------------------------------------------------------------------------------ summary
def failed(expected, est) -> bool:
    return not np.isfinite(est) or abs(est - expected) > 0.1 * expected


def _median(v):
    v = [x for x in v if np.isfinite(x)]
    return float(np.median(v)) if v else float("nan")


def run_defaults(cases, data: Path) -> dict:
    """Each group's stated files through ``bubblefit fit-spectrum`` with no switch (see the
    module): file -> thickness, stderr, ok, normalised, reasons, extrema phase of the
    stated value and of this one."""
    from bubblefit.cli import main as cli
    from bubblefit.inverse import extrema_phase, fringe_extrema

    out = {}
    groups = dict.fromkeys(c["group"] for c in cases if c["expected"] is not None)
    for g in groups:
        sub = [c for c in cases if c["group"] == g and c["expected"] is not None]
        with tempfile.TemporaryDirectory() as tmp:
            js = os.path.join(tmp, "o.json")
            argv = ["fit-spectrum", *[str(data / c["file"]) for c in sub], "--json", js,
                    "--thickness-range", f"0,{sub[0]['thickness_max']:g}"]
            argv += ["--n-film", "soap"] if sub[0]["n"] == SOAP else ["--n-film", str(sub[0]["n"])]
            if sub[0]["void"]:
                argv += ["--dark", str(data / sub[0]["void"])]
            if cli(argv) != 0:
                continue
            res = json.loads(Path(js).read_text())["spectra"]
        for c, r in zip(sub, res):
            lam, y = load(data / c["file"])
            ext = fringe_extrema(lam, y)
            n_of = soap_index if c["n"] == SOAP else (lambda x, n=float(c["n"]): np.full_like(x, n))
            stated, mine = extrema_phase(c["expected"], ext, n_of), extrema_phase(r["thickness_nm"], ext, n_of)
            doubt = bool(np.isfinite(stated) and np.isfinite(mine) and stated > 0.2 and mine < 0.1)
            out[c["file"]] = dict(bf_def=r["thickness_nm"], bf_def_stderr=r["thickness_nm_stderr"], bf_def_ok=r["ok"],
                                  bf_def_normalised=r["normalised"], bf_def_reasons=" | ".join(r["reasons"]),
                                  extrema=len(ext), extrema_phase_stated=stated, extrema_phase_bf_def=mine,
                                  stated_in_doubt=(f"the stated value puts the reading's {len(ext)} extrema "
                                                   f"{stated:.2f} rms off whole phases, the defaults' {mine:.2f}")
                                  if doubt else "")
    return out


TOOLS = {"bubblefit defaults": "bf_def", "bubblefit defaults ok only": "bf_def",
         "bubblefit": "bf", "bubblefit ok only": "bf", "bubblefit normalised": "bf_norm",
         "bubblefit norm. ok only": "bf_norm", "optifik ref": "of_ref",
         "optifik auto": "of_auto"}


def summarise_stated(rows) -> dict:
    out = {}
    for key in ["all", *dict.fromkeys(r["group"] for r in rows if r["expected"] is not None)]:
        sub = [r for r in rows if r["expected"] is not None and (key == "all" or r["group"] == key)]
        if not sub:
            continue
        entry = {"files": len(sub)}
        for tool, col in TOOLS.items():
            s = [r for r in sub if col in r and (not tool.endswith("ok only") or r[col + "_ok"])]
            if (tool.startswith("bubblefit norm") or col == "bf_def") and not [r for r in sub if col in r]:
                continue
            err = [abs(r[col] - r["expected"]) for r in s]
            rel = [abs(r[col] - r["expected"]) / r["expected"] for r in s]
            fails = [failed(r["expected"], r[col]) for r in s]
            e = {"files": len(s), "median_abs_err_nm": _median(err), "median_rel_err": _median(rel),
                 "fail_10pct": int(sum(fails)), "missing": int(sum(not np.isfinite(r[col]) for r in s))}
            if col.startswith("bf") and not tool.endswith("ok only"):
                okc = col + "_ok"
                e["flagged"] = int(sum(not r[okc] for r in s))
                e["silent_fail"] = int(sum(f and r[okc] for f, r in zip(fails, s)))
                e["ok_and_off_3se"] = int(sum(f and r[okc] and abs(r[col] - r["expected"]) > 3 * r[col + "_stderr"]
                                              for f, r in zip(fails, s)))
                e["within_10pct"] = float(np.mean([not f for f in fails])) if fails else float("nan")
            entry[tool] = e
        out[key] = entry
    return out


def summarise_series(rows) -> dict:
    sub = [r for r in rows if r["group"].startswith("series")]
    if not sub:
        return {}
    out = {"files": len(sub)}
    for tool, col in [("bubblefit", "bf"), ("bubblefit ok only", "bf"), ("optifik ref", "of_ref"), ("optifik auto", "of_auto")]:
        v = np.array([r[col] if (tool != "bubblefit ok only" or r["bf_ok"]) else np.nan for r in sub])
        fin = v[np.isfinite(v)]
        out[tool] = {"values": int(len(fin)), "median_abs_step_nm": float(np.median(np.abs(np.diff(fin)))) if len(fin) > 1 else float("nan"),
                     "median_thickness_nm": _median(fin)}
        if col == "bf" and tool == "bubblefit":
            out[tool]["flagged"] = int(sum(not r["bf_ok"] for r in sub))
    for other in ("of_ref", "of_auto"):
        d = [abs(r["bf"] - r[other]) for r in sub if np.isfinite(r["bf"]) and np.isfinite(r[other])]
        dok = [abs(r["bf"] - r[other]) for r in sub if r["bf_ok"] and np.isfinite(r[other])]
        out[f"bubblefit_vs_{other}"] = {"median_abs_diff_nm": _median(d), "ok_only_median_abs_diff_nm": _median(dok),
                                        "within_10pct": int(sum(abs(r["bf"] - r[other]) <= 0.1 * abs(r[other]) for r in sub
                                                                if np.isfinite(r["bf"]) and np.isfinite(r[other])))}
    return out


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), dpi=80)
    st = [r for r in rows if r["expected"] is not None]
    e = np.array([r["expected"] for r in st])
    for col, label, mk in [("bf", "bubblefit", "o"), ("of_ref", "optifik (reference method)", "x")]:
        v = np.array([r[col] for r in st])
        ax[0].loglog(e, np.where(np.isfinite(v), v, np.nan), mk, ms=3, alpha=0.6, label=label)
    nr = [r for r in st if "bf_norm" in r]
    ax[0].loglog([r["expected"] for r in nr], [r["bf_norm"] for r in nr], "+", ms=4, alpha=0.6,
                 label="bubblefit --normalised (lamp-divided readings)")
    bad = np.array([not r["bf_ok"] for r in st])
    ax[0].loglog(e[bad], [r["bf"] for r, b in zip(st, bad) if b], "o", mfc="none", mec="r", ms=5, lw=0.5,
                 label="bubblefit ok=false")
    lim = [30, 60000]
    ax[0].plot(lim, lim, "k-", lw=0.5)
    ax[0].set_xlim(lim)
    ax[0].set_ylim(lim)
    ax[0].set_xlabel("stated thickness (nm)")
    ax[0].set_ylabel("estimate (nm)")
    ax[0].legend(fontsize=7)
    se = [r for r in rows if r["group"].startswith("series")]
    x = np.arange(len(se))
    ax[1].plot(x, [r["of_ref"] for r in se], "x", ms=3, label="optifik min-max (RANSAC)")
    ax[1].plot(x, [r["bf"] for r in se], "o", ms=3, mfc="none", label="bubblefit")
    ok = [i for i, r in enumerate(se) if r["bf_ok"]]
    ax[1].plot(ok, [se[i]["bf"] for i in ok], "o", ms=3, label="bubblefit ok")
    ax[1].set_xlabel("reading (time order, spectraManue/sample3)")
    ax[1].set_ylabel("thickness (nm)")
    ax[1].set_yscale("log")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", help="optifik's data/ folder")
    ap.add_argument("--optifik-python", default=".venv-optifik/bin/python")
    ap.add_argument("--stride", type=int, default=25, help="every STRIDE-th reading of the time series")
    ap.add_argument("--quick", action="store_true", help="three files a group, a sparser series")
    ap.add_argument("--groups", default=None, help="comma-separated groups (default: all, and the series)")
    ap.add_argument("--whole-range", action="store_true",
                    help="bubblefit reads the whole reading, as the command does by default (optifik keeps >= 450 nm); "
                         "writes spectrum_real_whole.{json,png}")
    ap.add_argument("--optifik-worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.optifik_worker:
        return optifik_worker(*args.optifik_worker)
    if not args.data:
        ap.error("DATA_DIR is required")
    data = Path(args.data).resolve()
    cases = build_cases(data, args.stride, args.quick)
    if args.groups:
        keep = set(args.groups.split(","))
        cases = [c for c in cases if c["group"] in keep]
    of = run_optifik(cases, data, args.optifik_python)
    defaults = run_defaults(cases, data)
    rows = []
    for c, o in zip(cases, of):
        b = run_bubblefit(c, data, normalised=False, whole=args.whole_range)
        row = {"group": c["group"], "file": c["file"], "expected": c["expected"], "n": c["n"],
               "bf": b["t"], "bf_stderr": b["stderr"], "bf_ok": b["ok"], "bf_reasons": b["reasons"],
               "bf_time_s": b["time_s"], "of_method": c["method"], **o}
        if c["normalised"] and c["expected"] is not None:
            f = run_bubblefit(c, data, normalised=True, whole=args.whole_range)
            row.update(bf_norm=f["t"], bf_norm_stderr=f["stderr"], bf_norm_ok=f["ok"], bf_norm_reasons=f["reasons"])
        row.update(defaults.get(c["file"], {}))
        rows.append(row)
        exp = f"{c['expected']:8.1f}" if c["expected"] is not None else "       -"
        flat = f"  normalised {row['bf_norm']:8.1f} ok={row['bf_norm_ok']!s:5}" if "bf_norm" in row else ""
        print(f"{c['file']:<36} stated {exp}  bubblefit {b['t']:8.1f} +- {b['stderr']:6.2g} ok={b['ok']!s:5}{flat}  "
              f"optifik {c['method']} {o['of_ref']:8.1f}  auto {o['of_auto']:8.1f}", flush=True)
    stated, series = summarise_stated(rows), summarise_series(rows)
    RESULTS.mkdir(exist_ok=True)
    name = "spectrum_real_whole" if args.whole_range else "spectrum_real"
    (RESULTS / f"{name}.json").write_text(json.dumps(
        {"data": "github.com/sciunto/optifik data/ (not redistributed)",
         "wavelength_min_nm": {"bubblefit": 0.0 if args.whole_range else WMIN, "optifik": WMIN},
         "groups": args.groups or "all", "stated": stated, "series": series, "rows": rows}, indent=1))
    plot(rows, RESULTS / f"{name}.png")
    print(f"\n{'group':>8} {'tool':>23} {'files':>5} {'med|err|nm':>10} {'med rel':>7} {'fail10%':>7} {'flagged':>7} {'silent':>6}")
    for g, entry in stated.items():
        for tool, e in entry.items():
            if tool == "files":
                continue
            print(f"{g:>8} {tool:>23} {e['files']:5d} {e['median_abs_err_nm']:10.1f} {e['median_rel_err']:7.3f} "
                  f"{e['fail_10pct']:7d} {e.get('flagged', ''):>7} {e.get('silent_fail', ''):>6}")
    if series:
        print(f"\ntime series ({series['files']} readings):")
        for tool in ("bubblefit", "bubblefit ok only", "optifik ref", "optifik auto"):
            s = series[tool]
            print(f"  {tool:>18}: {s['values']} values, median |step| {s['median_abs_step_nm']:.1f} nm, "
                  f"median thickness {s['median_thickness_nm']:.0f} nm" + (f", flagged {s['flagged']}" if "flagged" in s else ""))
        for k in ("bubblefit_vs_of_ref", "bubblefit_vs_of_auto"):
            print(f"  {k}: {series[k]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
