"""Scene files (TOML, ``docs/design.md``, "Scene files"): parsing, validation, and rendering.

A scene is data: :class:`Scene` holds the validated tables; :meth:`Scene.params` gives
the differentiable :class:`~bubblefit.model.render.Params`, :meth:`Scene.config` resolves the
effects (:mod:`bubblefit.model.effects`) into a static :class:`~bubblefit.model.render.RenderConfig`.
Unknown keys, wrong types and out-of-range values raise :class:`InputError` with the
key's name.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..optics.dispersion import REFERENCE_WAVELENGTH_NM, Cauchy, refractive_index
from ..io.images import read_image
from ..lighting.envmap import CONVENTIONS, EnvMap, from_texel_centres
from .auto import DEFAULT_TOLERANCE, decide_pixels
from .bounds import SceneSummary, scene_bounds
from .effects import ALL_ON_NODES, check_harmonic
from .footprint import footprint
from ._scene_checks import check_radiance, check_values, colour_path, film_index, validate
from .geometry import OrthographicCamera, PerspectiveCamera
from .programs import STORED, stored_trace
from .regions import render_plan
from .render import NO_PROFILE, Params, PointLight, RenderConfig

__all__ = ["Scene", "load_scene", "render_scene", "read_envmap", "read_map_file", "MapFile", "DATA_DIR", "shipped_envmap"]

DATA_DIR = Path(__file__).resolve().parent.parent / "data"



@dataclass(frozen=True)
class MapFile:
    """An environment map as its file gave it: the map and the file's bits per channel
    (8 or 16 for integer files, 32 for float ones, half included:
    :attr:`~bubblefit.io.images.Image.bit_depth`)."""

    env: EnvMap
    bit_depth: int


def read_map_file(path, *, scale: float = 1.0, convention: str = "mitsuba") -> MapFile:
    """Read an equirectangular environment map file into a :class:`MapFile`: the
    :class:`~bubblefit.lighting.envmap.EnvMap` and the file's bit depth, from one read.
    ``convention`` says where the file's texel rows sit
    (:data:`~bubblefit.lighting.envmap.CONVENTIONS`): ``"texel-centre"`` (a map made for
    Blender or PBRT) is re-expressed on bubblefit's rows by
    :func:`~bubblefit.lighting.envmap.from_texel_centres`.

    Raises :class:`InputError` (one line) for an unreadable file, a map that is not twice
    as wide as high, or one with fewer than 2 rows.
    """

    try:
        img = read_image(path)
    except InputError as exc:
        raise InputError(f"environment map: {exc}") from None
    h, w = img.pixels.shape[:2]
    if w != 2 * h:
        raise InputError(f"environment map {path} is {w}x{h}; an equirectangular map must be twice as wide as high")
    if h < 2:
        raise InputError(f"environment map {path} is {w}x{h}; it needs at least 2 rows (4x2 texels)")
    if convention not in CONVENTIONS:
        raise InputError(f"environment map convention must be one of {', '.join(CONVENTIONS)}, got {convention!r}")
    check_radiance(path, img.pixels * scale)
    px = img.pixels * scale
    return MapFile(EnvMap.from_array(from_texel_centres(px) if convention == "texel-centre" else px),
                   int(img.bit_depth))


def read_envmap(path, *, scale: float = 1.0, convention: str = "mitsuba") -> EnvMap:
    """Read an equirectangular environment map file into an
    :class:`~bubblefit.lighting.envmap.EnvMap` (:func:`read_map_file`'s map)."""
    return read_map_file(path, scale=scale, convention=convention).env


def shipped_envmap(name: str = "courtyard") -> Path:
    """Path of an environment map shipped with the package (CC0, see data/LICENSE.md)."""
    return DATA_DIR / f"{name}.exr"


@dataclass
class Scene:
    """A validated scene (tables as dicts) and the folder relative paths are read from."""

    data: dict = field(default_factory=dict)
    base_dir: Path = Path(".")

    @staticmethod
    def from_dict(data: dict, base_dir: str | os.PathLike = ".") -> "Scene":
        scene = Scene(validate({k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}), Path(base_dir))
        check_values(scene)
        return scene

    # -- tables -----------------------------------------------------------------------------
    def table(self, name: str) -> dict:
        return self.data.get(name, {})

    def with_effects(self, **settings) -> "Scene":
        """A copy of the scene with keys of its ``[effects]`` table replaced (validated)."""
        data = dict(self.data, effects=dict(self.table("effects"), **settings))
        return Scene.from_dict(data, self.base_dir)

    # -- derived values -----------------------------------------------------------------------
    def resolve_path(self, p: str) -> Path:
        path = Path(p)
        return path if path.is_absolute() else self.base_dir / path

    def thickness_spec(self):
        """(kind, values as numpy array) of the film thickness."""
        b = self.table("bubble")
        th = b.get("thickness")
        if th is None or th.get("profile", "constant") == "constant":
            value = (th or {}).get("value_nm", b.get("thickness_nm", 500.0))
            return "constant", np.asarray(value, dtype=np.float64)
        if th["profile"] == "drainage":
            return "drainage", np.asarray([th.get("top_nm", 100.0), th.get("bottom_nm", 1000.0),
                                           th.get("exponent", 1.0)], dtype=np.float64)
    
        img = read_image(self.resolve_path(th["path"]), linear=True)
        m = img.pixels[..., 0]
        h, w = self.shape
        if m.shape != (h, w):
            raise InputError(f"thickness map {th['path']} is {m.shape[1]}x{m.shape[0]}, the camera is {w}x{h}")
        return "map", np.nan_to_num(m, nan=0.0)

    def map_profile(self) -> tuple:
        """The drainage profile ``(top, bottom, exponent)`` under a thickness map, from its
        table's ``top_nm`` and ``bottom_nm`` (and ``exponent``, default 1): the rear film
        and the internal bounces take the map's value changed by it between the heights
        (:attr:`~bubblefit.model.render.Params.profile`). None (NaN) when not given, or for
        the other kinds."""
        th = self.table("bubble").get("thickness") or {}
        if th.get("profile") != "map" or "top_nm" not in th or "bottom_nm" not in th:
            return NO_PROFILE
        return (float(th["top_nm"]), float(th["bottom_nm"]), float(th.get("exponent", 1.0)))

    @property
    def shape(self) -> tuple[int, int]:
        c = self.table("camera")
        return int(c.get("height", 256)), int(c.get("width", 256))

    def camera(self):
        c = self.table("camera")
        h, w = self.shape
        if c.get("type", "orthographic") == "perspective":
            return PerspectiveCamera(width=w, height=h, origin=tuple(c.get("origin", (0.0, 0.0, 4.0))),
                                     target=tuple(c.get("target", (0.0, 0.0, 0.0))),
                                     up=tuple(c.get("up", (0.0, 1.0, 0.0))), fov_deg=float(c.get("fov_deg", 35.0)))
        disc = c.get("disc")
        if disc is not None:
            if len(disc) != 3:
                raise InputError("camera.disc must be [cx, cy, r] in pixels")
            return OrthographicCamera(w, h, float(disc[0]), float(disc[1]), float(disc[2]))
        return OrthographicCamera(w, h)

    def params(self, dtype=None):
        """The scene's :class:`~bubblefit.model.render.Params` (thickness per its profile)."""
        b = self.table("bubble")
        dtype = dtype or jnp.float32
        _, values = self.thickness_spec()
        return Params.make(
            t=b.get("t", 0.972), r_d=b.get("r_d"), r_s=b.get("r_s", 0.0 if "r_d" in b else None), f=b.get("f", 0.3),
            roughness=b.get("roughness", 0.01), thickness=values,
            n_film=float(refractive_index(film_index(b), REFERENCE_WAVELENGTH_NM)),
            exposure=1.0, rotation=math.radians(self.table("lighting").get("rotation_deg", 0.0)),
            profile=self.map_profile(), dtype=dtype,
        )

    def colour(self) -> tuple[str, str, object]:
        """``(illuminant, response, white_balance)`` of the scene (``[lighting] illuminant``,
        ``[camera] response`` and ``white_balance``; :mod:`bubblefit.optics.spectral`), with
        CSV paths resolved against the scene's folder and checked."""
        from ..optics import spectral

        ill = self.table("lighting").get("illuminant", "D65")
        resp = self.table("camera").get("response", "srgb")
        wb = self.table("camera").get("white_balance", "illuminant")
        ill = colour_path(self, ill, spectral.is_named_illuminant(ill))
        resp = colour_path(self, resp, spectral.is_named_response(resp))
        spectral.illuminant_spectrum(ill)
        spectral.response_functions(resp)
        return ill, resp, (wb if isinstance(wb, str) else tuple(float(g) for g in wb))

    def dispersion(self) -> Cauchy | None:
        """The film's dispersion law (``[bubble] n_film`` as a Cauchy law or a preset), or
        None for a constant index (:attr:`Params.n_film <bubblefit.model.render.Params>`)."""
        law = film_index(self.table("bubble"))
        return law if isinstance(law, Cauchy) else None

    @property
    def film_rgb(self) -> str:
        """How the physical model colours each film (``[film] film_rgb``, default
        ``"spectral"``; :attr:`RenderConfig.film_rgb <bubblefit.model.render.RenderConfig>`)."""
        return self.table("film").get("film_rgb", "spectral")

    @property
    def samples_per_pixel(self) -> int:
        """Rays per pixel (``[camera] samples_per_pixel``, default 1)."""
        return int(self.table("camera").get("samples_per_pixel", 1))

    def load_envmap(self):
        """The scene's environment map as an :class:`~bubblefit.lighting.envmap.EnvMap` (or None)."""
        lighting = self.table("lighting")
        if "envmap" not in lighting:
            return None
        path = self.resolve_path(lighting["envmap"])
        if not path.exists() and (DATA_DIR / lighting["envmap"]).exists():
            path = DATA_DIR / lighting["envmap"]
        return read_envmap(path, scale=lighting.get("scale", 1.0))

    def background_kind(self) -> tuple[str, Path | None]:
        bg = self.table("lighting").get("background", "envmap")
        if bg in ("envmap", "black"):
            if bg == "envmap" and "envmap" not in self.table("lighting"):
                return "black", None
            return bg, None
        return "photo", self.resolve_path(bg)

    def point_lights(self):
        out = []
        for light in self.table("lighting").get("point_lights", []):
            d = np.asarray(light["direction"], dtype=np.float64)
            if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
                raise InputError("lighting.point_lights direction must be three numbers, not all zero")
            e = np.broadcast_to(np.asarray(light.get("radiance", [1.0, 1.0, 1.0]), dtype=np.float64), (3,))
            out.append(PointLight(tuple(d / np.linalg.norm(d)), tuple(float(x) for x in e)))
        return tuple(out)

    def _summaries(self, env, background) -> SceneSummary:
        """The scalar summaries :func:`~bubblefit.model.bounds.scene_bounds` reads."""
        e = self.table("effects")
        p = self.params()
        kind, values = self.thickness_spec()
        vals = np.atleast_1d(values)
        if kind == "drainage":
            trange = (float(min(vals[0], vals[1])), float(max(vals[0], vals[1])))
        else:
            trange = (float(vals.min()), float(vals.max()))
        lights = self.point_lights()
        env_px = None if env is None else np.asarray(env.pixels)
        camera = self.camera()
        return SceneSummary(
            model=e.get("model", "paper"), t=float(p.t), r_d=float(p.r_d), r_s=float(p.r_s),
            roughness=float(p.roughness), thickness_range=trange, n_film=float(p.n_film),
            env_texel_angle=None if env is None else env.texel_angle,
            env_peak=0.0 if env_px is None else float(env_px.max()),
            env_mean=0.0 if env_px is None else float(env_px.mean()),
            background=self.background_kind()[0],
            background_peak=(float(np.max(background)) if background is not None
                             else (0.0 if env_px is None else float(env_px.max()))),
            n_point_lights=len(lights), light_peak=max([max(l.irradiance) for l in lights], default=0.0),
            min_cos=_min_cos(camera), env_pixels=env_px,
            env_irradiance_peak=None if env is None else float(np.max(np.asarray(env.irradiance))))

    @property
    def center(self) -> tuple[float, float, float]:
        return tuple(float(x) for x in self.table("bubble").get("center", (0, 0, 0)))

    @property
    def radius(self) -> float:
        return float(self.table("bubble").get("radius", 1.0))

    def plan(self, env=None, background=None, *, chunk: int = 4096):
        """Decide the effects pixel by pixel (:func:`bubblefit.model.auto.decide_pixels`).

        Returns ``(parts, decisions)``: ``parts`` pairs a :class:`~bubblefit.model.render.RenderConfig`
        with the flat pixel indices it renders (None for every pixel), for
        :func:`~bubblefit.model.regions.render_plan`.
        """
        parts, decisions, _ = self.plan_with_footprint(env, background, chunk=chunk)
        return parts, decisions

    def plan_with_footprint(self, env=None, background=None, *, chunk: int = 4096):
        """:meth:`plan` and the :class:`~bubblefit.model.footprint.Footprint` it decided from,
        which :func:`~bubblefit.model.regions.render_plan` shades the bubble's pixels from."""
        e = self.table("effects")
        tol = float(e.get("tolerance", DEFAULT_TOLERANCE))
        nodes = int(e.get("nodes", ALL_ON_NODES))
        summ = self._summaries(env, background)
        kind, values = self.thickness_spec()
        law, spp = self.dispersion(), self.samples_per_pixel
        p = self.params()
        camera, lights = self.camera(), self.point_lights()
        bg_kind = summ.background
        try:
            b = scene_bounds(summ, nodes=nodes, per_pixel=True, field=kind != "constant")
            fp = footprint(camera=camera, center=self.center, radius=self.radius, model=summ.model,
                           roughness=summ.roughness, env=env, rotation=float(p.rotation), lights=lights,
                           background=background, background_kind=bg_kind, thickness_kind=kind,
                           thickness_values=values, thickness_profile=self.map_profile(), programs=stored_trace)
            plan, decisions = decide_pixels(b, fp, e, thickness_kind=kind, tolerance=tol, nodes=nodes,
                                            dispersive=law is not None)
        except ValueError as exc:  # a setting the checks above let through
            raise InputError(f"scene [effects]: {exc}") from None
        colour = self.colour()
        parts = []
        for fx, pixels in plan.parts:
            check_harmonic(fx.spectral, kind, law is not None)
            if fx.spectral is not None and colour != ("D65", "srgb", "illuminant"):
                fx = dataclasses.replace(fx, spectral=fx.spectral.with_colour(*colour))
            cfg = RenderConfig(effects=fx, camera=camera, center=self.center, radius=self.radius,
                               point_lights=lights, chunk=chunk,
                               dispersion=law, samples_per_pixel=spp, film_rgb=self.film_rgb)
            parts.append((cfg, pixels))
        return parts, decisions, fp

    def config(self, env=None, background=None, *, chunk: int = 4096):
        """Resolve the effects and return ``(RenderConfig, decisions)``: the configuration of
        the first region of :meth:`plan` (every pixel but the bright ones, if any)."""
        parts, decisions = self.plan(env, background, chunk=chunk)
        return parts[0][0], decisions


def _min_cos(camera) -> float:
    """Smallest film incidence cosine among pixel centres (orthographic: from the disc)."""
    if isinstance(camera, OrthographicCamera):
        cx, cy, r = camera.disc()
        jj, ii = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
        rho2 = ((jj - cx) ** 2 + (ii - cy) ** 2) / r**2
        inside = rho2 < 1
        if not inside.any():
            return 1.0
        return float(np.sqrt(1 - rho2[inside].max()))
    return 0.0


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a TOML scene file.

    Examples
    --------
    >>> import os, tempfile
    >>> import bubblefit as bf
    >>> path = os.path.join(tempfile.mkdtemp(), "bubble.toml")
    >>> with open(path, "w") as f:
    ...     _ = f.write('[bubble]\\nthickness_nm = 450\\n[lighting]\\nenvmap = "studio.exr"\\n')
    >>> scene = bf.load_scene(path)
    >>> float(scene.params().thickness)
    450.0
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"scene file not found: {path}")
    if path.is_dir():
        raise InputError(f"expected a scene file (TOML), got a folder: {path}")
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"cannot read scene file {path}: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"scene file {path} is not valid TOML: {exc}") from None
    return Scene.from_dict(data, base_dir=path.parent)


