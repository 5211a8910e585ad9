"""The forward render of a bubble on a dish: the sphere's film optics on a spherical cap.

A cap (:class:`~bubblefit.model.cap.Cap`) is the sphere bubble's film restricted to the
part above the liquid plane ``y = plane_y``. Its pixels are shaded by the sphere's own
code (:mod:`bubblefit.model.render`: the rays, :func:`~bubblefit.model.geometry.intersect_sphere`,
the films of :func:`~bubblefit.model.render.shading_points`, their filtered light and the
``paper`` or ``physical`` terms); this module only says where the liquid enters. The
liquid is a still, deep surface: it reflects with Fresnel's reflectance of air to the
liquid (``R_l``, unpolarised, grey: the liquid's index at 589.3 nm) and sends nothing back
from below it.

Light paths modelled, for a camera ray ``o + s d``:

1. *The cap seen directly* (the sphere's near hit ``p0`` lies above the plane): the front
   film, transmission through it, and then

   * the rear film at ``p1`` when ``p1`` lies above the plane (its reflection and the
     transmission through it, as for the sphere), and the ``physical`` model's further
     internal bounces while each stays above the plane; or
   * the liquid inside the cap's foot when ``p1`` lies below the plane: the ray reflects
     there (``R_l``), meets the cap's wall from inside, and the film there reflects
     (the rear reflection of this ray, its reflectance taken at the front film's angle of
     incidence: exact for a hemisphere, whose mirror image is its own sphere) or
     transmits it to the map. Both read the wall's film at the wall's own thickness, and
     the reflection leaves through the film where its chord ends, at that film's own.

2. *The cap mirrored in the liquid*: a ray that meets the liquid first (outside the foot)
   continues as its mirror ray from the liquid, with weight ``R_l``, and is then shaded as
   in 1 (the cap's mirror image) or reads the map (the liquid reflecting the environment).

3. *Every direction below the horizon meets the liquid*: wherever the sphere's code reads
   the environment along a direction ``w`` with ``w_y < 0`` (a film's mirror direction,
   the direction through the bubble), the light is ``R_l(|w_y|) L(w')`` with ``w'`` the
   direction mirrored about the plane. A liquid in a dish thus hides the map's lower half.

Light paths skipped (the fit's report and JSON list them, :data:`SKIPPED`): a film's
mirror direction reflected by the liquid onto the cap itself (the cap seen in its own
reflection in the liquid, ``R_film R_l``: about 1e-3 of the map); internal bounces past
the configured count, and past the first after the liquid's reflection inside the foot;
the diffuse term (a soap film has none); the meniscus at the foot; light from below the
liquid's surface.

*A whole bubble* (:meth:`CapConfig.sphere`, ``liquid = False``): the same paths with no
liquid, i.e. the sphere's front film, its rear film and internal bounces, and the map
straight through.

*Area light* (:attr:`CapConfig.area`, a rectangle or disc of given radiance whose
spectrum is the illuminant): every film adds the light it sends along the film's mirror
ray, traced from the film's own point (the light is at a finite distance, so the point
matters, not only the direction), and the rays straight through the bubble or beside it
add the light they meet. A mirror film (roughness 0, as fitted) sees the light or not
(exact); a rough film takes the share of its lobe landing on the light, a Gaussian spread
across the light's outline (:func:`~bubblefit.lighting.area.patch_coverage`, an
approximation stated there). The light sits in front of the map and does not hide it;
the bubble casts no shadow on it and it is not seen in a liquid.

``film_rgb = "clamped"`` (:class:`CapConfig`, its render configuration's
:attr:`~bubblefit.model.render.RenderConfig.film_rgb`) takes each film's reflectance to RGB
and clamps it to [0, 1] before the series (:func:`~bubblefit.model.render.clamped_series`),
as Blender Cycles' thin film shades; the default integrates the series per wavelength
(the physics).

References
----------
M. Pharr, W. Jakob and G. Humphreys, *Physically Based Rendering*, 3rd ed., sec. 3.2 and
8.2 (ray-sphere intersection, specular reflection); M. Born and E. Wolf, *Principles of
Optics*, 7th ed., sec. 1.5.2 (Fresnel's formulae); the paper, eqs. (2), (10), (11).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.area import Patch, patch_coverage
from ..lighting.filtering import reflect
from ..optics import dispersion, film
from .cap import Cap
from .geometry import internal_bounce, intersect_sphere, pixel_offsets
from .render import (Params, RenderConfig, _background, _camera_rays, _film_setup, _reflected, _terms,
                     pixel_chunks, shading_points)
from .thickness import drainage_profile

__all__ = ["CapConfig", "render_cap", "render_cap_pixels", "cap_classes", "cap_drainage", "area_light_hits", "SKIPPED",
           "SKIPPED_SPHERE", "TRACED_SPHERE"]

#: The light paths the cap's render does not trace (module docstring), for reports.
SKIPPED = (
    "the cap's wall crossed after the liquid's reflection inside the foot is taken at the front film's angle "
    "of incidence (exact for a hemisphere), its thickness at the wall's own height",
    "the cap seen in its own reflection in the liquid via a film's mirror direction (~1e-3 of the map)",
    "internal bounces past the configured count (3 in a fit), and any after the liquid's reflection inside "
    "the foot but the first (taken at the front film's angle of incidence)",
    "diffuse reflection of the film",
    "the meniscus at the foot and light from below the liquid's surface",
)

#: The light paths a whole bubble's render under an area light traces (module docstring).
TRACED_SPHERE = (
    "the front film's reflection of the area light, traced from the film's own point",
    "the rear film's reflection and the internal bounces (3 in a fit), each traced from its own point",
    "the area light and the map straight through the bubble",
    "the map in every film's mirror direction, when the scene gives one",
)

#: The light paths a whole bubble's render (no liquid, an area light) does not trace.
SKIPPED_SPHERE = (
    "internal bounces past the configured count (3 in a fit)",
    "diffuse reflection of the film",
    "the area light's lobe share on a rough film is a Gaussian estimate (exact for a mirror film, as fitted)",
    "light reflected by the room (the walls, the camera) other than the area light and the map",
)

_FLIP = jnp.asarray([1.0, -1.0, 1.0])


@dataclass(frozen=True)
class CapConfig:
    """A sphere's :class:`~bubblefit.model.render.RenderConfig` (its centre and radius are
    the cap's sphere) with the liquid plane and its index (hashable: a compiled program's
    static argument)."""

    render: RenderConfig
    plane_y: float
    n_liquid: float
    #: False: no liquid at all, a whole bubble floating free (``plane_y`` then only sets the
    #: drainage profile's foot at the sphere's bottom: the sphere's own profile).
    liquid: bool = True
    #: An area light (:class:`~bubblefit.lighting.area.Patch`) every film and the rays
    #: through the bubble see as well as the map (module docstring, "Area light"), or None.
    area: Patch | None = None

    @staticmethod
    def of(cfg: RenderConfig, cap: Cap, film_rgb: str = "spectral") -> "CapConfig":
        n = float(dispersion.refractive_index(cap.liquid, dispersion.REFERENCE_WAVELENGTH_NM))
        return CapConfig(replace(cfg, film_rgb=film_rgb), float(cap.plane_y), n)

    @staticmethod
    def sphere(cfg: RenderConfig, area: Patch | None = None, film_rgb: str = "spectral") -> "CapConfig":
        """A whole bubble (the sphere of ``cfg``, no liquid), lit by ``area`` and the map."""
        return CapConfig(replace(cfg, film_rgb=film_rgb), float(cfg.center[1]) - float(cfg.radius), 1.0,
                         liquid=False, area=area)

    @property
    def film_rgb(self) -> str:
        """The films' colour, spectral or clamped per channel (:attr:`RenderConfig.film_rgb
        <bubblefit.model.render.RenderConfig>`, :func:`~bubblefit.model.render.clamped_series`)."""
        return self.render.film_rgb


def liquid_reflectance(cos, n_liquid: float):
    """Unpolarised Fresnel reflectance of air to the liquid at incidence ``cos`` (Born & Wolf 1.5.2)."""
    return jnp.mean(film.fresnel_reflectance(jnp.clip(cos, 1e-6, 1.0), n_liquid), axis=-1)


def _fold(w, n_liquid: float, liquid: bool = True):
    """``(weight, w')``: a direction below the horizon meets the liquid and continues
    mirrored, with the liquid's reflectance as weight (module, path 3); unchanged without
    a liquid."""
    if not liquid:
        return jnp.ones(w.shape[:1], w.dtype), w
    down = w[:, 1] < 0
    weight = jnp.where(down, liquid_reflectance(jnp.abs(w[:, 1]), n_liquid), 1.0)
    return weight, jnp.where(down[:, None], w * _FLIP, w)


def cap_drainage(local_y, values, cfg: CapConfig):
    """The drainage profile along the cap's height: ``top + (bottom - top) u^exponent`` with
    ``u = (y_top - y) / H`` (0 at the top, 1 at the foot; ``H`` the cap's height), the
    sphere's :func:`~bubblefit.model.thickness.drainage_profile` at the local height whose
    ``(1 - y') / 2`` is ``u``."""
    r = cfg.render
    height = r.center[1] + r.radius - cfg.plane_y
    u = (1.0 - local_y) * r.radius / height
    return drainage_profile(1.0 - 2.0 * u, values[0], values[1], values[2])


def _bounce_above(cfg: CapConfig, hits, d) -> dict:
    """``{"bounce<k>": mask}``: where the k-th internal reflection (``physical``) and every one
    before it meet the film above the plane (below it the ray has met the liquid: the
    bounce does not happen and its light is not added, module docstring)."""
    fx = cfg.render.effects
    if fx.model != "physical" or not fx.rear_reflection:
        return {}
    out, ok = {}, jnp.ones(d.shape[:1], bool)
    if not cfg.liquid:
        return {f"bounce{k}": ok for k in range(1, fx.bounces + 1)}
    q, e = hits.p1, d - 2.0 * jnp.sum(d * hits.n1, axis=-1)[:, None] * hits.n1
    for k in range(1, fx.bounces + 1):
        ok = ok & (q[:, 1] >= cfg.plane_y)
        out[f"bounce{k}"] = ok
        q, e, _ = internal_bounce(q, e, cfg.render.center, cfg.render.radius)
    return out


def _wall_after_liquid(cfg: CapConfig, hits, d):
    """``(normal, direction to the viewer, weight, wall, exit)`` of the rear reflection of a
    ray whose rear hit lies below the plane: it meets the liquid inside the foot, reflects
    (weight ``R_l``) and meets the cap's wall from inside, where the film reflects it (module,
    path 1; the film's reflectance is taken at the front film's angle of incidence, exact for
    a hemisphere, whose mirror image is its own sphere). ``wall`` and ``exit`` (N, 3) are the
    unit local positions of the wall's film and of the film where the wall's reflection
    leaves the sphere (:func:`~bubblefit.model.geometry.internal_bounce`): the films whose
    thickness the reflection and the transmission through the wall see, not the rear hit
    below the plane, which the light never reaches (a drainage film is thinner up the wall
    than at the foot)."""
    r = cfg.render
    down = d[:, 1] < 0
    s = (cfg.plane_y - hits.p0[:, 1]) / jnp.where(down, d[:, 1], -1.0)
    q = hits.p0 + jnp.where(down, s, 0.0)[:, None] * d
    e = d * _FLIP
    wall = intersect_sphere(q, e, r.center, r.radius)
    _, _, exit_local = internal_bounce(wall.p1, e - 2.0 * jnp.sum(e * wall.n1, axis=-1)[:, None] * wall.n1,
                                       r.center, r.radius)
    return -wall.n1, -e, liquid_reflectance(jnp.abs(d[:, 1]), cfg.n_liquid), wall.local1, exit_local


def _thickness(cfg: CapConfig, values, local):
    if cfg.render.effects.thickness == "constant":
        return jnp.broadcast_to(values, local.shape[:1])
    return cap_drainage(local[:, 1], values, cfg)


def _trace(cfg: CapConfig, p: Params, rows, cols):
    """Rays after the liquid: ``(o, d, weight, hits, on, rear)``: the camera ray, or its
    mirror ray from the liquid (weight ``R_l``); ``on`` where it meets the cap above the
    plane, ``rear`` where its rear hit lies above the plane too."""
    r = cfg.render
    o, d = _camera_rays(r, p, rows, cols)
    hits = intersect_sphere(o, d, r.center, r.radius)
    s0 = jnp.sum((hits.p0 - o) * d, axis=-1)
    direct = hits.inside & (s0 > 0) & (hits.p0[:, 1] >= cfg.plane_y)
    down = d[:, 1] < 0
    s_l = (cfg.plane_y - o[:, 1]) / jnp.where(down, d[:, 1], -1.0)
    via = down & ~direct & (s_l > 0) & cfg.liquid
    p_l = o + jnp.where(via, s_l, 0.0)[:, None] * d
    o2 = jnp.where(via[:, None], p_l, o)
    d2 = jnp.where(via[:, None], d * _FLIP, d)
    weight = jnp.where(via, liquid_reflectance(jnp.abs(d[:, 1]), cfg.n_liquid), 1.0)
    hits = intersect_sphere(o2, d2, r.center, r.radius)
    s0 = jnp.sum((hits.p0 - o2) * d2, axis=-1)
    on = hits.inside & (s0 > 0) & (hits.p0[:, 1] >= cfg.plane_y)
    rear = (hits.p1[:, 1] >= cfg.plane_y) | (not cfg.liquid)
    return o2, d2, weight, hits, on, rear


def _shade(cfg: CapConfig, p: Params, env, rows, cols):
    """Radiance (N, 3) of the rays through ``rows``, ``cols`` (the module's light paths)."""
    r = cfg.render
    fx = r.effects
    dtype = p.t.dtype
    o, d, weight, hits, on, rear = _trace(cfg, p, rows.astype(dtype), cols.astype(dtype))
    p, lam = _film_setup(p, r)
    w_bg, d_bg = _fold(d, cfg.n_liquid, cfg.liquid)
    bg_rad = w_bg[:, None] * _background(env, fx, p, d_bg, None)
    if cfg.area is not None:   # the light straight along the ray (through the bubble, or beside it)
        bg_rad = bg_rad + _area_light(cfg, o, d, 0.0)
    films, exits = shading_points(fx, r, hits, d)
    above = _bounce_above(cfg, hits, d)
    foot_n, foot_wo, foot_w, foot_wall, foot_exit = _wall_after_liquid(cfg, hits, d)
    below = ~rear
    if exits:   # below the plane, the first rear reflection happens on the wall after the liquid
        exits = [jnp.where(below[:, None], foot_exit, exits[0]), *exits[1:]]
    refl = {}
    for k, (name, n, wo) in enumerate(films):
        keep, w_path = jnp.ones_like(rear), 1.0
        if name != "front":
            keep = above.get(name, rear)
        if k == int(fx.front_reflection) and fx.rear_reflection:   # the first rear reflection
            n = jnp.where(below[:, None], foot_n, n)
            wo = jnp.where(below[:, None], foot_wo, wo)
            w_path = jnp.where(below, foot_w, 1.0)
            keep = keep | below
        w_r, _ = _fold(reflect(wo, n), cfg.n_liquid, cfg.liquid)
        down = (w_r < 1.0)[:, None]
        spec, dif = _reflected(env, fx, r, p, jnp.where(down, n * _FLIP, n), jnp.where(down, wo * _FLIP, wo),
                               normalize=fx.model == "physical")
        if cfg.area is not None:   # the film point: on the sphere along its outward normal
            at = jnp.asarray(r.center, dtype) + r.radius * (n if name == "front" else -n)
            spec = spec + _area_light(cfg, at, reflect(wo, n), p.roughness)
        refl[name] = (jnp.where(keep[:, None], (w_path * w_r)[:, None] * spec, 0.0), dif)
    d0 = _thickness(cfg, p.thickness, hits.local0)
    d1 = _thickness(cfg, p.thickness, jnp.where(below[:, None], foot_wall, hits.local1))
    thick = lambda local: _thickness(cfg, p.thickness, local)
    terms = _terms(p, r, lam, hits.cos, d0, d1, exits, thick, refl, bg_rad)
    total = jnp.zeros_like(bg_rad)
    for v in terms.values():
        total = total + v
    pixel = jnp.where(on[:, None], total, p.exposure * bg_rad)
    return weight[:, None] * pixel


def _area_light(cfg: CapConfig, origins, dirs, roughness):
    """RGB radiance (N, 3) the area light sends back along rays leaving ``origins`` along
    ``dirs``: its radiance (grey in the camera's white, the lamp being the illuminant)
    times the share of the lobe that lands on it (:func:`~bubblefit.lighting.area.patch_coverage`)."""
    share = patch_coverage(cfg.area, origins, dirs, roughness)
    return (float(cfg.area.radiance) * share)[:, None] * jnp.ones((1, 3), dirs.dtype)


def area_light_hits(cfg: CapConfig, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """``(front, rear)``: whether the mirror ray of the front film and of the first rear
    reflection meets the area light, at the rays through ``rows``, ``cols`` (numpy bools;
    False off the bubble)."""
    p = Params.make()
    rows = jnp.asarray(rows, jnp.float32).ravel()
    cols = jnp.asarray(cols, jnp.float32).ravel()
    _, d, _, hits, on, _ = _trace(cfg, p, rows, cols)
    c = jnp.asarray(cfg.render.center, jnp.float32)
    front = patch_coverage(cfg.area, c + cfg.render.radius * hits.n0, reflect(-d, hits.n0)) > 0.5
    rear = patch_coverage(cfg.area, c + cfg.render.radius * hits.n1, reflect(-d, -hits.n1)) > 0.5
    on = np.asarray(on)
    return on & np.asarray(front), on & np.asarray(rear)


def _map(cfg: CapConfig, p: Params, env, rows, cols):
    offsets = jnp.asarray(pixel_offsets(cfg.render.samples_per_pixel), dtype=p.t.dtype)

    def body(xs):
        rr, cc = xs
        shade = lambda o: _shade(cfg, p, env, rr.astype(o.dtype) + o[0], cc.astype(o.dtype) + o[1])
        return jnp.mean(jax.lax.map(shade, offsets), axis=0)

    return jax.lax.map(body, (jnp.asarray(rows), jnp.asarray(cols)))


@functools.partial(jax.jit, static_argnames=("cfg",))
def render_cap(p: Params, cfg: CapConfig, env):
    """The (H, W, 3) linear image of a bubble on a dish (the module's light paths), each
    pixel the box mean over ``cfg.render.samples_per_pixel`` stratified rays."""
    h, w = cfg.render.shape
    rows, cols, _, npix = pixel_chunks(cfg.render)
    return _map(cfg, p, env, rows, cols).reshape(-1, 3)[:npix].reshape(h, w, 3)


@functools.partial(jax.jit, static_argnames=("cfg",))
def render_cap_pixels(p: Params, cfg: CapConfig, env, rows, cols):
    """Radiance (N, 3) of the pixels ``rows``, ``cols`` (chunked as
    :func:`~bubblefit.model.render.pixel_chunks` gives them), as :func:`render_cap`."""
    return _map(cfg, p, env, rows, cols).reshape(-1, 3)


def cap_classes(cfg: CapConfig, rows, cols) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(direct, mirrored, local0)`` at the rays through ``rows``, ``cols`` (continuous pixel
    coordinates): whether each meets the cap directly, or its mirror image in the liquid,
    and the unit local position of the film it meets first (numpy)."""
    p = Params.make()
    rows = jnp.asarray(rows, jnp.float32).ravel()
    cols = jnp.asarray(cols, jnp.float32).ravel()
    _, _, weight, hits, on, _ = _trace(cfg, p, rows, cols)
    on, weight = np.asarray(on), np.asarray(weight)
    return on & (weight == 1.0), on & (weight < 1.0), np.asarray(hits.local0)
