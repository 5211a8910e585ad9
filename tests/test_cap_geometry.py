"""A bubble on a dish: the cap's geometry and its mirror image in the liquid.

Independent references written out here: the image of a sphere in a plane mirror is the
sphere reflected about the plane (a ray reflected at the liquid meets the cap where the
straight ray meets the mirrored sphere, mirrored back), the ray-sphere quadratic, and
Fresnel's formulae for one interface.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.model.cap import Cap, trace_cap

N_LIQUID = 1.333


def _sphere_near(o, d, c, r):
    """Near root of |o + s d - c|^2 = r^2 (NaN where the ray misses), for unit d."""
    oc = o - c
    b = np.sum(oc * d, -1)
    disc = b * b - (np.sum(oc * oc, -1) - r * r)
    s = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    return np.where(s > 0, s, np.nan)


def _rays(n=6000, seed=3):
    """Rays from a camera above and beside the dish, towards random points around the cap."""
    rng = np.random.default_rng(seed)
    o = np.tile([0.3, 2.0, 4.0], (n, 1))
    target = rng.uniform([-2.0, -2.0, -2.0], [2.0, 1.2, 2.0], (n, 3))
    d = target - o
    return o, d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.mark.parametrize("plane_y", [0.0, -0.4, 0.5])   # a hemisphere, a taller and a lower cap
def test_the_liquid_shows_the_cap_as_a_plane_mirror_would(plane_y):
    cap = Cap(center=(0.1, 0.0, -0.2), radius=1.0, plane_y=plane_y, liquid=N_LIQUID)
    o, d = _rays()
    v = trace_cap(o, d, cap)
    c = np.array(cap.center)
    # the cap seen directly: the near root above the plane, and nothing of the plane before it
    s = _sphere_near(o, d, c, 1.0)
    direct = np.isfinite(s) & ((o + np.nan_to_num(s)[:, None] * d)[:, 1] >= plane_y)
    # the package traces in float32: rays grazing the silhouette or the foot may fall
    # either way (a few in 10^4)
    assert np.mean(v.film != direct) <= 1e-3
    # seen in the liquid: the straight ray meets the sphere mirrored about the plane, below it
    c_m = c * np.array([1, -1, 1]) + np.array([0, 2 * plane_y, 0])
    s_m = _sphere_near(o, d, c_m, 1.0)
    q = o + np.nan_to_num(s_m)[:, None] * d
    mirrored = np.isfinite(s_m) & (q[:, 1] <= plane_y) & ~direct
    assert mirrored.sum() > 100
    assert np.mean(v.mirror_film != mirrored) <= 1e-3
    both = mirrored & v.mirror_film
    back = q * np.array([1, -1, 1]) + np.array([0, 2 * plane_y, 0])
    # float32 along rays ~5 units long: a few 1e-7 relative
    np.testing.assert_allclose(v.mirror_point[both], back[both], atol=1e-5)
    # the incidence on the mirrored cap is that of the straight ray on the mirrored sphere
    n_m = (q - c_m) / 1.0
    np.testing.assert_allclose(v.mirror_cos[both], np.abs(np.sum(n_m * d, -1))[both], atol=1e-4)


def test_liquid_reflectance_is_fresnels():
    cap = Cap(center=(0.0, 0.0, 0.0), radius=1.0, plane_y=0.0, liquid=N_LIQUID)
    ang = np.radians([0.5, 30.0, 60.0, 80.0])
    d = np.stack([np.sin(ang), -np.cos(ang), np.zeros_like(ang)], -1)
    o = np.stack([-3.0 * np.tan(ang) - 2.0, np.full_like(ang, 3.0), np.zeros_like(ang)], -1)
    v = trace_cap(o, d, cap)
    assert v.liquid.all() and not v.film.any()
    ci = np.cos(ang)
    ct = np.sqrt(1 - (np.sin(ang) / N_LIQUID) ** 2)
    rs = ((ci - N_LIQUID * ct) / (ci + N_LIQUID * ct)) ** 2
    rp = ((N_LIQUID * ci - ct) / (N_LIQUID * ci + ct)) ** 2
    np.testing.assert_allclose(v.liquid_reflectance[:, 0], 0.5 * (rs + rp), rtol=1e-5)


def test_heights_and_a_cap_taller_than_its_sphere():
    assert Cap((0, 0, 0), 2.0, 0.0).height == 2.0
    assert math.isclose(Cap((0, 0, 0), 2.0, 1.0).foot_radius, math.sqrt(3.0))
    with pytest.raises(InputError, match="taller than its sphere"):
        Cap((0, 0, 0), 1.0, -2.5)
    with pytest.raises(InputError, match="above the sphere"):
        Cap((0, 0, 0), 1.0, 1.5)


@pytest.mark.slow
@pytest.mark.parametrize("plane_y, words", [(-2.5, "taller than its sphere"), (1.5, "above the sphere")])
def test_a_cap_scene_is_refused_in_one_line(tmp_path, plane_y, words):
    scene = tmp_path / "cap.toml"
    scene.write_text(f'[film]\nshape = "cap"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nplane_y = {plane_y}\n')
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"")
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(photo), "--scene", str(scene),
                           "--json", str(tmp_path / "r.json")], capture_output=True, text=True, timeout=300)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and words in lines[0], proc.stderr
    assert not (tmp_path / "r.json").exists()
