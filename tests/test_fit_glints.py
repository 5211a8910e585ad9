"""Glints of a compact bright source in the fit: when the pixel footprint is on by default,
and channels the photo clipped at black (a glint on a film whose colour lies outside the
camera's gamut has a large negative channel; an 8-bit photo records 0 there).

References: the censored residual of a Tobit model (J. Tobin, Econometrica 26, 1958);
the map's power-preserving halving is an average over solid angle, so a source's peak at a
fixed texel size does not depend on the resolution the map was stored at.
"""

from __future__ import annotations

import math

import numpy as np
import pytest


def _sun_map(rows: int, sun: float) -> np.ndarray:
    """A uniform map of radiance 1 with a sun of ``sun`` over the solid angle of one texel
    of the 128-row map, centred on texel (40, 100) of that map."""
    px = np.ones((rows, 2 * rows, 3))
    k = rows // 128
    px[40 * k:41 * k, 100 * k:101 * k] = sun
    return px


def test_compact_source_reads_the_map_at_a_fixed_texel_size():
    from bubblefit.inverse import COMPACT_SOURCE_RATIO, compact_source
    from bubblefit.lighting.envmap import EnvMap, texel_solid_angles

    sun = 5000.0
    on_128, why = compact_source(EnvMap.from_array(_sun_map(128, sun)))
    on_512, why_512 = compact_source(EnvMap.from_array(_sun_map(512, sun)))
    assert on_128 and on_512
    # the ratio by hand: peak luminance (1 + sun over one texel) over the solid-angle mean
    sa = np.repeat(texel_solid_angles(128, 256)[:, None], 256, axis=1)
    mean = (np.sum(sa) + (sun - 1.0) * sa[40, 100]) / np.sum(sa)
    ratio = sun / mean
    assert f"{ratio:.0f}x" in why and f"{ratio:.0f}x" in why_512, (why, why_512, ratio)
    # a source weaker than the ratio's limit is not compact
    weak = 0.5 * COMPACT_SOURCE_RATIO * mean
    assert not compact_source(EnvMap.from_array(_sun_map(128, weak)))[0]


def test_the_shipped_maps_decide_the_footprint():
    """The courtyard's sun is soft (peak 27x the mean at 1.4 degrees): one ray per pixel; the
    studio's lamps (630x) are compact: the footprint."""
    from bubblefit.inverse import compact_source
    from bubblefit.model.scene import read_envmap, shipped_envmap

    assert not compact_source(read_envmap(shipped_envmap("courtyard")))[0]
    assert compact_source(read_envmap(shipped_envmap("studio")))[0]


def test_the_command_line_turns_the_footprint_either_way():
    from bubblefit.cli import build_parser
    from bubblefit.inverse import FitOptions

    base = ["fit", "photo.png", "--envmap", "env.exr"]
    parse = build_parser().parse_args
    assert parse(base).pixel_footprint is None and FitOptions().pixel_footprint is None
    assert parse(base + ["--pixel-footprint"]).pixel_footprint is True
    assert parse(base + ["--no-pixel-footprint"]).pixel_footprint is False


@pytest.mark.parametrize("model_red, counted", [(-0.4, 0.0), (0.0005, 0.0), (0.05, 0.05 - 0.001)])
def test_a_channel_clipped_at_black_is_censored(model_red, counted):
    """A photo channel at or below the black clip only says the true value is there or
    lower: a model below the recorded value costs nothing, a model above it costs its
    distance; the other channels keep their plain residual ``y - m``."""
    from bubblefit.inverse import censored_residual

    y = np.array([0.001, 0.20, 0.03])      # red clipped at black
    m = np.array([model_red, 0.21, 0.03])
    r = np.asarray(censored_residual(y, m))
    assert r[0] == pytest.approx(-counted, abs=1e-7)
    assert r[1] == pytest.approx(-0.01, abs=1e-7) and r[2] == pytest.approx(0.0, abs=1e-7)


def test_a_dim_pixel_still_ranks_its_candidates():
    """A pixel whose every channel lies under the black clip (a dim but recorded colour):
    its own candidate costs are plain squared residuals, so the candidate of its colour
    beats a black film; censored, both would cost nothing and the tie would go to the
    grid's first candidate."""
    from bubblefit.inverse import search

    y = np.array([[0.0015, 0.0012, 0.0018]])
    refl = np.array([[[0.0, 0.0, 0.0]], [[0.0015, 0.0012, 0.0018]]])   # black film, the pixel's colour
    cost = np.asarray(search.pixel_costs(refl, np.zeros((1, 3)), y, np.ones((1, 3))))[:, 0]
    assert int(np.argmin(cost)) == 1 and cost[0] > 0.0


