"""Mitsuba 3: a scene XML with the bubble as a ``thindielectric`` sphere tinted by its film.

Mitsuba 3's ``thindielectric`` is the thick-film limit of a soap film: each interface's
unpolarised Fresnel reflectance ``R1`` summed incoherently, ``R = 2 R1 / (1 + R1)``, with
no interference. The fitted film's colour enters through the BSDF's two scale
textures, per texel of the sphere: ``specular_reflectance = R_film / R`` and
``specular_transmittance = (1 - R_film) / (1 - R)``, with ``R_film`` the RGB reflectance
of the exact two-interface (Airy) film at normal incidence under the fit's illuminant
(:func:`bubblefit.optics.chart.interference_colours`). At normal incidence this is the
film's colour; away from it the film's colour shifts (its optical path shortens as
``cos theta_t``) and Mitsuba keeps the normal-incidence tint times its own Fresnel
growth, which the export's log says. The sensor, the map (times the fit's gain, turned
by its rotation) and the backplate (the background photo as an emitting quad filling
the view) reproduce the photo's framing.

References
----------
W. Jakob et al., Mitsuba 3 documentation: ``thindielectric``, ``bitmap``, ``envmap``,
``orthographic``, ``perspective``, ``obj``, ``rectangle``, ``area`` plugins.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..io.atomic import write_text
from .assets import backplate_quad, copy_envmap, write_backplate, write_obj
from .notes import diffuse_note, paper_model_note
from .record import FittedBubble, thickness_texture

__all__ = ["write_mitsuba", "limitations", "TINT_SIZE", "thin_dielectric_reflectance"]

#: (width, height) of the tint textures (1.4 degrees of the sphere per texel).
TINT_SIZE = (256, 128)


def thin_dielectric_reflectance(n: float) -> float:
    """Normal-incidence reflectance of Mitsuba's ``thindielectric``: ``2 R1 / (1 + R1)``,
    ``R1 = ((n - 1)/(n + 1))^2`` (Fresnel at normal incidence, incoherent multiple bounces)."""
    r1 = ((n - 1.0) / (n + 1.0)) ** 2
    return 2 * r1 / (1 + r1)


def limitations(bubble: FittedBubble) -> list[str]:
    """What a Mitsuba 3 scene cannot say about this fit, in words."""
    out = ["Mitsuba 3's thindielectric has no interference: the film's colour is a tint at normal incidence "
           "(specular_reflectance, specular_transmittance) that does not shift with the angle of view",
           "the film is mirror-smooth (thindielectric has no roughness); "
           f"the fitted roughness a = {bubble.roughness:.4g} is left out",
           "the backplate also blocks the map behind the bubble for reflected rays at grazing angles",
           diffuse_note(bubble),
           paper_model_note(bubble, "Fresnel sets thindielectric's reflectance")]
    return [line for line in out if line]


def _film_rgb(thickness_nm: np.ndarray, bubble: FittedBubble) -> np.ndarray:
    from ..optics import spectral
    from ..optics.chart import interference_colours

    basis = spectral.spectral_basis("reference", illuminant=bubble.illuminant)
    flat = np.asarray(thickness_nm, np.float64).reshape(-1)
    uniq, inv = np.unique(np.round(flat, 1), return_inverse=True)
    rgb = np.asarray(interference_colours(uniq, model="airy", n_film=bubble.n_film, basis=basis), np.float64)
    return rgb[inv].reshape(*np.shape(thickness_nm), 3)


def _sub(parent, tag, **attrs):
    return ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})


def _matrix_text(m: np.ndarray) -> str:
    return " ".join(f"{v:.9g}" for v in np.asarray(m, float).reshape(-1))


def write_mitsuba(bubble: FittedBubble, out: Path, samples: int = 64) -> tuple[list[Path], list[str]]:
    """Write ``bubble_mitsuba.xml`` and the files it loads into ``out``; return (files, notes)."""
    from ..io.images import write_image

    mesh = write_obj(out)
    env = copy_envmap(bubble, out)
    plate = write_backplate(bubble, out)
    nu, nv = TINT_SIZE
    film = _film_rgb(thickness_texture(bubble, nu, nv), bubble)
    r = thin_dielectric_reflectance(bubble.n_film)
    refl, trans = out / "tint_reflectance.exr", out / "tint_transmittance.exr"
    write_image(refl, (film / r).astype(np.float32), bit_depth=32)
    write_image(trans, ((1 - film) / (1 - r)).astype(np.float32), bit_depth=32)

    cam = bubble.camera
    o, fwd, right, up = cam.basis()
    scene = ET.Element("scene", version="3.0.0")
    integ = _sub(scene, "integrator", type="path")
    _sub(integ, "integer", name="max_depth", value=24)
    sensor = _sub(scene, "sensor", type=cam.kind)
    tw = _sub(sensor, "transform", name="to_world")
    if cam.kind == "orthographic":
        half = cam.view_width / 2
        _sub(tw, "scale", x=half, y=half, z=1)
    else:
        _sub(sensor, "float", name="fov", value=cam.fov_deg)
        _sub(sensor, "string", name="fov_axis", value="x")
    _sub(tw, "lookat", origin=",".join(map(str, o)), target=",".join(map(str, o + fwd)),
         up=",".join(map(str, up)))
    _sub(sensor, "float", name="near_clip", value=0.01)
    _sub(sensor, "float", name="far_clip", value=1000)
    smp = _sub(sensor, "sampler", type="independent")
    _sub(smp, "integer", name="sample_count", value=samples)
    filmel = _sub(sensor, "film", type="hdrfilm")
    _sub(filmel, "integer", name="width", value=cam.width)
    _sub(filmel, "integer", name="height", value=cam.height)
    _sub(filmel, "string", name="pixel_format", value="rgb")
    _sub(filmel, "rfilter", type="box")
    if env is not None:
        em = _sub(scene, "emitter", type="envmap")
        _sub(em, "string", name="filename", value=env.name)
        _sub(em, "float", name="scale", value=bubble.exposure)
        etw = _sub(em, "transform", name="to_world")
        _sub(etw, "rotate", y=1, angle=bubble.rotation_deg)
    shape = _sub(scene, "shape", type="obj", id="bubble")
    _sub(shape, "string", name="filename", value=mesh.name)
    stw = _sub(shape, "transform", name="to_world")
    _sub(stw, "scale", value=bubble.radius)
    _sub(stw, "translate", x=bubble.center[0], y=bubble.center[1], z=bubble.center[2])
    bsdf = _sub(shape, "bsdf", type="thindielectric")
    _sub(bsdf, "float", name="int_ior", value=bubble.n_film)
    _sub(bsdf, "float", name="ext_ior", value=1.0)
    for name, path in (("specular_reflectance", refl), ("specular_transmittance", trans)):
        tex = _sub(bsdf, "texture", type="bitmap", name=name)
        _sub(tex, "string", name="filename", value=path.name)
        _sub(tex, "boolean", name="raw", value="true")
    if plate is not None:
        centre, hw, hh = backplate_quad(bubble)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right * hw, up * hh, -fwd, centre
        quad = _sub(scene, "shape", type="rectangle", id="backplate")
        _sub(_sub(quad, "transform", name="to_world"), "matrix", value=_matrix_text(m))
        black = _sub(quad, "bsdf", type="diffuse")
        _sub(black, "rgb", name="reflectance", value="0, 0, 0")
        area = _sub(quad, "emitter", type="area")
        tex = _sub(area, "texture", type="bitmap", name="radiance")
        _sub(tex, "string", name="filename", value=plate.name)
        _sub(tex, "boolean", name="raw", value="true")
        _sub(tex, "string", name="filter_type", value="nearest")
        utw = _sub(tex, "transform", name="to_uv")
        _sub(utw, "scale", x=1, y=-1)
        _sub(utw, "translate", x=0, y=1)
    ET.indent(scene)
    path = out / "bubble_mitsuba.xml"
    write_text(path, '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(scene, encoding="unicode") + "\n")
    files = [path, mesh, refl, trans] + [p for p in (env, plate) if p is not None]
    return files, limitations(bubble)
