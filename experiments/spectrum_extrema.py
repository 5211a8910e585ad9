"""Are the stated thicknesses of optifik's readings consistent with the readings' own fringes?

``spectrum_real.py`` scores bubblefit against the thicknesses optifik's repository states
for its readings. Those are the field's own outputs, not a truth. This checks both sets of
numbers against a closed form that neither tool's fit uses: at normal incidence the
reflectance of a film in air is extremal where its phase ``4 pi n d / lambda`` is a whole
multiple of pi (Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1), so at the
wavelengths of a reading's fringe extrema ``x = 4 n(lambda) d / lambda`` should be a whole
number. For each reading with at least ``--min-extrema`` extrema (Savitzky-Golay smoothed,
found by their prominence, at least 5 % of the reading's mean level) and a stated
thickness of ``MIN_STATED_NM`` or more, the score of a thickness is the rms distance of
``x`` from the nearest whole number at those extrema: 0 for a thickness that puts every
extremum where it is, ``1/sqrt(12) = 0.289`` on average for a thickness unrelated to the
fringes.

It is indicative, not a measurement: a lamp that slopes across the range moves the
reading's extrema a little off the film's (bubblefit's fit models the lamp, which this
test does not), and smoothing moves the extrema of low-contrast fringes.

Reads ``experiments/results/spectrum_real.json`` (bubblefit's default and ``--normalised``
thicknesses and optifik's) and the readings in ``DATA_DIR`` (optifik's ``data/`` folder,
not redistributed). Prints a table per group, writes ``spectrum_extrema.{json,png}`` to
``--out`` (default ``experiments/results``).

Usage: ``PYTHONPATH=. python experiments/spectrum_extrema.py DATA_DIR [--min-extrema 3] [--out DIR] [--quick]``
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

from bubblefit.inverse import RANDOM_PHASE as RANDOM
from bubblefit.inverse import extrema_phase, fringe_extrema

sys.path.insert(0, str(Path(__file__).resolve().parent))
from spectrum_real import load, soap_index  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: Readings stated thinner are skipped: a film under ~150 nm has at most one extremum in the
#: visible, and a thickness near 0 puts ``x`` near 0 everywhere, a perfect score for nothing.
MIN_STATED_NM = 150.0
TOOLS = {"stated": "expected", "bubblefit": "bf", "bubblefit normalised": "bf_norm", "optifik": "of_ref"}


def extrema(lam: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The reading's fringe extrema (:func:`bubblefit.inverse._spectrum_extrema.fringe_extrema`)."""
    return fringe_extrema(lam, y)


def mismatch(d: float, lam_ext: np.ndarray, n_of) -> float:
    """The extrema phase score (:func:`bubblefit.inverse._spectrum_extrema.extrema_phase`)."""
    return extrema_phase(d, lam_ext, n_of) if len(lam_ext) else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path, help="optifik's data/ folder")
    ap.add_argument("--min-extrema", type=int, default=3)
    ap.add_argument("--out", type=Path, default=RESULTS, help="folder for the JSON and the plot")
    ap.add_argument("--quick", action="store_true", help="the first five readings of each group")
    args = ap.parse_args()
    real = json.loads((RESULTS / "spectrum_real.json").read_text())
    rows = [r for r in real["rows"] if r.get("expected") is not None]
    if args.quick:  # spectrum_real.json lists its readings group by group
        rows = [r for _, group in itertools.groupby(rows, key=lambda r: r["group"]) for r in list(group)[:5]]
    out = []
    for r in rows:
        lam, y = load(args.data / r["file"])
        ext = extrema(lam, y)
        if len(ext) < args.min_extrema or r["expected"] < MIN_STATED_NM:
            continue
        n_of = soap_index if r["n"] == "soap" else (lambda lam_, n=float(r["n"]): np.full_like(lam_, n))
        row = {"group": r["group"], "file": r["file"], "extrema": len(ext)}
        for tool, key in TOOLS.items():
            row[tool] = r.get(key)
            row[tool + " mismatch"] = mismatch(r.get(key), ext, n_of)
        out.append(row)
    summary = {}
    groups = list(dict.fromkeys(r["group"] for r in out))
    print(f"{'group':8s} {'files':>5s} " + " ".join(f"{t:>20s}" for t in TOOLS) + "   (median rms, random 0.289)")
    for g in groups + ["all"]:
        sub = [r for r in out if g in ("all", r["group"])]
        entry = {"files": len(sub)}
        for tool in TOOLS:
            v = np.array([r[tool + " mismatch"] for r in sub], float)
            entry[tool] = float(np.nanmedian(v)) if np.isfinite(v).any() else float("nan")
        s = np.array([r["stated mismatch"] for r in sub], float)
        b = np.array([r["bubblefit normalised mismatch"] if r["bubblefit normalised"] is not None
                      else r["bubblefit mismatch"] for r in sub], float)
        entry["bubblefit closer than stated"] = int(np.sum(b < s))
        summary[g] = entry
        print(f"{g:8s} {len(sub):5d} " + " ".join(f"{entry[t]:20.3f}" for t in TOOLS)
              + f"   bubblefit closer in {entry['bubblefit closer than stated']}/{len(sub)}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "spectrum_extrema.json").write_text(json.dumps(
        {"random": RANDOM, "min_extrema": args.min_extrema, "summary": summary, "rows": out}, indent=1))
    plot(out, groups, args.out / "spectrum_extrema.png")


def plot(out, groups, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for i, (tool, colour) in enumerate(zip(TOOLS, ("k", "C0", "C2", "C3"))):
        med = []
        for g in groups:
            v = np.array([r[tool + " mismatch"] for r in out if r["group"] == g], float)
            med.append(float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else np.nan)
        ax.bar(np.arange(len(groups)) + (i - 1.5) * 0.2, med, 0.2, color=colour, label=tool)
    ax.axhline(RANDOM, color="0.5", ls="--", lw=1, label="unrelated to the fringes")
    ax.set_xticks(np.arange(len(groups)), groups)
    ax.set_ylabel("median rms distance of 4 n d / lambda\nfrom a whole number at the extrema")
    ax.set_title("Thicknesses against the readings' own fringe extrema")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
