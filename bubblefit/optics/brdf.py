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

import math

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

__all__ = ["ward_lobe", "ward", "tan2_half_angle", "half_vector_weight", "slope_nodes", "facet_cosines",
           "ggx_facet_cosines", "ggx_ward_widths", "GGX_FACET_NODES"]

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


#: Half-width (in units of ``a``) of the uniform slope grid used for more than 4 nodes; the
#: square [-2.5, 2.5]^2 holds all but 8e-4 of the Gaussian's mass.
UNIFORM_EXTENT = 2.5


def slope_nodes(nodes: int):
    """Nodes ``x`` and weights (sum 1) for ``exp(-x^2)`` per axis, and each node's width.

    Up to 4 nodes: Gauss-Hermite (the best few-node rule for a smooth integrand). The width
    of node j is the spacing to its neighbours (the outer nodes stand for wider cells); for
    one node it is ``sqrt(6)``, the box with the Gaussian's variance 1/2.
    More nodes: the midpoint rule on a uniform grid over ``[-UNIFORM_EXTENT, UNIFORM_EXTENT]``
    with weights ``exp(-x^2)``. Its cells shrink like ``1/nodes`` (Gauss-Hermite's central
    spacing only like ``1/sqrt(nodes)``), so with each node prefiltered over its cell a
    map with a sun converges much faster (measured in tests/test_filtering.py).
    """
    if nodes > 4:
        step = 2.0 * UNIFORM_EXTENT / nodes
        x = -UNIFORM_EXTENT + (np.arange(nodes) + 0.5) * step
        w = np.exp(-x * x)
        return x, w / w.sum(), np.full(nodes, step)
    x, w = np.polynomial.hermite.hermgauss(nodes)
    if nodes == 1:
        width = np.array([math.sqrt(6.0)])
    else:
        mid = 0.5 * (x[1:] + x[:-1])
        edges = np.concatenate([[2 * x[0] - mid[0]], mid, [2 * x[-1] - mid[-1]]])
        width = np.diff(edges)
    return x, w / w.sum(), width


def facet_cosines(cos_i: ArrayLike, a: ArrayLike) -> tuple[list[Array], list[Array]]:
    """The incidence cosines ``w_i . h`` on the microfacets of eq. (1)'s lobe that a ray at
    ``cos_i`` (N,) to the mean surface sees, and their weights: three nodes (lists of
    three (N,) arrays, :func:`slope_nodes`) for the mean over visible facets of a function of ``w_i . h``, such
    as a thin film's Fresnel term in a microfacet BRDF, ``F(w_i . h)`` (Walter et al.,
    EGSR 2007, eq. 20), which Blender Cycles evaluates per sampled facet.

    Ward's lobe is a Gaussian in slope space (module docstring): each slope component
    is normal with variance ``a^2 / 2``. A facet of slopes ``(p, q)``, ``p`` in the plane
    of incidence, has ``w_i . h = (cos_i + p sin_i) / sqrt(1 + p^2 + q^2)`` and shows the
    ray the projected area ``cos_i + p sin_i`` per unit of the mean surface, so the
    visible facets (Heitz, JCGT 3(2), 2014, the distribution of visible normals without
    masking) weigh each slope by ``max(1 + p tan_i, 0)``. ``p = a x`` is integrated with the
    three-point Gauss-Hermite rule for ``exp(-x^2)`` (exact for polynomials in ``x`` up to
    degree 5) and ``q`` through its mean square (``q^2 -> a^2 / 2``, a second-order term). At ``a = 0`` every node is ``cos_i``: the mean is the function
    at the mean surface's angle."""
    c = jnp.clip(jnp.asarray(cos_i), 1e-6, 1.0)
    s = jnp.sqrt(jnp.maximum(1.0 - c * c, 0.0))
    a = jnp.asarray(a)
    x, wx, _ = slope_nodes(3)
    cos_nodes, weights = [], []
    for xj, wj in zip(x.tolist(), wx.tolist()):
        slope = a * xj
        cos_nodes.append(jnp.clip((c + slope * s) / jnp.sqrt(1.0 + slope * slope + 0.5 * a * a), 1e-6, 1.0))
        weights.append(wj * jnp.maximum(c + slope * s, 0.0))
    total = sum(weights)
    return cos_nodes, [w / total for w in weights]


#: Nodes of :func:`ggx_facet_cosines`' product rule: Gauss-Legendre in ``v = sqrt(1 - u1)``
#: (the radial coordinate of Heitz's disc, whose end ``v -> 0`` holds GGX's tail), midpoints
#: in the angle over the half of the disc the film is even in. Against scipy's adaptive
#: quadrature of the visible normals (tests/test_film_rgb.py), at ``alpha = 0.0225`` and
#: cosines 0.4-0.95: a film's first harmonic clipped at 0 (the clamped film's kink) within
#: 1.4e-3 (8 x 3 nodes: 4.9e-3; 32 x 8: 2e-4), a tenth or less of what separates GGX's
#: visible facets from Ward's there; ``(w_i . h)^4`` within 1.4e-5 (5e-5 at ``alpha = 0.2``).
GGX_FACET_NODES = (16, 4)


