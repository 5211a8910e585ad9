"""What sets the Newton validation photo's fitted radius: fits of it with one thing changed.

The photo is experiments/validation/data/film_newton_bk7_na010 (reference_films.py: BK7
lens R = 100 mm, NA 0.1, 3200 K). Two measurements (docs/films.md, worked example 1):

* ``fit [--photo P] [--samples K] [--no-box] [--envelope none]``: the ``newton`` fit
  (bubblefit.inverse.planar.fit_planar, as the command line runs it) of the photo or of
  another render of it (a linear EXR: no clipping), with ``K`` spectral samples instead of
  :data:`bubblefit.inverse.planar.SPECTRAL_SAMPLES`, or without the pixel's box average
  (:func:`bubblefit.inverse._newton.pixel_mean` at a pitch of 0: the colour at the
  pixel's centre), or without the lamp's envelope. Prints R, its standard error and the
  fit's CPU seconds as one JSON line.
* ``scale [K ...]``: the scale ``s`` of the gap for which bubblefit's forward at ``s h``
  best matches (least squares, a free gain) the reference renderer's noise-free colours
  at the photo's pixel centres ``h`` (no box on either side), per number of spectral
  samples: ``1/s`` is the radius a fit without noise would read, in units of the true one.

Run from the repository root with the project's venv; minutes per fit on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CASE = ROOT / "experiments" / "validation" / "data" / "film_newton_bk7_na010"


def fit(args) -> dict:
    import bubblefit.inverse._newton as newton
    import bubblefit.inverse.planar as planar
    from bubblefit.io.camera_files import read_photo
    from bubblefit.model.planar_scene import load_planar

    if args.samples:
        planar.SPECTRAL_SAMPLES = args.samples
        planar.PlanarForward.__init__.__defaults__ = (args.samples,)
    if args.no_box:
        box = newton.pixel_mean
        newton.pixel_mean = lambda fwd, h, s2, b, gx, gy, pitch, lo, hi: box(fwd, h, s2, b, gx, gy, 0.0, lo, hi)
    scene = load_planar(CASE / "scene.toml")
    if args.envelope:
        scene = replace(scene, envelope=args.envelope)
    photo = args.photo or CASE / "photo.png"
    pixels = read_photo(str(photo), dtype=np.float64).pixels[..., :3]
    cpu = time.process_time()
    res = planar.fit_planar(pixels, scene, kind="newton", clip_high=np.inf if str(photo).endswith(".exr") else 1.0)
    return {"photo": str(photo), "samples": args.samples or planar.SPECTRAL_SAMPLES, "box": not args.no_box,
            "envelope": args.envelope or scene.envelope, "radius_mm": res.params["radius_mm"],
            "radius_stderr_mm": res.stderr["radius_mm"], "reduced_chi2": res.reduced_chi2,
            "cpu_seconds": round(time.process_time() - cpu, 1)}


def scale(samples) -> list[dict]:
    import jax
    import jax.numpy as jnp

    import bubblefit.inverse.planar as planar
    from bubblefit.optics import coaxial

    sys.path.insert(0, str(ROOT / "experiments" / "validation"))
    import reference_films as rf

    h, ref = rf.newton_case(sub=1)
    hv, rv = h.ravel(), ref.reshape(-1, 3)
    out = []
    for k in samples:
        fwd = planar.PlanarForward(coaxial.Stack("bk7", "air", "bk7"), "3200K", "srgb", 0.1, 4000.0, k)
        f = jax.jit(lambda s: fwd.rgb(jnp.asarray(hv, jnp.float32) * s, 0.0))

        def cost(s):
            m = np.asarray(f(jnp.float32(s)), np.float64)
            g = float((m * rv).sum() / (m * m).sum())
            return float(((g * m - rv) ** 2).sum())

        ss = 1.0 + np.linspace(-1e-3, 1e-3, 41)
        c = np.array([cost(s) for s in ss])
        i = int(np.clip(np.argmin(c), 2, len(ss) - 3))
        a, b, _ = np.polyfit(ss[i - 2:i + 3], c[i - 2:i + 3], 2)
        out.append({"samples": k, "bin_nm": 400.0 / k, "scale": -b / (2 * a)})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    f = sub.add_parser("fit")
    f.add_argument("--photo", type=Path)
    f.add_argument("--samples", type=int, default=0)
    f.add_argument("--no-box", action="store_true")
    f.add_argument("--envelope", choices=["none", "fit", "auto"])
    s = sub.add_parser("scale")
    s.add_argument("samples", type=int, nargs="*", default=[80, 800])
    args = ap.parse_args()
    print(json.dumps(fit(args) if args.what == "fit" else scale(args.samples)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
