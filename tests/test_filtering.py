"""Environment filtering (bubblefit.lighting.filtering): convergence of the window (eq. 13) and
mip-map methods to the exact sum (eq. 12), the mirror limit, and the white furnace.

Ward's lobe as written (eq. 1) is not energy-normalised: in a white furnace its albedo is
``1 - 3 a^2 + O(a^4)`` at normal incidence (expand ``g(s)`` of bubblefit.optics.brdf:
``sqrt(cos 2 delta) cos^4 delta ~ 1 - 3 delta^2``, and ``E[tan^2 delta] = a^2``) and tends
to ``cos th_r`` at oblique view as ``a -> 0`` (Walter, "Notes on the Ward BRDF", 2005).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bubblefit.lighting import filtering as F
from bubblefit.lighting.envmap import EnvMap


# The renderer calls the filters inside its compiled programs (bubblefit.model.render), and
# the tests call them compiled too: one program per setting. Called eagerly, JAX compiles
# each operation again for every array size (from an empty compilation cache the window's
# and the mip-map's convergence checks took 20 s of CPU eagerly, 4 s compiled; the results
# differ by float32 rounding, 2e-6 at most).
specular_mipmap = jax.jit(F.specular_mipmap, static_argnames=("nodes", "normalize"))
specular_window = jax.jit(F.specular_window, static_argnames=("window", "level", "normalize"))
specular_mirror = jax.jit(F.specular_mirror, static_argnames=("normalize",))
full_sum = jax.jit(F.full_sum, static_argnames=("level", "chunk", "normalize"))


def _points(count=120, max_angle=1.1, seed=0):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v = rng.normal(size=(count, 3))
    v -= (v * n).sum(1, keepdims=True) * n
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    th = rng.uniform(0, max_angle, count)
    wo = np.cos(th)[:, None] * n + np.sin(th)[:, None] * v
    return jnp.asarray(n, jnp.float32), jnp.asarray(wo, jnp.float32)


@pytest.fixture(scope="module")
def env(small_courtyard):
    return EnvMap.from_array(small_courtyard)


@pytest.fixture(scope="module")
def full_sum_of(env):
    """Eq. (12) summed over every texel of the courtyard at the points of :func:`_points`,
    per lobe width ``a``: computed once and shared by the window's and the mip-map's
    convergence checks, which compare with the same sum."""
    sums = {}

    def full(a):
        if a not in sums:
            n, wo = _points()
            sums[a] = np.asarray(full_sum(env, n, wo, a, level=0, chunk=4096, normalize=False)[0])
        return sums[a]

    return full


def _rel(x, ref):
    x = np.asarray(x)
    return float(np.sqrt(np.mean((x - ref) ** 2)) / np.sqrt(np.mean(ref**2)))


# the 0.1 lobe (a level-0 sum over many texels per point) is the longest: slow; 0.3 runs in the fast part
@pytest.mark.parametrize("a", [pytest.param(0.1, marks=pytest.mark.slow), 0.3])
def test_window_converges_to_full_sum(env, full_sum_of, a):
    n, wo = _points()
    ref = full_sum_of(a)
    errs = [_rel(specular_window(env, n, wo, a, window=k, level=0, normalize=False), ref) for k in (2, 6, 16, 40)]
    assert all(e1 <= e0 + 1e-6 for e0, e1 in zip(errs, errs[1:])), errs
    assert errs[-1] < 0.01 and errs[0] > 0.1, errs


@pytest.mark.parametrize("a", [pytest.param(0.1, marks=pytest.mark.slow), 0.3])  # as above
def test_mipmap_converges_to_full_sum(env, full_sum_of, a):
    """On the courtyard (a sun ~50x the mean) the mip-map quadrature approaches eq. (12)."""
    n, wo = _points()
    ref = full_sum_of(a)
    nodes = (4, 8, 16, 32)
    errs = [_rel(specular_mipmap(env, n, wo, a, nodes=k, normalize=False), ref) for k in nodes]
    print(dict(zip(nodes, errs)))
    assert errs[1] < errs[0] and errs[2] < errs[1] and errs[3] < errs[2], errs
    assert errs[-1] < 0.02, errs


def test_roughness_to_zero_tends_to_mirror(env):
    n, wo = _points(max_angle=1.0)
    mirror = np.asarray(specular_mirror(env, n, wo, normalize=True))
    errs = [_rel(specular_mipmap(env, n, wo, a, nodes=6, normalize=True), mirror) for a in (0.05, 0.01, 0.002, 2e-4)]
    assert all(e1 < e0 for e0, e1 in zip(errs, errs[1:])), errs
    assert errs[-1] < 2e-3, errs
    # Unnormalised (eq. 1 as written) the limit carries the lobe's albedo cos th_r.
    cos_r = np.asarray(jnp.sum(n * wo, -1))[:, None]
    raw = np.asarray(specular_mipmap(env, n, wo, 2e-4, nodes=6, normalize=False))
    assert _rel(raw, mirror * cos_r) < 2e-3


@pytest.mark.parametrize("a", [pytest.param(0.05, marks=pytest.mark.slow), 0.1, 0.2])  # 0.05: the longest sum
def test_white_furnace_energy(a):
    """r_d + r_s = 1 - t (eq. 14) in a white furnace returns 1 - t up to Ward's known error."""
    white = EnvMap.constant(1.0, height=64)
    t = 0.9
    r_s, r_d = 0.07, 0.03  # r_d + r_s = 1 - t
    n = jnp.asarray([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8], [0.8, 0.0, 0.6]], jnp.float32)
    wo = jnp.asarray([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], jnp.float32)
    cos_r = np.asarray(jnp.sum(n * wo, -1))
    spec, irr = full_sum(white, n, wo, a, level=0, chunk=4096, normalize=False)
    diffuse = r_d / np.pi * np.asarray(F.irradiance(white, n))[:, 0]
    np.testing.assert_allclose(np.asarray(irr)[:, 0], np.pi, rtol=2e-3)  # E = pi in a white furnace
    np.testing.assert_allclose(diffuse, r_d, rtol=1e-2)
    total = r_s * np.asarray(spec)[:, 0] + diffuse
    # Normal incidence: 1 - t within Ward's normalisation error 3 a^2 (stated above).
    assert abs(total[0] / (1 - t) - 1) <= r_s / (1 - t) * (3 * a * a * 1.1 + 2e-3)
    assert total[0] < 1 - t  # the error has that sign
    # Oblique: the lobe's albedo tends to cos th_r (the known error), within O(a^2).
    albedo = np.asarray(spec)[:, 0]
    np.testing.assert_allclose(albedo[1:], cos_r[1:], rtol=4 * a * a + 2e-3)
    # Mip-map quadrature sees the same furnace, and normalised filtering returns exactly 1.
    mip = np.asarray(specular_mipmap(white, n, wo, a, nodes=8, normalize=False))[:, 0]
    np.testing.assert_allclose(mip, albedo, rtol=5e-3)  # measured 0.2 % at most
    norm = np.asarray(specular_mipmap(white, n, wo, a, nodes=8, normalize=True))
    np.testing.assert_allclose(norm, 1.0, rtol=1e-5)


