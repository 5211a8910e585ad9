"""Newton's rings with light that does not interfere: a grey stray reflectance added to the gap's.

The pixel's colour is ``g L rgb(R(h) + b)`` (Born and Wolf, *Principles of Optics*, sec.
7.5.1: beams without a fixed phase relation add their intensities; sec. 7.5.3, Newton's
rings): the other surfaces' reflections fill in the dark rings and lower the fringes'
contrast, which the gap's reflectance alone cannot.
"""

from __future__ import annotations

import numpy as np
import pytest

from bubblefit.errors import InputError

PITCH_UM = 10.0


def _scene_data(tmp_path, stray=None, kind="newton", width=64, height=48):
    lam = np.arange(380.0, 780.0001, 0.01)  # the sodium D doublet, lines 0.05 nm wide, D2 twice D1
    power = np.exp(-0.5 * ((lam - 588.995) / 0.05) ** 2) + 0.5 * np.exp(-0.5 * ((lam - 589.592) / 0.05) ** 2)
    np.savetxt(tmp_path / "sodium.csv", np.column_stack([lam, power]), delimiter=",", header="wavelength_nm,power",
               comments="", fmt="%.2f,%.6g")
    (tmp_path / "grey.csv").write_text("wavelength_nm,r,g,b\n" + "".join(f"{w},1,1,1\n" for w in range(380, 781, 5)))
    film = {"shape": "plane", "n": "air", "above": "bk7", "below": "bk7", "thickness": kind, "range_nm": [0.0, 4000.0]}
    if stray is not None:
        film["stray"] = stray
    return {"film": film, "light": {"type": "coaxial", "na": 0.0, "lamp": "sodium.csv"},
            "camera": {"width": width, "height": height, "pixel_um": PITCH_UM, "response": str(tmp_path / "grey.csv")}}


def _box_rings(fwd, view, cx, cy, radius_um, h0, stray, n_sub=8):
    """(H, W, 3) linear colours of Newton's rings about ``(cx, cy)``, each pixel the mean of
    its ``n_sub`` x ``n_sub`` sub-pixel centres (the midpoint rule of the pixel's box: the
    camera integrates over its pixel, independent of the model's Gauss-Legendre points)."""
    import jax.numpy as jnp

    from bubblefit.inverse._newton import newton_gap

    sub = (np.arange(n_sub) + 0.5) / n_sub - 0.5
    lin = 0.0
    for sx in sub:
        for sy in sub:
            r = np.hypot(view.x_um + sx * PITCH_UM - cx, view.y_um + sy * PITCH_UM - cy)
            gap = newton_gap(jnp.asarray(r), radius_um, h0)
            lin = lin + np.asarray(fwd.rgb(gap, np.zeros_like(r), stray), np.float64) / n_sub ** 2
    return lin


def test_stray_scene_key(tmp_path):
    """``[film] stray``: fitted by default for Newton's rings, a number fixes it, the other
    models refuse it in one line (under one thickness it is not told apart from the thickness)."""
    from bubblefit.model.planar_scene import parse_planar

    assert parse_planar(_scene_data(tmp_path), tmp_path).stray == "fit"
    assert parse_planar(_scene_data(tmp_path, 0.0), tmp_path).stray == 0.0
    assert parse_planar(_scene_data(tmp_path, 0.05), tmp_path).stray == 0.05
    assert parse_planar(_scene_data(tmp_path, kind="constant"), tmp_path).stray == 0.0
    for data in (_scene_data(tmp_path, "fit", kind="map"), _scene_data(tmp_path, 0.1, kind="constant"),
                 _scene_data(tmp_path, "yes"), _scene_data(tmp_path, -0.1)):
        with pytest.raises(InputError, match="film.stray"):
            parse_planar(data, tmp_path)


def test_linear_exposure_and_stray():
    """The exposure and the stray light are linear in ``(g, g b)``: least squares gives
    them exactly from noiseless colours; a negative ``b`` (not a reflectance) is held at 0."""
    from bubblefit.inverse._newton import _linear_exposure

    rng = np.random.default_rng(0)
    unit = rng.uniform(0.0, 0.15, (50, 3))
    white = np.ones((50, 3))
    g, b = _linear_exposure(unit, white, 2.5 * (unit + 0.2 * white), True)
    assert (g, b) == (pytest.approx(2.5, rel=1e-12), pytest.approx(0.2, rel=1e-12))
    g, b = _linear_exposure(unit, white, 2.5 * unit - 0.1, True)
    assert b == 0.0 and g > 0
    g, b = _linear_exposure(unit, white, 2.5 * (unit + 0.2 * white), False)
    assert b == 0.0


