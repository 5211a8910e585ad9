"""Scene files of a bubble on a dish: ``[film] shape = "cap"`` with its map and camera.

``[film]``
    ``shape = "cap"``; ``center``, ``radius`` (the sphere), ``plane_y`` (the liquid's
    surface, +y up), ``liquid`` (its index: a number, ``"water"``, ...; water by default),
    ``n`` (the film's index at 589.3 nm, 1.4 by default), ``thickness`` = ``"constant"``
    or ``"drainage"`` (along the cap's height: :func:`~bubblefit.model.cap_render.cap_drainage`),
    ``range_nm = [lo, hi]``; ``film_rgb`` = ``"spectral"`` (the default: the film's
    light per wavelength, integrated to RGB once) or ``"clamped"`` (each film's
    reflectance clamped to [0, 1] per RGB channel first, as Blender Cycles' thin film
    shades: for its renders, :class:`~bubblefit.model.cap_render.CapConfig`).
``[environment]``
    ``path`` (an equirectangular map, relative to the scene file), ``rotation_deg``, ``scale``,
    ``convention`` (where the map's texel rows sit: ``"mitsuba"``, the default, or
    ``"texel-centre"`` for a map made for Blender or PBRT:
    :data:`~bubblefit.lighting.envmap.CONVENTIONS`).
``[camera]``
    ``type = "perspective"`` with ``width``, ``height``, ``origin``, ``target``, ``up``,
    ``fov_deg``; ``response`` (the camera's sensitivities, ``"srgb"`` by default).
``[lighting]``
    ``illuminant``: the white the camera's colours are balanced to (``D65`` by default;
    ``E`` for Blender Cycles' thin film).

A whole bubble under an area light takes the same file with ``[film] shape = "sphere"``
(``center``, ``radius``, ``n``, ``thickness``: ``"drainage"`` is the sphere's own profile
along its height, ``range_nm``, ``film_rgb``; no liquid) and a ``[light] type = "area"``
table, read by the flat films' parser (:func:`~bubblefit.model.planar_scene.parse_area_light`;
its ``lamp`` is the illuminant). ``[environment]`` is then optional: without it the room is
dark but for the light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from .cap import Cap
from .geometry import PerspectiveCamera
from ..lighting.area import Patch, check_light_faces
from ..lighting.envmap import CONVENTIONS
from .planar_scene import (_lamp, _num, _read_toml, _vec, film_kind_and_range, is_area_sphere, parse_area_light,
                           parse_cap)

__all__ = ["CapScene", "load_cap_scene", "parse_cap_scene", "is_cap_file", "KINDS"]

KINDS = ("constant", "drainage")


@dataclass(frozen=True)
class CapScene:
    """A bubble on a dish, its map and its camera (typed record of the scene's tables)."""

    cap: Cap
    camera: PerspectiveCamera
    envmap: Path | None
    n_film: float = 1.4
    thickness: str = "constant"
    thickness_range: tuple = (0.0, 1500.0)
    rotation_deg: float = 0.0
    env_scale: float = 1.0
    illuminant: str = "D65"
    response: str = "srgb"
    film_rgb: str = "spectral"
    #: A whole bubble (``[film] shape = "sphere"``): no liquid; ``cap`` then carries the
    #: sphere, its plane at the sphere's bottom.
    sphere: bool = False
    area: Patch | None = None
    #: Where the map's texel rows sit (:data:`~bubblefit.lighting.envmap.CONVENTIONS`).
    env_convention: str = "mitsuba"


def is_cap_file(path) -> bool:
    """Whether the scene file at ``path`` says ``[film] shape = "cap"``, or ``"sphere"`` under
    a ``[light] type = "area"`` (a whole bubble, fitted by the cap's path without a
    liquid, :func:`~bubblefit.model.planar_scene.is_area_sphere`); False for a missing or
    bad file (``bubblefit render``; ``fit`` asks :func:`~bubblefit.model.planar_scene.scene_fit`)."""
    try:
        data = _read_toml(path)
    except InputError:
        return False
    f = data.get("film")
    return (isinstance(f, dict) and f.get("shape") == "cap") or is_area_sphere(data)


def load_cap_scene(path) -> CapScene:
    """Read and check a dish bubble's scene file (one line for a bad value)."""
    return parse_cap_scene(_read_toml(path), Path(path).parent)


def _misses(cap: Cap, camera: PerspectiveCamera) -> bool:
    """Whether the camera sits below the liquid or inside the sphere: it cannot see the cap."""
    o = camera.origin
    inside = math.dist(o, cap.center) <= cap.radius
    return o[1] <= cap.plane_y or inside


def parse_cap_scene(data: dict, base_dir=".") -> CapScene:
    """The :class:`CapScene` of a parsed scene file."""
    base = Path(base_dir)
    f, env, cam, light = (data.get(k, {}) for k in ("film", "environment", "camera", "lighting"))
    sphere = is_area_sphere(data)
    if sphere:
        radius = _num(f, "radius", "film", 1.0, 0.0)
        if radius <= 0:
            raise InputError(f"film.radius must be positive, got {radius:g}")
        center = _vec(f, "center", "film", 3, (0.0, 0.0, 0.0))
        cap = Cap(center=center, radius=radius, plane_y=center[1] - radius)
    else:
        cap = parse_cap(f)
        if "light" in data:
            raise InputError('an area light ([light]) is available for a whole bubble (film.shape = "sphere") and '
                             'flat films, not for a cap on a liquid')
    what = " of a bubble" if sphere else " of a cap"
    kind, (lo, hi) = film_kind_and_range(f, KINDS, "constant", (0.0, 1500.0), 5000, what=what)
    n_film = _num(f, "n", "film", 1.4, 1.0, 3.0)
    film_rgb = f.get("film_rgb", "spectral")
    if film_rgb not in ("spectral", "clamped"):
        raise InputError(f'film.film_rgb must be "spectral" or "clamped", got {film_rgb!r}')
    area, illuminant = None, str(light.get("illuminant", "D65"))
    if sphere:
        area = parse_area_light(data["light"])
        check_light_faces(area, cap.center, "the bubble")
        illuminant = _lamp(data["light"].get("lamp", "D65"), base, "light.lamp")
        if "illuminant" in light and str(light["illuminant"]) != illuminant:
            raise InputError(f"lighting.illuminant {light['illuminant']!r} differs from the area light's lamp "
                             f"{illuminant!r}: the camera is balanced to the lamp, give one of them")
    envmap = None
    if not sphere or "environment" in data:
        if not isinstance(env, dict) or not isinstance(env.get("path"), str):
            raise InputError("a cap needs [environment] path = the environment map it stands in")
        envmap = Path(env["path"])
        envmap = envmap if envmap.is_absolute() else base / envmap
        if not envmap.is_file():
            raise InputError(f"environment map not found: {envmap}")
    convention = env.get("convention", "mitsuba") if isinstance(env, dict) else "mitsuba"
    if convention not in CONVENTIONS:
        raise InputError(f"environment.convention must be one of {', '.join(map(repr, CONVENTIONS))}, "
                         f"got {convention!r}")
    if cam.get("type") != "perspective":
        raise InputError(f'a {"bubble" if sphere else "cap"} needs a [camera] type = "perspective" '
                         '(origin, target, up, fov_deg)')
    camera = PerspectiveCamera(width=int(_num(cam, "width", "camera", 256, 8, 16384)),
                               height=int(_num(cam, "height", "camera", 256, 8, 16384)),
                               origin=_vec(cam, "origin", "camera", 3), target=_vec(cam, "target", "camera", 3),
                               up=_vec(cam, "up", "camera", 3, (0.0, 1.0, 0.0)),
                               fov_deg=_num(cam, "fov_deg", "camera", 35.0, 1.0, 170.0))
    if sphere and math.dist(camera.origin, cap.center) <= cap.radius:
        raise InputError("the camera lies inside the bubble: it cannot see its film")
    if not sphere and _misses(cap, camera):
        raise InputError("the camera lies below the liquid or inside the bubble: it cannot see the cap")
    return CapScene(cap=cap, camera=camera, envmap=envmap, n_film=n_film, thickness=kind, thickness_range=(lo, hi),
                    rotation_deg=_num(env, "rotation_deg", "environment", 0.0, -360.0, 360.0),
                    env_scale=_num(env, "scale", "environment", 1.0, 0.0),
                    illuminant=illuminant, response=str(cam.get("response", "srgb")),
                    film_rgb=film_rgb, sphere=sphere, area=area, env_convention=convention)
