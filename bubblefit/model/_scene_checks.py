"""Checks of a scene's tables and values: the schema, types, ranges and geometry.

Every check raises :class:`~bubblefit.errors.InputError` with one line naming the key and
what is wrong with it (docs/design.md, "Scene files"). :class:`~bubblefit.model.scene.Scene`
calls :func:`validate` on the parsed TOML and :func:`check_values` on the result.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..optics.dispersion import parse_index
from ..lighting.filtering import METHODS as FILTER_METHODS
from ..optics.spectral import SPECTRAL_METHODS
from .modes import INTERFERENCE_MODES, MODELS, THICKNESS_KINDS

__all__ = ["SCHEMA", "validate", "check_values", "check_radiance", "colour_path", "film_index", "value_range", "vector",
           "samples_per_pixel", "white_balance"]

SCHEMA = {
    "camera": {"type": str, "width": int, "height": int, "origin": list, "target": list, "up": list,
               "fov_deg": float, "disc": list, "samples_per_pixel": int,
               "response": str, "white_balance": (str, list)},
    "bubble": {"center": list, "radius": float, "n_film": (float, dict, str), "t": float, "roughness": float,
               "f": float, "r_d": float, "r_s": float, "thickness_nm": float, "thickness": dict},
    "lighting": {"envmap": str, "rotation_deg": float, "scale": float, "point_lights": list,
                 "background": str, "illuminant": str},
    "effects": {"model": str, "interference": str, "filtering": (str,), "spectral": (str, dict),
                "front_reflection": (str, bool), "rear_reflection": (str, bool), "transmission": (str, bool),
                "transmission_tint": (str, bool), "diffuse": (str, bool), "bounces": (str, int),
                "tolerance": float, "nodes": int, "window": int, "level": int},
    "film": {"shape": str, "film_rgb": str},
}
THICKNESS_KEYS = {"profile": str, "top_nm": float, "bottom_nm": float, "exponent": float, "path": str,
                   "value_nm": float}


def check_type(where: str, value, kind):
    kinds = kind if isinstance(kind, tuple) else (kind,)
    for k in kinds:
        if k is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise InputError(f"scene key {where} must be a finite number, got {value!r}")
            return float(value)
        if k is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if k is not float and k is not int and isinstance(value, k):
            return value
    names = " or ".join(k.__name__ for k in kinds)
    raise InputError(f"scene key {where} must be {names}, got {value!r}")


def validate(data: dict) -> dict:
    out = {}
    for table, value in data.items():
        if table not in SCHEMA:
            raise InputError(f"unknown scene table [{table}] (known: {', '.join(SCHEMA)})")
        if not isinstance(value, dict):
            raise InputError(f"scene entry {table} must be a table")
        clean = {}
        for key, v in value.items():
            if key not in SCHEMA[table]:
                raise InputError(f"unknown scene key {table}.{key} (known: {', '.join(SCHEMA[table])})")
            clean[key] = check_type(f"{table}.{key}", v, SCHEMA[table][key])
        out[table] = clean
    th = out.get("bubble", {}).get("thickness")
    if th is not None:
        for key, v in th.items():
            if key not in THICKNESS_KEYS:
                raise InputError(f"unknown scene key bubble.thickness.{key} (known: {', '.join(THICKNESS_KEYS)})")
            th[key] = check_type(f"bubble.thickness.{key}", v, THICKNESS_KEYS[key])
    return out


def value_range(name, value, lo, hi, lo_open=False, why: str = ""):
    """An InputError unless ``lo <= value <= hi`` (``lo < value`` when ``lo_open``), written
    with the interval's true brackets and, when given, what the bound means."""
    if not (lo < value if lo_open else lo <= value) or not value <= hi:
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise InputError(f"scene value {name} = {value:g} is out of range {interval}" + (f": {why}" if why else ""))