def test_filter_config_rejects_bad_knobs():
    with pytest.raises(ValueError):
        F.FilterConfig("blur")
    with pytest.raises(ValueError):
        F.FilterConfig("mipmap", nodes=0)


@pytest.mark.parametrize("shape,out_height", [((64, 128), 32), ((40, 80), 10), ((30, 70), 8)])
def test_irradiance_table_is_the_direct_cosine_sum(shape, out_height):
    """The irradiance table (FFT in azimuth when the widths divide, else direct) equals the
    cosine-weighted sum over every texel, with the texel geometry written in the test from
    docs/design.md's convention (tests/helpers.py: centres from (u, v), band solid angles by
    quadrature); a single bright texel's irradiance follows Lambert's cosine law."""
    from bubblefit.lighting.envmap import irradiance_map

    from helpers import texel_band_solid_angles, texel_centres

    rng = np.random.default_rng(3)
    px = rng.uniform(0.0, 5.0, shape + (3,))
    h, w = shape
    dirs = texel_centres(h, w).reshape(-1, 3)
    rad = px.reshape(-1, 3) * np.repeat(texel_band_solid_angles(h, w), w)[:, None]
    normals = texel_centres(out_height, 2 * out_height).reshape(-1, 3)
    direct = np.maximum(normals @ dirs.T, 0.0) @ rad
    table = irradiance_map(px, out_height=out_height, src_height=h).reshape(-1, 3)
    np.testing.assert_allclose(table, direct, rtol=1e-12, atol=1e-12 * direct.max())
    sun = np.zeros((h, w, 3))
    sun[h // 3, w // 5] = 1.0
    e = irradiance_map(sun, out_height=out_height, src_height=h).reshape(-1, 3)[:, 0]
    power = texel_band_solid_angles(h, w)[h // 3]
    np.testing.assert_allclose(e, power * np.maximum(normals @ texel_centres(h, w)[h // 3, w // 5], 0.0),
                               atol=1e-15)


@pytest.mark.parametrize("h,out_height", [(64, 32), (40, 10), (30, 8)])
def test_irradiance_of_a_linear_sky_is_the_closed_form(h, out_height):
    """A sky ``L(w) = c (1 + a . w)`` has the irradiance ``E(n) = c (pi + 2 pi / 3 a . n)``
    (the clamped cosine integrates to pi over the hemisphere, and ``w (n . w)`` to
    ``2 pi / 3 n``). The texel sum is a midpoint rule in both angles with step
    ``D = pi / (H - 1)``: its relative error is O(D^2), held here to D^2 / 4 (measured:
    0.13 D^2 at every size)."""
    from bubblefit.lighting.envmap import irradiance_map

    from helpers import harmonic_map, texel_centres

    a, c = np.array([0.3, -0.2, 0.25]), np.array([1.0, 0.8, 0.6])
    table = irradiance_map(harmonic_map(h, 2 * h, a, c), out_height=out_height, src_height=h)
    n = texel_centres(out_height, 2 * out_height)
    exact = c * (np.pi + 2 * np.pi / 3 * (n @ a))[..., None]
    assert np.max(np.abs(table / exact - 1)) < 0.25 * (np.pi / (h - 1)) ** 2


# --- The rough lookup over a pixel's footprint, against a brute-force integral --------------
#
# A map with a sun of 0.6 texels (sd), far smaller than the spacing of 4 x 4 nodes spread
# over a long, thin footprint (a film near the rim, an internal bounce). The reference is
# written here in numpy from the design notes' conventions: the pixel's half vectors
# ``n + J (s, t)``, (s, t) on a 32 x 32 midpoint grid of the pixel's box [-1/2, 1/2]^2
# (what a camera's pixel integrates), each reflected and read by a bilinear lookup
# (u = atan2(x, -z) / 2 pi, v = acos(y) / pi, x = u W - 1/2 wrapping, y = v (H - 1)).

SUN_H, SUN_W = 128, 256


def _sun_map():
    v = np.arange(SUN_H) / (SUN_H - 1)
    u = (np.arange(SUN_W) + 0.5) / SUN_W
    th, ph = np.pi * v[:, None], 2 * np.pi * u[None, :]
    d = np.stack(np.broadcast_arrays(np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)), -1)
    sun = np.array([0.3, 0.25, -0.9])
    sun /= np.linalg.norm(sun)
    sd = 0.6 * np.pi / (SUN_H - 1)
    ang = np.arccos(np.clip(d @ sun, -1, 1))
    rad = 1.0 + 0.3 * d[..., 1] + 2000.0 * np.exp(-0.5 * (ang / sd) ** 2)
    return (rad[..., None] * np.array([1.0, 0.8, 0.6])).astype(np.float32), sun, sd


def _bilinear(pixels, d):
    h, w = pixels.shape[:2]
    u = (np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    x, y = u * w - 0.5, v * (h - 1)
    x0 = np.floor(x)
    y0 = np.clip(np.floor(y), 0, h - 2)
    fx, fy = (x - x0)[..., None], np.clip(y - y0, 0, 1)[..., None]
    x0 = x0.astype(int) % w
    x1, y0 = (x0 + 1) % w, y0.astype(int)
    y1 = y0 + 1
    return ((pixels[y0, x0] * (1 - fx) + pixels[y0, x1] * fx) * (1 - fy)
            + (pixels[y1, x0] * (1 - fx) + pixels[y1, x1] * fx) * fy)


def _box_pixel_mirror(pixels, n, wo, jac, k=32):
    s = (np.arange(k) + 0.5) / k - 0.5
    ss, tt = (g.ravel() for g in np.meshgrid(s, s))
    h = n[None] + ss[:, None] * jac[:, 0] + tt[:, None] * jac[:, 1]
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    r = 2 * (h @ wo)[:, None] * h - wo
    return _bilinear(pixels, r).mean(0)


#: Half-length of the scan, in units of the footprint's long side.
SCAN = 0.6


@pytest.mark.parametrize("elongation", [30.0, 12.0])
def test_footprint_lookup_resolves_a_small_sun(elongation):
    """``specular_mipmap`` with a footprint at roughness 0 (a mirror film, the limit a fit
    reaches) swept across a small sun along the footprint's long axis, against the
    brute-force integral over the pixel's box above (RMS and largest error over the
    sweep, in units of its peak). Nodes that each read an isotropic mip level from their
    cells' geometric mean alias the sun: 0.36 and 0.81 at an elongation of 30 (0.35 and
    0.79 at 12). Cells of the Gaussian of the box's variance (Gauss-Hermite nodes) reach
    past the box to the sun beside it: 0.22 and 0.39. The box's own midpoint cells tile
    it exactly at roughness 0; what they leave is each cell read as the box of its second
    moments on the map's axes, wider across than a thin cell turned 0.3 rad from them
    (0.14 and 0.21 at both elongations). Allowed: 0.18 and 0.30, below what the Gaussian
    stand-in leaves."""
    pixels, sun, sd = _sun_map()
    env = EnvMap.from_array(pixels)
    wo = np.array([0.0, 0.0, 1.0])
    n0 = (sun + wo) / np.linalg.norm(sun + wo)
    t1 = np.cross(n0, [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n0, t1)
    e1, e2 = np.cos(0.3) * t1 + np.sin(0.3) * t2, -np.sin(0.3) * t1 + np.cos(0.3) * t2
    long = 5.0 * sd  # the footprint's long side in slope: 10 sun sd in the reflected direction
    jac = np.stack([e1 * long, e2 * long / elongation], axis=1)
    offsets = np.linspace(-SCAN, SCAN, 25) * long
    n = np.stack([(n0 + o * e1) / np.linalg.norm(n0 + o * e1) for o in offsets])
    jacs = np.stack([jac - np.outer(m, m @ jac) for m in n])  # tangent at each normal
    ref = np.stack([_box_pixel_mirror(pixels, m, wo, j) for m, j in zip(n, jacs)])[:, 0]
    got = np.asarray(specular_mipmap(env, jnp.asarray(n, jnp.float32), jnp.asarray(np.tile(wo, (len(n), 1)), jnp.float32),
                                       jnp.float32(0.0), nodes=4, normalize=True,
                                       footprint=jnp.asarray(jacs, jnp.float32)))[:, 0]
    err = (got - ref) / ref.max()
    rms, worst = float(np.sqrt(np.mean(err**2))), float(np.abs(err).max())
    assert rms <= 0.18 and worst <= 0.30, (rms, worst)


def test_footprint_lookup_of_a_smooth_map_is_the_brute_force_integral():
    """On a smooth map the footprint lookup is the integral over the pixel's box above to
    the map's own curvature over the footprint (0.5 % allowed), near the poles too."""
    pixels, sun, sd = _sun_map()
    smooth = (1.0 + 0.3 * np.cos(np.linspace(0, 2 * np.pi, SUN_W))[None, :] * np.sin(np.linspace(0, np.pi, SUN_H))[:, None]
              )[..., None] * np.ones(3, np.float32)
    smooth = smooth.astype(np.float32)
    env = EnvMap.from_array(smooth)
    rng = np.random.default_rng(3)
    n = rng.normal(size=(40, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.5
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wo = np.tile([0.0, 0.0, 1.0], (40, 1))
    jac = rng.normal(scale=0.05, size=(40, 3, 2))
    jac -= n[:, :, None] * np.einsum("nc,nck->nk", n, jac)[:, None, :]
    ref = np.stack([_box_pixel_mirror(smooth, m, o, j) for m, o, j in zip(n, wo, jac)])
    got = np.asarray(specular_mipmap(env, jnp.asarray(n, jnp.float32), jnp.asarray(wo, jnp.float32), jnp.float32(0.0),
                                       nodes=4, normalize=True, footprint=jnp.asarray(jac, jnp.float32)))
    np.testing.assert_allclose(got, ref, rtol=5e-3)  # measured 0.2 % at most


def test_footprint_lookups_are_never_negative():
    """Every lookup of a non-negative map is a weighted mean of its texels with weights
    >= 0 (the bilinear tents; a box's weights are differences of the tent's monotone
    antiderivative at its ends, rounded monotonically in float32; the mip levels are
    means of texels), so no lookup can read below 0, however the footprint is shaped.
    Probed where rounding is worst: lamps of 1e4 beside black texels, boxes from 1e-6 to
    far over the map's width, thin parallelograms diagonal to the map's axes, near the
    poles and across the columns' seam. (A film's colour can still be a negative linear
    sRGB channel: that is its spectrum outside the sRGB gamut, not the map.)"""
    rng = np.random.default_rng(7)
    h = 32
    pixels = np.where(rng.random((h, 2 * h, 3)) < 0.03, 1e4, 0.0).astype(np.float32)
    env = EnvMap.from_array(pixels)
    m = 4000
    d = rng.normal(size=(m, 3))
    d[: m // 4, 1] = np.sign(d[: m // 4, 1]) * 50.0  # near the poles
    d[m // 4: m // 2, 0] *= 1e-3  # along the seam (u = 0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scale = 10.0 ** rng.uniform(-6, 1, size=(m, 1, 1))
    dr = rng.normal(size=(m, 3, 2)) * scale
    dr[::2, :, 1] = dr[::2, :, 0] * 1e-3 + dr[::2, :, 1] * 1e-5  # thin
    dr -= d[:, :, None] * np.einsum("mc,mck->mk", d, dr)[:, None, :]
    d32, dr32 = jnp.asarray(d, jnp.float32), jnp.asarray(dr, jnp.float32)
    widths = jnp.asarray(10.0 ** rng.uniform(-6, 3, size=(m, 2)), jnp.float32)
    box = np.asarray(jax.jit(env.lookup_box)(d32, widths))
    para = np.asarray(jax.jit(env.lookup_parallelogram)(d32, dr32))
    assert box.min() >= 0.0 and para.min() >= 0.0, (box.min(), para.min())
    assert box.max() > 0.0 and para.max() > 0.0  # not vacuous: lamps are read
    n = jnp.asarray(d, jnp.float32)
    wo = n  # normal view: the reflected direction is n, the footprint its slope / 2
    fp = dr32 * 0.5
    mirror = np.asarray(specular_mirror(env, n, wo, normalize=True, footprint=fp))
    mip = np.asarray(specular_mipmap(env, n, wo, jnp.float32(0.0), nodes=4, normalize=True, footprint=fp))
    assert mirror.min() >= 0.0 and mip.min() >= 0.0, (mirror.min(), mip.min())


def test_each_footprint_is_read_by_the_cut_it_needs():
    """:func:`~bubblefit.lighting.envmap.lookup_parallelogram` reads every footprint with
    the cut :func:`~bubblefit.lighting.envmap.pieces_needed` gives it, whichever share of
    a lookup's footprints needs which cut: each value is that cut's own
    (``_pieces``), to float32 rounding of a sum of up to 16 boxes of 36 texels of a map
    whose texels reach 2000 times its floor (1e-5 of the footprint's largest cut's
    value) and of its texel coordinates. A footprint under a texel, or one whose sides lie along the map's axes and
    fit one box of level 0, needs one box; one 12 texels long diagonal to the axes and a
    tenth of a texel wide needs 4 pieces along and one across (a single box of its second
    moments would read a coarser level, two pieces would err by ``(12 / 2)^2 / 24``
    texels^2, four times the 4 pieces' error; pieces across would not lessen it)."""
    from bubblefit.lighting import envmap as E

    pixels, _, _ = _sun_map()
    env = EnvMap.from_array(pixels)
    rng = np.random.default_rng(3)
    m = 512
    d = rng.normal(size=(m, 3))
    d[:, 1] *= 0.3  # away from the poles, where a column is narrower than a row
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    texel = np.pi / (SUN_H - 1)
    dr = rng.normal(size=(m, 3, 2))
    dr -= d[:, :, None] * np.einsum("mc,mck->mk", d, dr)[:, None, :]
    dr /= np.linalg.norm(dr, axis=1, keepdims=True)
    rungs = E.piece_counts(E.BOX_PROBES, E.BOX_PROBES)
    assert rungs[0] == (1, 1) and rungs[-1] == (E.BOX_PROBES, E.BOX_PROBES)
    # a footprint read in a block of others may have its texel coordinates rounded
    # otherwise (XLA's vectorised and scalar loops): 4 float32 ulps of a column index up to
    # SUN_W, times the sun's steepest slope, 2000 e^(-1/2) / 0.6 per texel
    rounding = 4 * np.spacing(np.float32(SUN_W)) * 2000 * np.exp(-0.5) / 0.6
    reader = jax.jit(env.lookup_parallelogram)
    cuts = [jax.jit(lambda r, s, p=p, q=q: E._pieces(env.atlas, env.shapes, r, s, p, q)) for p, q in rungs]
    for long_share in (0.05, 0.3, 0.9):
        long = rng.random(m) < long_share
        length = np.where(long, rng.uniform(5, 20, m), rng.uniform(0.0, 0.25, m)) * texel
        s32 = jnp.asarray(dr * length[:, None, None], jnp.float32)
        d32 = jnp.asarray(d, jnp.float32)
        need = np.asarray(E.pieces_needed(env.shapes, d32, s32, rungs))
        assert (need[~long] == 0).all()
        got = np.asarray(reader(d32, s32))
        each = np.stack([np.asarray(c(d32, s32)) for c in cuts])
        own = each[need, np.arange(m)]
        scale = np.abs(each).max(axis=(0, 2))[:, None]
        assert np.all(np.abs(got - own) <= 1e-5 * scale + rounding)
    # along the map's axes at the equator: one box; the same length diagonal: 4 pieces
    r = np.array([[0.0, 0.0, -1.0]] * 2)
    col = np.pi * 2 / SUN_W  # a column's angle at the equator
    side = lambda cols, rows: np.array([cols * col, -rows * texel, 0.0])  # du along +x, dv along -y at u = 0
    straight = np.stack([side(3.0, 0.0), side(0.0, 0.5)], axis=-1)
    diagonal = np.stack([side(12 / np.sqrt(2), 12 / np.sqrt(2)), side(0.1, -0.1)], axis=-1)
    need = np.asarray(E.pieces_needed(env.shapes, jnp.asarray(r, jnp.float32),
                                      jnp.asarray(np.stack([straight, diagonal]), jnp.float32), rungs))
    assert rungs[need[0]] == (1, 1) and rungs[need[1]] == (E.BOX_PROBES, 1), need