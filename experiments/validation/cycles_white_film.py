"""Blender Cycles' rough thin film alone: the light it reflects in a uniform white world,
against the mean of the clamped film over GGX's and over Ward's visible facets.

A sphere (radius 1) with the rough Cycles cases' material (make_cycles.py: Principled BSDF,
IOR 1, Transmission Weight 1, Thin Film IOR 1.4, the given thickness and Roughness, GGX alpha
= roughness^2) holds a black sphere of radius 0.98, which absorbs what the film transmits;
the world is white (radiance 1) and the camera orthographic. A pixel at radius ``r`` of the
disc then reads the film's directional albedo at ``cos = sqrt(1 - r^2)``: at a mirror the
clamped film itself, on a rough film its mean over the facets Cycles samples. Read on thin
rings of a 512 px disc, so that the film's change across a ring stays small.

``compare`` evaluates, at each ring's cosine, the mean of the clamped film ``clip(rgb(R))``
(the Airy reflectance of :func:`bubblefit.optics.film.airy_reflectance`, s and p averaged,
integrated to linear sRGB under illuminant E, as ``--film-rgb clamped`` forms it) over the
visible facets (projected area ``max(w_i . h, 0)`` per unit of the mean surface, Heitz,
JCGT 3(2), 2014) by a product rule in slope space on +-60 alpha (1201 x 1201 nodes; doubling
the extent changes the means by under 5e-5):

* GGX's slope density ``1 / (pi alpha^2 (1 + |s|^2 / alpha^2)^2)`` (Walter et al., EGSR 2007,
  eq. 33 in slope space), Cycles' lobe;
* Ward's Gaussian slopes of variance ``alpha^2 / 2`` (paper eq. 1's lobe) by the same rule;
* :func:`bubblefit.optics.brdf.facet_cosines`' three nodes, what the fit uses.

Two steps, in two virtual environments::

    .venv-render/bin/python experiments/validation/cycles_white_film.py render --out /tmp/x/white.exr
    PYTHONPATH=. .venv/bin/python experiments/validation/cycles_white_film.py compare /tmp/x/white.exr --json OUT
"""
from __future__ import annotations

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

SIZE, DISC_R = 512, 240.0
RINGS = (0.0, 0.24, 0.40, 0.48, 0.56, 0.64, 0.72, 0.80, 0.88)
RING_WIDTH = 0.01


def render(a) -> None:
    """The white-world sphere (module docstring) into ``a.out`` (linear EXR)."""
    import bpy

    import make_cycles as mc
    import reference_renderer as rr

    sc = mc.reset(SIZE, SIZE, a.spp)
    mc.camera(sc, rr.Camera("ortho", SIZE, SIZE, disc=(SIZE / 2, SIZE / 2, DISC_R)))
    world = bpy.data.worlds.new("white")
    sc.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[0].default_value = (1, 1, 1, 1)
    mat = bpy.data.materials.new("film")
    mat.use_nodes = True
    p = mat.node_tree.nodes["Principled BSDF"]
    p.distribution = a.distribution
    p.inputs["Base Color"].default_value = (1, 1, 1, 1)
    p.inputs["IOR"].default_value = 1.0
    p.inputs["Transmission Weight"].default_value = 1.0
    p.inputs["Roughness"].default_value = a.roughness
    p.inputs["Thin Film IOR"].default_value = mc.N_FILM
    p.inputs["Thin Film Thickness"].default_value = a.thickness
    mc.sphere(sc, mat)
    black = bpy.data.materials.new("black")
    black.use_nodes = True
    nt = black.node_tree
    nt.nodes.clear()
    emit = nt.nodes.new("ShaderNodeEmission")
    emit.inputs[1].default_value = 0.0
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(emit.outputs[0], out.inputs[0])
    inner = mc.sphere(sc, black)
    inner.scale = (0.98, 0.98, 0.98)
    sc.render.filepath = os.path.abspath(a.out)
    bpy.ops.render.render(write_still=True)


