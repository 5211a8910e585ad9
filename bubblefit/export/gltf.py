"""glTF 2.0: the bubble as a thin-walled transmissive sphere with an iridescent film.

The material is the core metallic-roughness model (white base, metallic 0, roughness
``sqrt(a)``: Ward's ``a`` read as the microfacet slope width ``alpha = roughness^2``)
with ``KHR_materials_transmission`` (factor 1: the sphere is a thin wall, no
``KHR_materials_volume``), ``KHR_materials_ior`` (1.0: the wall itself does not reflect,
the film does) and ``KHR_materials_iridescence`` (film index ``n_g``; thickness between
``iridescenceThicknessMinimum`` and ``Maximum`` read from the texture's green channel, or
the maximum alone for a constant film). The camera node sees the sphere as in the photo.
Buffers and the texture are embedded as data URIs: one self-contained ``bubble.gltf``.

References
----------
Khronos Group, glTF 2.0 specification and the extensions ``KHR_materials_iridescence``,
``KHR_materials_transmission``, ``KHR_materials_ior`` (github.com/KhronosGroup/glTF).
"""

from __future__ import annotations

import base64
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.atomic import write_text
from .assets import MESH_SEGMENTS, copy_envmap, write_thickness_texture
from .notes import diffuse_note, paper_model_note, roughness_note
from .record import FittedBubble, sphere_mesh

__all__ = ["write_gltf", "limitations", "EXTENSIONS"]

EXTENSIONS = ["KHR_materials_iridescence", "KHR_materials_transmission", "KHR_materials_ior"]


def limitations(bubble: FittedBubble) -> list[str]:
    """What glTF cannot say about this fit, in words (the export's log)."""
    out = ["KHR_materials_iridescence colours the specular reflection only: the light the film transmits keeps "
           "its colour, so what is seen through the bubble lacks the film's complementary tint",
           "glTF has no environment lighting: the map, its rotation and the gain (exposure) are in the "
           "scene's extras for the viewer to set",
           "the background photo is not part of a glTF scene",
           roughness_note(bubble, "roughnessFactor"),
           diffuse_note(bubble, "a transmissive glTF material has none"),
           paper_model_note(bubble, "the viewer's Fresnel sets reflection and transmission")]
    if bubble.thickness.kind != "constant":
        out.append("the thickness is a 16-bit texture over the sphere between iridescenceThicknessMinimum and Maximum")
    return [line for line in out if line]


