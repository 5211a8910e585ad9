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

__all__ = ["ward_lobe", "ward", "tan2_half_angle", "half_vector_weight"]

_TINY = 1e-12
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
