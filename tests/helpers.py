"""Shared problem builders and independent references for the tests.

Two kinds of helpers live here, both written without calling the package's own
implementation of the quantity they produce, so that a test comparing the package with
them compares two formulations:

* problem builders: small synthetic photos (a smooth backdrop, sensor noise and 8-bit
  sRGB quantisation), small environment maps with known content;
* references: the sRGB transfer functions (IEC 61966-2-1), the equirectangular map
  convention of docs/design.md (Mitsuba 3's), Fresnel reflectance (Hecht, Optics, 4.4),
  the incoherent film (Born & Wolf 7.6) and the Airy film (Born & Wolf 7.6.1), a mirror
  ball photographed by an orthographic camera, and the sensor's noise model.

Everything is numpy float64.
"""

from __future__ import annotations

import numpy as np

# --------------------------------------------------------------------------------------
# sRGB (IEC 61966-2-1)
# --------------------------------------------------------------------------------------


def srgb_to_linear(v):
    """IEC 61966-2-1 decoding of an sRGB value in [0, 1]."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x):
    """IEC 61966-2-1 encoding of a linear value in [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def srgb_decode_slope(v):
    """d(linear)/d(sRGB value) of :func:`srgb_to_linear`, differentiated by hand."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((v + 0.055) / 1.055) ** 1.4)


def sensor_sigma(linear, read: float, shot: float, bits: int | None):
    """Noise standard deviation of a pixel: read noise, shot noise ``shot * I`` in variance,
    and a uniform quantisation error of one code (variance step^2 / 12) carried to linear
    units through the sRGB slope."""
    i = np.clip(np.asarray(linear, dtype=np.float64), 0.0, None)
    var = read**2 + shot * i
    if bits:
        step = srgb_decode_slope(linear_to_srgb(i)) / (2**bits - 1)
        var = var + step**2 / 12.0
    return np.sqrt(var)


def block_average(a, k: int):
    """``a`` (H, W, ...) averaged over k x k blocks, the remainder rows and columns dropped."""
    a = np.asarray(a, dtype=np.float64)
    h, w = a.shape[0] // k, a.shape[1] // k
    return a[: h * k, : w * k].reshape(h, k, w, k, *a.shape[2:]).mean(axis=(1, 3))


# --------------------------------------------------------------------------------------
# Synthetic photos
# --------------------------------------------------------------------------------------


def smooth_backdrop(rng: np.random.Generator, size: int, lo: float = 0.15, hi: float = 0.6, blur: float = 2.5):
    """A smooth, textured background photo (size x size x 3, linear): uniform noise blurred."""
    from scipy import ndimage as ndi

    return ndi.gaussian_filter(rng.uniform(lo, hi, (size, size, 3)), (blur, blur, 0))


def quantise_8bit(img, rng: np.random.Generator, read: float = 0.003, shot: float = 1e-4):
    """Read and shot noise, 8-bit sRGB codes (IEC 61966-2-1), decoded back to linear."""
    img = np.asarray(img, dtype=np.float64)
    noisy = img + rng.normal(size=img.shape) * np.sqrt(read**2 + shot * np.clip(img, 0.0, None))
    return srgb_to_linear(np.round(linear_to_srgb(noisy) * 255) / 255)


def pinhole_ray(cam, i, j):
    """``(origin, unit direction)`` of a pinhole camera's ray through the centre of pixel
    row ``i``, column ``j``: looking from ``cam.origin`` at ``cam.target`` with +y up, the
    field of view ``cam.fov_deg`` across the width (a square image)."""
    import math

    o = np.asarray(cam.origin, float)
    fwd = np.asarray(cam.target, float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = math.tan(math.radians(cam.fov_deg) / 2)
    d = ((2 * (j + 0.5) / cam.width - 1) * t) * right + ((1 - 2 * (i + 0.5) / cam.height) * t) * up + fwd
    return o, d / np.linalg.norm(d)


def save_sensor_png(img, path, seed: int, full_well: float = 4000.0, read_e: float = 3.0):
    """A linear image (1 = full well) as an 8-bit sRGB PNG through a sensor: Poisson shot
    noise of ``full_well`` electrons at 1, Gaussian read noise of ``read_e`` electrons."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    electrons = rng.poisson(np.clip(img, 0, None) * full_well) + rng.normal(0.0, read_e, np.shape(img))
    Image.fromarray(np.round(linear_to_srgb(electrons / full_well) * 255).astype(np.uint8)).save(path)


def fit_scene_photo(img, folder, seed: int, timeout: float) -> dict:
    """Write ``img`` through the sensor of :func:`save_sensor_png` as ``folder/photo.png``,
    run ``bubblefit fit photo.png --scene folder/scene.toml`` in a subprocess, assert that
    it exits 0, and return its JSON."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    folder = Path(folder)
    save_sensor_png(img, folder / "photo.png", seed=seed)
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(folder / "photo.png"), "--scene",
                           str(folder / "scene.toml"), "--json", str(folder / "r.json")],
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr
    return json.loads((folder / "r.json").read_text())


#: The synthetic camera films of :func:`film_photo`: a 48 px orthographic view, its disc.
FILM_PHOTO_SIZE = 48
FILM_PHOTO_DISC = (FILM_PHOTO_SIZE / 2, FILM_PHOTO_SIZE / 2, 0.42 * FILM_PHOTO_SIZE)


def film_photo(env, thickness, seed: int, response: str = "srgb", illuminant: str = "D65",
               quantised: bool | int = True, noise: bool = True):
    """``(photo, background)``: a constant film of ``thickness`` nm (or a draining film,
    ``thickness = (top_nm, bottom_nm, exponent)``) over a smooth backdrop
    (:func:`smooth_backdrop`), rendered by bubblefit's ``render_scene`` (paper model, 48
    uniform spectral samples) through the camera ``response`` under ``illuminant``, then
    read and shot noise and, when ``quantised``, 8-bit sRGB codes (:func:`quantise_8bit`),
    or with ``quantised=16`` 16-bit linear codes; with ``noise`` False the noise-free
    renders, whose noise :func:`film_noise` draws.
    The one builder of the camera tests (tests/test_cameras.py) and experiments
    (wrong_camera.py, calibrated_camera.py, colour_check_null.py)."""
    from bubblefit.model.scene import Scene, render_scene

    rng = np.random.default_rng(seed)
    bg = smooth_backdrop(rng, FILM_PHOTO_SIZE)
    scene = Scene.from_dict({
        "camera": {"width": FILM_PHOTO_SIZE, "height": FILM_PHOTO_SIZE, "disc": list(FILM_PHOTO_DISC),
                   "response": response},
        "bubble": {"t": 0.972, "roughness": 0.08, "f": 0.3, **(
            {"thickness_nm": thickness} if np.isscalar(thickness) else
            {"thickness": dict(zip(("profile", "top_nm", "bottom_nm", "exponent"), ("drainage", *thickness)))})},
        "lighting": {"envmap": "unused.exr", "illuminant": illuminant},
        "effects": {"model": "paper", "transmission_tint": True, "spectral": {"method": "uniform", "samples": 48}},
    })
    img = np.asarray(render_scene(scene, bg, env=env), np.float64)
    if not noise:
        return img, bg
    return film_noise(img, rng, quantised), film_noise(bg, rng, quantised)


def kept_per_pixels(fn):
    """``fn(ys, xs)`` kept per pixel set: the colour check's parts repeat between noise
    draws of one photo, and their Jacobians with them."""
    kept = {}

    def get(ys, xs):
        key = (np.asarray(ys).tobytes(), np.asarray(xs).tobytes())
        if key not in kept:
            kept[key] = fn(ys, xs)
        return kept[key]

    return get


def film_noise(img, rng: np.random.Generator, quantised: bool | int = True):
    """:func:`film_photo`'s noise on a noise-free render ``img``: read and shot noise, then
    8-bit sRGB codes (``quantised`` True or 8), 16-bit linear codes (16) or none (False)."""
    if quantised is True or quantised == 8:
        return quantise_8bit(img, rng)
    noisy = img + rng.normal(size=img.shape) * np.sqrt(0.003**2 + 1e-4 * np.clip(img, 0.0, None))
    if quantised == 16:
        return np.round(np.clip(noisy, 0.0, 1.0) * 65535) / 65535
    return noisy


# --------------------------------------------------------------------------------------
# Equirectangular maps (docs/design.md, "Conventions": Mitsuba 3's)
# --------------------------------------------------------------------------------------


def direction_to_uv(d):
    """``u = atan2(x, -z) / (2 pi)`` in [0, 1) and ``v = acos(y) / pi`` of unit directions."""
    d = np.asarray(d, dtype=np.float64)
    u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return u, v


def uv_to_direction(u, v):
    """The unit direction at map coordinates (u, v): the inverse of :func:`direction_to_uv`."""
    phi, theta = np.broadcast_arrays(2 * np.pi * np.asarray(u, float), np.pi * np.asarray(v, float))
    return np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=-1)


def texel_centres(h: int, w: int):
    """Directions (H, W, 3) of the texel centres: column j at u = (j + 1/2) / W, row i at
    v = i / (H - 1) (row 0 the zenith, the last row the nadir)."""
    u = (np.arange(w) + 0.5) / w
    v = np.arange(h) / (h - 1)
    return uv_to_direction(u[None, :], v[:, None])


def texel_band_solid_angles(h: int, w: int, nodes: int = 16):
    """Solid angle (H,) of one texel per row, integrating ``sin(theta) d theta`` by
    Gauss-Legendre quadrature over the row's band ``theta in pi [i - 1/2, i + 1/2] / (H - 1)``
    (clipped to [0, pi]) times ``2 pi / W``."""
    x, wq = np.polynomial.legendre.leggauss(nodes)
    i = np.arange(h)
    a = np.clip((i - 0.5) / (h - 1), 0, 1) * np.pi
    b = np.clip((i + 0.5) / (h - 1), 0, 1) * np.pi
    theta = 0.5 * (b - a)[:, None] * x[None, :] + 0.5 * (a + b)[:, None]
    return 0.5 * (b - a) * (np.sin(theta) @ wq) * (2 * np.pi / w)


def equirect_lookup(pixels, d):
    """Bilinear lookup of an equirectangular map in unit directions ``d`` (..., 3): texel
    positions ``x = u W - 1/2`` (wrapping) and ``y = v (H - 1)`` (clamped)."""
    px = np.asarray(pixels, dtype=np.float64)
    h, w = px.shape[:2]
    u, v = direction_to_uv(d)
    x, y = u * w - 0.5, v * (h - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx = (x - x0)[..., None]
    fy = np.clip(y - y0, 0.0, 1.0)[..., None]
    xa, xb = np.mod(x0, w), np.mod(x0 + 1, w)
    return ((px[y0, xa] * (1 - fx) + px[y0, xb] * fx) * (1 - fy)
            + (px[y0 + 1, xa] * (1 - fx) + px[y0 + 1, xb] * fx) * fy)


def harmonic_map(h: int, w: int, a=(0.3, -0.2, 0.25), c=(1.0, 0.8, 0.6)):
    """A smooth map with a closed form: ``L(w) = c (1 + a . w)`` per channel, sampled at the
    texel centres (all positive for |a| < 1). Its irradiance is ``c (pi + 2 pi / 3 a . n)``."""
    dirs = texel_centres(h, w)
    return np.asarray(c, float)[None, None, :] * (1.0 + dirs @ np.asarray(a, float))[..., None]


def harmonic_radiance(d, a=(0.3, -0.2, 0.25), c=(1.0, 0.8, 0.6)):
    """The exact radiance of :func:`harmonic_map` in directions ``d``."""
    return np.asarray(c, float) * (1.0 + np.asarray(d, float) @ np.asarray(a, float))[..., None]


# --------------------------------------------------------------------------------------
# Films (Hecht, Optics, 4.4; Born & Wolf, Principles of Optics, 7.6)
# --------------------------------------------------------------------------------------


def fresnel_rs_rp(cos_i, n):
    """Power reflectance (..., 2) of one air/medium interface for s and p polarisation."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    sin_t = np.sqrt(np.maximum(1 - cos_i**2, 0.0)) / n
    cos_t = np.sqrt(1 - sin_t**2)
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (cos_t - n * cos_i) / (cos_t + n * cos_i)
    return np.stack([rs**2, rp**2], axis=-1)


