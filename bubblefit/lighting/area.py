"""A flat film seen in reflection of an area light (a diffuse panel, a disc lamp).

A flat, mirror-smooth film sends each camera ray into its mirror direction; the pixel
sees the radiance the light emits along that direction, times the film's reflectance
at the angle of incidence:

    ``L_pixel(lambda) = R(d, lambda, theta_i) L_light(lambda)``  if the mirror ray hits the light,
    ``0`` otherwise (a dark room),

with ``cos(theta_i) = |n . w|`` for the film's unit normal ``n`` and the camera ray ``w``.
A Lambertian panel has the same radiance in every direction, so ``L_light`` is its
radiance (its spectrum is the lamp's). The light and the film are planar patches: a
rectangle (centre, unit normal, an ``up`` direction in its plane, width and height) or a
disc (centre, normal, radius).

A curved film (a whole bubble) meets the light from many points: :func:`patch_coverage`
says, for a ray leaving a film point along its mirror direction, how much of a rough
film's reflection lobe lands on the light (1 or 0 for a mirror film).

References
----------
M. Pharr, W. Jakob and G. Humphreys, *Physically Based Rendering*, 3rd ed., sec. 8.2
(specular reflection: the mirror direction ``w - 2 (w . n) n``) and 12.2 (area lights);
G. J. Ward, "Measuring and modeling anisotropic reflection", SIGGRAPH 1992 (the lobe's
width ``a``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["Patch", "PlaneView", "view_plane", "patch_coverage", "check_light_faces"]


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(v)
    if v.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise InputError(f"{what} must be a non-zero 3-vector, got {v.tolist()}")
    return v / norm


@dataclass(frozen=True)
class Patch:
    """A planar patch: ``shape`` "rect" (``size`` = width, height along ``right``, ``up``) or "disc" (``size`` = radius, radius)."""

    center: tuple
    normal: tuple
    up: tuple = (0.0, 1.0, 0.0)
    size: tuple = (1.0, 1.0)
    shape: str = "rect"
    radiance: float = 1.0

    def __post_init__(self):
        size = tuple(float(v) for v in self.size)
        if len(size) != 2 or not all(math.isfinite(v) and v > 0 for v in size):
            what = "radius" if self.shape == "disc" else "size (width, height)"
            raise InputError(f"a patch's {what} must be positive, got {list(size)}")

    def frame(self):
        """(centre, unit normal, unit right, unit up) with up projected into the plane."""
        n = _unit(self.normal, "normal")
        up = np.asarray(self.up, dtype=np.float64)
        up = up - np.dot(up, n) * n
        if np.linalg.norm(up) < 1e-9:
            raise InputError("a patch's up direction must not be along its normal")
        up = up / np.linalg.norm(up)
        return np.asarray(self.center, dtype=np.float64), n, np.cross(up, n), up

    def intersect(self, origins: np.ndarray, dirs: np.ndarray):
        """(t, inside, local x, local y) of rays ``origins + t dirs`` with the patch's plane."""
        c, n, right, up = self.frame()
        den = dirs @ n
        safe = np.abs(den) > 1e-12
        t = np.where(safe, ((c - origins) @ n) / np.where(safe, den, 1.0), np.inf)
        with np.errstate(invalid="ignore"):  # a ray along the plane: t = inf, x = y = NaN, not inside
            p = origins + t[..., None] * dirs
        x, y = (p - c) @ right, (p - c) @ up
        if self.shape == "disc":
            inside = x * x + y * y <= self.size[0] ** 2
        else:
            inside = (np.abs(x) <= 0.5 * self.size[0]) & (np.abs(y) <= 0.5 * self.size[1])
        return t, inside & safe & (t > 0), x, y


@dataclass(frozen=True)
class PlaneView:
    """Per pixel: on the film (``mask``), ``sin2_air`` of the incidence, the light's ``radiance``
    along the mirror direction (0 where the mirror ray misses it), and the film coordinates ``x, y``."""

    mask: np.ndarray
    sin2_air: np.ndarray
    radiance: np.ndarray
    x: np.ndarray
    y: np.ndarray


