"""Blender: a Python script that builds the fitted bubble as a Cycles scene (Blender >= 4.2).

``bubble_blender.py`` runs inside Blender (``blender --background --python
bubble_blender.py -- [--render OUT.exr] [--samples N] [--save OUT.blend]``) or with the
``bpy`` module (``python bubble_blender.py ...``). It builds:

* the sphere (``sphere.obj`` beside it, the shared UV sphere) with a Principled BSDF of
  IOR 1.0, Transmission 1 and the thin film of Blender 4.2 (Thin Film Thickness from the
  texture between its minimum and maximum, or the constant; Thin Film IOR ``n_g``):
  Cycles' film over a base of IOR 1 is an air | film | air soap film with its exact
  two-interface reflectance, and transmits what it does not reflect;
* the world: the environment map times the fit's gain, turned by the fit's rotation;
* the backplate: the background photo as an emitting quad behind the bubble that fills
  the camera's view, seen by camera and transmission rays only (what the fit composites
  behind the film), not by reflections;
* the camera of the photo.

bubblefit's frame (+y up) is Blender's turned +90 degrees about X: a bubblefit point
(x, y, z) is Blender's (x, -z, y). The scene is built in bubblefit's frame under one
parent empty carrying that turn. Blender's Environment Texture reads a direction at
``u_Blender = u + 1/4`` of docs/design.md's ``u`` (verified in
experiments/validation/check_conventions.py), so the world's lookup is turned by
90 degrees minus the fit's rotation about Blender's +Z (bubblefit's +y).

References
----------
Blender 4.2 manual, Principled BSDF, "Thin Film" inputs; Cycles ``thin_film`` closure.
"""

from __future__ import annotations

import math
import pprint
from pathlib import Path

from ..io.atomic import write_text
from .assets import backplate_quad, copy_envmap, write_backplate, write_obj, write_thickness_texture
from .notes import diffuse_note, paper_model_note, roughness_note
from .record import FittedBubble

__all__ = ["write_blender", "limitations", "MIN_BLENDER"]

#: The first Blender whose Principled BSDF has a thin film.
MIN_BLENDER = (4, 2, 0)


def limitations(bubble: FittedBubble) -> list[str]:
    """What a Cycles scene cannot say about this fit, in words."""
    out = [f"Cycles converts the film's spectrum to RGB under illuminant E; the fit used {bubble.illuminant}"
           if bubble.illuminant != "E" else "Cycles converts the film's spectrum under illuminant E, as the fit did",
           "Cycles averages s and p polarisation at each surface hit (the fit's physical model carries them apart)",
           roughness_note(bubble, "Roughness"),
           diffuse_note(bubble, "a fully transmissive Principled BSDF has none"),
           paper_model_note(bubble, "Cycles' film sets reflection and transmission from n_g by Fresnel's and "
                            "Airy's formulas", with_r_s=True)]
    return [line for line in out if line]


