"""Blender Cycles flat films: a vertical film in a frame under a diffuse panel (render venv).

    .venv-render/bin/python make_films_cycles.py [probe] [cap] [CASE ...]   # default: every case

``cap`` renders the masks of a bubble on a dish for check_cap.py (data/conventions/);
the ``cyc_cap_*`` cases render soap bubbles standing on water (:func:`make_dish`), the
``cyc_sphere_*`` cases whole bubbles under a panel behind the camera (:func:`make_sphere_panel`).

The film is a square mesh (the frame's opening, 0.18 m) in the plane z = 0 of the
bubblefit frame (normal +z, up +y), with a Principled BSDF whose Thin Film Thickness
comes from a node tree of the object's height (Blender's object Z = bubblefit y): the
drainage profile ``d = top + (bottom - top) ((h/2 - y) / h)^exponent`` of a frame of
height ``h``, or a constant. The base is IOR 1.0 (air behind the film), Thin Film IOR
1.33 (water, no dispersion in Cycles' film), Roughness 0. The light is a Blender Area
light (a 1 m square, spread 180 degrees: a Lambertian panel) behind a perspective camera;
the world is black, so the film shows the panel's mirror image and nothing else.

Settings follow make_cycles.py (its reset(), camera(), to_blender() and node helpers are
reused): box filter, denoiser off, no clamping, fixed seed. Two choices differ:

* ``Transmission Weight`` is 0 and the base colour black: behind this film lies a black
  room, and with a transmissive base Cycles picks reflection or transmission at random
  in proportion to the film's reflectance (a few per cent), which leaves a photo of
  mostly black samples; with an opaque black base every camera sample reflects off the
  film's specular layer, whose Fresnel term is the thin film's. ``probe`` renders a
  constant film both ways and prints their mean colours and pixel-to-pixel scatter, the
  check that the two materials reflect the same (and that the opaque one is quiet).
* 64 samples per pixel: a mirror reflection of a uniform panel has no Monte Carlo noise
  beyond the pixel filter's sub-pixel positions.

Known approximations of Cycles (recorded in each truth.json): its thin film averages s
and p polarisation and integrates the spectrum under illuminant E into linear Rec.709
RGB, clamped per channel to [0, 1]; its film index here is 1.33 at every wavelength. The
scene files say ``n = 1.33`` and ``lamp = "E"`` accordingly. Truth maps: the thickness at
each pixel centre's ray's intersection with the film plane (reference_renderer.Camera,
numpy), NaN off the frame; pixels the frame's edge crosses are partly black.
"""

from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import make_cycles as mc  # noqa: E402  (render settings, camera, frames, node helpers)
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402

import bpy  # noqa: E402

FULL_WELL, READ_NOISE = 4000.0, 3.0
N_FILM = 1.33
SPP = 64
FRAME = 0.18          # the frame's opening (m), square
PANEL = (0.0, 0.0, 0.7)
PANEL_SIZE = 1.0
SIZE = 128

CASES = {
    # a draining film: nearly black at the top, 1 um at the bottom; the camera a little off-axis
    "cyc_film_drain_panel": dict(top_nm=30.0, bottom_nm=1000.0, exponent=1.6, origin=(0.05, 0.03, 0.6),
                                 fov_deg=30.0, seed=51, fits=["drainage", "map"]),
    # held out (split.toml, test part): thicker and nearly a wedge, the camera further off-axis
    "cyc_film_drain_offaxis_panel": dict(top_nm=60.0, bottom_nm=1300.0, exponent=1.1, origin=(0.12, -0.04, 0.55),
                                         fov_deg=34.0, seed=53, fits=["drainage", "map"]),
    # a film of one thickness (second-order green, red clipped), the camera below the axis
    "cyc_film_const_panel": dict(top_nm=480.0, bottom_nm=480.0, exponent=1.0, origin=(-0.04, -0.05, 0.6),
                                 fov_deg=30.0, seed=52, fits=["constant"]),
}


