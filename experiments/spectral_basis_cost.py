"""What the fit's spectral quadrature costs in accuracy and in time, on a validation photo
at its true parameters.

For one case of ``experiments/validation`` this builds the fit's own set-up (the
physical model, the fit's bounces, the pixel footprint where the fit turns it on, the
background photo; the true disc of an orthographic case, the case's scene for a
perspective one), sets the true thickness (constant or drainage), exposure, a mirror film
and no diffuse term, and renders the photo at full resolution with each spectral basis
asked for. Per basis it prints:

* the colour check's statistic per degree of freedom
  (:func:`bubblefit.inverse.colour_check.colour_check`, threshold 1.64) and the reduced
  chi^2 with the 3 % model-error floor over the fitted pixels (black-clipped channels
  censored, as the fit censors them): what the quadrature leaves
  before anything is fitted;
* the render's CPU time (user + system of this process, the median of ``REPEATS`` warm
  calls, after one call that compiles), and its ratio to the 8-lobe basis' in the same
  run, with the load average beside it;
* what the fit's rule reads for this basis on the case's true films
  (:func:`bubblefit.inverse.quadrature_excess`: the largest addition of its hue error to
  the colour check's statistic per degree of freedom on a noise-free cell; the rule
  allows 0.25).

Run from the repository root (names as ``method/samples``):

    PYTHONPATH=. .venv/bin/python experiments/spectral_basis_cost.py CASE \
        [fourier/8 fourier/10 fourier/12 fourier/16 uniform/64 uniform/100]
"""
from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import replace

import numpy as np

D = os.path.join(os.path.dirname(os.path.abspath(__file__)), "validation", "data")
REPEATS = 3
DEFAULT_BASES = ("fourier/8", "fourier/10", "fourier/12", "fourier/16", "uniform/64", "uniform/100")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        print(__doc__)
        return 2
    case, names = argv[0], argv[1:] or DEFAULT_BASES
    import jax.numpy as jnp

    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import FitOptions, censored_residual, noise_sigma
    from bubblefit.inverse._programs import render_level
    from bubblefit.inverse._setup import setup
    from bubblefit.inverse.colour_check import INNER_COS, colour_check
    from bubblefit.inverse import quadrature_excess
    from bubblefit.io.images import read_image
    from bubblefit.model.scene import load_scene, read_envmap
    from bubblefit.optics.spectral import SpectralBasis

    t = json.load(open(f"{D}/{case}/truth.json"))
    photo = read_image(f"{D}/{case}/photo.png").pixels
    bg = read_image(f"{D}/{case}/background.png").pixels
    env = read_envmap(f"{D}/{t['envmap']}")
    th = t["thickness"]
    kind = "constant" if th["profile"] == "constant" else "drainage"
    scene = None
    if t["camera"]["type"] == "orthographic":
        d = t["disc"]
        opts = FitOptions(thickness=kind, model="physical", view=ORTHOGRAPHIC, illuminant=t["illuminant"],
                          disc=(d["cx"], d["cy"], d["r"]))
    else:
        scene = load_scene(f"{D}/{case}/scene.toml")
        opts = FitOptions(thickness=kind, model="physical", illuminant=t["illuminant"])
    st = setup(photo, env, opts, bg, None, scene, None)
    vals = dict(st.vals, exposure=float(t["exposure"]), roughness=0.0, r_d=0.0, rotation_deg=0.0,
                n_film=float(t["bubble"]["n_film"]), disc_x=0.0, disc_y=0.0, disc_r=0.0)
    if kind == "constant":
        vals["thickness_nm"] = float(th["thickness_nm"])
        lo = hi = float(th["thickness_nm"])
    else:
        vals.update(top_nm=float(th["top_nm"]), bottom_nm=float(th["bottom_nm"]), exponent=float(th["exponent"]))
        lo, hi = sorted((float(th["top_nm"]), float(th["bottom_nm"])))
    p = st.table.render_params({k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if np.ndim(v) == 0})
    full = st.level(1, opts)
    sig = noise_sigma(photo, 2e-3, 2e-4, 8)
    inner = full.mask & (full.cos > INNER_COS)
    fx = st.base_cfg.effects
    min_cos = float(np.min(full.cos[full.mask]))
    print(f"{case}: {kind} {lo:.0f}-{hi:.0f} nm, incidence cosines {min_cos:.2f}-1, "
          f"footprint {st.base_cfg.pixel_footprint}, bounces {fx.bounces}, load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"{'basis':12s} {'samples':>7s} {'colour':>7s} {'chi2 fl':>7s} {'cpu s':>7s} {'x 8 lobes':>9s} "
          f"{'excess':>8s}")
    base_cpu = None
    for name in names:
        method, k = name.split("/")
        basis = SpectralBasis(method, int(k), illuminant=t["illuminant"])
        cfg = replace(full.cfg, effects=replace(fx, spectral=basis))
        img = np.asarray(render_level(p, full, env, cfg=cfg), np.float64)  # compiles
        cpu = []
        for _ in range(REPEATS):
            c0 = time.process_time()
            img = np.asarray(render_level(p, full, env, cfg=cfg), np.float64)
            cpu.append(time.process_time() - c0)
        cpu = float(np.median(cpu))
        base_cpu = cpu if name == "fourier/8" else base_cpu
        cc = colour_check(photo, img, inner, sig, model_error=0.03)
        r = censored_residual(photo, img, xp=np)
        chi = np.sum(r**2 / (sig**2 + (0.03 * np.clip(photo, 0, None)) ** 2), axis=-1)
        chi2 = float(chi[full.mask].sum() / (3 * full.mask.sum()))
        err = quadrature_excess(basis, (lo, hi), vals["n_film"], min_cos, fx.bounces)
        ratio = f"{cpu / base_cpu:9.2f}" if base_cpu else f"{'':9s}"
        print(f"{name:12s} {basis.samples:7d} {cc.chi2_per_dof:7.2f} {chi2:7.2f} {cpu:7.2f} {ratio} {err:8.4f}"
              f"   load {os.getloadavg()[0]:.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
