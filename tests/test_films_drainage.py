"""A vertical flat film draining along gravity: the profile model of ``thickness = "drainage"``.

References, all independent of the package: the pinhole camera and the ray-plane
intersection written out here; the film colours of
``experiments/validation/reference_films.py`` (numpy and colour-science: complex Airy
sum, water from Daimon & Masumura's Sellmeier law, CIE 1931 observer); the profile
``top + (bottom - top) f^exponent`` with ``f`` the depth below the frame's top edge over
its height, written out here.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "experiments" / "validation"))

FRAME, DIST, FOV, SIZE = 0.18, 0.6, 30.0, 64


def _scene(kind="drainage", size=SIZE):
    from bubblefit.model.planar_scene import parse_planar

    return parse_planar({
        "film": {"shape": "plane", "n": "water", "thickness": kind, "range_nm": [0.0, 1600.0],
                 "center": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0], "up": [0.0, 1.0, 0.0],
                 "size": [FRAME, FRAME]},
        "light": {"type": "area", "shape": "rect", "center": [0.0, 0.0, 0.7], "normal": [0.0, 0.0, -1.0],
                  "up": [0.0, 1.0, 0.0], "size": [1.0, 1.0], "lamp": "D65"},
        "camera": {"type": "perspective", "width": size, "height": size, "origin": [0.0, 0.0, DIST],
                   "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_deg": FOV}})


def _hit_y(row: float, size: int = SIZE) -> float:
    """Height (m) where the ray through image row ``row`` (continuous, 0 = top edge) meets
    the film plane z = 0, for the camera on the axis at z = DIST: y = DIST tan(fov/2) (1 - 2 row / H)."""
    return DIST * math.tan(math.radians(FOV) / 2) * (1.0 - 2.0 * row / size)


def test_film_height_is_the_frame_coordinate_of_each_pixel():
    from bubblefit.inverse.planar import view_of

    v = view_of(_scene())
    rows = np.arange(SIZE)
    expect = np.array([_hit_y(r + 0.5) for r in rows]) / (FRAME / 2)
    col = SIZE // 2
    on = v.mask[:, col]
    np.testing.assert_allclose(v.height[on, col], expect[on], atol=1e-9)
    # a pixel is on the film when its whole footprint is: its top and bottom edges' rays too
    whole = np.array([abs(_hit_y(r)) <= FRAME / 2 and abs(_hit_y(r + 1)) <= FRAME / 2 for r in rows])
    assert np.array_equal(on, whole)
    centre_only = np.array([abs(_hit_y(r + 0.5)) <= FRAME / 2 for r in rows])
    assert centre_only.sum() > whole.sum()  # the frame's edge crosses pixels that are left out


def test_global_search_finds_a_closed_form_profile_in_independent_colours():
    """Colours of the reference renderer, no noise: the cost volume's search lands within
    its grid (6 nm on the ends, the nearest tried exponent) of a profile it did not make."""
    import reference_films as rf

    from bubblefit.inverse import search_drainage

    lam, w = rf.colour_weights("D65")
    n1, one = rf.index("water", lam), np.ones_like(lam)
    top, bottom, expo = 150.0, 1050.0, 1.4
    height = np.linspace(1.0, -1.0, 200)
    f = (1.0 - height) / 2
    d = top + (bottom - top) * f ** expo
    grid = np.arange(0.0, 1600.0 + 1, 2.0)
    table = rf.stack_reflectance(grid, lam, one, n1, one, 0.0) @ w.T
    y = rf.stack_reflectance(d, lam, one, n1, one, 0.0) @ w.T
    cost = ((y[:, None, :] - table[None, :, :]) ** 2).sum(-1)
    t, b, e = search_drainage(cost, grid, height)
    assert abs(t - top) <= 6.0 and abs(b - bottom) <= 6.0 and e == 1.4
    # a region of known thickness keeps only the profiles through it
    t, b, e = search_drainage(cost, grid, height, reference=(0.5, top + (bottom - top) * 0.5 ** expo), window_nm=20.0)
    assert abs(t - top) <= 6.0 and abs(b - bottom) <= 6.0


@pytest.mark.slow
@pytest.mark.parametrize("top, bottom, expo", [(200.0, 900.0, 0.8), (90.0, 1250.0, 1.8)])
def test_drainage_fit_of_an_independent_render(top, bottom, expo):
    """Reference renderer's vertical film under a panel, Poisson-Gaussian noise, 8-bit sRGB:
    the ends within 3 standard errors (the model error of 0.6 nm included) and 5 nm."""
    import reference_films as rf
    import vio

    from bubblefit.inverse.planar import fit_planar
    from bubblefit.io.images import srgb_decode

    d, rgb, _ = rf.drainage_area_case(SIZE, top, bottom, expo, "D65", "water")
    exposure = 0.9 / float(np.nanpercentile(rgb, 99.5))
    codes = vio.add_noise_and_quantise(rgb * exposure, np.random.default_rng(7))
    res = fit_planar(srgb_decode(codes / 255.0), _scene(), clip_high=1.0)
    assert res.ok, res.warnings
    for key, true in (("top_nm", top), ("bottom_nm", bottom)):
        err = res.params[key] - true
        assert abs(err) <= 3.0 * res.stderr[key] and abs(err) <= 5.0, (key, res.params, res.stderr)
    assert abs(res.params["exponent"] - expo) <= 0.01
    on = np.isfinite(res.thickness_map) & np.isfinite(d)
    assert np.median(np.abs(res.thickness_map - d)[on]) <= 2.0


def test_model_error_reaches_the_exponent_through_the_middle_height():
    """log(exponent) = (d_mid - (1 - h) top - h bottom) / slope with h = 0.5^e and slope =
    (bottom - top) h ln(0.5) e: independent errors s at the top, bottom and middle give it
    the variance s^2 (1 + (1 - h)^2 + h^2) / slope^2; the ends keep s^2."""
    from bubblefit.inverse import JudgeSettings
    from bubblefit.inverse import drainage_covariance

    s2 = JudgeSettings.thickness_model_error_nm ** 2
    top, bottom, e = 100.0, 900.0, 1.5
    h = 0.5 ** e
    slope = (bottom - top) * h * math.log(0.5) * e
    cov = drainage_covariance(top, bottom, e)
    np.testing.assert_allclose(np.diag(cov), [s2, s2, s2 * (1 + (1 - h) ** 2 + h ** 2) / slope ** 2], rtol=1e-12)
    assert np.isinf(drainage_covariance(300.0, 300.0, 1.0)[2, 2])   # a flat film has no exponent