def _facet_mean(film, c: float, density, alpha: float, extent: float = 60.0, n: int = 1201):
    """The mean of ``film`` (a function of the facet cosine) over the visible facets of the
    slope ``density`` (a function of ``(p, q) / alpha``) for a ray at ``c`` to the mean
    surface (module docstring)."""
    import numpy as np

    g = np.linspace(-extent * alpha, extent * alpha, n)
    p, q = np.meshgrid(g, g, indexing="ij")
    s = np.sqrt(1.0 - c * c)
    weight = np.maximum(c + p * s, 0.0) * density(p / alpha, q / alpha)
    cos_h = np.clip((c + p * s) / np.sqrt(1.0 + p * p + q * q), 0.0, 1.0)
    return (weight[..., None] * film(cos_h)).sum((0, 1)) / weight.sum()


def compare(a) -> dict:
    """Each ring's Cycles albedo against the facet means (module docstring)."""
    import jax.numpy as jnp
    import numpy as np

    from bubblefit.inverse.response_error import response_perturbation
    from bubblefit.io.images import read_image
    from bubblefit.optics import brdf

    err = response_perturbation("srgb", "E", 1.4)  # the film's channel shares under E
    grid = np.linspace(0.0, 1.0, 4001)
    table = np.clip(err.shares(err.reflectance(np.full(grid.size, a.thickness), np.maximum(grid, 1e-6))), 0.0, 1.0)

    def film(cos):
        return np.stack([np.interp(cos, grid, table[:, k]) for k in range(3)], axis=-1)

    alpha = a.roughness ** 2
    ggx = lambda u, v: 1.0 / (1.0 + u * u + v * v) ** 2
    ward = lambda u, v: np.exp(-(u * u + v * v))  # slopes N(0, alpha^2 / 2)
    img = np.asarray(read_image(a.exr).pixels, np.float64)[..., :3]
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    rho = np.hypot(x - SIZE / 2, y - SIZE / 2) / DISC_R
    rows = []
    for r0 in RINGS:
        c = float(np.sqrt(1.0 - (r0 + RING_WIDTH / 2) ** 2))
        nodes, weights = brdf.facet_cosines(jnp.asarray([c]), alpha)
        three = sum(float(w[0]) * film(np.asarray(n, np.float64))[0] for n, w in zip(nodes, weights))
        row = {"r": r0, "cos": c, "cycles": img[(rho >= r0) & (rho < r0 + RING_WIDTH)].mean(axis=0),
               "ggx_facets": _facet_mean(film, c, ggx, alpha), "ward_facets": _facet_mean(film, c, ward, alpha),
               "three_nodes": three, "mirror": film(np.asarray([c]))[0]}
        rows.append({k: (np.round(v, 5).tolist() if isinstance(v, np.ndarray) else v) for k, v in row.items()})
        print(f"r {r0:.2f} cos {c:.3f}: cycles {row['cycles'].round(4)}  GGX facets {row['ggx_facets'].round(4)}  "
              f"Ward facets {row['ward_facets'].round(4)}  three nodes {row['three_nodes'].round(4)}")
    worst = {k: float(max(np.max(np.abs(np.subtract(r[k], r["cycles"]))) for r in rows))
             for k in ("ggx_facets", "ward_facets", "three_nodes", "mirror")}
    print("largest |difference| from Cycles:", {k: round(v, 5) for k, v in worst.items()})
    return {"thickness_nm": a.thickness, "roughness": a.roughness, "alpha": alpha, "rings": rows,
            "largest_difference": worst}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="step", required=True)
    r = sub.add_parser("render")
    r.add_argument("--out", required=True)
    r.add_argument("--spp", type=int, default=256)
    r.add_argument("--distribution", default="GGX", choices=("GGX", "MULTI_GGX"))
    c = sub.add_parser("compare")
    c.add_argument("exr")
    c.add_argument("--json")
    for p in (r, c):
        p.add_argument("--thickness", type=float, default=700.0)
        p.add_argument("--roughness", type=float, default=0.15)
    a = ap.parse_args()
    if a.step == "render":
        render(a)
        return
    rec = compare(a)
    if a.json:
        from bubblefit.io.atomic import write_text

        rec = {"what": "Cycles' rough thin film in a uniform white world (cycles_white_film.py; Blender "
                       "5.0.1, 512 px, rings 0.01 of the radius wide) against the clamped film's mean over "
                       "GGX's and Ward's visible facets and over facet_cosines' three nodes", **rec}
        write_text(a.json, json.dumps(rec, indent=1) + "\n")


if __name__ == "__main__":
    main()
