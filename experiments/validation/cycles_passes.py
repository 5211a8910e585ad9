"""The rough constant Cycles film's light split by Cycles' own render passes, against
bubblefit's terms at the true parameters: where the hue error sits (reflection at the front,
light through the front, the film's colour or the light).

Two steps, in two virtual environments:

``render`` (the render venv: ``.venv-render/bin/python``) renders
cyc_const700_sunset_ortho_rough's scene as ``make_cycles.py`` sets it up (camera, map,
material, seed 2) into a multilayer EXR with the passes Glossy Color / Direct / Indirect,
Transmission Color / Direct / Indirect and Environment (Blender 5.0 manual, Render Layers >
Passes > Light). Cycles writes the Color passes at the camera ray's first hit, from the
closure's albedo estimate (``bsdf_microfacet_estimate_albedo`` in
``intern/cycles/kernel/closure/bsdf_microfacet.h``: the thin film at the mean surface's angle
``cos_NI``, without its lookup tables), and stores the Direct / Indirect passes divided by
them, so ``Color * (Direct + Indirect)`` is the light reflected (Glossy) or transmitted
(Transmission) at the first hit. Options, one change each: ``--distribution GGX`` (the
Principled BSDF's default is Multiscatter GGX: ``microfacet_ggx_preserve_energy``),
``--envmap FILE`` (another map, e.g. without its sun), ``--through-only`` (the world's
strength set to 0 for paths with a glossy bounce, through a Light Path node's Glossy Depth,
and the world not sampled as a light, so that only the light straight through both films is
left), ``--roughness`` and ``--spp``. It never writes into the case's folder.

``compare`` (the project venv) renders bubblefit's model of the case at its true parameters
(``rough_misfit.setup``: physical model, exact Airy film at 100 wavelengths, 8 bounces, the
pixel footprint, the ``mipmap`` lobe, illuminant E; with ``--film-rgb clamped``, Ward's lobe
of width alpha = roughness^2, the map at Blender's texel centres, the map as background and
unit exposure) and prints, per ring of the radius and channel:

* the Glossy Color pass against bubblefit's clamped film at the pixel's cosine
  (``clamped_series``' film, :func:`bubblefit.optics.film.airy_reflectance` averaged over s
  and p, integrated to RGB and clipped), the film's colour without any light;
* the light split into the front reflection (Glossy), the light straight through both films
  (the Transmission passes of a ``--through-only`` render) and the rest of the Transmission
  passes (the light the rear film reflects: bubblefit's ``rear`` term), each as
  ``(Cycles - bubblefit) / bubblefit's image`` summed over the ring, so the three add up to
  the image's difference.

    .venv-render/bin/python experiments/validation/cycles_passes.py render --spp 2048 --out /tmp/x/full.exr
    .venv-render/bin/python experiments/validation/cycles_passes.py render --spp 1024 --through-only --out /tmp/x/through.exr
    PYTHONPATH=. .venv/bin/python experiments/validation/cycles_passes.py compare /tmp/x/full.exr /tmp/x/through.exr [--envmap FILE] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import vio  # noqa: E402

CASE = "cyc_const700_sunset_ortho_rough"
RINGS = [(0.0, 0.16), (0.16, 0.32), (0.32, 0.48), (0.48, 0.64), (0.64, 0.8), (0.8, 0.88), (0.88, 0.96),
         (0.0, 0.5), (0.5, 0.8), (0.0, 0.8), (0.8, 0.96)]
PASSES = ("glossy_color", "glossy_direct", "glossy_indirect", "transmission_color", "transmission_direct",
          "transmission_indirect", "environment")


def render(a) -> None:
    """Cycles' render of the case with the light passes (module docstring)."""
    import time

    import bpy
    import make_cycles as mc

    c = mc.CASES[CASE]
    cam = c["camera"]
    sc = mc.reset(cam.width, cam.height, a.spp)
    mc.world(sc, a.envmap or os.path.join(vio.ENVMAPS, c["envmap"] + ".exr"))
    mc.camera(sc, cam)
    if a.through_only:
        nt = sc.world.node_tree
        path = nt.nodes.new("ShaderNodeLightPath")
        none = nt.nodes.new("ShaderNodeMath")
        none.operation = "LESS_THAN"
        none.inputs[1].default_value = 0.5
        nt.links.new(path.outputs["Glossy Depth"], none.inputs[0])
        nt.links.new(none.outputs[0], nt.nodes["Background"].inputs["Strength"])
        sc.world.cycles.sampling_method = "NONE"   # every world hit by a path's own ray
    m = mc.bubble_material(c["thickness"], roughness=c["roughness"] if a.roughness is None else a.roughness)
    m.node_tree.nodes["Principled BSDF"].distribution = a.distribution
    mc.sphere(sc, m)
    sc.cycles.seed = 2
    mc.sampling(sc, a.spp)
    layer = sc.view_layers[0]
    for name in PASSES:
        setattr(layer, "use_pass_" + name, True)
    sc.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    sc.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    sc.render.image_settings.color_depth = "32"
    sc.render.filepath = a.out
    t0 = time.time()
    bpy.ops.render.render(write_still=True)
    print(f"{a.out}: {a.distribution}, {a.spp} spp, {time.time() - t0:.1f} s", flush=True)