def ggx_facet_cosines(cos_i: ArrayLike, alpha: ArrayLike, nodes: tuple = GGX_FACET_NODES) -> tuple[Array, Array]:
    """The incidence cosines ``w_i . h`` on the visible microfacets of GGX's distribution of
    width ``alpha`` (Walter, Marschner, Li & Torrance, EGSR 2007, eq. 33; the facets Blender
    Cycles samples), and their weights: ``(cos (M, N), weights (M,))``, ``M`` the product of
    ``nodes``, the weights summing to 1, for the mean over visible facets of a function of
    ``w_i . h`` as :func:`facet_cosines` gives it for Ward's lobe.

    Heitz's map of the unit square onto GGX's distribution of visible normals (E. Heitz,
    "Sampling the GGX distribution of visible normals", JCGT 7(4), 2018, sections 3-4: the
    view stretched by ``alpha``, a point of the unit disc at radius ``sqrt(u1)`` and angle
    ``2 pi u2`` warped towards the view, lifted onto the hemisphere and unstretched) takes
    the uniform measure on ``(u1, u2)`` to the visible normals' (Heitz, JCGT 3(2), 2014:
    ``G1(w_i) max(w_i . h, 0) D(h) / cos_i``), so the mean is an integral over the unit
    square. GGX's slopes are a Student t with 2 degrees of freedom, a fraction
    ``alpha^2 / (alpha^2 + r^2)`` of them beyond slope ``r`` (``1 - u1`` at normal view):
    the rule takes Gauss-Legendre nodes in ``v = sqrt(1 - u1)`` (``du1 = 2 v dv``), in which
    the tail is smooth, and midpoints in the angle over ``[-pi/2, pi/2]`` (the facets'
    cosines are even in the cross-plane slope). At ``alpha = 0`` every node is ``cos_i``."""
    c = jnp.clip(jnp.asarray(cos_i), 1e-6, 1.0)
    s = jnp.sqrt(jnp.maximum(1.0 - c * c, 0.0))
    alpha = jnp.asarray(alpha)
    norm = jnp.sqrt((alpha * s) ** 2 + c * c)
    vx, vz = alpha * s / norm, c / norm                  # the stretched view, in the plane of incidence
    x, wx = np.polynomial.legendre.leggauss(nodes[0])
    v = 0.5 * (x + 1.0)
    u1, w1 = 1.0 - v * v, wx * v                          # 0.5 wx * 2 v: the weights of u1 on [0, 1]
    phi = (np.arange(nodes[1]) + 0.5) / nodes[1] * np.pi - 0.5 * np.pi
    r = np.sqrt(u1)[:, None]
    t1, t2 = (r * np.cos(phi)).reshape(-1), (r * np.sin(phi)).reshape(-1)
    weights = np.repeat(w1 / nodes[1], nodes[1])
    t1, t2 = t1[:, None], t2[:, None]                    # (M, 1) against the rays' (N,)
    t2 = 0.5 * (1.0 - vz) * np.sqrt(1.0 - t1 * t1) + 0.5 * (1.0 + vz) * t2
    up = jnp.sqrt(jnp.maximum(1.0 - t1 * t1 - t2 * t2, 0.0))
    hx, hy, hz = alpha * (up * vx - t2 * vz), alpha * t1, jnp.maximum(up * vz + t2 * vx, 0.0)
    length = jnp.sqrt(jnp.maximum(hx * hx + hy * hy + hz * hz, _TINY))
    cos_nodes = jnp.clip((hx * s + hz * c) / length, 1e-6, 1.0)
    return cos_nodes, jnp.asarray(weights / weights.sum(), dtype=cos_nodes.dtype)


def ggx_ward_widths(alpha: float, k: int) -> np.ndarray:
    """Widths of ``k`` Ward lobes whose equal-weight mean is GGX's slope distribution of
    width ``alpha``: ``(1 + |s|^2/alpha^2)^-2 / (pi alpha^2)`` (Walter et al. 2007, eq. 33, in
    slope space) is a bivariate Student t with 2 degrees of freedom, a Gaussian scale
    mixture ``s | w ~ N(0, alpha^2 / (2 w))``, ``w ~ Exp(1)`` (D. F. Andrews & C. L.
    Mallows, "Scale mixtures of normal distributions", JRSS B 36, 1974), i.e. of Ward lobes
    (``N(0, a^2 / 2)`` in slope space, module docstring) of ``a = alpha / sqrt(w)``; ``w``
    at the mid-quantiles ``-ln((j + 1/2) / k)`` of Exp(1). The widest is ``alpha /
    sqrt(-ln(1 - 1/(2k)))`` (3.4 alpha for 6): the mixture stops short of GGX's tail."""
    u = (np.arange(k) + 0.5) / k
    return float(alpha) / np.sqrt(-np.log(u))