def film_material(c, transmissive=False):
    m = bpy.data.materials.new("film")
    m.use_nodes = True
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (1, 1, 1, 1) if transmissive else (0, 0, 0, 1)
    p.inputs["IOR"].default_value = 1.0
    p.inputs["Transmission Weight"].default_value = 1.0 if transmissive else 0.0
    p.inputs["Roughness"].default_value = 0.0
    p.inputs["Metallic"].default_value = 0.0
    p.inputs["Thin Film IOR"].default_value = N_FILM
    if c["top_nm"] == c["bottom_nm"]:
        p.inputs["Thin Film Thickness"].default_value = c["top_nm"]
        return m
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(tc.outputs["Object"], sep.inputs[0])
    z = sep.outputs["Z"]                                      # bubblefit y: height in the film (m)
    s = mc.math_node(nt, "SUBTRACT", 0.5 * FRAME, z)          # h/2 - y
    s = mc.math_node(nt, "MULTIPLY", s, 1.0 / FRAME)          # 0 at the top edge, 1 at the bottom
    s = mc.math_node(nt, "MAXIMUM", s, 0.0)
    s = mc.math_node(nt, "POWER", s, c["exponent"])
    s = mc.math_node(nt, "MULTIPLY", s, c["bottom_nm"] - c["top_nm"])
    d = mc.math_node(nt, "ADD", s, c["top_nm"])
    nt.links.new(d, p.inputs["Thin Film Thickness"])
    return m


def film(sc, material):
    """The frame's opening: a square in bubblefit's z = 0 plane, facing +z (the camera)."""
    import bmesh

    mesh = bpy.data.meshes.new("film")
    bm = bmesh.new()
    h = 0.5 * FRAME
    # counter-clockwise seen from +z (bubblefit), so the face normal is +z = Blender -Y
    corners = [(-h, -h, 0.0), (h, -h, 0.0), (h, h, 0.0), (-h, h, 0.0)]
    bm.faces.new([bm.verts.new(mc.to_blender(v)) for v in corners])
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new("film", mesh)
    sc.collection.objects.link(obj)
    mesh.materials.append(material)
    return obj


def panel(sc):
    """A Lambertian square of PANEL_SIZE at PANEL facing the film (Blender area lights emit along local -Z)."""
    data = bpy.data.lights.new("panel", type="AREA")
    data.shape = "SQUARE"
    data.size = PANEL_SIZE
    data.energy = 100.0
    data.spread = math.pi
    data.color = (1.0, 1.0, 1.0)
    obj = bpy.data.objects.new("panel", data)
    sc.collection.objects.link(obj)
    obj.location = mc.to_blender(PANEL)
    obj.rotation_euler = (math.pi / 2, 0.0, 0.0)             # local -Z to Blender +Y = bubblefit -z
    return obj


def black_world(sc):
    w = bpy.data.worlds.new("black")
    sc.world = w
    w.use_nodes = True
    w.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    w.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0


def cam_of(c) -> rr.Camera:
    return rr.Camera("persp", SIZE, SIZE, origin=c["origin"], target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0),
                     fov_deg=c["fov_deg"])


def render(c, spp=SPP, transmissive=False, path="/tmp/cyc_film.exr"):
    cam = cam_of(c)
    sc = mc.reset(cam.width, cam.height, spp)
    black_world(sc)
    mc.camera(sc, cam)
    panel(sc)
    film(sc, film_material(c, transmissive))
    return mc.render_to_array(sc, path)


def thickness_truth(c) -> np.ndarray:
    """Thickness at each pixel centre's intersection with the film, NaN off the frame."""
    cam = cam_of(c)
    jj, ii = np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5)
    o, d = cam.rays(jj.reshape(-1), ii.reshape(-1), np.zeros(3), 1.0)
    t = -o[:, 2] / d[:, 2]
    p = o + t[:, None] * d
    on = (np.abs(p[:, 0]) <= 0.5 * FRAME) & (np.abs(p[:, 1]) <= 0.5 * FRAME) & (t > 0)
    f = np.clip((0.5 * FRAME - p[:, 1]) / FRAME, 0.0, 1.0)
    th = c["top_nm"] + (c["bottom_nm"] - c["top_nm"]) * f ** c["exponent"]
    return np.where(on, th, np.nan).reshape(SIZE, SIZE)


