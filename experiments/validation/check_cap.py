"""Check the geometry of a bubble on a dish (bubblefit.model.cap) against Blender Cycles.

make_films_cycles.py ``cap`` renders a sphere of radius 1 at the origin that emits red,
standing in a liquid plane y = -0.3 that is either black (the cap alone:
``cycles_cap_direct.exr``) or a perfect mirror (the cap and its mirror image:
``cycles_cap_mirror.exr``), seen by a perspective camera, 16 samples per pixel (box
filter). Here the same camera's pixel-centre rays are traced with
:func:`bubblefit.model.cap.trace_cap`: a pixel is "cap" where a ray meets the cap first,
"mirror" where it meets the liquid and its mirror ray meets the cap. Cycles' pixels are
classed by their red value (> 0.5: more than half the pixel shows the cap); the
disagreements must lie on the outlines, where a pixel is partly covered (a pixel whose
four corner rays do not all agree in bubblefit's classes).

Run with the project's venv: writes data/conventions/cap_report.json.
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.normpath(os.path.join(HERE, "..", "..")))
import vio  # noqa: E402

CONV = os.path.join(vio.DATA, "conventions")
PLANE_Y, SIZE = -0.3, 96
CAMERA = dict(origin=(0.4, 1.6, 5.0), target=(0.0, -0.3, 0.0), fov_deg=40.0)   # as make_films_cycles.py


def classes(rows, cols):
    import jax.numpy as jnp

    from bubblefit.model.cap import Cap, trace_cap
    from bubblefit.model.geometry import PerspectiveCamera

    cam = PerspectiveCamera(width=SIZE, height=SIZE, up=(0.0, 1.0, 0.0), **CAMERA)
    o, d = cam.rays(jnp.asarray(rows), jnp.asarray(cols))
    v = trace_cap(np.asarray(o).reshape(-1, 3), np.asarray(d).reshape(-1, 3), Cap((0.0, 0.0, 0.0), 1.0, PLANE_Y))
    return v.film.reshape(rows.shape), v.mirror_film.reshape(rows.shape)


def main():
    direct = vio.read_image(os.path.join(CONV, "cycles_cap_direct.exr"))[..., 0] > 0.5
    both = vio.read_image(os.path.join(CONV, "cycles_cap_mirror.exr"))[..., 0] > 0.5
    mirror = both & ~direct
    r, c = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    cap_c, mir_c = classes(r, c)
    # corners: rays at (row - 1/2, col - 1/2) on a (SIZE+1)^2 grid
    cr, cc = np.mgrid[0:SIZE + 1, 0:SIZE + 1].astype(np.float64) - 0.5
    cap_k, mir_k = classes(cr, cc)

    def uniform(k):
        return (k[:-1, :-1] == k[1:, :-1]) & (k[:-1, :-1] == k[:-1, 1:]) & (k[:-1, :-1] == k[1:, 1:])

    inner = uniform(cap_k) & uniform(mir_k)
    rep = {}
    for name, cyc, bf in (("cap", direct, cap_c), ("mirror image", mirror, mir_c)):
        diff = cyc != bf
        rep[name] = {"pixels_cycles": int(cyc.sum()), "pixels_bubblefit": int(bf.sum()),
                     "disagree": int(diff.sum()), "disagree_off_outline": int((diff & inner).sum())}
    with open(os.path.join(CONV, "cap_report.json"), "w") as fh:
        json.dump(rep, fh, indent=2)
    for k, v in rep.items():
        print(k, v)
    return 0 if all(v["disagree_off_outline"] == 0 for v in rep.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
