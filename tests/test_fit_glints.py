"""Glints of a compact bright source in the fit: when the pixel footprint is on by default,
and channels the photo clipped at black (a glint on a film whose colour lies outside the
camera's gamut has a large negative channel; an 8-bit photo records 0 there).

References: the censored residual of a Tobit model (J. Tobin, Econometrica 26, 1958);
the map's power-preserving halving is an average over solid angle, so a source's peak at a
fixed texel size does not depend on the resolution the map was stored at.
"""

from __future__ import annotations

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
    lower: a model below the recorded value costs nothing, a model above it costs its distance."""
    from bubblefit.inverse import search

    y = np.array([[0.001, 0.20, 0.03]])      # red clipped at black
    w2 = np.array([[1e6, 1e4, 1e5]])
    refl = np.array([[[model_red, 0.21, 0.03]]])
    fixed = np.zeros((1, 3))
    cost = float(np.asarray(search.pixel_costs(refl, fixed, y, w2))[0, 0])
    expected = 1e6 * counted**2 + 1e4 * 0.01**2
    assert cost == pytest.approx(expected, rel=1e-5)
