"""OpenPBR Surface in a MaterialX document: the soap film as a material.

``bubble.mtlx`` holds one ``open_pbr_surface`` (MaterialX 1.39's standard library): a
thin-walled, fully transmissive surface (``transmission_weight`` 1,
``geometry_thin_walled`` true) whose dielectric base has ``specular_ior`` 1.0, so that
the only reflection is the thin film's (``thin_film_weight`` 1, ``thin_film_ior`` n_g,
``thin_film_thickness`` in micrometres, OpenPBR's unit): air | film | air. A film that
is not constant reads its thickness from ``thickness.png`` through an ``image`` node and
a ``range`` node (code 0..1 to the minimum..maximum in um), in the texture coordinates of
``sphere.obj`` written beside it (MaterialX's origin is the lower left, as OBJ's).
``specular_roughness`` is ``sqrt(a)`` (Ward's ``a`` as the microfacet width).

MaterialX's own implementation of the surface (the ``open_pbr_surface`` node graph of
MaterialX 1.39 and the GLSL generated from it) films the reflection lobe only and does not
take the film's reflection out of the transmitted light; the export's log says so
(docs/export.md measures what it costs).

References
----------
Academy Software Foundation, OpenPBR Surface specification v1.1 (thin film, thin-walled
geometry) and MaterialX 1.39 specification (``image``, ``range``, ``surfacematerial``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from ..io.atomic import write_text
from .assets import write_obj, write_thickness_texture
from .notes import diffuse_note, paper_model_note, roughness_note
from .record import FittedBubble

__all__ = ["write_openpbr", "limitations"]


def limitations(bubble: FittedBubble) -> list[str]:
    """What a MaterialX material cannot say about this fit, in words."""
    out = ["MaterialX describes the material only: the sphere is sphere.obj, and the camera, the environment map "
           f"(its rotation {bubble.rotation_deg:g} deg and gain {bubble.exposure:.4g}) and the backplate are the "
           "renderer's to set (export.json lists them)",
           "MaterialX's own open_pbr_surface (its node graph, 1.39) puts the thin film on the reflection lobe "
           "only, and its GLSL does not take the film's reflection out of the transmitted light: what is seen "
           "through the bubble keeps its colour and is brighter by the film's reflectance (renderers that take "
           "the film's reflectance out of the transmitted light do not have this)",
           roughness_note(bubble, "specular_roughness"),
           diffuse_note(bubble),
           paper_model_note(bubble, "the film's Fresnel sets it")]
    return [line for line in out if line]


def _input(node, name, type_, value=None, nodename=None, **extra):
    attrs = {"name": name, "type": type_}
    if value is not None:
        attrs["value"] = str(value)
    if nodename is not None:
        attrs["nodename"] = nodename
    attrs.update(extra)
    return ET.SubElement(node, "input", attrs)


def write_openpbr(bubble: FittedBubble, out: Path) -> tuple[list[Path], list[str]]:
    """Write ``bubble.mtlx`` (and ``thickness.png``, ``sphere.obj``) into ``out``; return (files, notes)."""
    tex = write_thickness_texture(bubble, out)
    mesh = write_obj(out)
    doc = ET.Element("materialx", {"version": "1.39", "colorspace": "lin_rec709"})
    if tex.path is not None:
        img = ET.SubElement(doc, "image", {"name": "film_code", "type": "float"})
        _input(img, "file", "filename", tex.path.name, colorspace="raw")
        _input(img, "uaddressmode", "string", "periodic")
        _input(img, "vaddressmode", "string", "clamp")
        rng = ET.SubElement(doc, "range", {"name": "film_thickness_um", "type": "float"})
        _input(rng, "in", "float", nodename="film_code")
        _input(rng, "inlow", "float", "0")
        _input(rng, "inhigh", "float", "1")
        _input(rng, "outlow", "float", f"{tex.minimum / 1000:.7g}")
        _input(rng, "outhigh", "float", f"{tex.maximum / 1000:.7g}")
    sh = ET.SubElement(doc, "open_pbr_surface", {"name": "soap_film", "type": "surfaceshader"})
    _input(sh, "base_weight", "float", "1")
    _input(sh, "base_color", "color3", "1, 1, 1")
    _input(sh, "specular_weight", "float", "1")
    _input(sh, "specular_ior", "float", "1")
    _input(sh, "specular_roughness", "float", f"{math.sqrt(max(bubble.roughness, 0.0)):.6g}")
    _input(sh, "transmission_weight", "float", "1")
    _input(sh, "thin_film_weight", "float", "1")
    if tex.path is not None:
        _input(sh, "thin_film_thickness", "float", nodename="film_thickness_um")
    else:
        _input(sh, "thin_film_thickness", "float", f"{tex.minimum / 1000:.7g}")
    _input(sh, "thin_film_ior", "float", f"{bubble.n_film:.6g}")
    _input(sh, "geometry_thin_walled", "boolean", "true")
    mat = ET.SubElement(doc, "surfacematerial", {"name": "soap_bubble", "type": "material"})
    _input(mat, "surfaceshader", "surfaceshader", nodename="soap_film")
    ET.indent(doc)
    path = out / "bubble.mtlx"
    write_text(path, '<?xml version="1.0"?>\n' + ET.tostring(doc, encoding="unicode") + "\n")
    files = [path, mesh] + ([tex.path] if tex.path is not None else [])
    return files, limitations(bubble)
