"""Newton's rings finer than the pixels: each pixel averages the gap's reflectance over its
box (J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed., sec. 2.1, Table 2.1: the
box aperture's transfer function ``sinc``); rings under two pixels apart alias and are
left out of the fit."""

from __future__ import annotations

import numpy as np
import pytest

from test_newton_stray import PITCH_UM, _box_rings, _scene_data


def _gauss_legendre_box(d, lam, n, cos_i, span_x, span_y, above, below, nodes):
    """The mean of the Airy reflectance over each pixel's box by ``nodes`` x ``nodes``
    Gauss-Legendre points of the linear thickness ``d + a span_x + b span_y`` (``a, b`` in
    ``[-1/2, 1/2]``), independent of the closed form."""
    from bubblefit.optics import film

    x, w = np.polynomial.legendre.leggauss(nodes)
    total = 0.0
    for a, wa in zip(0.5 * x, w):
        for b, wb in zip(0.5 * x, w):
            r = film.airy_reflectance(d + a * span_x + b * span_y, lam, n, cos_i, above, below)
            total = total + 0.25 * wa * wb * np.asarray(r, np.float64)
    return total


@pytest.mark.parametrize("n, above, below", [(1.0, 1.517, 1.517), (1.33, 1.0, 1.0), (1.38, 1.0, 1.517)])
def test_box_airy_reflectance_is_the_box_average(n, above, below):
    """The closed-form box mean of the Airy reflectance (each harmonic ``m`` of the phase by
    ``sinc(m u_x) sinc(m u_y)``, :func:`bubblefit.optics.film.box_airy_reflectance`) against
    Gauss-Legendre quadratures of the point reflectance over the pixel: an air gap between
    glasses, a water film in air, a coating on glass; thicknesses 0-3000 nm, 400-700 nm,
    fringes down to 2 pixels apart (the finest the fit keeps). A 9 x 9 rule integrates
    ``cos`` over ``+-pi/2`` to 1e-13, so the two agree to float32's rounding of a phase
    near 2 pi 15 (1e-6 of a fringe) and of a reflectance near 1 (``1 - T``): 1e-5 of the
    fringe's amplitude covers both. The 3 x 3 rule's error there is 8e-4 of the fringe's
    amplitude on one axis (|0.6374 - 2/pi|): under 2e-3 for both. A whole fringe across
    the pixel (all harmonics' ``sinc(m) = 0``) leaves the incoherent mean, ``1 - (1 -
    r01^2)(1 - r12^2) / (1 - q^2)``."""
    import jax.numpy as jnp

    from bubblefit.inverse._newton import MIN_FRINGE_PX
    from bubblefit.optics import film

    rng = np.random.default_rng(1)
    k = 500
    lam = rng.uniform(400.0, 700.0, k)
    d = rng.uniform(0.0, 3000.0, k)
    cos_i = np.sqrt(1.0 - rng.uniform(0.0, 0.1, k) / above ** 2)  # light from an objective of NA 0.3
    fringe = lam / (2.0 * n)  # nm of thickness per fringe
    slope = rng.uniform(0.0, 1.0 / MIN_FRINGE_PX, k) * fringe * 0.99
    ang = rng.uniform(0.0, 2.0 * np.pi, k)
    sx, sy = slope * np.cos(ang), slope * np.sin(ang)
    box = np.asarray(film.box_airy_reflectance(d, lam, n, cos_i, sx, sy, above, below), np.float64)
    amp = np.ptp(np.asarray(film.airy_reflectance(np.linspace(0.0, 600.0, 800)[:, None], lam, n, cos_i, above,
                                                  below)), axis=0)
    fine = _gauss_legendre_box(d, lam, n, cos_i, sx, sy, above, below, 9)
    coarse = _gauss_legendre_box(d, lam, n, cos_i, sx, sy, above, below, 3)
    point = np.asarray(film.airy_reflectance(d, lam, n, cos_i, above, below), np.float64)
    assert np.all(np.abs(box - fine) < 1e-5 * amp + 1e-7)
    assert np.all(np.abs(box - coarse) < 2e-3 * amp + 1e-7)
    assert np.max(np.abs(box - point) / amp) > 0.1  # the box matters: (1 - sinc(1/2)) / 2 = 0.18 at 2 pixels
    assert np.array_equal(np.asarray(film.box_airy_reflectance(d, lam, n, cos_i, 0.0 * sx, 0.0 * sy, above, below)),
                          np.asarray(film.airy_reflectance(d, lam, n, cos_i, above, below)))
    cos_t = np.sqrt(1.0 - (above / n) ** 2 * (1.0 - cos_i ** 2))
    whole = np.asarray(film.box_airy_reflectance(d, lam, n, cos_i, fringe / cos_t, 0.0 * d, above, below))
    r01 = np.asarray(film.fresnel_amplitudes(jnp.asarray(cos_i), n, above), np.float64)
    r12 = np.asarray(film.fresnel_amplitudes(jnp.asarray(cos_t), below, n), np.float64)
    q = -r01 * r12
    assert np.allclose(whole, 1.0 - (1.0 - r01 ** 2) * (1.0 - r12 ** 2) / (1.0 - q * q), atol=1e-5)


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

    monkeypatch.setattr(nw, "pixel_mean", lambda fwd, h, s2, b, gx, gy, pitch, lo, hi: fwd.rgb(h, s2, b))
    old, chi2_old, _ = fit()
    assert abs(old.params["radius_mm"] - radius_um / 1000.0) > 3.0 * old.stderr["radius_mm"] or chi2_old > bound