def view_plane(origins: np.ndarray, dirs: np.ndarray, film: Patch, light: Patch,
               min_cos: float = 0.05, strict: bool = True) -> PlaneView:
    """The film and the light as a camera's rays see them (the module's equation, geometry part).

    ``origins`` and ``dirs`` (H, W, 3): the camera's rays. Raises a one-line
    :class:`~bubblefit.errors.InputError` when the film is seen edge-on (every ray meets it
    at ``cos(theta_i) < min_cos``; 0.05 is 87 degrees) or not at all (``strict``; else an
    empty mask).
    """
    t, on_film, x, y = film.intersect(origins, dirs)
    _, n, _, _ = film.frame()
    cos_i = np.abs(dirs @ n)
    if strict and not np.any(on_film):
        raise InputError("the film plane does not appear in the photo (no camera ray meets it)")
    if strict and np.max(cos_i[on_film]) < min_cos:
        raise InputError(f"the film plane is seen edge-on (every ray meets it within {np.degrees(np.arccos(min_cos)):.0f}"
                         " degrees of grazing); turn the camera towards the film")
    mask = on_film & (cos_i >= min_cos)
    hit = origins + np.where(np.isfinite(t), t, 0.0)[..., None] * dirs
    mirror = dirs - 2.0 * (dirs @ n)[..., None] * n
    _, on_light, _, _ = light.intersect(hit + 1e-9 * mirror, mirror)
    radiance = np.where(mask & on_light, float(light.radiance), 0.0)
    return PlaneView(mask=mask, sin2_air=np.clip(1.0 - cos_i * cos_i, 0.0, 1.0), radiance=radiance, x=x, y=y)


def check_light_faces(light: Patch, point, what: str = "the film") -> None:
    """Raise a one-line :class:`~bubblefit.errors.InputError` unless the light's emitting
    side (along its ``normal``) faces ``point``: a panel turned away lights nothing there."""
    c, n, _, _ = light.frame()
    if float(np.dot(np.asarray(point, np.float64) - c, n)) <= 0.0:
        raise InputError(f"the area light faces away from {what} (its normal {np.round(n, 3).tolist()} points "
                         "away from it): turn its normal towards the film")


def patch_coverage(light: Patch, origins, dirs, roughness=0.0):
    """The share of a film's reflection lobe that lands on the light, for rays leaving the
    film at ``origins`` along their mirror directions ``dirs`` (N, 3) (jax, differentiable).

    A mirror film (``roughness`` 0): 1 where the ray meets the light's emitting side inside
    its outline, else 0 (Pharr et al. 8.2, 12.2). A rough film spreads its reflection over
    Ward's lobe ``exp(-tan^2(delta) / a^2)``: each slope of the half-vector is a Gaussian of
    standard deviation ``a / sqrt(2)``, and the mirror direction turns by twice the
    half-vector's angle, ``sqrt(2) a`` radians per axis; at the distance ``t`` along the ray
    this is a spread ``sigma = sqrt(2) a t / |cos|`` on the light's plane (``cos`` the
    ray's incidence on it). The share is then that Gaussian's mass over the outline, taken per axis for a
    rectangle (``Phi((w/2 - x)/sigma) - Phi((-w/2 - x)/sigma)`` times the same along ``y``)
    and across the rim for a disc (``Phi((radius - r)/sigma)``).

    The rough case is an approximation: the lobe is taken isotropic and its foreshortening
    on the plane the same along both axes, which holds while ``sigma`` is small against the
    light and its incidence moderate. The mirror case is exact.
    """
    import jax.numpy as jnp
    from jax.scipy.special import ndtr

    c, n, right, up = (jnp.asarray(v, dtype=dirs.dtype) for v in light.frame())
    den = dirs @ n
    front = den < -1e-9                               # travelling against the normal: meets the lit side
    t = jnp.where(front, ((c - origins) @ n) / jnp.where(front, den, -1.0), -1.0)
    hit = front & (t > 0)
    p = origins + jnp.where(hit, t, 0.0)[..., None] * dirs - c
    x, y = p @ right, p @ up
    sigma = jnp.maximum(math.sqrt(2.0) * roughness * jnp.maximum(t, 0.0) / jnp.maximum(-den, 1e-9), 1e-12)
    if light.shape == "disc":
        share = ndtr((light.size[0] - jnp.hypot(x, y)) / sigma)
    else:
        hw, hh = 0.5 * light.size[0], 0.5 * light.size[1]
        share = (ndtr((hw - x) / sigma) - ndtr((-hw - x) / sigma)) * (ndtr((hh - y) / sigma) - ndtr((-hh - y) / sigma))
    return jnp.where(hit, share, 0.0)