def _quaternion(m: np.ndarray) -> list[float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    t = np.trace(m)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
        q = [0.0] * 4
        q[i] = 0.25 * s
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
        q[3] = (m[k, j] - m[j, k]) / s
    return [float(v) for v in q]


def write_gltf(bubble: FittedBubble, out: Path) -> tuple[list[Path], list[str]]:
    """Write ``bubble.gltf`` (and ``envmap.*`` beside it) into ``out``; return (files, notes)."""
    try:
        import pygltflib as g
    except ImportError:
        raise InputError("the glTF export needs pygltflib (pip install 'bubblefit[export]')") from None

    pos, uv, tris = sphere_mesh(*MESH_SEGMENTS)
    nrm = pos.copy()
    blobs = [pos.tobytes(), nrm.tobytes(), uv.tobytes(), tris.astype(np.uint32).tobytes()]
    offsets = np.cumsum([0] + [len(b) for b in blobs])
    data = b"".join(blobs)
    views = [g.BufferView(buffer=0, byteOffset=int(offsets[i]), byteLength=len(blobs[i]),
                          target=g.ARRAY_BUFFER if i < 3 else g.ELEMENT_ARRAY_BUFFER) for i in range(4)]
    n = len(pos)
    accessors = [
        g.Accessor(bufferView=0, componentType=g.FLOAT, count=n, type=g.VEC3,
                   min=[float(v) for v in pos.min(0)], max=[float(v) for v in pos.max(0)]),
        g.Accessor(bufferView=1, componentType=g.FLOAT, count=n, type=g.VEC3),
        g.Accessor(bufferView=2, componentType=g.FLOAT, count=n, type=g.VEC2),
        g.Accessor(bufferView=3, componentType=g.UNSIGNED_INT, count=int(tris.size), type=g.SCALAR),
    ]
    tex = write_thickness_texture(bubble, out)
    irid = {"iridescenceFactor": 1.0, "iridescenceIor": float(bubble.n_film),
            "iridescenceThicknessMinimum": float(tex.minimum), "iridescenceThicknessMaximum": float(tex.maximum)}
    images, textures, samplers = [], [], []
    if tex.path is not None:
        uri = "data:image/png;base64," + base64.b64encode(tex.path.read_bytes()).decode("ascii")
        images.append(g.Image(uri=uri, mimeType=None, name="film thickness (nm), fraction of [min, max]"))
        samplers.append(g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR, wrapS=g.REPEAT, wrapT=g.CLAMP_TO_EDGE))
        textures.append(g.Texture(sampler=0, source=0))
        irid["iridescenceThicknessTexture"] = {"index": 0, "texCoord": 0}
    material = g.Material(
        name="soap film", doubleSided=True,
        pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0,
                                                    roughnessFactor=float(math.sqrt(max(bubble.roughness, 0.0)))),
        extensions={"KHR_materials_iridescence": irid,
                    "KHR_materials_transmission": {"transmissionFactor": 1.0},
                    "KHR_materials_ior": {"ior": 1.0}})
    mesh = g.Mesh(name="bubble", primitives=[g.Primitive(
        attributes=g.Attributes(POSITION=0, NORMAL=1, TEXCOORD_0=2), indices=3, material=0)])
    cam = bubble.camera
    o, fwd, right, up = cam.basis()
    if cam.kind == "orthographic":
        camera = g.Camera(type="orthographic", name="photo camera", orthographic=g.Orthographic(
            xmag=float(cam.view_width / 2), ymag=float(cam.view_width * cam.height / cam.width / 2),
            znear=0.01, zfar=100.0))
    else:
        yfov = 2 * math.atan(math.tan(math.radians(cam.fov_deg) / 2) * cam.height / cam.width)
        camera = g.Camera(type="perspective", name="photo camera", perspective=g.Perspective(
            yfov=float(yfov), aspectRatio=float(cam.width / cam.height), znear=0.01, zfar=1000.0))
    # a glTF camera looks along its local -z with +y up: columns (right, up, -forward)
    rot = np.stack([right, up, -fwd], axis=1)
    nodes = [g.Node(name="bubble", mesh=0, translation=[float(v) for v in bubble.center],
                    scale=[float(bubble.radius)] * 3),
             g.Node(name="photo camera", camera=0, translation=[float(v) for v in o], rotation=_quaternion(rot))]
    env = copy_envmap(bubble, out)
    extras = {"bubblefit": {"fit": bubble.source, "model": bubble.model, "ok": bubble.ok,
                            "environment_map": None if env is None else env.name,
                            "environment_rotation_deg_about_y": bubble.rotation_deg,
                            "environment_gain": bubble.exposure, "image_size": [cam.width, cam.height],
                            "thickness": bubble.summary()["thickness"]}}
    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator="bubblefit export"), scene=0,
        scenes=[g.Scene(name="bubble", nodes=[0, 1], extras=extras)], nodes=nodes, meshes=[mesh],
        materials=[material], cameras=[camera], accessors=accessors, bufferViews=views,
        buffers=[g.Buffer(byteLength=len(data),
                          uri="data:application/octet-stream;base64," + base64.b64encode(data).decode("ascii"))],
        images=images, textures=textures, samplers=samplers, extensionsUsed=list(EXTENSIONS))
    path = out / "bubble.gltf"
    write_text(path, doc.to_json(indent=1))
    files = [path] + ([tex.path] if tex.path is not None else []) + ([env] if env is not None else [])
    return files, limitations(bubble)
