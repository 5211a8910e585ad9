"""Coaxial (epi-) illumination of a flat film through an objective, and the film's stack of media.

A reflected-light microscope or an interferometer lights the film through its objective:
every direction inside the cone of half-angle ``asin(NA)`` (in air) carries the lamp's
radiance, and the light the film reflects back into the same cone forms the image. For a
flat film each incident direction is reflected into its mirror direction, which lies in
the cone too, so a pixel sees the film's reflectance averaged over the cone with the
irradiance weight ``L cos(theta) dOmega``. With ``u = sin^2(theta)`` that weight is
uniform, ``cos(theta) sin(theta) dtheta dphi = du dphi / 2`` (a uniformly filled pupil
of an aplanatic objective), so the average is

    ``R_NA(d, lambda) = (1 / NA^2) int_0^{NA^2} R(d, lambda, theta(u)) du``,

taken here by Gauss-Legendre quadrature in ``u``. Spreading the incidence angle spreads
the film's optical path ``2 n d cos(theta_t)``, which washes out the fringes of thick
films; a few nodes suffice below a fringe of spread (:func:`cone_nodes_needed`).

The light enters the medium above the film (a glass plate, a lens, water) through a face
parallel to the film, so in a medium of index ``n0`` the angle obeys
``n0 sin(theta_0) = sin(theta_air)``. The faces of the plates outside the film are taken
as not imaged (out of focus or anti-reflection coated): only the film's reflectance
counts.

References
----------
M. Born and E. Wolf, *Principles of Optics*, 7th ed., sec. 7.6 (fringes of a plate with
an extended source) and 8.6 (Koehler illumination).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..errors import InputError
from . import dispersion, film

__all__ = ["Stack", "StackIndices", "cone_quadrature", "cone_nodes_needed", "coaxial_reflectance",
           "reflectance_at_angles"]


@dataclass(frozen=True)
class Stack:
    """The media of a flat film: ``above`` (where the light comes from), ``film``, ``below``.

    Each is an index description of :mod:`bubblefit.optics.dispersion` (a number, a
    Cauchy or Sellmeier law, a preset name such as ``"air"``, ``"water"``, ``"bk7"``).
    A soap film in air is ``Stack("air", "soap", "air")``; an air gap between glass
    plates ``Stack("bk7", "air", "bk7")``.
    """

    above: dispersion.IndexSpec = "air"
    film: dispersion.IndexSpec = 1.4
    below: dispersion.IndexSpec = "air"

    def indices(self, wavelength_nm) -> "StackIndices":
        """The three indices at each wavelength (nm), as arrays shaped like it."""
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        return StackIndices(*(dispersion.refractive_index(m, lam) for m in (self.above, self.film, self.below)))

    def describe(self) -> str:
        return " | ".join(dispersion.describe(m) for m in (self.above, self.film, self.below))


@dataclass(frozen=True)
class StackIndices:
    """Per-wavelength indices (K,) of a :class:`Stack`."""

    above: np.ndarray
    film: np.ndarray
    below: np.ndarray


def reflectance_at_angles(thickness: ArrayLike, wavelength: ArrayLike, n: StackIndices,
                          sin2_air: ArrayLike, span=None) -> Float[Array, "..."]:
    """Unpolarised reflectance of the stack for light that left air at ``sin^2(theta_air)``.

    The angle in the medium above follows from Snell's law across a parallel face
    (``n0 sin(theta_0) = sin(theta_air)``); the film's reflectance is the three-media Airy
    sum of :func:`bubblefit.optics.film.airy_reflectance`, s and p averaged (unpolarised
    lamp). Broadcasts ``thickness``, ``wavelength`` (last axis, like the indices) and
    ``sin2_air``. ``span`` ``(span_x, span_y)`` (nm, broadcasting like ``thickness``): the
    thickness's change across a pixel's box along its two sides, whose mean over the box
    is taken (:func:`bubblefit.optics.film.box_airy_reflectance`); None: the point's.
    """
    cos0 = jnp.sqrt(jnp.clip(1.0 - sin2_air / jnp.asarray(n.above) ** 2, 0.0, 1.0))
    media = dict(n_above=jnp.asarray(n.above), n_below=jnp.asarray(n.below))
    if span is not None:
        return film.box_airy_reflectance(thickness, wavelength, jnp.asarray(n.film), cos0, span[0], span[1],
                                         **media).mean(-1)
    return film.airy_reflectance(thickness, wavelength, jnp.asarray(n.film), cos0, **media).mean(-1)


def cone_quadrature(na: float, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``u = sin^2(theta_air)`` and weights (summing to 1) of the cos-weighted cone average.

    Gauss-Legendre with ``nodes`` points on ``[0, NA^2]`` (exact for polynomials in ``u``
    of degree ``2 nodes - 1``); ``na = 0`` is normal incidence alone.
    """
    if not 0.0 <= na < 1.0:
        raise InputError(f"the numerical aperture must lie in [0, 1) (an objective in air), got {na}")
    if na == 0.0:
        return np.zeros(1), np.ones(1)
    x, w = np.polynomial.legendre.leggauss(int(nodes))
    return 0.5 * na * na * (x + 1.0), 0.5 * w


def cone_nodes_needed(max_thickness_nm: float, na: float, n_film_min: float, lambda_min_nm: float = 380.0) -> int:
    """Gauss-Legendre nodes for the cone average of a film up to ``max_thickness_nm``.

    Across the cone the optical path ``2 n d cos(theta_t)`` changes by about
    ``d NA^2 / n`` (``cos(theta_t) ~ 1 - sin^2(theta_air) / (2 n^2)``), i.e. by
    ``f = d NA^2 / (n lambda)`` fringes; the integrand is then a trigonometric
    function of ``u`` of about ``f`` periods (and of higher harmonics with the Airy sum's
    multiple beams). Six nodes per fringe plus four keep the quadrature error below
    1e-4 in reflectance over 0-3000 nm, NA <= 0.6 (tests/test_films_lamps.py compares
    with 400 nodes).
    """
    fringes = max_thickness_nm * na * na / (max(n_film_min, 1.0) * lambda_min_nm)
    return int(min(64, 4 + math.ceil(6.0 * fringes)))


def coaxial_reflectance(thickness: ArrayLike, wavelength: ArrayLike, n: StackIndices, na: float,
                        nodes: int, span=None) -> Float[Array, "..."]:
    """The stack's reflectance averaged over an objective's cone (the module's equation).

    ``thickness`` broadcasts against ``wavelength`` (the last axis); returns the
    unpolarised, cos-weighted cone average of :func:`reflectance_at_angles`. The nodes are
    summed in order by one loop (``jax.lax.scan``), so that the program has one copy of the
    film's reflectance whatever the number of nodes; each weight is taken in the
    reflectance's precision. ``span``: a pixel's box, as in :func:`reflectance_at_angles`.
    """
    u, w = cone_quadrature(na, nodes)
    u, w = jnp.asarray(u), jnp.asarray(w)

    def add(out, node):
        uk, wk = node
        r = reflectance_at_angles(thickness, wavelength, n, uk, span)
        return out + wk.astype(r.dtype) * r, None

    like = jax.eval_shape(lambda: reflectance_at_angles(thickness, wavelength, n, u[0], span))
    out, _ = jax.lax.scan(add, jnp.zeros(like.shape, like.dtype), (u, w))
    return out
