"""Cameras and ray-sphere geometry of a bubble: front and rear films and internal bounces.

A bubble is a sphere of centre ``c`` and radius ``R``. A camera ray ``o + s d`` that hits
it enters at the front film ``p0`` and meets the rear film at ``p1``; by the symmetry of
the chord, both hits (and every further internal bounce) see the film at the same
incidence angle, ``cos th = sqrt(b^2 - |o - c|^2 + R^2) / R`` with ``b = (o - c) . d``.

Cameras (docs/design.md): ``orthographic`` looks along -z; the bubble's disc has centre
``(cx, cy)`` and radius ``r`` in pixels. ``perspective`` has an origin, a target, an up
vector and a horizontal field of view ``fov_deg`` (Mitsuba's default axis).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "OrthographicCamera",
    "PerspectiveCamera",
    "DivergentCamera",
    "Hits",
    "intersect_sphere",
    "front_hits",
    "hit_pixels",
    "internal_bounce",
    "pixel_offsets",
    "gauss_offsets",
    "canonical_frame",
    "compose_shift",
    "slope_footprint",
    "disc_angles",
    "divergent_rays",
]


def pixel_offsets(samples_per_pixel: int) -> np.ndarray:
    """(S, 2) sub-pixel offsets (rows, columns) from the pixel centre for a box filter.

    ``S = s^2`` samples stratified over the pixel's box: the centres of an ``s x s`` grid,
    ``(k + 1/2) / s - 1/2`` for ``k = 0 .. s-1``, so that their mean is the box average a
    camera's pixel (and a renderer's box reconstruction filter) integrates. ``S = 1`` is
    the pixel centre.
    """
    s = math.isqrt(int(samples_per_pixel))
    if s < 1 or s * s != samples_per_pixel:
        raise ValueError(f"samples per pixel must be a square number (1, 4, 9, 16, ...), got {samples_per_pixel}")
    k = (np.arange(s) + 0.5) / s - 0.5
    dy, dx = np.meshgrid(k, k, indexing="ij")
    return np.stack([dy.ravel(), dx.ravel()], axis=-1)


def gauss_offsets(samples_per_pixel: int) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets (S, 2), weights (S,))`` of the ``s x s`` Gauss-Legendre product rule over
    the pixel's box (``S = s^2``): the nodes ``x_k / 2`` of the ``s``-point rule on
    ``[-1, 1]`` along rows and columns, the weights ``w_k w_l / 4`` (summing to 1). The
    weighted sum of the rays is the box average of a radiance that is a polynomial of
    degree ``2 s - 1`` in each axis, exactly (Abramowitz and Stegun, *Handbook of
    Mathematical Functions*, 25.4.29); :func:`pixel_offsets`' ``s x s`` stratified centres
    are exact to degree 1 and take ``1 - 1/s^2`` of the curvature term ``f'' h^2 / 24``.
    ``s = 2``: the nodes ``+-1 / (2 sqrt 3)``, equal weights.
    """
    s = math.isqrt(int(samples_per_pixel))
    if s < 1 or s * s != samples_per_pixel:
        raise ValueError(f"samples per pixel must be a square number (1, 4, 9, 16, ...), got {samples_per_pixel}")
    x, w = np.polynomial.legendre.leggauss(s)
    dy, dx = np.meshgrid(x / 2, x / 2, indexing="ij")
    return np.stack([dy.ravel(), dx.ravel()], axis=-1), np.outer(w, w).ravel() / 4


