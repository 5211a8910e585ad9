"""Files several formats share: the sphere mesh, the thickness texture, the map, the backplate.

Every file is written through :mod:`bubblefit.io.atomic` (images through
:mod:`bubblefit.io.images`). The thickness texture is a 16-bit PNG whose codes are data,
not colour: ``d = minimum + (maximum - minimum) code / 65535`` in every channel (glTF's
``KHR_materials_iridescence`` reads green), so that the same file serves every format.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path, write_text
from .record import FittedBubble, sphere_mesh, thickness_texture

__all__ = ["ThicknessTexture", "write_thickness_texture", "write_obj", "copy_envmap", "write_backplate",
           "TEXTURE_SIZE", "MESH_SEGMENTS"]

#: (width, height) of the thickness texture: 0.7 degrees of the sphere per texel.
TEXTURE_SIZE = (512, 256)
#: (around, top to bottom) segments of the exported UV sphere: its flat facets stay within
#: 1 - cos(pi / 64) = 0.12 % of the radius of the true sphere.
MESH_SEGMENTS = (128, 64)


@dataclass(frozen=True)
class ThicknessTexture:
    """A written thickness texture: its file (None for a constant film) and range in nm."""

    path: Path | None
    minimum: float
    maximum: float
    step_nm: float


def write_thickness_texture(bubble: FittedBubble, out: Path) -> ThicknessTexture:
    """``thickness.png`` (16-bit, codes = fraction of [min, max]) unless the film is constant."""
    import OpenImageIO as oiio

    from ..io.images import _write_oiio

    if bubble.thickness.kind == "constant":
        d = float(bubble.thickness.value)
        return ThicknessTexture(None, d, d, 0.0)
    nu, nv = TEXTURE_SIZE
    tex = thickness_texture(bubble, nu, nv)
    lo, hi = float(tex.min()), float(tex.max())
    span = max(hi - lo, 1e-6)
    codes = np.round((tex - lo) / span * 65535).astype(np.uint16)
    data = np.ascontiguousarray(np.repeat(codes[..., None], 3, axis=-1))
    path = out / "thickness.png"
    spec = oiio.ImageSpec(nu, nv, 3, oiio.UINT16)
    spec.attribute("oiio:ColorSpace", "Linear")
    with atomic_path(path) as tmp:
        _write_oiio(tmp, path, spec, data)
    return ThicknessTexture(path, lo, hi, span / 65535)


def write_obj(out: Path, name: str = "sphere.obj") -> Path:
    """The unit UV sphere of :func:`~bubblefit.export.record.sphere_mesh` as Wavefront OBJ
    (positions, texture coordinates with v up as OBJ counts it, normals = positions)."""
    pos, uv, tris = sphere_mesh(*MESH_SEGMENTS)
    lines = ["# unit sphere, +y up; uv: u = atan2(x, z)/(2 pi), v = theta/pi from +y (OBJ vt stores 1 - v)"]
    lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in pos]
    lines += [f"vt {u:.7f} {1.0 - v:.7f}" for u, v in uv]
    lines += [f"vn {x:.7f} {y:.7f} {z:.7f}" for x, y, z in pos]
    lines += ["f " + " ".join(f"{k + 1}/{k + 1}/{k + 1}" for k in t) for t in tris]
    path = out / name
    write_text(path, "\n".join(lines) + "\n")
    return path


def copy_envmap(bubble: FittedBubble, out: Path) -> Path | None:
    """The fit's environment map, copied beside the export (None when the fit named none)."""
    if not bubble.envmap:
        return None
    src = Path(bubble.envmap)
    path = out / ("envmap" + src.suffix.lower())
    if path.resolve() == src.resolve():
        return path
    with atomic_path(path) as tmp:
        shutil.copyfile(src, tmp)
    return path


def write_backplate(bubble: FittedBubble, out: Path) -> Path | None:
    """The background photo as linear EXR (``background.exr``): the backplate behind the bubble."""
    if not bubble.background:
        return None
    from ..io.images import read_image, write_image

    img = read_image(bubble.background).pixels[..., :3]
    path = out / "background.exr"
    write_image(path, img.astype(np.float32), bit_depth=32)
    return path


def backplate_quad(bubble: FittedBubble, depth: float = 3.0) -> tuple[np.ndarray, float, float]:
    """``(centre, half_width, half_height)`` of a quad facing the camera ``depth`` radii
    behind the bubble's centre that fills the camera's view exactly (pixel for pixel)."""
    cam = bubble.camera
    o, fwd, right, up = cam.basis()
    dist = float(np.dot(np.asarray(bubble.center) - o, fwd)) + depth * bubble.radius
    centre = o + dist * fwd
    if cam.kind == "orthographic":
        half_w = cam.view_width / 2
    else:
        half_w = dist * np.tan(np.radians(cam.fov_deg) / 2)
    return centre, float(half_w), float(half_w * cam.height / cam.width)


def write_log(out: Path, name: str, lines: list[str]) -> Path:
    """The export's log: what was written and where the format cannot express the fit."""
    path = out / name
    write_text(path, "\n".join(lines) + "\n")
    return path
