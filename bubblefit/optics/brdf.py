"""Ward's isotropic BRDF, eq. (1) of the paper (Ward, SIGGRAPH 1992, eq. 5a).

``f(w_i -> w_r) = r_d / pi + r_s exp(-tan^2(delta) / a^2) / (4 pi a^2 sqrt(cos th_i cos th_r))``
with ``delta`` the angle between the half vector and the normal.

The lobe is a Gaussian in slope space: with ``s = tan(delta)`` (a 2-vector in the tangent
plane), ``exp(-|s|^2 / a^2) / (pi a^2)`` integrates to 1 over the plane. Using the
half-vector Jacobians ``dw_i = 4 (w_o . h) dw_h`` and ``dw_h = cos^3(delta) d^2 s``,

``int f_spec cos th_i dw_i = int exp(-|s|^2/a^2)/(pi a^2) * g(s) d^2 s``,
``g(s) = cos th_i (w_o . h) cos^3(delta) / sqrt(cos th_i cos th_r)``,

which is what :mod:`bubblefit.lighting.filtering` integrates by Gauss-Hermite quadrature. At the
mirror direction ``g = cos th_r``: the albedo of eq. (1) tends to ``cos th_r`` (not 1) as
``a -> 0``, the known normalisation error of Ward's original lobe (Walter, "Notes on the
Ward BRDF", 2005); at normal incidence the albedo is ``1 - O(a^2)``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

__all__ = ["ward_lobe", "ward", "tan2_half_angle", "half_vector_weight", "facet_cosines"]

_TINY = 1e-12
# Three-point Gauss-Hermite rule for a standard normal variable: nodes 0, +-sqrt(3),
# weights 2/3, 1/6, 1/6 (exact for polynomials up to degree 5; Abramowitz & Stegun 25.4.46).
_GH3_NODES = (0.0, 3.0 ** 0.5, -(3.0 ** 0.5))
_GH3_WEIGHTS = (2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0)
# Lower bound of sqrt(cos th_i cos th_r): Ward's lobe is singular at grazing angles.
_MIN_SQRT_COS = 1e-4


def tan2_half_angle(cos_h: ArrayLike) -> Array:
    """``tan^2(delta) = (1 - cos^2) / cos^2``, finite (and large) as ``cos_h -> 0``.

    ``cos^2`` is clipped to [1e-12, 1]: a non-unit normal (e.g. of a ray that misses the
    bubble, masked later) must not give ``tan^2 < 0`` and ``exp(+huge) = inf`` in the lobe,
    whose gradient would turn the masked pixel into NaN."""
    c2 = jnp.clip(jnp.asarray(cos_h) ** 2, _TINY, 1.0)
    return (1.0 - c2) / c2


def ward_lobe(cos_i: ArrayLike, cos_r: ArrayLike, cos_h: ArrayLike, a: ArrayLike) -> Array:
    """Specular part of eq. (1) with ``r_s = 1``; 0 where either direction is below the surface.

    ``exp(-tan^2(delta)/a^2) / (4 pi a^2 sqrt(cos th_i cos th_r))``. The exponent is
    evaluated before dividing by ``a^2`` in a form that underflows to 0 (with a zero
    gradient) for tiny roughness, and ``sqrt(cos th_i cos th_r)`` is bounded below by
    1e-4 so the grazing singularity stays finite.
    """
    cos_i = jnp.asarray(cos_i)
    cos_r = jnp.asarray(cos_r)
    above = (cos_i > 0) & (cos_r > 0)
    a2 = a * a
    expo = jnp.exp(-tan2_half_angle(cos_h) / a2)
    root = jnp.sqrt(jnp.maximum(jnp.where(above, cos_i * cos_r, 1.0), _MIN_SQRT_COS**2))
    return jnp.where(above, expo / (4.0 * jnp.pi * a2 * root), 0.0)


def ward(cos_i, cos_r, cos_h, r_d, r_s, a) -> Array:
    """Eq. (1): ``r_d / pi + r_s * ward_lobe``; 0 below either horizon."""
    above = (jnp.asarray(cos_i) > 0) & (jnp.asarray(cos_r) > 0)
    return jnp.where(above, r_d / jnp.pi, 0.0) + r_s * ward_lobe(cos_i, cos_r, cos_h, a)


def half_vector_weight(cos_i: ArrayLike, cos_r: ArrayLike, o_dot_h: ArrayLike, cos_h: ArrayLike) -> Array:
    """``g(s)`` of the module docstring: eq. (1)'s lobe times ``cos th_i`` per unit slope-space
    Gaussian measure. 0 where the reflected direction is below the surface."""
    cos_i = jnp.asarray(cos_i)
    above = (cos_i > 0) & (jnp.asarray(cos_r) > 0)
    root = jnp.sqrt(jnp.maximum(jnp.where(above, cos_i * cos_r, 1.0), _MIN_SQRT_COS**2))
    return jnp.where(above, cos_i * o_dot_h * jnp.asarray(cos_h) ** 3 / root, 0.0)


def facet_cosines(cos_i: ArrayLike, a: ArrayLike) -> tuple[list[Array], list[Array]]:
    """The incidence cosines ``w_i . h`` on the microfacets of eq. (1)'s lobe that a ray at
    ``cos_i`` (N,) to the mean surface sees, and their weights: three nodes (lists of
    three (N,) arrays) for the mean over visible facets of a function of ``w_i . h``, such
    as a thin film's Fresnel term in a microfacet BRDF, ``F(w_i . h)`` (Walter et al.,
    EGSR 2007, eq. 20), which Blender Cycles evaluates per sampled facet.

    Ward's lobe is a Gaussian in slope space (module docstring): each slope component
    is normal with variance ``a^2 / 2``. A facet of slopes ``(p, q)``, ``p`` in the plane
    of incidence, has ``w_i . h = (cos_i + p sin_i) / sqrt(1 + p^2 + q^2)`` and shows the
    ray the projected area ``cos_i + p sin_i`` per unit of the mean surface, so the
    visible facets (Heitz, JCGT 3(2), 2014, the distribution of visible normals without
    masking) weigh each slope by ``max(1 + p tan_i, 0)``. ``p`` is integrated with the
    three-point Gauss-Hermite rule and ``q`` through its mean square (``q^2 -> a^2 / 2``,
    a second-order term). At ``a = 0`` every node is ``cos_i``: the mean is the function
    at the mean surface's angle."""
    c = jnp.clip(jnp.asarray(cos_i), 1e-6, 1.0)
    s = jnp.sqrt(jnp.maximum(1.0 - c * c, 0.0))
    sigma = jnp.asarray(a) / jnp.sqrt(2.0)
    cos_nodes, weights = [], []
    for z, w in zip(_GH3_NODES, _GH3_WEIGHTS):
        slope = sigma * z
        cos_nodes.append(jnp.clip((c + slope * s) / jnp.sqrt(1.0 + slope * slope + sigma * sigma), 1e-6, 1.0))
        weights.append(w * jnp.maximum(c + slope * s, 0.0))
    total = sum(weights)
    return cos_nodes, [w / total for w in weights]
