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
