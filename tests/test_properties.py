"""Property-based tests (hypothesis) of the physics.

* Film reflectance lies in [0, 1]; for the lossless film R + T = 1, checked against an
  independent transfer-matrix computation (the ``tmm`` package: Byrnes, "Multilayer optical
  calculations", arXiv:1603.02720), which computes R and T separately.
* Airy's sum (Born & Wolf 7.6) averages over one period of the phase to the incoherent
  ``2R/(1+R)``; the two-beam form differs from it by O(R1^2).
* Ward's BRDF (eq. 1) is reciprocal: f(w_i -> w_o) = f(w_o -> w_i).
* Symmetry under the sign of the angle: a bubble in a left-right symmetric environment
  renders a left-right symmetric image (every pixel at +x sees the film at the same angle
  as its mirror at -x).
* Energy: the physical model in a white furnace (constant environment of radiance 1) with
  every internal bounce renders 1 per pixel, the sum R + T (R + T^2 + T R T + ...) = 1.
* Monotone limits: a film thinner than a quarter wave brightens as it thickens from black
  (d = 0); Fresnel's R_s grows towards 1 at grazing incidence; R_p vanishes at Brewster's
  angle; the filtered radiance tends to the mirror lookup as the roughness goes to 0.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bubblefit.optics import brdf, film
from bubblefit.model.effects import Effects
from bubblefit.lighting.envmap import EnvMap
from bubblefit.lighting.filtering import FilterConfig, specular
from bubblefit.model.geometry import OrthographicCamera
from bubblefit.model.render import Params, RenderConfig, render
from bubblefit.optics.spectral import spectral_basis

tmm = pytest.importorskip("tmm")

PROPS = settings(max_examples=40, deadline=None, derandomize=True)

angles = st.floats(0.0, 89.5)
thicknesses = st.floats(0.0, 20000.0)
indices = st.floats(1.0, 2.0)
wavelengths = st.floats(380.0, 780.0)


@pytest.fixture(autouse=True, scope="module")
def _x64():
    with jax.enable_x64(True):
        yield


_airy = jax.jit(film.airy_reflectance)
_two = jax.jit(film.two_beam_reflectance)
_inc = jax.jit(film.incoherent_reflectance)
_fres = jax.jit(film.fresnel_reflectance)


@PROPS
@given(angle=angles, d=thicknesses, n=indices, lam=wavelengths)
def test_airy_matches_transfer_matrix_and_conserves_energy(angle, d, n, lam):
    """R in [0, 1]; R(Airy) = R(tmm) per polarisation, and R(tmm) + T(tmm) = 1 (lossless)."""
    th = math.radians(angle)
    r = np.asarray(_airy(d, lam, n, math.cos(th)), np.float64)
    assert np.all((r >= 0) & (r <= 1))
    for k, pol in enumerate("sp"):
        res = tmm.coh_tmm(pol, [1.0, n, 1.0], [np.inf, d, np.inf], th, lam)
        assert res["R"] + res["T"] == pytest.approx(1.0, abs=1e-9)
        assert r[k] == pytest.approx(res["R"], abs=2e-7), (pol, r[k], res["R"])
        assert 1.0 - r[k] == pytest.approx(res["T"], abs=2e-7)


@PROPS
@given(angle=angles, d0=thicknesses, n=st.floats(1.01, 2.0), lam=wavelengths)
def test_airy_period_mean_is_incoherent(angle, d0, n, lam):
    """The mean of Airy's R over one period of the phase equals 2 R1 / (1 + R1)."""
    c = math.cos(math.radians(angle))
    cos_t = float(film.cos_transmitted(c, n))
    period = lam / (2.0 * n * cos_t)
    d = d0 + period * (np.arange(256) + 0.5) / 256
    mean = np.asarray(_airy(jnp.asarray(d), lam, n, c)).mean(axis=0)
    np.testing.assert_allclose(mean, np.asarray(_inc(c, n)), atol=1e-6)