def check_values(scene) -> None:
    """Check a scene's values (ranges, camera geometry, effects, lights): one line for the first wrong one."""
    b = scene.table("bubble")
    value_range("bubble.t", b.get("t", 0.972), 0.0, 1.0)
    value_range("bubble.roughness", b.get("roughness", 0.01), 0.0, 10.0, why="0 is a perfect mirror")
    film_index(b)
    value_range("bubble.radius", b.get("radius", 1.0), 0.0, math.inf, lo_open=True,
           why="the bubble's radius must be positive (a sphere of radius 0 is not seen)")
    value_range("bubble.thickness_nm", b.get("thickness_nm", 500.0), 0.0, 1e6)
    for k in ("r_d", "r_s", "f"):
        if k in b:
            value_range(f"bubble.{k}", b[k], 0.0, math.inf)
    physical = scene.table("effects").get("model", "paper") == "physical"
    if ("r_d" in b) != ("r_s" in b) and not (physical and "r_d" in b):
        raise InputError("scene keys bubble.r_d and bubble.r_s must be given together in the paper model "
                         "(or give f); the physical model takes r_d alone")
    th = b.get("thickness")
    if th is not None:
        prof = th.get("profile", "constant")
        if prof not in THICKNESS_KINDS:
            raise InputError(f"bubble.thickness.profile must be constant, drainage or map, got {prof!r}")
        for k in ("top_nm", "bottom_nm", "value_nm"):
            if k in th:
                value_range(f"bubble.thickness.{k}", th[k], 0.0, 1e6)
        if prof == "map" and "path" not in th:
            raise InputError("bubble.thickness.profile = \"map\" needs bubble.thickness.path")
    f = scene.table("film")
    if f.get("shape", "sphere") != "sphere":
        raise InputError(f'film.shape = {f["shape"]!r} is not a bubble in an environment map (use "sphere")')
    if f.get("film_rgb", "spectral") not in ("spectral", "clamped"):
        raise InputError(f'film.film_rgb must be "spectral" or "clamped", got {f["film_rgb"]!r}')
    c = scene.table("camera")
    ctype = c.get("type", "orthographic")
    if ctype not in ("orthographic", "perspective"):
        raise InputError(f"camera.type must be orthographic or perspective, got {ctype!r}")
    for k in ("width", "height"):
        if k in c and not 1 <= c[k] <= 16384:
            raise InputError(f"scene value camera.{k} = {c[k]} is out of range [1, 16384]")
    samples_per_pixel(c.get("samples_per_pixel", 1), "camera.samples_per_pixel")
    white_balance(c.get("white_balance", "illuminant"), "camera.white_balance")
    for k, n in (("origin", 3), ("target", 3), ("up", 3), ("disc", 3)):
        if k in c:
            vector(f"camera.{k}", c[k], n)
    if "center" in b:
        vector("bubble.center", b["center"], 3)
    _check_camera_geometry(c, b)
    e = scene.table("effects")
    if e.get("model", "paper") not in MODELS:
        raise InputError(f"effects.model must be paper or physical, got {e.get('model')!r}")
    check_effects_table(e)
    lighting = scene.table("lighting")
    if "envmap" not in lighting and not lighting.get("point_lights") and lighting.get("background") in (None, "envmap"):
        pass  # a dark room with nothing in it renders black; allowed, explained by --explain
    for i, light in enumerate(lighting.get("point_lights", [])):
        if not isinstance(light, dict) or set(light) - {"direction", "radiance"} or "direction" not in light:
            raise InputError(f"lighting.point_lights[{i}] must be a table with direction and radiance")
        vector(f"lighting.point_lights[{i}].direction", light["direction"], 3)
        if "radiance" in light:
            rad = light["radiance"]
            vector(f"lighting.point_lights[{i}].radiance", rad if isinstance(rad, list) else [rad] * 3, 3)


#: Negative texels of real HDR maps (ringing of demosaicing and resampling) carry far less
#: than this fraction of the map's energy (at most 2.5e-7 in the maps of data/envmaps).
NEGATIVE_ENERGY_TOLERANCE = 1e-4


def check_radiance(path, pixels: np.ndarray) -> None:
    """Refuse a map with truly negative radiance (a sign error, a negative scale, a broken
    file); the tiny negatives of real maps pass: each smaller than the map's median
    radiance and all together below :data:`NEGATIVE_ENERGY_TOLERANCE` of its energy."""
    negative = pixels < 0
    if not negative.any():
        return
    neg_energy = -float(pixels[negative].sum())
    pos_energy = float(pixels[~negative].sum())
    typical = float(np.median(np.abs(pixels)))
    if neg_energy > NEGATIVE_ENERGY_TOLERANCE * pos_energy or -float(pixels.min()) > typical:
        count = int(np.count_nonzero(negative.any(axis=2)))
        raise InputError(f"environment map {path} has {count} texel(s) of negative radiance (down to "
                         f"{float(pixels.min()):.3g}); radiance is never negative: fix the map or its scale")


def _check_camera_geometry(c: dict, b: dict) -> None:
    """Refuse cameras that see nothing or are not defined, before any arithmetic warns.

    A disc needs a positive radius; a perspective camera needs a field of view strictly
    between 0 and 180 degrees, a target apart from its origin, an ``up`` not parallel to
    the view direction, and to stand outside the bubble (the model composites the front
    film, the rear film and the background as seen from outside, eq. 11).
    """
    if "disc" in c and float(c["disc"][2]) <= 0:
        raise InputError(f"scene value camera.disc radius = {c['disc'][2]} must be positive")
    if c.get("type", "orthographic") != "perspective":
        return
    fov = c.get("fov_deg", 35.0)
    if isinstance(fov, bool) or not isinstance(fov, (int, float)) or not 0.0 < fov < 180.0:
        raise InputError(f"scene value camera.fov_deg = {fov} must lie strictly between 0 and 180 degrees")
    origin = np.asarray(c.get("origin", (0.0, 0.0, 4.0)), dtype=np.float64)
    target = np.asarray(c.get("target", (0.0, 0.0, 0.0)), dtype=np.float64)
    up = np.asarray(c.get("up", (0.0, 1.0, 0.0)), dtype=np.float64)
    view = target - origin
    if not np.linalg.norm(view) > 0:
        raise InputError("scene values camera.origin and camera.target are the same point: the camera looks nowhere")
    if not np.linalg.norm(up) > 0 or np.linalg.norm(np.cross(view, up)) <= 1e-9 * np.linalg.norm(view) * np.linalg.norm(up):
        raise InputError("scene value camera.up is parallel to the view direction (target - origin): "
                         "choose an up that is not")
    center = np.asarray(b.get("center", (0.0, 0.0, 0.0)), dtype=np.float64)
    radius = float(b.get("radius", 1.0))
    if np.linalg.norm(origin - center) <= radius:
        raise InputError("the camera (camera.origin) is inside the bubble: place it farther from bubble.center "
                         "than bubble.radius")