def slope_footprint(directions, rows: Array, cols: Array, n: Float[Array, "N 3"], wo: Float[Array, "N 3"],
                    samples_per_pixel=1) -> Float[Array, "N 3 2"]:
    """The pixel's footprint in the half vector's slope space: ``(N, 3, 2)``, the two
    tangent vectors ``J`` at each normal ``n`` along which the half vectors of the pixel's
    rays move from one side of the pixel (or sub-pixel) box to the other: the box's rays
    reflect into ``reflect(wo, n + J (u, v))``, ``u, v`` in ``[-1/2, 1/2]``, to first order.

    ``directions(rows, cols)`` returns the direction each film reads, ``reflect(wo, n)``
    (N, 3), for rays through the (continuous) pixel coordinates; its two derivatives
    ``dr/drow`` and ``dr/dcol`` are the ray differentials of Igehy (1999), taken here by
    forward-mode differentiation of the renderer's own rays, hits and internal bounces,
    so every camera and every film is covered by one rule. A reflected direction that
    moves by ``dr`` across the pixel is the mirror image of the viewer in a half vector
    ``h = normalize(wo + r)`` that moves by ``(I - n n^T) dr / (2 n.wo)`` (at the pixel's
    centre ``h = n`` and ``|wo + r| = 2 n.wo``). A sub-pixel ray of
    ``samples_per_pixel = s^2`` covers ``1/s`` of the pixel per axis:
    ``J = [dh/drow, dh/dcol] / s``. ``samples_per_pixel`` is one count for all rays, or
    each ray's own (N,), where a list mixes rays of pixels sampled differently.

    The footprint is a smoothing scale, not a parameter of the fit: it is returned
    through ``stop_gradient``, so a Jacobian does not differentiate it.

    References
    ----------
    H. Igehy, "Tracing ray differentials", SIGGRAPH 1999 (the reflected ray's
    differential); ``docs/design.md``, "Pixel footprints".
    """
    zero, one = jnp.zeros_like(rows), jnp.ones_like(rows)
    _, dr_row = jax.jvp(directions, (rows, cols), (one, zero))
    _, dr_col = jax.jvp(directions, (rows, cols), (zero, one))
    cos = jnp.sum(n * wo, axis=-1, keepdims=True)
    s = math.sqrt(samples_per_pixel) if np.isscalar(samples_per_pixel) else jnp.sqrt(samples_per_pixel)[:, None]
    scale = 1.0 / (2.0 * jnp.maximum(cos, 1e-3) * s)
    tangent = lambda v: (v - n * jnp.sum(n * v, axis=-1, keepdims=True)) * scale
    return jax.lax.stop_gradient(jnp.stack([tangent(dr_row), tangent(dr_col)], axis=-1))


@dataclass(frozen=True)
class OrthographicCamera:
    """Orthographic camera looking along -z at a bubble seen as a disc ``(cx, cy, r)`` pixels.

    Pixel ``(i, j)`` (row, column; centre at ``j + 1/2, i + 1/2``) shoots the ray with
    origin ``c + R ((j + 1/2 - cx)/r, -(i + 1/2 - cy)/r, 4)`` and direction ``(0, 0, -1)``.

    ``shift = (sx, sy, sr)`` (traced, in units of ``r``) moves the disc to
    ``(cx + sx r, cy + sy r)`` with radius ``r (1 + sr)``: how a fit refines a disc that
    was found to a fraction of a pixel (:mod:`bubblefit.inverse._parameters`).
    """

    width: int = 256
    height: int = 256
    cx: float | None = None
    cy: float | None = None
    r: float | None = None

    def disc(self) -> tuple[float, float, float]:
        cx = self.width / 2 if self.cx is None else self.cx
        cy = self.height / 2 if self.cy is None else self.cy
        r = 0.4 * min(self.width, self.height) if self.r is None else self.r
        return float(cx), float(cy), float(r)

    def rays(self, rows: Array, cols: Array, center, radius, shift=None, disc=None, view=0.0):
        """``(origins, direction)`` of the rays through pixels ``rows``, ``cols``; ``disc``
        (``(cx, cy, r)``, may be traced) stands for :meth:`disc`'s values. ``view`` (a
        :class:`DivergentCamera`'s divergence) is not read: parallel rays have none."""
        cx, cy, r = self.disc() if disc is None else disc
        x = (cols + 0.5 - cx) / r
        y = -(rows + 0.5 - cy) / r
        if shift is not None:
            x = (x - shift[0]) / (1.0 + shift[2])
            y = (y + shift[1]) / (1.0 + shift[2])
        o = jnp.stack([x, y, jnp.full_like(x, 4.0)], axis=-1) * radius + jnp.asarray(center)
        d = jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0], dtype=o.dtype), o.shape)
        return o, d


def canonical_frame(camera: OrthographicCamera, height: int, width: int):
    """``(canonical, base)``: an orthographic camera of ``height x width`` pixels whose disc
    depends on its size alone, and the shift ``base = (a, b, s)`` (float32) that moves its
    disc onto ``camera``'s, ``(cx, cy, r) = (cx0 + a r0, cy0 + b r0, s r0)``.

    A program compiled for ``canonical`` and given the shift as data renders every disc
    at this size (:func:`compose_shift`): a fit's compiled solves then serve every photo
    whose fit level pads to the same size, wherever its bubble lies.
    """
    canonical = OrthographicCamera(width, height, width / 2, height / 2, 0.4 * min(width, height))
    (cx, cy, r), (cx0, cy0, r0) = camera.disc(), canonical.disc()
    return canonical, np.asarray([(cx - cx0) / r0, (cy - cy0) / r0, r / r0], np.float32)