def test_the_footprint_lookup_has_a_finite_roughness_derivative_at_a_mirror():
    """A thin footprint (one axis 1e-4 of the other) at roughness 0 and 1e-6: float32 rounds
    the determinant of the lobe-plus-pixel covariance to <= 0, and the Jacobian a mirror
    film's fit takes through the lookup must stay finite (a NaN made the off-centre sunset
    drainage fit fail at roughness 1.8e-6). The derivative's value is checked against a
    central difference at a roughness where both sides are smooth."""
    import jax
    import jax.numpy as jnp

    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.lighting.filtering import specular_mipmap

    rng = np.random.default_rng(3)
    env = EnvMap.from_array(rng.uniform(0.2, 1.0, (32, 64, 3)).astype(np.float32))
    n = jnp.asarray([[0.3, 0.2, 0.93], [0.0, 0.6, 0.8]], jnp.float32)
    n = n / jnp.linalg.norm(n, axis=-1, keepdims=True)
    wo = jnp.asarray([[0.0, 0.0, 1.0]] * 2, jnp.float32)
    long = jnp.asarray([[0.7, -0.5, 0.1], [0.2, 0.9, -0.3]], jnp.float32) * 0.02
    fp = jnp.stack([long, 1e-4 * long[:, ::-1]], axis=-1)  # (N, 3, 2), nearly rank 1

    # compiled, as the fit's Jacobian takes it (eagerly, each of the lookup's operations
    # compiles on its own: about 350 programs)
    @jax.jit
    def total(a):
        return jnp.sum(specular_mipmap(env, n, wo, a, nodes=4, normalize=True, footprint=fp))

    slope = jax.jit(jax.grad(total))
    for a in (0.0, 1e-6):
        assert np.isfinite(float(slope(jnp.float32(a))))
    a0, h = 0.05, 1e-3
    fd = (float(total(jnp.float32(a0 + h))) - float(total(jnp.float32(a0 - h)))) / (2 * h)
    assert float(slope(jnp.float32(a0))) == pytest.approx(fd, rel=0.05, abs=1e-3)


def test_ok_reads_the_photo_at_its_own_resolution():
    """``ok`` reads the final render against the photo's own pixels (``photo_misfit``). A
    model error common to neighbouring pixels, half a pixel's noise here, adds 0.25 to the
    photo's reduced chi^2 (1.25), but 0.25 k^2 on a level of k x k block means, whose noise
    is k times smaller (2.0 for k = 2): a solve's level can call unexplained a photo that
    its noise explains. Tolerances: 5 standard deviations of a reduced chi^2 of n data
    (sqrt(2 / n) times its expectation, at most). A channel clipped at black costs nothing
    while the model lies below it, as in the solves."""
    from bubblefit.inverse._censored import BLACK_CLIP
    from bubblefit.inverse._observation import Level
    from bubblefit.inverse._uncertainty import photo_misfit, residual_misfit

    rng = np.random.default_rng(3)
    h = w = 64
    sigma, bias = 0.01, 0.005
    truth = np.full((h, w, 3), 0.3)
    photo = truth + sigma * rng.standard_normal(truth.shape)
    render = truth + bias
    ones = np.ones((h, w), bool)

    def level(k, y):
        m = ones[::k, ::k]
        return Level(k, None, y, np.full(y.shape, k / sigma), None, m, m, np.ones(m.shape), np.zeros(m.shape))

    full = photo_misfit(level(1, photo), render, 0.0, 1)
    expect = 1 + (bias / sigma) ** 2
    assert abs(full.chi2_nu - expect) < 5 * expect * math.sqrt(2 / photo.size), full
    blocks = photo.reshape(h // 2, 2, w // 2, 2, 3).mean(axis=(1, 3))
    lev2 = level(2, blocks)
    coarse = residual_misfit((blocks - render[::2, ::2]) * lev2.w, lev2, 0.0, 1)
    expect2 = 1 + 4 * (bias / sigma) ** 2
    assert abs(coarse.chi2_nu - expect2) < 5 * expect2 * math.sqrt(2 / blocks.size), coarse

    clipped = photo.copy()
    clipped[..., 0] = BLACK_CLIP / 2   # red clipped at black everywhere
    below = render.copy()
    below[..., 0] = -0.2                # an interference colour outside the gamut
    lev = level(1, clipped)
    censored = photo_misfit(lev, below, 0.0, 1)
    plain = residual_misfit(np.where(np.arange(3) == 0, 0.0, (clipped - below) * lev.w), lev, 0.0, 1)
    assert censored.chi2_nu == pytest.approx(plain.chi2_nu, rel=1e-12)


def test_a_clipped_pixel_is_censored_with_every_pixel_the_demosaic_spreads_it_into():
    """A fit leaves out a clipped pixel and the pixels a camera's demosaic fills from its
    photosite: the block found here by raising one photosite of a Bayer mosaic through the
    RAW reader's bilinear demosaic, the diagonal neighbours included (a cross would keep
    the four diagonal ones)."""
    from types import SimpleNamespace

    from bubblefit.inverse import saturation_mask
    from bubblefit.io.camera_files import _develop_bayer
    from bubblefit.io.encoding import PhotoReading

    n = 9
    cfa = np.array([[0, 1], [3, 2]])[np.arange(n)[:, None] % 2, np.arange(n)[None, :] % 2]  # RGGB
    reading = PhotoReading(raw_white_balance="none")
    wb = np.ones(4)

    def develop(vals):
        raw = SimpleNamespace(raw_image_visible=vals, raw_colors_visible=cfa, black_level_per_channel=[0, 0, 0, 0],
                              white_level=1000, color_matrix=np.eye(3, 4))
        return _develop_bayer(raw, "RGBG", wb, reading)[0]

    flat = np.full((n, n), 400.0)
    for site in [(4, 4), (4, 5), (5, 5)]:  # a red, a green and a blue photosite
        bright = flat.copy()
        bright[site] = 1000.0  # clipped
        spread = np.any(develop(bright) != develop(flat), axis=-1)
        photo = np.full((n, n, 3), 0.4)
        photo[site] = 1.0
        censored = saturation_mask(photo, 0.995, None)
        # every pixel the photosite reaches is censored, and nothing a pixel farther
        assert not np.any(spread & ~censored), site
        assert censored.sum() == 9 and spread.sum() >= 5, site
    # the red photosite reaches all eight neighbours (its blue and green neighbours' red)
    bright = flat.copy()
    bright[4, 4] = 1000.0
    assert np.any(develop(bright) != develop(flat), axis=-1)[3:6, 3:6].all()