def scene_toml(c, kind) -> str:
    return (
        "# A vertical water film in a 0.18 m frame, a 1 m diffuse panel behind the camera (Blender Cycles)\n"
        f"[film]\nshape = \"plane\"\nn = {N_FILM}\nabove = \"air\"\nbelow = \"air\"\nthickness = \"{kind}\"\n"
        "range_nm = [0.0, 1500.0]\ncenter = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nup = [0.0, 1.0, 0.0]\n"
        f"size = [{FRAME}, {FRAME}]\n\n"
        f"[light]\ntype = \"area\"\nshape = \"rect\"\ncenter = {list(PANEL)}\nnormal = [0.0, 0.0, -1.0]\n"
        f"up = [0.0, 1.0, 0.0]\nsize = [{PANEL_SIZE}, {PANEL_SIZE}]\nradiance = 1.0\n"
        "lamp = \"E\"   # Cycles integrates its thin film under illuminant E\n\n"
        f"[camera]\ntype = \"perspective\"\nwidth = {SIZE}\nheight = {SIZE}\norigin = {list(c['origin'])}\n"
        f"target = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov_deg = {c['fov_deg']}\n")


def probe():
    c = dict(CASES["cyc_film_const_panel"])
    for tr in (False, True):
        img = render(c, spp=256, transmissive=tr, path=f"/tmp/cyc_film_probe_{int(tr)}.exr")
        core = img[54:74, 54:74]
        print(f"transmissive={tr}: mean {core.mean((0, 1))}, pixel scatter {core.std((0, 1)) / core.mean((0, 1))}",
              flush=True)


#: A bubble on a dish for the geometry check (check_cap.py): a sphere of radius 1 at the
#: origin above a liquid plane y = CAP_PLANE_Y, a camera above and in front.
CAP_PLANE_Y = -0.3
CAP_CAMERA = dict(origin=(0.4, 1.6, 5.0), target=(0.0, -0.3, 0.0), fov_deg=40.0)
CAP_SIZE = 96


def emission_material(rgb):
    m = bpy.data.materials.new("emit")
    m.use_nodes = True
    nt = m.node_tree
    nt.nodes.clear()
    e = nt.nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = (*rgb, 1.0)
    e.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(e.outputs["Emission"], out.inputs["Surface"])
    return m


def liquid_material(mirror: bool):
    """A perfect mirror (Glossy, roughness 0, white) or an opaque black plane."""
    m = bpy.data.materials.new("liquid")
    m.use_nodes = True
    nt = m.node_tree
    nt.nodes.clear()
    if mirror:
        b = nt.nodes.new("ShaderNodeBsdfGlossy")
        b.distribution = "GGX"
        b.inputs["Roughness"].default_value = 0.0
    else:
        b = nt.nodes.new("ShaderNodeBsdfDiffuse")
    b.inputs["Color"].default_value = (1, 1, 1, 1) if mirror else (0, 0, 0, 1)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(b.outputs["BSDF"], out.inputs["Surface"])
    return m


def make_cap():
    """Masks of a cap on a liquid: the sphere emits red; the plane is a mirror (the cap and
    its mirror image) or black (the cap alone). Written to data/conventions/cycles_cap_*.exr."""
    import bmesh

    out = os.path.join(vio.DATA, "conventions")
    os.makedirs(out, exist_ok=True)
    cam = rr.Camera("persp", CAP_SIZE, CAP_SIZE, origin=CAP_CAMERA["origin"], target=CAP_CAMERA["target"],
                    up=(0.0, 1.0, 0.0), fov_deg=CAP_CAMERA["fov_deg"])
    for mirror in (False, True):
        sc = mc.reset(CAP_SIZE, CAP_SIZE, 16)
        black_world(sc)
        mc.camera(sc, cam)
        mc.sphere(sc, emission_material((1.0, 0.0, 0.0)))
        mesh = bpy.data.meshes.new("liquid")
        bm = bmesh.new()
        h = 50.0
        corners = [(-h, CAP_PLANE_Y, h), (h, CAP_PLANE_Y, h), (h, CAP_PLANE_Y, -h), (-h, CAP_PLANE_Y, -h)]
        bm.faces.new([bm.verts.new(mc.to_blender(v)) for v in corners])
        bm.to_mesh(mesh)
        bm.free()
        obj = bpy.data.objects.new("liquid", mesh)
        sc.collection.objects.link(obj)
        mesh.materials.append(liquid_material(mirror))
        name = "cycles_cap_mirror.exr" if mirror else "cycles_cap_direct.exr"
        mc.render_to_array(sc, os.path.join(out, name))
        print("cycles cap", name, flush=True)