def compose_shift(base, shift):
    """The shift (:meth:`OrthographicCamera.rays`) that moves a camera's disc by ``base``
    and then by ``shift`` (in units of the disc ``base`` reached): with ``base = (a, b, s)``,
    ``(a + s sx, b + s sy, s (1 + sr) - 1)``. Rays through the same pixel are the same."""
    xp = np if isinstance(base, np.ndarray) and isinstance(shift, np.ndarray) else jnp
    return xp.stack([base[0] + base[2] * shift[0], base[1] + base[2] * shift[1], base[2] * (1.0 + shift[2]) - 1.0])


@dataclass(frozen=True)
class PerspectiveCamera:
    """Pinhole camera with a horizontal field of view (Mitsuba's ``fov_axis = "x"``)."""

    width: int = 256
    height: int = 256
    origin: tuple = (0.0, 0.0, 4.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: float = 35.0

    def basis(self):
        o = np.asarray(self.origin, dtype=np.float64)
        fwd = np.asarray(self.target, dtype=np.float64) - o
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(self.up, dtype=np.float64))
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return o, fwd, right, up

    def rays(self, rows: Array, cols: Array, center=None, radius=None, view=0.0):
        """``(origin, directions)`` of the pinhole's rays through pixels ``rows``, ``cols``;
        ``view`` (a :class:`DivergentCamera`'s divergence) is not read: the pinhole's field
        of view is its own."""
        o, fwd, right, up = self.basis()
        tan_half = math.tan(math.radians(self.fov_deg) / 2)
        x = (2 * (cols + 0.5) / self.width - 1) * tan_half
        y = (1 - 2 * (rows + 0.5) / self.height) * tan_half * self.height / self.width
        d = x[..., None] * right + y[..., None] * up + fwd
        d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
        return jnp.broadcast_to(jnp.asarray(o, dtype=d.dtype), d.shape), d


def _atan_over(z, xp):
    """``atan(z) / z``, 1 at ``z = 0`` (smooth there: its series ``1 - z^2/3``)."""
    small = xp.abs(z) < 1e-3
    zs = xp.where(small, 1.0, z)
    return xp.where(small, 1.0 - z * z / 3.0, xp.arctan(zs) / zs)


def _sin_over(z, xp):
    """``sin(z) / z``, 1 at ``z = 0`` (series ``1 - z^2/6``)."""
    small = xp.abs(z) < 1e-3
    zs = xp.where(small, 1.0, z)
    return xp.where(small, 1.0 - z * z / 6.0, xp.sin(zs) / zs)


def _disc_scaled(rho, r, g, xp):
    """``(theta / g, alpha / g)`` of :func:`disc_angles`: finite and smooth through ``g = 0``,
    where they are ``(rho, r)``."""
    a = r
    for _ in range(3):
        sp, sm = (rho + a) * _atan_over((rho + a) * g, xp), (rho - a) * _atan_over((rho - a) * g, xp)
        th, al = (sp + sm) / 2.0, (sp - sm) / 2.0
        ratio = xp.sqrt(xp.maximum(xp.cos(th * g) ** 2 - xp.sin(al * g) ** 2, 1e-12)) / xp.cos(al * g)
        a = 2.0 * r / (1.0 + ratio)
    return th, al


def disc_angles(rho, r, g, xp=np):
    """``(theta, alpha)``: the direction of a sphere's centre off the optical axis and the
    half-angle it subtends (radians), seen through a pinhole of inverse focal length ``g``
    (1/pixels) as a disc of radius ``r`` whose centre lies ``rho`` pixels from the principal
    point: :func:`~bubblefit.capture.view.outline_axes` inverted in closed form (:func:`~bubblefit.capture.view.perspective_from_disc`
    gives the steps). ``xp``: ``numpy`` or ``jax.numpy`` (differentiable in ``g``).

    References
    ----------
    R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2004,
    sec. 8.3 (the outline's cone); I. Kasa, IEEE Trans. Instrum. Meas. 25(1), 1976.
    """
    th, al = _disc_scaled(rho, r, g, xp)
    return th * g, al * g


