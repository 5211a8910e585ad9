"""``render`` against references written in the test (numpy, float64) for the features the
ray-traced orthographic test of tests/test_render.py does not reach: the perspective
camera, rough (Ward-filtered) films, point lights, and the colours of a draining film and
of a thickness map.

Each reference follows the paper's equations as docs/design.md reads them (eq. 1's Ward
lobe, eq. 3's point lights, eqs. 8-10's two-beam film, eq. 12's sum over texels) and the
documented conventions (cameras, map layout, spectra to sRGB via colour-science); none
calls the package for the quantity under test. Renders run in float64, so the tolerances
are those of the references' own approximations, stated per test.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bubblefit.lighting.envmap import EnvMap
from bubblefit.lighting.filtering import FilterConfig
from bubblefit.lighting.point_lights import PointLight
from bubblefit.model.effects import Effects
from bubblefit.model.geometry import OrthographicCamera, PerspectiveCamera
from bubblefit.model.render import Params, RenderConfig, render
from helpers import equirect_lookup, incoherent_slab, texel_band_solid_angles, texel_centres

pytestmark = pytest.mark.usefixtures("x64")


def _ward(n, wi, wo, a):
    """Eq. (1)'s specular lobe with r_s = 1: ``exp(-tan^2 delta / a^2) / (4 pi a^2
    sqrt(cos_i cos_r))``, delta the angle of the half vector from the normal; 0 below
    either horizon."""
    cos_i, cos_r = np.sum(n * wi, -1), np.sum(n * wo, -1)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    cos_h = np.clip(np.sum(n * h, -1), 1e-12, 1.0)
    tan2 = (1.0 - cos_h**2) / cos_h**2
    above = (cos_i > 0) & (cos_r > 0)
    root = np.sqrt(np.where(above, cos_i * cos_r, 1.0))
    return np.where(above, np.exp(-tan2 / a**2) / (4 * np.pi * a**2 * root), 0.0)


def _orthographic_front(cam):
    """Per pixel centre of an orthographic camera looking along -z at the unit sphere:
    ``inside``, the front film's outward normal and the direction to the viewer."""
    cx, cy, r = cam.disc()
    jj, ii = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    x, y = (jj - cx) / r, -(ii - cy) / r
    inside = x**2 + y**2 < 1
    n = np.stack([x, y, np.sqrt(np.clip(1 - x**2 - y**2, 0, 1))], axis=-1)
    return inside, n, np.broadcast_to([0.0, 0.0, 1.0], n.shape)


def _reflect(d, n):
    return d - 2 * np.sum(d * n, -1, keepdims=True) * n


# --------------------------------------------------------------------------------------
# Perspective camera: a two-film bubble traced ray by ray
# --------------------------------------------------------------------------------------


