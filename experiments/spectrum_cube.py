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


def truth(size, dmin=150.0, dmax=10000.0):
    """The film's thickness (size, size), nm: a wedge from ``dmin`` to ``dmax``."""
    yy, xx = np.mgrid[0:size, 0:size]
    return dmin + (dmax - dmin) * (0.75 * (xx / (size - 1)) ** 1.5 + 0.25 * (yy / (size - 1)))


def synth(size, bands, dmin=150.0, dmax=10000.0, noise=0.01, seed=0, out=None):
    rng = np.random.default_rng(seed)
    lam = np.linspace(420.0, 780.0, bands)
    yy, xx = np.mgrid[0:size, 0:size]
    t = truth(size, dmin, dmax)
    illum = 0.7 + 0.3 * np.cos(2.0 * xx / size) * np.cos(yy / size)
    peak = 0.08
    cube = out if out is not None else np.empty((size, size, bands), np.float32)
    for i in range(size):  # row by row: the synthesis, not the fit
        r = airy(t[i][:, None], lam, soap_index(lam))
        cube[i] = illum[i][:, None] * lamp(lam) * r + 0.04 * peak + noise * peak * rng.standard_normal(r.shape)
    return lam, cube, t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--bands", type=int, default=128)
    ap.add_argument("--write-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--memmap", metavar="DIR", help="write the cube to DIR/cube.npy and fit it from the file "
                    "(memory-mapped, read a block at a time): the peak memory is then the fit's, not the cube's")
    args = ap.parse_args()
    from bubblefit.inverse.spectral_map import MapOptions, count_order_hops, fit_cube
    from bubblefit.io.cubes import SpectralCube

    import resource

    from bubblefit.io.cubes import read_cube

    if args.memmap:
        path = Path(args.memmap) / "cube.npy"
        if args.write_only or not path.exists():
            if not args.write_only:  # written by a child process, so that its pages are not this one's peak
                import subprocess

                subprocess.run([sys.executable, __file__, "--size", str(args.size), "--bands", str(args.bands),
                                "--memmap", args.memmap, "--write-only"], check=True)
            else:
                mm = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32,
                                               shape=(args.size, args.size, args.bands))
                lam, _, _ = synth(args.size, args.bands, out=mm)
                mm.flush()
                np.savetxt(Path(args.memmap) / "bands.txt", lam)
                return
        lam, t = np.loadtxt(Path(args.memmap) / "bands.txt"), truth(args.size)
        source = read_cube(path, wavelengths=Path(args.memmap) / "bands.txt")
    else:
        lam, cube_array, t = synth(args.size, args.bands)
        source = SpectralCube(lam, cube_array, (0, 1, 2), "synthetic")
    fit_cube(SpectralCube(lam, np.asarray(source.rows(0, 16))[:, :16], (0, 1, 2), "warm-up"))  # compile first
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    m = fit_cube(source, options=MapOptions())
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    load1 = os.getloadavg()
    err = np.abs(m.thickness_nm - t)
    out = {"size": args.size, "bands": args.bands, "memmap": bool(args.memmap),
           "cube_mb": args.size**2 * args.bands * 4 / 2**20,
           "peak_rss_mb_before_fit": rss0, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
           "wall_s": wall, "cpu_s": cpu, "load_before": load0, "load_after": load1,
           "cpus": os.cpu_count(), "median_err_nm": float(np.nanmedian(err)),
           "p90_err_nm": float(np.nanpercentile(err, 90)),
           "order_hops": count_order_hops(m.thickness_nm, t, m.order_spacing_nm),
           "fraction_ok": float(m.ok.mean()), "median_stderr_nm": float(np.median(m.stderr_nm[m.ok])),
           "median_abs_pull": float(np.median(err[m.ok] / m.stderr_nm[m.ok]))}
    print(json.dumps(out, indent=1))
    res = Path(__file__).resolve().parent / "results"
    res.mkdir(exist_ok=True)
    name = f"spectrum_cube_{args.size}x{args.bands}" + ("_memmap" if args.memmap else "")
    (res / f"{name}.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