def divergent_rays(u, disc: tuple, width: int, height: int, rows, cols, xp=None):
    """``(origins, directions)`` of the rays through pixels ``rows``, ``cols`` of a
    ``width x height`` photo whose view has the divergence ``u = tan(fov/2)``
    (:func:`~bubblefit.capture.view.divergence`), the sphere (radius 1 at the origin) seen as ``disc``: smooth in
    ``u`` through the orthographic view (``u = 0``), where they are
    :class:`OrthographicCamera`'s rays.

    For ``u > 0`` the rays are those of :func:`~bubblefit.capture.view.perspective_from_disc`'s pinhole, each
    origin moved along its ray to 4 radii before the ray's closest approach to the
    sphere's centre. With ``g = 2u / W`` (the inverse focal length in pixels), a pixel's
    direction is ``d = (q g, -1) / |(q g, -1)|`` (``q``: its offset from the principal
    point, +y up) and the pinhole lies at ``-D c`` (``c = (sin theta e, -cos theta)``
    toward the centre, ``D = 1 / sin alpha``, :func:`disc_angles`), so the moved origin is
    ``-(c - (c.d) d) / sin alpha - 4 d``. Written with ``theta / g``, ``alpha / g`` and
    ``sin(x)/x`` every term is finite at ``g = 0``, where it is ``((q - rho e) / r, 4)``,
    the orthographic ray's origin. ``xp``: ``numpy`` or ``jax.numpy`` (default), which
    differentiates through ``u``.

    References
    ----------
    R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2004,
    sec. 6.1 (the pinhole; the orthographic camera as its limit at infinity, sec. 6.3).
    """
    xp = jnp if xp is None else xp
    cx, cy, r = (float(v) for v in disc)
    g = 2.0 * u / width
    ux, uy = cx - width / 2.0, height / 2.0 - cy
    rho = math.hypot(ux, uy)
    ex, ey = (ux / rho, uy / rho) if rho > 0 else (1.0, 0.0)
    th_g, al_g = _disc_scaled(rho, r, g, xp)
    th = th_g * g
    s_al = al_g * _sin_over(al_g * g, xp)  # sin(alpha) / g
    s_th = th_g * _sin_over(th_g * g, xp)  # sin(theta) / g
    qx = xp.asarray(cols, dtype=float) + 0.5 - width / 2.0
    qy = height / 2.0 - (xp.asarray(rows, dtype=float) + 0.5)
    n = xp.sqrt(1.0 + g * g * (qx * qx + qy * qy))
    d = xp.stack([qx * g / n, qy * g / n, -xp.ones_like(qx) / n], axis=-1)
    cd = (s_th * g * g * (ex * qx + ey * qy) + xp.cos(th)) / n  # c . d
    # (c - (c.d) d) / sin(alpha), term by term divided by g
    px = (s_th * ex - cd * qx / n) / s_al
    py = (s_th * ey - cd * qy / n) / s_al
    pz = (-xp.cos(th) * g * (qx * qx + qy * qy) + s_th * g * (ex * qx + ey * qy)) / (n * n) / s_al
    origins = -xp.stack([px, py, pz], axis=-1) - 4.0 * d
    return origins, d


@dataclass(frozen=True)
class DivergentCamera:
    """The camera of a photo whose view's divergence ``u = tan(fov/2)`` is a parameter:
    the rays of :func:`divergent_rays` for the bubble seen as the disc ``(cx, cy, r)``
    pixels, with ``u`` passed to :meth:`rays` as data (``Params.view``). At ``u = 0`` they
    are :class:`OrthographicCamera`'s rays; for ``u > 0``, those of the pinhole that
    :func:`~bubblefit.capture.view.perspective_from_disc` builds for the field of view
    ``2 atan(u)``, so one compiled program renders every view of the photo.

    References
    ----------
    R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2004,
    sec. 6.1 and 6.3 (the pinhole and its orthographic limit).
    """

    width: int
    height: int
    cx: float
    cy: float
    r: float

    def disc(self) -> tuple[float, float, float]:
        return float(self.cx), float(self.cy), float(self.r)

    def rays(self, rows: Array, cols: Array, center, radius, view=0.0):
        """``(origins, directions)`` of the rays through pixels ``rows``, ``cols`` of the view
        of divergence ``view`` (may be traced), for the sphere of ``center`` and ``radius``."""
        o, d = divergent_rays(view, self.disc(), self.width, self.height, rows, cols)
        return o * radius + jnp.asarray(center, dtype=o.dtype), d


@jax.tree_util.register_dataclass
@dataclass
class Hits:
    """Ray-sphere hits for a batch of rays (all arrays have a leading axis N); a pytree,
    so that traced rays can be kept between programs (:func:`~bubblefit.model.render.trace_pixels`).

    Attributes:
        inside: (N,) True where the ray hits the bubble.
        cos: (N,) cosine of the incidence angle on the films (the same at every hit).
        p0, n0: front hit point and outward normal.
        p1, n1: rear hit point and outward normal.
        d: (N, 3) ray direction (the background direction).
        local0, local1: front/rear hit points relative to the centre over the radius.
    """

    inside: Array
    cos: Array
    p0: Array
    n0: Array
    p1: Array
    n1: Array
    d: Array
    local0: Array
    local1: Array


