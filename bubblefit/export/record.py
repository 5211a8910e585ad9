"""The fitted bubble as every exporter reads it: one narrow, typed record.

:func:`load_fit` reads the JSON that ``bubblefit fit --json`` writes and the files it
names (the photo, the thickness map of ``-o PREFIX``; the environment map, the background
photo and the scene from the JSON's ``inputs`` or from the caller) and returns a
:class:`FittedBubble`: the sphere in the camera's frame, the camera that sees it as in
the photo, the film (thickness, index), the reflection (roughness, ``r_s``, ``r_d``,
``t``), the gain and the map with its rotation. Nothing here knows a file format.

Frames follow docs/design.md: right-handed, +y up, the camera looking along -z. An
orthographic fit knows its bubble only as a disc ``(cx, cy, r)`` in pixels: the record
puts the sphere at the origin with radius 1 and the camera where the disc lands where the
photo shows it, exactly the rays of :class:`bubblefit.model.geometry.OrthographicCamera`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["ExportCamera", "Thickness", "FittedBubble", "load_fit", "sphere_mesh", "thickness_texture",
           "sphere_points"]

@dataclass(frozen=True)
class ExportCamera:
    """The camera that sees the bubble as in the photo.

    ``orthographic``: looks along -z from ``origin``; ``view_width`` world units across
    the image's width (square pixels). ``perspective``: pinhole at ``origin`` looking at
    ``target`` with ``up``, ``fov_deg`` across the image's width.
    """

    kind: str
    width: int
    height: int
    origin: tuple
    target: tuple
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: float | None = None
    view_width: float | None = None

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(origin, forward, right, up)`` unit vectors (as :class:`PerspectiveCamera.basis`)."""
        o = np.asarray(self.origin, float)
        fwd = np.asarray(self.target, float) - o
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(self.up, float))
        right /= np.linalg.norm(right)
        return o, fwd, right, np.cross(right, fwd)

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Continuous pixel ``(col, row)`` of world points ``p`` (N, 3); pixel centres at
        integers, as the rays of :mod:`bubblefit.model.geometry` (centre ``j + 1/2``)."""
        o, fwd, right, up = self.basis()
        rel = p - o
        if self.kind == "orthographic":
            x, y = rel @ right, rel @ up
            scale = self.width / self.view_width
        else:
            z = np.maximum(rel @ fwd, 1e-9)
            x, y = rel @ right / z, rel @ up / z
            scale = self.width / (2 * math.tan(math.radians(self.fov_deg) / 2))
        return self.width / 2 + x * scale - 0.5, self.height / 2 - y * scale - 0.5

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


@dataclass(frozen=True)
class Thickness:
    """The film's thickness in nm: ``constant`` (``value``), ``drainage`` (``profile`` =
    (top, bottom, exponent) of :func:`bubblefit.model.thickness.drainage_profile`) or
    ``map`` (the front film per photo pixel, NaN off the bubble, with its standard error
    and the profile under it when the fit had one)."""

    kind: str
    value: float | None = None
    profile: tuple | None = None
    map: np.ndarray | None = field(default=None, repr=False)
    map_stderr: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class FittedBubble:
    """Everything an exporter writes, in the units of docs/design.md (nm, degrees in names
    ``*_deg``, linear radiance). ``notes`` say what the record itself had to assume."""

    source: str
    model: str
    ok: bool
    center: tuple
    radius: float
    camera: ExportCamera
    thickness: Thickness
    n_film: float
    dispersive: bool
    roughness: float
    r_s: float
    r_d: float
    t: float
    exposure: float
    rotation_deg: float
    illuminant: str
    envmap: str | None
    background: str | None
    photo: str | None
    notes: tuple = ()

    def summary(self) -> dict:
        """The record as JSON (no arrays): what ``export.json`` beside every export holds."""
        th = self.thickness
        thick = {"kind": th.kind, "value_nm": th.value,
                 "profile": None if th.profile is None else dict(zip(("top_nm", "bottom_nm", "exponent"), th.profile))}
        if th.map is not None:
            thick["map_range_nm"] = [float(np.nanmin(th.map)), float(np.nanmax(th.map))]
        return {"source": self.source, "model": self.model, "ok": self.ok, "center": list(self.center),
                "radius": self.radius, "camera": self.camera.to_json(), "thickness": thick, "n_film": self.n_film,
                "roughness": self.roughness, "r_s": self.r_s, "r_d": self.r_d, "t": self.t,
                "exposure": self.exposure, "rotation_deg": self.rotation_deg, "illuminant": self.illuminant,
                "envmap": self.envmap, "background": self.background, "photo": self.photo, "notes": list(self.notes)}


def _image_size(path: str) -> tuple[int, int]:
    from ..io.images import read_image

    h, w = read_image(path).pixels.shape[:2]
    return int(w), int(h)


def load_fit(path: str | os.PathLike, *, envmap: str | None = None, background: str | None = None,
             scene: str | None = None) -> FittedBubble:
    """Read a ``bubblefit fit --json`` result and the files it names into a :class:`FittedBubble`.

    ``envmap``, ``background`` and ``scene`` stand in for (or replace) the JSON's
    ``inputs``. Raises :class:`~bubblefit.errors.InputError` in one line when the file is
    not a fit result or a file it needs is missing.
    """
    from ..io.fitresult import named_path, read_fit_result

    path = Path(path)
    data = read_fit_result(path)
    inputs = data.get("inputs") or {}
    photo = named_path(data.get("photo"), path, "photo")
    env = envmap or named_path(inputs.get("envmap"), path, "environment map")
    bg = background or named_path(inputs.get("background"), path, "background photo")
    scene_path = scene or named_path(inputs.get("scene"), path, "scene")
    for given, what in ((envmap, "environment map"), (background, "background photo"), (scene, "scene")):
        if given and not os.path.isfile(given):
            raise InputError(f"the {what} {given} does not exist")
    p = data["params"]
    notes = []
    kind = data["thickness"]
    size = None
    for candidate in (photo, named_path((data.get("outputs") or {}).get("render"), path, "render",
                                        must_exist=False)):
        if candidate and os.path.isfile(candidate):
            size = _image_size(candidate)
            break
    if size is None:
        raise InputError(f"{path}: neither its photo nor its render exists, so the image size is unknown")
    width, height = size
    if data.get("frame"):
        notes.append("the fit ran on a crop or reduction of the photo (its 'frame'): the camera frames the photo")
    # the scene (perspective camera, the sphere's centre and radius)
    sc = None
    if scene_path:
        from ..model.scene import load_scene

        sc = load_scene(scene_path)
    cam_table = sc.table("camera") if sc is not None else {}
    if cam_table.get("type", "orthographic") == "perspective":
        pc = sc.camera()
        center, radius = tuple(float(v) for v in sc.center), float(sc.radius)
        camera = ExportCamera("perspective", width, height, tuple(map(float, pc.origin)),
                              tuple(map(float, pc.target)), tuple(map(float, pc.up)), fov_deg=float(pc.fov_deg))
        if (pc.width, pc.height) != (width, height):
            raise InputError(f"the scene's camera is {pc.width}x{pc.height}, the photo {width}x{height}")
    else:
        disc = data.get("disc")
        if not disc:
            raise InputError(f"{path}: an orthographic fit without a disc cannot place the bubble")
        cx, cy, r = float(disc["cx"]), float(disc["cy"]), float(disc["r"])
        center, radius = (0.0, 0.0, 0.0), 1.0
        # OrthographicCamera: pixel (i, j) sees x = (j + 1/2 - cx)/r, y = -(i + 1/2 - cy)/r
        ox, oy = (width / 2 - cx) / r, -(height / 2 - cy) / r
        camera = ExportCamera("orthographic", width, height, (ox, oy, 4.0), (ox, oy, 0.0), view_width=width / r)
    thickness = _thickness(data, kind, path, height, width)
    colour = data.get("colour") or {}
    try:
        n_film = float(p.get("n_film", colour.get("n_film", 1.4)))
    except (TypeError, ValueError):
        n_film = 1.4
    dispersive = bool(colour.get("dispersive"))
    if dispersive:
        notes.append(f"the film's index disperses; exported as its value at 589.3 nm ({n_film:g})")
    getf = lambda k, d: float(p[k]) if p.get(k) is not None else d
    return FittedBubble(
        source=str(path), model=str(data["model"]), ok=bool(data["ok"]), center=center, radius=radius,
        camera=camera, thickness=thickness, n_film=n_film, dispersive=dispersive,
        roughness=getf("roughness", 0.0), r_s=getf("r_s", 0.0), r_d=getf("r_d", 0.0), t=getf("t", 1.0),
        exposure=getf("exposure", 1.0), rotation_deg=getf("rotation_deg", 0.0),
        illuminant=str(colour.get("illuminant", "D65")), envmap=env, background=bg, photo=photo,
        notes=tuple(notes))


def _thickness(data: dict, kind: str, source: Path, height: int, width: int) -> Thickness:
    p = data["params"]
    profile = None
    if all(p.get(k) is not None for k in ("top_nm", "bottom_nm", "exponent")):
        profile = (float(p["top_nm"]), float(p["bottom_nm"]), float(p["exponent"]))
    if kind == "constant":
        if p.get("thickness_nm") is None:
            raise InputError("the fit result has a constant film but no params.thickness_nm")
        return Thickness("constant", value=float(p["thickness_nm"]))
    if kind == "drainage":
        if profile is None:
            raise InputError("the fit result has a drainage film but not its top_nm, bottom_nm and exponent")
        return Thickness("drainage", profile=profile)
    if kind == "map":
        from ..io.fitresult import named_path
        from ..io.images import read_image

        outputs = data.get("outputs") or {}
        mpath = named_path(outputs.get("thickness"), source, "thickness map")
        if mpath is None:
            raise InputError("the fit result of a thickness map names no map (run `bubblefit fit -o PREFIX`)")
        tmap = read_image(mpath, linear=True, allow_nan=True).pixels[..., 0]
        if tmap.shape != (height, width):
            raise InputError(f"the thickness map {mpath} is {tmap.shape[1]}x{tmap.shape[0]}, "
                             f"the photo {width}x{height}")
        spath = named_path(outputs.get("thickness_stderr"), source, "thickness standard error map",
                           must_exist=False)
        serr = read_image(spath, linear=True, allow_nan=True).pixels[..., 0] if spath and os.path.isfile(spath) else None
        if not np.isfinite(tmap).any():
            raise InputError(f"the thickness map {mpath} has no finite value")
        return Thickness("map", profile=profile, map=tmap, map_stderr=serr)
    raise InputError(f"unknown thickness model {kind!r} in the fit result")


def sphere_points(nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit-sphere points at the texel centres of an ``nv x nu`` texture, and their (u, v).

    The exported sphere's texture parameterisation (every format shares it): ``v = theta /
    pi`` from the top (+y, row 0) and ``u = atan2(x, z) / (2 pi)`` wrapped to [0, 1)
    (u = 0 faces the camera of an orthographic fit, +z).
    """
    u = (np.arange(nu) + 0.5) / nu
    v = (np.arange(nv) + 0.5) / nv
    uu, vv = np.meshgrid(u, v)
    th, ph = np.pi * vv, 2 * np.pi * uu
    pts = np.stack([np.sin(th) * np.sin(ph), np.cos(th), np.sin(th) * np.cos(ph)], axis=-1)
    return pts, np.stack([uu, vv], axis=-1)


