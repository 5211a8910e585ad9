"""Numerical stability at the singular points of the paper's formulas, in values and gradients.

Hard cases (issue "hard cases stay numerically stable"): Ward's ``1/sqrt(cos th_i cos th_r)``
and ``tan^2(delta)`` at grazing angles, ``exp(-tan^2/a^2)/a^2`` as the roughness goes to 0,
the rim of the bubble's disc, Snell's law near total internal reflection, thickness 0 and
20000 nm, t at 0 and 1, n_film from 1 to 2, and environment maps with NaN, black and
30000 "sun" texels. Each test sweeps a grid that includes the end points (angles 0 and 90
degrees inclusive) in float32 and float64 and checks:

* no NaN/Inf in values, in ``jax.grad`` and in ``jax.jacfwd``;
* float32 within a stated tolerance of float64 away from the singular points;
* renders through :func:`bubblefit.model.render.render`: a fit loss has finite gradients for every
  parameter at every hard point, for both models and all four filtering methods.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bubblefit.optics import brdf, film
from bubblefit.model.effects import Effects
from bubblefit.lighting.envmap import EnvMap
from bubblefit.lighting.filtering import FilterConfig, specular
from bubblefit.model.geometry import OrthographicCamera, intersect_sphere
from bubblefit.model.render import Params, RenderConfig, render
from bubblefit.optics.spectral import spectral_basis
from bubblefit.model.thickness import drainage_profile

DTYPES = [jnp.float32, jnp.float64]
ANGLES_DEG = np.concatenate([np.linspace(0.0, 90.0, 19), [89.9, 89.999]])  # 0 and 90 included
THICKNESS_NM = np.array([0.0, 1e-3, 1.0, 20.0, 100.0, 500.0, 1000.0, 5000.0, 20000.0])
N_FILM = np.array([1.0, 1.0 + 1e-7, 1.001, 1.2, 1.4, 1.7, 2.0])
WAVELENGTHS = np.array([380.0, 550.0, 780.0])
ROUGHNESS = np.array([1e-4, 1e-3, 1e-2, 0.1, 1.0])
T_VALUES = np.array([0.0, 0.5, 0.972, 1.0])

# float32 against float64, away from the singular points (angle <= 85 deg, n >= 1.05):
# the phase 4 pi n d cos t / lambda reaches ~900 rad at 20 um, where float32 keeps ~1e-4 rad.
FILM_F32_ATOL = 2e-4
# Ward's lobe relative to its peak 1/(4 pi a^2 sqrt(cos_i cos_r)): the lobe is evaluated from
# cos(delta), whose float32 rounding (eps ~ 6e-8) is an error eps/a^2 in tan^2(delta)/a^2. So
# the float32 error bound is 4 eps32 / a^2 of the peak: 2.4e-3 at a = 0.01, 2.4e-5 at 0.1.
# Below a ~ 1e-3 float32 cannot resolve the lobe from cos(delta) at all (the mipmap filter
# does not evaluate it that way: its Gauss-Hermite nodes are placed in slope space).
WARD_F32_RTOL = lambda a: 4 * float(np.finfo(np.float32).eps) / a**2 + 1e-6


@pytest.fixture
def enable_x64():
    with jax.enable_x64(True):
        yield


def _cos(angles_deg):
    c = np.cos(np.radians(angles_deg))
    return np.where(angles_deg >= 90.0, 0.0, c)  # exactly 0 at 90 degrees


def _film_grid(dtype):
    c, d, n, lam = np.meshgrid(_cos(ANGLES_DEG), THICKNESS_NM, N_FILM, WAVELENGTHS, indexing="ij")
    return tuple(jnp.asarray(x.ravel(), dtype) for x in (d, lam, n, c))


def _all_finite(tree) -> bool:
    # read in numpy: eagerly, jnp.isfinite and jnp.all compile again for every shape and dtype
    return all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree_util.tree_leaves(tree))


FILM_FUNCS = {
    "airy": lambda d, lam, n, c: film.airy_reflectance(d, lam, n, c),
    "two_beam": lambda d, lam, n, c: film.two_beam_reflectance(d, lam, n, c),
    "incoherent": lambda d, lam, n, c: film.incoherent_reflectance(c, n),
    "fresnel": lambda d, lam, n, c: film.fresnel_reflectance(c, n),
}


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize("name", sorted(FILM_FUNCS))
def test_film_values_and_gradients_finite(name, dtype, enable_x64):
    """Reflectance in [0, 1] and finite d/d(thickness, n, cos_i) over the whole grid."""
    fn = FILM_FUNCS[name]
    d, lam, n, c = _film_grid(dtype)
    r = jax.jit(fn)(d, lam, n, c)
    assert r.dtype == dtype
    assert _all_finite(r)
    assert float(r.min()) >= 0.0 and float(r.max()) <= 1.0
    scalar = lambda d_, n_, c_, l_: jnp.sum(fn(d_, l_, n_, c_))
    grads = jax.jit(jax.vmap(jax.grad(scalar, argnums=(0, 1, 2))))(d, n, c, lam)
    assert _all_finite(grads), [(i, int((~jnp.isfinite(g)).sum())) for i, g in enumerate(grads)]
    # Forward mode as the fit uses it: d(all outputs)/d(thickness, n) along grazing..normal.
    jac = jax.jit(jax.vmap(jax.jacfwd(lambda x, l_, c_: fn(x[0], l_, x[1], c_))))(jnp.stack([d, n], axis=1), lam, c)
    assert _all_finite(jac)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_paper_factor_and_snell_near_tir(dtype, enable_x64):
    """Eq. (10)'s factor for t in [0, 1], and Snell's law from a denser medium (n_outside > n)
    through the critical angle: values and gradients finite, cos_t = 0 beyond it."""
    d, lam, n, c = _film_grid(dtype)
    for t in T_VALUES:
        f = jax.jit(film.paper_interference_factor)(d, lam, n, c, t)
        assert _all_finite(f) and float(f.min()) >= 0 and float(f.max()) <= 4 * t * t + 1e-6
        g = jax.jit(jax.vmap(jax.grad(film.paper_interference_factor, argnums=(0, 2, 3, 4))))(
            d, lam, n, c, jnp.full_like(d, t))
        assert _all_finite(g)
    # Glass-like inside (1.5) to a film of n in [1, 1.5]: the critical angle asin(n/1.5).
    cos_i = jnp.asarray(_cos(np.linspace(0, 90, 721)), dtype)
    cos_transmitted = jax.jit(film.cos_transmitted)  # compiled, as the renderer runs it
    grad_cos = jax.jit(jax.vmap(jax.grad(film.cos_transmitted, argnums=(0, 1)), in_axes=(0, None, None)))
    for n_in in (1.0, 1.2, 1.4999):
        ct = cos_transmitted(cos_i, jnp.asarray(n_in, dtype), 1.5)
        g = grad_cos(cos_i, jnp.asarray(n_in, dtype), 1.5)
        assert _all_finite(ct) and _all_finite(g)
        sin_i = np.sqrt(1 - np.asarray(cos_i, np.float64) ** 2)
        beyond = 1.5 * sin_i > n_in * (1 + 1e-3)
        assert np.all(np.asarray(ct)[beyond] == 0.0)
        assert np.all(np.asarray(ct)[~beyond] >= 0.0)


def test_film_float32_matches_float64(enable_x64):
    """Away from grazing incidence and n = 1 the float32 film agrees with float64."""
    c, d, n, lam = np.meshgrid(_cos(np.linspace(0, 85, 18)), THICKNESS_NM, N_FILM[N_FILM >= 1.05], WAVELENGTHS,
                               indexing="ij")
    for name in ("airy", "two_beam", "incoherent"):
        fn = jax.jit(FILM_FUNCS[name])  # compiled, as the renderer runs it (eagerly, each operation compiles)
        r64 = np.asarray(fn(*(jnp.asarray(x, jnp.float64) for x in (d, lam, n, c))))
        r32 = np.asarray(fn(*(jnp.asarray(x, jnp.float32) for x in (d, lam, n, c))))
        err = np.abs(r64 - r32)
        assert err.max() < FILM_F32_ATOL, (name, err.max())
        # The error grows with the phase (thickness), not at random: thin films are exact to 1e-5.
        assert err[:, d[0, :, 0, 0] <= 1000.0].max() < 1e-5, name


def _ward_grid(dtype, a_values):
    """Grid over a, cos_i, cos_r (0..90 deg inclusive) and half-vector angles that resolve the lobe
    (delta = 0, a/2, a, 2a, 3a) plus far-off and grazing half vectors (and cos_h > 1: a non-unit normal)."""
    cos = _cos(ANGLES_DEG)
    rows = []
    for a in a_values:
        deltas = np.concatenate([a * np.array([0.0, 0.5, 1.0, 2.0, 3.0]), [0.5, 1.2, np.pi / 2]])
        ch = np.concatenate([np.cos(deltas), [0.0, 1e-8, 1.3]])
        ci, cr, hh = np.meshgrid(cos, cos, ch, indexing="ij")
        rows.append(np.stack([ci.ravel(), cr.ravel(), hh.ravel(), np.full(ci.size, a)], axis=1))
    g = np.concatenate(rows)
    return tuple(jnp.asarray(g[:, i], dtype) for i in range(4))


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_ward_values_and_gradients_finite(dtype, enable_x64):
    """Eq. (1) at grazing angles (cos = 0 exactly), tiny roughness and tan^2(delta) -> inf."""
    ci, cr, ch, a = _ward_grid(dtype, ROUGHNESS)
    f = jax.jit(brdf.ward)(ci, cr, ch, 0.1, 0.9, a)
    assert _all_finite(f) and float(f.min()) >= 0.0
    g = jax.jit(jax.vmap(jax.grad(brdf.ward, argnums=(0, 1, 2, 3, 4, 5))))(
        ci, cr, ch, 0.1 * jnp.ones_like(a), 0.9 * jnp.ones_like(a), a)
    assert _all_finite(g)
    w = jax.jit(brdf.half_vector_weight)(ci, cr, ci, ch)
    gw = jax.jit(jax.vmap(jax.grad(brdf.half_vector_weight, argnums=(0, 1, 2, 3))))(ci, cr, ci, ch)
    assert _all_finite(w) and _all_finite(gw)
    jac = jax.jit(jax.vmap(jax.jacfwd(brdf.ward_lobe, argnums=3)))(ci, cr, ch, a)
    assert _all_finite(jac)


def test_ward_lobe_nonunit_normal_is_finite():
    """Regression: cos_h > 1 (the normal of a ray that misses the bubble is not unit) made
    tan^2 < 0 and exp(+huge) = inf; the masked pixel's gradient was then NaN."""
    ch = jnp.asarray([1.0, 1.3, 1.6], jnp.float32)
    f = brdf.ward_lobe(0.5, 0.5, ch, 0.05)
    g = jax.grad(lambda a: jnp.sum(brdf.ward_lobe(0.5, 0.5, ch, a)))(jnp.float32(0.05))
    assert _all_finite(f) and bool(jnp.isfinite(g))
    assert float(f[1]) == pytest.approx(float(f[0]))


