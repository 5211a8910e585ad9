"""Newton's rings finer than the pixels: each pixel averages the gap's reflectance over its
box (J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed., sec. 2.1, Table 2.1: the
box aperture's transfer function ``sinc``); rings under two pixels apart alias and are
left out of the fit."""

from __future__ import annotations

import numpy as np
import pytest

from test_newton_stray import PITCH_UM, _box_rings, _scene_data


def test_pixel_mean_of_two_beam_fringes_is_the_box_sinc():
    """For ``cos(delta)`` with ``delta`` linear across a square pixel, the pixel's mean is
    ``cos(delta_c) sinc(g_x p/2) sinc(g_y p/2)``. The 3-point rule's error on one axis at
    ``+-pi/2`` (fringes 2 pixels apart, the finest the fit keeps) is 8e-4 of the fringe's
    amplitude (|0.6374 - 2/pi|); the two axes' means multiply: under 2e-3 in all."""
    import jax.numpy as jnp

    from bubblefit.inverse._newton import MIN_FRINGE_PX, pixel_mean

    fringe, pitch = 300.0, 10.0
    rng = np.random.default_rng(1)
    n = 400
    h = rng.uniform(0.0, 3000.0, n)
    slope = rng.uniform(0.0, fringe / (MIN_FRINGE_PX * pitch), n)  # nm per um, fringes >= 2 px apart
    ang = rng.uniform(0.0, 2.0 * np.pi, n)
    gx, gy = slope * np.cos(ang), slope * np.sin(ang) / np.sqrt(2.0)

    def colour(hs):
        return jnp.repeat(jnp.cos(2.0 * jnp.pi * hs / fringe)[:, None], 3, -1)

    mean = np.asarray(pixel_mean(colour, jnp.asarray(h), jnp.asarray(gx), jnp.asarray(gy), pitch, -1e9, 1e9))
    k = 2.0 * np.pi / fringe  # phase per nm of gap
    expect = np.cos(k * h) * np.sinc(k * gx * pitch / 2.0 / np.pi) * np.sinc(k * gy * pitch / 2.0 / np.pi)
    assert np.max(np.abs(mean[:, 1] - expect)) < 2e-3
    # fringes at the pixel pitch (a whole fringe per pixel) average out
    one = np.asarray(pixel_mean(colour, jnp.zeros(1), jnp.asarray([fringe / pitch]), jnp.zeros(1), pitch, -1e9, 1e9))
    assert abs(one[0, 1]) < 0.1  # the rule's mean of cos over +-pi: 0.0219 (3 points), exact 0


def test_aliased_pixels():
    """Fringes under two pixels apart: the gap changes by more than half a fringe per pixel."""
    from bubblefit.inverse._newton import aliased_pixels, newton_gap_gradient

    import jax.numpy as jnp

    gx, gy = newton_gap_gradient(jnp.asarray([100.0, 0.0, 300.0]), jnp.asarray([0.0, 200.0, 300.0]), 20000.0)
    # dh/dr = r / sqrt(R^2 - r^2) um/um: 100 um from contact 5.0 nm/um, 200 um 10.0, 424 um 21.2
    assert np.allclose(np.hypot(gx, gy), 1000.0 * np.array([100.0, 200.0, 424.264]) /
                       np.sqrt(20000.0 ** 2 - np.array([100.0, 200.0, 424.264]) ** 2), rtol=1e-5)
    # fringe 300 nm, pitch 10 um: aliased above 15 nm/um
    assert aliased_pixels(gx, gy, 10.0, 300.0).tolist() == [False, False, True]


def _rings_photo(tmp_path, radius_um, h0, stray, n_sub=8, size=48):
    """A grey photo of Newton's rings rendered by averaging each pixel's ``n_sub`` x ``n_sub``
    sub-pixel centres (the midpoint rule of the pixel's box, independent of the model's
    Gauss-Legendre points), Gaussian noise 0.01 per pixel and 8-bit steps."""
    from bubblefit.inverse.planar import PlanarForward, view_of
    from bubblefit.model.planar_scene import parse_planar

    scene = parse_planar(_scene_data(tmp_path, width=size, height=size), tmp_path)
    view = view_of(scene)
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 4000.0)
    cx, cy = 0.5 * size * PITCH_UM, 0.5 * size * PITCH_UM
    lin = _box_rings(fwd, view, cx, cy, radius_um, h0, stray, n_sub)
    lin = lin * 0.8 / lin.max()
    noise = np.random.default_rng(3).normal(0.0, 0.01, lin.shape[:2])[..., None]
    photo = np.round(np.clip(lin + noise, 0.0, 1.0) * 255.0) / 255.0
    return scene, view, fwd, photo, (cx, cy)


def test_rings_at_the_pixel_pitch(tmp_path, monkeypatch):
    """A 48x48 grey photo of sodium Newton's rings (R = 18.5 mm on BK7, stray reflectance
    0.2, 10 um pixels) whose rings come 2.3 pixels apart at the edges' middles and 1.6 in
    the corners. The pixel-averaged model leaves the aliased corners out (a note) and
    finds ``R`` and ``b`` within 3 of their standard errors with a reduced chi^2 within 5 of its
    standard deviations ``sqrt(2/N)`` of 1 (plus 0.05: the 8-bit steps' variance, 1.3 %
    of the noise's, and the quadrature rules' errors); the model sampled at each pixel's
    centre (the rule's one middle point) keeps the fringes' full contrast and misses by more."""
    import jax.numpy as jnp

    import bubblefit.inverse._newton as nw

    radius_um, h0, stray, sigma = 18500.0, 30.0, 0.2, 0.01
    scene, view, fwd, photo, (cx, cy) = _rings_photo(tmp_path, radius_um, h0, stray)
    mask = view.mask
    y = photo.reshape(-1, 3)[mask.ravel()]
    lum, sin2 = view.radiance[mask], view.sin2[mask]
    truth = np.asarray(nw.newton_gap(jnp.asarray(np.hypot(view.x_um - cx, view.y_um - cy)[mask]), radius_um, h0))

    def fit():
        res = nw.fit_newton(fwd, y, lum, sin2, view, mask, truth, 1.0, sigma, 0.0, 4000.0, 1.0, envelope="none")
        keep = res.fitted
        chi2 = float(np.mean((y[keep, 1] - res.model[keep, 1]) ** 2) / sigma ** 2)
        return res, chi2, keep.sum()

    res, chi2, n = fit()
    assert res.notes and "aliased" in res.notes[0]
    assert 0 < (~res.fitted).sum() < 0.3 * len(y)
    bound = 1.0 + 5.0 * np.sqrt(2.0 / n) + 0.05
    p, se = res.params, res.stderr
    assert abs(p["radius_mm"] - radius_um / 1000.0) < 3.0 * se["radius_mm"]
    assert chi2 < bound
    assert abs(p["stray_reflectance"] - stray) < 3.0 * se["stray_reflectance"]

    monkeypatch.setattr(nw, "_NODES", np.zeros(1))
    monkeypatch.setattr(nw, "_WEIGHTS", np.full(1, 2.0))
    old, chi2_old, _ = fit()
    assert abs(old.params["radius_mm"] - radius_um / 1000.0) > 3.0 * old.stderr["radius_mm"] or chi2_old > bound