def intersect_sphere(o: Float[Array, "N 3"], d: Float[Array, "N 3"], center, radius) -> Hits:
    """Both intersections of rays with the bubble's sphere, safe for rays that miss it.

    Rays that miss (or graze) get ``inside = False``, ``cos = 0`` and the hit points of the
    closest approach, so every output stays finite and differentiable.
    """
    c = jnp.asarray(center, dtype=o.dtype)
    oc = o - c
    b = jnp.sum(oc * d, axis=-1)
    disc = b * b - (jnp.sum(oc * oc, axis=-1) - radius * radius)
    inside = disc > 0
    root = jnp.sqrt(jnp.where(inside, disc, 1.0))
    root = jnp.where(inside, root, 0.0)
    s0 = -b - root
    s1 = -b + root
    p0 = o + s0[:, None] * d
    p1 = o + s1[:, None] * d
    local0 = (p0 - c) / radius
    local1 = (p1 - c) / radius
    cos = jnp.clip(root / radius, 0.0, 1.0)
    return Hits(inside=inside, cos=cos, p0=p0, n0=local0, p1=p1, n1=local1, d=d, local0=local0, local1=local1)


def front_hits(camera, center: tuple, radius: float, view: float = 0.0):
    """``(inside, cos, local0)`` of :func:`intersect_sphere` for the ray through every pixel
    centre of ``camera`` (row-major, ``height x width`` rays). An orthographic camera's disc,
    a divergent camera's view ``view`` (its divergence ``u = tan(fov/2)``,
    :class:`DivergentCamera`), the centre and the radius are the program's data, so that
    one program serves every disc of a size (a fit's levels, each photo's own disc) and
    every view of a divergent camera."""
    disc = None
    if isinstance(camera, OrthographicCamera):
        disc = jnp.asarray(camera.disc(), jnp.float32)
        camera = OrthographicCamera(camera.width, camera.height)
    return _front_hits(camera, disc, jnp.asarray(center, jnp.float32), jnp.asarray(radius, jnp.float32),
                       jnp.asarray(view, jnp.float32))


@functools.partial(jax.jit, static_argnames=("camera",))
def _front_hits(camera, disc, center, radius, view):
    rows, cols = jnp.divmod(jnp.arange(camera.height * camera.width), camera.width)
    rows, cols = rows.astype(jnp.float32), cols.astype(jnp.float32)
    o, d = camera.rays(rows, cols, center, radius, disc=disc) if disc is not None else \
        camera.rays(rows, cols, center, radius, view=view)
    hits = intersect_sphere(o, jnp.broadcast_to(d, o.shape), center, radius)
    return hits.inside, hits.cos, hits.local0


@functools.lru_cache(maxsize=8)
def hit_pixels(camera, center: tuple, radius: float, view: float = 0.0) -> np.ndarray:
    """Flat indices (numpy) of the pixels whose centre ray hits the sphere (:func:`front_hits`,
    through a divergent camera's view ``view``), kept per camera: the footprint of ``auto``
    and the renderer's regions read the same set."""
    idx = np.flatnonzero(np.asarray(front_hits(camera, center, radius, view)[0]))
    idx.flags.writeable = False
    return idx


def internal_bounce(p: Float[Array, "N 3"], e: Float[Array, "N 3"], center, radius):
    """Follow a ray inside the sphere from ``p`` (on the sphere) along ``e`` to its next hit
    ``q`` and reflect it there: returns ``(q, reflected direction, unit local position of q)``.

    The chord length is ``-2 (p - c) . e``; the reflection about the inward normal keeps
    the same incidence angle, the property the ``physical`` compositing relies on.
    """
    c = jnp.asarray(center, dtype=p.dtype)
    pc = p - c
    q = p + (-2.0 * jnp.sum(pc * e, axis=-1))[:, None] * e
    # Re-project onto the sphere: without it rounding errors grow geometrically over many
    # bounces (a non-unit normal scales the reflected direction) and end in inf/NaN.
    qc = q - c
    nq = qc / jnp.sqrt(jnp.maximum(jnp.sum(qc * qc, axis=-1, keepdims=True), 1e-30))
    q = c + radius * nq
    e2 = e - 2.0 * jnp.sum(e * nq, axis=-1)[:, None] * nq
    return q, e2, nq
