"""Closing the loop: one film measured from a camera's photo and from a spectrometer.

A soap film whose thickness falls linearly across the frame (a wedge, 150 to 1500 nm,
the soap-solution index law) is lit by a halogen lamp (CIE illuminant A) and

- photographed by a camera with measured sensitivities (colour-science's
  ``MSDS_CAMERA_SENSITIVITIES``, default ``Nikon 5100 (NPL)``), white-balanced to the
  lamp, exposed with a white card, with photon noise and 8-bit quantisation of the
  sRGB-encoded photo;
- read by a spectrometer at a few spots (the same lamp times a spectrometer response,
  1.5 nm resolution, 1% noise, a dark offset), without a reference reading.

The photo and the spectra are synthesised by numpy code in this file (Airy reflectance,
the sensitivities integrated at 1 nm), independent of bubblefit. The photo is read
pixel by pixel against bubblefit's interference chart (``optics.chart``) built three ways:
with the camera's response, the lamp and the index law (the model of the measurement);
with bubblefit's former defaults (sRGB observer, D65, n = 1.4); and with the camera and lamp
but a constant n = 1.333. Each pixel's thickness is the chart entry nearest its colour,
tracked along the wedge (the search window follows the previous pixel: interference
colours repeat with the order). The spectra are read with ``fit_spectrum``.

Prints a table, writes ``experiments/results/camera_and_spectrum.{csv,json,png}``.
Usage: ``PYTHONPATH=. python experiments/camera_and_spectrum.py [--camera NAME]``
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import colour
import numpy as np

from spectrum_vs_optifik import airy, soap_index  # noqa: E402  (the same independent film, one copy)

RESULTS = Path(__file__).resolve().parent / "results"
D_TOP, D_BOTTOM, WIDTH = 150.0, 1500.0, 400


def photograph(d, camera: str, rng) -> np.ndarray:
    """8-bit sRGB-encoded photo (decoded back to linear) of films of thickness ``d`` (N,)."""
    lam = np.arange(380.0, 781.0, 1.0)
    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    sens = np.stack([np.interp(lam, msds.wavelengths, msds.values[:, c], left=0, right=0) for c in range(3)], 1)
    a = colour.SDS_ILLUMINANTS["A"]
    ill = np.interp(lam, a.wavelengths, a.values)
    white = (sens * ill[:, None]).sum(0)  # the white card: white balance and exposure
    refl = airy(d[:, None], lam[None, :], soap_index(lam)[None, :])
    raw = (refl * ill) @ sens / white
    exposure = 0.9 / raw.max()
    img = raw * exposure
    img = np.clip(img + np.sqrt(np.maximum(img, 0) * 2e-4) * rng.standard_normal(img.shape), 0, 1)
    enc = np.round(colour.cctf_encoding(img, function="sRGB") * 255) / 255
    return np.asarray(colour.cctf_decoding(enc, function="sRGB")) / exposure


def spectrometer(d: float, rng):
    lam = np.arange(400.0, 800.01, 0.5)
    fine = np.arange(385.0, 815.0, 0.02)
    a = colour.SDS_ILLUMINANTS["A"]
    lamp = np.interp(fine, a.wavelengths, a.values) * np.exp(-0.5 * ((fine - 620) / 160) ** 2)
    s = lamp / lamp.max() * airy(d, fine, soap_index(fine))
    sig = 1.5 / 2.35482
    m = int(5 * sig / 0.02)
    g = np.exp(-0.5 * (np.arange(-m, m + 1) * 0.02 / sig) ** 2)
    y = np.interp(lam, fine, np.convolve(s, g / g.sum(), mode="same"))
    return lam, y + 0.01 + 0.01 * y.max() * rng.standard_normal(lam.shape)


def read_photo(rgb: np.ndarray, chart_d: np.ndarray, chart_rgb: np.ndarray, window: float = 60.0) -> np.ndarray:
    """Per-pixel thickness: the chart entry nearest in colour, tracked along the wedge."""
    out = np.empty(len(rgb))
    prev = None
    for i, c in enumerate(rgb):
        sel = slice(None) if prev is None else (np.abs(chart_d - prev) <= window)
        cand_d, cand = chart_d[sel], chart_rgb[sel]
        k = int(np.argmin(np.sum((cand - c) ** 2, axis=1)))
        out[i] = prev = cand_d[k]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--camera", default="Nikon 5100 (NPL)", choices=list(colour.MSDS_CAMERA_SENSITIVITIES))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    from bubblefit.inverse.spectrum import fit_spectrum
    from bubblefit.io.spectra import Spectrum
    from bubblefit.optics import spectral
    from bubblefit.optics.chart import interference_colours

    rng = np.random.default_rng(args.seed)
    d_true = np.linspace(D_TOP, D_BOTTOM, WIDTH)
    photo = photograph(d_true, args.camera, rng)
    chart_d = np.arange(50.0, 2000.0, 0.5)
    models = {
        "camera+lamp+dispersion": dict(basis=spectral.spectral_basis("reference", illuminant="A", response=args.camera),
                                       n_film="soap"),
        "srgb+D65+n1.4 (old defaults)": dict(basis=spectral.spectral_basis("reference"), n_film=1.4),
        "camera+lamp, n=1.333": dict(basis=spectral.spectral_basis("reference", illuminant="A", response=args.camera),
                                     n_film=1.333),
    }
    photo_d = {}
    for name, kw in models.items():
        chart = interference_colours(chart_d, **kw)
        photo_d[name] = read_photo(photo, chart_d, chart)
    spots = np.linspace(20, WIDTH - 20, 6).astype(int)
    rows = []
    for i in spots:
        lam, y = spectrometer(d_true[i], rng)
        r = fit_spectrum(Spectrum(lam, y))
        row = {"pixel": int(i), "true_nm": float(d_true[i]), "spectrum_nm": r.thickness_nm,
               "spectrum_stderr_nm": r.thickness_nm_stderr, "spectrum_ok": r.ok}
        for name in models:
            row[f"photo[{name}]_nm"] = float(photo_d[name][i])
        rows.append(row)
    summary = {name: {"median_abs_err_nm": float(np.median(np.abs(v - d_true))),
                      "p90_abs_err_nm": float(np.percentile(np.abs(v - d_true), 90))} for name, v in photo_d.items()}
    ok_rows = [r for r in rows if r["spectrum_ok"]]
    summary["spectrum"] = {"median_abs_err_nm": float(np.median([abs(r["spectrum_nm"] - r["true_nm"]) for r in ok_rows]))
                           if ok_rows else float("nan"), "spots_ok": len(ok_rows), "spots": len(rows)}
    key = "photo[camera+lamp+dispersion]_nm"
    summary["photo_minus_spectrum_at_spots_nm"] = [r[key] - r["spectrum_nm"] for r in rows]

    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / "camera_and_spectrum.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (RESULTS / "camera_and_spectrum.json").write_text(json.dumps({"camera": args.camera, "summary": summary,
                                                                  "spots": rows}, indent=1))
    _plot(d_true, photo_d, rows, RESULTS / "camera_and_spectrum.png", args.camera)
    print(f"camera {args.camera}, illuminant A, wedge {D_TOP:g}-{D_BOTTOM:g} nm over {WIDTH} pixels")
    for name, s in summary.items():
        print(f"  {name:32s} {s}")
    for r in rows:
        print(f"  spot {r['pixel']:4d}: true {r['true_nm']:7.1f}  spectrum {r['spectrum_nm']:7.1f} +- "
              f"{r['spectrum_stderr_nm']:.2g} (ok={r['spectrum_ok']})  photo {r[key]:7.1f}")
    return 0


def _plot(d_true, photo_d, rows, path, camera):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(8, 6), dpi=110, sharex=True)
    x = np.arange(len(d_true))
    ax[0].plot(x, d_true, "k-", lw=1, label="true")
    for name, v in photo_d.items():
        ax[0].plot(x, v, ".", ms=2, label=f"photo, {name}")
        ax[1].plot(x, v - d_true, ".", ms=2)
    ax[0].errorbar([r["pixel"] for r in rows], [r["spectrum_nm"] for r in rows],
                   yerr=[r["spectrum_stderr_nm"] for r in rows], fmt="s", color="C3", ms=5, label="spectrum")
    ax[1].plot([r["pixel"] for r in rows], [r["spectrum_nm"] - r["true_nm"] for r in rows], "s", color="C3", ms=5)
    ax[0].set_ylabel("thickness (nm)")
    ax[0].legend(fontsize=7)
    ax[0].set_title(f"one wedge film, photographed ({camera}, illuminant A) and read by a spectrometer", fontsize=9)
    ax[1].set_ylabel("error (nm)")
    ax[1].set_ylim(-150, 150)
    ax[1].set_xlabel("pixel along the wedge")
    fig.tight_layout()
    fig.savefig(path)


if __name__ == "__main__":
    sys.exit(main())