@PROPS
@given(angle=st.floats(0.0, 70.0), d=thicknesses, n=indices, lam=wavelengths)
def test_two_beam_close_to_airy(angle, d, n, lam):
    """The two-beam truncation differs from the Airy sum by O(R1^2) (docs/design.md)."""
    c = math.cos(math.radians(angle))
    r1 = np.asarray(_fres(c, n))
    diff = np.abs(np.asarray(_two(d, lam, n, c)) - np.asarray(_airy(d, lam, n, c)))
    assert np.all(diff <= 4.0 * r1**2 + 1e-12), (diff, r1)


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


vectors = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 1e-3)


@PROPS
@given(wi=vectors, wo=vectors, a=st.floats(1e-3, 1.0), r_d=st.floats(0, 1), r_s=st.floats(0, 1))
def test_ward_reciprocity(wi, wo, a, r_d, r_s):
    """f(w_i -> w_o) = f(w_o -> w_i), and f >= 0, for any pair of directions (n = +z)."""
    wi, wo = _unit(wi), _unit(wo)
    h = wi + wo
    if np.linalg.norm(h) < 1e-6:
        return
    cos_h = _unit(h)[2]
    f1 = float(brdf.ward(wi[2], wo[2], cos_h, r_d, r_s, a))
    f2 = float(brdf.ward(wo[2], wi[2], cos_h, r_d, r_s, a))
    assert f1 >= 0.0
    assert f1 == pytest.approx(f2, rel=1e-12, abs=1e-300)


@PROPS
@given(n=st.floats(1.0, 2.0), lam=wavelengths, angle=st.floats(0.0, 80.0))
def test_thin_film_brightens_from_black(n, lam, angle):
    """d = 0 reflects nothing (eq. 8's half-wave shift); up to a quarter wave R grows with d."""
    c = math.cos(math.radians(angle))
    cos_t = float(film.cos_transmitted(c, n))
    quarter = lam / (4.0 * n * cos_t)
    d = np.linspace(0.0, quarter * 0.999, 64)
    r = np.asarray(_airy(jnp.asarray(d), lam, n, c)).mean(axis=1)
    assert r[0] == pytest.approx(0.0, abs=1e-12)
    if n > 1.0 + 1e-6:
        assert np.all(np.diff(r) > 0)


@PROPS
@given(n=st.floats(1.05, 2.0))
def test_fresnel_grazing_and_brewster(n):
    """R_s grows monotonically to 1 at grazing incidence; R_s >= R_p; R_p = 0 at Brewster."""
    th = np.radians(np.linspace(0.0, 90.0, 181))
    r = np.asarray(_fres(np.where(th >= np.pi / 2, 0.0, np.cos(th)), n))
    assert np.all(np.diff(r[:, 0]) > 0)
    assert r[-1, 0] == pytest.approx(1.0) and r[-1, 1] == pytest.approx(1.0)
    assert np.all(r[:, 0] >= r[:, 1] - 1e-15)
    assert r[0, 0] == pytest.approx(((n - 1) / (n + 1)) ** 2)
    brewster = math.atan(n)
    assert float(_fres(math.cos(brewster), n)[1]) == pytest.approx(0.0, abs=1e-20)


# --------------------------------------------------------------------------------------
# Through the renderer (one compilation per test; parameters are traced)
# --------------------------------------------------------------------------------------
def _symmetric_env(h=16, seed=3):
    """A map that is symmetric under x -> -x (u -> 1 - u), with a bright off-axis source."""
    rng = np.random.default_rng(seed)
    px = rng.uniform(0.05, 1.0, (h, 2 * h, 3))
    px[4, 9] = 50.0
    return 0.5 * (px + px[:, ::-1])


@pytest.fixture(scope="module")
def symmetric_setup():
    env = EnvMap.from_array(_symmetric_env(), dtype=jnp.float64)
    fx = Effects(model="physical", interference="airy", filtering=FilterConfig("mipmap", nodes=3),
                 spectral=spectral_basis("uniform", 12), bounces=2)
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(14, 10, 7.0, 5.0, 4.6), chunk=140)
    f = jax.jit(lambda p: render(p, cfg, env))
    return f