def test_ward_float32_matches_float64(enable_x64):
    keep = ROUGHNESS >= 1e-2
    c64 = _ward_grid(jnp.float64, ROUGHNESS[keep])
    c32 = tuple(x.astype(jnp.float32) for x in c64)
    ci, cr, ch, a = (np.asarray(x) for x in c64)
    ok = (ci >= np.cos(np.radians(85))) & (cr >= np.cos(np.radians(85))) & (ch <= 1.0)
    peak = 1.0 / (4 * np.pi * a**2 * np.sqrt(np.maximum(ci * cr, 1e-8)))
    lobe = jax.jit(brdf.ward_lobe)  # compiled, as the renderer runs it
    err = np.abs(np.asarray(lobe(*c64)) - np.asarray(lobe(*c32))) / peak
    assert np.all(err[ok] < WARD_F32_RTOL(a[ok])), (err / WARD_F32_RTOL(a))[ok].max()


# --------------------------------------------------------------------------------------
# Environment maps and their filtering
# --------------------------------------------------------------------------------------
def _hard_env(h=16, seed=0):
    """A small map with everything that hurts: a 30000 sun, NaN, Inf, -1 and a black band."""
    rng = np.random.default_rng(seed)
    px = rng.uniform(0.05, 1.0, (h, 2 * h, 3))
    px[3, 5] = 30000.0
    px[7, 2] = np.nan
    px[8, 20] = np.inf
    px[9, 9] = -1.0
    px[11:13] = 0.0
    return px