SCRIPT = r'''"""Build the fitted soap bubble in Blender (written by `bubblefit export --to blender`).

    blender --background --python bubble_blender.py -- [--render OUT.exr] [--samples N] [--save OUT.blend]
    python bubble_blender.py [--render OUT.exr] [--samples N] [--save OUT.blend]    # with the bpy module

It replaces the open file's contents with the bubble, its camera, world and backplate.
"""
import argparse
import math
import os
import sys

import bpy
from mathutils import Matrix

P = __PARAMS__
HERE = os.path.dirname(os.path.abspath(__file__))
if bpy.app.version < (4, 2, 0):
    sys.exit(f"Blender {bpy.app.version_string} has no Principled thin film: Blender 4.2 or later is needed")


def read_obj(path):
    """Positions, per-corner uvs and triangles of an OBJ whose v/vt/vn indices agree."""
    verts, uvs, faces = [], [], []
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append(tuple(map(float, line.split()[1:4])))
            elif line.startswith("vt "):
                uvs.append(tuple(map(float, line.split()[1:3])))
            elif line.startswith("f "):
                faces.append(tuple(int(c.split("/")[0]) - 1 for c in line.split()[1:]))
    return verts, uvs, faces


def build(samples):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_adaptive_sampling = False
    sc.cycles.use_denoising = False
    sc.cycles.pixel_filter_type = "BOX"
    sc.cycles.filter_width = 1.0
    for k in ("max_bounces", "transmission_bounces", "glossy_bounces", "transparent_max_bounces"):
        setattr(sc.cycles, k, 32)
    sc.cycles.diffuse_bounces = 0
    sc.cycles.sample_clamp_direct = 0.0
    sc.cycles.sample_clamp_indirect = 0.0
    sc.cycles.blur_glossy = 0.0
    sc.cycles.caustics_reflective = True
    sc.cycles.caustics_refractive = True
    sc.render.resolution_x, sc.render.resolution_y = P["camera"]["width"], P["camera"]["height"]
    sc.render.resolution_percentage = 100
    sc.render.film_transparent = False
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"

    # bubblefit's frame (+y up) under one empty turned +90 degrees about X
    root = bpy.data.objects.new("bubblefit frame", None)
    sc.collection.objects.link(root)
    root.rotation_euler = (math.pi / 2, 0.0, 0.0)

    # world: the map times the fit's gain, turned by the fit's rotation about +y
    w = bpy.data.worlds.new("environment")
    sc.world = w
    w.use_nodes = True
    nt = w.node_tree
    nt.nodes.clear()
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = P["exposure"]
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    if P["envmap"]:
        tc = nt.nodes.new("ShaderNodeTexCoord")
        mp = nt.nodes.new("ShaderNodeMapping")
        mp.vector_type = "VECTOR"
        mp.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(90.0 - P["rotation_deg"]))
        tex = nt.nodes.new("ShaderNodeTexEnvironment")
        tex.image = bpy.data.images.load(os.path.join(HERE, P["envmap"]))
        tex.image.colorspace_settings.name = "Linear Rec.709"
        tex.interpolation = "Linear"
        nt.links.new(tc.outputs["Generated"], mp.inputs["Vector"])
        nt.links.new(mp.outputs["Vector"], tex.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
    else:
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)

    # the bubble
    verts, uvs, faces = read_obj(os.path.join(HERE, P["mesh"]))
    mesh = bpy.data.meshes.new("bubble")
    mesh.from_pydata(verts, [], faces)
    layer = mesh.uv_layers.new(name="UVMap")
    for loop in mesh.loops:
        layer.data[loop.index].uv = uvs[loop.vertex_index]
    for poly in mesh.polygons:
        poly.use_smooth = True
    bubble = bpy.data.objects.new("bubble", mesh)
    sc.collection.objects.link(bubble)
    bubble.parent = root
    bubble.location = P["center"]
    bubble.scale = (P["radius"],) * 3
    m = bpy.data.materials.new("soap film")
    m.use_nodes = True
    mt = m.node_tree
    pr = mt.nodes["Principled BSDF"]
    pr.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    pr.inputs["IOR"].default_value = 1.0
    pr.inputs["Transmission Weight"].default_value = 1.0
    pr.inputs["Roughness"].default_value = P["blender_roughness"]
    pr.inputs["Metallic"].default_value = 0.0
    pr.inputs["Thin Film IOR"].default_value = P["n_film"]
    th = P["thickness"]
    if th["texture"] is None:
        pr.inputs["Thin Film Thickness"].default_value = th["minimum_nm"]
    else:
        img = mt.nodes.new("ShaderNodeTexImage")
        img.image = bpy.data.images.load(os.path.join(HERE, th["texture"]))
        img.image.colorspace_settings.name = "Non-Color"
        img.interpolation = "Linear"
        uvn = mt.nodes.new("ShaderNodeUVMap")
        uvn.uv_map = "UVMap"
        mt.links.new(uvn.outputs["UV"], img.inputs["Vector"])
        rng = mt.nodes.new("ShaderNodeMapRange")
        rng.inputs["From Min"].default_value = 0.0
        rng.inputs["From Max"].default_value = 1.0
        rng.inputs["To Min"].default_value = th["minimum_nm"]
        rng.inputs["To Max"].default_value = th["maximum_nm"]
        rng.clamp = False
        mt.links.new(img.outputs["Color"], rng.inputs["Value"])
        mt.links.new(rng.outputs["Result"], pr.inputs["Thin Film Thickness"])
    mesh.materials.append(m)

    # the backplate: the background photo, seen by camera and transmission rays only
    if P["backplate"]:
        bp = P["backplate"]
        hw, hh = bp["half_width"], bp["half_height"]
        pm = bpy.data.meshes.new("backplate")
        pm.from_pydata([(-hw, -hh, 0), (hw, -hh, 0), (hw, hh, 0), (-hw, hh, 0)], [], [(0, 1, 2, 3)])
        pl = pm.uv_layers.new(name="UVMap")
        for loop, uv in zip(pm.loops, ((0, 0), (1, 0), (1, 1), (0, 1))):
            pl.data[loop.index].uv = uv
        plate = bpy.data.objects.new("backplate", pm)
        sc.collection.objects.link(plate)
        plate.parent = root
        plate.matrix_basis = Matrix(bp["matrix"])
        for k in ("visible_diffuse", "visible_glossy", "visible_shadow", "visible_volume_scatter"):
            setattr(plate, k, False)
        bm = bpy.data.materials.new("background photo")
        bm.use_nodes = True
        bt = bm.node_tree
        bt.nodes.clear()
        em = bt.nodes.new("ShaderNodeEmission")
        em.inputs["Strength"].default_value = 1.0
        tx = bt.nodes.new("ShaderNodeTexImage")
        tx.image = bpy.data.images.load(os.path.join(HERE, bp["image"]))
        tx.image.colorspace_settings.name = "Linear Rec.709"
        tx.interpolation = "Closest"
        mo = bt.nodes.new("ShaderNodeOutputMaterial")
        bt.links.new(tx.outputs["Color"], em.inputs["Color"])
        bt.links.new(em.outputs["Emission"], mo.inputs["Surface"])
        pm.materials.append(bm)

    # the camera of the photo (local -z forward, +y up, as in bubblefit)
    c = P["camera"]
    cd = bpy.data.cameras.new("photo camera")
    cam = bpy.data.objects.new("photo camera", cd)
    sc.collection.objects.link(cam)
    cam.parent = root
    sc.camera = cam
    cd.sensor_fit = "HORIZONTAL"
    cd.clip_start, cd.clip_end = 0.01, 1000.0
    if c["kind"] == "orthographic":
        cd.type = "ORTHO"
        cd.ortho_scale = c["view_width"]
    else:
        cd.type = "PERSP"
        cd.angle = math.radians(c["fov_deg"])
    cam.matrix_basis = Matrix(c["matrix"])
    return sc


def main(argv):
    ap = argparse.ArgumentParser(prog="bubble_blender.py")
    ap.add_argument("--render", help="render to this EXR (linear)")
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--threads", type=int, default=0, help="0: all")
    ap.add_argument("--save", help="save the scene as this .blend")
    a = ap.parse_args(argv)
    sc = build(a.samples)
    if a.threads:
        sc.render.threads_mode = "FIXED"
        sc.render.threads = a.threads
    if a.save:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(a.save))
    if a.render:
        sc.render.filepath = os.path.abspath(a.render)
        bpy.ops.render.render(write_still=True)


main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
'''


