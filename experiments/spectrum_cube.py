"""Time and accuracy of a thickness map from a synthetic spectral cube (``fit_cube``).

A 512 x 512 x 128 cube (420-780 nm) of a soap film thickening from 150 nm to 10 um
across the image, synthesised with the Airy formula written here (Born & Wolf 7.6(13)),
the soap solution's dispersion, a 3000 K lamp times a Gaussian response, an illumination
varying over the image, stray light and 1 % noise. Reports the map's median and 90th
percentile errors, the order hops (pixels more than half an order off), the share of ok
pixels, the wall time of ``fit_cube`` and the load average before and after (the machine
is shared). Writes ``experiments/results/spectrum_cube.json``.

Usage: ``PYTHONPATH=. python experiments/spectrum_cube.py [--size 512] [--bands 128]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from spectrum_synth import airy, lamp, soap_index  # noqa: E402


def synth(size, bands, dmin=150.0, dmax=10000.0, noise=0.01, seed=0):
    rng = np.random.default_rng(seed)
    lam = np.linspace(420.0, 780.0, bands)
    yy, xx = np.mgrid[0:size, 0:size]
    t = dmin + (dmax - dmin) * (0.75 * (xx / (size - 1)) ** 1.5 + 0.25 * (yy / (size - 1)))
    illum = 0.7 + 0.3 * np.cos(2.0 * xx / size) * np.cos(yy / size)
    peak = 0.08
    cube = np.empty((size, size, bands), np.float32)
    for i in range(size):  # row by row: the synthesis, not the fit
        r = airy(t[i][:, None], lam, soap_index(lam))
        cube[i] = illum[i][:, None] * lamp(lam) * r + 0.04 * peak + noise * peak * rng.standard_normal(r.shape)
    return lam, cube, t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--bands", type=int, default=128)
    args = ap.parse_args()
    from bubblefit.inverse.spectral_map import MapOptions, count_order_hops, fit_cube
    from bubblefit.io.cubes import SpectralCube

    lam, cube, t = synth(args.size, args.bands)
    fit_cube(SpectralCube(lam, cube[:16, :16], (0, 1, 2), "warm-up"))  # compile once, outside the timing
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    m = fit_cube(SpectralCube(lam, cube, (0, 1, 2), "synthetic"), options=MapOptions())
    wall = time.perf_counter() - t0
    load1 = os.getloadavg()
    err = np.abs(m.thickness_nm - t)
    out = {"size": args.size, "bands": args.bands, "wall_s": wall, "load_before": load0, "load_after": load1,
           "cpus": os.cpu_count(), "median_err_nm": float(np.nanmedian(err)),
           "p90_err_nm": float(np.nanpercentile(err, 90)),
           "order_hops": count_order_hops(m.thickness_nm, t, m.order_spacing_nm),
           "fraction_ok": float(m.ok.mean()), "median_stderr_nm": float(np.median(m.stderr_nm[m.ok])),
           "median_abs_pull": float(np.median(err[m.ok] / m.stderr_nm[m.ok]))}
    print(json.dumps(out, indent=1))
    res = Path(__file__).resolve().parent / "results"
    res.mkdir(exist_ok=True)
    (res / "spectrum_cube.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