def render_scene(scene: Scene, background: np.ndarray | None = None, *, env=None, explain: bool = False,
                 dtype=None):
    """Render a scene to a linear (H, W, 3) numpy image.

    Args:
        scene: a :class:`Scene`.
        background: optional (H, W, 3) linear background photo (overrides lighting.background).
        env: an already loaded :class:`EnvMap` (else the scene's is loaded).
        explain: also return the list of effect decisions.

    Examples
    --------
    A 500 nm film in the shipped courtyard map, 32 pixels wide (compiles on a first call):

    >>> import bubblefit as bf
    >>> scene = bf.Scene.from_dict({
    ...     "camera": {"width": 32, "height": 32, "disc": [16, 16, 12]},
    ...     "bubble": {"thickness_nm": 500.0},
    ...     "lighting": {"envmap": "courtyard.exr"}})
    >>> image = bf.render_scene(scene)
    >>> image.shape, bool((image >= 0).all())
    ((32, 32, 3), True)
    """
    env = env if env is not None else scene.load_envmap()
    bg_kind, bg_path = scene.background_kind()
    if background is None and bg_kind == "photo":
        background = read_image(bg_path).pixels
    if background is not None:
        background = np.asarray(background, dtype=np.float64)
        if background.shape[:2] != scene.shape:
            raise InputError(f"background photo is {background.shape[1]}x{background.shape[0]}, "
                             f"the camera is {scene.shape[1]}x{scene.shape[0]}")
        scene = Scene(dict(scene.data, lighting=dict(scene.table("lighting"), background="photo")), scene.base_dir)
        if "background" not in scene.data["lighting"]:
            scene.data["lighting"]["background"] = "photo"
    parts, decisions, fp = scene.plan_with_footprint(env, background)
    if parts[0][0].effects.background == "photo" and background is None:
        raise InputError("lighting.background names a photo that could not be read")
    img = render_plan(scene.params(), parts, env, background, footprint=fp, programs=STORED)
    return (img, decisions) if explain else img