def read_layers(path: str) -> dict:
    """The passes of a multilayer EXR: {pass name: (H, W, 3)}."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise SystemExit(f"cannot read {path}: {oiio.geterror()}")
    out, k = {}, 0
    while inp.seek_subimage(k, 0):
        s = inp.spec()
        px = np.asarray(inp.read_image(k, 0, 0, s.nchannels, oiio.FLOAT), float)
        out[s.channelnames[0].split(".")[1]] = px.reshape(s.height, s.width, s.nchannels)[..., :3]
        k += 1
    inp.close()
    return out


def bubblefit_terms(envmap: str | None) -> tuple[dict, dict]:
    """bubblefit's image and terms (front, rear, background) of the case at its true
    parameters (module docstring), and the case's truth.json."""
    import dataclasses
    import tempfile

    import rough_misfit as rm

    from bubblefit.model.render import render_terms

    t = json.load(open(f"{vio.DATA}/{CASE}/truth.json"))
    pixels = vio.read_image(envmap or f"{vio.DATA}/{t['envmap']}")[..., :3].astype(np.float64)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "map.exr")
        vio.write_exr(path, rm.blender_rows(pixels).astype(np.float32))
        t, cfg, p, env, bg = rm.setup(CASE, "E", path)
    cfg = dataclasses.replace(cfg, film_rgb="clamped", effects=dataclasses.replace(cfg.effects, background="envmap"))
    img, terms = render_terms(dataclasses.replace(p, exposure=np.float32(1.0)), cfg, env, bg)
    return {"img": np.asarray(img), **{k: np.asarray(v) for k, v in terms.items()}}, t


def clamped_film(cos: np.ndarray, d_nm: float, n: float = 1.4) -> np.ndarray:
    """bubblefit's clamped RGB film (``clamped_series``, at one angle) at ``cos`` (N,)."""
    import jax.numpy as jnp

    from bubblefit.optics import film, spectral

    basis = spectral.spectral_basis("uniform", 100, "E")
    lam = jnp.asarray(basis.wavelengths)[None, :]
    r = jnp.mean(film.airy_reflectance(d_nm, lam, n, jnp.asarray(cos)[:, None]), axis=-1)
    return np.clip(np.asarray(spectral.integrate(r, basis)), 0.0, 1.0)


