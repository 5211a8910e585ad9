"""Newton's rings whose gap runs past the scene's searched range.

The gap of a sphere on a flat, ``h = R - sqrt(R^2 - r^2) + h0`` (Born and Wolf,
*Principles of Optics*, sec. 7.5.3), is the lens's wherever the photo reaches: the scene's
``range_nm`` bounds the per-pixel map that starts the fit (its colour table, whose memory
grows with the range), not the lens's gap.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_newton_stray import _scene_data


def test_forward_reaches_the_gap(tmp_path):
    """:meth:`PlanarForward.reaching`: the fringes' contrast at 10-14 um of the sodium doublet
    (2:1 lines at 588.995 and 589.592 nm, 0.6 nm apart: they beat at 145 um) through bins
    narrowed for a 14 um gap (1.07 nm) is within 5 % of the doublet's own: the lamp CSV read
    per nanometre (cells at 589 and 590 nm, 2.1:1) keeps a contrast ``|0.68 + 0.32 exp(i 4 pi
    h / lambda^2 1 nm)|`` of 0.99-0.97 there. Through the 5 nm bins of a 3 um reach (the light
    at 587.5 and 592.5 nm, 0.82:0.18) it is ``|0.82 + 0.18 exp(i 4 pi h / lambda^2 5 nm)|``,
    0.80 at 10 um: below 0.85. The lamp lights a few bins: only those are kept."""
    import jax.numpy as jnp

    from bubblefit.inverse.planar import SPECTRAL_SAMPLES, PlanarForward
    from bubblefit.model.planar_scene import parse_planar

    scene = parse_planar(_scene_data(tmp_path), tmp_path)
    near = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 4000.0)
    far = near.reaching(14000.0)
    assert near.reaching(3000.0) is near and near.basis.samples == SPECTRAL_SAMPLES
    assert far.basis.samples > SPECTRAL_SAMPLES and len(np.asarray(far.lam)) < 8
    h = jnp.linspace(10000.0, 14000.0, 4001)  # 14 fringes, 1 nm apart
    lines = np.asarray(near.reflectance(h, jnp.zeros_like(h), lam=np.array([588.995, 589.592]))) @ [2 / 3, 1 / 3]
    contrast = {f: float(np.ptp(np.asarray(f.rgb(h, jnp.zeros_like(h)))[:, 1])) for f in (near, far)}
    assert abs(contrast[far] / np.ptp(lines) - 1.0) < 0.05
    assert contrast[near] / np.ptp(lines) < 0.85


@pytest.mark.slow
def test_rings_past_the_searched_range(tmp_path):
    """A 120x90 grey photo of Newton's rings under sodium light (R = 100 mm, contact offset
    40 nm, the contact point near a corner: the gap reaches 9.1 um at the far corner, 31
    fringes, rings 2.2 pixels apart there), rendered by the model itself (each pixel's mean
    over its box), a stray reflectance of 0.2, Gaussian noise 0.01 and 8-bit steps, fitted
    with the scene's range 0-4000 nm (27 % of the pixels lie beyond it): R within 3 of its
    standard errors (the noise's 99.7 %), ``ok`` (no warning), the map past 4000 nm."""
    import jax.numpy as jnp

    from bubblefit.inverse._newton import newton_gap, newton_gap_gradient, pixel_mean
    from bubblefit.inverse.planar import PlanarForward, fit_planar, view_of
    from bubblefit.model.planar_scene import parse_planar

    radius_um, h0, stray, pitch = 100000.0, 40.0, 0.2, 10.0
    data = _scene_data(tmp_path, width=120, height=90)
    data["light"]["envelope"] = "none"  # a uniform lamp: the lens, the exposure and b
    scene = parse_planar(data, tmp_path)
    view = view_of(scene)
    cx, cy = 12.0 * pitch, 9.0 * pitch
    dx, dy = jnp.asarray(view.x_um - cx), jnp.asarray(view.y_um - cy)
    gap = np.asarray(newton_gap(jnp.hypot(dx, dy), radius_um, h0))
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 4000.0).reaching(float(gap.max()))
    gx, gy = newton_gap_gradient(dx, dy, radius_um)
    lin = np.asarray(pixel_mean(fwd, jnp.asarray(gap.ravel()), jnp.zeros(gap.size), stray, gx.ravel(), gy.ravel(),
                                pitch, 0.0, np.inf), np.float64).reshape(gap.shape + (3,))
    lin *= 0.8 / lin.max()
    noise = np.random.default_rng(0).normal(0.0, 0.01, lin.shape[:2])[..., None]  # one grey value per pixel
    photo = np.round(np.clip(lin + noise, 0.0, 1.0) * 255.0) / 255.0
    assert 0.2 < float(np.mean(gap > 4000.0)) < 0.35

    res = fit_planar(photo, scene, clip_high=1.0)
    p, se = res.params, res.stderr
    assert res.ok, res.warnings
    assert abs(p["radius_mm"] - radius_um / 1000.0) < 3.0 * se["radius_mm"]
    assert float(np.nanmax(res.thickness_map)) > 4000.0
