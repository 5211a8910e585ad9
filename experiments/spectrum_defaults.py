"""``fit-spectrum`` with no switch on synthetic readings made like the real draining-film series.

The real readings this stands in for (two series of a draining foam film, 82 to 4048 nm as
stated, read by a spectrometer and already divided by the lamp, files named in time order)
are not on this machine; these are synthesised with their conditions, by numpy code of this
file (the Airy formula, Born & Wolf 7.6(13), and the soap solution's Cauchy law, not
bubblefit's):

    y = g(nu) (R(d, nu) + b) + c + noise(lambda),

``g`` a residual gain tilting by 30 % across the range (the lamp drifted after the
reference was read), ``b`` 0.01 of light that does not interfere, ``c`` stray light, and
noise of 1 % of the fringes' swing at the red end growing as ``1 / L(lambda)`` towards the
blue (a divided reading is noisiest where the lamp is dim; ``L`` a 3000 K lamp), on
450-800 nm in 0.35 nm steps. Series A drains from 4048 to 400 nm and series B from 1500 to
82 nm, 25 readings each, the thickness falling exponentially in time.

Each reading is read as the command reads it:

- ``old defaults``: each file alone with a raw reading's model (``--not-normalised --no-series``,
  what the command did before it looked at the readings);
- ``--normalised``: alone, as divided;
- ``--normalised --series``: one series per folder, its shared lamp;
- ``defaults``: no switch: the command decides (divided or not, series or not, time order).

Reports per series and in all: the median relative error, the share within 10 %, how many
are called ok and how many of those are within 10 %, and the readings called ok that are
more than 10 % and 3 standard errors off. Writes ``experiments/results/spectrum_defaults.json``.

Usage: ``PYTHONPATH=. python experiments/spectrum_defaults.py [--readings 25] [--out DIR]``
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from spectrum_synth import airy, planck, soap_index  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def divided_reading(d, rng, lo=450.0, hi=800.0, step=0.35):
    lam = np.arange(lo, hi, step)
    nu = 1.0 / lam
    x = 2.0 * (nu - nu.min()) / (nu.max() - nu.min()) - 1.0
    gain = 1.0 - 0.15 * x
    swing = 0.08
    noise = 0.01 * swing * planck(hi) / planck(lam)
    y = gain * (airy(d, lam, soap_index(lam)) + 0.01) + 0.002 + noise * rng.standard_normal(lam.shape)
    return lam, y


SERIES = {"A": (4048.0, 400.0), "B": (1500.0, 82.0)}
SEEDS = {"A": 1, "B": 2}
MODES = {"old defaults": ["--not-normalised", "--no-series"], "--normalised": ["--normalised", "--no-series"],
         "--normalised --series": ["--normalised", "--series"], "defaults": []}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readings", type=int, default=25)
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    from bubblefit.cli import main as cli

    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        files = {}
        for name, (d0, d1) in SERIES.items():
            rng = np.random.default_rng(SEEDS[name])
            truth = d0 * (d1 / d0) ** np.linspace(0.0, 1.0, args.readings)
            folder = Path(tmp) / name
            folder.mkdir()
            paths = []
            for k, d in enumerate(truth):
                lam, y = divided_reading(d, rng)
                p = folder / f"T{k:04d}.csv"
                np.savetxt(p, np.column_stack([lam, y]), delimiter=",", header="wavelength_nm,intensity", comments="")
                paths.append(str(p))
            files[name] = (paths, truth)
        for mode in args.modes.split(","):
            for name, (paths, truth) in files.items():
                out = Path(tmp) / f"{name}_{mode.replace(' ', '_')}.json"
                t0 = time.perf_counter()
                with contextlib.redirect_stdout(io.StringIO()) as said:
                    code = cli(["fit-spectrum", *paths, *MODES[mode], "--thickness-range", "0,15000",
                                "--json", str(out)])
                decisions = [line for line in said.getvalue().splitlines() if line.startswith("series:")]
                wall = time.perf_counter() - t0
                res = json.loads(out.read_text())["spectra"] if code == 0 else []
                rows[(mode, name)] = dict(truth=truth.tolist(), got=[r["thickness_nm"] for r in res],
                                          stderr=[r["thickness_nm_stderr"] for r in res], ok=[r["ok"] for r in res],
                                          normalised=[r["normalised"] for r in res], wall_s=wall, said=decisions,
                                          reasons=[r["reasons"] for r in res])
                print(f"{mode:>24} {name}: {wall:.0f} s " + " / ".join(decisions), file=sys.stderr, flush=True)
    table = {}
    print(f"{'mode':>24} {'series':>6} {'med rel':>8} {'<=10%':>6} {'ok (of them <=10%)':>19} {'ok & off':>8}")
    for mode in args.modes.split(","):
        for name in [*SERIES, "all"]:
            keys = [(mode, n) for n in SERIES] if name == "all" else [(mode, name)]
            truth = np.concatenate([rows[k]["truth"] for k in keys])
            got = np.concatenate([rows[k]["got"] for k in keys])
            err = np.concatenate([rows[k]["stderr"] for k in keys])
            ok = np.concatenate([rows[k]["ok"] for k in keys]).astype(bool)
            rel = np.abs(got - truth) / truth
            within = rel <= 0.1
            bad = ok & ~within & (np.abs(got - truth) > 3 * err)
            e = {"median_rel_err": float(np.median(rel)), "within_10pct": float(within.mean()), "ok": int(ok.sum()),
                 "ok_within_10pct": int((ok & within).sum()), "ok_and_off": int(bad.sum()), "readings": len(truth)}
            table[f"{mode} | {name}"] = e
            print(f"{mode:>24} {name:>6} {e['median_rel_err']:8.1%} {e['within_10pct']:6.0%} "
                  f"{e['ok']:>10} ({e['ok_within_10pct']:>3})     {e['ok_and_off']:>8}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = "spectrum_defaults.json" if args.modes == ",".join(MODES) else "spectrum_defaults_partial.json"
    (out / name).write_text(json.dumps(
        {"table": table, "rows": {f"{m} | {n}": v for (m, n), v in rows.items()}}, indent=1))


if __name__ == "__main__":
    main()
