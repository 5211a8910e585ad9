"""Where a map's texel rows sit: a map made for Blender Cycles (texel centres at
``v = (i + 1/2) / H``) re-expressed on bubblefit's rows (``v = i / (H - 1)``) by
:func:`bubblefit.lighting.envmap.from_texel_centres`, checked against a closed form: a map
whose rows are a known linear function of the polar angle at their texel centres, which a
bilinear lookup in that convention returns exactly at every polar angle between the first
and the last centre."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.lighting.envmap import EnvMap, from_texel_centres, uv_to_direction

H, W = 16, 32
#: Float32 lookups of values up to ~4: a few roundings of 2^-24 relative each, and the
#: direction's polar angle itself recovered in float32 (acos near the poles loses most).
TOL = 2e-5 * 4 + 1e-4


def _latitude_map():
    """Rows ``theta_i (1 + a_j)`` with ``theta_i = pi (i + 1/2) / H`` the texel centres'
    polar angles and ``a_j`` a per-column factor: linear in the polar angle along a column."""
    theta = np.pi * (np.arange(H) + 0.5) / H
    a = 0.3 * np.sin(2 * np.pi * (np.arange(W) + 0.5) / W)
    row = theta[:, None] * (1.0 + a[None, :])
    return np.repeat(row[..., None], 3, axis=-1), theta, a


def _read(pixels, theta, col):
    u = np.full_like(theta, (col + 0.5) / W)
    d = np.asarray(uv_to_direction(u, theta / np.pi), np.float64)
    return np.asarray(EnvMap.from_array(pixels).lookup(d), np.float64)[:, 0]


@pytest.mark.parametrize("col", [0, 7, 20])
def test_texel_centre_map_reads_its_closed_form(col):
    px, theta_c, a = _latitude_map()
    theta = np.linspace(theta_c[0], theta_c[-1], 301)
    got = _read(from_texel_centres(px), theta, col)
    np.testing.assert_allclose(got, theta * (1.0 + a[col]), atol=TOL, rtol=0)
    # beyond the outer centres the texel-centre lookup is the pole row's value
    poles = np.array([0.25 * theta_c[0], np.pi - 0.25 * theta_c[0]])
    np.testing.assert_allclose(_read(from_texel_centres(px), poles, col),
                               np.array([theta_c[0], theta_c[-1]]) * (1.0 + a[col]), atol=TOL, rtol=0)


def test_the_same_file_read_on_mitsuba_rows_is_off_by_up_to_half_a_texel():
    """Read as it is, row ``i`` sits at ``i / (H - 1)``: a direction at polar angle theta
    reads ``pi (v (H - 1) + 1/2) / H`` with ``v = theta / pi``, off by ``pi (1/2 - v) / H``
    (half a texel at the poles, none at the equator): the difference the option removes."""
    px, theta_c, a = _latitude_map()
    # (not at the poles themselves, where a direction has no azimuth to pick its column)
    theta = np.linspace(0.01, np.pi - 0.01, 301)
    v = theta / np.pi
    got = _read(px, theta, 0)
    np.testing.assert_allclose(got, np.pi * (v * (H - 1) + 0.5) / H * (1.0 + a[0]), atol=TOL, rtol=0)
    assert np.max(np.abs(got - theta * (1.0 + a[0]))) > 0.4 * np.pi / H


def test_conversion_keeps_every_texel():
    """The file's texels are the odd rows, at their own centres ``v = (i + 1/2) / H``."""
    px, _, _ = _latitude_map()
    out = from_texel_centres(px)
    assert out.shape == (2 * H + 1, W, 3)
    np.testing.assert_array_equal(out[1::2], px)


def _scene(tmp_path, extra):
    from bubblefit.io.images import write_image
    from bubblefit.model.cap_scene import parse_cap_scene

    write_image(str(tmp_path / "env.exr"), np.ones((8, 16, 3), np.float32))
    text = ('[film]\nshape = "cap"\nradius = 1.0\nplane_y = 0.0\n[environment]\npath = "env.exr"\n'
            f'{extra}\n[camera]\ntype = "perspective"\nwidth = 32\nheight = 32\norigin = [0.0, 1.0, 5.0]\n'
            'target = [0.0, 0.0, 0.0]\n')
    return parse_cap_scene(tomllib.loads(text), tmp_path)


def test_a_cap_scene_says_its_maps_convention(tmp_path):
    from bubblefit.model.scene import read_envmap

    assert _scene(tmp_path, "").env_convention == "mitsuba"
    scene = _scene(tmp_path, 'convention = "texel-centre"')
    assert scene.env_convention == "texel-centre"
    assert read_envmap(scene.envmap, convention=scene.env_convention).height == 2 * 8 + 1
    with pytest.raises(InputError, match="environment.convention") as err:
        _scene(tmp_path, 'convention = "blender"')
    assert "\n" not in str(err.value)