#: Bubbles on a dish: a soap film on the sphere of radius 1 at the origin (make_cycles.py's
#: UV sphere and thin-film material, n = 1.4, transmissive), standing in a water surface
#: y = plane_y, in an environment map. The film's thickness is a constant or the drainage
#: profile along the cap's height, d = top + (bottom - top) u^exponent with u = (1 - y) / H
#: (0 at the top, 1 at the foot, H = 1 - plane_y the cap's height).
DISH_CASES = {
    "cyc_cap_const_courtyard": dict(plane_y=-0.3, top_nm=460.0, bottom_nm=460.0, exponent=1.0, envmap="courtyard",
                                    origin=(0.4, 1.6, 5.0), target=(0.0, -0.1, 0.0), fov_deg=34.0, seed=61,
                                    fits=["constant"]),
    # held out (split.toml, test part): a hemisphere, thicker, another map and camera
    "cyc_cap_const_city_hemi": dict(plane_y=0.0, top_nm=680.0, bottom_nm=680.0, exponent=1.0, envmap="city",
                                    origin=(-0.9, 1.9, 4.6), target=(0.0, 0.2, 0.0), fov_deg=32.0, seed=62,
                                    fits=["constant"]),
    "cyc_cap_drain_sunrise": dict(plane_y=-0.2, top_nm=220.0, bottom_nm=900.0, exponent=1.3, envmap="sunrise",
                                  origin=(0.3, 1.4, 5.0), target=(0.0, 0.0, 0.0), fov_deg=34.0, seed=63,
                                  fits=["drainage"]),
    # held out (split.toml, test part)
    "cyc_cap_drain_forest_hemi": dict(plane_y=0.0, top_nm=150.0, bottom_nm=1000.0, exponent=1.6, envmap="forest",
                                      origin=(0.7, 1.7, 4.8), target=(0.0, 0.25, 0.0), fov_deg=32.0, seed=64,
                                      fits=["drainage"]),
}
DISH_SIZE = 112
N_LIQUID = 1.333   # water at 589 nm; Cycles' Principled IOR is one number


def dish_film_material(c):
    """make_cycles.py's bubble material, its thickness a constant or the cap's drainage profile."""
    m = mc.bubble_material(rr.Thickness("constant", c["top_nm"]))
    if c["top_nm"] == c["bottom_nm"]:
        return m
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(tc.outputs["Object"], sep.inputs[0])
    u = mc.math_node(nt, "SUBTRACT", 1.0, sep.outputs["Z"])           # 1 - y (bubblefit y = object Z)
    u = mc.math_node(nt, "MULTIPLY", u, 1.0 / (1.0 - c["plane_y"]))   # 0 at the top, 1 at the foot
    u = mc.math_node(nt, "MAXIMUM", u, 0.0)
    u = mc.math_node(nt, "POWER", u, c["exponent"])
    u = mc.math_node(nt, "MULTIPLY", u, c["bottom_nm"] - c["top_nm"])
    d = mc.math_node(nt, "ADD", u, c["top_nm"])
    nt.links.new(d, p.inputs["Thin Film Thickness"])
    return m


