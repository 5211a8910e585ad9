"""A calibrated response's share of the error bars of flat-film (planar) fits.

The photos are the package's own renders of a constant water film on BK7 under coaxial
light (``PlanarForward``), with Gaussian noise; the response is colour-science's Nikon
D5100 written as a CSV with correlated errors (tests/test_response_error.py). The
sandwich itself is checked against Monte Carlo in tests/test_response_error.py."""

import numpy as np
import pytest

from test_response_error import _modes_csv


def _scene(response):
    from bubblefit.model.planar_scene import parse_planar

    return parse_planar({"film": {"shape": "plane", "n": "water", "above": "air", "below": "bk7",
                                  "thickness": "constant", "range_nm": [0.0, 1600.0]},
                         "light": {"type": "coaxial", "na": 0.25, "lamp": "E"},
                         "camera": {"width": 16, "height": 16, "pixel_um": 2.0, "response": response}})


def _photo(scene, d, rng, sigma=0.002):
    from bubblefit.inverse.planar import PlanarForward, view_of

    view = view_of(scene)
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 1600.0)
    rgb = np.asarray(fwd.rgb(np.full(int(view.mask.sum()), d), view.sin2[view.mask]), np.float64)
    photo = np.zeros((scene.height, scene.width, 3))
    photo[view.mask] = 0.6 * view.radiance[view.mask][:, None] * rgb / rgb.max() + sigma * rng.normal(size=rgb.shape)
    return photo


@pytest.mark.slow
@pytest.mark.parametrize("d", [600.0])
def test_planar_fits_state_the_camera_term(tmp_path, d):
    """With a response that states errors (3 % of the peak, 25 nm correlation) a constant
    film's and a thickness map's error bars hold the camera's share (``stderr_camera``,
    positive and inside ``stderr``); under coaxial light every pixel sees the same cone, so
    the constant film's term equals each map pixel's. A response taken as exact has none."""
    from bubblefit.inverse.planar import fit_planar

    path, _, _ = _modes_csv(tmp_path, 0.03, 25.0)
    rng = np.random.default_rng(2)
    scene = _scene(path)
    photo = _photo(scene, d, rng)
    const = fit_planar(photo, scene, kind="constant")
    cam = const.stderr_camera["thickness_nm"]
    assert cam > 0.1 and const.stderr["thickness_nm"] >= cam
    mapped = fit_planar(photo, scene, kind="map", reference_region=(0, 0, 16, 16), reference_nm=d)
    assert mapped.stderr_camera["thickness_nm"] == pytest.approx(cam, rel=0.05)
    assert np.nanmin(mapped.thickness_stderr_map) >= 0.95 * cam
    assert const.to_json()["stderr_camera"] == const.stderr_camera
    plain = fit_planar(_photo(_scene("Nikon 5100 (NPL)"), d, rng), _scene("Nikon 5100 (NPL)"), kind="constant")
    assert plain.stderr_camera is None


@pytest.mark.slow
def test_planar_drainage_states_the_camera_term(tmp_path):
    """A draining flat film (300 -> 900 nm down the frame) fitted as a drainage profile with
    a response that states errors: each profile parameter's camera share is positive and
    inside its standard error; with the response taken as exact there is none."""
    from bubblefit.inverse.planar import PlanarForward, fit_planar, view_of
    from bubblefit.model.thickness import drainage_profile

    path, _, _ = _modes_csv(tmp_path, 0.03, 25.0)
    rng = np.random.default_rng(5)
    for response, stated in ((path, True), ("Nikon 5100 (NPL)", False)):
        scene = _scene(response)
        view = view_of(scene)
        fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 1600.0)
        d = np.asarray(drainage_profile(view.height[view.mask], 300.0, 900.0, 1.0), np.float64)
        rgb = np.asarray(fwd.rgb(d, view.sin2[view.mask]), np.float64)
        photo = np.zeros((scene.height, scene.width, 3))
        photo[view.mask] = 0.6 * rgb / rgb.max() + 0.002 * rng.normal(size=rgb.shape)
        res = fit_planar(photo, scene, kind="drainage", reference_region=(0, 0, 16, 2), reference_nm=300.0)
        if not stated:
            assert res.stderr_camera is None
            continue
        for key in ("top_nm", "bottom_nm"):
            assert 0 < res.stderr_camera[key] <= res.stderr[key], (key, res.stderr_camera, res.stderr)