def colour_path(scene: "Scene", value: str, named: bool) -> str:
    """A named illuminant/response as is; a CSV path resolved against the scene's folder."""
    return value if named else str(scene.resolve_path(value))


def film_index(bubble: dict):
    """The ``[bubble] n_film`` of a scene: a number, ``{cauchy = [A, B(, C)]}`` or a preset
    (:mod:`bubblefit.optics.dispersion`); 1.4 when absent."""
    return parse_index(bubble.get("n_film", 1.4), "bubble.n_film")


def samples_per_pixel(value, where: str) -> int:
    """Rays per pixel (scene ``camera.samples_per_pixel``, ``fit --samples-per-pixel``): a
    square number in [1, 1024], the side of the stratified grid of
    :func:`~bubblefit.model.geometry.pixel_offsets` squared."""
    ok = isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 1024
    if not (ok and math.isqrt(value) ** 2 == value):
        raise InputError(f"{where} must be a square number in [1, 1024] (1, 4, 9, 16, ...), got {value!r}")
    return int(value)


def white_balance(value, where: str):
    """``"illuminant"`` or three positive gains ``(r, g, b)`` (:mod:`bubblefit.optics.spectral`)."""
    if isinstance(value, str):
        if value != "illuminant":
            raise InputError(f"{where} must be \"illuminant\" or [r, g, b] gains, got {value!r}")
        return value
    ok = (isinstance(value, (list, tuple)) and len(value) == 3
          and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value))
    if not ok:
        raise InputError(f"{where} must be \"illuminant\" or three finite gains [r, g, b], got {value!r}")
    gains = tuple(float(x) for x in value)
    if min(gains) <= 0:
        raise InputError(f"{where} gains must be positive, got {value!r}")
    return gains


def vector(name: str, value, n: int) -> list[float]:
    """A list of ``n`` finite numbers, or an :class:`InputError` naming the key."""
    ok = (isinstance(value, list) and len(value) == n
          and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value))
    if not ok:
        raise InputError(f"scene key {name} must be a list of {n} finite numbers, got {value!r}")
    return [float(x) for x in value]


def check_effects_table(e: dict) -> None:
    """Values of a scene's ``[effects]`` table (``docs/design.md``, "Scene files"), checked
    before anything is computed; raises :class:`~bubblefit.errors.InputError` naming the key."""

    def one_of(key, allowed):
        if key in e and e[key] not in allowed:
            raise InputError(f"effects.{key} must be one of {', '.join(map(str, allowed))}, got {e[key]!r}")

    one_of("interference", ("auto",) + INTERFERENCE_MODES)
    one_of("filtering", ("auto",) + FILTER_METHODS)
    for key in ("front_reflection", "rear_reflection", "transmission", "transmission_tint", "diffuse"):
        if key in e and not isinstance(e[key], bool) and e[key] != "auto":
            raise InputError(f"effects.{key} must be true, false or \"auto\", got {e[key]!r}")
    if "bounces" in e and e["bounces"] != "auto" and not (isinstance(e["bounces"], int) and 0 <= e["bounces"] <= 64):
        raise InputError(f"effects.bounces must be \"auto\" or an integer in [0, 64], got {e['bounces']!r}")
    for key, lo, hi in (("nodes", 1, 32), ("window", 0, 4096), ("level", 0, 32)):
        if key in e and not lo <= e[key] <= hi:
            raise InputError(f"scene value effects.{key} = {e[key]} is out of range [{lo}, {hi}]")
    if "tolerance" in e and not e["tolerance"] > 0:
        raise InputError(f"scene value effects.tolerance = {e['tolerance']} must be positive")
    spec = e.get("spectral", "auto")
    if isinstance(spec, str):
        if spec != "auto" and spec not in SPECTRAL_METHODS:
            raise InputError(f"effects.spectral must be \"auto\", one of {', '.join(SPECTRAL_METHODS)} "
                             f"or a table {{method, samples}}, got {spec!r}")
    else:
        unknown = set(spec) - {"method", "samples"}
        method, samples = spec.get("method", "uniform"), spec.get("samples", 30)
        if unknown or method not in SPECTRAL_METHODS or isinstance(samples, bool) \
                or not isinstance(samples, int) or not 1 <= samples <= 4000:
            raise InputError("effects.spectral table must be {method = uniform|reference|fourier, "
                             f"samples = 1..4000}}, got {spec!r}")
