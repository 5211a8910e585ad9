"""A draining film read as one series under one lamp (``fit-spectrum --shared-lamp``) on real readings.

optifik's ``spectraVictor2`` readings (https://github.com/sciunto/optifik, folder ``data/``;
pass that folder as ``DATA_DIR``, nothing of it is copied here) follow one soap film from
interference order 5 down to the black film, with one lamp, one spectrometer and one
reading of the empty frame (``void.xy``, the dark). Every reading with a stated thickness
(optifik's ``known_value*.yaml`` and ``known_to_fail.yaml``: the field's own readings, not
an independent truth) is read, in time order (the ``T`` number of the file), at 450 nm and
up with the soap index law and ``--normalised`` (the readings were divided by the lamp):

- alone (``fit_spectrum``, each reading by itself, as ``bubblefit fit-spectrum`` does);
- as a series (``fit_spectrum_series``): the readings that are ok alone fit the lamp, the
  others are read with it.

optifik's own reading of each file by its reference method (Scheludko's formula; at
order 0 with the void reading) is taken from ``experiments/results/spectrum_real.json``
when ``spectrum_real.py`` has been run. A result *fails* when it is more than 10 % + 2 nm
off the stated value; ``ok and off`` counts the failures called ok. Prints a table per
order, writes ``experiments/results/spectrum_series.{json,png}``.

Usage: ``PYTHONPATH=. python experiments/spectrum_series.py DATA_DIR [--stride K]``
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
sys.path.insert(0, str(Path(__file__).resolve().parent))
from spectrum_real import stated_values  # noqa: E402  (optifik's yaml entries, one parser)


def stated(data: Path) -> dict[str, float]:
    """``orderK/Txxxx.xy -> stated thickness`` of the spectraVictor2 series."""
    out = {}
    for k in range(6):
        for y in sorted((data / "spectraVictor2" / f"order{k}").glob("known*.yaml")):
            out.update({f"order{k}/{name}": v for name, v in stated_values(y).items()})
    return out


def summary(rows, key, err_key) -> dict:
    e = np.array([r[key] - r["stated"] for r in rows if np.isfinite(r.get(key, np.nan))])
    s = np.array([abs(r["stated"]) for r in rows if np.isfinite(r.get(key, np.nan))])
    out = {"files": int(len(e)), "median_abs_err_nm": float(np.median(np.abs(e))) if len(e) else float("nan"),
           "off": int(np.sum(np.abs(e) > 0.1 * s + 2.0))}
    if err_key:
        ok = np.array([r[err_key + "_ok"] for r in rows])
        se = np.array([r[err_key + "_stderr"] for r in rows])
        e_all = np.array([r[key] - r["stated"] for r in rows])
        off = np.abs(e_all) > 0.1 * np.abs([r["stated"] for r in rows]) + 2.0
        out.update(ok=int(ok.sum()), ok_and_off=int(np.sum(ok & off)),
                   median_err_over_stderr=float(np.median(np.abs(e_all) / se)),
                   median_abs_err_ok_nm=float(np.median(np.abs(e_all[ok]))) if ok.any() else float("nan"))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--stride", type=int, default=1, help="every K-th reading (in time order)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    from bubblefit.inverse.spectrum import SpectrumOptions, fit_spectrum
    from bubblefit.inverse.spectrum_series import fit_spectrum_series
    from bubblefit.io.spectra import read_spectrum

    vals = stated(args.data)
    names = sorted(vals, key=lambda n: int(re.sub(r"\D", "", Path(n).stem)))[:: args.stride]
    folder = args.data / "spectraVictor2"
    spectra = [read_spectrum(folder / n) for n in names]
    dark = read_spectrum(folder / "void.xy")
    opts = SpectrumOptions(normalised=True, wavelength_range=(450.0, float(spectra[0].wavelength_nm.max())))
    t0 = time.perf_counter()
    alone = [fit_spectrum(s, dark=dark, options=opts) for s in spectra]
    t_alone = time.perf_counter() - t0
    t0 = time.perf_counter()
    series, lamp = fit_spectrum_series(spectra, dark=dark, options=opts)
    t_series = time.perf_counter() - t0
    optifik = {}
    real = RESULTS / "spectrum_real.json"
    if real.exists():
        for r in json.loads(real.read_text())["rows"]:
            if r["file"].startswith("spectraVictor2/"):
                optifik[r["file"].removeprefix("spectraVictor2/")] = r.get("of_ref", float("nan"))
    rows = []
    for n, a, s in zip(names, alone, series):
        rows.append(dict(file=n, order=int(n[5]), stated=vals[n],
                         alone=a.thickness_nm, alone_stderr=a.thickness_nm_stderr,
                         alone_ok=bool(a.ok), series=s.thickness_nm, series_stderr=s.thickness_nm_stderr,
                         series_ok=bool(s.ok), pinned=bool(lamp is not None and names.index(n) in lamp.pinning),
                         optifik=float(optifik.get(n, float("nan")) if optifik.get(n) is not None else float("nan"))))
    groups = {}
    print(f"{len(names)} readings; alone {t_alone:.0f} s, series {t_series:.0f} s; "
          + (f"lamp from {len(lamp.pinning)} readings, brightness spread {lamp.scale_spread:.1%}"
             if lamp else "no lamp"))
    print(f"{'order':>5} {'files':>5} | {'alone':>22} | {'series':>30} | {'optifik':>8}")
    for k in range(6):
        rk = [r for r in rows if r["order"] == k]
        if not rk:
            continue
        g = {"alone": summary(rk, "alone", "alone"), "series": summary(rk, "series", "series"),
             "optifik": summary(rk, "optifik", None)}
        groups[f"order{k}"] = g
        a, s, o = g["alone"], g["series"], g["optifik"]
        print(f"{k:>5} {len(rk):>5} | {a['median_abs_err_nm']:6.1f} nm ok {a['ok']:3d} off-ok {a['ok_and_off']:3d} | "
              f"{s['median_abs_err_nm']:6.1f} nm ok {s['ok']:3d} off-ok {s['ok_and_off']:3d} "
              f"e/se {s['median_err_over_stderr']:4.2f} | "
              f"{o['median_abs_err_nm']:6.1f} nm")
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"readings": len(names), "stride": args.stride, "time_alone_s": t_alone, "time_series_s": t_series,
            "lamp": None if lamp is None else {"pinning": len(lamp.pinning), "scale_spread": lamp.scale_spread}}
    (args.out / "spectrum_series.json").write_text(json.dumps({"meta": meta, "groups": groups, "rows": rows}, indent=1))
    _plot(rows, args.out / "spectrum_series.png")


def _plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = np.arange(len(rows))
    get = lambda key: np.array([r[key] for r in rows], dtype=float)  # noqa: E731
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5), dpi=100)
    for ax, lim in zip(axes, (None, 260.0)):
        ax.plot(k, get("stated"), "-", color="0.3", lw=1, label="stated (optifik's reading)")
        ok = get("series_ok").astype(bool)
        ax.errorbar(k[ok], get("series")[ok], get("series_stderr")[ok], fmt="o", ms=2.5, lw=0.6, color="C0",
                    label="bubblefit series, ok")
        ax.errorbar(k[~ok], get("series")[~ok], get("series_stderr")[~ok], fmt="x", ms=3, lw=0.6, color="C3",
                    label="bubblefit series, not ok")
        ax.plot(k, get("alone"), ".", ms=2, color="C2", alpha=0.6, label="bubblefit alone")
        if np.isfinite(get("optifik")).any():
            ax.plot(k, get("optifik"), "+", ms=3, color="C1", alpha=0.7, label="optifik (reference method)")
        ax.set_xlabel("reading, in time order")
        ax.set_ylabel("thickness (nm)")
        if lim:
            ax.set_ylim(-20.0, lim)
            first = int(np.argmax(get("stated") < lim))
            ax.set_xlim(first - 2, len(rows))
    axes[0].set_ylim(-20.0, 1.2 * np.nanmax(get("stated")))
    axes[0].legend(fontsize=7)
    axes[1].set_title("orders 0-1", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    main()