def water_material():
    """A deep, still water surface: Principled BSDF, IOR 1.333, black base (nothing comes
    back from under the surface), roughness 0, opaque: its specular layer is the
    dielectric Fresnel reflectance of air to water."""
    m = bpy.data.materials.new("water")
    m.use_nodes = True
    p = m.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0, 0, 0, 1)
    p.inputs["IOR"].default_value = N_LIQUID
    p.inputs["Roughness"].default_value = 0.0
    p.inputs["Metallic"].default_value = 0.0
    p.inputs["Transmission Weight"].default_value = 0.0
    return m


def liquid_plane(sc, plane_y, material, half=60.0):
    import bmesh

    mesh = bpy.data.meshes.new("liquid")
    bm = bmesh.new()
    corners = [(-half, plane_y, half), (half, plane_y, half), (half, plane_y, -half), (-half, plane_y, -half)]
    bm.faces.new([bm.verts.new(mc.to_blender(v)) for v in corners])
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new("liquid", mesh)
    sc.collection.objects.link(obj)
    mesh.materials.append(material)
    return obj


def dish_camera(c) -> rr.Camera:
    return rr.Camera("persp", DISH_SIZE, DISH_SIZE, origin=c["origin"], target=c["target"], up=(0.0, 1.0, 0.0),
                     fov_deg=c["fov_deg"])


def dish_truth(c) -> np.ndarray:
    """Thickness of the film each pixel centre's ray meets first (NaN where it meets none)."""
    cam = dish_camera(c)
    jj, ii = np.meshgrid(np.arange(DISH_SIZE) + 0.5, np.arange(DISH_SIZE) + 0.5)
    o, d = cam.rays(jj.reshape(-1), ii.reshape(-1), np.zeros(3), 1.0)
    hit, s = rr._intersect(o, d, np.zeros(3), 1.0)
    p = o + np.where(hit, s, 0.0)[:, None] * d
    on = hit & (p[:, 1] >= c["plane_y"])
    u = np.clip((1.0 - p[:, 1]) / (1.0 - c["plane_y"]), 0.0, 1.0)
    th = c["top_nm"] + (c["bottom_nm"] - c["top_nm"]) * u ** c["exponent"]
    return np.where(on, th, np.nan).reshape(DISH_SIZE, DISH_SIZE)


def dish_scene_toml(c, kind) -> str:
    return (
        "# A soap bubble standing on water (a spherical cap) in an environment map (Blender Cycles)\n"
        f"[film]\nshape = \"cap\"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nplane_y = {c['plane_y']}\n"
        f"liquid = {N_LIQUID}\nn = {mc.N_FILM}\nthickness = \"{kind}\"\nrange_nm = [0.0, 1500.0]\n"
        "film_rgb = \"clamped\"   # Cycles clamps each film's RGB reflectance to [0, 1]\n\n"
        f"[environment]\npath = \"../envmaps/{c['envmap']}.exr\"\n"
        "convention = \"texel-centre\"   # Blender's Environment Texture reads texel centres at (i + 1/2) / H\n\n"
        "[lighting]\nilluminant = \"E\"   # Cycles integrates its thin film under illuminant E\n\n"
        f"[camera]\ntype = \"perspective\"\nwidth = {DISH_SIZE}\nheight = {DISH_SIZE}\n"
        f"origin = {list(c['origin'])}\ntarget = {list(c['target'])}\nup = [0.0, 1.0, 0.0]\n"
        f"fov_deg = {c['fov_deg']}\n")


def render_photo(sc, name, out, seed, t0):
    """Render ``sc``, scale its 99.5th percentile to 0.9, add the sensor's noise and write
    ``out/photo.png`` (8-bit sRGB); returns (render seconds, exposure)."""
    img = mc.render_to_array(sc, os.path.join("/tmp", name + ".exr"))
    secs = time.time() - t0
    expo = 0.9 / float(np.percentile(img, 99.5))
    rng = np.random.default_rng(seed)
    vio.write_png8(os.path.join(out, "photo.png"), None,
                   vio.add_noise_and_quantise(img * expo, rng, FULL_WELL, READ_NOISE))
    return secs, expo