def compare(a) -> None:
    """Print (and with --json write) the film's and the light's comparison per ring."""
    full, through = read_layers(a.full), read_layers(a.through)
    bf, t = bubblefit_terms(a.envmap)
    h, w, _ = full["Combined"].shape
    d = t["disc"]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rho = np.hypot(jj - d["cx"], ii - d["cy"]) / d["r"]
    disc = rho < 0.96
    film = np.zeros((h, w, 3))
    film[disc] = clamped_film(np.sqrt(1.0 - rho[disc] ** 2), float(t["thickness"]["thickness_nm"]))
    gloss_col = full["Glossy Color"]
    colour_diff = np.abs(gloss_col - film)[disc]
    trans = lambda L: L["Transmission Color"] * (L["Transmission Direct"] + L["Transmission Indirect"])
    cyc = {"front": full["Glossy Color"] * (full["Glossy Direct"] + full["Glossy Indirect"]),
           "background": trans(through)}
    cyc["rear"] = trans(full) - cyc["background"]
    cyc["img"] = full["Combined"]
    report = {"case": CASE, "full": a.full, "through": a.through, "envmap": a.envmap,
              "glossy_color_minus_film": {"max_abs_rgb": colour_diff.max(0).round(5).tolist(),
                                          "median_abs_rgb": np.median(colour_diff, 0).round(6).tolist()},
              "note": "per ring: (Cycles - bubblefit) / bubblefit's image, summed over the ring, R G B", "rings": {}}
    print("Glossy Color - bubblefit's clamped film: max", report["glossy_color_minus_film"]["max_abs_rgb"],
          "median", report["glossy_color_minus_film"]["median_abs_rgb"])
    print("ring       | front (R G B)          | rear                   | through                | image")
    for lo, hi in RINGS:
        m = (rho >= lo) & (rho < hi)
        tot = bf["img"][m].sum(0)
        row = {k: ((cyc[k] - bf[k])[m].sum(0) / tot).round(4).tolist() for k in ("front", "rear", "background", "img")}
        row["glossy_color_over_film_minus_1"] = (gloss_col[m].sum(0) / np.maximum(film[m].sum(0), 1e-12) - 1).round(4).tolist()
        report["rings"][f"{lo:.2f}-{hi:.2f}"] = row
        print(f"{lo:.2f}-{hi:.2f} | " + " | ".join(" ".join(f"{v:+.4f}" for v in row[k])
                                               for k in ("front", "rear", "background", "img")))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(report, fh, indent=1)


def main(argv=None) -> None:
    """Command line: ``render`` or ``compare`` (module docstring)."""
    argv = sys.argv[sys.argv.index("--") + 1:] if argv is None and "--" in sys.argv else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="step", required=True)
    r = sub.add_parser("render", help="Cycles' render with the light passes (render venv)")
    r.add_argument("--out", required=True, help="the multilayer EXR to write")
    r.add_argument("--spp", type=int, default=1024)
    r.add_argument("--distribution", default="MULTI_GGX", choices=("MULTI_GGX", "GGX"))
    r.add_argument("--envmap", help="another map (default: the case's)")
    r.add_argument("--roughness", type=float, help="the Principled BSDF's roughness (default: the case's)")
    r.add_argument("--through-only", action="store_true", help="only the light straight through both films")
    c = sub.add_parser("compare", help="the passes against bubblefit's terms (project venv)")
    c.add_argument("full", help="a render's EXR")
    c.add_argument("through", help="the same scene's --through-only EXR")
    c.add_argument("--envmap", help="the map the renders used, when not the case's")
    c.add_argument("--json", help="write the comparison here")
    a = ap.parse_args(argv)
    if a.step == "render":
        if a.spp < 1:
            ap.error("--spp must be at least 1")
        if os.path.exists(a.out):
            ap.error(f"{a.out} exists: give a new file")
        render(a)
    else:
        for path in (a.full, a.through):
            if not os.path.isfile(path):
                ap.error(f"no such file: {path}")
        compare(a)


if __name__ == "__main__":
    main()