def _matrix(origin, right, up, back) -> list[list[float]]:
    """4x4 rows of the transform whose columns are the local axes and the origin."""
    rows = [[float(right[i]), float(up[i]), float(back[i]), float(origin[i])] for i in range(3)]
    return rows + [[0.0, 0.0, 0.0, 1.0]]


def write_blender(bubble: FittedBubble, out: Path) -> tuple[list[Path], list[str]]:
    """Write ``bubble_blender.py`` and the files it loads into ``out``; return (files, notes)."""
    mesh = write_obj(out)
    tex = write_thickness_texture(bubble, out)
    env = copy_envmap(bubble, out)
    plate = write_backplate(bubble, out)
    cam = bubble.camera
    o, fwd, right, up = cam.basis()
    camera = {"kind": cam.kind, "width": cam.width, "height": cam.height, "view_width": cam.view_width,
              "fov_deg": cam.fov_deg, "matrix": _matrix(o, right, up, -fwd)}
    backplate = None
    if plate is not None:
        centre, hw, hh = backplate_quad(bubble)
        backplate = {"image": plate.name, "half_width": hw, "half_height": hh,
                     "matrix": _matrix(centre, right, up, -fwd)}
    params = {"fit": bubble.source, "exposure": bubble.exposure, "rotation_deg": bubble.rotation_deg,
              "envmap": None if env is None else env.name, "mesh": mesh.name,
              "center": [float(v) for v in bubble.center], "radius": float(bubble.radius),
              "n_film": float(bubble.n_film), "blender_roughness": math.sqrt(max(bubble.roughness, 0.0)),
              "thickness": {"texture": None if tex.path is None else tex.path.name,
                            "minimum_nm": tex.minimum, "maximum_nm": tex.maximum},
              "backplate": backplate, "camera": camera}
    text = SCRIPT.replace("__PARAMS__", pprint.pformat(params, sort_dicts=False))
    path = out / "bubble_blender.py"
    write_text(path, text)
    files = [path, mesh] + [p for p in (tex.path, env, plate) if p is not None]
    notes = limitations(bubble)
    if plate is None:
        notes.append("no background photo: the bubble is seen against the environment map")
    return files, notes
