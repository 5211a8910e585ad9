"""Pixel footprints (bubblefit.model.geometry.slope_footprint): the ray differentials of the
films' reflected directions, and the glint they integrate.

References written independently of the package:

- the footprint against a central finite difference of camera rays traced here in numpy
  (the cameras of docs/design.md's conventions, a ray-sphere intersection, a mirror
  reflection), for an orthographic and a perspective camera, the front and rear films
  and the physical model's first internal bounce; and, for the orthographic front film,
  against the sphere's closed form ``J = dn/dpixel`` (the view direction is fixed, so the
  half vector of the pixel's rays is their normal);
- the glint of a small bright patch of the map in a mirror sphere against the closed form
  of its flux: an orthographic mirror sphere of radius ``r`` pixels maps solid angle to
  image area uniformly, ``dA = r^2 / 4 dOmega`` (``rho = r sin th``, reflection angle
  ``2 th``: ``dA = r^2 sin th cos th dth dphi`` and ``dOmega = 4 sin th cos th dth dphi``),
  so the glint's summed pixels are ``r^2 / 4 r_s cos th_s int L dOmega`` at every
  resolution.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bubblefit.lighting.envmap import EnvMap
from bubblefit.lighting.filtering import FilterConfig
from bubblefit.model.effects import Effects
from bubblefit.model.geometry import OrthographicCamera, PerspectiveCamera, intersect_sphere
from bubblefit.model.render import Params, RenderConfig, film_footprints, render, shading_points


# --- numpy reference: cameras, sphere hits, reflections --------------------------------

def _ortho_ray(cam, row, col, radius=1.0):
    cx, cy, r = cam.cx, cam.cy, cam.r
    o = np.array([(col + 0.5 - cx) / r, -(row + 0.5 - cy) / r, 4.0]) * radius
    return o, np.array([0.0, 0.0, -1.0])


def _persp_ray(cam, row, col, radius=1.0):
    o = np.asarray(cam.origin, float)
    f = np.asarray(cam.target, float) - o
    f /= np.linalg.norm(f)
    right = np.cross(f, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    t = math.tan(math.radians(cam.fov_deg) / 2)
    x = (2 * (col + 0.5) / cam.width - 1) * t
    y = (1 - 2 * (row + 0.5) / cam.height) * t * cam.height / cam.width
    d = x * right + y * up + f
    return o, d / np.linalg.norm(d)


def _reflect(d, n):
    return d - 2 * np.dot(d, n) * n


def _hits(o, d):
    b = np.dot(o, d)
    return b * b - (np.dot(o, o) - 1.0) > 0.05


def _films(o, d):
    """(normal, direction to the viewer) of the front film, the paper model's rear film and
    the first internal bounce of a unit sphere at the origin, traced in float64."""
    b = np.dot(o, d)
    root = math.sqrt(b * b - (np.dot(o, o) - 1.0))
    p0, p1 = o + (-b - root) * d, o + (-b + root) * d
    front = (p0, -d)
    rear = (-p1, -d)
    # the physical model's first internal bounce reflects the ray arriving along d at the
    # rear film, about its inward normal: the paper's rear film seen from inside
    return {"front": front, "rear": rear, "bounce1": (-p1, -d)}


def _lookup_dir(film):
    n, wo = film
    return _reflect(-wo, n)


def _numeric_footprint(ray, cam, row, col, name, h=1e-4):
    """``(I - n n^T) dr / (2 n.wo)`` per pixel axis by central differences of the reflected
    direction ``r`` that film ``name`` reads."""
    film = lambda dr_, dc_: _films(*ray(cam, row + dr_, col + dc_))[name]
    n, wo = film(0, 0)
    cols = []
    for dr_, dc_ in ((1, 0), (0, 1)):
        g = (_lookup_dir(film(dr_ * h, dc_ * h)) - _lookup_dir(film(-dr_ * h, -dc_ * h))) / (2 * h)
        cols.append((g - n * np.dot(n, g)) / (2 * np.dot(n, wo)))
    return np.stack(cols, axis=-1)


def _package_footprint(cam, fx, rows, cols):
    cfg = RenderConfig(effects=fx, camera=cam, pixel_footprint=True)
    p = Params.make()

    def rays(r, c):
        if isinstance(cam, OrthographicCamera):
            o, d = cam.rays(r, c, cfg.center, cfg.radius, p.disc)
        else:
            o, d = cam.rays(r, c, cfg.center, cfg.radius)
        return o, jnp.broadcast_to(d, o.shape)

    names = []

    def footprints(r, c):
        o, d = rays(r, c)
        films, _ = shading_points(fx, cfg, intersect_sphere(o, d, cfg.center, cfg.radius), d)
        names[:] = [f[0] for f in films]
        return film_footprints(fx, cfg, rays, r, c, films)

    # compiled, as the renderer runs it (eagerly, each operation would compile on its own)
    fp = np.asarray(jax.jit(footprints)(jnp.asarray(rows, jnp.float32), jnp.asarray(cols, jnp.float32)))
    return {name: fp[k * len(rows):(k + 1) * len(rows)] for k, name in enumerate(names)}


CAMERAS = {
    "orthographic": (OrthographicCamera(64, 64, 31.3, 33.1, 24.6), _ortho_ray),
    "perspective": (PerspectiveCamera(64, 48, (0.3, 0.2, 4.5), (0.0, 0.1, 0.0), fov_deg=30.0), _persp_ray),
}
# pixels inside the disc of both cameras, from near the centre to near the rim
PIXELS = [(32, 32), (20, 41), (40, 14), (26, 50), (12, 30)]


@pytest.mark.parametrize("camera", sorted(CAMERAS))
@pytest.mark.parametrize("model,names", [("paper", ("front", "rear")), ("physical", ("front", "bounce1"))])
def test_footprint_is_the_finite_difference_of_the_camera_rays(camera, model, names):
    cam, ray = CAMERAS[camera]
    fx = Effects(model=model, bounces=1 if model == "physical" else 0)
    rows, cols = np.array(PIXELS).T
    assert all(_hits(*ray(cam, r, c)) for r, c in PIXELS)
    got = _package_footprint(cam, fx, rows, cols)
    for name in names:
        want = np.stack([_numeric_footprint(ray, cam, r, c, name) for r, c in PIXELS])
        scale = np.abs(want).max()
        # float32 rays against float64 central differences: a few 1e-4 of the footprint
        np.testing.assert_allclose(got[name], want, atol=2e-3 * scale, err_msg=f"{camera} {model} {name}")
        assert scale > 1e-3  # not vacuous: a pixel spans a visible angle


def test_orthographic_front_footprint_is_the_normals_derivative():
    cam = CAMERAS["orthographic"][0]
    rows, cols = np.array(PIXELS).T
    got = _package_footprint(cam, Effects(model="paper", rear_reflection=False), rows, cols)["front"]
    x = (cols + 0.5 - cam.cx) / cam.r
    y = -(rows + 0.5 - cam.cy) / cam.r
    z = np.sqrt(1 - x * x - y * y)
    # n = (x, y, z): d/dcol = (1, 0, -x/z) / r, d/drow = (0, -1, y/z) / r
    want_col = np.stack([np.ones_like(x), np.zeros_like(x), -x / z], axis=-1) / cam.r
    want_row = np.stack([np.zeros_like(x), -np.ones_like(x), y / z], axis=-1) / cam.r
    np.testing.assert_allclose(got[..., 1], want_col, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(got[..., 0], want_row, rtol=1e-4, atol=1e-6)


def _sun_map(h=128, value=400.0, angle_deg=47.0):
    """A black map with a 2 x 2 texel patch of ``value`` on the equator, ``angle_deg`` from
    +z towards +x, and the patch's ``int L dOmega`` (the bilinear interpolant of a patch
    integrates to the texels' sum times a texel's area, its rows' solid angles)."""
    w = 2 * h
    px = np.zeros((h, w, 3))
    u = math.atan2(math.sin(math.radians(angle_deg)), -math.cos(math.radians(angle_deg))) / (2 * math.pi)
    col = int(round(u * w - 0.5))
    rows = [h // 2 - 1, h // 2]  # around v = 1/2
    px[rows[0]:rows[1] + 1, col:col + 2] = value
    th = np.pi * np.array(rows) / (h - 1)  # the rows' polar angles, texel centres
    flux = value * 2 * sum(np.sin(th)) * (np.pi / (h - 1)) * (2 * np.pi / w)
    return px, flux


def test_glint_flux_is_independent_of_the_resolution():
    px, flux = _sun_map()
    env = EnvMap.from_array(px)
    th_s = math.radians(47.0) / 2  # the normal halfway between the view (+z) and the sun
    r_s = 0.02
    fx = Effects(model="paper", rear_reflection=False, transmission=False, interference="off", diffuse=False,
                 filtering=FilterConfig("mirror"))
    p = Params.make(r_s=r_s, r_d=0.0, roughness=0.0)
    want = r_s * math.cos(th_s) * flux / 4  # summed pixels per square pixel of disc radius
    for size in (40, 64, 100):
        # disc radius 16, 25.6 and 40 px: a pixel's reflection spans 5, 3.2 and 2 texels
        cam = OrthographicCamera(size, size, size / 2 + 0.17, size / 2 - 0.31, 0.4 * size)
        img = np.asarray(render(p, RenderConfig(effects=fx, camera=cam, pixel_footprint=True), env))[..., 0]
        point = np.asarray(render(p, RenderConfig(effects=fx, camera=cam, pixel_footprint=False), env))[..., 0]
        # the closed form holds to the patch rows' solid angles (1e-4) and the mirror's
        # cos th_r across the patch (1e-3); the box of second moments that stands for the
        # pixel's parallelogram in 4 x 4 pieces
        # measured 0.2-0.3 % here
        assert img.sum() / cam.r**2 == pytest.approx(want, rel=0.015), size
        # not vacuous: one ray per pixel misses or hits the patch (x 4.0, 1.55, 0.81)
        assert abs(point.sum() / cam.r**2 / want - 1) > 0.15, size
        if size >= 64:
            # and pixel by pixel it is the box average a camera takes (64 rays per pixel;
            # measured 1.6 % and 0.8 % RMS of the glint, the single ray 91 % and 37 %)
            boxed = np.asarray(render(p, RenderConfig(effects=fx, camera=cam, samples_per_pixel=64,
                                                      pixel_footprint=False), env))[..., 0]
            assert np.sqrt(np.mean((img - boxed) ** 2) / np.mean(boxed**2)) < 0.03, size


# --- the footprint's lookup at the rim against the pixel's own rays -------------------

STUDIO = Path(__file__).resolve().parents[1] / "experiments" / "validation" / "data"


def _bilinear(px, d):
    """The equirectangular map's bilinear interpolant at unit directions ``d`` (..., 3),
    in numpy: ``u = atan2(x, -z) / 2 pi``, ``v = acos(y) / pi``, texel centres at
    ``((j + 1/2) / W, i / (H - 1))``, columns wrapping, rows clamped."""
    h, w = px.shape[:2]
    u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    x, y = u * w - 0.5, v * (h - 1)
    x0 = np.floor(x)
    y0 = np.clip(np.floor(y), 0, h - 2)
    fx, fy = (x - x0)[..., None], np.clip(y - y0, 0.0, 1.0)[..., None]
    x0, y0 = x0.astype(int) % w, y0.astype(int)
    x1, y1 = (x0 + 1) % w, y0 + 1
    return (px[y0, x0] * (1 - fx) + px[y0, x1] * fx) * (1 - fy) + (px[y1, x0] * (1 - fx) + px[y1, x1] * fx) * fy


def _bounce_directions(cam, rows, cols, bounces):
    """The directions the front film and the first ``bounces`` internal bounces of a unit
    sphere at the origin read (the mirror images of the arriving ray), per pixel, in numpy."""
    out = {f"bounce{k}": [] for k in range(1, bounces + 1)}
    out["front"] = []
    for r, c in zip(rows, cols):
        o, d = _persp_ray(cam, r, c)
        b = np.dot(o, d)
        root = math.sqrt(b * b - (np.dot(o, o) - 1.0))
        p0, q = o + (-b - root) * d, o + (-b + root) * d
        out["front"].append(_reflect(d, p0))
        e = d
        for k in range(1, bounces + 1):
            e = _reflect(e, q)
            out[f"bounce{k}"].append(e)
            q = q - 2 * np.dot(q, e) * e  # the chord to the next hit
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("method,block", [("mirror", 1), ("mirror", 2), ("mipmap", 2)])
def test_rim_footprint_reads_what_the_pixels_rays_read(method, block):
    """At the rim of the studio drainage case (a black map with compact lamps), each film's
    footprint lookup against 16 stratified rays per pixel traced here: the summed absolute
    difference over the pixels between 0.9 and 0.96 of the disc's radius must stay within
    the 16 rays' own sampling error, ``sum_i s_i / 4`` (``s_i`` the standard deviation of
    pixel ``i``'s 16 samples; a stratified estimate errs less than 16 independent ones, and
    a mean error of ``|N(0, s/4)|`` is 0.8 s/4), at the photo's resolution and at the 2 x 2
    blocks of a fit's last level (``block``), where each pixel's footprint is twice as
    long. One box per footprint, which reads a footprint longer than 4 texels at a coarser
    mip level and so widens it across its width to the lamps beside it, errs by 1.9 and 2.3
    times that at the mirror's second bounce (the spread of the 16 rays' directions is the
    footprint's to 0.3 % at these pixels: the differential itself is right). The
    ``mipmap`` lookup's 4 x 4 cells of the footprint guard the fit's level."""
    from bubblefit.lighting.filtering import specular
    from bubblefit.model.geometry import pixel_offsets
    from bubblefit.model.scene import read_envmap

    case = STUDIO / "ref_drain_exp15_studio_persp"
    truth = json.loads((case / "truth.json").read_text())
    c = truth["camera"]
    cam = PerspectiveCamera(c["width"] // block, c["height"] // block, tuple(c["origin"]), tuple(c["target"]),
                            tuple(c["up"]), c["fov_deg"])
    env = read_envmap(STUDIO / truth["envmap"])
    px = np.asarray(env.pixels, np.float64)
    disc = truth["disc"]
    ii, jj = np.mgrid[0:cam.height, 0:cam.width]
    rho = np.hypot(jj + 0.5 - disc["cx"] / block, ii + 0.5 - disc["cy"] / block) / (disc["r"] / block)
    rows, cols = ii[(rho > 0.9) & (rho < 0.96)], jj[(rho > 0.9) & (rho < 0.96)]
    fx = Effects(model="physical", bounces=2, filtering=FilterConfig(method, nodes=4))
    cfg = RenderConfig(effects=fx, camera=cam, pixel_footprint=True)

    def looked_up(r, c_):
        o, d = cam.rays(r, c_)
        films, _ = shading_points(fx, cfg, intersect_sphere(o, d, cfg.center, cfg.radius), d)
        fp = film_footprints(fx, cfg, lambda a, b: cam.rays(a, b), r, c_, films)
        n, wo = jnp.concatenate([f[1] for f in films]), jnp.concatenate([f[2] for f in films])
        return specular(env, n, wo, 0.0, fx.filtering, normalize=True, footprint=fp)

    got = np.asarray(jax.jit(looked_up)(jnp.asarray(rows, jnp.float32), jnp.asarray(cols, jnp.float32)))
    samples = [_bounce_directions(cam, rows + dy, cols + dx, 2) for dy, dx in pixel_offsets(16)]
    for k, name in enumerate(("front", "bounce1", "bounce2")):
        rad = np.stack([_bilinear(px, s[name]) for s in samples])  # (16, N, 3)
        err = np.abs(got[k * len(rows):(k + 1) * len(rows)] - rad.mean(axis=0)).sum()
        sampling = (rad.std(axis=0) / 4).sum()
        assert sampling > 0, name  # not vacuous: the lamps vary across these pixels
        assert err <= sampling, (name, err, sampling)
