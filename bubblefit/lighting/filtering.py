"""Filtering an environment map with Ward's BRDF: eqs. (4)-(7), (12) and (13).

For a shading point with unit normal ``n`` and unit direction to the viewer ``w_o``
(both ``(N, 3)``, in the map's frame) these functions return the specular integral

    ``L_s(n, w_o) = int f_spec(w_i -> w_o) L(w_i) max(0, n . w_i) dw_i``   (r_s = 1)

by one of four methods, and the irradiance ``E(n) = int L max(0, n . w_i) dw_i`` that the
diffuse term ``r_d / pi * E`` needs. ``L`` is the environment's radiance.

Methods (the ``filtering`` knob of a scene):

``mirror``
    The limit ``a -> 0``: one lookup in the reflected direction, times the limit of the
    lobe's albedo (``cos th_r`` for eq. (1) as written, 1 when normalised).
``window`` (eq. 13)
    The sum of eq. (12) restricted to a window of ``(2k+1)^2`` texels of mip level ``level``
    around the reflected direction; the paper's method, exact for its texels as ``k`` grows.
``mipmap`` (hierarchical, after Kautz et al. 2000)
    Quadrature of the lobe in slope space with ``nodes x nodes`` nodes (Gauss-Hermite up
    to 4 per axis, a uniform midpoint grid beyond); each node reads the mip level whose
    texels match the cell it stands for, so even one node integrates the whole lobe
    without aliasing. Converges to the exact integral as ``nodes`` grows.
``full`` (eq. 12)
    The exact sum over every texel of mip level ``level``: the reference.

With ``normalize=True`` (the ``physical`` model, where the film's Fresnel reflectance
sets the strength and Ward's lobe only the shape) the lobe's weights are divided by their
sum, so the result is a weighted mean of the radiance and a white environment returns 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..optics.brdf import half_vector_weight, slope_nodes, ward_lobe
from .envmap import EnvMap, direction_to_uv, texel_directions, texel_solid_angles

__all__ = [
    "FilterConfig",
    "reflect",
    "tangent_frame",
    "specular",
    "irradiance",
    "specular_mirror",
    "specular_mipmap",
    "specular_window",
    "full_sum",
    "mip_footprint_level",
]

#: The filtering methods of a scene's ``filtering`` knob (see the module docstring).
FilterMethod = Literal["mirror", "window", "mipmap", "full"]
METHODS: tuple[str, ...] = get_args(FilterMethod)
MIP_BLUR = 0.5
#: Most pieces each footprint node's cell is read in along its longer side (one across;
#: one box where that reads it as well, :func:`~bubblefit.lighting.envmap.pieces_needed`)
#: (:func:`~bubblefit.lighting.envmap.lookup_parallelogram`): with 4 nodes per axis a cell
#: is a quarter of the pixel's footprint, so 2 pieces read a footprint up to 8 x
#: ``BOX_TEXELS`` long at the map's own level. Chosen on ref_drain_exp15_studio_persp at
#: the fit's last level (2 x 2 blocks, true parameters, reduced chi^2 with the floor):
#: 1 piece 9.8, 2 and 4 pieces 4.1, 2 x 2 pieces 3.7 at twice the lookups.
NODE_PROBES = 2


@dataclass(frozen=True)
class FilterConfig:
    """Static settings of the environment filter (hashable; part of the compiled program).

    Attributes:
        method: ``mirror`` | ``window`` | ``mipmap`` | ``full``.
        nodes: Gauss-Hermite nodes per axis for ``mipmap`` (1 = a single prefiltered lookup).
        window: half-size ``k`` of the texel window for ``window``.
        level: mip level summed over by ``window`` and ``full`` (0 = full resolution).
        chunk: texels per step of the ``full`` sum (bounds memory).
    """

    method: FilterMethod = "mipmap"
    nodes: int = 4
    window: int = 8
    level: int = 0
    chunk: int = 4096

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"unknown filtering method {self.method!r}; expected one of {METHODS}")
        if self.nodes < 1 or self.window < 0 or self.level < 0:
            raise ValueError("filter knobs must be positive")


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _normalize(v):
    n2 = _dot(v, v)[..., None]
    return v / jnp.sqrt(jnp.maximum(n2, 1e-30))


def reflect(w: Float[Array, "N 3"], n: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """Mirror direction of ``w`` (pointing away from the surface) about ``n``: ``2 (w.n) n - w``."""
    return 2.0 * _dot(w, n)[..., None] * n - w


def tangent_frame(n: Float[Array, "N 3"]):
    """Orthonormal tangents (t1, t2) of unit normals ``n``, continuous except on one
    meridian (Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 2017)."""
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = jnp.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = jnp.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    t2 = jnp.stack([b, sign + y * y * a, -y], axis=-1)
    return t1, t2


def specular_mirror(env: EnvMap, n, wo, *, normalize: bool, footprint=None) -> Float[Array, "N 3"]:
    """The ``a -> 0`` limit: ``L(reflect(w_o, n))``, times ``cos th_r`` for eq. (1) as written.

    With a pixel ``footprint`` (:func:`~bubblefit.model.geometry.slope_footprint`) the
    mirror reads the map averaged over the directions the pixel's rays reflect into
    (:func:`specular_box`): 16 texels instead of the bilinear lookup's 4.
    """
    if footprint is not None:
        return specular_box(env, n, wo, footprint, normalize=normalize)
    cos_r = jnp.clip(_dot(n, wo), 0.0, 1.0)[..., None]
    rad = env.lookup(reflect(wo, n))
    return rad if normalize else rad * cos_r


def mip_footprint_level(slope_width, texel_angle: float):
    """Continuous mip level whose texels are as wide as a quadrature cell.

    A cell ``slope_width`` wide in the half vector's slope is about twice as wide in the
    reflected direction's angle (``w_i = reflect(w_o, h)`` turns twice as fast as ``h``);
    the level is ``log2`` of that width over the texel angle of level 0.
    """
    return jnp.log2(jnp.maximum(MIP_BLUR * 2.0 * slope_width / texel_angle, 1e-30))


def specular_box(env: EnvMap, n, wo, footprint, *, normalize: bool) -> Float[Array, "N 3"]:
    """A mirror's reflection averaged over the pixel's box: the map's mean over the
    directions ``reflect(wo, n + J (s, t))``, ``s, t`` in ``[-1/2, 1/2]`` (``J = footprint``,
    (N, 3, 2), :func:`~bubblefit.model.geometry.slope_footprint`).

    A half vector that moves by ``dh`` (normal to ``n``) turns the reflected direction by
    ``dr = 2 (wo . dh) n + 2 (wo . n) dh``; the parallelogram those span is cut into up
    to 4 x 4 pieces (as few as read it as well), each read as the box of its second moments in the map's texels and averaged exactly over the bilinear interpolant
    (:func:`~bubblefit.lighting.envmap.lookup_parallelogram`): no sun between sub-pixel
    samples is missed, none is counted whole, and a footprint many texels long and under
    one wide (near the rim, an internal bounce) is not widened to a coarser mip level's
    texels across its width. Weighted as :func:`specular_mirror` (``cos th_r``, 1
    when normalised).

    References
    ----------
    H. Igehy, "Tracing ray differentials", SIGGRAPH 1999 (the footprint).
    """
    cos = _dot(n, wo)
    wo_dh = jnp.sum(wo[:, :, None] * footprint, axis=1)  # (N, 2)
    dr = 2.0 * wo_dh[:, None, :] * n[:, :, None] + 2.0 * cos[:, None, None] * footprint
    rad = env.lookup_parallelogram(reflect(wo, n), dr)
    if normalize:
        return rad
    return rad * jnp.clip(cos, 0.0, 1.0)[..., None]


def box_nodes(nodes: int):
    """Nodes, weights and widths of the midpoint rule for a box with the variance of
    ``exp(-x^2)`` (1/2): ``nodes`` equal cells tiling ``[-sqrt(3/2), sqrt(3/2)]``."""
    half = math.sqrt(1.5)
    step = 2.0 * half / nodes
    x = -half + (np.arange(nodes) + 0.5) * step
    return x, np.full(nodes, 1.0 / nodes), np.full(nodes, step)


def _footprint_nodes(footprint, t1, t2, a, nodes: int):
    """The nodes of :func:`specular_mipmap` for the lobe convolved with a pixel footprint:
    their slopes ``(s1, s2)`` (N, M) along ``t1``, ``t2``, their weights (N, M), and the two
    sides of the parallelogram each node's cell covers (each a pair of (N, M) slopes).

    With ``G`` the footprint in the ``t1, t2`` frame over ``sqrt(12)`` (the pixel box's
    covariance is ``G G^T``) and ``C = G G^T + a^2/2 I``, the nodes sit at
    ``sqrt(2) L (x_j, x_k)`` with ``L = C^(1/2) R``, ``R`` the rotation (or reflection) of
    ``G``'s polar decomposition: ``L L^T = C``, ``L = G`` at ``a = 0`` and ``L`` tends to
    ``a / sqrt(2)`` times a rotation as the lobe outgrows the pixel. The rule ``x``, its
    weights and cell widths pass from the box's midpoint rule (:func:`box_nodes`, the
    pixel's own box at ``a = 0``, tiled exactly) to :func:`slope_nodes` (the lobe's) in
    proportion to the lobe's share of the variance, ``b = (a^2/2) / (a^2/2 + tr(G G^T)/2)``.
    """
    g = footprint / math.sqrt(12.0)  # the box's variance, 1/12 of its side squared
    g11 = jnp.sum(t1 * g[..., 0], axis=-1)
    g12 = jnp.sum(t1 * g[..., 1], axis=-1)
    g21 = jnp.sum(t2 * g[..., 0], axis=-1)
    g22 = jnp.sum(t2 * g[..., 1], axis=-1)
    half_a2 = 0.5 * a * a
    c11 = half_a2 + g11 * g11 + g12 * g12
    c12 = g11 * g21 + g12 * g22
    c22 = half_a2 + g21 * g21 + g22 * g22
    # C^(1/2) of a 2 x 2 SPD matrix: (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C))
    # (a floor above 0: where float32 rounds det C of a thin footprint at roughness ~0 to
    # <= 0, sqrt's infinite slope at 0 times max's zero slope would make a NaN Jacobian)
    root_det = jnp.sqrt(jnp.maximum(c11 * c22 - c12 * c12, 1e-30))
    den = jnp.sqrt(c11 + c22 + 2.0 * root_det + 1e-30)
    q11, q12, q22 = (c11 + root_det) / den, c12 / den, (c22 + root_det) / den
    # G's polar factor: a rotation where det G >= 0, else a reflection
    det_g = g11 * g22 - g12 * g21
    rot = jnp.arctan2(g21 - g12, g11 + g22)
    ref = jnp.arctan2(g21 + g12, g11 - g22)
    pos = det_g >= 0
    r11 = jnp.where(pos, jnp.cos(rot), jnp.cos(ref))
    r21 = jnp.where(pos, jnp.sin(rot), jnp.sin(ref))
    r12 = jnp.where(pos, -jnp.sin(rot), jnp.sin(ref))
    r22 = jnp.where(pos, jnp.cos(rot), -jnp.cos(ref))
    l11, l12 = q11 * r11 + q12 * r21, q11 * r12 + q12 * r22
    l21, l22 = q12 * r11 + q22 * r21, q12 * r12 + q22 * r22
    share = half_a2 / (half_a2 + 0.5 * (g11**2 + g12**2 + g21**2 + g22**2) + 1e-30)
    xg, wg, dg = slope_nodes(nodes)
    xb, wb, db = box_nodes(nodes)
    col = lambda v: v[:, None]
    b = col(share)
    mix = lambda u, v: jnp.asarray(u, g.dtype)[None, :] * (1.0 - b) + jnp.asarray(v, g.dtype)[None, :] * b
    x, w, d = mix(xb, xg), mix(wb, wg), mix(db, dg)  # (N, nodes) each
    xj, xk = x[:, None, :], x[:, :, None]  # node (k, j): j along the first column of L
    dj, dk = d[:, None, :], d[:, :, None]
    flat = lambda v: jnp.broadcast_to(v, (x.shape[0], nodes, nodes)).reshape(x.shape[0], -1)
    xj, xk, dj, dk = flat(xj), flat(xk), flat(dj), flat(dk)
    weights = flat(w[:, :, None] * w[:, None, :])
    root2 = math.sqrt(2.0)
    e = lambda v: root2 * col(v)
    s1 = e(l11) * xj + e(l12) * xk
    s2 = e(l21) * xj + e(l22) * xk
    side1 = (e(l11) * dj, e(l21) * dj)
    side2 = (e(l12) * dk, e(l22) * dk)
    return s1, s2, weights, side1, side2


def specular_mipmap(env: EnvMap, n, wo, a, *, nodes: int, normalize: bool, footprint=None) -> Float[Array, "N 3"]:
    """Quadrature of the slope-space Gaussian lobe (see :mod:`bubblefit.optics.brdf`).

    Node ``(j, k)`` sits at slope ``a (x_j t1 + x_k t2)``, with ``x`` and the weights of
    :func:`slope_nodes` for ``exp(-x^2)`` (weights ``W_j W_k``, summing to 1). Its half
    vector gives ``w_i = reflect(w_o, h)``, read at the mip level whose texels match the
    cell the node stands for (:func:`mip_footprint_level`), so that a bright sun is
    prefiltered rather than aliased between nodes.

    With a pixel ``footprint`` ``F`` (N, 3, 2) (:func:`~bubblefit.model.geometry.slope_footprint`)
    the quadrature integrates the lobe over the pixel: the half vectors of the pixel's rays
    spread about ``n`` with covariance ``F F^T / 12`` (a box of side 1 has variance 1/12)
    and Ward's lobe about each of them with ``a^2 / 2`` per axis, and the two are taken as
    Gaussians, whose convolution adds the covariances: ``C = a^2/2 I + M M^T`` with ``M``
    the footprint over ``sqrt(12)`` in the nodes' tangent frame. The nodes sit at
    ``sqrt(2) L (x_j, x_k)`` with ``L L^T = C`` (Cholesky), which is the plain lobe's
    ``a (x_j, x_k)`` when ``F = 0``. Each node then reads the map averaged over the
    parallelogram of directions its own cell (``sqrt(2) L`` times the node's widths)
    reflects into, as :func:`specular_box` does for a pixel
    (:func:`~bubblefit.lighting.envmap.lookup_parallelogram`: :data:`NODE_PROBES` pieces
    along the cell's longer side, each on the map's axes): the cells tile the
    distribution, so a sun smaller than the nodes' spacing is neither missed between
    nodes nor counted whole at one, and a long, thin footprint (a film near the rim, an
    internal bounce) is filtered along each of its axes by its own width. (An isotropic
    mip level from the cells' geometric mean, which the plain lobe uses, blurs such a
    footprint's long axis far less than its nodes are spaced: on the sunny off-centre
    drainage photo of the validation set it put the sun's reflection on single nodes.)
    The approximations: a pixel's box is replaced by the Gaussian of its variance, each
    cell by the box of its second moments on the map's axes, and the differentials are
    those of the pixel's centre (the footprint is linear across the pixel).
    """
    x, w, width = slope_nodes(nodes)
    xx, yy = np.meshgrid(x, x)
    ww = jnp.asarray((w[:, None] * w[None, :]).ravel(), dtype=n.dtype)
    sx = jnp.asarray(xx.ravel(), dtype=n.dtype)[None, :]
    sy = jnp.asarray(yy.ravel(), dtype=n.dtype)[None, :]
    t1, t2 = tangent_frame(n)
    # All nodes at once, one (N, M) array per vector component: XLA fuses the chain from
    # the normals to the lookup's directions into one loop (with (N, M, 3) arrays it
    # wrote each step to memory and reduced the size-3 axis in separate kernels).
    comp = lambda v: [v[:, k:k + 1] for k in range(3)]
    dot = lambda u, v: u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    n_c, wo_c = comp(n), comp(wo)
    t1_c, t2_c = comp(t1), comp(t2)
    if footprint is None:
        s1, s2 = a * sx, a * sy
    else:
        s1, s2, ww, side1, side2 = _footprint_nodes(footprint, t1, t2, a, nodes)
    h = [nk + s1 * ak + s2 * bk for nk, ak, bk in zip(n_c, t1_c, t2_c)]
    norm = jnp.sqrt(jnp.maximum(dot(h, h), 1e-30))
    h = [hk / norm for hk in h]
    o_h = dot(wo_c, h)
    wi = [2.0 * o_h * hk - ok for hk, ok in zip(h, wo_c)]
    cos_i = dot(n_c, wi)
    cos_h = dot(n_c, h)
    cos_r = _dot(n, wo)[:, None]
    g = ww * half_vector_weight(cos_i, cos_r, o_h, cos_h)
    wi = jnp.stack(wi, axis=-1)
    if footprint is None:
        cell = jnp.asarray(np.sqrt(width[:, None] * width[None, :]).ravel(), dtype=n.dtype)
        level = mip_footprint_level(a * cell, env.texel_angle)
        rad = env.lookup_level(wi, jnp.broadcast_to(level, g.shape))
    else:
        # each node reads the map's mean over the parallelogram of directions its cell
        # reflects into (as specular_box for the pixel): cells tile the lobe convolved with
        # the pixel, so a source smaller than the nodes' spacing is neither missed nor
        # counted whole, and an elongated footprint is filtered along its own axes
        def turn(side):
            dh = [side[0] * ak + side[1] * bk for ak, bk in zip(t1_c, t2_c)]
            wo_dh = dot(wo_c, dh)
            return jnp.stack([2.0 * wo_dh * hk + 2.0 * o_h * dk for hk, dk in zip(h, dh)], axis=-1)

        dr = jnp.stack([turn(side1), turn(side2)], axis=-1)  # (N, M, 3, 2)
        m = wi.shape[0] * wi.shape[1]
        rad = env.lookup_parallelogram(wi.reshape(m, 3), dr.reshape(m, 3, 2), NODE_PROBES, 1).reshape(wi.shape)
    num = jnp.einsum("nm,nmc->nc", g, rad)
    if normalize:
        return num / jnp.maximum(jnp.sum(g, axis=1), 1e-12)[:, None]
    return num


def _level_tables(env: EnvMap, level: int):
    pixels = env.level(level)
    h, w = pixels.shape[:2]
    dirs = jnp.asarray(texel_directions(h, w), dtype=pixels.dtype)
    sa = jnp.asarray(texel_solid_angles(h, w), dtype=pixels.dtype)
    return pixels, dirs, sa


def _lobe_terms(n, wo, wi, a):
    """Eq. (1)'s lobe times ``cos th_i`` for shading points (N, 3) and texel directions (N, M, 3)."""
    cos_i = jnp.einsum("nc,nmc->nm", n, wi) if wi.ndim == 3 else wi @ n.T
    cos_r = _dot(n, wo)[:, None]
    h = _normalize(wi + wo[:, None, :])
    cos_h = jnp.einsum("nc,nmc->nm", n, h)
    return ward_lobe(cos_i, cos_r, cos_h, a) * jnp.maximum(cos_i, 0.0), cos_i


def specular_window(env: EnvMap, n, wo, a, *, window: int, level: int, normalize: bool):
    """Eq. (13): eq. (12) summed over the ``(2k+1)^2`` texels of mip ``level`` around the
    reflected direction (rows outside the map are dropped, columns wrap).

    Below one texel the window degenerates: a lobe narrower than the texels (``4 a`` below
    the level's texel angle) puts its weight on the nearest texel centre, a
    nearest-neighbour lookup (19% RMS from the bilinear lookup at ``a = 5e-4`` on a 2k
    map). There it returns the bilinear mirror lookup (:func:`specular_mirror`), the
    limit the sum converges to as the texels shrink.
    """
    narrow = 4.0 * a < env.texel_angle * 2.0**level
    a = jnp.maximum(a, 1e-12)
    summed = _window_sum(env, n, wo, a, window=window, level=level, normalize=normalize)
    return jnp.where(narrow, specular_mirror(env, n, wo, normalize=normalize), summed)


def _window_sum(env: EnvMap, n, wo, a, *, window: int, level: int, normalize: bool):
    """The sum of :func:`specular_window` over its texels."""
    pixels, dirs, sa = _level_tables(env, level)
    h, w = pixels.shape[:2]
    k = min(window, (w - 1) // 2)
    r = reflect(wo, n)
    u, v = direction_to_uv(r)
    col = jnp.floor(u * w).astype(jnp.int32)
    row = jnp.round(v * (h - 1)).astype(jnp.int32)
    off = jnp.arange(-k, k + 1)
    rows = row[:, None, None] + off[None, :, None]
    cols = (col[:, None, None] + off[None, None, :]) % w
    valid = (rows >= 0) & (rows < h)
    rows_c = jnp.clip(rows, 0, h - 1)
    rows_c, cols = jnp.broadcast_arrays(rows_c, cols)
    valid = jnp.broadcast_to(valid, rows_c.shape)
    npts = n.shape[0]
    wi = dirs[rows_c, cols].reshape(npts, -1, 3)
    rad = pixels[rows_c, cols].reshape(npts, -1, pixels.shape[2])
    dom = jnp.where(valid, sa[rows_c], 0.0).reshape(npts, -1)
    lobe, _ = _lobe_terms(n, wo, wi, a)
    wts = lobe * dom
    num = jnp.einsum("nm,nmc->nc", wts, rad)
    if normalize:
        den = jnp.sum(wts, axis=1)
        mirror = specular_mirror(env, n, wo, normalize=True)
        ok = (den > 1e-12)[:, None]
        return jnp.where(ok, num / jnp.where(ok, den[:, None], 1.0), mirror)
    return num


def full_sum(env: EnvMap, n, wo, a, *, level: int, chunk: int, normalize: bool):
    """Eq. (12) over every texel of mip ``level``: returns ``(L_s, E)``, the specular
    integral and the irradiance, accumulated over chunks of ``chunk`` texels."""
    pixels, dirs, sa = _level_tables(env, level)
    m = pixels.shape[0] * pixels.shape[1]
    nch = pixels.shape[2]
    dirs = dirs.reshape(m, 3)
    rad = (pixels.reshape(m, nch) * jnp.repeat(sa, pixels.shape[1])[:, None])
    steps = -(-m // chunk)
    pad = steps * chunk - m
    dirs = jnp.concatenate([dirs, jnp.tile(jnp.asarray([[0.0, 1.0, 0.0]], dirs.dtype), (pad, 1))])
    rad = jnp.concatenate([rad, jnp.zeros((pad, nch), rad.dtype)])
    dirs = dirs.reshape(steps, chunk, 3)
    rad = rad.reshape(steps, chunk, nch)
    npts = n.shape[0]
    cos_r = _dot(n, wo)[:, None]

    def step(carry, xs):
        spec, irr = carry
        d, l = xs  # padded texels carry no radiance, so they add nothing
        cos_i = n @ d.T
        h = _normalize(d[None, :, :] + wo[:, None, :])
        cos_h = jnp.einsum("nc,nmc->nm", n, h)
        lobe = ward_lobe(cos_i, cos_r, cos_h, a) * jnp.maximum(cos_i, 0.0)
        return (spec + lobe @ l, irr + jnp.maximum(cos_i, 0.0) @ l), None

    zeros = jnp.zeros((npts, nch), dtype=pixels.dtype)
    (spec, irr), _ = jax.lax.scan(step, (zeros, zeros), (dirs, rad))
    if normalize:
        # Divide by the lobe's own albedo over the same texels (a white map).
        ones = jnp.ones_like(pixels[..., :1])
        white = EnvMap(pixels=ones, atlas=ones.reshape(-1, 1), irradiance=env.irradiance[..., :1],
                       shapes=(ones.shape[:2],))
        alb, _ = full_sum(white, n, wo, a, level=0, chunk=chunk, normalize=False)
        mirror = specular_mirror(env, n, wo, normalize=True)
        ok = alb > 1e-12
        spec = jnp.where(ok, spec / jnp.where(ok, alb, 1.0), mirror)
    return spec, irr


def irradiance(env: EnvMap, n) -> Float[Array, "N 3"]:
    """``E(n)`` read from the environment's irradiance table (see :func:`envmap.irradiance_map`)."""
    return env.lookup_irradiance(n)


def specular(env: EnvMap, n, wo, a, config: FilterConfig, *, normalize: bool, footprint=None) -> Float[Array, "N 3"]:
    """The specular integral by ``config.method`` (``full`` returns only its specular part).

    ``footprint`` (N, 3, 2), the pixel's spread in slope space
    (:func:`~bubblefit.model.geometry.slope_footprint`), widens the ``mirror`` and
    ``mipmap`` lookups to the pixel's area; ``window`` and ``full``, the references, read
    the pixel's centre ray."""
    if config.method == "mirror":
        return specular_mirror(env, n, wo, normalize=normalize, footprint=footprint)
    if config.method == "mipmap":
        return specular_mipmap(env, n, wo, a, nodes=config.nodes, normalize=normalize, footprint=footprint)
    if config.method == "window":
        return specular_window(env, n, wo, a, window=config.window, level=config.level, normalize=normalize)
    return full_sum(env, n, wo, a, level=config.level, chunk=config.chunk, normalize=normalize)[0]
