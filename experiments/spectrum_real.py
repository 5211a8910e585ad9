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
no switch but the film's index: each group's files given together (whole readings; the
void reading, a reading of the empty frame with the light on, is not a dark reading and is
left out unless ``--void-as-dark``), so that the command decides whether they
were divided by the lamp, whether they form one series (and reads them with its shared
lamp), and uses their time order (the file names) against jumps to a twin. With ``--join``
the groups named are given to one command, as a user with the whole data set would give
them: the command tells the series apart by their folders (``spectraVictor2``'s six folders
share their boundary frames and are one film) and shares the lamp's shape among them. Each row also
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
        vals, src = {}, {}
        for y in yamls:
            got = stated_values((data / folder / y).resolve())
            vals.update(got)
            src.update(dict.fromkeys(got, Path(y).name))
        names = sorted(vals)
        if quick:
            names = names[:: max(1, len(names) // 3)][:3]
        for name in names:
            cases.append(dict(group=g, file=f"{folder}/{name}", expected=vals[name], src=src[name], n=n, method=method, prom=prom,
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
    """optifik's results per case, from its own environment; without one (``python`` not
    there), its results of the same files in the results file already written (they do not
    depend on bubblefit), NaN where it has none."""
    if not Path(python).exists():
        old = {}
        for name in ("spectrum_real.json", "spectrum_real_whole.json"):
            if (RESULTS / name).exists():
                for r in json.loads((RESULTS / name).read_text())["rows"]:
                    old.setdefault(r["file"], {k: r[k] for k in ("of_ref", "of_ref_time_s", "of_auto", "of_auto_method")
                                               if k in r})
        print(f"no optifik environment at {python}: optifik's results of the results file already written "
              f"({sum(c['file'] in old for c in cases)} of {len(cases)} files)", flush=True)
        return [old.get(c["file"], {"of_ref": float("nan"), "of_auto": float("nan")}) for c in cases]
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


def run_defaults(cases, data: Path, join: list[str] | None = None, void_as_dark: bool = False) -> dict:
    """Each group's stated files through ``bubblefit fit-spectrum`` with no switch (see the
    module): file -> thickness, stderr, ok, normalised, reasons, extrema phase of the
    stated value and of this one."""
    from bubblefit.cli import main as cli
    from bubblefit.inverse import extrema_phase, fringe_extrema

    out = {}
    groups = dict.fromkeys(c["group"] for c in cases if c["expected"] is not None)
    if join:  # one command for the joined groups, in time order (the files' names)
        groups = {g: [g] for g in groups if g not in join} | {"+".join(join): join}
    else:
        groups = {g: [g] for g in groups}
    for g, members in groups.items():
        sub = [c for c in cases if c["group"] in members and c["expected"] is not None]
        sub.sort(key=lambda c: int(re.sub(r"\D", "", Path(c["file"]).name) or 0))
        # The void reading (the empty frame, light on) is not given as --dark: a dark reading
        # has no light, and the void's stray light is not the series' (the series' last,
        # black, film reads up to 0.015 below it from 450 nm on, where a black film reflects
        # about 0.01 above the stray light); each reading's own stray light is fitted instead.
        void = next((c["void"] for c in sub if c["void"]), None) if void_as_dark else None
        with tempfile.TemporaryDirectory() as tmp:
            js = os.path.join(tmp, "o.json")
            argv = ["fit-spectrum", *[str(data / c["file"]) for c in sub], "--json", js,
                    "--thickness-range", f"0,{sub[0]['thickness_max']:g}"]
            argv += ["--n-film", "soap"] if sub[0]["n"] == SOAP else ["--n-film", str(sub[0]["n"])]
            if void:
                argv += ["--dark", str(data / void)]
            t0 = time.perf_counter()
            if cli(argv) != 0:
                continue
            print(f"{g}: {len(sub)} readings with the defaults in {time.perf_counter() - t0:.0f} s", flush=True)
            res = json.loads(Path(js).read_text())["spectra"]
        for c, r in zip(sub, res):
            lam, y = load(data / c["file"])
            ext = fringe_extrema(lam, y)
            n_of = soap_index if c["n"] == SOAP else (lambda x, n=float(c["n"]): np.full_like(x, n))
            stated, mine = extrema_phase(c["expected"], ext, n_of), extrema_phase(r["thickness_nm"], ext, n_of)
            out[c["file"]] = dict(bf_def_dark=bool(void), bf_def=r["thickness_nm"], bf_def_stderr=r["thickness_nm_stderr"], bf_def_ok=r["ok"],
                                  bf_def_normalised=r["normalised"], bf_def_reasons=" | ".join(r["reasons"]),
                                  extrema=len(ext), extrema_phase_stated=stated, extrema_phase_bf_def=mine)
    return out


#: A stated value is in doubt when, with the lamp and stray light refitted at it, the reading's
#: residual is at least this many times (in chi^2) the residual at the defaults' thickness
#: read alone with the same model, and its extrema phase is worse: the model cannot put the
#: fringes where they are at the stated thickness.
DOUBT_CHI2_RATIO = 2.0


def stated_check(c, data: Path, row: dict) -> dict:
    """The stated value against the reading: ``fit_spectrum`` read alone with the model the
    defaults chose (divided or not), free and held at the stated thickness (+- 0.5 nm)."""
    from bubblefit.inverse.spectrum import SpectrumOptions, fit_spectrum
    from bubblefit.io.spectra import Spectrum

    lam, y = load(data / c["file"], 0.0)
    dark = None
    if c["void"] and row.get("bf_def_dark", True):
        dl, dy = load(data / c["void"], 0.0)
        dark = Spectrum(dl, dy, c["void"])
    v = c["expected"]
    base = dict(n_film=c["n"], normalised=bool(row["bf_def_normalised"]))
    free = fit_spectrum(Spectrum(lam, y, c["file"]), dark=dark,
                        options=SpectrumOptions(thickness_range=(0.0, c["thickness_max"]), **base))
    held = fit_spectrum(Spectrum(lam, y, c["file"]), dark=dark,
                        options=SpectrumOptions(thickness_range=(max(0.0, v - 0.5), v + 0.5), **base))
    ratio = held.reduced_chi2 / free.reduced_chi2 if free.reduced_chi2 > 0 else float("nan")
    return {"alone_t": free.thickness_nm, "alone_stderr": free.thickness_nm_stderr, "alone_chi2r": free.reduced_chi2,
            "stated_chi2r": held.reduced_chi2, "stated_chi2_ratio": ratio}


def judge_doubt(row: dict) -> str:
    """Why the stated value of a row is in doubt ("" when it is not).

    With the check held at the stated value (:func:`stated_check`): the reading read alone
    supports a thickness (standard error under 5 %) within 5 % of the defaults' value, the
    model held at the stated value leaves :data:`DOUBT_CHI2_RATIO` times its chi2 or more,
    and the stated value puts the reading's extrema further from whole phases than the
    defaults' value (both tests must speak: a reading without three clear extrema, a
    washed-out thick film, is not described by the model at any thickness). Without it: the
    defaults' value is ok, puts the extrema within 0.1 of whole phases and the stated value
    more than 0.2 off."""
    v, ps, pb = row["expected"], row.get("extrema_phase_stated", np.nan), row.get("extrema_phase_bf_def", np.nan)
    phases = bool(np.isfinite(ps) and np.isfinite(pb))
    if "stated_chi2_ratio" in row:
        supported = abs(row["alone_t"] - row["bf_def"]) <= 0.05 * v and row.get("alone_stderr", 0.0) <= 0.05 * v
        if supported and phases and ps > pb and row["stated_chi2_ratio"] >= DOUBT_CHI2_RATIO:
            return (f"held at the stated {v:.0f} nm the model leaves {row['stated_chi2_ratio']:.1f} times the chi2 it "
                    f"leaves at {row['alone_t']:.0f} nm, and the stated value puts the reading's {row['extrema']} "
                    f"extrema {ps:.2f} rms off whole phases (the defaults' value {pb:.2f}; 0.29 random)")
        return ""
    if row.get("bf_def_ok") and phases and ps > 0.2 and pb < 0.1:
        return (f"the stated value puts the reading's {row['extrema']} extrema {ps:.2f} rms off whole phases, "
                f"the defaults' {pb:.2f}")
    return ""


def minimum_check(row: dict, data: Path) -> dict:
    """The fringe-minimum test (:func:`bubblefit.inverse._spectrum_extrema.minima_phase`) of
    the stated value and of the defaults' value on a reading with one to three clear extrema
    and a clear minimum (a zero of ``R``, placed whatever the lamp): the distance of
    ``4 n d / lambda`` from an even number there. Empty for other readings."""
    from bubblefit.inverse import fringe_extrema, fringe_minima, minima_phase

    lam, y = load(data / row["file"])
    minima = fringe_minima(lam, y)
    if not len(minima) or len(fringe_extrema(lam, y)) >= 4:
        return {}
    n_of = soap_index if row["n"] == SOAP else (lambda x, n=float(row["n"]): np.full_like(x, n))
    return {"minima": int(len(minima)), "minima_phase_stated": minima_phase(row["expected"], minima, n_of),
            "minima_phase_bf_def": minima_phase(row["bf_def"], minima, n_of)}


def plot_doubt(rows, data: Path, path, count: int = 4):
    """The readings whose stated value is most in doubt, with the fits free and held at it."""
    import matplotlib.pyplot as plt

    from bubblefit.inverse.spectrum import SpectrumOptions, fit_spectrum
    from bubblefit.io.spectra import Spectrum

    pick = sorted([r for r in rows if r.get("stated_in_doubt")], key=lambda r: -r.get("stated_chi2_ratio", 0.0))
    pick = sorted(pick[:count], key=lambda r: r["file"])
    if not pick:
        return
    fig, ax = plt.subplots(len(pick), 1, figsize=(9, 2.4 * len(pick)), dpi=80, squeeze=False)
    for a, r in zip(ax[:, 0], pick):
        lam, y = load(data / r["file"], 0.0)
        base = dict(n_film=r["n"], normalised=bool(r["bf_def_normalised"]))
        free = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(**base))
        held = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(
            thickness_range=(r["expected"] - 0.5, r["expected"] + 0.5), **base))
        a.plot(lam, y, color="0.6", lw=0.4, label="reading")
        a.plot(free.wavelength_nm, free.fitted, lw=1.2, label=f"{free.thickness_nm:.0f} nm (read), chi2/dof {free.reduced_chi2:.1f}")
        a.plot(held.wavelength_nm, held.fitted, lw=1.2, label=f"{r['expected']:.0f} nm (stated), chi2/dof {held.reduced_chi2:.1f}")
        a.set_title(f"{r['file']}: extrema phase {r['extrema_phase_stated']:.2f} (stated), "
                    f"{r['extrema_phase_bf_def']:.2f} (read)", fontsize=8)
        a.set_ylabel("divided reading" if r["bf_def_normalised"] else "reading")
        a.legend(fontsize=7, loc="upper left")
    ax[-1, 0].set_xlabel("wavelength (nm)")
    fig.tight_layout()
    fig.savefig(path)


TOOLS = {"bubblefit defaults": "bf_def", "bubblefit defaults ok only": "bf_def",
         "bubblefit": "bf", "bubblefit ok only": "bf", "bubblefit normalised": "bf_norm",
         "bubblefit norm. ok only": "bf_norm", "optifik ref": "of_ref",
         "optifik auto": "of_auto"}


def summarise_stated(rows) -> dict:
    out = {}
    groups = list(dict.fromkeys(r["group"] for r in rows if r["expected"] is not None))
    # spectraVictor1 and spectraVictor2 (its orders: one film) are the two draining series; "known"
    # keeps the readings of known_value*.yaml (82-4048 nm), not those optifik's tests expect to fail
    series = ["SV2"] if any(g.startswith("SV2") for g in groups) else []
    known = ["known SV1+SV2", "known SV2"] if series else []

    def member(r, key):
        if key == "all":
            return True
        if key.startswith("known"):
            return (r.get("stated_in") or "").startswith("known_value") and \
                r["group"].startswith("SV2" if key == "known SV2" else "SV")
        return r["group"] == key or (key == "SV2" and r["group"].startswith("SV2"))

    for key in ["all", *known, *series, *groups]:
        sub = [r for r in rows if r["expected"] is not None and member(r, key)]
        if not sub:
            continue
        entry = {"files": len(sub)}
        for tool, col in TOOLS.items():
            s = [r for r in sub if col in r and (not tool.endswith("ok only") or r[col + "_ok"])]
            if (tool.startswith("bubblefit norm") or col in ("bf", "bf_def")) and not [r for r in sub if col in r]:
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
                if col == "bf_def":
                    trusted = [(f, r) for f, r in zip(fails, s) if not r.get("stated_in_doubt")]
                    e["stated_in_doubt"] = len(s) - len(trusted)
                    e["not_in_doubt"] = {
                        "files": len(trusted),
                        "median_rel_err": _median([abs(r[col] - r["expected"]) / r["expected"] for _, r in trusted]),
                        "within_10pct": float(np.mean([not f for f, _ in trusted])) if trusted else float("nan"),
                        "ok": int(sum(r[okc] for _, r in trusted)),
                        "ok_within_10pct": int(sum(r[okc] and not f for f, r in trusted)),
                        "ok_and_off_3se": int(sum(f and r[okc] and abs(r[col] - r["expected"]) > 3 * r[col + "_stderr"]
                                                  for f, r in trusted))}
                    e["ok"] = int(sum(r[okc] for r in s))
                    e["ok_within_10pct"] = int(sum(r[okc] and not f for f, r in zip(fails, s)))
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
    if st and "bf" not in st[0]:  # --defaults-only
        return plot_defaults(st, path)
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


def plot_defaults(st, path):
    """Stated against read (bubblefit with no switch, optifik's reference method), and the
    extrema phase test of the stated and of bubblefit's value."""
    import matplotlib.pyplot as plt

    st = [r for r in st if "bf_def" in r]
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), dpi=80)
    e = np.array([r["expected"] for r in st])
    v = np.array([r["bf_def"] for r in st])
    ok = np.array([bool(r["bf_def_ok"]) for r in st])
    ax[0].loglog(e, [r["of_ref"] for r in st], "x", ms=3, alpha=0.6, label="optifik (reference method)")
    ax[0].loglog(e[ok], v[ok], "o", ms=3, label="bubblefit defaults, ok")
    ax[0].loglog(e[~ok], v[~ok], "o", mfc="none", mec="r", ms=4, label="bubblefit defaults, not ok")
    lim = [50, 6000]
    ax[0].plot(lim, lim, "k-", lw=0.5)
    ax[0].set(xlim=lim, ylim=lim, xlabel="stated thickness (nm)", ylabel="read (nm)")
    ax[0].legend(fontsize=7)
    ps = np.array([r["extrema_phase_stated"] for r in st])
    pb = np.array([r["extrema_phase_bf_def"] for r in st])
    # thicknesses the readings support (stderr under 5 %): the test says little of a value
    # whose phase is under one at every extremum (a washed-out film read from its brightness)
    firm = np.array([r["bf_def_stderr"] < 0.05 * r["bf_def"] for r in st])
    for g, mk in (("SV1", "o"), ("SV2", "s")):
        sel = np.array([r["group"].startswith(g) for r in st]) & firm
        ax[1].plot(ps[sel], pb[sel], mk, ms=4, mfc="none", label=f"{g} readings")
    ax[1].axhline(0.289, color="0.6", lw=0.5)
    ax[1].axvline(0.289, color="0.6", lw=0.5)
    ax[1].plot([0, 0.45], [0, 0.45], "k-", lw=0.5)
    ax[1].set(xlabel="extrema phase of the stated value (rms, 0.289 random)",
              ylabel="extrema phase of bubblefit's value", xlim=(0, 0.45), ylim=(0, 0.45))
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
    ap.add_argument("--defaults-only", action="store_true",
                    help="bubblefit only as the command runs with no switch (skip the single-reading columns)")
    ap.add_argument("--merge", action="store_true",
                    help="keep the rows of the groups not run from the results file already written (runs in parts)")
    ap.add_argument("--join", default=None,
                    help="comma-separated groups read by one command, as one series (e.g. SV2o1,SV2o0: the end of "
                         "spectraVictor2's film, whose order-1 readings pin the lamp of the order-0 ones)")
    ap.add_argument("--skip-failing", default="",
                    help="comma-separated groups whose known_to_fail.yaml readings are left out (time)")
    ap.add_argument("--void-as-dark", action="store_true",
                    help="give the void reading (empty frame) to the defaults' command as --dark (it is not a dark reading)")
    ap.add_argument("--resummarise", action="store_true",
                    help="recompute the summary and figures of the results file already written (no fitting)")
    ap.add_argument("--optifik-worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.optifik_worker:
        return optifik_worker(*args.optifik_worker)
    if not args.data:
        ap.error("DATA_DIR is required")
    data = Path(args.data).resolve()
    cases = build_cases(data, args.stride, args.quick)
    stated_in = {c["file"]: c.get("src") for c in cases}
    skip = set(args.skip_failing.split(",")) if args.skip_failing else set()
    cases = [c for c in cases if not (c["group"] in skip and c.get("src") == "known_to_fail.yaml")]
    if args.resummarise:
        cases = []
    if args.groups:
        keep = set(args.groups.split(","))
        cases = [c for c in cases if c["group"] in keep]
    of = run_optifik(cases, data, args.optifik_python) if cases else []
    defaults = run_defaults(cases, data, args.join.split(",") if args.join else None, args.void_as_dark)
    rows = []
    for c, o in zip(cases, of):
        row = {"group": c["group"], "file": c["file"], "expected": c["expected"], "stated_in": c.get("src"), "n": c["n"],
               "of_method": c["method"], **o}
        if args.defaults_only:
            row.update(defaults.get(c["file"], {}))
            if "bf_def" in row and abs(row["bf_def"] - c["expected"]) > 0.05 * c["expected"]:
                row.update(stated_check(c, data, row))
            rows.append(row)
            if "bf_def" in row:
                print(f"{c['file']:<36} stated {c['expected']:8.1f}  defaults {row['bf_def']:8.1f} +- "
                      f"{row['bf_def_stderr']:6.2g} ok={row['bf_def_ok']!s:5}  optifik {o['of_ref']:8.1f}", flush=True)
            continue
        b = run_bubblefit(c, data, normalised=False, whole=args.whole_range)
        row.update({"bf": b["t"], "bf_stderr": b["stderr"], "bf_ok": b["ok"], "bf_reasons": b["reasons"],
                    "bf_time_s": b["time_s"]})
        if c["normalised"] and c["expected"] is not None:
            f = run_bubblefit(c, data, normalised=True, whole=args.whole_range)
            row.update(bf_norm=f["t"], bf_norm_stderr=f["stderr"], bf_norm_ok=f["ok"], bf_norm_reasons=f["reasons"])
        row.update(defaults.get(c["file"], {}))
        rows.append(row)
        exp = f"{c['expected']:8.1f}" if c["expected"] is not None else "       -"
        flat = f"  normalised {row['bf_norm']:8.1f} ok={row['bf_norm_ok']!s:5}" if "bf_norm" in row else ""
        print(f"{c['file']:<36} stated {exp}  bubblefit {b['t']:8.1f} +- {b['stderr']:6.2g} ok={b['ok']!s:5}{flat}  "
              f"optifik {c['method']} {o['of_ref']:8.1f}  auto {o['of_auto']:8.1f}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    name = "spectrum_real_whole" if args.whole_range else "spectrum_real"
    if (args.merge or args.resummarise) and (RESULTS / f"{name}.json").exists():
        ran = {r["group"] for r in rows}
        old = json.loads((RESULTS / f"{name}.json").read_text())["rows"]
        rows = [r for r in old if r["group"] not in ran] + rows
        for r in rows:
            r.setdefault("stated_in", stated_in.get(r["file"]))
    for r in rows:
        if "bf_def" in r and r["expected"] is not None:
            r.update(minimum_check(r, data))
            r["stated_in_doubt"] = judge_doubt(r)
    order = list(GROUPS) + ["basic", "series_manue3"]
    rows.sort(key=lambda r: (order.index(r["group"]) if r["group"] in order else len(order), r["file"]))
    stated, series = summarise_stated(rows), summarise_series(rows)
    (RESULTS / f"{name}.json").write_text(json.dumps(
        {"data": "github.com/sciunto/optifik data/ (not redistributed)",
         "wavelength_min_nm": {"bubblefit": 0.0 if args.whole_range else WMIN, "optifik": WMIN},
         "groups": sorted({r["group"] for r in rows}), "stated": stated, "series": series, "rows": rows}, indent=1))
    plot(rows, RESULTS / f"{name}.png")
    if args.defaults_only:
        plot_doubt(rows, data, RESULTS / f"{name}_doubt.png")
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