@pytest.mark.slow
def test_rings_with_stray_light(tmp_path):
    """A 64x48 grey photo of Newton's rings under sodium light (lens R = 60 mm on BK7, six
    fringes, rings 3.8 pixels wide at the photo's edge) with a grey stray reflectance of 0.2
    added (each pixel's mean over its box; 2.5 times the gap's mean Airy reflectance 0.081, which leaves fringes of 0.20
    of the mean, rms, about the 0.18 of the real sodium photos of
    experiments/real_photos.py), Gaussian noise 0.01 and 8-bit steps. The model with the
    stray term finds R and b within 3 of their standard errors (the noise's 99.7 %); the
    model without it (``stray = 0``), which must darken the rings to zero, is not ``ok``
    and misses R by more than 3 of its own standard errors."""
    from bubblefit.inverse.planar import PlanarForward, fit_planar, view_of
    from bubblefit.model.planar_scene import parse_planar

    radius_um, h0, stray = 60000.0, 30.0, 0.2
    scene = parse_planar(_scene_data(tmp_path), tmp_path)
    view = view_of(scene)
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 4000.0)
    lin = _box_rings(fwd, view, 0.4 * scene.width * PITCH_UM, 0.55 * scene.height * PITCH_UM, radius_um, h0, stray)
    lin *= 0.8 / lin.max()
    noise = np.random.default_rng(0).normal(0.0, 0.01, lin.shape[:2])[..., None]  # one grey value per pixel
    photo = np.round(np.clip(lin + noise, 0.0, 1.0) * 255.0) / 255.0

    res = fit_planar(photo, scene, clip_high=1.0)
    p, se = res.params, res.stderr
    assert res.ok, res.warnings
    assert abs(p["radius_mm"] - radius_um / 1000.0) < 3.0 * se["radius_mm"]
    assert abs(p["stray_reflectance"] - stray) < 3.0 * se["stray_reflectance"]

    old = fit_planar(photo, parse_planar(_scene_data(tmp_path, 0.0), tmp_path), clip_high=1.0)
    assert old.params["stray_reflectance"] == 0.0
    assert not old.ok
    assert abs(old.params["radius_mm"] - radius_um / 1000.0) > 3.0 * old.stderr["radius_mm"]


def test_neighbour_noise_of_a_grey_photo():
    """A grey photo's noise from neighbouring pixels (:func:`bubblefit.inverse.planar._neighbour_sigma`):
    a film's smooth fringes (periods of 30-40 pixels) plus Gaussian noise of 0.02, over a
    disc. The neighbours' difference leaves of the fringes at most a quarter of their
    Laplacian, ``0.25 * 0.3 * ((2 pi / 40)^2 + (2 pi / 30)^2) = 0.0052``, so without noise
    the estimate stays under ``1.4826 * 0.0052 / sqrt(5/4)``; that adds at most 7 % of 0.02
    in quadrature, and the median absolute deviation of ~2800 differences, each sharing
    pixels with its four neighbours, has a relative standard error under 4 %: the noisy
    estimate is within 15 % of 0.02. Fewer than 20 usable pixels give None."""
    from bubblefit.inverse.planar import _neighbour_sigma

    yy, xx = np.mgrid[:64, :64].astype(float)
    mask = (xx - 31.5) ** 2 + (yy - 31.5) ** 2 < 30.0 ** 2
    fringes = 0.4 + 0.3 * np.sin(2 * np.pi * xx / 40.0) * np.cos(2 * np.pi * yy / 30.0)
    noisy = fringes + np.random.default_rng(3).normal(0.0, 0.02, fringes.shape)
    sigma = _neighbour_sigma(np.repeat(noisy[..., None], 3, axis=-1), mask)
    assert sigma == pytest.approx(0.02, rel=0.15)
    lap = 0.25 * 0.3 * ((2 * np.pi / 40.0) ** 2 + (2 * np.pi / 30.0) ** 2)
    assert _neighbour_sigma(np.repeat(fringes[..., None], 3, axis=-1), mask) < 1.4826 * lap / np.sqrt(1.25)
    tiny = np.zeros_like(mask)
    tiny[10:14, 10:14] = True
    assert _neighbour_sigma(np.repeat(noisy[..., None], 3, axis=-1), tiny) is None


@pytest.mark.slow
def test_grey_rings_without_stray_light(tmp_path):
    """Newton's rings as :func:`test_rings_with_stray_light`'s, with no stray light: the
    grey photo's one reading a pixel leaves each pixel's own thickness no residual, so the
    noise is read from neighbouring pixels. The fit states the photo's noise, 0.01 with the
    8-bit step's 1/255/sqrt(12) added in quadrature (0.01006), within 15 % (the estimate's
    own scatter is under 4 %), its reduced chi^2 is that of noise (within 0.3 of 1), it is
    ``ok``, R is within 3 standard errors, and the stray reflectance, which the fit takes
    below its bound of 0, is reported at 0 with the unbounded fit's positive error."""
    from bubblefit.inverse.planar import PlanarForward, fit_planar, view_of
    from bubblefit.model.planar_scene import parse_planar

    radius_um, h0 = 60000.0, 30.0
    scene = parse_planar(_scene_data(tmp_path), tmp_path)
    view = view_of(scene)
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 4000.0)
    lin = _box_rings(fwd, view, 0.4 * scene.width * PITCH_UM, 0.55 * scene.height * PITCH_UM, radius_um, h0, 0.0)
    lin *= 0.8 / lin.max()
    noise = np.random.default_rng(0).normal(0.0, 0.01, lin.shape[:2])[..., None]
    photo = np.round(np.clip(lin + noise, 0.0, 1.0) * 255.0) / 255.0

    res = fit_planar(photo, scene, clip_high=1.0)
    assert res.sigma == pytest.approx(np.hypot(0.01, 1.0 / 255.0 / np.sqrt(12.0)), rel=0.15)
    assert abs(res.reduced_chi2 - 1.0) < 0.3
    assert res.ok, res.warnings
    assert abs(res.params["radius_mm"] - radius_um / 1000.0) < 3.0 * res.stderr["radius_mm"]
    assert res.params["stray_reflectance"] == 0.0
    assert 0.0 < res.stderr["stray_reflectance"] < 1e-3
