"""Step by step, what the finest level's per-pixel Gauss-Newton of a map does on held frames.

Runs ``experiments/profile_sequence_maps.py`` (its arguments follow this script's) with
:func:`bubblefit.inverse._map_pixels.refine` replaced by the same solve run for a fixed
``STEPS`` steps (default 30) with no stopping test, recording for every trial step: the
damping, the energy before and after, whether it was accepted, and the sizes of the
pixels' steps ``|dh|`` (nm: largest, 50th, 90th, 99th and 99.9th percentiles, how many
pixels move by more than :data:`~bubblefit.inverse._map_pixels.REFINE_TOL_NM`, how many of
those lie on the mask's edge or at the window's bound), and the curvature of the pixel
that moves most against the median pixel's. Writes ``OUT`` (JSON: one list of steps per
refine call).

    PYTHONPATH=.:experiments python experiments/refine_steps.py OUT.json \
        experiments/profile_sequence_maps.py RUN FRAMES_96 1 2 PROFILE_OUT.json
"""
import json
import os
import runpy
import sys

from bubblefit.io.jaxcache import jax_setup

jax_setup()

import numpy as np  # noqa: E402

import bubblefit.inverse._map_pixels as MP  # noqa: E402
import bubblefit.inverse._maps as M  # noqa: E402

STEPS = int(os.environ.get("STEPS", "30"))
LOG = []


def refine_steps(costs, centre, nb, s, half):
    """:func:`bubblefit.inverse._map_pixels.refine` (Levenberg-Marquardt damped Gauss-Newton
    on the map's energy; Levenberg 1944, Marquardt 1963) for ``STEPS`` trial steps with no
    stopping test, every step's sizes recorded."""
    has = nb >= 0
    edge = has.sum(axis=1) < 4
    lo, hi = np.maximum(centre - half, 0.0), centre + half
    steps = []

    def record(d, trial, hdiag, lam, e, e2):
        dh = np.abs(trial - d)
        big = dh > MP.REFINE_TOL_NM
        at_bound = (trial <= lo + 1e-6) | (trial >= hi - 1e-6)
        top = int(np.argmax(dh))
        steps.append({"step": len(steps), "damping": lam, "energy": round(e, 4), "energy_trial": round(e2, 4),
                      "accepted": bool(e2 <= e), "pixels": int(d.size), "max_nm": round(float(dh.max()), 5),
                      **{f"p{q}_nm": round(float(np.percentile(dh, q)), 5) for q in (50, 90, 99, 99.9)},
                      "over_tol": int(big.sum()), "over_tol_on_edge": int((big & edge).sum()),
                      "over_tol_at_bound": int((big & at_bound).sum()), "largest_pixel": top,
                      "curvature_largest": round(float(hdiag[top]), 5), "curvature_median": round(float(np.median(hdiag)), 5)})

    out = MP.refine(costs, centre, nb, s, half, steps=STEPS, stop=False, observe=record)
    LOG.append(steps)
    return out


M.refine = refine_steps
out = sys.argv[1]
sys.argv = sys.argv[2:]
try:
    runpy.run_path(sys.argv[0], run_name="__main__")
finally:
    with open(out, "w") as f:
        json.dump({"steps": STEPS, "refines": LOG}, f, indent=1)
