"""What the sodium Newton's-rings photos leave unexplained: rings with and without stray light and a lamp envelope.

For each photo of ``experiments/real_photos.py`` (the 2x2-binned green channel, sRGB
decoded, clipped pixels left out) the mean squared residual of least-squares fits that are
linear once the gap is given, ``photo ~ E (g R(h) + c)`` (``c = g b``):

* ``R(h)``: the Airy reflectance of an air gap between BK7 glasses at 589.3 nm, normal
  incidence (:func:`bubblefit.optics.film.airy_reflectance`, mean of the polarisations);
* the gap ``h = h0 + r^2 / (2 R)`` of the rings (Born and Wolf sec. 7.5.3) at the
  colour-free start's centre and ``R`` (``start`` in ``real_photos.json``) and at the
  textbook ``R``, the offset ``h0`` the best of a 5 nm grid over one fringe; or the gap of
  the full fit (``grey.params``);
* with and without the stray reflectance ``b`` (light that does not interfere, added in
  intensity, Born and Wolf sec. 7.5.1);
* ``E`` = 1 (a uniform lamp, the ``newton`` model's) or the lamp's envelope: ``exp`` of a
  quadratic in the pixel coordinates fitted to the log of the photo's local mean (a
  Gaussian of 8 pixels, wider than the fringes): a Gaussian spot of the lamp; or the
  envelope the full fit found with the rings (``fitted``,
  :func:`bubblefit.inverse._newton.lamp_envelope` of its coefficients).

Run after ``experiments/real_photos.py`` (which writes the grey photos into its work
folder): ``python experiments/real_photos_residuals.py [--work real_photos_work]``; writes
``experiments/results/real_photos/residuals.json``. Seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "experiments" / "results" / "real_photos"
SODIUM_NM = 589.3
#: Width (pixels) of the local mean the lamp's envelope is fitted to: wider than the
#: fringes (1.5-20 pixels on these photos), narrower than the lamp's spot.
ENVELOPE_SIGMA_PX = 8.0


def _linear(png: Path) -> tuple[np.ndarray, np.ndarray]:
    """The grey photo decoded from sRGB (its green channel) and the mask of unclipped pixels."""
    from PIL import Image

    code = np.asarray(Image.open(png), np.float64)[..., 1] / 255.0
    lin = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)
    return lin, code < 254.5 / 255.0


def _envelope(lin: np.ndarray) -> np.ndarray:
    """``exp`` of the quadratic in the pixel coordinates nearest (least squares) the log of
    the photo's local mean (a Gaussian of :data:`ENVELOPE_SIGMA_PX`)."""
    from scipy import ndimage

    h, w = lin.shape
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    x, y = xx.ravel(), yy.ravel()
    a = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    coef, *_ = np.linalg.lstsq(a, np.log(np.maximum(ndimage.gaussian_filter(lin, ENVELOPE_SIGMA_PX), 1e-6)).ravel(),
                               rcond=None)
    return np.exp(a @ coef).reshape(h, w)


def _mse(refl, env, lin, keep, stray: bool) -> tuple[float, float]:
    """``(mean squared residual, b)`` of ``lin ~ env (g refl + c)`` by least squares, ``b = c / g``."""
    m, e, p = refl[keep], env[keep], lin[keep]
    a = np.column_stack([m * e, e]) if stray else (m * e)[:, None]
    coef, *_ = np.linalg.lstsq(a, p, rcond=None)
    return float(np.mean((p - a @ coef) ** 2)), float(coef[1] / coef[0]) if stray else 0.0


def main() -> int:
    from bubblefit.inverse._newton import ENVELOPE_TERMS, envelope_coordinates, lamp_envelope
    from bubblefit.optics import dispersion
    from bubblefit.optics.film import airy_reflectance

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("real_photos_work"))
    args = ap.parse_args()
    records = json.loads((OUT / "real_photos.json").read_text())["photos"]
    n_glass = float(dispersion.refractive_index("bk7", SODIUM_NM))

    def airy(h):
        refl = airy_reflectance(np.asarray(h, np.float64), SODIUM_NM, 1.0, 1.0, n_glass, n_glass)
        return np.asarray(refl, np.float64).mean(-1)

    out = []
    for rec in records:
        png = args.work / f"rings_{rec['stated_radius_mm']}_grey.png"
        if not png.exists():
            print(f"{png} is missing: run experiments/real_photos.py --work {args.work} first", file=sys.stderr)
            return 1
        lin, keep = _linear(png)
        h, w = lin.shape
        pitch = rec["pixel_um_binned"]
        yy, xx = np.mgrid[0:h, 0:w]
        x, y = (xx + 0.5) * pitch, (yy + 0.5) * pitch
        envs = {"uniform": np.ones_like(lin), "envelope": _envelope(lin)}
        g = rec.get("grey", {}).get("params")
        if g and g.get("envelope_ratio", 1.0) != 1.0:  # the full fit's own lamp envelope
            u, v = envelope_coordinates(x.ravel(), y.ravel())
            envs["fitted"] = np.asarray(lamp_envelope(u, v, [g[k] for k in ENVELOPE_TERMS]), np.float64).reshape(h, w)
        row = {"stated_radius_mm": rec["stated_radius_mm"], "photo_variance": float(lin[keep].var()),
               "envelope_max_over_min": float(envs["envelope"].max() / envs["envelope"].min()), "fits": []}
        s = rec["start"]
        cx, cy = s["centre_px"][0] * pitch, s["centre_px"][1] * pitch  # the start's pixel-centre convention
        r2 = (x - cx) ** 2 + (y - cy) ** 2
        for what, radius_mm in (("rings at the start's R", s["radius_mm"]), ("rings at the textbook R",
                                                                             rec["textbook_radius_mm"])):
            for env_name, env in envs.items():
                for stray in (False, True):
                    best = min(_mse(airy(h0 + r2 / (2.0 * radius_mm)), env, lin, keep, stray) + (float(h0),)
                               for h0 in np.arange(0.0, 0.5 * SODIUM_NM, 5.0))  # r2 um^2 / R mm = nm
                    row["fits"].append({"gap": what, "radius_mm": radius_mm, "lamp": env_name, "stray": stray,
                                        "mse": best[0], "b": best[1], "h0_nm": best[2]})
        if g:
            rf = g["radius_mm"] * 1000.0
            r2f = (x - g["center_x_um"]) ** 2 + (y - g["center_y_um"]) ** 2
            hfit = np.maximum(1000.0 * r2f / (rf + np.sqrt(rf * rf - r2f)) + g["contact_offset_nm"], 0.0)
            for env_name, env in envs.items():
                for stray in (False, True):
                    mse, b = _mse(airy(hfit), env, lin, keep, stray)
                    row["fits"].append({"gap": "the full fit's", "radius_mm": g["radius_mm"], "lamp": env_name,
                                        "stray": stray, "mse": mse, "b": b})
        out.append(row)
        for f in row["fits"]:
            print(rec["stated_radius_mm"], f["gap"], f"{f['radius_mm']:.4g}", f["lamp"], f["stray"],
                  f"{f['mse']:.4f}", f"{f['b']:.3f}")
    (OUT / "residuals.json").write_text(json.dumps({"script": "experiments/real_photos_residuals.py", "photos": out},
                                                   indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
