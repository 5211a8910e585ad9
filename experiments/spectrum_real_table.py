"""The table of ``docs/spectra.md`` ("Measured on real readings") from the results of
``experiments/spectrum_real.py --defaults-only`` (``experiments/results/spectrum_real.json``),
per series of optifik's readings; with ``--before OLD.json`` the same rows from an older
results file beside them. Writes ``experiments/results/spectrum_real_table.md`` (or ``--out``).

Usage: ``python experiments/spectrum_real_table.py [--before OLD.json] [--out FILE.md]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"

#: (label, test of a row)
ROWS = [
    ("spectraVictor1", lambda r: r["group"] == "SV1"),
    ("spectraVictor2 order 5", lambda r: r["group"] == "SV2o5"),
    ("order 4", lambda r: r["group"] == "SV2o4"),
    ("order 3", lambda r: r["group"] == "SV2o3"),
    ("order 2", lambda r: r["group"] == "SV2o2"),
    ("order 1 (2 known, 64 known to fail)", lambda r: r["group"] == "SV2o1"),
    ("order 0 (known, 82-124 nm)", lambda r: r["group"] == "SV2o0"),
    ("spectraVictor2, known", lambda r: r["group"].startswith("SV2") and _known(r)),
    ("**both series, known**", lambda r: r["group"].startswith("SV") and _known(r)),
    ("both series, all with a stated value", lambda r: r["group"].startswith("SV")),
]


def _known(r) -> bool:
    return (r.get("stated_in") or "").startswith("known_value")


def summary(rows) -> dict:
    """n, median relative error, fraction within 10 %, called ok (of them within 10 %), ok and
    more than 10 % and 3 standard errors off (all and with the stated values in doubt left
    out), and optifik's reference method's median error and fraction within 10 %."""
    v = np.array([r["expected"] for r in rows])
    t = np.array([r["bf_def"] for r in rows])
    s = np.array([r["bf_def_stderr"] for r in rows])
    ok = np.array([bool(r["bf_def_ok"]) for r in rows])
    doubt = np.array([bool(r.get("stated_in_doubt")) for r in rows])
    err = np.abs(t - v) / v
    within = err <= 0.1
    wrong = ok & ~within & (np.abs(t - v) > 3.0 * s)
    of = np.array([r.get("of_ref", np.nan) for r in rows], float)
    oferr = np.abs(of - v) / v
    return dict(n=len(rows), median=float(np.median(err)), within=float(np.mean(within)), ok=int(ok.sum()),
                ok_within=int((ok & within).sum()), wrong=int(wrong.sum()), wrong_trusted=int((wrong & ~doubt).sum()),
                of_median=float(np.nanmedian(oferr)), of_within=float(np.mean(oferr <= 0.1)))


def table(rows, before=None) -> str:
    head = "| readings | files | median relative error | within 10 % | called ok (of them within 10 %) | " \
           "ok and > 10 % and 3 stderr off (stated value not in doubt) | optifik's method: median error, within 10 % |"
    lines = [head, "|---|---:|---:|---:|---:|---:|---:|"]
    for label, test in ROWS:
        sub = [r for r in rows if r.get("expected") is not None and "bf_def" in r and test(r)]
        if not sub:
            continue
        e = summary(sub)
        cell = [f"{e['n']}", f"{e['median']:.1%}", f"{e['within']:.0%}", f"{e['ok']} ({e['ok_within']})",
                f"{e['wrong']} ({e['wrong_trusted']})"]
        if before is not None:
            old = [r for r in before if r.get("expected") is not None and "bf_def" in r and test(r)]
            if old:
                b = summary(old)
                prev = [f"{b['n']}", f"{b['median']:.1%}", f"{b['within']:.0%}", f"{b['ok']} ({b['ok_within']})",
                        f"{b['wrong']} ({b['wrong_trusted']})"]
                cell = [f"{p} -> {c}" if p != c else c for p, c in zip(prev, cell)]
        lines.append(f"| {label} | " + " | ".join(cell) + f" | {e['of_median']:.1%}, {e['of_within']:.0%} |")
    return "\n".join(lines).replace("%", " %").replace("  %", " %")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=str(RESULTS / "spectrum_real.json"))
    ap.add_argument("--before", default=None, help="an older results file, its rows shown as 'before -> now'")
    ap.add_argument("--out", default=str(RESULTS / "spectrum_real_table.md"), help="the markdown file written")
    args = ap.parse_args()
    rows = json.loads(Path(args.results).read_text())["rows"]
    before = json.loads(Path(args.before).read_text())["rows"] if args.before else None
    text = table(rows, before)
    print(text)
    out = Path(args.out)
    note = f"Before -> now (the 'before' file: {Path(args.before).name})\n\n" if before else ""
    out.write_text(note + text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