def incoherent_slab(cos_i, n):
    """Reflectance and transmittance (..., 2) of a thin slab with incoherent internal
    bounces: the geometric series ``R = r + (1-r)^2 r / (1 - r^2) = 2 r / (1 + r)``."""
    r = fresnel_rs_rp(cos_i, n)
    return 2 * r / (1 + r), (1 - r) / (1 + r)


def airy_reflectance(cos_i, n, d_nm, lam_nm):
    """Coherent reflectance (..., 2) of a film of index n and thickness d in air (Airy's
    summation): ``R = F sin^2(delta/2) / (1 + F sin^2(delta/2))`` with ``F = 4 r / (1 - r)^2``
    and ``delta = 4 pi n d cos(theta_t) / lambda``."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    r = fresnel_rs_rp(cos_i, n)
    cos_t = np.sqrt(1 - (1 - cos_i**2) / n**2)
    delta = 4 * np.pi * n * np.asarray(d_nm, float) * cos_t / np.asarray(lam_nm, float)
    s2 = np.sin(0.5 * delta)[..., None] ** 2
    f = 4 * r / (1 - r) ** 2
    return f * s2 / (1 + f * s2)


# --------------------------------------------------------------------------------------
# Mirror ball
# --------------------------------------------------------------------------------------


def mirror_ball_photo(radiance, size: int, cx: float, cy: float, r: float, ss: int = 4, bg=0.0):
    """Photo (size x size x 3) of a perfect mirror sphere by an orthographic camera looking
    along -z, pixel centres at +1/2, ``ss x ss`` box samples per pixel.

    A sample at (x, y) = ((col - cx) / r, -(row - cy) / r) inside the unit disc hits the
    sphere where its normal is ``n = (x, y, sqrt(1 - x^2 - y^2))``; the camera ray
    ``(0, 0, -1)`` reflects into ``(2 x nz, 2 y nz, 2 nz^2 - 1)``, which reads
    ``radiance(direction)``. Outside the disc the photo is ``bg``.
    """
    acc = np.zeros((size, size, 3))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    for a in range(ss):
        for b in range(ss):
            x = (xx + (a + 0.5) / ss - cx) / r
            y = -(yy + (b + 0.5) / ss - cy) / r
            rho2 = x * x + y * y
            nz = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
            d = np.stack([2 * x * nz, 2 * y * nz, 2 * nz * nz - 1], axis=-1)
            acc += np.where((rho2 < 1.0)[..., None], radiance(d), bg)
    return acc / (ss * ss)


def mirror_ball_photo_perspective(radiance, size: int, cx: float, cy: float, r: float, distance: float,
                                  ss: int = 4, bg=0.0):
    """Like :func:`mirror_ball_photo` for a pinhole camera at ``distance`` ball radii on +z,
    looking along -z at the unit sphere; ``r`` is the outline's radius in pixels, so the
    focal length is ``r / tan(alpha)`` with ``sin(alpha) = 1 / distance`` (the tangent cone).
    Each ray ``o + s d`` meets the sphere at the smaller root of ``|o + s d|^2 = 1``."""
    f = r / np.tan(np.arcsin(1.0 / distance))
    o = np.array([0.0, 0.0, distance])
    acc = np.zeros((size, size, 3))
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    for a in range(ss):
        for b in range(ss):
            d = np.stack([(xx + (a + 0.5) / ss - cx) / f, -(yy + (b + 0.5) / ss - cy) / f,
                          -np.ones_like(xx)], axis=-1)
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
            bq = d @ o
            disc = bq**2 - (o @ o - 1.0)
            hit = disc > 0
            s_hit = -bq - np.sqrt(np.where(hit, disc, 0.0))
            n = o + s_hit[..., None] * d
            refl = d - 2 * np.sum(d * n, axis=-1, keepdims=True) * n
            acc += np.where(hit[..., None], radiance(refl), bg)
    return acc / (ss * ss)


def texel_mean_directions(h: int, w: int):
    """Solid-angle mean (H, W, 3) of the direction over each texel (not normalised): the
    band ``theta in pi [i - 1/2, i + 1/2] / (H - 1)`` (clipped to [0, pi]) times the column
    ``phi in 2 pi [j, j + 1] / W``, integrated in closed form:
    ``int sin^2 = theta / 2 - sin(2 theta) / 4``, ``int sin cos = sin^2(theta) / 2``."""
    i = np.arange(h)
    t0 = np.clip((i - 0.5) / (h - 1), 0, 1) * np.pi
    t1 = np.clip((i + 0.5) / (h - 1), 0, 1) * np.pi
    p0 = 2 * np.pi * np.arange(w) / w
    p1 = p0 + 2 * np.pi / w
    area = ((np.cos(t0) - np.cos(t1))[:, None] * (p1 - p0)[None, :])
    s2 = (0.5 * (t1 - t0) - 0.25 * (np.sin(2 * t1) - np.sin(2 * t0)))[:, None]
    sc = (0.5 * (np.sin(t1) ** 2 - np.sin(t0) ** 2))[:, None]
    x = s2 * (np.cos(p0) - np.cos(p1))[None, :]       # int sin(phi) = cos(p0) - cos(p1)
    y = sc * (p1 - p0)[None, :]
    z = -s2 * (np.sin(p1) - np.sin(p0))[None, :]      # int -cos(phi) = -(sin(p1) - sin(p0))
    return np.stack([x, y, z], axis=-1) / area[..., None]