@settings(max_examples=8, deadline=None, derandomize=True)
@given(d=thicknesses, n=indices, a=st.floats(0.01, 0.5))
def test_mirror_symmetric_scene_renders_symmetric(d, n, a, symmetric_setup):
    """Symmetry of the film under the sign of the angle, seen through the whole model."""
    img = np.asarray(symmetric_setup(Params.make(t=0.9, roughness=a, thickness=d, n_film=n, dtype=jnp.float64)))
    assert np.all(np.isfinite(img))
    np.testing.assert_allclose(img, img[:, ::-1], rtol=1e-6, atol=1e-9 * max(1.0, img.max()))


@pytest.fixture(scope="module")
def furnace():
    env = EnvMap.constant(1.0, height=16, dtype=jnp.float64)
    fx = Effects(model="physical", interference="airy", filtering=FilterConfig("mipmap", nodes=2),
                 spectral=spectral_basis("uniform", 12), bounces=8, diffuse=False)
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(12, 12, 6.0, 6.0, 5.0), chunk=144)
    return jax.jit(lambda p: render(p, cfg, env))


@settings(max_examples=8, deadline=None, derandomize=True)
@given(d=thicknesses, n=st.floats(1.0, 1.8), exposure=st.floats(0.5, 2.0))
def test_white_furnace_conserves_energy(d, n, exposure, furnace):
    """R + T = 1 through the compositing: front reflection + background through both films +
    every internal bounce of a lossless film in a uniform environment sum to the exposure."""
    img = np.asarray(furnace(Params.make(t=0.9, r_d=0.0, r_s=0.1, thickness=d, n_film=n, exposure=exposure,
                                         roughness=0.05, dtype=jnp.float64)))
    yy, xx = np.mgrid[0:12, 0:12] + 0.5
    rho2 = ((xx - 6) ** 2 + (yy - 6) ** 2) / 25.0
    inner = rho2 < 1 - 0.6**2  # cos > 0.6: R^9 of the truncated series is < 1e-3 there
    np.testing.assert_allclose(img[inner], exposure, rtol=2e-3)
    # never creates light (at the rim the truncated remainder R^9 is coloured, and sRGB's
    # colour-matching weights are partly negative, so a channel may exceed 1 by ~1e-5 there)
    assert img[inner].max() <= exposure * (1 + 1e-4), img[inner].max() / exposure - 1
    assert img.max() <= exposure * (1 + 1e-2), img.max() / exposure - 1


@pytest.fixture(scope="module")
def mirror_limit():
    rng = np.random.default_rng(4)
    px = rng.uniform(0.1, 1.0, (32, 64, 3))
    # smooth the map so that the limit is reached before the texel scale
    from scipy.ndimage import gaussian_filter

    px = gaussian_filter(px, sigma=(3, 3, 0), mode="wrap")
    env = EnvMap.from_array(px, dtype=jnp.float64)
    n = jnp.asarray([[0.0, 0.0, 1.0], [0.3, 0.2, 0.93]], jnp.float64)
    n = n / jnp.linalg.norm(n, axis=1, keepdims=True)
    wo = jnp.asarray([[0.2, 0.1, 0.97], [0.0, 0.0, 1.0]], jnp.float64)
    wo = wo / jnp.linalg.norm(wo, axis=1, keepdims=True)
    spec = jax.jit(lambda a: specular(env, n, wo, a, FilterConfig("mipmap", nodes=4), normalize=True))
    mirror = np.asarray(specular(env, n, wo, 0.0, FilterConfig("mirror"), normalize=True))
    return spec, mirror


@settings(max_examples=10, deadline=None, derandomize=True)
@given(a=st.floats(1e-3, 0.3))
def test_roughness_to_zero_tends_to_mirror(a, mirror_limit):
    """|L(a) - L_mirror| shrinks as a -> 0: at a/4 it is no larger than at a (plus a floor)."""
    spec, mirror = mirror_limit
    e1 = np.abs(np.asarray(spec(a)) - mirror).max()
    e2 = np.abs(np.asarray(spec(a / 4)) - mirror).max()
    assert e2 <= e1 + 2e-3
    assert np.abs(np.asarray(spec(1e-4)) - mirror).max() < 5e-3