def _pinhole_rays(width, height, origin, target, up, fov_deg):
    """Mitsuba's pinhole with the field of view along the image width (docs/design.md):
    the ray through pixel (i, j) points along ``fwd + x right + y up`` with
    ``x = (2 (j + 1/2) / W - 1) tan(fov / 2)`` and ``y = (1 - 2 (i + 1/2) / H) tan(fov / 2) H / W``."""
    o = np.asarray(origin, float)
    fwd = np.asarray(target, float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    tan_half = np.tan(np.radians(fov_deg) / 2)
    jj, ii = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    x = (2 * jj / width - 1) * tan_half
    y = (1 - 2 * ii / height) * tan_half * height / width
    d = x[..., None] * right + y[..., None] * upv + fwd
    return np.broadcast_to(o, d.shape), d / np.linalg.norm(d, axis=-1, keepdims=True)


def _trace_bubble(env, o, d, n_film, tol=1e-12):
    """Radiance of rays (..., 3) meeting a unit sphere of two smooth incoherent films at
    the origin: split at every film into reflected and transmitted parts per polarisation
    (s and p stay s and p in a sphere), inside rays followed chord by chord until their
    weight is below ``tol``; rays that leave read the map in their direction."""
    shape = d.shape[:-1]
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    out = equirect_lookup(env, d)
    b = np.sum(o * d, -1)
    disc = b**2 - (np.sum(o * o, -1) - 1.0)
    hit = disc > 0
    s = -b[hit] - np.sqrt(disc[hit])
    p = o[hit] + s[:, None] * d[hit]
    dd = d[hit].copy()
    cos_i = np.abs(np.sum(p * dd, -1))
    refl, trans = incoherent_slab(cos_i, n_film)
    acc = refl[..., None] * equirect_lookup(env, _reflect(dd, p))[:, None, :]
    weight = trans
    while weight.max() > tol:
        p = p + (-2 * np.sum(p * dd, -1))[:, None] * dd   # the chord to the next film
        p /= np.linalg.norm(p, axis=-1, keepdims=True)
        cos_i = np.abs(np.sum(p * dd, -1))
        refl, trans = incoherent_slab(cos_i, n_film)
        acc += (weight * trans)[..., None] * equirect_lookup(env, dd)[:, None, :]
        dd = _reflect(dd, p)
        weight = weight * refl
    out[hit] = acc.mean(axis=1)
    return out.reshape(shape + (3,))


@pytest.mark.parametrize("origin", [(0.0, 0.0, 4.0), (1.2, 0.8, 3.0)])
def test_perspective_bubble_equals_the_traced_rays(small_courtyard, origin):
    """The physical model through a pinhole camera (on axis, and off axis looking at the
    bubble from above right) equals the rays traced in the test through both films and
    every internal bounce: to 1e-6 of the pixel (float64; the package's bounce series is
    cut after 48 bounces, whose remainder ``R^48`` is below 1e-6 for incidences up to
    about 85 degrees, and pixels whose incidence is grazing (cos < 0.1) are left out), and
    the map itself around the bubble."""
    env_px = np.asarray(small_courtyard, np.float64)
    cam = PerspectiveCamera(40, 32, origin=origin, target=(0.0, 0.0, 0.0), fov_deg=40.0)
    fx = Effects(model="physical", interference="off", filtering=FilterConfig("mirror"), diffuse=False, bounces=48)
    p = Params.make(t=0.97, roughness=1e-3, n_film=1.4, dtype=jnp.float64)
    img = np.asarray(render(p, RenderConfig(effects=fx, camera=cam, chunk=640),
                            EnvMap.from_array(env_px, dtype=jnp.float64)))
    o, d = _pinhole_rays(40, 32, origin, (0.0, 0.0, 0.0), np.array([0.0, 1.0, 0.0]), 40.0)
    ref = _trace_bubble(env_px, o, d, 1.4)
    b = np.sum(o * d, -1)
    disc = b**2 - (np.sum(o * o, -1) - 1.0)
    hit = disc > 0
    cos_i = np.sqrt(np.clip(disc, 0, None))        # |o + s d| = 1 at the hit: cos = sqrt(disc)
    assert hit.sum() > 200 and (~hit).sum() > 200
    np.testing.assert_allclose(img[~hit], ref[~hit], rtol=1e-9)
    judged = hit & (cos_i > 0.1)
    err = np.abs(img - ref).max(-1) / np.abs(ref).max(-1)
    assert err[judged].max() < 1e-6, err[judged].max()
    # and it is not the orthographic view of the same bubble
    ortho = _trace_bubble(env_px, *_ortho_rays_like(hit), 1.4)
    assert np.abs(ortho - ref)[judged].max() > 1e-2


def _ortho_rays_like(hit):
    """Orthographic rays along -z over the perspective image's bounding disc."""
    h, w = hit.shape
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    r = 0.5 * max(np.ptp(np.nonzero(hit)[0]), np.ptp(np.nonzero(hit)[1])) + 0.5
    x, y = (jj - w / 2) / r, -(ii - h / 2) / r
    o = np.stack([x, y, np.full_like(x, 5.0)], axis=-1)
    return o, np.broadcast_to([0.0, 0.0, -1.0], o.shape)


# --------------------------------------------------------------------------------------
# Point lights: eq. (3) with eq. (1)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("diffuse", [False, True])
def test_point_light_is_wards_lobe_times_its_irradiance(diffuse):
    """A distant light on a rough film (paper model, front film only, no map): each pixel
    is ``exposure (r_s lobe + r_d / pi) cos_i E`` (eqs. 1 and 3), the lobe written in the
    test from the paper; the highlight sits where the half vector is the normal."""
    cam = OrthographicCamera(48, 48, 24.0, 24.0, 22.0)
    light = np.array([0.5, 0.6, 1.0])
    light /= np.linalg.norm(light)
    e = np.array([3.0, 2.0, 1.0])
    fx = Effects(model="paper", front_reflection=True, rear_reflection=False, transmission=False,
                 interference="off", diffuse=diffuse, environment=False, point_lights=True,
                 filtering=FilterConfig("mirror"))
    p = Params.make(t=0.97, r_d=0.02, r_s=0.05, roughness=0.15, dtype=jnp.float64)
    cfg = RenderConfig(effects=fx, camera=cam, point_lights=(PointLight(tuple(light), tuple(e)),))
    img = np.asarray(render(p, cfg, None))
    inside, n, wo = _orthographic_front(cam)
    cos_i = np.sum(n * light, -1)
    lobe = _ward(n, np.broadcast_to(light, n.shape), wo, 0.15)
    dif = (0.02 / np.pi) * (cos_i > 0) if diffuse else 0.0
    ref = float(p.exposure) * ((0.05 * lobe + dif) * np.maximum(cos_i, 0.0))[..., None] * e
    np.testing.assert_allclose(img[inside], ref[inside], rtol=1e-9, atol=1e-12 * ref.max())
    peak = np.unravel_index(np.argmax(ref[..., 1]), ref.shape[:2])
    half = light + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    assert np.hypot(peak[1] + 0.5 - 24 - 22 * half[0], peak[0] + 0.5 - 24 + 22 * half[1]) < 1.5


# --------------------------------------------------------------------------------------
# Rough films: eq. (12), the sum over every texel
# --------------------------------------------------------------------------------------


def _small_sky(h=16):
    """A 16 x 32 map: a smooth gradient and one bright texel block (a sun)."""
    dirs = texel_centres(h, 2 * h)
    sky = (1.0 + 0.4 * dirs[..., 1:2] + 0.2 * dirs[..., 0:1]) * np.array([0.6, 0.8, 1.0])
    sky[h // 4, 5 * h // 4: 5 * h // 4 + 2] = 40.0
    return sky


@pytest.mark.parametrize("roughness", [0.05, 0.3])
def test_rough_film_is_the_sum_over_texels(roughness):
    """``filtering = full`` reflects eq. (12) written in the test: for each pixel,
    ``exposure r_s sum_i lobe(w_i, w_o) L_i max(0, n . w_i) dOmega_i`` over every texel
    (centres and band solid angles of docs/design.md's layout), to float64 rounding. (The
    faster filters approximate this sum; tests/test_filtering.py holds their convergence
    to it.)"""
    sky = _small_sky()
    env = EnvMap.from_array(sky, dtype=jnp.float64)
    cam = OrthographicCamera(24, 24, 12.0, 12.0, 11.0)
    p = Params.make(t=0.97, r_d=0.0, r_s=0.05, roughness=roughness, dtype=jnp.float64)
    inside, n, wo = _orthographic_front(cam)
    dirs = texel_centres(*sky.shape[:2]).reshape(-1, 3)
    omega = np.repeat(texel_band_solid_angles(*sky.shape[:2]), sky.shape[1])
    nn, ww = n[inside], wo[inside]
    lobe = _ward(nn[:, None, :], dirs[None, :, :], ww[:, None, :], roughness)
    cos = np.maximum(nn @ dirs.T, 0.0)
    ref = np.zeros(n.shape)
    ref[inside] = float(p.exposure) * 0.05 * (lobe * cos * omega) @ sky.reshape(-1, 3)
    fx = Effects(model="paper", front_reflection=True, rear_reflection=False, transmission=False,
                 interference="off", diffuse=False, filtering=FilterConfig("full"))
    img = np.asarray(render(p, RenderConfig(effects=fx, camera=cam, chunk=576), env))
    np.testing.assert_allclose(img[inside], ref[inside], rtol=1e-9, atol=1e-12 * ref.max())
    # the sun's glint: the brightest pixel of the sum is brighter than the sky around it
    assert ref[inside].max() > 3 * np.median(ref[inside])


# --------------------------------------------------------------------------------------
# Drainage: the film's colours, eqs. (8)-(10), through colour-science
# --------------------------------------------------------------------------------------


def _film_rgb(d_nm, cos_i, n_film, t):
    """Linear sRGB of eq. (10)'s factor ``4 t^2 cos^2(delta / 2)``, ``delta = 4 pi n d
    cos(theta_t) / lambda + pi`` (eq. 8), under D65 with the CIE 1931 2 degree observer
    (colour-science, 1 nm, 380-780 nm), normalised so that a flat spectrum c is (c, c, c)."""
    colour = pytest.importorskip("colour")
    lam = np.arange(380.0, 781.0)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(colour.SpectralShape(380, 780, 1))
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(380, 780, 1))
    w = cmfs.values * ill.values[:, None]                        # (K, 3) XYZ weights
    m = colour.models.RGB_COLOURSPACE_sRGB.matrix_XYZ_to_RGB
    cos_t = np.sqrt(1 - (1 - cos_i**2) / n_film**2)
    delta = 4 * np.pi * n_film * d_nm[..., None] * cos_t[..., None] / lam + np.pi
    f = 4 * t**2 * np.cos(0.5 * delta) ** 2
    rgb = (f @ w) @ m.T
    white = (np.ones_like(lam) @ w) @ m.T
    return rgb / white


@pytest.mark.parametrize("kind", ["drainage", "map"])
def test_film_has_the_colours_of_its_thickness(kind, tmp_path):
    """A draining film, or a film given as a thickness map (an EXR of per-pixel values from
    120 to 1000 nm, a different film at every pixel), paper model, front film, white sky,
    mirror: each pixel is ``exposure r_s cos_r RGB(F(d))`` with ``d`` the profile
    ``top + (bottom - top) ((1 - y) / 2)^exponent`` at the film's height y
    (docs/design.md) or the map's value at the pixel, and eq. (10)'s factor integrated by
    colour-science. The package integrates 400 uniform samples: the two quadratures agree
    to 2e-3 of the factor's range (4 t^2) for films below 1 um (period of the fringes in
    wavelength >= 56 nm against a 1 nm step)."""
    from bubblefit.io.images import write_image
    from bubblefit.model.scene import Scene

    top, bottom, expo, t, r_s = 150.0, 900.0, 1.5, 0.97, 0.05
    inside, n, wo = _orthographic_front(OrthographicCamera(32, 32, 16.0, 16.0, 15.0))
    if kind == "drainage":
        thickness = {"profile": "drainage", "top_nm": top, "bottom_nm": bottom, "exponent": expo}
        d = top + (bottom - top) * ((1 - n[..., 1]) / 2) ** expo
    else:
        d = np.random.default_rng(11).uniform(120.0, 1000.0, (32, 32))
        write_image(tmp_path / "thickness.exr", np.repeat(d[..., None], 3, -1).astype(np.float32), bit_depth=32)
        d = d.astype(np.float32).astype(np.float64)
        thickness = {"profile": "map", "path": str(tmp_path / "thickness.exr")}
    scene = Scene.from_dict({
        "camera": {"width": 32, "height": 32, "disc": [16.0, 16.0, 15.0]},
        "bubble": {"t": t, "r_d": 0.0, "r_s": r_s, "roughness": 1e-4, "n_film": 1.4, "thickness": thickness},
        "lighting": {"envmap": "unused.exr"},
        "effects": {"model": "paper", "interference": "two_beam", "rear_reflection": False, "transmission": False,
                    "diffuse": False, "filtering": "mirror", "spectral": {"method": "uniform", "samples": 400}}})
    env = EnvMap.constant(1.0, height=16, dtype=jnp.float64)
    cfg, _ = scene.config(env)
    p = scene.params(dtype=jnp.float64)
    img = np.asarray(render(p, cfg, env))
    cos = n[..., 2]
    ref = float(p.exposure) * r_s * cos[..., None] * _film_rgb(d, cos, 1.4, t)
    err = np.abs(img - ref)[inside]
    assert err.max() < 2e-3 * 4 * t**2 * r_s, err.max()
    # the films differ: the colours vary far more than the error
    assert np.ptp(ref[inside], axis=0).max() > 20 * err.max()


# --------------------------------------------------------------------------------------
# The map convention itself, against Mitsuba 3
# --------------------------------------------------------------------------------------

_CONV = __import__("pathlib").Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data"


def test_map_convention_is_mitsubas():
    """A perfect mirror sphere in the courtyard map, path traced by Mitsuba 3 (orthographic
    camera, disc (64, 64), r = 50 px, 128 x 128): the test's own lookup (tests/helpers.py,
    docs/design.md's convention) reproduces it to a relative RMS of 4 % inside 0.9 r
    (measured 2.7 %: Mitsuba's pixel filter and sample noise), while the map mirrored,
    turned by 90 degrees or upside down is off by more than 50 %. The package's lookup
    agrees with the test's to float32 rounding at any direction."""
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import lookup

    from helpers import mirror_ball_photo

    env = read_image(_CONV / "envmaps" / "courtyard.exr").pixels[..., :3].astype(np.float64)
    mitsuba = read_image(_CONV / "conventions" / "mitsuba_mirror_ortho.exr").pixels[..., :3].astype(np.float64)
    yy, xx = np.mgrid[0:128, 0:128] + 0.5
    inner = np.hypot(xx - 64, yy - 64) <= 0.9 * 50

    def rel(transform):
        img = mirror_ball_photo(lambda d: equirect_lookup(env, transform(d)), 128, 64.0, 64.0, 50.0)
        return float(np.sqrt(np.mean((img[inner] - mitsuba[inner]) ** 2)) / np.sqrt(np.mean(mitsuba[inner] ** 2)))

    assert rel(lambda d: d) < 0.04
    for wrong in (lambda d: d * np.array([-1.0, 1.0, 1.0]), lambda d: np.stack([d[..., 2], d[..., 1], -d[..., 0]], -1),
                  lambda d: d * np.array([1.0, -1.0, 1.0])):
        assert rel(wrong) > 0.5
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    ours = equirect_lookup(env, dirs)
    theirs = np.asarray(lookup(jnp.asarray(env), jnp.asarray(dirs)), dtype=np.float64)
    np.testing.assert_allclose(theirs, ours, rtol=1e-9, atol=1e-9 * env.max())
