"""Newton's rings under one wavelength: the contact point and the lens radius found without colour."""

import numpy as np
import pytest

from bubblefit.inverse._newton import rings_centre, rings_period

PITCH_UM = 25.9  # a 2x2-binned 12.94 um camera pixel
LAMBDA_UM = 0.5893  # sodium D


def _rings(cx, cy, radius_um, h0_um, noise, seed=0, w=120, h=90):
    """Independent closed form: I = a + b cos(4 pi h(r) / lambda + pi), h = h0 + r^2 / (2 R) (Hecht, Optics, 9.4)."""
    yy, xx = np.mgrid[0:h, 0:w]
    x, y = ((xx - w / 2) * PITCH_UM).ravel(), ((yy - h / 2) * PITCH_UM).ravel()
    gap = h0_um + ((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * radius_um)
    value = 0.5 + 0.4 * np.cos(4.0 * np.pi * gap / LAMBDA_UM + np.pi)
    return x, y, value + np.random.default_rng(seed).normal(0.0, noise, value.shape)


@pytest.mark.parametrize("cx, cy", [(300.0, -200.0), (1900.0, -700.0)])  # off the middle; past the right edge
def test_sodium_rings_centre_and_radius(cx, cy):
    radius = 1.0e6  # um
    x, y, value = _rings(cx, cy, radius, 0.05, noise=0.05)
    fx, fy = rings_centre(x, y, value, PITCH_UM)
    assert np.hypot(fx - cx, fy - cy) < 2.0 * PITCH_UM
    r2 = (x - fx) ** 2 + (y - fy) ** 2
    period, _ = rings_period(r2, value, 4.0 * PITCH_UM * np.median(np.sqrt(r2)))
    # a centre off by d changes r^2 by 2 r d cos(theta), the period in r^2 by at most d / r
    # of itself: the tolerance is the allowed centre error over the pixels' median radius
    tol = 2.0 * PITCH_UM / float(np.median(np.sqrt(r2)))
    assert period / LAMBDA_UM == pytest.approx(radius, rel=tol)


def test_rings_phase_gives_the_contact_offset():
    """The intensity's phase at r = 0 is 4 pi h0 / lambda + pi (mod 2 pi)."""
    h0 = 0.1
    x, y, value = _rings(0.0, 0.0, 8.0e5, h0, noise=0.02)
    r2 = x ** 2 + y ** 2
    _, phi = rings_period(r2, value, 4.0 * PITCH_UM * np.median(np.sqrt(r2)))
    want = (4.0 * np.pi * h0 / LAMBDA_UM + np.pi) % (2.0 * np.pi)
    assert abs(np.angle(np.exp(1j * (phi - want)))) < 0.1  # 0.1 rad = 5 nm of gap; noise 0.02 of 0.4 gives ~1e-3 rad


def _gap_map(radius_um=1.0e5, h0_nm=0.0, w=64, h=48, pitch=9.0, cx=90.0, cy=-45.0):
    """The gap (nm) of a lens on a plate at a grid of pixels (Born and Wolf sec. 7.5.3,
    h = h0 + r^2 / (2 R) for r << R), and a brightness dark at the contact only."""
    yy, xx = np.mgrid[0:h, 0:w]
    x, y = ((xx - w / 2) * pitch).ravel(), ((yy - h / 2) * pitch).ravel()
    gap = h0_nm + 1000.0 * ((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * radius_um)
    return x, y, gap, np.where(gap < 50.0, 0.05, 1.0)


def test_colour_start_of_a_right_map_is_unambiguous():
    """A per-pixel map of the right orders (white light: the colours tell them) is the gap
    itself: its line in r^2 gives R, and every pixel lies on it, so the colour-free start
    is not sought."""
    from bubblefit.inverse._newton import colour_start

    radius = 1.0e5
    x, y, gap, bright = _gap_map(radius)
    start, unambiguous = colour_start(x, y, gap, bright, 0.0, 4000.0, 275.0)
    assert unambiguous
    # the contact point on a pixel: the thin pixels lie symmetrically about it, their centre
    # is the contact point, and the line in r^2 is the gap itself (exact to rounding)
    assert start[0] == pytest.approx(radius, rel=1e-6)


@pytest.mark.parametrize("fold", ["saw", "mirror"])
def test_colour_start_of_a_folded_map_is_ambiguous(fold):
    """Under one wavelength the per-pixel map folds every fringe onto the first (the
    thickness modulo a fringe, or its mirror image within it): spread evenly over a
    fringe (or half one), at most a fifth (or two fifths) of the pixels lie within a tenth
    of a fringe of any line, below the share that makes the start unambiguous."""
    from bubblefit.inverse._newton import UNAMBIGUOUS_SHARE, colour_start

    fringe = 275.0
    x, y, gap, _ = _gap_map(1.0e4)  # about 70 fringes across the photo
    folded = gap % fringe if fold == "saw" else 0.5 * fringe - np.abs(gap % fringe - 0.5 * fringe)
    bright = np.where(folded < 0.1 * fringe, 0.05, 1.0)  # every dark ring looks like the contact point
    start, unambiguous = colour_start(x, y, folded, bright, 0.0, 4000.0, fringe)
    assert not unambiguous
    assert UNAMBIGUOUS_SHARE > 0.4


def test_white_light_fit_skips_the_colour_free_start(monkeypatch):
    """A white-light render of Newton's rings (the package's own flat-film model: an air gap
    between BK7 glasses, lamp E, sRGB, 16 x 16 pixels of 2 um, the gap growing by 300 nm
    over 16 um as in tests/test_order_planar.py, each pixel's colour its mean over the pixel
as the model's) started from its own map: the colour start
    is unambiguous, so the fit does not seek the colour-free one and still finds R."""
    import jax.numpy as jnp

    import bubblefit.inverse._newton as newton
    from bubblefit.inverse.planar import PlanarForward, view_of
    from bubblefit.model.planar_scene import parse_planar

    def refuse(*args, **kwargs):
        raise AssertionError("the colour-free start was sought")

    monkeypatch.setattr(newton, "_rings_start", refuse)
    hi = 3000.0
    scene = parse_planar({"film": {"shape": "plane", "n": "air", "above": "bk7", "below": "bk7",
                                   "thickness": "newton", "range_nm": [0.0, hi]},
                          "light": {"type": "coaxial", "na": 0.25, "lamp": "E"},
                          "camera": {"width": 16, "height": 16, "pixel_um": 2.0}})
    fwd, view = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, hi), view_of(scene)
    m = view.mask
    x, yy, s2, lum = view.x_um[m], view.y_um[m], view.sin2[m], view.radiance[m]
    radius = 1000.0 * 16.0**2 / (2 * 300.0)  # um
    gap = np.asarray(newton.newton_gap(jnp.asarray(np.hypot(x - 1.0, yy - 1.0)), radius, 0.0), np.float64)
    gx, gy = newton.newton_gap_gradient(jnp.asarray(x - 1.0), jnp.asarray(yy - 1.0), radius)
    # each pixel's mean colour over its 2 um box (the model's own)
    y = np.asarray(newton.pixel_mean(fwd, jnp.asarray(gap), jnp.asarray(s2), 0.0, gx, gy, 2.0, 0.0, hi),
                   np.float64) * lum[:, None]
    res = newton.fit_newton(fwd, y, lum, s2, view, m, gap, 1.0, 0.002, 0.0, hi)
    # noise-free photo from the same model: R to float32's precision in the model's colours
    assert res.params["radius_mm"] * 1000.0 == pytest.approx(radius, rel=1e-3)


def test_lost_rings_warning():
    """The 850 mm sodium photo's fit: the colour-free start's rings span ~63 fringes of
    295 nm across the photo (R = 905 mm), the fitted lens of 2 km under one; a fit that kept
    the rings (R within the start's few per cent) spans as many as the start and passes."""
    from bubblefit.inverse._newton import LOST_RINGS_RATIO, lost_rings_warning

    fringe, span = 295.0, 63 * 295.0
    assert lost_rings_warning(span, 1.03 * span, fringe, 9.05e5, 9.3e5) is None
    assert lost_rings_warning(span, 0.99 * span / LOST_RINGS_RATIO, fringe, 9.05e5, 1.9e6) is not None
    msg = lost_rings_warning(span, 295.0, fringe, 9.05e5, 2.0e9)
    assert "lost the rings" in msg and "1.0 fringes" in msg and "63.0" in msg and "\n" not in msg
