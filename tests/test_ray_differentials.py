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

import math

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
        # pixel's parallelogram (and, above 4 texels, the coarser level's wider texels)
        # measured 0.05-0.9 % here
        assert img.sum() / cam.r**2 == pytest.approx(want, rel=0.015), size
        # not vacuous: one ray per pixel misses or hits the patch (x 4.0, 1.55, 0.81)
        assert abs(point.sum() / cam.r**2 / want - 1) > 0.15, size
        if size >= 64:
            # and pixel by pixel it is the box average a camera takes (64 rays per pixel;
            # measured 1.6 % and 0.8 % RMS of the glint, the single ray 91 % and 37 %)
            boxed = np.asarray(render(p, RenderConfig(effects=fx, camera=cam, samples_per_pixel=64,
                                                      pixel_footprint=False), env))[..., 0]
            assert np.sqrt(np.mean((img - boxed) ** 2) / np.mean(boxed**2)) < 0.03, size
