"""Equirectangular environment maps: directions, texel solid angles, lookups, mip-maps.

Convention (docs/design.md, identical to Mitsuba 3's ``envmap`` emitter): for a unit direction
(x, y, z) in the map's frame, ``u = atan2(x, -z) / (2 pi)`` wrapped to [0, 1) and
``v = acos(y) / pi``; the bilinear lookup reads column ``u W - 1/2`` (wrapping) and row
``v (H - 1)`` (clamped), so row 0 is the zenith and row H-1 the nadir. A scene may rotate
the map about +y by ``rotation`` radians: a world direction ``w`` reads the map at
``R_y(-rotation) w``.

Maps made for renderers that put texel ``(i, j)``'s centre at ``((j + 1/2) / W, (i + 1/2) / H)``
(Blender, PBRT, Poly Haven's previews: :data:`CONVENTIONS` ``"texel-centre"``) differ from
these rows by half a texel at the poles; :func:`from_texel_centres` re-expresses such a map
on this module's rows exactly.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "EnvMap",
    "direction_to_uv",
    "uv_to_direction",
    "rotate_y",
    "lookup",
    "texel_directions",
    "texel_solid_angles",
    "downsample",
    "build_mipmap",
    "irradiance_map",
    "lookup_box",
    "texel_footprint",
    "lookup_parallelogram",
    "dark_room",
    "CONVENTIONS",
    "from_texel_centres",
]

#: Where a map's texel rows sit: ``"mitsuba"``, row ``i`` at ``v = i / (H - 1)`` (this
#: module's, Mitsuba 3's); ``"texel-centre"``, row ``i`` at ``v = (i + 1/2) / H`` (Blender
#: Cycles' Environment Texture, PBRT). Columns sit at ``u = (j + 1/2) / W`` in both.
CONVENTIONS = ("mitsuba", "texel-centre")


def _safe_norm_xz(x, z):
    """sqrt(x^2 + z^2) with a finite gradient at the poles."""
    r2 = x * x + z * z
    safe = jnp.where(r2 > 0, r2, 1.0)
    return jnp.where(r2 > 0, jnp.sqrt(safe), 0.0)


def direction_to_uv(d: Float[Array, "... 3"]) -> tuple[Array, Array]:
    """Map unit directions to (u, v) in [0, 1) x [0, 1] (Mitsuba's equirectangular map).

    ``v`` is computed as ``atan2(sqrt(x^2+z^2), y) / pi`` (equal to ``acos(y)/pi`` for unit
    vectors) so that values and gradients stay finite at the poles.
    """
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    # atan2(0, 0) has an undefined gradient: nudge the argument at the poles only.
    pole = (x == 0) & (z == 0)
    u = jnp.arctan2(jnp.where(pole, 0.0, x), jnp.where(pole, -1.0, -z)) / (2 * jnp.pi)
    u = u - jnp.floor(u)
    v = jnp.arctan2(_safe_norm_xz(x, z), y) / jnp.pi
    return u, v


def uv_to_direction(u: Array, v: Array) -> Float[Array, "... 3"]:
    """Inverse of :func:`direction_to_uv`."""
    phi = 2 * jnp.pi * u
    theta = jnp.pi * v
    s = jnp.sin(theta)
    return jnp.stack([s * jnp.sin(phi), jnp.cos(theta), -s * jnp.cos(phi)], axis=-1)


def rotate_y(d: Float[Array, "... 3"], angle) -> Float[Array, "... 3"]:
    """Rotate directions about +y by ``angle`` radians (right-handed)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return jnp.stack([c * x + s * z, y, -s * x + c * z], axis=-1)


def lookup(pixels: Float[Array, "H W C"], d: Float[Array, "... 3"]) -> Float[Array, "... C"]:
    """Bilinear lookup of an equirectangular map in directions ``d`` (Mitsuba texel positions)."""
    u, v = direction_to_uv(d)
    return lookup_uv(pixels, u, v)


def lookup_uv(pixels: Float[Array, "H W C"], u: Array, v: Array) -> Array:
    """Bilinear lookup at continuous map coordinates (u, v); columns wrap, rows clamp."""
    h, w = pixels.shape[0], pixels.shape[1]
    x = u * w - 0.5
    y = v * (h - 1)
    x0 = jnp.floor(x)
    y0 = jnp.clip(jnp.floor(y), 0, max(h - 2, 0))
    fx = x - x0
    fy = jnp.clip(y - y0, 0.0, 1.0)
    x0i = x0.astype(jnp.int32) % w
    x1i = (x0i + 1) % w
    y0i = y0.astype(jnp.int32)
    y1i = jnp.minimum(y0i + 1, h - 1)
    fx = fx[..., None]
    fy = fy[..., None]
    top = pixels[y0i, x0i] * (1 - fx) + pixels[y0i, x1i] * fx
    bot = pixels[y1i, x0i] * (1 - fx) + pixels[y1i, x1i] * fx
    return top * (1 - fy) + bot * fy


def from_texel_centres(pixels: np.ndarray) -> np.ndarray:
    """The ``(2H + 1, W)`` map whose bilinear lookup (:func:`lookup_uv`, row ``i'`` at
    ``v = i' / 2H``) equals, at every direction, the bilinear lookup of the ``(H, W)`` map
    ``pixels`` read with its texel centres at ``v = (i + 1/2) / H`` (rows clamped at the
    poles), as Blender Cycles' Environment Texture reads an equirectangular image.

    Odd rows ``2i + 1`` sit at ``v = (i + 1/2) / H``, the texel centres, and hold row ``i``;
    even rows ``2i`` sit at ``v = i / H``, midway between two centres, and hold the mean of
    rows ``i - 1`` and ``i`` (the pole rows ``0`` and ``2H`` repeat the first and last row,
    the texel-centre lookup being constant beyond the outer centres). Between two such
    rows both lookups are linear in ``v`` with the same end values, so they agree
    exactly; columns sit at ``(j + 1/2) / W`` in both conventions and are kept.

    References
    ----------
    Blender Cycles, ``kernel/camera/projection.h`` (``direction_to_equirectangular``:
    ``v = 1 - acos(z)/pi``, the image's rows counted from its bottom) and
    ``kernel/svm/image.h`` (the Environment Texture's bilinear lookup, texel centres at
    half-integer coordinates); M. Pharr, W. Jakob and
    G. Humphreys, *Physically Based Rendering*, 3rd ed., sec. 7.8 (texel centres at
    half-integer coordinates); W. Jakob et al., Mitsuba 3 ``envmap`` emitter (rows at
    ``v (H - 1)``).
    """
    px = np.asarray(pixels, dtype=np.float64)
    h = px.shape[0]
    out = np.empty((2 * h + 1, *px.shape[1:]))
    out[1::2] = px
    out[2:-1:2] = 0.5 * (px[:-1] + px[1:])
    out[0], out[-1] = px[0], px[-1]
    return out


def texel_directions(h: int, w: int) -> np.ndarray:
    """Direction of each texel centre, (H, W, 3) float64: column j at u = (j + 1/2)/W,
    row i at v = i/(H - 1). Static geometry, computed in numpy."""
    phi = 2 * np.pi * (np.arange(w) + 0.5) / w
    theta = np.pi * np.arange(h) / (h - 1)
    s = np.sin(theta)[:, None]
    return np.stack(
        np.broadcast_arrays(s * np.sin(phi), np.cos(theta)[:, None], -s * np.cos(phi)), axis=-1
    )


def texel_solid_angles(h: int, w: int) -> np.ndarray:
    """Solid angle of a texel in each row, (H,) float64 (the bands partition the sphere:
    ``W * sum = 4 pi``). Row i covers polar angles ``pi (i -/+ 1/2)/(H - 1)``, clipped to [0, pi]."""
    i = np.arange(h)
    th0 = np.clip((i - 0.5) / (h - 1), 0.0, 1.0) * np.pi
    th1 = np.clip((i + 0.5) / (h - 1), 0.0, 1.0) * np.pi
    return (np.cos(th0) - np.cos(th1)) * (2 * np.pi / w)


def downsample(pixels: np.ndarray) -> np.ndarray:
    """Halve an equirectangular map in both directions, weighting rows by solid angle.

    Texel rows are grouped in pairs (the last row joins the previous pair when H is odd),
    columns in pairs; each output texel is the solid-angle weighted mean of its group, so
    the map's total power is preserved.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    h, w, c = pixels.shape
    sa = texel_solid_angles(h, w)
    if w % 2:
        pixels = np.concatenate([pixels, pixels[:, :1]], axis=1)
        w += 1
    cols = 0.5 * (pixels[:, 0::2] + pixels[:, 1::2])
    h2 = max(h // 2, 2)
    groups = np.array_split(np.arange(h), h2)
    out = np.empty((h2, w // 2, c))
    for k, g in enumerate(groups):
        wts = sa[g] + 1e-30
        out[k] = np.tensordot(wts / wts.sum(), cols[g], axes=(0, 0))
    return out


def build_mipmap(pixels: np.ndarray, min_height: int = 4) -> list[np.ndarray]:
    """Mip pyramid of an equirectangular map: level 0 is the map, each next is halved."""
    levels = [np.asarray(pixels, dtype=np.float64)]
    while levels[-1].shape[0] // 2 >= min_height:
        levels.append(downsample(levels[-1]))
    return levels


def irradiance_map(pixels: np.ndarray, out_height: int = 32, src_height: int = 64) -> np.ndarray:
    """Irradiance ``E(n) = sum_i L_i max(0, n . w_i) dOmega_i`` on an equirectangular grid of normals.

    The cosine-weighted integral is smooth in ``n``, so it is computed exactly on a
    downsampled copy of the map (power-preserving :func:`downsample`) and tabulated at
    ``out_height x 2 out_height`` normals, to be read back with :func:`lookup`.
    The diffuse term of Ward's BRDF, ``r_d / pi * E(n)`` (eq. 1 with eq. 4), is read from
    this table so that it is never lost outside a filtering window (sec. 3.2).

    ``n . w = sin(theta_n) sin(theta_w) cos(phi_n - phi_w) + cos(theta_n) cos(theta_w)``
    depends on the azimuths only through their difference, so when the map's width is a
    multiple of the table's each row pair is a circular convolution in azimuth, summed by
    FFT (the same sum as the direct one, ~100x faster); other widths sum directly.
    """
    src = np.asarray(pixels, dtype=np.float64)
    while src.shape[0] > src_height:
        src = downsample(src)
    hs, ws = src.shape[:2]
    wo = 2 * out_height
    rad = src * texel_solid_angles(hs, ws)[:, None, None]
    if ws % wo:
        dirs = texel_directions(hs, ws).reshape(-1, 3)
        normals = texel_directions(out_height, wo).reshape(-1, 3)
        cos = np.maximum(normals @ dirs.T, 0.0)
        return (cos @ rad.reshape(-1, src.shape[2])).reshape(out_height, wo, src.shape[2])
    r = ws // wo  # normal column j sits at source offset r j + (r - 1)/2 texels
    th_n = np.pi * np.arange(out_height) / (out_height - 1)
    th_w = np.pi * np.arange(hs) / (hs - 1)
    dphi = 2 * np.pi * (np.arange(ws) + (r - 1) / 2) / ws
    kernel = np.maximum(np.sin(th_n)[:, None, None] * np.sin(th_w)[None, :, None] * np.cos(dphi)
                        + np.cos(th_n)[:, None, None] * np.cos(th_w)[None, :, None], 0.0)
    spectrum = np.einsum("ikf,kfc->ifc", np.fft.rfft(kernel, axis=-1), np.fft.rfft(rad, axis=1))
    return np.fft.irfft(spectrum, n=ws, axis=1)[:, ::r]


def lookup_levels(atlas, shapes: tuple, d: Float[Array, "... 3"], level) -> Float[Array, "... C"]:
    """Bilinear lookup in the mip level ``level`` (integer array broadcast against ``d``'s
    leading axes) of a pyramid packed into one ``atlas`` of shape (sum of H_l W_l, C).

    One gather serves every level, so a dynamic (even traced) level costs the same as a
    fixed one.
    """
    hs = jnp.asarray([s[0] for s in shapes], dtype=jnp.int32)
    ws = jnp.asarray([s[1] for s in shapes], dtype=jnp.int32)
    offs = jnp.asarray(np.cumsum([0] + [s[0] * s[1] for s in shapes[:-1]]), dtype=jnp.int32)
    level = jnp.broadcast_to(level, d.shape[:-1])
    h, w, off = hs[level], ws[level], offs[level]
    u, v = direction_to_uv(d)
    x = u * w - 0.5
    y = v * (h - 1)
    x0 = jnp.floor(x)
    y0 = jnp.clip(jnp.floor(y), 0, h - 2)
    fx = (x - x0)[..., None]
    fy = jnp.clip(y - y0, 0.0, 1.0)[..., None]
    x0i = x0.astype(jnp.int32) % w
    x1i = (x0i + 1) % w
    y0i = y0.astype(jnp.int32)
    y1i = jnp.minimum(y0i + 1, h - 1)
    at = lambda yy, xx: atlas[off + yy * w + xx]
    top = at(y0i, x0i) * (1 - fx) + at(y0i, x1i) * fx
    bot = at(y1i, x0i) * (1 - fx) + at(y1i, x1i) * fx
    return top * (1 - fy) + bot * fy


def _tent_integral(s):
    """The antiderivative of the bilinear tent ``max(0, 1 - |s|)``, 0 at ``s = -1``."""
    s = jnp.clip(s, -1.0, 1.0)
    return jnp.where(s < 0, 0.5 * (s + 1.0) ** 2, 1.0 - 0.5 * (1.0 - s) ** 2)


#: Widest box (in texels of the level it reads) :func:`lookup_box` integrates: each axis
#: then reads at most ``BOX_TEXELS + 2`` texels; a wider footprint reads a coarser level.
BOX_TEXELS = 4


def _box_axis(x, width):
    """Indices (..., K) and weights of the texels whose bilinear tents a box ``[x - w/2,
    x + w/2]`` covers, K = ``BOX_TEXELS + 2``: ``(T(x + w/2 - i) - T(x - w/2 - i)) / w``."""
    k = BOX_TEXELS + 2
    first = jnp.floor(x - 0.5 * width)
    idx = first[..., None] + jnp.arange(k, dtype=x.dtype)
    hi = _tent_integral(x[..., None] + 0.5 * width[..., None] - idx)
    lo = _tent_integral(x[..., None] - 0.5 * width[..., None] - idx)
    wts = (hi - lo) / width[..., None]
    return idx.astype(jnp.int32), wts


def _box_level(shapes: tuple, d: Float[Array, "... 3"], wx, wy):
    """The mip level :func:`lookup_box` reads a box of ``wx x wy`` texels (level 0) centred
    on ``d`` at: the first where the box's angular extent, ``wx sin(theta)`` columns of
    ``2 pi / W`` against ``wy`` rows of ``pi / (H - 1)``, is at most :data:`BOX_TEXELS`
    texels (L. Williams, "Pyramidal parametrics", SIGGRAPH 1983)."""
    h0, w0 = shapes[0]
    cos_t = d[..., 1] / jnp.sqrt(jnp.maximum(jnp.sum(d * d, axis=-1), 1e-30))
    sin_t = jnp.sqrt(jnp.clip(1.0 - cos_t**2, 0.0, 1.0))
    wx_angle = wx * sin_t * (2.0 * (h0 - 1) / w0)
    level = jnp.ceil(jnp.log2(jnp.maximum(jnp.maximum(wx_angle, wy) / BOX_TEXELS, 1.0)))
    return jnp.clip(level, 0, len(shapes) - 1).astype(jnp.int32)


def lookup_box(atlas, shapes: tuple, d: Float[Array, "... 3"], widths) -> Float[Array, "... C"]:
    """The mean of the map's bilinear interpolant over a box of ``widths = (wx, wy)`` texels
    of level 0 (..., 2) centred on the directions ``d``: the area average a camera's pixel
    takes of a map seen through its footprint (:func:`texel_footprint`).

    Along each axis the box's integral of the tent-interpolated texels is exact (the
    tent's antiderivative at the box's ends). A box wider than :data:`BOX_TEXELS` texels
    reads the first mip level where it is not (the level's texels average the map's, so
    the box is then widened by about half a texel of that level). Columns wrap, rows clamp,
    as :func:`lookup_uv`.

    References
    ----------
    F. C. Crow, "Summed-area tables for texture mapping", SIGGRAPH 1984 (box-filtered
    lookups); L. Williams, "Pyramidal parametrics", SIGGRAPH 1983 (the pyramid).
    """
    h0, w0 = shapes[0]
    wx = jnp.maximum(widths[..., 0], 1e-3)
    wy = jnp.maximum(widths[..., 1], 1e-3)
    # The level is chosen by the box's angular extent: a column's texel spans sin(theta)
    # times a row's angle (2 pi / W against pi / (H - 1)), so near a pole a box many
    # columns wide is small, and reading it at the level its column count asks for would
    # blur it along the rows by as much; there it reads the level its size asks for, and
    # the columns it spans beyond BOX_TEXELS of that level (directions closer together
    # than its rows) are left out.
    level = _box_level(shapes, d, wx, wy)
    hs = jnp.asarray([sh[0] for sh in shapes], dtype=jnp.int32)[level]
    ws = jnp.asarray([sh[1] for sh in shapes], dtype=jnp.int32)[level]
    offs = jnp.asarray(np.cumsum([0] + [sh[0] * sh[1] for sh in shapes[:-1]]), dtype=jnp.int32)[level]
    u, v = direction_to_uv(d)
    x = u * ws - 0.5
    y = v * (hs - 1)
    scale_x = ws / shapes[0][1]
    scale_y = (hs - 1) / (h0 - 1)
    cols, cw = _box_axis(x, jnp.minimum(wx * scale_x, BOX_TEXELS))
    rows, rw = _box_axis(y, jnp.minimum(wy * scale_y, BOX_TEXELS))
    cols = cols % ws[..., None]
    rows = jnp.clip(rows, 0, hs[..., None] - 1)
    texels = atlas[offs[..., None, None] + rows[..., :, None] * ws[..., None, None] + cols[..., None, :]]
    wts = rw[..., :, None] * cw[..., None, :]
    return jnp.einsum("...ij,...ijc->...c", wts, texels)


def texel_footprint(r: Float[Array, "N 3"], dr: Float[Array, "N 3 2"], height: int, width: int):
    """The widths (N, 2), in texels of a ``height x width`` map, of the box with the second
    moments of the parallelogram that the directions ``r + dr (s, t)``, ``s, t`` in
    ``[-1/2, 1/2]``, cover (:func:`lookup_box`): along each map axis
    ``sqrt(a^2 + b^2)`` for the parallelogram's sides ``a, b`` there (its variance is
    ``(a^2 + b^2) / 12``, a box's ``w^2 / 12``).

    ``u = atan2(x, -z) / 2 pi`` and ``v = acos(y) / pi`` (:func:`direction_to_uv`) move by
    ``du = (-z dx + x dz) / (2 pi (x^2 + z^2))`` and ``dv = -dy / (pi sqrt(1 - y^2))``; a
    box is at most the map's width (near the poles, where ``du`` grows without bound).
    """
    tx, ty = _texel_sides(r, dr, height, width)
    wx = jnp.sqrt(jnp.sum(tx**2, axis=-1))
    wy = jnp.sqrt(jnp.sum(ty**2, axis=-1))
    return jnp.stack([jnp.minimum(wx, width), jnp.minimum(wy, height)], axis=-1)


def _texel_sides(r: Float[Array, "N 3"], dr: Float[Array, "N 3 K"], height: int, width: int):
    """The sides ``dr[:, :, k]`` at ``r`` in texels of a ``height x width`` map: their
    columns ``du W`` and rows ``dv (H - 1)`` (each (N, K)), with ``du``, ``dv`` the
    differentials of :func:`direction_to_uv` (:func:`texel_footprint`)."""
    x, y, z = r[:, 0, None], r[:, 1, None], r[:, 2, None]
    rho2 = jnp.maximum(x * x + z * z, 1e-12)
    du = (-z * dr[:, 0] + x * dr[:, 2]) / (2 * jnp.pi * rho2)
    dv = -dr[:, 1] / (jnp.pi * jnp.sqrt(rho2))
    return du * width, dv * (height - 1)


#: Pieces :func:`lookup_parallelogram` cuts a footprint into along each side by default.
BOX_PROBES = 4


#: Longest footprint side, in texels of the level it reads, that one box reads as well as
#: its pieces whatever its orientation: the bilinear tent's own width, so that the box
#: spills past the footprint by less than the tent's reach.
SHORT_TEXELS = 1.0
#: The largest error :func:`pieces_needed` allows a cut coarser than the finest, in
#: texels^2 of the level read: a box's on a footprint :data:`SHORT_TEXELS` long diagonal
#: to the map's axes, ``SHORT_TEXELS^2 / 24`` (its correlation ``|A_x A_y| / 12`` with
#: ``|A_x| = |A_y| = SHORT_TEXELS / sqrt(2)``). Chosen among three on the development
#: case ref_drain_exp15_studio_persp (its misfit at the true parameters,
#: experiments/validation/truth_misfit.py): the tent's variance 1/6 left the rim's lamps
#: wider than the finest cut does.
SHORT_ERROR = SHORT_TEXELS**2 / 24.0


def piece_counts(probes: int, across: int) -> tuple[tuple[int, int], ...]:
    """The ways :func:`lookup_parallelogram` may cut a footprint, ``(along, across)``,
    cheapest first, each finer than the one before along both sides: one box, then
    ``2, 4, ...`` pieces along up to ``probes`` (one across), then ``2, 4, ...`` across up
    to ``across``."""
    rungs = [(1, 1)]
    for side, fixed in ((probes, None), (across, probes)):
        k = 2
        while k < side * 2:
            k = min(k, side)
            rungs.append((k, 1) if fixed is None else (fixed, k))
            k *= 2
    return tuple(dict.fromkeys(rungs))


def pieces_needed(shapes: tuple, r: Float[Array, "N 3"], dr: Float[Array, "N 3 2"],
                  rungs: tuple[tuple[int, int], ...]) -> Array:
    """For each footprint, the index into ``rungs`` (:func:`piece_counts`) of the fewest
    pieces that read it as well as the most: the first cut whose pieces' boxes read the
    same mip level as the finest cut's (:func:`_box_level`) and whose error is at most the
    finest cut's or a single box's on a footprint :data:`SHORT_TEXELS` long
    (:data:`SHORT_ERROR`, in texels of that level), whichever is larger.

    The error: a piece with sides ``A / p`` and ``B / q`` (in texels, :func:`_texel_sides`)
    has the covariance ``(A A^T / p^2 + B B^T / q^2) / 12``; the box of its second moments
    (:func:`texel_footprint`) has the same variances along the map's axes but no
    correlation, so for a map of Hessian ``H`` the box's mean differs from the piece's by
    ``-H_xy S_xy`` to second order, ``S_xy = (A_x A_y / p^2 + B_x B_y / q^2) / 12`` (the
    first order vanishes: both are centred on the piece). The mean of the pieces' boxes
    errs by the mean of theirs, which is the same for every piece. A box on the map's
    axes, or a footprint along one of them, has none; a diagonal one ``|A|^2 / 24``.

    References
    ----------
    F. C. Crow, "Summed-area tables for texture mapping", SIGGRAPH 1984 (the box);
    P. S. Heckbert, "Fundamentals of texture mapping and image warping", M.Sc. thesis,
    UC Berkeley 1989, sec. 3.5 (a filter's footprint by its second moments).
    """
    h0, w0 = shapes[0]
    long_first = jnp.sum(dr[..., 0] ** 2, axis=-1) >= jnp.sum(dr[..., 1] ** 2, axis=-1)
    ax, ay = _texel_sides(r, dr, h0, w0)
    (bx, by) = (jnp.where(long_first, ax[:, 1], ax[:, 0]), jnp.where(long_first, ay[:, 1], ay[:, 0]))
    (ax, ay) = (jnp.where(long_first, ax[:, 0], ax[:, 1]), jnp.where(long_first, ay[:, 0], ay[:, 1]))

    def cut(p, q):
        wx = jnp.minimum(jnp.sqrt((ax / p) ** 2 + (bx / q) ** 2), w0)
        wy = jnp.minimum(jnp.sqrt((ay / p) ** 2 + (by / q) ** 2), h0)
        return _box_level(shapes, r, wx, wy), jnp.abs(ax * ay / p**2 + bx * by / q**2) / 12.0

    level_top, err_top = cut(*rungs[-1])
    tolerance = jnp.maximum(err_top, SHORT_ERROR * 4.0 ** level_top)
    need = jnp.full(r.shape[:1], len(rungs) - 1, jnp.int32)
    for k in range(len(rungs) - 2, -1, -1):
        level, err = cut(*rungs[k])
        need = jnp.where((level <= level_top) & (err <= tolerance), k, need)
    return need


def lookup_parallelogram(atlas, shapes: tuple, r: Float[Array, "N 3"], dr: Float[Array, "N 3 2"],
                         probes: int = BOX_PROBES, across: int = BOX_PROBES) -> Float[Array, "N C"]:
    """The map's mean over the directions ``r + dr (s, t)``, ``s, t`` in ``[-1/2, 1/2]``:
    the parallelogram cut into up to ``probes`` equal pieces along its longer side (in
    angle, ``|dr[:, :, k]|``) and ``across`` along its shorter, each piece read by
    :func:`lookup_box` over the box of its second moments (:func:`texel_footprint`), and
    the pieces averaged (equal areas of a uniform distribution, so the mean of the
    pieces' means is the whole's).

    A single box reads a coarser mip level as soon as its longer axis passes
    :data:`BOX_TEXELS`, and that level's texels widen the shorter axis as well: a pixel
    near the bubble's rim or an internal bounce, whose footprint is many texels long and
    under one wide, then reads a source beside the line its rays sweep. Each piece is
    ``1/probes`` as long, so a footprint up to ``probes * BOX_TEXELS`` texels long is read
    at level 0 along its own width; and the box of a piece's second moments covers more
    than the piece wherever its sides are not the map's axes (a footprint diagonal to
    them, or sheared), by an error that shrinks with the square of the piece's size:
    ``probes x across`` pieces tile the parallelogram as the midpoint rule tiles a
    pixel's box.

    Each footprint is cut as few times as reads it as well (:func:`pieces_needed`: the
    same mip level, and an error no larger than the finest cut's or than one box's on a
    footprint a texel long); a short one, or one along the map's axes, is one box. The shapes being
    static, the footprints are sorted by the cut they need (:func:`piece_counts`) and
    each cut reads its own in :data:`CHUNKS` blocks of ``N / CHUNKS`` footprints, a
    block only where it holds some: a lookup costs about as many boxes as its
    footprints need, to a block per cut.

    References
    ----------
    J. McCormack, R. Perry, K. I. Farkas, N. P. Jouppi, "Feline: fast elliptical lines
    for anisotropic texture mapping", SIGGRAPH 1999 (probes along the footprint's major
    axis); F. C. Crow, "Summed-area tables for texture mapping", SIGGRAPH 1984 (each
    probe's box).
    """
    n = r.shape[0]
    rungs = piece_counts(probes, across)
    if len(rungs) == 1 or n < 2 * CHUNKS:
        return _pieces(atlas, shapes, r, dr, probes, across)
    need = jax.lax.stop_gradient(pieces_needed(shapes, r, dr, rungs))
    order = jnp.argsort(-need, stable=True)  # the finest cut first
    chunk = -(-n // CHUNKS)
    order = jnp.concatenate([order, jnp.full((chunk,), n, order.dtype)])  # a block's end past the last
    counts = jnp.sum(need[:, None] == jnp.arange(len(rungs))[None, :], axis=0)
    starts = jnp.cumsum(counts[::-1])[::-1] - counts  # cut k's first sorted position: the finer ones' count
    out = jnp.zeros((n, atlas.shape[-1]), atlas.dtype)
    for k, (p, q) in enumerate(rungs):
        def block(out, j, k=k, p=p, q=q):
            def read(out):
                pos = j * chunk + jnp.arange(chunk)
                idx = jax.lax.dynamic_slice(order, (starts[k] + j * chunk,), (chunk,))
                idx = jnp.where(pos < counts[k], idx, n)  # past this cut's own: dropped
                got = _pieces(atlas, shapes, jnp.take(r, idx, axis=0, mode="clip"),
                              jnp.take(dr, idx, axis=0, mode="clip"), p, q)
                return out.at[idx].set(got, mode="drop")

            return jax.lax.cond(j * chunk < counts[k], read, lambda o: o, out), None

        out, _ = jax.lax.scan(block, out, jnp.arange(CHUNKS))
    return out


#: Blocks a cut of :func:`lookup_parallelogram` reads its footprints in: it reads whole
#: blocks of ``N / CHUNKS`` footprints, so a lookup costs up to a block per cut more than
#: its footprints need (speed only).
CHUNKS = 16


def _pieces(atlas, shapes: tuple, r: Float[Array, "N 3"], dr: Float[Array, "N 3 2"],
            probes: int, across: int) -> Float[Array, "N C"]:
    """:func:`lookup_parallelogram` with every footprint cut into ``probes x across`` pieces
    (J. McCormack et al., "Feline", SIGGRAPH 1999: probes along the major axis; each
    piece's box as F. C. Crow's summed-area tables read one)."""
    h0, w0 = shapes[0]
    long_first = jnp.sum(dr[..., 0] ** 2, axis=-1) >= jnp.sum(dr[..., 1] ** 2, axis=-1)
    a = jnp.where(long_first[:, None], dr[..., 0], dr[..., 1])
    b = jnp.where(long_first[:, None], dr[..., 1], dr[..., 0])
    piece = jnp.stack([a / probes, b / across], axis=-1)
    total = 0.0
    for k in range(probes):
        for j in range(across):
            rk = r + ((k + 0.5) / probes - 0.5) * a + ((j + 0.5) / across - 0.5) * b
            rk = rk / jnp.sqrt(jnp.maximum(jnp.sum(rk * rk, axis=-1, keepdims=True), 1e-30))
            total = total + lookup_box(atlas, shapes, rk, texel_footprint(rk, piece, h0, w0))
    return total / (probes * across)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True, eq=False)
class EnvMap:
    """An environment map with what filtering needs precomputed.

    Attributes:
        pixels: (H, W, 3) linear radiance.
        atlas: the mip pyramid (level 0 = ``pixels``, each next halved) packed row-major
            into one (sum H_l W_l, 3) array, read with :func:`lookup_levels`.
        shapes: the (H_l, W_l) of each level (static).
        irradiance: (h, 2h, 3) irradiance table for the diffuse term.
    """

    pixels: Array
    atlas: Array
    irradiance: Array
    shapes: tuple = dataclasses.field(metadata=dict(static=True))

    @staticmethod
    def from_array(pixels, *, dtype=jnp.float32, sanitize: bool = True) -> "EnvMap":
        """Build from a linear (H, W, 3) array with W = 2H.

        With ``sanitize`` (default), NaN/Inf/negative texels are replaced by 0 so that a
        damaged map cannot poison every pixel through the filters.

        Examples
        --------
        >>> import numpy as np
        >>> import bubblefit as bf
        >>> env = bf.EnvMap.from_array(np.full((64, 128, 3), 0.25))
        >>> env.width, env.lookup(np.array([[0.0, 0.0, -1.0]])).tolist()
        (128, [[0.25, 0.25, 0.25]])
        """
        px = np.asarray(pixels, dtype=np.float64)
        if px.ndim != 3 or px.shape[2] != 3:
            raise ValueError(f"environment map must be (H, W, 3), got {px.shape}")
        if sanitize:
            px = np.where(np.isfinite(px), np.maximum(px, 0.0), 0.0)
        mips = build_mipmap(px)
        irr = irradiance_map(px)
        atlas = np.concatenate([m.reshape(-1, m.shape[2]) for m in mips])
        return EnvMap(
            pixels=jnp.asarray(px, dtype=dtype),
            atlas=jnp.asarray(atlas, dtype=dtype),
            irradiance=jnp.asarray(irr, dtype=dtype),
            shapes=tuple((m.shape[0], m.shape[1]) for m in mips),
        )

    @staticmethod
    def constant(value=1.0, height: int = 64, dtype=jnp.float32) -> "EnvMap":
        """A uniform environment (the white furnace for value = 1)."""
        val = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
        return EnvMap.from_array(np.broadcast_to(val, (height, 2 * height, 3)).copy(), dtype=dtype)

    @property
    def height(self) -> int:
        return self.pixels.shape[0]

    @property
    def width(self) -> int:
        return self.pixels.shape[1]

    @property
    def levels(self) -> int:
        return len(self.shapes)

    @property
    def texel_angle(self) -> float:
        """Angular size of one texel at the equator (radians)."""
        return math.pi / (self.height - 1)

    def level(self, i: int) -> Array:
        """Mip level ``i`` as an (H_i, W_i, 3) array (a static slice of the atlas)."""
        i = min(i, self.levels - 1)
        off = sum(h * w for h, w in self.shapes[:i])
        h, w = self.shapes[i]
        return self.atlas[off: off + h * w].reshape(h, w, -1)

    def lookup(self, d: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        return lookup(self.pixels, d)

    def lookup_level(self, d: Float[Array, "... 3"], level) -> Float[Array, "... 3"]:
        """Trilinear lookup at a continuous mip ``level`` (broadcast against ``d``)."""
        level = jnp.clip(level, 0.0, self.levels - 1.0)
        l0 = jnp.floor(level)
        frac = (level - l0)[..., None] if jnp.ndim(level) else level - l0
        l0 = l0.astype(jnp.int32)
        l1 = jnp.minimum(l0 + 1, self.levels - 1)
        a = lookup_levels(self.atlas, self.shapes, d, l0)
        b = lookup_levels(self.atlas, self.shapes, d, l1)
        return a * (1 - frac) + b * frac

    def lookup_box(self, d: Float[Array, "... 3"], widths) -> Float[Array, "... 3"]:
        """:func:`lookup_box`: the map averaged over boxes of ``widths`` texels (level 0)."""
        return lookup_box(self.atlas, self.shapes, d, widths)

    def lookup_parallelogram(self, r: Float[Array, "N 3"], dr: Float[Array, "N 3 2"],
                             probes: int = BOX_PROBES, across: int = BOX_PROBES) -> Float[Array, "N 3"]:
        """:func:`lookup_parallelogram`: the map averaged over the directions ``r + dr (s, t)``."""
        return lookup_parallelogram(self.atlas, self.shapes, r, dr, probes, across)

    def lookup_irradiance(self, n: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        return lookup(self.irradiance, n)


def dark_room() -> "EnvMap":
    """A black map (8 x 16 texels): a room dark but for the scene's own lights."""
    return EnvMap.from_array(np.zeros((8, 16, 3)))
