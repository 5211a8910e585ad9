"""Scene files for flat films and gaps: ``[film] shape = "plane"`` with its media and lamp.

A spherical bubble keeps its ``[bubble]`` table (:mod:`bubblefit.model.scene`); a flat
film or a gap is described by

``[film]``
    ``shape = "plane"``; ``n`` (the film or the gap: a number, ``"water"``, ``"soap"``,
    ``"air"``, ``{cauchy = [...]}``), ``above`` and ``below`` (the media on either side,
    ``"air"`` by default; ``above`` is where the light comes from), ``thickness`` =
    ``"map"`` (a per-pixel map), ``"newton"`` (a lens on a plate, ``h(r) = R - sqrt(R^2 - r^2)``)
    or ``"constant"``; ``range_nm = [lo, hi]``; ``reference`` = ``"thinnest"`` (a black film
    or a contact point: the darkest first-order pixels), or a region and value given as
    ``reference_region = [x0, y0, x1, y1]`` and ``reference_nm``. For a perspective camera
    the plane's ``center``, ``normal``, ``up`` and ``size`` (width, height) in scene units.
    ``stray`` (``"newton"`` only): the grey reflectance of the light that reaches the camera
    without interfering (the lens's top, the plate's bottom, scatter), ``"fit"`` (the
    default: a free parameter ``>= 0``, which the rings' maxima and minima fix) or a number
    in [0, 1] (fixed; 0: none). The other models take none: under one thickness or a map
    it is not told apart from the thickness.
``[light]``
    ``type = "coaxial"`` with ``na`` (the objective's numerical aperture) and ``lamp``
    (``"D65"``, ``"3200K"``, a CSV ``wavelength_nm,power``); ``envelope`` (``"newton"``
    only): the lamp's irradiance across the field, ``"auto"`` (the default: a smooth
    envelope fitted with the rings where they span enough fringes across the photo to fix
    it, :data:`bubblefit.inverse._newton.ENVELOPE_MIN_FRINGES`), ``"fit"`` (always) or
    ``"none"`` (a uniform lamp, or a photo already divided by its flat field); or ``type = "area"`` with
    ``shape`` (``"rect"``/``"disc"``), ``center``, ``normal``, ``up``, ``size``,
    ``radiance`` and ``lamp``.
``[camera]``
    coaxial light: ``width``, ``height`` and ``pixel_um`` (microns per pixel on the film,
    an orthographic view along the axis); area light: ``type = "perspective"`` with
    ``origin``, ``target``, ``up``, ``fov_deg`` as for bubbles. ``response`` as elsewhere.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..lighting.area import Patch, check_light_faces
from ..optics.coaxial import Stack
from ..optics import dispersion

__all__ = ["ENVELOPE_CHOICES", "ENVELOPE_DEFAULT", "PlanarScene", "STRAY_DEFAULT", "film_kind_and_range", "scene_fit", "is_area_sphere", "is_planar", "load_planar",
           "parse_area_light", "parse_cap", "parse_planar", "parse_region"]

THICKNESS_KINDS = ("map", "newton", "constant", "drainage")


#: What the ``newton`` model does with light that does not interfere (``[film] stray``):
#: ``"fit"`` (a free grey reflectance ``>= 0``) or a number (that reflectance, fixed; 0:
#: none). The scene's default and :func:`bubblefit.inverse._newton.fit_newton`'s.
STRAY_DEFAULT = "fit"

#: What the ``newton`` model does with the lamp's irradiance across the field (``[light]
#: envelope``): ``"auto"`` (fitted where the rings span enough fringes to fix it),
#: ``"fit"`` or ``"none"`` (uniform). The scene's default and
#: :func:`bubblefit.inverse._newton.fit_newton`'s; ``fit-planar --flat`` turns ``"auto"``
#: to ``"none"`` (the flat field has divided the lamp out).
ENVELOPE_DEFAULT = "auto"
ENVELOPE_CHOICES = ("auto", "fit", "none")


@dataclass(frozen=True)
class PlanarScene:
    """A flat film or gap, its lamp and its camera (typed record of the scene's tables)."""

    stack: Stack
    light: str                      # "coaxial" | "area"
    lamp: str                       # illuminant name or CSV path
    response: str
    width: int
    height: int
    thickness: str = "map"
    thickness_range: tuple = (0.0, 2000.0)
    reference: str = "thinnest"
    reference_region: tuple | None = None   # (x0, y0, x1, y1) pixels, half-open
    reference_nm: float | None = None
    stray: object = STRAY_DEFAULT           # "fit" or a fixed grey reflectance (newton only)
    envelope: str = ENVELOPE_DEFAULT        # the lamp across the field: "auto" | "fit" | "none" (newton only)
    na: float = 0.0
    pixel_um: float = 1.0
    camera: object | None = None            # PerspectiveCamera for an area light
    plane: Patch | None = None
    area: Patch | None = None
    files: tuple = field(default_factory=tuple)


def is_planar(data: dict) -> bool:
    """Whether a parsed scene file describes a flat film (``[film] shape = "plane"``)."""
    f = data.get("film")
    return isinstance(f, dict) and f.get("shape", "sphere") == "plane"


def _read_toml(path) -> dict:
    import tomllib

    path = Path(path)
    if not path.is_file():
        raise InputError(f"scene file not found: {path}")
    try:
        return tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"cannot read scene file {path}: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"scene file {path} is not valid TOML: {exc}") from None


def is_area_sphere(data: dict) -> bool:
    """Whether a parsed scene file describes a whole bubble under an area light
    (``[film] shape = "sphere"`` with ``[light] type = "area"``), which the cap's fit fits
    without a liquid (:mod:`bubblefit.model.cap_scene`)."""
    f, light = data.get("film"), data.get("light")
    return (isinstance(f, dict) and f.get("shape") == "sphere" and isinstance(light, dict)
            and light.get("type") == "area")


def scene_fit(path) -> str:
    """Which fit the scene file at ``path`` asks for: ``"plane"`` (a flat film or a gap),
    ``"cap"`` (the cap's fit: a bubble on a dish, or a whole bubble under an area light,
    :func:`is_area_sphere`) or ``"bubble"`` (a floating bubble in an environment map; also
    for a missing or bad file: the bubble's loader then says what is wrong). A ``[film]``
    of another shape is refused in one line, as is a cap whose plane misses its sphere
    (:class:`~bubblefit.model.cap.Cap`)."""
    try:
        data = _read_toml(path)
    except InputError:
        return "bubble"
    f = data.get("film")
    shape = f.get("shape", "sphere") if isinstance(f, dict) else "sphere"
    if shape == "cap":
        parse_cap(f)  # a bad cap gets its own line here; a good one is fitted by the cap's path
        return "cap"
    if shape not in ("plane", "sphere"):
        raise InputError(f'{path}: film.shape = {shape!r} is not supported (use "plane" for a flat film or a gap, '
                         '"cap" for a bubble on a dish, "sphere" or a [bubble] table for a bubble)')
    if shape == "plane":
        return "plane"
    return "cap" if is_area_sphere(data) else "bubble"
    if shape not in ("plane", "sphere"):
        raise InputError(f'{path}: film.shape = {shape!r} is not supported (use "plane" for a flat film or a gap, '
                         '"cap" for a bubble on a dish, "sphere" or a [bubble] table for a bubble)')
    return shape


def parse_cap(f: dict):
    """The :class:`~bubblefit.model.cap.Cap` of a ``[film] shape = "cap"`` table: ``center``,
    ``radius``, ``plane_y`` (the liquid's height) and ``liquid`` (its index, "water" by default)."""
    from .cap import Cap

    return Cap(center=_vec(f, "center", "film", 3, (0.0, 0.0, 0.0)), radius=_num(f, "radius", "film", 1.0, 0.0),
               plane_y=_num(f, "plane_y", "film", 0.0), liquid=dispersion.parse_index(f.get("liquid", "water"),
                                                                                      "film.liquid"))


def load_planar(path) -> PlanarScene:
    """Read and check a flat film's scene file."""
    return parse_planar(_read_toml(path), Path(path).parent)


def _num(table: dict, key: str, where: str, default=None, lo=-math.inf, hi=math.inf) -> float:
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise InputError(f"{where}.{key} must be a number within [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def film_kind_and_range(f: dict, kinds, default_kind: str, default_range: tuple, limit_nm: float,
                        what: str = "") -> tuple[str, tuple[float, float]]:
    """The ``[film]`` table's thickness model (one of ``kinds``) and searched range
    ``range_nm`` (0 <= lo < hi <= ``limit_nm``); ``what`` names the film in the messages."""
    kind = f.get("thickness", default_kind)
    if kind not in kinds:
        raise InputError(f"film.thickness{what} must be one of {', '.join(kinds)}, got {kind!r}")
    lo, hi = _vec(f, "range_nm", "film", 2, default_range)
    if not 0 <= lo < hi <= limit_nm:
        raise InputError(f"film.range_nm must satisfy 0 <= lo < hi <= {limit_nm:g} nm, got {[lo, hi]}")
    return kind, (lo, hi)


def _vec(table: dict, key: str, where: str, n: int, default=None) -> tuple:
    v = table.get(key, default)
    ok = isinstance(v, (list, tuple)) and len(v) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    if not ok:
        raise InputError(f"{where}.{key} must be {n} numbers, got {v!r}")
    return tuple(float(x) for x in v)


def parse_region(text: str, width: int | None = None, height: int | None = None) -> tuple[tuple, float]:
    """``"x0,y0,x1,y1=VALUE_NM"`` (pixels, half-open) into ``((x0, y0, x1, y1), value)``."""
    try:
        box, value = text.split("=")
        x0, y0, x1, y1 = (int(float(v)) for v in box.split(","))
        nm = float(value)
    except ValueError:
        raise InputError(f"--reference-region must be x0,y0,x1,y1=VALUE_NM, got {text!r}") from None
    if not (x1 > x0 and y1 > y0) or not math.isfinite(nm) or nm < 0:
        raise InputError(f"--reference-region {text!r}: need x1 > x0, y1 > y0 and a thickness >= 0 nm")
    if width is not None and (x0 < 0 or y0 < 0 or x1 > width or y1 > height):
        raise InputError(f"--reference-region {text!r} lies outside the {width}x{height} photo")
    return (x0, y0, x1, y1), nm


def _lamp(value, base: Path, where: str) -> str:
    from ..optics import spectral

    if not isinstance(value, str):
        raise InputError(f"{where} must be an illuminant name (D65, 3200K, ...) or a CSV file, got {value!r}")
    if spectral.is_named_illuminant(value):
        return value
    path = (base / value) if not os.path.isabs(value) else Path(value)
    if not path.is_file():
        raise InputError(f"{where} {value!r} is neither a known illuminant nor a file")
    spectral.illuminant_spectrum(str(path))  # checks the table now (one line on a bad one)
    return str(path)


def _stray(f: dict, kind: str):
    """``[film] stray``: ``"fit"`` or a fixed reflectance in [0, 1] for ``"newton"``; 0 for
    the other models, which refuse any other value in one line."""
    value = f.get("stray", STRAY_DEFAULT if kind == "newton" else 0.0)
    if kind != "newton":
        if value != 0:
            raise InputError(f'film.stray applies to thickness = "newton" only (got {value!r} for "{kind}": under '
                             "one thickness or a per-pixel map, light that does not interfere is not told apart from "
                             "the thickness)")
        return 0.0
    if value == "fit":
        return value
    if isinstance(value, str):
        raise InputError(f'film.stray must be "fit" or a number in [0, 1], got {value!r}')
    return _num(f, "stray", "film", None, 0.0, 1.0)


def _envelope(light: dict, kind: str) -> str:
    """``[light] envelope``: one of :data:`ENVELOPE_CHOICES` for ``"newton"``; ``"none"`` for
    the other models, which refuse any other value in one line."""
    value = light.get("envelope", ENVELOPE_DEFAULT if kind == "newton" else "none")
    if kind != "newton":
        if value != "none":
            raise InputError(f'light.envelope applies to thickness = "newton" only (got {value!r} for "{kind}": under '
                             "one thickness or a per-pixel map, the lamp's fall-off is not told apart from the film)")
        return "none"
    if value not in ENVELOPE_CHOICES:
        raise InputError(f'light.envelope must be one of {", ".join(map(repr, ENVELOPE_CHOICES))}, got {value!r}')
    return value


def parse_planar(data: dict, base_dir: str | os.PathLike = ".") -> PlanarScene:
    """The :class:`PlanarScene` of a parsed scene file; one-line errors for bad values."""
    from .geometry import PerspectiveCamera

    base = Path(base_dir)
    f, light, cam = data.get("film", {}), data.get("light", {}), data.get("camera", {})
    if not isinstance(light, dict) or light.get("type") not in ("coaxial", "area"):
        raise InputError('a flat film needs [light] type = "coaxial" or "area"')
    stack = Stack(above=dispersion.parse_index(f.get("above", "air"), "film.above"),
                  film=dispersion.parse_index(f.get("n", 1.4), "film.n"),
                  below=dispersion.parse_index(f.get("below", "air"), "film.below"))
    kind, (lo, hi) = film_kind_and_range(f, THICKNESS_KINDS, "map", (0.0, 2000.0), 20000)
    region, ref_nm = None, None
    if "reference_region" in f:
        region = tuple(int(v) for v in _vec(f, "reference_region", "film", 4))
        ref_nm = _num(f, "reference_nm", "film", None, 0.0, 20000.0)
    stray = _stray(f, kind)
    width = int(_num(cam, "width", "camera", 256, 1, 16384))
    height = int(_num(cam, "height", "camera", 256, 1, 16384))
    response = cam.get("response", "srgb")
    lamp = _lamp(light.get("lamp", "D65"), base, "light.lamp")
    common = dict(stack=stack, lamp=lamp, response=response, width=width, height=height, thickness=kind,
                  thickness_range=(lo, hi), reference="region" if region else str(f.get("reference", "thinnest")),
                  reference_region=region, reference_nm=ref_nm, stray=stray, envelope=_envelope(light, kind))
    if common["reference"] not in ("thinnest", "region"):
        raise InputError(f'film.reference must be "thinnest" or a reference_region, got {f.get("reference")!r}')
    if light["type"] == "coaxial":
        na = _num(light, "na", "light", 0.0, 0.0, 0.95)
        pixel_um = _num(cam, "pixel_um", "camera", 1.0, 1e-6, 1e6)
        return PlanarScene(light="coaxial", na=na, pixel_um=pixel_um, **common)
    if cam.get("type") != "perspective":
        raise InputError('an area light needs a [camera] type = "perspective" (origin, target, up, fov_deg)')
    camera = PerspectiveCamera(width=width, height=height, origin=_vec(cam, "origin", "camera", 3),
                               target=_vec(cam, "target", "camera", 3), up=_vec(cam, "up", "camera", 3, (0, 1, 0)),
                               fov_deg=_num(cam, "fov_deg", "camera", 35.0, 1.0, 170.0))
    plane = Patch(center=_vec(f, "center", "film", 3), normal=_vec(f, "normal", "film", 3),
                  up=_vec(f, "up", "film", 3, (0, 1, 0)), size=_vec(f, "size", "film", 2))
    area = parse_area_light(light)
    check_light_faces(area, plane.center, "the film")
    return PlanarScene(light="area", camera=camera, plane=plane, area=area, **common)


def parse_area_light(light: dict) -> Patch:
    """The :class:`~bubblefit.lighting.area.Patch` of a ``[light] type = "area"`` table
    (flat films and whole bubbles alike): ``shape`` ``"rect"`` (``size = [w, h]``) or
    ``"disc"`` (``radius``), ``center``, ``normal`` (the side it shines to), ``up`` and
    ``radiance``; a zero size is one line."""
    shape = light.get("shape", "rect")
    if shape not in ("rect", "disc"):
        raise InputError(f'light.shape must be "rect" or "disc", got {shape!r}')
    size = _vec(light, "size", "light", 2) if shape == "rect" else (_num(light, "radius", "light", None, 0),) * 2
    if min(size) <= 0:
        raise InputError(f"the area light has no size (light.{'size' if shape == 'rect' else 'radius'} must be "
                         f"positive, got {list(size) if shape == 'rect' else size[0]})")
    return Patch(center=_vec(light, "center", "light", 3), normal=_vec(light, "normal", "light", 3),
                 up=_vec(light, "up", "light", 3, (0, 1, 0)), size=size, shape=shape,
                 radiance=_num(light, "radiance", "light", 1.0, 0.0))