@functools.partial(jax.jit, static_argnums=(4, 5))
def _filter_and_grad(env, n, wo, a, method, normalize):
    """Filtered radiance (A, N, 3) and d(sum)/da (A,) for each roughness in ``a`` (compiled once
    per method and normalisation; the map is an argument, so every damaged map reuses it)."""
    cfg = FilterConfig(method, nodes=3, window=2, level=1)
    one = lambda aa: specular(env, n, wo, aa, cfg, normalize=normalize)
    return jax.vmap(one)(a), jax.vmap(jax.grad(lambda aa: jnp.sum(one(aa))))(a)


@pytest.mark.parametrize("kind", ["hard", "black", "all_nan", "sun_only"])
@pytest.mark.parametrize("method", ["mirror", "mipmap", "window", "full"])
def test_filters_on_damaged_maps(kind, method):
    """Every filter stays finite (and non-negative) on a map with NaN/black/30000 texels,
    normalised or not, with finite d/d(roughness) for roughness 1e-4..1."""
    h = 16
    if kind == "hard":
        px = _hard_env(h)
    elif kind == "black":
        px = np.zeros((h, 2 * h, 3))
    elif kind == "all_nan":
        px = np.full((h, 2 * h, 3), np.nan)
    else:
        px = np.zeros((h, 2 * h, 3))
        px[2, 7] = 30000.0
    env = EnvMap.from_array(px)
    assert _all_finite(env.atlas) and _all_finite(env.irradiance)
    rng = np.random.default_rng(1)
    n = rng.normal(size=(24, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wo = rng.normal(size=(24, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo[:4] = n[:4]  # normal incidence
    wo[4:8] = np.cross(n[4:8], [0.0, 0.0, 1.0])  # grazing (cos_r = 0)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    n, wo = jnp.asarray(n, jnp.float32), jnp.asarray(wo, jnp.float32)
    a = jnp.asarray([1e-4, 1e-2, 0.1, 1.0], jnp.float32)
    for normalize in (False, True):
        s, g = _filter_and_grad(env, n, wo, a, method, normalize)
        assert _all_finite(s) and float(s.min()) >= 0.0, normalize
        assert _all_finite(g), (normalize, g)
        if kind in ("black", "all_nan"):
            assert float(jnp.abs(s).max()) == 0.0


def test_sun_map_float32_matches_float64(enable_x64):
    """A 30000 sun in float32: the mip pyramid and the filtered radiance agree with float64."""
    px = _hard_env(32)
    e32 = EnvMap.from_array(px, dtype=jnp.float32)
    e64 = EnvMap.from_array(px, dtype=jnp.float64)
    rng = np.random.default_rng(2)
    n = rng.normal(size=(64, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wo = n + 0.3 * rng.normal(size=(64, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    cfg = FilterConfig("mipmap", nodes=4)
    filt = jax.jit(lambda env, n, wo, a: specular(env, n, wo, a, cfg, normalize=True))
    s64 = np.asarray(filt(e64, jnp.asarray(n), jnp.asarray(wo), 0.05))
    s32 = np.asarray(filt(e32, jnp.asarray(n, jnp.float32), jnp.asarray(wo, jnp.float32), jnp.float32(0.05)))
    np.testing.assert_allclose(s32, s64, rtol=1e-3, atol=1e-3 * np.abs(s64).max() * 1e-2)


# --------------------------------------------------------------------------------------
# Geometry and thickness fields
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_rim_of_the_disc(dtype, enable_x64):
    """Rays through the rim: tangent, just inside (disc ~ eps) and just outside give a finite
    cosine in [0, 1] and a finite gradient w.r.t. the radius and the ray position."""
    eps = float(jnp.finfo(dtype).eps)
    x = jnp.asarray([0.0, 0.5, 1.0 - 1e-3, 1.0 - 10 * eps, 1.0 - eps, 1.0, 1.0 + eps, 1.5], dtype)

    def cosines(x, radius):
        o = jnp.stack([x, jnp.zeros_like(x), jnp.full_like(x, 4.0)], axis=1)
        d = jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0], dtype), o.shape)
        return intersect_sphere(o, d, (0.0, 0.0, 0.0), radius).cos

    c = jax.jit(cosines)(x, jnp.asarray(1.0, dtype))
    assert _all_finite(c) and float(c.min()) >= 0 and float(c.max()) <= 1
    assert float(c[-1]) == 0.0 and float(c[0]) == 1.0
    gx, gr = jax.jit(jax.vmap(jax.grad(lambda xx, r: cosines(xx[None], r)[0], argnums=(0, 1)), in_axes=(0, None)))(
        x, jnp.asarray(1.0, dtype))
    assert _all_finite(gx) and _all_finite(gr)


@jax.jit
def _drainage_jac(y, q):
    return jax.jacfwd(lambda q: drainage_profile(y, q[0], q[1], q[2]))(q)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_drainage_profile_at_the_top(dtype, enable_x64):
    """d = top + (bottom - top) ((1 - y)/2)^p at the top (y = 1, base 0) and bottom, for p from
    0.1 to 5: finite value and gradient w.r.t. every profile parameter."""
    y = jnp.asarray([1.0, 1.0 - 1e-7, 0.5, 0.0, -1.0], dtype)
    for p in (0.1, 0.5, 1.0, 2.0, 5.0):
        v = jax.jit(drainage_profile)(y, 100.0, 1000.0, p)
        g = _drainage_jac(y, jnp.asarray([100.0, 1000.0, p], dtype))
        assert _all_finite(v) and _all_finite(g)
        assert float(v[0]) == pytest.approx(100.0) and float(v[-1]) == pytest.approx(1000.0, rel=1e-5)


# --------------------------------------------------------------------------------------
# Through the renderer: a fit loss at every hard point, for every parameter
# --------------------------------------------------------------------------------------
HARD_POINTS = [
    {},
    {"t": 0.0}, {"t": 1.0},
    {"roughness": 1e-4}, {"roughness": 1.0},
    {"thickness": 0.0}, {"thickness": 20000.0},
    {"n_film": 1.0}, {"n_film": 2.0},
    {"rotation": np.pi}, {"exposure": 0.0},
]
PARAM_NAMES = ("t", "r_d", "r_s", "roughness", "thickness", "n_film", "exposure", "rotation")
RENDER_CASES = [
    ("paper", "two_beam", "mipmap"),
    ("paper", "two_beam", "full"),
    ("physical", "airy", "window"),
]


def _params(**kw):
    base = dict(t=0.9, f=0.3, roughness=0.05, thickness=400.0, n_film=1.4, exposure=1.0, rotation=0.3)
    base.update(kw)
    return Params.make(**base)


def _stack(plist):
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *plist)


@pytest.fixture(scope="module")
def hard_env():
    return EnvMap.from_array(_hard_env(16))


@pytest.mark.slow
@pytest.mark.parametrize("model,interference,method", RENDER_CASES)
def test_render_loss_gradients_at_hard_points(model, interference, method, hard_env):
    """A 12x12 render (the disc's rim crosses pixels, corners miss the bubble) on a map with
    NaN/black/sun texels: image and grad/jacfwd of a squared-error loss are finite for every
    parameter at every hard point."""
    fx = Effects(model=model, interference=interference,
                 filtering=FilterConfig(method, nodes=2, window=2, level=2),
                 spectral=spectral_basis("uniform", 8) if interference in ("two_beam", "airy") else None,
                 bounces=1)
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(12, 12, 6.0, 6.0, 5.2), chunk=144)
    target = render(_params(), cfg, hard_env)
    assert _all_finite(target)

    def loss(p):
        return jnp.mean((render(p, cfg, hard_env) - target) ** 2)

    stacked = _stack([_params(**h) for h in HARD_POINTS])
    # Reverse mode for the paper model, forward mode (what the Levenberg-Marquardt Jacobian
    # uses) for the physical one.
    diff = jax.grad(loss) if model == "paper" else jax.jacfwd(loss)
    images, grads = jax.jit(jax.vmap(lambda p: (render(p, cfg, hard_env), diff(p))))(stacked)
    bad = [(HARD_POINTS[i], name) for name in PARAM_NAMES for i in range(len(HARD_POINTS))
           if not bool(jnp.isfinite(getattr(grads, name)[i]))]
    assert _all_finite(images)
    assert not bad, f"non-finite gradients: {bad}"


def test_render_float32_matches_float64(enable_x64):
    """One tiny render in float32 and float64 agrees away from the rim (cos > 0.2)."""
    px = _hard_env(16)
    px = np.where(px > 100, 100.0, px)  # same scene, a milder sun: a clean relative tolerance
    fx = Effects(model="physical", interference="airy", filtering=FilterConfig("mipmap", nodes=3),
                 spectral=spectral_basis("uniform", 10), bounces=2)
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(12, 12, 6.0, 6.0, 5.2), chunk=144)
    img = {}
    for dt in (jnp.float32, jnp.float64):
        p = Params.make(t=0.9, roughness=0.05, thickness=700.0, n_film=1.33, rotation=0.2, dtype=dt)
        img[dt] = np.asarray(render(p, cfg, EnvMap.from_array(px, dtype=dt)), np.float64)
    yy, xx = np.mgrid[0:12, 0:12] + 0.5
    rho2 = ((xx - 6) ** 2 + (yy - 6) ** 2) / 5.2**2
    inner = rho2 < 1 - 0.2**2
    diff = np.abs(img[jnp.float32] - img[jnp.float64])[inner]
    assert diff.max() < 1e-4 * max(1.0, np.abs(img[jnp.float64]).max()), diff.max()


# --------------------------------------------------------------------------------------
# Fits from bad starting values or on images that cannot identify a parameter
# --------------------------------------------------------------------------------------
FIT_N = 24
FIT_DISC = (FIT_N / 2, FIT_N / 2, 0.42 * FIT_N)


def _fit_photo(env, bubble, seed=0):
    """A rendered photo with noise and 8-bit sRGB quantisation, and a quantised background."""
    from scipy import ndimage as ndi

    from bubblefit.io.images import srgb_decode, srgb_encode
    from bubblefit.model.scene import Scene, render_scene

    rng = np.random.default_rng(seed)
    bg = ndi.gaussian_filter(rng.uniform(0.15, 0.6, (FIT_N, FIT_N, 3)), (2.5, 2.5, 0))
    scene = Scene.from_dict({"camera": {"width": FIT_N, "height": FIT_N, "disc": list(FIT_DISC)}, "bubble": bubble,
                             "lighting": {"envmap": "unused.exr"}, "effects": {"transmission_tint": True}})
    img = render_scene(scene, bg, env=env)
    q = lambda x: srgb_decode(np.round(srgb_encode(x + rng.normal(0, 0.003, x.shape)) * 255) / 255)
    return q(img), q(bg)


def _fit_options(**kw):
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, ImageSizes, SolverSettings
    from bubblefit.inverse import starts

    base = dict(disc=FIT_DISC, parameters=starts(t=0.968, roughness=0.04), solver=SolverSettings(max_steps=30),
                sizes=ImageSizes(search=24),
                model="paper", view=ORTHOGRAPHIC,
                effects=(("spectral", {"method": "uniform", "samples": 32}),))
    base.update(kw)
    return FitOptions(**base)


def _recovered(res, truth: dict):
    """The fit converged, every reported value and error bar is finite, and each value in
    ``truth`` (value, floor) is within 5 standard errors (+ the floor) of the truth."""
    print("fit:", res.converged, res.message, {k: (res.params[k], res.stderr.get(k)) for k in res.params})
    assert res.converged, res.message
    for k, v in res.params.items():
        assert v is not None and np.isfinite(v), (k, v)
    for key, (value, floor) in truth.items():
        err = res.stderr.get(key)
        assert err is not None and np.isfinite(err) and err > 0, (key, err)
        assert abs(res.params[key] - value) <= 5 * err + floor, (key, res.params[key], value, err)


@pytest.fixture(scope="module")
def fit_env(small_courtyard):
    return EnvMap.from_array(small_courtyard)


@pytest.mark.slow
@pytest.mark.parametrize("init", [
    {"thickness_nm": 1900.0, "roughness": 0.6, "t": 0.6, "exposure": 20.0},
    {"thickness_nm": 0.0, "roughness": 1e-4, "t": 0.999, "exposure": 1e-3},
])
def test_fit_from_bad_start_reports_or_recovers(init, fit_env):
    """Warm starts far from the truth: the fit rejects the warm start (its solve fails or
    ends at a poor chi^2), searches globally and ends converged at the truth, within its
    error bars. A fit that gives up fails this test."""
    from bubblefit.inverse.fit import fit_photo

    photo, bg = _fit_photo(fit_env, dict(t=0.972, roughness=0.08, f=0.3, thickness_nm=700.0))
    res = fit_photo(photo, fit_env, options=_fit_options(), background=bg, init=init)
    assert "warm start rejected" in res.message and "searched globally" in res.message, res.message
    _recovered(res, {"thickness_nm": (700.0, 5.0), "t": (0.972, 0.003)})


@pytest.mark.slow
def test_fit_unidentifiable_roughness_in_uniform_light():
    """In a uniform environment the roughness does not change the image: the fit converges
    with the thickness at the truth and the roughness held at its starting value, without
    an error bar, and says so (``held``), not as a confident number."""
    from bubblefit.inverse.fit import fit_photo

    env = EnvMap.constant(0.8, height=64)  # the courtyard's shape: the compiled solver is shared
    photo, bg = _fit_photo(env, dict(t=0.972, roughness=0.08, f=0.3, thickness_nm=600.0), seed=1)
    opts = _fit_options()
    res = fit_photo(photo, env, options=opts, background=bg)
    print("fit:", res.converged, res.message, res.params, res.stderr, res.held)
    assert res.converged, res.message
    assert abs(res.params["thickness_nm"] - 600.0) <= 5 * res.stderr["thickness_nm"] + 5.0, res.params
    assert "roughness" in {name for name, _ in res.held}, res.held
    assert res.stderr.get("roughness") is None and res.params["roughness"] == pytest.approx(0.04)  # _fit_options' start


@pytest.mark.slow
@pytest.mark.parametrize("what", ["nan", "saturated"])
def test_fit_on_unusable_photo(what, fit_env):
    """NaN pixels or a saturated bubble are refused before any fit, with one line that says
    what is wrong with the photo. (A black bubble region ends as "the solver failed",
    converged=False; it takes a whole fit, so it is not run here.)"""
    from bubblefit.errors import InputError
    from bubblefit.inverse.fit import fit_photo

    photo = np.full((FIT_N, FIT_N, 3), 0.3)
    yy, xx = np.mgrid[0:FIT_N, 0:FIT_N] + 0.5
    disc = (xx - FIT_DISC[0]) ** 2 + (yy - FIT_DISC[1]) ** 2 < FIT_DISC[2] ** 2
    photo[disc] = {"black": 0.0, "nan": np.nan, "saturated": 1.0}[what]
    with pytest.raises(InputError) as info:
        fit_photo(photo, fit_env, options=_fit_options())
    line = str(info.value).strip()
    print(what, line)
    assert line and "\n" not in line
