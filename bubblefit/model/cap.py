"""A bubble blown onto a wet dish: a spherical cap standing on a liquid surface (geometry).

The paper's second way to photograph a bubble (sec. 3.1): a bubble on a wet surface is
the part of a sphere (centre ``c``, radius ``R``) above a horizontal liquid plane
``y = plane_y`` (bubblefit's +y is up). Its height is ``H = c_y + R - plane_y``
(``0 < H <= 2 R``: a hemisphere when the plane passes through the centre), its foot a
circle of radius ``sqrt(R^2 - (plane_y - c_y)^2)`` on the liquid.

A camera ray ``o + s d`` meets, first,

* the cap: the sphere's near intersection ``s0`` with the point above the plane (the
  film seen directly);
* else the liquid: the plane at ``s_l = (plane_y - o_y) / d_y`` (``d_y < 0``), outside the
  foot (inside it the ray would have met the cap first); the liquid reflects the mirror
  ray ``d - 2 d_y e_y`` with the Fresnel reflectance of air to the liquid, and that ray
  meets the cap or goes on to the surroundings. The camera thus sees the cap mirrored in
  the liquid, as a plane mirror shows the image of the sphere reflected about the plane;
* else nothing (the environment).

Only this geometry is modelled here: the film's optics at the cap (the thickness, the
rear film and the liquid seen through the cap) and a fit of a cap are not.

References
----------
M. Pharr, W. Jakob and G. Humphreys, *Physically Based Rendering*, 3rd ed., sec. 3.2
(ray-sphere intersection) and 8.2 (specular reflection); M. Born and E. Wolf,
*Principles of Optics*, 7th ed., sec. 1.5 (Fresnel's formulae).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..optics import dispersion, film
from .geometry import intersect_sphere

__all__ = ["Cap", "CapView", "trace_cap"]


@dataclass(frozen=True)
class Cap:
    """A spherical cap: the sphere (``center``, ``radius``) above the liquid plane ``y = plane_y``,
    the liquid's index ``liquid`` (a number, ``"water"``, ...)."""

    center: tuple
    radius: float
    plane_y: float
    liquid: dispersion.IndexSpec = "water"

    def __post_init__(self):
        r = float(self.radius)
        if not (math.isfinite(r) and r > 0):
            raise InputError(f"a cap's radius must be positive, got {self.radius!r}")
        h = self.height
        if h > 2.0 * r:
            raise InputError(f"the cap is taller than its sphere: the plane lies {h - 2 * r:g} below the sphere's "
                             f"bottom (height {h:g} > diameter {2 * r:g})")
        if h <= 0.0:
            raise InputError(f"the cap has no height: the plane y = {self.plane_y:g} lies above the sphere")

    @property
    def height(self) -> float:
        """``c_y + R - plane_y``: from the liquid to the cap's top."""
        return float(self.center[1]) + float(self.radius) - float(self.plane_y)

    @property
    def foot_radius(self) -> float:
        """Radius of the circle where the cap meets the liquid."""
        dy = float(self.plane_y) - float(self.center[1])
        return math.sqrt(max(float(self.radius) ** 2 - dy * dy, 0.0))


@dataclass(frozen=True)
class CapView:
    """Per ray: ``film`` (the ray meets the cap first) at ``film_point`` with the outward
    ``film_cos`` of incidence; ``liquid`` (it meets the liquid first) at ``liquid_point``,
    with the liquid's unpolarised reflectance ``liquid_reflectance`` (per wavelength, last
    axis) and the mirror ray ``mirror_dir``; ``mirror_film``: that ray meets the cap, at
    ``mirror_point`` with ``mirror_cos``."""

    film: np.ndarray
    film_point: np.ndarray
    film_cos: np.ndarray
    liquid: np.ndarray
    liquid_point: np.ndarray
    liquid_reflectance: np.ndarray
    mirror_dir: np.ndarray
    mirror_film: np.ndarray
    mirror_point: np.ndarray
    mirror_cos: np.ndarray


@functools.partial(jax.jit, static_argnames=("radius",))
def _sphere_hits(o, d, center, radius: float):
    """``(p0, inside, cos)`` of :func:`bubblefit.model.geometry.intersect_sphere`, compiled
    once per radius (the radius stays a Python number, as in an eager call)."""
    hits = intersect_sphere(o, d, center, radius)
    return hits.p0, hits.inside, hits.cos


#: :func:`bubblefit.optics.film.fresnel_reflectance`, compiled.
_fresnel_reflectance = jax.jit(film.fresnel_reflectance)


def _cap_hit(o, d, cap: Cap):
    """(hit, point, cos) of rays' first meeting with the cap's surface above the plane."""
    o32 = jnp.asarray(o)
    p0, inside, cos = _sphere_hits(o32, jnp.asarray(d), jnp.asarray(cap.center, o32.dtype), float(cap.radius))
    p0 = np.asarray(p0)
    s0 = np.sum((p0 - o) * d, axis=-1)
    hit = np.asarray(inside) & (s0 > 0) & (p0[:, 1] >= cap.plane_y)
    return hit, p0, np.asarray(cos)


def trace_cap(origins, dirs, cap: Cap, wavelength_nm=(550.0,)) -> CapView:
    """The cap and its mirror image in the liquid as rays ``origins + s dirs`` (N, 3) see them
    (the module's geometry); ``dirs`` unit vectors."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    on_cap, p_cap, cos_cap = _cap_hit(o, d, cap)
    down = d[:, 1] < 0
    s_l = np.where(down, (cap.plane_y - o[:, 1]) / np.where(down, d[:, 1], -1.0), np.inf)
    p_l = o + np.where(np.isfinite(s_l), s_l, 0.0)[:, None] * d
    c = np.asarray(cap.center, np.float64)
    outside_foot = np.hypot(p_l[:, 0] - c[0], p_l[:, 2] - c[2]) > cap.foot_radius
    liquid = down & (s_l > 0) & outside_foot & ~on_cap
    m = d * np.array([1.0, -1.0, 1.0])
    mirror_film, p_m, cos_m = _cap_hit(p_l + 1e-9 * m, m, cap)
    mirror_film &= liquid
    lam = np.asarray(wavelength_nm, np.float64)
    n_liq = np.asarray(dispersion.refractive_index(cap.liquid, lam), np.float64)
    cos_l = np.abs(d[:, 1])[:, None]
    refl = np.asarray(_fresnel_reflectance(jnp.asarray(cos_l), jnp.asarray(n_liq))).mean(-1)
    return CapView(film=on_cap, film_point=p_cap, film_cos=cos_cap, liquid=liquid, liquid_point=p_l,
                   liquid_reflectance=np.where(liquid[:, None], refl, 0.0), mirror_dir=m, mirror_film=mirror_film,
                   mirror_point=p_m, mirror_cos=cos_m)
