"""Bounds of how much each effect can change a scene's image (the evidence behind ``auto``).

:mod:`bubblefit.model.effects` decides each effect by comparing a bound with the tolerance.
This module computes the bounds: once per scene, :func:`scene_bounds` gathers what every
decision reads into one frozen :class:`SceneBounds` record (radiance bounds of each term,
the film's thickness and incidence grids, the map and the range of directions the image
reads); :class:`FilmTable` evaluates the film's coefficients on those grids for each
interference mode and spectral basis, with the renderer's own film functions.

The bounds (see ``docs/design.md``, "Effects"):

- film terms (interference, spectral sampling, internal bounces): the film's coefficient
  of each term (eq. 10's factor ``4 t^2 cos^2(delta/2)`` for ``paper``; the Airy
  ``R``, ``T T`` and ``T R^k T`` for ``physical``) is evaluated with
  :mod:`bubblefit.optics.film` and :mod:`bubblefit.optics.spectral` on a grid of thickness
  over the scene's range and incidence cosine over the image's range, for the cheaper
  choice and for the converged one; the largest RGB difference times the largest
  radiance the term multiplies is the bound (:func:`coefficient_difference`).
- roughness filtering (:func:`filter_bound`): the mirror lookup and the filtered lookup
  differ by (i) the lobe's albedo against the mirror's (eq. 1's ``cos th_r`` limit) times
  the map's peak and (ii) how much the bilinear map can change over the lobe's angular
  radius (:func:`lookup_variation`).
- front/rear reflection, background transmission, diffuse: the term's largest film
  coefficient times the largest radiance it can carry (map peak, point-light peak of
  eq. 3, irradiance-table peak over pi, background peak).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ..io.executables import stored
from ..lighting.filtering import mip_footprint_level
from ..optics.brdf import slope_nodes
from ..optics import film
from ..optics.spectral import LAMBDA_MIN, SpectralBasis, harmonic_weights
from .modes import GREY, Interference, Model

__all__ = ["SceneSummary", "SceneBounds", "FilmTable", "scene_bounds", "film_grids", "film_spectra", "harmonic_spectra",
           "film_coefficients", "coefficient_difference", "lookup_variation", "mipmap_albedo", "filter_bound",
           "MAX_BOUNCES"]

#: Most internal bounces (``physical``): the all-on model's count and the cap of ``auto``.
MAX_BOUNCES = 8


# ----------------------------------------------------------------------------------------
# Bounds of the film terms
# ----------------------------------------------------------------------------------------

def film_grids(thickness_range, min_cos, n_film, max_points: int = 800, reach: float = 1.0,
               per_pixel: bool = False):
    """Thickness (D, C) and incidence-cosine (C,) grids covering the scene.

    Interference depends on the optical path ``x = 2 n d cos t`` (eq. 8) and, weakly, on
    the Fresnel factors of ``cos``. Every pixel's ``x`` lies in
    ``[2 n d_min cos t_min, 2 n d_max]``; the grid pairs each of a few cosines with that
    whole range of ``x`` (a superset of the image's pairs), in steps of lambda_min / 24 (the
    two-beam colour is sampled 24 times per shortest period), at most ``max_points``. The
    cosines are spaced evenly and, with ``per_pixel`` (the grids of ``auto``'s cells), also
    geometrically towards the rim: there the face reflectance ``R1`` climbs to 1 and the
    film's harmonics (``R1^m``) with it, so a cell spanning 0.01-0.2 would charge every
    pixel in it with the rim's worst case.

    ``reach`` > 1 extends ``x`` to ``reach x_max``: a field's internal bounces multiply
    films of different thickness, whose products oscillate with the sums of their paths.

    One thickness (``d_min = d_max``, ``per_pixel``): every pixel's ``(x, cos)`` lies on the curve
    ``x = 2 n d cos t(cos)``, so the grid is that curve, one row (1, C), with cosines
    placed so that ``x`` moves by at most the same step between neighbours.
    """
    dmin, dmax = thickness_range
    c_lo = max(min(min_cos, 1.0), 1e-3)
    cos = np.unique(np.concatenate([np.linspace(c_lo, 1.0, 6), np.geomspace(c_lo, 1.0, 8) if per_pixel else [],
                                    [1.0]]))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - cos**2) / n_film**2))
    x_lo, x_hi = 2 * n_film * dmin * float(cos_t.min()), 2 * n_film * dmax
    step = LAMBDA_MIN / 24.0
    if dmax <= dmin and per_pixel:
        npts = int(min(max_points, max(2, math.ceil((x_hi - x_lo) / step) + 1)))
        ct = np.linspace(x_lo, x_hi, npts) / max(2 * n_film * dmin, 1e-9)
        cos_x = np.sqrt(np.clip(1.0 - n_film**2 * (1.0 - np.clip(ct, 0.0, 1.0) ** 2), 0.0, 1.0))
        cos = np.unique(np.clip(np.concatenate([cos, cos_x]), c_lo, 1.0))
        return np.full((1, cos.size), float(dmin)), cos
    x_hi = x_hi * reach
    npts = int(min(max_points, max(2, math.ceil((x_hi - x_lo) / step) + 1)))
    x = np.linspace(x_lo, x_hi, npts) if x_hi > x_lo else np.array([x_lo])
    d = x[:, None] / (2 * n_film * np.maximum(cos_t[None, :], 1e-6))
    return d, cos


def film_spectra(model, mode, lam, d, cos, t, n_film, sigma=None) -> np.ndarray:
    """Per-wavelength film values on the grid: eq. (10)'s factor (D, C, K) for ``paper``,
    the reflectance R (D, C, K, 2) of :func:`film.airy_reflectance` or
    :func:`film.two_beam_reflectance` for ``physical``. One evaluation for all ``lam`` (K,).
    With ``sigma`` (K,) (a ``fourier`` basis) the lobe-filtered functions of
    :mod:`bubblefit.optics.film` instead. Compiled once per grid shape."""
    return np.asarray(_program(_film_spectra, model, mode)(_f32(lam), _f32(d), _f32(cos), _f32(t), _f32(n_film),
                                                           None if sigma is None else _f32(sigma)))


def harmonic_spectra(model, mode, bases: list[SpectralBasis], d, cos, t, n_film) -> list[tuple]:
    """``harmonic`` bases on the grid, each as (values, weights): the film values at its
    phases, broadcast to (D, C, K[, 2]) (the phase samples are the same at every
    thickness), and each grid point's weights (D, C, K, 3)
    (:func:`bubblefit.optics.spectral.harmonic_weights`). One film evaluation for all."""
    phases = np.concatenate([bb.phases for bb in bases])
    vals = np.asarray(_program(_phase_spectra, model, mode)(_f32(phases), _f32(cos), _f32(t), _f32(n_film)))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - np.asarray(cos, np.float64) ** 2) / n_film**2))
    opd = 2.0 * np.asarray(d, np.float64) * n_film * cos_t[None, :]  # eq. (8)'s x
    offs = np.cumsum([0] + [bb.samples for bb in bases])
    out = []
    for i, bb in enumerate(bases):
        v = vals[:, offs[i]: offs[i + 1]]
        out.append((np.broadcast_to(v[None], (np.shape(d)[0],) + v.shape), harmonic_weights(opd, bb)))
    return out


def _f32(x) -> np.ndarray:
    """``x`` as float32 on the host (a conversion on the device would be one more program)."""
    return np.asarray(x, dtype=np.float32)


@functools.lru_cache(maxsize=None)
def _program(fn, *static):
    """``fn`` with its leading static arguments bound, jitted, through the executable store
    (:func:`bubblefit.io.executables.stored`): a new process loads it rather than tracing it."""
    return stored(jax.jit(functools.partial(fn, *static)), f"model.bounds.{fn.__name__}", static)


def _phase_spectra(model, mode, delta, cos, t, n_film):
    dl = delta[None, :]
    cc = cos[:, None]
    if model == "paper":
        return jnp.broadcast_to(film.paper_factor_at_phase(dl, t), (cos.shape[0], delta.shape[0]))
    fn = film.two_beam_at_phase if mode == "two_beam" else film.airy_at_phase
    return fn(dl, n_film, cc)


def _film_spectra(model, mode, lam, d, cos, t, n_film, sigma=None):
    dd = d[..., None]
    cc = cos[None, :, None]
    ll = lam[None, None, :]
    if sigma is not None:
        sg = sigma[None, None, :]
        if model == "paper":
            return film.filtered_paper_interference_factor(dd, ll, n_film, cc, t, sg)
        fn = film.filtered_two_beam_reflectance if mode == "two_beam" else film.filtered_airy_reflectance
        return fn(dd, ll, n_film, cc, sg)
    if model == "paper":
        return film.paper_interference_factor(dd, ll, n_film, cc, t)
    fn = film.two_beam_reflectance if mode == "two_beam" else film.airy_reflectance
    return fn(dd, ll, n_film, cc)


def film_coefficients(model, mode, weights, spectra, cos, t, n_film, bounces, tint_rs=None):
    """RGB coefficients of the model's terms on a (thickness, cosine) grid.

    Args:
        model: ``paper`` | ``physical``; mode: ``off`` | ``incoherent`` | ``two_beam`` | ``airy``.
        weights: (K, 3) spectral weights (:class:`SpectralBasis`), or (D, C, K, 3) per grid
            point (a ``harmonic`` basis), ignored for grey modes.
        spectra: :func:`film_spectra` at the basis's wavelengths (D, C, K[, 2]), or for the
            grey modes any array whose first axis is D.
        cos: (C,) incidence cosines; bounces: internal bounces to return (physical).
        tint_rs: ``r_s`` when the paper model's transmission tint is on, else None.

    Returns:
        dict with ``front`` (D, C, 3), ``background`` (D, C, 3) and ``rear`` a list of
        (D, C, 3), one per bounce (paper: one, eq. 11's ``t^2 F``).
    """
    grey = mode in GREY
    shape = (np.shape(spectra)[0], len(cos), 1)
    if grey:
        rgb = lambda s: np.broadcast_to(s, s.shape[:-1] + (3,))
    elif np.ndim(weights) == 4:  # per grid point (harmonic): a batched (1, K) @ (K, 3)
        rgb = lambda s: (s[..., None, :] @ weights)[..., 0, :]
    else:
        rgb = lambda s: s @ np.asarray(weights, dtype=s.dtype)
    if model == "paper":
        if mode == "off":
            f = np.ones(shape)
        elif mode == "incoherent":
            f = np.full(shape, 2.0 * t * t)
        else:
            f = spectra
        bg = np.full(f.shape[:-1] + (3,), t**4)
        if tint_rs is not None and not grey:
            bg = rgb(np.asarray(film.paper_tinted_transmission(f, t, tint_rs)) ** 2)
        f = rgb(f)
        return {"front": f, "rear": [t * t * f], "background": bg}
    if grey:
        r1 = np.asarray(_program(_incoherent)(_f32(cos), _f32(n_film)), dtype=np.float64)
        r = np.broadcast_to(r1[None, :, None, :], shape + (2,))
        pol = lambda x: np.broadcast_to(np.mean(x, axis=-1), x.shape[:-2] + (3,))
    else:
        r = np.ascontiguousarray(spectra)
        if np.ndim(weights) == 4:
            pol = lambda x: rgb(np.mean(x, axis=-1))
        else:  # the polarisation mean folded into the weights: one (D C, 2 K) @ (2 K, 3) product
            w_pol = np.repeat(0.5 * np.asarray(weights, dtype=r.dtype), 2, axis=0)
            pol = lambda x: (x.reshape(x.shape[:-2] + (-1,)) @ w_pol)
    tr = 1.0 - r
    out = {"front": pol(r), "background": pol(tr * tr), "rear": []}
    path = tr * r
    for _ in range(bounces):
        out["rear"].append(pol(path * tr))
        path *= r
    return out


def _incoherent(cos, n_film):
    return film.incoherent_reflectance(cos, n_film)


def coefficient_difference(a, b, w_front, w_rear, w_bg, bounces=None):
    """Largest radiance difference of two coefficient sets, each term times its radiance bound."""
    nb = len(a["rear"]) if bounces is None else bounces
    diff = w_front * np.max(np.abs(a["front"] - b["front"]))
    diff += w_bg * np.max(np.abs(a["background"] - b["background"]))
    rear = 0.0
    for k in range(max(len(a["rear"]), len(b["rear"]))):
        ra = a["rear"][k] if k < len(a["rear"]) and k < nb else 0.0
        rb = b["rear"][k] if k < len(b["rear"]) else 0.0
        rear = rear + np.abs(ra - rb)
    return float(diff + w_rear * np.max(rear))


# ----------------------------------------------------------------------------------------
# Bound of the roughness filter (mirror lookup against the filtered lookup)
# ----------------------------------------------------------------------------------------

def lookup_variation(pixels: np.ndarray, radius: float, theta_range=(0.0, math.pi)) -> float:
    """Largest change of the bilinear lookup of an equirectangular map over ``radius`` rad.

    Only directions whose polar angle lies in ``theta_range`` (widened by ``radius``)
    count. Per band of texel rows the change is bounded by the largest neighbouring-texel
    difference along the rows times the number of columns ``radius`` spans there
    (``radius / (sin(theta) 2 pi / W)`` at the band's smallest ``sin(theta)``), capped by
    the band's full range (at a pole, where the columns meet), plus the largest difference
    between rows times ``radius / (pi / (H - 1))``.
    """
    px = np.asarray(pixels, dtype=np.float64)
    h, w = px.shape[:2]
    dth = math.pi / (h - 1)
    dph = 2 * math.pi / w
    gc = np.max(np.abs(np.roll(px, -1, axis=1) - px), axis=(1, 2))  # (H,)
    gr = np.max(np.abs(px[1:] - px[:-1]), axis=(1, 2))  # (H-1,)
    lo, hi = max(theta_range[0] - radius, 0.0), min(theta_range[1] + radius, math.pi)
    best = 0.0
    for i in range(h - 1):
        # Directions in the cell between rows i and i+1, moved by up to one more row.
        c_lo, c_hi = max((i - 1) * dth, lo), min((i + 2) * dth, hi)
        if c_lo > c_hi:
            continue
        band = slice(max(i - 1, 0), min(i + 3, h))
        s_min = min(math.sin(c_lo), math.sin(c_hi))
        rng = float(np.max(px[band]) - np.min(px[band]))
        cols = radius / (s_min * dph) if s_min > 1e-12 else math.inf
        col_term = min(rng, float(np.max(gc[band])) * cols)
        row_term = float(np.max(gr[max(i - 1, 0): min(i + 2, h - 1)])) * radius / dth
        best = max(best, min(rng, col_term + row_term))
    return best


def mipmap_albedo(roughness: float, cos: np.ndarray, nodes: int) -> np.ndarray:
    """Albedo (C,) of the unnormalised ``mipmap`` lobe (white map) at incidence cosines (C,).

    The sum of :func:`bubblefit.lighting.filtering.specular_mipmap`'s node weights
    ``W_j W_k g(s)`` (:func:`bubblefit.optics.brdf.half_vector_weight`), in numpy, for the
    normal +z (whose tangent frame is +x, +y).
    """
    x, wts, _ = slope_nodes(nodes)
    sx, sy = (v.ravel() for v in np.meshgrid(x, x))
    ww = (wts[:, None] * wts[None, :]).ravel()
    hv = np.stack([roughness * sx, roughness * sy, np.ones_like(sx)], axis=-1)
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)  # (M, 3)
    s = np.sqrt(np.maximum(0.0, 1.0 - cos**2))
    wo = np.stack([s, np.zeros_like(s), cos], axis=-1)  # (C, 3)
    o_h = wo @ hv.T  # (C, M)
    wi = 2.0 * o_h[..., None] * hv[None] - wo[:, None, :]
    cos_i, cos_h, cos_r = wi[..., 2], hv[None, :, 2], cos[:, None]
    above = (cos_i > 0) & (cos_r > 0)
    root = np.sqrt(np.maximum(np.where(above, cos_i * cos_r, 1.0), 1e-8))
    g = np.where(above, cos_i * o_h * cos_h**3 / root, 0.0)
    return g @ ww


def filter_bound(pixels, texel_angle, roughness, min_cos, nodes, normalize, theta_range=(0.0, math.pi)):
    """Bound of |mirror lookup - mipmap lookup| for a white film (multiply by the specular weight).

    Returns ``(bound, detail)``; ``bound`` is ``inf`` when the lobe reads coarser mip levels.
    """
    x, _, width = slope_nodes(nodes)
    cell = float(np.sqrt(np.max(width) * np.max(width)))
    level = float(mip_footprint_level(roughness * cell, texel_angle))
    radius = 2.0 * roughness * math.sqrt(2.0) * float(np.max(np.abs(x)))
    if level > 0:
        return math.inf, f"lobe reads mip level {level:.2f} > 0"
    var = lookup_variation(pixels, radius, theta_range)
    peak = float(np.max(pixels))
    if normalize:
        alb_err, alb_max = 0.0, 1.0
    else:
        cos = np.linspace(max(min_cos, 1e-3), 1.0, 8)
        alb = mipmap_albedo(roughness, cos, nodes)
        alb_err, alb_max = float(np.max(np.abs(alb - cos))), max(1.0, float(np.max(alb)))
    bound = alb_max * var + peak * alb_err
    return bound, (f"lobe radius {radius:.2e} rad moves the lookup by <= {var:.2e}, "
                   f"albedo vs mirror {alb_err:.1e} x peak {peak:.3g}")


@dataclass(frozen=True, eq=False)
class SceneBounds:
    """What every ``auto`` decision of one scene reads, computed once (:func:`scene_bounds`).

    Attributes:
        model: ``paper`` | ``physical``.
        t, r_d, r_s, roughness, n_film: the scene's (or a fit's starting) values.
        thickness_range: (min, max) film thickness over the bubble, nm.
        min_cos: smallest incidence cosine on the film among the image's pixels (the rim).
        has_env: whether an environment map lights the bubble.
        env_peak: the map's largest radiance (0 without a map).
        env_pixels: the (H, W, 3) map, or None; texel_angle: its texel's angle (rad).
        spec_peak: largest specular radiance a film can reflect (map peak plus the point
            lights' eq. (3) peak); irr_peak: largest irradiance (table peak plus lights).
        background: ``envmap`` | ``black`` | ``photo``; bg_peak: its largest radiance
            (0 for black).
        n_point_lights: number of distant lights.
        albedo: the largest albedo of the unnormalised lobe (eq. 1 as written; ``paper``).
        w_refl: the radiance bound the film's reflection coefficients multiply:
            ``r_s S_max albedo + r_d E_max / pi`` (paper) or ``S_max + r_d E_max / pi``.
        reflect_theta_range: polar angles (rad) of the mirror directions the image reads
            (the whole sphere unless a caller knows better).
        d_grid, c_grid: thickness (D, C) and incidence-cosine (C,) grids (:func:`film_grids`).
    """

    model: Model
    t: float
    r_d: float
    r_s: float
    roughness: float
    n_film: float
    thickness_range: tuple[float, float]
    min_cos: float
    has_env: bool
    env_peak: float
    env_pixels: np.ndarray | None
    texel_angle: float | None
    spec_peak: float
    irr_peak: float
    background: str
    bg_peak: float
    n_point_lights: int
    albedo: float
    w_refl: float
    reflect_theta_range: tuple[float, float]
    d_grid: np.ndarray = field(repr=False)
    c_grid: np.ndarray = field(repr=False)

    @property
    def weights(self) -> tuple[float, float, float]:
        """Radiance bounds of the (front, rear, background) film coefficients."""
        return self.w_refl, self.w_refl, self.bg_peak

    def filter_bound(self, nodes: int) -> tuple[float, str]:
        """:func:`filter_bound` of this scene's map at its roughness with ``nodes`` slope nodes
        per axis: ``(bound, detail)``, ``inf`` when no map is given to bound the mirror lookup."""
        if self.env_pixels is None:
            return math.inf, "no map given to bound the mirror lookup"
        return filter_bound(self.env_pixels, self.texel_angle, max(self.roughness, 1e-12), self.min_cos, nodes,
                            self.model == "physical", self.reflect_theta_range)


@dataclass(frozen=True, eq=False)
class SceneSummary:
    """The scalar summaries of one scene that :func:`scene_bounds` turns into its :class:`SceneBounds`.

    A scene file (:meth:`bubblefit.model.scene.Scene.plan`) and a fit's setup
    (:func:`bubblefit.inverse.fit.fit_photo`) each fill one from what they hold.

    Attributes
    ----------
    model : Model
        ``paper`` | ``physical``.
    t, r_d, r_s, roughness, n_film : float
        The scene's (or a fit's starting) values.
    thickness_range : tuple of float
        (min, max) film thickness over the bubble, nm.
    env_texel_angle : float or None
        The map's texel angle (rad); None without a map.
    env_peak, env_mean : float
        The map's largest and mean radiance (0 without a map).
    background : str
        ``envmap`` | ``black`` | ``photo``.
    background_peak : float
        The background's largest radiance.
    n_point_lights : int
        Number of distant lights.
    light_peak : float
        The largest irradiance of one light.
    min_cos : float
        Smallest incidence cosine on the film among the image's pixels (the rim).
    env_pixels : ndarray or None
        The (H, W, 3) map.
    env_irradiance_peak : float or None
        The peak of the map's irradiance table; None: ``4 pi`` times ``env_mean`` bounds it.
    reflect_theta_range : tuple of float
        Polar angles (rad) of the mirror directions the image reads (the whole sphere
        unless a caller knows better).
    """

    model: Model
    t: float
    r_d: float
    r_s: float
    roughness: float
    thickness_range: tuple[float, float]
    n_film: float
    env_texel_angle: float | None
    env_peak: float
    env_mean: float
    background: str
    background_peak: float
    n_point_lights: int
    light_peak: float
    min_cos: float
    env_pixels: np.ndarray | None = field(default=None, repr=False)
    env_irradiance_peak: float | None = None
    reflect_theta_range: tuple[float, float] = (0.0, math.pi)


def scene_bounds(s: SceneSummary, *, nodes: int, per_pixel: bool = False, field: bool = False) -> SceneBounds:
    """The :class:`SceneBounds` of a scene from its scalar summaries (:class:`SceneSummary`).

    ``per_pixel``: the grids serve ``auto``'s per-pixel cells (:func:`film_grids`);
    ``field``: the thickness varies over the film (drainage, a map), so the
    physical model's bounces multiply films of different thickness and the grid reaches
    twice as far in optical path. The scalar path of a fit (a range of one thickness)
    takes neither.

    The radiance bounds: eq. (3)'s lobe times ``cos th_i`` peaks at
    ``1 / (4 pi a^2 sqrt(cos th_r))`` for a light of irradiance 1; without an irradiance
    table ``4 pi`` times the map's mean bounds any irradiance. ``nodes`` is the ``mipmap``
    quadrature whose albedo (eq. 1 unnormalised, :func:`mipmap_albedo`) scales the paper
    model's specular radiance.
    """
    model, min_cos, n_lights = s.model, s.min_cos, s.n_point_lights
    has_env = s.env_texel_angle is not None
    a = max(float(s.roughness), 1e-12)
    peak_env = s.env_peak if has_env else 0.0
    irr_env = ((s.env_irradiance_peak if s.env_irradiance_peak is not None else 4 * math.pi * s.env_mean)
               if has_env else 0.0)
    light_spec = s.light_peak / (4 * math.pi * a * a * math.sqrt(max(min_cos, 1e-3))) if n_lights else 0.0
    light_irr = s.light_peak * max(n_lights, 0)
    spec_peak = max(peak_env, 0.0) + light_spec * max(n_lights, 0)
    irr_peak = irr_env + light_irr
    alb = 1.0
    if model == "paper" and has_env:
        alb = max(1.0, float(np.max(mipmap_albedo(a, np.linspace(max(min_cos, 1e-3), 1.0, 8), nodes))))
    if model == "paper":
        # L' = r_s S + r_d E / pi (eq. 2), the radiance the paper's factors multiply.
        w_refl = max(s.r_s, 0.0) * spec_peak * alb + max(s.r_d, 0.0) * irr_peak / math.pi
    else:
        w_refl = spec_peak + max(s.r_d, 0.0) * irr_peak / math.pi
    dmin, dmax = (float(s.thickness_range[0]), float(s.thickness_range[1]))
    d_grid, c_grid = film_grids((dmin, dmax), min_cos, s.n_film, reach=2.0 if model == "physical" and field else 1.0,
                                per_pixel=per_pixel)
    return SceneBounds(model=model, t=float(s.t), r_d=float(s.r_d), r_s=float(s.r_s), roughness=float(s.roughness),
                       n_film=float(s.n_film), thickness_range=(dmin, dmax), min_cos=float(min_cos), has_env=has_env,
                       env_peak=float(peak_env), env_pixels=s.env_pixels, texel_angle=s.env_texel_angle,
                       spec_peak=spec_peak, irr_peak=irr_peak, background=s.background,
                       bg_peak=s.background_peak if s.background != "black" else 0.0,
                       n_point_lights=int(n_lights), albedo=alb, w_refl=w_refl,
                       reflect_theta_range=tuple(s.reflect_theta_range), d_grid=d_grid, c_grid=c_grid)


class FilmTable:
    """The film's RGB coefficients on a scene's grids, per interference mode and basis (cached).

    Every wavelength a decision may ask for (the reference's and the candidates' in
    ``wanted``) is evaluated in one call of :func:`film_spectra` per mode.
    """

    def __init__(self, b: SceneBounds, bounces: int, tint_rs: float | None, wanted: list[SpectralBasis]):
        self.b, self.bounces, self.tint_rs, self.wanted = b, bounces, tint_rs, list(wanted)
        self._cache: dict = {}
        self._spectra: dict = {}

    def _values(self, mode: Interference, basis: SpectralBasis) -> np.ndarray:
        b = self.b
        if basis.phases is not None:  # harmonic: (values, per-point weights); every wanted basis in one call
            key = ("harmonic", mode)
            if basis not in self._spectra.get(key, {}):
                bases = [bb for bb in self.wanted if bb.phases is not None]
                self.wanted += [] if basis in bases else [basis]
                bases += [] if basis in bases else [basis]
                self._spectra[key] = dict(zip(bases, harmonic_spectra(b.model, mode, bases, b.d_grid, b.c_grid,
                                                                      b.t, b.n_film)))
            return self._spectra[key][basis]
        if basis.sigma is not None:  # fourier: the lobe-filtered film at the lobes' centres, all bases at once
            key = ("fourier", mode)
            if key not in self._spectra:
                bases = [bb for bb in self.wanted if bb.sigma is not None] or [basis]
                if basis not in bases:
                    bases.append(basis)
                lam = np.concatenate([bb.wavelengths for bb in bases])
                sig = np.concatenate([bb.sigma for bb in bases])
                vals = film_spectra(b.model, mode, lam, b.d_grid, b.c_grid, b.t, b.n_film, sig)
                offs = np.cumsum([0] + [bb.samples for bb in bases])
                self._spectra[key] = {bb: vals[:, :, offs[i]: offs[i + 1]] for i, bb in enumerate(bases)}
            if basis not in self._spectra[key]:
                del self._spectra[key]
                self.wanted.append(basis)
                return self._values(mode, basis)
            return self._spectra[key][basis]
        if mode in self._spectra:
            lam_all, vals = self._spectra[mode]
            idx = np.searchsorted(lam_all, basis.wavelengths)
            if np.allclose(lam_all[np.minimum(idx, len(lam_all) - 1)], basis.wavelengths):
                return vals[:, :, idx]
        lam_all = np.unique(np.concatenate([bb.wavelengths for bb in self.wanted + [basis] if bb.sigma is None and bb.phases is None]))
        self._spectra[mode] = (lam_all, film_spectra(b.model, mode, lam_all, b.d_grid, b.c_grid, b.t, b.n_film))
        return self._values(mode, basis)

    def difference(self, a: dict, b: dict) -> float:
        """:func:`coefficient_difference` of two of this table's coefficient sets, each term
        weighted by the scene's radiance bound (:attr:`SceneBounds.weights`)."""
        return coefficient_difference(a, b, *self.b.weights)

    def __call__(self, mode: Interference, basis: SpectralBasis | None = None) -> dict:
        """:func:`film_coefficients` for ``mode`` with ``basis`` (None for the grey modes)."""
        b = self.b
        key = (mode, None if basis is None else basis.samples, None if basis is None else basis.method)
        if key not in self._cache:
            if mode in GREY:
                self._cache[key] = film_coefficients(b.model, mode, None, b.d_grid, b.c_grid, b.t, b.n_film,
                                                     self.bounces, self.tint_rs)
            elif basis.phases is not None:
                vals, weights = self._values(mode, basis)
                self._cache[key] = film_coefficients(b.model, mode, weights, vals, b.c_grid, b.t, b.n_film,
                                                     self.bounces, self.tint_rs)
            else:
                self._cache[key] = film_coefficients(b.model, mode, basis.weights, self._values(mode, basis), b.c_grid,
                                                     b.t, b.n_film, self.bounces, self.tint_rs)
        return self._cache[key]
