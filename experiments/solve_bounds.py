"""Each local solve of one ``bubblefit fit`` process: its steps, CPU seconds and the
Gauss-Newton step left from its end, and per free parameter of the last solve that step
in ``z``, its standard error and whether the bounds' rule takes the parameter as an
active constraint (:func:`bubblefit.inverse._lm.presses_bound`, the rule of
:func:`bubblefit.inverse._local.remaining_step`; Nocedal & Wright, *Numerical
Optimization*, 2006, ch. 16.6).

Runs the command line in this process with :func:`bubblefit.inverse._local.solve_local`
wrapped, and prints one ``SOLVE {json}`` line per solve on stderr; the fit's own output
is unchanged. On the 320x320 sunset photo of docs/speed.md:

    D=experiments/results/photos320/ref_const380_sunset_ortho_320
    PYTHONPATH=. python experiments/solve_bounds.py fit $D/photo.png --envmap \\
        experiments/results/photos320/envmaps/sunset.exr --background $D/background.png \\
        --thickness constant --json fit.json -o fit --fov 0 --illuminant D65
"""

import json
import sys
import time

import numpy as np

import bubblefit.inverse.fit as fit_module
from bubblefit.cli import main
from bubblefit.inverse._lm import presses_bound
from bubblefit.inverse._local import remaining_step
from bubblefit.inverse._parameters import value_and_slope

_solve_local = fit_module.solve_local


def _recorded(lev, table, solver, vals, env, *args, **kwargs):
    """:func:`~bubblefit.inverse._local.solve_local`, with its record printed on stderr."""
    t0 = time.process_time()
    sol = _solve_local(lev, table, solver, vals, env, *args, **kwargs)
    cpu = time.process_time() - t0
    chi2 = sol.cost / max(int(np.count_nonzero(lev.w)) - len(table.free), 1)
    rec = {"shape": list(np.shape(lev.w))[:2], "free": list(table.free), "steps": sol.steps, "cpu": cpu,
           "chi2nu": chi2, "remaining": remaining_step(sol, chi2, table.free), "params": {}}
    try:
        a_inv = np.linalg.inv(sol.jacobian.T @ sol.jacobian)
    except np.linalg.LinAlgError:
        a_inv = None
    if a_inv is not None:
        step = -a_inv @ (sol.jacobian.T @ sol.residual)
        se = np.sqrt(np.abs(np.diag(a_inv)) * max(1.0, chi2))
        for i, name in enumerate(table.free):
            v, slope = value_and_slope(name, sol.z[i])
            rec["params"][name] = {"v": v, "dz": float(step[i]), "se_z": float(se[i]),
                                   "dz_over_se": float(step[i] / se[i]),
                                   "held": bool(presses_bound(name, v, slope, step[i], se[i], np.sign))}
    print("SOLVE", json.dumps(rec, default=float), file=sys.stderr, flush=True)
    return sol


if __name__ == "__main__":
    fit_module.solve_local = _recorded
    sys.exit(main(sys.argv[1:]))
