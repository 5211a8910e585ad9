"""Where the light of each pixel comes from: the per-pixel evidence behind ``auto``.

A sun in the map matters for the pixels whose reflection, or whose Ward lobe, reaches it,
not for the whole image. :func:`footprint` traces, for every pixel centre that hits the
bubble, the films the renderer shades (:func:`bubblefit.model.render.shading_points`: the
front film, the rear film, and for ``physical`` every internal bounce) and records what
each film reads from the map:

- the specular radiance it reflects with each filter ``auto`` may choose (the mirror
  lookup, the one- and two-node ``mipmap``) and with the all-on reference (four nodes),
  plus the point lights' eq. (3): the filtering choice is measured, pixel by pixel, and
  the film choices multiply the reference's own radiance;
- the irradiance at the front and rear normals (eq. 2's diffuse term), the background
  radiance straight through, and each film's thickness and incidence cosine.

:mod:`bubblefit.model.effects` multiplies the film coefficients of each candidate choice
(:class:`bubblefit.model.bounds.FilmTable`) by these radiances pixel by pixel, and compares
the difference with each pixel's budget (:func:`pixel_budget`).

References:
    ``docs/design.md``, "Effects and auto".
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.envmap import EnvMap, rotate_y
from ..lighting.filtering import FilterConfig, specular
from ..lighting.point_lights import lights_radiance
from .bounds import MAX_BOUNCES
from .effects import Effects
from .geometry import hit_pixels, intersect_sphere
from .modes import Model, ThicknessKind
from .render import (NO_PROFILE, RenderConfig, film_footprints, film_names,
                     shading_points)
from .thickness import thickness_at

__all__ = ["Footprint", "footprint", "trace_function", "jitted_trace", "pixel_budget", "filter_key", "FILTER_CANDIDATES",
           "REFERENCE_FILTER", "FLOOR_FRACTION", "BRIGHT_PERCENTILE"]

#: The all-on model's filter (:func:`bubblefit.model.effects.all_on_settings`).
REFERENCE_FILTER = FilterConfig("mipmap", nodes=4)
#: The filters ``auto`` measures per pixel, cheapest first, and the reference last.
FILTER_CANDIDATES = (FilterConfig("mirror"), FilterConfig("mipmap", nodes=1), FilterConfig("mipmap", nodes=2),
                     REFERENCE_FILTER)

#: The budget's floor, as a fraction of the image's bright level (:func:`pixel_budget`).
FLOOR_FRACTION = 0.1
#: The traced pixels are padded to a multiple of this, so that scenes share programs.
PIXEL_BUCKET = 4096
#: The percentile of the bubble's estimated radiance that stands for its bright level.
BRIGHT_PERCENTILE = 99.0


@dataclass(frozen=True, eq=False)
class Footprint:
    """Per pixel of the bubble (N pixels, F films), what each film reads; see the module docstring.

    Attributes:
        pixels: (N,) flat image index of each pixel whose ray hits the bubble.
        shape: (H, W) of the image.
        films: the F film names (``front``, ``rear`` or ``bounce1`` ... ``bounce8``).
        cos: (N,) incidence cosine (the same at every film of a pixel).
        d0, d1: (N,) thickness (nm) at the front and rear hit points.
        dq: (B, N) thickness where each internal bounce's light meets the film next
            (``physical``; (0, N) for ``paper``): bounce k's coefficient reads the film at
            ``d0``, ``d1`` and ``dq[:k]``.
        spec: for each filter of :data:`FILTER_CANDIDATES` (by :func:`filter_key`), the
            (F, N, 3) specular radiance each film reflects with it (plus the point lights).
        irr: (2, N, 3) irradiance at the front normal and at the rear film's inward normal.
        bg: (N, 3) the background radiance behind each pixel.
        roughness, rotation, thickness: the parameters it was traced with (Ward's ``a``,
            the map's rotation, the thickness field's values).
        environment, lights: whether ``spec`` and ``irr`` hold the map's light and the
            point lights' light.
        view: the divergence of a divergent camera's view it was traced through
            (:attr:`~bubblefit.model.render.Params.view`).

    The same rays, lookups (with the pixel footprints) and films as the renderer's at
    ``samples_per_pixel = 1``, so
    :func:`~bubblefit.model.regions.render_plan` shades these pixels from it without reading
    the map again.
    """

    pixels: np.ndarray
    shape: tuple[int, int]
    films: tuple[str, ...]
    cos: np.ndarray
    d0: np.ndarray
    d1: np.ndarray
    dq: np.ndarray
    spec: dict
    irr: np.ndarray
    bg: np.ndarray
    roughness: float = 0.0
    rotation: float = 0.0
    thickness: np.ndarray | None = None
    environment: bool = False
    lights: bool = False
    view: float = 0.0

    @property
    def count(self) -> int:
        return int(self.pixels.size)


def _probe(model: Model) -> Effects:
    """The effects whose films the footprint traces: both reflections and every bounce."""
    return Effects(model=model, front_reflection=True, rear_reflection=True, bounces=MAX_BOUNCES)


@functools.partial(jax.jit, static_argnames=("camera", "center", "radius", "model", "lights", "background_kind",
                                             "thickness_kind"))
def _trace(env, background, roughness, rotation, thickness_values, profile, pix, view, *, camera, center, radius, model,
           lights, background_kind, thickness_kind):
    """The films of the pixels ``pix`` (flat indices; the renderer's own geometry) and what
    they read, in one program; ``view``: a divergent camera's divergence (data)."""
    w = camera.width
    rows, cols = jnp.divmod(pix, w)
    rows, cols = rows.astype(jnp.float32), cols.astype(jnp.float32)

    def rays(r, c):
        o, d = camera.rays(r, c, center, radius, view=view)
        return o, jnp.broadcast_to(d, o.shape)

    o, d = rays(rows, cols)
    hits = intersect_sphere(o, d, center, radius)
    probe = _probe(model)
    cfg = RenderConfig(effects=probe, camera=camera, center=center, radius=radius)
    films, exits = shading_points(probe, cfg, hits, d)
    n_all = jnp.stack([f[1] for f in films])
    wo_all = jnp.stack([f[2] for f in films])
    out = {"cos": hits.cos}
    if env is not None:
        nm, wm = rotate_y(n_all, -rotation), rotate_y(wo_all, -rotation)
        flat = lambda x: x.reshape(-1, 3)
        # the renderer's pixel footprints (RenderConfig.pixel_footprint), in the map's frame
        fp = film_footprints(probe, cfg, rays, rows, cols, films)
        if fp is not None:
            fp = jnp.stack([rotate_y(fp[..., k], -rotation) for k in range(2)], axis=-1)
        for conf in FILTER_CANDIDATES:
            out[_key(conf)] = specular(env, flat(nm), flat(wm), roughness, conf, normalize=model == "physical",
                                       footprint=fp).reshape(n_all.shape)
        out["irr"] = env.lookup_irradiance(nm[:2])
        out["bg"] = env.lookup(rotate_y(d, -rotation))
    if lights:
        spec, diff = lights_radiance(lights, n_all.reshape(-1, 3), wo_all.reshape(-1, 3), roughness, 1.0, diffuse=True)
        out["light_spec"] = spec.reshape(n_all.shape)
        out["light_irr"] = jnp.pi * diff.reshape(n_all.shape)[:2]
    thick = lambda q: thickness_at(thickness_kind, thickness_values, q, pix, profile, hits.local0)
    out["d0"] = thickness_at(thickness_kind, thickness_values, hits.local0, pix)
    out["d1"] = thick(hits.local1)
    if exits and thickness_kind != "constant":
        out["dq"] = jnp.stack([thick(q) for q in exits])
    return out


def trace_function(camera, center, radius, model, lights, background_kind, thickness_kind) -> Callable:
    """``(env, roughness, rotation, values, profile, pix, view) -> dict``: :func:`_trace` with
    these static settings bound (not compiled: the caller jits it, or stores it,
    :func:`bubblefit.model.programs.stored_trace`)."""
    statics = dict(camera=camera, center=center, radius=radius, model=model, lights=lights,
                   background_kind=background_kind, thickness_kind=thickness_kind)
    return lambda env, roughness, rotation, values, profile, pix, view: _trace(env, None, roughness, rotation, values,
                                                                                profile, pix, view, **statics)


@functools.lru_cache(maxsize=16)
def jitted_trace(*statics) -> Callable:
    """:func:`trace_function` for ``statics`` through ``jax.jit`` (:func:`footprint`'s default)."""
    return jax.jit(trace_function(*statics))


def _first_pixels(v: np.ndarray, n: int) -> np.ndarray:
    """The first ``n`` pixels of a traced array: its pixel axis is the last for a value per
    pixel (N,), the one before the colour channels for (..., N, 3)."""
    return v[..., :n, :] if v.ndim >= 2 and v.shape[-1] == 3 else v[..., :n]


def footprint(*, camera, center, radius: float, model: Model, roughness: float, env: EnvMap | None,
              rotation: float, lights: tuple, background: np.ndarray | None, background_kind: str,
              thickness_kind: ThicknessKind, thickness_values, thickness_profile=NO_PROFILE,
              programs: Callable = jitted_trace, view: float = 0.0) -> Footprint:
    """The :class:`Footprint` of a scene (see the module docstring); ``thickness_profile``:
    the drainage profile under a thickness map (:attr:`~bubblefit.model.render.Params.profile`);
    ``view``: a :class:`~bubblefit.model.geometry.DivergentCamera`'s divergence
    (:attr:`~bubblefit.model.render.Params.view`), the trace's data.
    ``programs(camera, center, radius, model, lights, background_kind, thickness_kind)``
    gives the compiled trace (:func:`jitted_trace`, or the stored
    :func:`bubblefit.model.programs.stored_trace`)."""
    a = max(float(roughness), 0.0)
    trace = programs(camera, tuple(center), float(radius), model, tuple(lights), background_kind, thickness_kind)
    # Only the pixels on the bubble are traced, padded to a multiple of PIXEL_BUCKET so that
    # scenes of one size share their compiled program.
    idx = hit_pixels(camera, tuple(center), float(radius), float(view))
    npx = idx.size
    pix = np.full(max(PIXEL_BUCKET, -(-npx // PIXEL_BUCKET) * PIXEL_BUCKET), idx[-1] if npx else 0, np.int32)
    pix[:npx] = idx
    res = trace(env, np.float32(a), np.float32(rotation), np.asarray(thickness_values, dtype=np.float32),
                np.asarray(thickness_profile, dtype=np.float32), pix, np.float32(view))
    res = {k: _first_pixels(np.asarray(v, dtype=np.float64), npx) for k, v in res.items()}
    names = tuple(film_names(_probe(model)))
    nf = len(names)
    spec = {_key(c): np.zeros((nf, npx, 3)) for c in FILTER_CANDIDATES}
    irr = np.zeros((2, npx, 3))
    bg = np.zeros((npx, 3))
    if env is not None:
        spec = {k: res[k] for k in spec}
        irr = res["irr"]
        if background_kind == "envmap":
            bg = res["bg"]
    if lights:
        spec = {k: v + res["light_spec"] for k, v in spec.items()}
        irr = irr + res["light_irr"]
    if background_kind == "photo" and background is not None:
        bg = np.asarray(background, dtype=np.float64).reshape(-1, 3)[idx]
    return Footprint(pixels=idx, shape=(camera.height, camera.width), films=names, cos=res["cos"],
                     d0=res["d0"], d1=res["d1"], dq=res.get("dq", np.zeros((0, npx))), spec=spec, irr=irr, bg=bg,
                     roughness=a, rotation=float(rotation), thickness=np.asarray(thickness_values, dtype=np.float64),
                     environment=env is not None, lights=bool(lights), view=float(view))


def filter_key(conf: FilterConfig) -> str:
    """``mirror`` or ``mipmap/N``: the name of a filter in :attr:`Footprint.spec` and ``--explain``."""
    return conf.method if conf.method == "mirror" else f"{conf.method}/{conf.nodes}"


_key = filter_key


def pixel_budget(estimate: np.ndarray, tolerance: float, floor_fraction: float = FLOOR_FRACTION) -> np.ndarray:
    """Each pixel's budget (N,), in linear radiance: ``tolerance (L_p + floor_fraction L_bright)``.

    ``L_p`` is the pixel's own estimated radiance (largest channel) and ``L_bright`` the
    :data:`BRIGHT_PERCENTILE` percentile of ``L_p`` over the bubble: a skipped or
    cheapened effect may change a pixel by ``tolerance`` of what it shows, and a dark
    pixel by ``tolerance x floor_fraction`` of the image's bright level.
    """
    lum = np.max(np.asarray(estimate), axis=-1)
    bright = float(np.percentile(lum, BRIGHT_PERCENTILE)) if lum.size else 0.0
    return tolerance * (lum + floor_fraction * bright)
