"""Compositing the bubble: eqs. (2), (3), (10), (11) (``paper``) and the ``physical`` variant.

``paper`` (eq. 11), per pixel whose ray hits the bubble:

    ``I = F_0 L'_front + t^2 F_1 L'_rear + t^4 L_b``,

with ``L'`` Ward-filtered radiance at the front film (normal ``n0``) and at the rear film
(inward normal ``-n1``), ``F = 4 t^2 cos^2(delta/2)`` the interference factor of eq. (10)
integrated over the spectrum (``F = 1`` without interference), and ``L_b`` the background
straight through. Point lights add eq. (3)'s BRDF values to ``L'`` (eq. 2).

Transmission tint (``paper``, off unless asked; :mod:`bubblefit.model.effects`): eq. (11)
transmits a grey ``t^4``, but a film that does not absorb transmits, wavelength by
wavelength, what it does not reflect. With the tint each film transmits
``T = t^2 - r_s (F - 2 t^2)``, the paper's grey value minus the deviation of its specular
reflectance ``r_s F`` from the spectral mean ``2 t^2 r_s``, and the background term is
``T_front T_rear L_b`` integrated over the spectrum. (With a ``fourier`` basis each lobe
carries the product of the lobe means, which differs from the lobe mean of the product by
``O(r_s^2)``.)

``physical`` (``docs/design.md``): per wavelength and polarisation, the film reflects ``R`` (Airy,
two-beam, or incoherent) and transmits ``T = 1 - R``; the front reflection is ``R_0``,
the background ``T_0 T_1``, and the k-th internal bounce adds ``T_0 R_1 ... R_k T_(k+1)``
times the radiance filtered at the k-th bounce. Every bounce meets the film at the same
angle. Polarisations are averaged after the products, then the spectrum is integrated.
Ward's lobe is normalised here (shape only) and ``r_d / pi E(n)`` adds a diffuse term.

A term whose effect is off is not traced at all: the Python ``if`` statements below run
at trace time on the static :class:`~bubblefit.model.effects.Effects`, and each term function
records that it was traced in :data:`TRACE_COUNTS` (tests use it to check that skipped
effects are really skipped).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..lighting.envmap import EnvMap, rotate_y
from ..lighting.filtering import irradiance, reflect, specular
from ..lighting.point_lights import PointLight, lights_radiance
from ..optics import brdf, film, spectral
from ..optics.dispersion import Cauchy, index_offset
from .effects import Effects
from .modes import COLOURED
from .geometry import (DivergentCamera, OrthographicCamera, PerspectiveCamera, internal_bounce, intersect_sphere,
                       pixel_offsets, slope_footprint)
from .thickness import thickness_at

__all__ = ["Params", "RenderConfig", "render", "render_terms", "render_pixels", "render_pixels_at", "shade_lit",
           "trace_pixels", "shade_pixels", "clamped_series", "FILM_RGB",
           "paper_terms", "film_footprints", "pixel_chunks", "chunk_size", "film_names", "shading_points",
           "TRACE_COUNTS", "PointLight"]

#: No drainage profile under a thickness map (:attr:`Params.profile`): every film of a
#: pixel takes the map's value there.
NO_PROFILE = (float("nan"),) * 3

#: The choices of :attr:`RenderConfig.film_rgb`.
FILM_RGB = ("spectral", "clamped")

#: The choices of :attr:`RenderConfig.facets`.
FACETS = ("ward", "ggx")

#: How many times each term of the model has been traced (for tests of ``effects``).
TRACE_COUNTS: collections.Counter = collections.Counter()


@jax.tree_util.register_dataclass
@dataclass(frozen=True, eq=False)
class Params:
    """Differentiable parameters of the forward model (scalars unless said otherwise).

    Attributes:
        t: transmission fraction per interface (paper; 0..1).
        r_d, r_s: Ward's diffuse and specular reflectance (eq. 1, eq. 14).
        roughness: Ward's ``a``.
        thickness: film thickness parameters in nm (see :mod:`bubblefit.model.thickness`).
        n_film: refractive index of the film (``n_g``).
        exposure: camera gain applied to the rendered radiance.
        rotation: environment rotation about +y, radians.
        disc: (3,) shift of an orthographic camera's disc ``(sx, sy, sr)`` in units of its
            radius (:meth:`~bubblefit.model.geometry.OrthographicCamera.rays`); zeros
            render the camera's own disc.
        profile: (3,) ``(top, bottom, exponent)`` of the drainage profile under a
            thickness ``map``: the rear film and internal bounces, which the photo does not
            show, take the map's value at their pixel changed by the profile between the
            heights (:func:`~bubblefit.model.thickness.thickness_at`); NaN (the default,
            :data:`NO_PROFILE`): the map's value at their pixel. Unused by the other kinds.
        view: the divergence ``u = tan(fov/2)`` of a
            :class:`~bubblefit.model.geometry.DivergentCamera`'s view (0: parallel rays);
            unused by the other cameras.
    """

    t: Array
    r_d: Array
    r_s: Array
    roughness: Array
    thickness: Array
    n_film: Array
    exposure: Array
    rotation: Array
    disc: Array
    profile: Array
    view: Array

    @staticmethod
    def make(t=0.972, r_d=None, r_s=None, f=0.3, roughness=0.01, thickness=500.0, n_film=1.4,
             exposure=1.0, rotation=0.0, disc=(0.0, 0.0, 0.0), profile=NO_PROFILE, view=0.0,
             dtype=jnp.float32) -> "Params":
        """Parameters with eq. (14): ``r_d + r_s = 1 - t`` and ``f = r_d / r_s`` unless both given.

        Examples
        --------
        >>> import bubblefit as bf
        >>> p = bf.Params.make(t=0.97, f=0.5)
        >>> round(float(p.r_d + p.r_s), 6), round(float(p.r_d / p.r_s), 6)   # 1 - t and f
        (0.03, 0.5)
        """
        if r_d is None or r_s is None:
            r_s = (1.0 - t) / (1.0 + f)
            r_d = (1.0 - t) - r_s
        cast = lambda v: jnp.asarray(v, dtype=dtype)
        return Params(cast(t), cast(r_d), cast(r_s), cast(roughness), cast(thickness), cast(n_film),
                      cast(exposure), cast(rotation), cast(disc), cast(profile), cast(view))


@dataclass(frozen=True)
class RenderConfig:
    """Everything static about a render (hashable: it is part of the compiled program)."""

    effects: Effects
    camera: OrthographicCamera | PerspectiveCamera | DivergentCamera = OrthographicCamera()
    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0
    point_lights: tuple = ()
    chunk: int = 4096
    #: The film's dispersion law (:class:`~bubblefit.optics.dispersion.Cauchy`) or None: the
    #: index per wavelength is ``Params.n_film`` (quoted at 589.3 nm) plus the law's offset.
    dispersion: Cauchy | None = None
    #: Rays per pixel, a square number: the pixel is the mean over a stratified ``s x s``
    #: grid of its box (:func:`~bubblefit.model.geometry.pixel_offsets`); 1 = its centre.
    samples_per_pixel: int = 1
    #: Integrate each film's map lookup over the pixel's footprint (ray differentials,
    #: :func:`~bubblefit.model.geometry.slope_footprint`), the area the camera's pixel (or
    #: sub-pixel ray) covers; False reads the centre ray's direction only. A fit turns it on
    #: where the map holds a compact bright source (:func:`bubblefit.inverse.compact_source`);
    #: a render does so when asked (docs/validation-split.md: its effect and cost on the
    #: sunny photos).
    pixel_footprint: bool = False
    #: How the ``physical`` model turns each film's reflectance into colour (the ``paper``
    #: model ignores it): ``"spectral"``, the series per wavelength and polarisation
    #: integrated to RGB at the end (:func:`_physical_terms`, the physics a camera sees), or
    #: ``"clamped"``, each film's reflectance integrated to RGB and clamped to [0, 1] per
    #: channel first and the series taken in RGB (:func:`clamped_series`), as Blender
    #: Cycles' thin film (Principled BSDF) shades: for fitting renders made by it.
    film_rgb: str = "spectral"
    #: Whose microfacets the ``clamped`` film is averaged over on a rough film
    #: (:func:`clamped_series`): ``"ward"``, the visible facets of eq. (1)'s lobe
    #: (:func:`~bubblefit.optics.brdf.facet_cosines`, the model), or ``"ggx"``, GGX's of width
    #: ``alpha`` = the roughness (:func:`~bubblefit.optics.brdf.ggx_facet_cosines`: the two
    #: slope laws have the same density ``1 / (pi a^2)`` at the mirror direction), as Blender
    #: Cycles draws them; a fit renders it once to bound the hue the choice moves
    #: (:func:`bubblefit.inverse.colour_check.microfacet_offsets`).
    facets: str = "ward"

    def __post_init__(self):
        if self.film_rgb not in FILM_RGB:
            raise ValueError(f"film_rgb must be 'spectral' or 'clamped', got {self.film_rgb!r}")
        if self.facets not in FACETS:
            raise ValueError(f"facets must be 'ward' or 'ggx', got {self.facets!r}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.camera.height, self.camera.width


def _count(name):
    TRACE_COUNTS[name] += 1


class _Film:
    """Per-hit film optics for one chunk: spectral (N, K, 2) or grey (N, 1, 2) arrays.

    With a ``harmonic`` basis the K samples are phases of eq. (8), the same for every film
    of a pixel (one thickness, one incidence angle), and :meth:`rgb` weighs them with the
    pixel's own weights (:func:`~bubblefit.optics.spectral.harmonic_weights` of the optical
    path at thickness ``d``).
    """

    def __init__(self, fx: Effects, p: Params, cos, lam, d=None):
        self.fx, self.p, self.cos, self.lam = fx, p, cos, lam
        # ``fourier`` basis: each sample is the spectrum filtered by a Gaussian lobe (K,).
        basis = fx.spectral
        self.sigma = None if basis is None or basis.sigma is None else jnp.asarray(basis.sigma, dtype=cos.dtype)
        self.delta = None
        if basis is not None and basis.phases is not None and fx.interference in COLOURED:
            if fx.thickness != "constant":
                raise ValueError("the harmonic spectral basis needs one film thickness (a thickness field gives "
                                 "each film its own optical path)")
            self.delta = jnp.asarray(basis.phases, dtype=cos.dtype)[None, :]
            self.weights = spectral.harmonic_weights(film.optical_path(d, p.n_film, cos), basis)  # (N, K, 3)

    def rgb(self, spec_nk):
        """Integrate (N, K) over the spectrum, or broadcast a grey (N, 1) factor to RGB."""
        if spec_nk.shape[-1] == 1:
            return jnp.broadcast_to(spec_nk, spec_nk.shape[:-1] + (3,))
        _count("spectral")
        if self.delta is not None:
            return jnp.einsum("nk,nkc->nc", spec_nk, self.weights.astype(spec_nk.dtype))
        return spectral.integrate(spec_nk, self.fx.spectral)

    def reflectance(self, d):
        """Film reflectance R for thicknesses ``d`` (N,), shape (N, K, 2)."""
        mode = self.fx.interference
        cos = self.cos[:, None]
        if self.delta is not None and mode in ("airy", "two_beam"):
            _count("interference")
            fn = film.airy_at_phase if mode == "airy" else film.two_beam_at_phase
            return fn(self.delta, self.p.n_film, cos)
        if mode == "airy":
            _count("interference")
            if self.sigma is not None:
                return film.filtered_airy_reflectance(d[:, None], self.lam, self.p.n_film, cos, self.sigma)
            return film.airy_reflectance(d[:, None], self.lam, self.p.n_film, cos)
        if mode == "two_beam":
            _count("interference")
            if self.sigma is not None:
                return film.filtered_two_beam_reflectance(d[:, None], self.lam, self.p.n_film, cos, self.sigma)
            return film.two_beam_reflectance(d[:, None], self.lam, self.p.n_film, cos)
        return film.incoherent_reflectance(cos, self.p.n_film)

    def paper_factor(self, d):
        """Eq. (10)'s factor ``4 t^2 cos^2(delta/2)``, shape (N, K); for ``incoherent``
        its spectral mean ``2 t^2`` (a thick film), shape (N, 1), without a spectral loop."""
        if self.fx.interference == "incoherent":
            return jnp.broadcast_to(2.0 * self.p.t * self.p.t, d.shape)[:, None]
        _count("interference")
        if self.delta is not None:
            return jnp.broadcast_to(film.paper_factor_at_phase(self.delta, self.p.t), (d.shape[0], self.delta.shape[1]))
        if self.sigma is not None:
            return film.filtered_paper_interference_factor(d[:, None], self.lam, self.p.n_film, self.cos[:, None],
                                                           self.p.t, self.sigma)
        return film.paper_interference_factor(d[:, None], self.lam, self.p.n_film, self.cos[:, None], self.p.t)


def _reflected(env, fx: Effects, cfg: RenderConfig, p: Params, n, wo, *, normalize, footprint=None):
    """Filtered specular radiance and diffuse radiance at a film (world-frame n, wo; the
    pixel's ``footprint`` (N, 3, 2) in slope space, or None for the centre ray)."""
    spec = 0.0
    diff = 0.0
    if fx.environment:
        nm = rotate_y(n, -p.rotation)
        wm = rotate_y(wo, -p.rotation)
        fm = None if footprint is None else jnp.stack([rotate_y(footprint[..., k], -p.rotation) for k in range(2)],
                                                      axis=-1)
        _count(f"filter_{fx.filtering.method}")
        spec = specular(env, nm, wm, p.roughness, fx.filtering, normalize=normalize, footprint=fm)
        if fx.diffuse:
            _count("diffuse")
            diff = p.r_d / jnp.pi * irradiance(env, nm)
    if fx.point_lights and cfg.point_lights:
        _count("point_lights")
        if fx.diffuse:
            _count("diffuse")
        lspec, ldiff = lights_radiance(cfg.point_lights, n, wo, p.roughness, p.r_d, diffuse=fx.diffuse)
        spec = spec + lspec
        diff = diff + ldiff
    return spec, diff


def _background(env, fx, p: Params, d, bg):
    """The background radiance behind each ray: the photo's pixels ``bg`` (N, 3), the map
    straight through, or black."""
    if fx.background == "photo":
        return bg
    if fx.background == "envmap" and fx.environment:
        _count("background_lookup")
        return env.lookup(rotate_y(d, -p.rotation))
    return jnp.zeros(d.shape, dtype=d.dtype)


def shading_points(fx: Effects, cfg: RenderConfig, hits, d):
    """The films this scene shades: ``[(name, normal, direction to the viewer)]`` and, for
    the physical model's internal bounces, the unit local position of each bounce's exit.

    ``paper``: the front film (normal ``n0``) and the rear film (inward normal ``-n1``).
    ``physical``: reflection ``k`` happens at ``q`` (``q = p1`` for ``k = 1``) on a ray
    arriving along ``e``; the reflected ray leaves the bubble, or reflects again, at the
    next hit (:func:`~bubblefit.model.geometry.internal_bounce`).
    """
    wo = -d
    films = []
    if fx.front_reflection:
        films.append(("front", hits.n0, wo))
    exits = []
    if fx.rear_reflection:
        if fx.model == "paper":
            films.append(("rear", -hits.n1, wo))
        else:
            q, e_next, nq = internal_bounce(hits.p0, d, cfg.center, cfg.radius)
            e = d
            for k in range(1, fx.bounces + 1):
                _count("bounce")
                films.append((f"bounce{k}", -nq, -e))
                q2, e2, nq2 = internal_bounce(q, e_next, cfg.center, cfg.radius)
                exits.append(nq2)
                e, q, e_next, nq = e_next, q2, e2, nq2
    return films, exits


def paper_terms(fx: Effects, p: Params, opt: "_Film", refl: dict, d0, d1, bg_rad, photo_bg: bool) -> dict:
    """Eqs. (2) and (11): the ``paper`` model's terms of the pixels of a chunk.

    Eq. (11), ``F_0 L'_front + t^2 F_1 L'_rear + t^4 L_b`` (or the tinted transmission,
    see the module docstring), with the light each film reflects ``L' = r_s S + r_d E / pi``
    (eq. 2: ``S`` the filtered specular radiance, ``E`` the irradiance, both in ``refl``)
    and ``F`` eq. (10)'s factor (1 without interference). Returns the terms ``front``,
    ``rear`` and ``background`` (N, 3) of the effects that are on, times the camera gain.

    References
    ----------
    The paper, eqs. (2), (10) and (11) (``docs/design.md``, "Reading the paper").
    """
    t2 = p.t * p.t
    terms = {}
    factors = {}

    def factor(which):  # eq. (10)'s factor of the front (0) or rear (1) film, traced once
        if which not in factors:
            factors[which] = opt.paper_factor(d0 if which == 0 else d1)
        return factors[which]

    for name, which, scale in (("front", 0, 1.0), ("rear", 1, t2)):
        if name not in refl:
            continue
        _count(f"{name}_reflection")
        s, dif = refl[name]
        lp = p.r_s * s + dif
        if fx.interference != "off":
            lp = opt.rgb(factor(which)) * lp
        terms[name] = p.exposure * scale * lp
    if fx.transmission:
        _count("transmission")
        gain = 1.0 if photo_bg else p.exposure
        if fx.tint and fx.interference in COLOURED:
            # Each film transmits the complement of its reflection about the mean.
            _count("transmission_tint")
            tr = lambda f: film.paper_tinted_transmission(f, p.t, p.r_s)
            terms["background"] = gain * opt.rgb(tr(factor(0)) * tr(factor(1))) * bg_rad
        else:
            terms["background"] = gain * t2 * t2 * bg_rad
    return terms


def _physical_terms(fx: Effects, p: Params, opt: "_Film", refl: dict, d0, d1, exits, thick, bg_rad,
                    photo_bg: bool) -> dict:
    """The physical series: front ``R_0 S_0``, background ``T_0 T_1 L_b`` and the internal
    bounces ``sum_k T_0 R_1 ... R_k T_(k+1) S_k`` (plus ``r_d E / pi`` diffuse at the front and
    the first bounce), per wavelength and polarisation, averaged over polarisations."""
    terms = {}
    mean_pol = lambda x: jnp.mean(x, axis=-1)
    # A constant film meets every bounce at the front's thickness and angle: one reflectance.
    one = fx.thickness == "constant"
    if fx.front_reflection or fx.transmission or fx.rear_reflection:
        r0 = opt.reflectance(d0)
        t0 = 1.0 - r0
    if fx.front_reflection:
        _count("front_reflection")
        s, dif = refl["front"]
        terms["front"] = p.exposure * (opt.rgb(mean_pol(r0)) * s + dif)
    if fx.transmission or (fx.rear_reflection and fx.bounces > 0):
        r1 = r0 if one else opt.reflectance(d1)
    if fx.transmission:
        _count("transmission")
        gain = 1.0 if photo_bg else p.exposure
        terms["background"] = gain * opt.rgb(mean_pol(t0 * (1.0 - r1))) * bg_rad
    if fx.rear_reflection and fx.bounces > 0:
        _count("rear_reflection")
        path = t0 * r1  # (N, K, 2): entered the front, reflected at the rear
        rear = jnp.zeros_like(bg_rad)
        for k, nq in enumerate(exits, start=1):
            r_q = r0 if one else opt.reflectance(thick(nq))
            s, dif = refl[f"bounce{k}"]
            rear = rear + opt.rgb(mean_pol(path * (1.0 - r_q))) * s
            if k == 1 and fx.diffuse:
                rear = rear + opt.rgb(mean_pol(t0 * (1.0 - r_q))) * dif
            path = path * r_q
        terms["rear"] = p.exposure * rear
    return terms


def clamped_series(fx: Effects, p: Params, opt: "_Film", refl: dict, d0, d1, exits, thick, bg_rad,
                   photo_bg: bool, facets: str = "ward") -> dict:
    """The physical series of :func:`_physical_terms` with each film's reflectance first
    averaged over polarisations, integrated to RGB and clamped to [0, 1] per channel,
    ``R = clip(rgb(R(lambda)))``, and the series taken per channel: front ``R_0 S_0`` (plus
    the diffuse ``r_d E / pi``), background ``(1 - R_0)(1 - R_1) L_b``, bounces
    ``(1 - R_0) R_1 ... R_k (1 - R_(k+1)) S_k``. A film whose colour lies outside the
    camera's gamut then reflects nothing in that channel, as Blender Cycles' thin film
    shades it: its Fresnel term is an RGB triple in [0, 1] (s and p averaged) that each
    path samples (Blender 5.0 manual, Principled BSDF, "Thin Film"; A. Belcour and
    P. Barla, ACM TOG 36(4), 2017, the thin-film Fresnel term Cycles evaluates). On a rough
    film Cycles evaluates it at each sampled facet's angle, so ``R`` is the mean of the
    clamped colours over the lobe's visible facets (:func:`~bubblefit.optics.brdf.facet_cosines`;
    microfacet theory's ``F(w_i . h)``, Walter et al. 2007, eq. 20); ``facets = "ggx"``
    averages it over GGX's visible facets instead (:attr:`RenderConfig.facets`,
    :func:`~bubblefit.optics.brdf.ggx_facet_cosines`), their nodes taken in a loop."""
    _count("clamped_film")
    # Cycles samples a facet of the rough lobe and evaluates the film at its angle, w_i . h,
    # then clamps (bsdf_microfacet.h, fresnel_iridescence): the mean of the clamped colours
    # over the visible facets of the lobe (brdf.facet_cosines; at a mirror, the film itself).
    clamped = lambda f, d: jnp.clip(f.rgb(jnp.mean(f.reflectance(d), axis=-1)), 0.0, 1.0)
    if facets == "ggx":
        cos_nodes, weights = brdf.ggx_facet_cosines(opt.cos, p.roughness)

        def rgb_r(d):
            def node(total, cw):
                return total + cw[1] * clamped(_Film(fx, p, cw[0], opt.lam, d0), d), None

            zero = jnp.zeros(opt.cos.shape + (3,), opt.cos.dtype)
            return jax.lax.scan(node, zero, (cos_nodes, weights))[0]
    else:
        cos_nodes, weights = brdf.facet_cosines(opt.cos, p.roughness)
        films = [_Film(fx, p, c, opt.lam, d0) for c in cos_nodes]
        rgb_r = lambda d: sum(w[:, None] * clamped(f, d) for f, w in zip(films, weights))
    one = fx.thickness == "constant"
    r0 = rgb_r(d0)
    r1 = r0 if one else rgb_r(d1)
    terms = {}
    if fx.front_reflection:
        s, dif = refl["front"]
        terms["front"] = p.exposure * (r0 * s + dif)
    if fx.transmission:
        terms["background"] = (1.0 if photo_bg else p.exposure) * (1.0 - r0) * (1.0 - r1) * bg_rad
    if fx.rear_reflection and fx.bounces > 0:
        path = (1.0 - r0) * r1
        rear = jnp.zeros_like(bg_rad)
        for k, nq in enumerate(exits, start=1):
            r_q = r0 if one else rgb_r(thick(nq))
            s, dif = refl[f"bounce{k}"]
            rear = rear + path * (1.0 - r_q) * s
            if k == 1 and fx.diffuse:
                rear = rear + (1.0 - r0) * (1.0 - r_q) * dif
            path = path * r_q
        terms["rear"] = p.exposure * rear
    return terms


def _film_setup(p: Params, cfg: RenderConfig):
    """``(p, lam)``: the parameters with the film index per wavelength when the film
    disperses, and the basis' wavelengths (None for a grey film or the harmonic basis)."""
    basis = cfg.effects.spectral
    dtype = p.t.dtype
    lam = jnp.asarray(basis.wavelengths, dtype=dtype) if basis is not None and basis.phases is None else None
    if cfg.dispersion is not None and basis is not None:  # n per wavelength (K,)
        if lam is None:
            raise ValueError("the harmonic spectral basis needs a non-dispersive film index")
        offset = jnp.asarray(index_offset(cfg.dispersion, basis.wavelengths), dtype=dtype)
        p = dataclasses.replace(p, n_film=p.n_film + offset)
    return p, lam


def _terms(p: Params, cfg: RenderConfig, lam, cos, d0, d1, exits, thick, refl, bg_rad) -> dict:
    """The model's terms (eq. 11, or the physical series: spectral, or clamped per channel
    as :attr:`RenderConfig.film_rgb` says) from the films' geometry and light."""
    fx = cfg.effects
    opt = _Film(fx, p, cos, lam, d0)
    photo_bg = fx.background == "photo"
    if fx.model == "paper":
        return paper_terms(fx, p, opt, refl, d0, d1, bg_rad, photo_bg)
    if cfg.film_rgb == "clamped":
        return clamped_series(fx, p, opt, refl, d0, d1, exits, thick, bg_rad, photo_bg, cfg.facets)
    return _physical_terms(fx, p, opt, refl, d0, d1, exits, thick, bg_rad, photo_bg)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class _Traced:
    """One chunk's rays and what their films read (:func:`_trace_chunk`), before any film
    optics; a pytree, so that a program can return it and another shade it
    (:func:`trace_pixels`, :func:`shade_pixels`)."""

    p: Params  # with the film index per wavelength (:func:`_film_setup`)
    lam: object
    hits: object
    d: object
    exits: list
    refl: dict
    bg_rad: object


def _camera_rays(cfg: RenderConfig, p: Params, rows, cols):
    """``(origins, directions)`` (N, 3) of the camera's rays through the pixel coordinates
    ``rows``, ``cols`` (an orthographic camera's disc moved by ``p.disc``; a divergent
    camera's view of divergence ``p.view``)."""
    if isinstance(cfg.camera, OrthographicCamera):
        o, d = cfg.camera.rays(rows, cols, cfg.center, cfg.radius, p.disc)
    else:
        o, d = cfg.camera.rays(rows, cols, cfg.center, cfg.radius, view=p.view)
    return o, jnp.broadcast_to(d, o.shape)


def film_footprints(fx: Effects, cfg: RenderConfig, rays, rows, cols, films, samples=None):
    """The pixel footprint in slope space of every film of ``films`` (as
    :func:`shading_points` returns them for the rays ``rays(rows, cols)``), (F N, 3, 2) in
    their order, or None when ``cfg.pixel_footprint`` is off: the differentials of each film's reflected direction
    across the pixel (:func:`~bubblefit.model.geometry.slope_footprint`), through the same
    rays, hits and internal bounces; each ray covers ``1 / s`` of its pixel per axis,
    ``s^2`` = ``samples`` (N,), the rays of its pixel, or ``cfg.samples_per_pixel``."""
    if not cfg.pixel_footprint or not films:
        return None

    def directions(r, c):
        o, d = rays(r, c)
        hits = intersect_sphere(o, d, cfg.center, cfg.radius)
        return jnp.concatenate([reflect(f[2], f[1]) for f in shading_points(fx, cfg, hits, d)[0]])

    spp = cfg.samples_per_pixel if samples is None else jnp.tile(jnp.asarray(samples, rows.dtype), len(films))
    return slope_footprint(directions, rows, cols, jnp.concatenate([f[1] for f in films]),
                           jnp.concatenate([f[2] for f in films]), spp)


def _trace_chunk(p: Params, cfg: RenderConfig, env: EnvMap, bg, rows, cols, samples=None) -> _Traced:
    """Trace one chunk of pixels and read the light of every film this scene shades (the
    filtered map, the point lights, the background: the photo's pixels ``bg`` (N, 3) of the
    chunk): all of a render that does not depend on the film's thickness (``samples``:
    each ray's pixel's ray count, for its footprint, :func:`film_footprints`)."""
    fx = cfg.effects
    dtype = p.t.dtype
    rows, cols = rows.astype(dtype), cols.astype(dtype)
    rays = lambda r, c: _camera_rays(cfg, p, r, c)
    o, d = rays(rows, cols)
    hits = intersect_sphere(o, d, cfg.center, cfg.radius)
    p, lam = _film_setup(p, cfg)
    bg_rad = _background(env, fx, p, d, bg)

    # Shading points of every film this scene needs, filtered in one batch.
    films, exits = shading_points(fx, cfg, hits, d)
    refl = {}
    if films:
        nn = len(films)
        s_all, d_all = _reflected(env, fx, cfg, p, jnp.concatenate([f[1] for f in films]),
                                  jnp.concatenate([f[2] for f in films]), normalize=fx.model == "physical",
                                  footprint=film_footprints(fx, cfg, rays, rows, cols, films, samples))
        split = lambda x: jnp.split(x, nn) if jnp.ndim(x) else [x] * nn
        refl = dict(zip([f[0] for f in films], zip(split(s_all), split(d_all))))
    return _Traced(p, lam, hits, d, exits, refl, bg_rad)


def _composite(tr: _Traced, cfg: RenderConfig, terms: dict):
    """The pixel (N, 3) and the terms masked to the pixels whose ray hits the bubble."""
    total = jnp.zeros(tr.d.shape, dtype=tr.p.t.dtype)
    for v in terms.values():
        total = total + v
    inside = tr.hits.inside[:, None]
    outside = tr.bg_rad if cfg.effects.background == "photo" else tr.p.exposure * tr.bg_rad
    pixel = jnp.where(inside, total, outside)
    return pixel, {k: jnp.where(inside, v, 0.0) for k, v in terms.items()}


def trace_pixels(p: Params, cfg: RenderConfig, env: EnvMap, bg, rows, cols) -> list[_Traced]:
    """The traced rays of one chunk of pixels (:func:`_trace_chunk`), one per sub-pixel
    sample: the pixel centres, or the ``samples_per_pixel`` stratified offsets
    (:func:`~bubblefit.model.geometry.pixel_offsets`) whose mean is the box-filtered pixel.

    With :func:`shade_pixels` this splits a render into what does not depend on the film's
    thickness (traced once) and the film's optics (evaluated per thickness).
    """
    if cfg.samples_per_pixel == 1:
        return [_trace_chunk(p, cfg, env, bg, rows, cols)]
    offsets = pixel_offsets(cfg.samples_per_pixel)
    dt = p.t.dtype
    return [_trace_chunk(p, cfg, env, bg, rows.astype(dt) + float(o[0]), cols.astype(dt) + float(o[1]))
            for o in np.asarray(offsets)]


def _shade_traced(tr: _Traced, cfg: RenderConfig, d0, d1, thick):
    """The pixels (N, 3) and the masked terms of one traced chunk (:func:`trace_pixels`)
    with front films of thickness ``d0`` and rear films ``d1`` (N,): eq. (11) or the
    physical series (:func:`_terms`), composited over the background (:func:`_composite`).
    ``thick(local)`` gives the thickness at other film points (the internal bounces')."""
    terms = _terms(tr.p, cfg, tr.lam, tr.hits.cos, d0, d1, tr.exits, thick, tr.refl, tr.bg_rad)
    return _composite(tr, cfg, terms)


def shade_pixels(traced: list[_Traced], cfg: RenderConfig, films):
    """The pixels (N, 3) and the masked terms of one chunk from its traced sub-pixel rays
    (:func:`trace_pixels`): the mean over the rays (the box filter) of eq. (11) or the
    physical series, composited over the background.

    ``films(tr)`` gives, for one traced ray set, ``(d0, d1, thick)``: the front films'
    thicknesses (N,), the rear films' (N,) and ``thick(local)``, the thickness at other
    film points (the internal bounces'). Only the film's optics are evaluated here; the
    rays and the light they read are those traced.
    """
    pixel, terms = None, None
    for tr in traced:
        img, t = _shade_traced(tr, cfg, *films(tr))
        pixel = img if pixel is None else pixel + img
        terms = t if terms is None else {k: terms[k] + v for k, v in t.items()}
    n = len(traced)
    return pixel / n, {k: v / n for k, v in terms.items()}


def _shade_chunk(p: Params, cfg: RenderConfig, env: EnvMap, bg, rows, cols, idx, samples=None):
    """Radiance (N, 3) of one chunk of pixels (or rays: ``samples`` as :func:`_trace_chunk`),
    and a dict of the model's terms."""
    fx = cfg.effects
    if fx.background == "photo":
        bg = bg.reshape(-1, 3)[idx]
    tr = _trace_chunk(p, cfg, env, bg, rows, cols, samples)
    hits = tr.hits
    thick = lambda local: thickness_at(fx.thickness, tr.p.thickness, local, idx, tr.p.profile, hits.local0)
    d0 = thickness_at(fx.thickness, tr.p.thickness, hits.local0, idx)
    d1 = thick(hits.local1)
    return _shade_traced(tr, cfg, d0, d1, thick)


@functools.partial(jax.jit, static_argnames=("cfg",))
def render_pixels_at(p: Params, cfg: RenderConfig, env: EnvMap | None, background, rows, cols, idx, thickness):
    """The terms of :func:`render_pixels`' pixels for each constant film thickness of
    ``thickness`` (G,): a dict of (G, N, 3), each pixel's terms masked to the bubble, as
    :func:`render_terms` gives them with ``p.thickness`` set to each value.

    The rays, the map's filtered light and the background do not depend on a constant
    film's thickness: they are traced once per pixel (and sub-pixel ray), and only the
    film's optics (:func:`_terms`) are evaluated per thickness.
    """
    if cfg.effects.thickness != "constant":
        raise ValueError("render_pixels_at evaluates constant films")
    dtype = p.t.dtype
    bg_all = None if background is None else jnp.asarray(background, dtype=dtype).reshape(-1, 3)
    thickness = jnp.asarray(thickness, dtype)

    def chunk(xs):
        r, c, i = xs
        bg = None if bg_all is None else bg_all[i]
        traced = trace_pixels(p, cfg, env, bg, r, c)  # the box filter of _map_chunks: the mean over sub-pixel rays

        def at(th):
            def films(tr):
                d = jnp.broadcast_to(th, tr.hits.cos.shape)
                return d, d, lambda _: d

            return shade_pixels(traced, cfg, films)[1]

        return jax.lax.map(at, thickness)

    terms = jax.lax.map(chunk, (jnp.asarray(rows), jnp.asarray(cols), jnp.asarray(idx)))
    return {k: jnp.swapaxes(v, 0, 1).reshape(thickness.shape[0], -1, 3) for k, v in terms.items()}


def film_names(fx: Effects) -> list[str]:
    """The films :func:`shading_points` returns for ``fx``, in its order."""
    names = ["front"] if fx.front_reflection else []
    if fx.rear_reflection:
        names += ["rear"] if fx.model == "paper" else [f"bounce{k}" for k in range(1, fx.bounces + 1)]
    return names


def shade_lit(p: Params, cfg: RenderConfig, lit: dict):
    """Radiance (N, 3) of pixels that hit the bubble, from their traced films and light
    (:func:`~bubblefit.model.regions.lit_chunks`, from a :class:`~bubblefit.model.footprint.Footprint`): the terms of
    :func:`_shade_chunk` without tracing the rays or reading the map again."""
    fx = cfg.effects
    p, lam = _film_setup(p, cfg)
    names = film_names(fx)
    # The counts of the effects this program simulates, as _shade_chunk records them.
    if fx.environment and names:
        _count(f"filter_{fx.filtering.method}")
    if fx.point_lights and cfg.point_lights and names:
        _count("point_lights")
    if fx.diffuse and names and (fx.environment or (fx.point_lights and cfg.point_lights)):
        _count("diffuse")
    if fx.background == "envmap" and fx.environment:
        _count("background_lookup")
    for name in names:
        if name.startswith("bounce"):
            _count("bounce")
    zero = jnp.zeros_like(lit["bg"])
    refl = {}
    for i, name in enumerate(names):
        diffuse = fx.diffuse and name in ("front", "rear", "bounce1")
        dif = p.r_d / jnp.pi * lit["irr"][0 if name == "front" else 1] if diffuse else zero
        refl[name] = (lit["spec"][i], dif)
    d0 = lit["d0"]
    dq = lit.get("dq")
    thick = (lambda k: dq[k]) if dq is not None else (lambda k: d0)
    exits = list(range(fx.bounces)) if fx.model == "physical" and fx.rear_reflection else []
    terms = _terms(p, cfg, lam, lit["cos"], d0, lit["d1"], exits, thick, refl, lit["bg"])
    total = zero
    for v in terms.values():
        total = total + v
    return total


#: Fewest pixels of a chunk: a region's pixel count is rounded up to a power of two from
#: here, so that regions of similar size share one compiled program.
MIN_CHUNK = 256


def chunk_size(cfg: RenderConfig, npix: int) -> int:
    """``cfg.chunk``, or the power of two (at least :data:`MIN_CHUNK`) that holds ``npix``."""
    return max(1, min(cfg.chunk, 1 << max(MIN_CHUNK.bit_length() - 1, (npix - 1).bit_length())))


def pixel_chunks(cfg: RenderConfig, pixels=None):
    """Flat pixel indices in chunks of ``cfg.chunk``: every pixel, or those of ``pixels``
    (M,), in chunks of a power of two (at least :data:`MIN_CHUNK`) when they are fewer;
    the padding repeats the last index and is dropped."""
    h, w = cfg.shape
    flat = np.arange(h * w) if pixels is None else np.asarray(pixels, dtype=np.int64).ravel()
    npix = flat.size
    chunk = chunk_size(cfg, npix)
    steps = -(-npix // chunk)
    idx = flat[np.minimum(np.arange(steps * chunk), npix - 1)]
    rows, cols = np.divmod(idx, w)
    return rows.reshape(steps, chunk), cols.reshape(steps, chunk), idx.reshape(steps, chunk), npix


def _map_chunks(p: Params, cfg: RenderConfig, env, bg, rows, cols, idx, samples=None):
    offsets = jnp.asarray(pixel_offsets(cfg.samples_per_pixel), dtype=p.t.dtype)

    def body(xs):
        r, c, i, s = xs
        if cfg.samples_per_pixel == 1:
            return _shade_chunk(p, cfg, env, bg, r, c, i, s)
        # Box filter: the mean over stratified sub-pixel rays, one pass per offset.
        shade = lambda o: _shade_chunk(p, cfg, env, bg, r.astype(o.dtype) + o[0], c.astype(o.dtype) + o[1], i)
        return jax.tree_util.tree_map(lambda v: jnp.mean(v, axis=0), jax.lax.map(shade, offsets))

    return jax.lax.map(body, (jnp.asarray(rows), jnp.asarray(cols), jnp.asarray(idx),
                              None if samples is None else jnp.asarray(samples)))


def render_terms(p: Params, cfg: RenderConfig, env: EnvMap | None, background=None):
    """Render and return ``(image, terms)``: the (H, W, 3) image and a dict of its terms
    (``front``, ``rear``, ``background``), each (H, W, 3), for the effects that are on."""
    h, w = cfg.shape
    rows, cols, idx, npix = pixel_chunks(cfg)
    bg = None if background is None else jnp.asarray(background, dtype=p.t.dtype)
    img, terms = _map_chunks(p, cfg, env, bg, rows, cols, idx)
    img = img.reshape(-1, 3)[:npix].reshape(h, w, 3)
    terms = {k: v.reshape(-1, 3)[:npix].reshape(h, w, 3) for k, v in terms.items()}
    return img, terms


@functools.partial(jax.jit, static_argnames=("cfg",))
def render(p: Params, cfg: RenderConfig, env: EnvMap | None, background=None) -> Float[Array, "H W 3"]:
    """The (H, W, 3) linear image of the bubble, jit-compiled per static ``cfg``."""
    return render_terms(p, cfg, env, background)[0]


@functools.partial(jax.jit, static_argnames=("cfg",))
def render_pixels(p: Params, cfg: RenderConfig, env: EnvMap | None, background, rows, cols, idx, samples=None):
    """Radiance (N, 3) of the pixels ``rows``, ``cols`` (flat indices ``idx``), given in
    chunks (steps, chunk) as :func:`pixel_chunks` makes them: :func:`render`'s values at
    those pixels, for a fit that compares some of an image's pixels only.

    With ``samples`` (steps, chunk), ``cfg.samples_per_pixel`` 1 and fractional ``rows``,
    ``cols``, an entry is one ray of the pixel ``idx`` among ``samples`` of its own
    (:func:`~bubblefit.model.geometry.pixel_offsets`), its footprint ``1 / sqrt(samples)``
    of the pixel per axis: a list whose pixels take different numbers of rays, whose means
    the caller takes (the box filter of :func:`render`'s sub-pixel rays)."""
    bg = None if background is None else jnp.asarray(background, dtype=p.t.dtype)
    return _map_chunks(p, cfg, env, bg, rows, cols, idx, samples)[0].reshape(-1, 3)