def make_dish(name, c):
    """A bubble on a dish: the film (make_cycles.py's sphere, whole: its part under the
    water is hidden, the water plane being opaque) standing in a water plane, in a map."""
    out = os.path.join(vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    cam = dish_camera(c)
    t0 = time.time()
    sc = mc.reset(cam.width, cam.height, mc.SPP)
    mc.world(sc, os.path.join(vio.ENVMAPS, c["envmap"] + ".exr"))
    mc.camera(sc, cam)
    liquid_plane(sc, c["plane_y"], water_material())
    mc.sphere(sc, dish_film_material(c))
    secs, expo = render_photo(sc, name, out, c["seed"], t0)
    vio.write_exr(os.path.join(out, "thickness_true.exr"), dish_truth(c).astype(np.float32))
    kind = c["fits"][0]
    with open(os.path.join(out, "scene.toml"), "w") as fh:
        fh.write(dish_scene_toml(c, kind))
    truth = {
        "case": name, "kind": "film",
        "renderer": f"Blender {bpy.app.version_string} Cycles (CPU), {mc.SPP} spp, box filter 1 px, denoiser off",
        "renderer_version": f"bpy {bpy.app.version_string}", "render_seconds": round(secs, 1),
        "camera": cam.describe(),
        "cap": {"center": [0.0, 0.0, 0.0], "radius": 1.0, "plane_y": c["plane_y"], "height": 1.0 - c["plane_y"],
                "n_film": mc.N_FILM, "liquid_ior": N_LIQUID,
                "material": "Principled BSDF: IOR 1.0, Transmission Weight 1, Roughness 0, Thin Film IOR 1.4",
                "mesh": "UV sphere 256 x 128, smooth shading (its part under the water hidden by the water plane)",
                "liquid": "120 x 120 plane, Principled BSDF: IOR 1.333, Base Color black, Roughness 0, opaque"},
        "envmap": f"envmaps/{c['envmap']}.exr",
        "top_nm": c["top_nm"], "bottom_nm": c["bottom_nm"], "exponent": c["exponent"],
        "profile": "d = top + (bottom - top) u^exponent, u = (1 - y) / H: 0 at the cap's top, 1 at its foot",
        "illuminant": "E",
        "approximations": [
            "Cycles averages s and p polarisation at each surface hit",
            "Cycles integrates the film's spectrum under illuminant E",
            "film index 1.4 and water index 1.333 at every wavelength",
            "UV-sphere mesh (256 x 128) with interpolated normals, not an exact sphere",
            "every light path (to 64 bounces), Monte Carlo noise (denoiser off)"],
        "exposure": expo,
        "noise": {"model": "Cycles Monte Carlo noise, then Poisson-Gaussian and 8-bit sRGB",
                  "full_well_e_at_1.0": FULL_WELL, "read_noise_e": READ_NOISE, "seed": c["seed"]},
        "fits": c["fits"], "fit_args": ["--scene", "scene.toml"],
    }
    if c["top_nm"] == c["bottom_nm"]:
        truth["thickness_nm"] = c["top_nm"]
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: {secs:.1f} s, exposure {expo:.4g}", flush=True)


#: A whole soap bubble under a diffuse panel behind the camera, in a dark room: make_cycles.py's
#: bubble (UV sphere of radius 1 at the origin, transmissive, Thin Film IOR 1.4, roughness 0)
#: and a Blender rectangular area light (spread 180 degrees: a Lambertian panel) facing -z.
SPHERE_PANEL_CASES = {
    # held out (split.toml, test part): rendered before any fit was run on it
    "cyc_sphere_const_panel": dict(thickness_nm=590.0, origin=(0.25, 0.3, 4.0), target=(0.0, 0.0, 0.0), fov_deg=34.0,
                                   panel_center=(0.0, 0.4, 4.6), panel_size=(6.0, 4.0), spp=1024, seed=71,
                                   fits=["constant"]),
}
SPHERE_SIZE = 112


def sphere_panel(sc, c):
    """The rectangle ``panel_size`` (width along x, height along y) at ``panel_center``, emitting towards -z."""
    data = bpy.data.lights.new("panel", type="AREA")
    data.shape = "RECTANGLE"
    data.size, data.size_y = c["panel_size"]
    data.energy = 1000.0
    data.spread = math.pi
    data.color = (1.0, 1.0, 1.0)
    obj = bpy.data.objects.new("panel", data)
    sc.collection.objects.link(obj)
    obj.location = mc.to_blender(c["panel_center"])
    obj.rotation_euler = (math.pi / 2, 0.0, 0.0)             # local -Z to bubblefit -z, local Y to bubblefit +y
    return obj


def sphere_scene_toml(c) -> str:
    w, h = c["panel_size"]
    return (
        "# A soap bubble under a diffuse panel behind the camera, in a dark room (Blender Cycles)\n"
        f"[film]\nshape = \"sphere\"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nn = {mc.N_FILM}\n"
        "thickness = \"constant\"\nrange_nm = [0.0, 1500.0]\n"
        "film_rgb = \"clamped\"   # Cycles clamps each film's RGB reflectance to [0, 1]\n\n"
        f"[light]\ntype = \"area\"\nshape = \"rect\"\ncenter = {list(c['panel_center'])}\nnormal = [0.0, 0.0, -1.0]\n"
        f"up = [0.0, 1.0, 0.0]\nsize = [{w}, {h}]\nradiance = 1.0\n"
        "lamp = \"E\"   # Cycles integrates its thin film under illuminant E\n\n"
        f"[camera]\ntype = \"perspective\"\nwidth = {SPHERE_SIZE}\nheight = {SPHERE_SIZE}\n"
        f"origin = {list(c['origin'])}\ntarget = {list(c['target'])}\nup = [0.0, 1.0, 0.0]\n"
        f"fov_deg = {c['fov_deg']}\n")


def make_sphere_panel(name, c):
    """A whole bubble lit by a panel behind the camera; the world is black."""
    out = os.path.join(vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    cam = rr.Camera("persp", SPHERE_SIZE, SPHERE_SIZE, origin=c["origin"], target=c["target"], up=(0.0, 1.0, 0.0),
                    fov_deg=c["fov_deg"])
    t0 = time.time()
    sc = mc.reset(cam.width, cam.height, c["spp"])
    black_world(sc)
    mc.camera(sc, cam)
    sphere_panel(sc, c)
    mc.sphere(sc, mc.bubble_material(rr.Thickness("constant", c["thickness_nm"])))
    secs, expo = render_photo(sc, name, out, c["seed"], t0)
    jj, ii = np.meshgrid(np.arange(SPHERE_SIZE) + 0.5, np.arange(SPHERE_SIZE) + 0.5)
    o, d = cam.rays(jj.reshape(-1), ii.reshape(-1), np.zeros(3), 1.0)
    hit, _ = rr._intersect(o, d, np.zeros(3), 1.0)
    vio.write_exr(os.path.join(out, "thickness_true.exr"),
                  np.where(hit, c["thickness_nm"], np.nan).reshape(SPHERE_SIZE, SPHERE_SIZE).astype(np.float32))
    with open(os.path.join(out, "scene.toml"), "w") as fh:
        fh.write(sphere_scene_toml(c))
    truth = {
        "case": name, "kind": "film",
        "renderer": f"Blender {bpy.app.version_string} Cycles (CPU), {c['spp']} spp, box filter 1 px, denoiser off",
        "renderer_version": f"bpy {bpy.app.version_string}", "render_seconds": round(secs, 1),
        "camera": cam.describe(),
        "sphere": {"center": [0.0, 0.0, 0.0], "radius": 1.0, "n_film": mc.N_FILM,
                   "material": "Principled BSDF: IOR 1.0, Transmission Weight 1, Roughness 0, Thin Film IOR 1.4",
                   "mesh": "UV sphere 256 x 128, smooth shading"},
        "light": {"type": "Blender Area light, rectangle, spread 180 deg, emitting along -z",
                  "center": list(c["panel_center"]), "size": list(c["panel_size"])},
        "world": "black",
        "thickness_nm": c["thickness_nm"], "illuminant": "E",
        "approximations": [
            "Cycles averages s and p polarisation at each surface hit",
            "Cycles integrates the film's spectrum under illuminant E and clamps each RGB channel to [0, 1]",
            "film index 1.4 at every wavelength",
            "UV-sphere mesh (256 x 128) with interpolated normals, not an exact sphere",
            "every light path (to 64 bounces), Monte Carlo noise (denoiser off): each sample reflects or "
            "transmits at random in proportion to the film's reflectance"],
        "exposure": expo,
        "noise": {"model": "Cycles Monte Carlo noise, then Poisson-Gaussian and 8-bit sRGB",
                  "full_well_e_at_1.0": FULL_WELL, "read_noise_e": READ_NOISE, "seed": c["seed"]},
        "fits": c["fits"], "fit_args": ["--scene", "scene.toml"],
    }
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: {secs:.1f} s, exposure {expo:.4g}", flush=True)


def make(name, c):
    out = os.path.join(vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    t0 = time.time()
    img = render(c, path=os.path.join("/tmp", name + ".exr"))
    secs = time.time() - t0
    truth_map = thickness_truth(c)
    expo = 0.9 / float(np.percentile(img, 99.5))
    rng = np.random.default_rng(c["seed"])
    vio.write_png8(os.path.join(out, "photo.png"), None, vio.add_noise_and_quantise(img * expo, rng, FULL_WELL, READ_NOISE))
    vio.write_exr(os.path.join(out, "thickness_true.exr"), truth_map.astype(np.float32))
    kind = c["fits"][0]
    with open(os.path.join(out, "scene.toml"), "w") as fh:
        fh.write(scene_toml(c, kind))
    truth = {
        "case": name, "kind": "film",
        "renderer": f"Blender {bpy.app.version_string} Cycles (CPU), {SPP} spp, box filter 1 px, denoiser off",
        "renderer_version": f"bpy {bpy.app.version_string}", "render_seconds": round(secs, 1),
        "camera": cam_of(c).describe(),
        "film": {"frame_m": FRAME, "n_film": N_FILM, "plane": "z = 0, normal +z, up +y",
                 "material": "Principled BSDF: IOR 1.0, Transmission Weight 0, Base Color black, Roughness 0, "
                             f"Thin Film IOR {N_FILM}"},
        "light": {"type": "Blender Area light, square, spread 180 deg", "center": list(PANEL), "size_m": PANEL_SIZE},
        "top_nm": c["top_nm"], "bottom_nm": c["bottom_nm"], "exponent": c["exponent"],
        "profile": "d = top + (bottom - top) f^exponent, f = 0 at the frame's top edge, 1 at its bottom",
        "illuminant": "E",
        "approximations": [
            "Cycles averages s and p polarisation of the film",
            "Cycles integrates the film's spectrum under illuminant E and clamps each RGB channel to [0, 1]",
            "film index 1.33 at every wavelength",
            "pixels crossed by the frame's edge are partly black (box filter)"],
        "exposure": expo,
        "noise": {"model": "Poisson-Gaussian then 8-bit sRGB", "full_well_e_at_1.0": FULL_WELL,
                  "read_noise_e": READ_NOISE, "seed": c["seed"]},
        "fits": c["fits"], "fit_args": ["--scene", "scene.toml"],
    }
    if c["top_nm"] == c["bottom_nm"]:
        truth["thickness_nm"] = c["top_nm"]
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: {secs:.1f} s, exposure {expo:.4g}, d {np.nanmin(truth_map):.0f}..{np.nanmax(truth_map):.0f} nm",
          flush=True)


if __name__ == "__main__":
    jobs = sys.argv[1:] or [*CASES, "cap", *DISH_CASES, *SPHERE_PANEL_CASES]
    if "probe" in jobs:
        probe()
    if "cap" in jobs:
        make_cap()
    for name in jobs:
        if name in CASES:
            make(name, CASES[name])
        if name in DISH_CASES:
            make_dish(name, DISH_CASES[name])
        if name in SPHERE_PANEL_CASES:
            make_sphere_panel(name, SPHERE_PANEL_CASES[name])