def sphere_mesh(nu: int = 128, nv: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A UV sphere of radius 1: ``(positions (N, 3), uvs (N, 2), triangles (M, 3))``.

    Vertices on a (nv + 1) x (nu + 1) grid of :func:`sphere_points`' parameterisation (the
    seam duplicated so that u runs 0 to 1); normals equal positions. Triangles wind
    counter-clockwise seen from outside.
    """
    u = np.linspace(0.0, 1.0, nu + 1)
    v = np.linspace(0.0, 1.0, nv + 1)
    uu, vv = np.meshgrid(u, v)
    th, ph = np.pi * vv, 2 * np.pi * uu
    pos = np.stack([np.sin(th) * np.sin(ph), np.cos(th), np.sin(th) * np.cos(ph)], axis=-1).reshape(-1, 3)
    uv = np.stack([uu, vv], axis=-1).reshape(-1, 2)
    idx = np.arange((nv + 1) * (nu + 1)).reshape(nv + 1, nu + 1)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    # drop the degenerate triangles at the poles
    p = pos[tris]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=-1)
    return pos.astype(np.float32), uv.astype(np.float32), tris[area > 1e-12].astype(np.uint32)


def thickness_texture(bubble: FittedBubble, nu: int = 512, nv: int = 256) -> np.ndarray:
    """The film's thickness (nm) over the sphere as an ``nv x nu`` texture (:func:`sphere_points`).

    ``drainage``: :func:`bubblefit.model.thickness.drainage_profile` of the height. ``map``:
    :func:`bubblefit.model.thickness.thickness_at`, the fit's own rule for a film point the
    photo does not show directly: each texel takes the map's value at the pixel it projects
    to, changed by the profile between that pixel's front-film height and its own; texels
    outside the photo or off the map take the profile (or the map's median without one).
    """
    import jax
    import jax.numpy as jnp

    from ..model.thickness import drainage_profile, thickness_at

    th = bubble.thickness
    local, _ = sphere_points(nu, nv)
    flat = local.reshape(-1, 3)
    if th.kind == "constant":
        return np.full((nv, nu), th.value, np.float64)
    # each call compiled as one program (eagerly each of its operations compiles on its
    # own); the profile's three numbers stay Python numbers, as in an eager call
    profile_at = jax.jit(drainage_profile, static_argnums=(1, 2, 3))
    if th.kind == "drainage":
        return np.asarray(profile_at(jnp.asarray(flat[:, 1]), *th.profile), np.float64).reshape(nv, nu)
    cam = bubble.camera
    world = np.asarray(bubble.center) + bubble.radius * flat
    col, row = cam.project(world)
    j, i = np.round(col).astype(int), np.round(row).astype(int)
    seen = (j >= 0) & (j < cam.width) & (i >= 0) & (i < cam.height)
    tmap = th.map
    valid = np.isfinite(tmap)
    pix = np.where(seen, np.clip(i, 0, cam.height - 1) * cam.width + np.clip(j, 0, cam.width - 1), 0)
    seen &= valid.reshape(-1)[pix]
    front = _front_points(bubble, pix)
    prof = np.asarray(th.profile if th.profile is not None else (np.nan,) * 3, np.float32)
    out = np.asarray(jax.jit(thickness_at, static_argnums=0)(
        "map", jnp.asarray(np.nan_to_num(tmap.reshape(-1)), jnp.float32),
                                  jnp.asarray(flat, jnp.float32), jnp.asarray(pix), jnp.asarray(prof),
                                  jnp.asarray(front, jnp.float32)), np.float64)
    if th.profile is not None:
        fill = np.asarray(profile_at(jnp.asarray(flat[:, 1]), *th.profile), np.float64)
    else:
        fill = np.full(len(flat), float(np.nanmedian(tmap)))
    return np.where(seen, out, fill).reshape(nv, nu)


def geometry_camera(cam: ExportCamera):
    """The :mod:`bubblefit.model.geometry` camera whose rays :class:`ExportCamera` describes
    (an orthographic one sees the unit sphere at the origin as the fit's disc)."""
    from ..model.geometry import OrthographicCamera, PerspectiveCamera

    if cam.kind == "orthographic":
        r = cam.width / cam.view_width
        return OrthographicCamera(cam.width, cam.height, cam.width / 2 - cam.origin[0] * r,
                                  cam.height / 2 + cam.origin[1] * r, r)
    return PerspectiveCamera(cam.width, cam.height, cam.origin, cam.target, cam.up, cam.fov_deg)


def _front_points(bubble: FittedBubble, pix: np.ndarray) -> np.ndarray:
    """Unit-sphere front-film points of the rays through the centres of pixels ``pix``
    (:func:`bubblefit.model.geometry.intersect_sphere`)."""
    import jax.numpy as jnp

    cam = bubble.camera
    i, j = np.divmod(pix, cam.width)
    return np.asarray(_front_local(geometry_camera(cam), jnp.asarray(i, jnp.float32), jnp.asarray(j, jnp.float32),
                                   tuple(bubble.center), bubble.radius), np.float64)


def _front_local(camera, rows, cols, center: tuple, radius: float):
    """The front hits' ``local0`` of the rays through pixels ``(rows, cols)``, compiled as
    one program per camera, centre and radius (which stay Python values, as in an eager
    call)."""
    import jax

    from ..model.geometry import intersect_sphere

    def local(camera, rows, cols, center, radius):
        o, d = camera.rays(rows, cols, center, radius)
        d = jax.numpy.broadcast_to(d, o.shape)
        return intersect_sphere(o, d, center, radius).local0

    return jax.jit(local, static_argnums=(0, 3, 4))(camera, rows, cols, center, radius)
