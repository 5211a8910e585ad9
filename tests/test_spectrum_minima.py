"""The fringe-minimum test: a film in air reflects nothing where ``4 n d / lambda`` is even,
whatever the lamp, so one clear minimum of a reading places its thickness within its order.

References are written here: the Airy reflectance of a film in air at normal incidence
(Born & Wolf, sec. 7.6.1), a lamp divided out with a residual tilt, stray light with a
slope, noise growing towards the dim blue end, and 4-digit rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from bubblefit.inverse import SpectrumOptions, fit_spectrum, fringe_extrema, fringe_minima, minima_phase
from bubblefit.io.spectra import Spectrum

N = 1.34  # a constant index keeps the reference independent of the package's laws


def _airy(d, lam, n=N):
    r2 = ((n - 1.0) / (n + 1.0)) ** 2
    c = np.cos(4.0 * np.pi * n * d / lam)
    return 2.0 * r2 * (1.0 - c) / (1.0 + r2**2 - 2.0 * r2 * c)


def _reading(d, seed=0):
    """An order-1 film read as optifik's readings are: divided by a lamp, with a residual
    tilt of a factor 2 over the range, a sloping stray light and noise."""
    rng = np.random.default_rng(seed)
    lam = np.linspace(400.0, 800.0, 1200)
    tilt = 4.75 + 5.0 * (lam - 400.0) / 400.0
    stray = 0.04 + 0.04 * (lam - 400.0) / 400.0
    noise = 0.002 * (1.0 + 4.0 * np.exp(-(lam - 400.0) / 30.0))
    y = tilt * _airy(d, lam) + stray + noise * rng.standard_normal(lam.size)
    return lam, np.round(y, 4)


@pytest.mark.parametrize("d", [180.0, 220.0, 260.0])
def test_the_minimum_places_the_true_thickness(d):
    lam, y = _reading(d)
    minima = fringe_minima(lam, y)
    assert len(minima) == 1
    # the zero of R is at 2 n d / lambda = 1; the stray light's slope moves the reading's
    # minimum by -S'/(L R''): here 1e-4 / (7 * 2 F (pi x / 2 lambda)^2) ~ 3 nm, and the red end's noise a few nm more
    assert abs(minima[0] - 2.0 * N * d) < 10.0
    assert minima_phase(d, minima, lambda x: np.full_like(x, N)) < 0.05
    # a film 12 % thinner puts the zero 0.24 away (x = 2 * 0.88): beyond the limit of 0.2
    assert minima_phase(0.88 * d, minima, lambda x: np.full_like(x, N)) > 0.2
    # a maximum of R put at the minimum (x odd) scores 1
    assert minima_phase(1.5 * d, minima, lambda x: np.full_like(x, N)) == pytest.approx(1.0, abs=0.03)


def test_a_thickness_that_misplaces_the_minimum_is_not_ok():
    lam, y = _reading(220.0, seed=3)
    opts = dict(n_film=N, normalised=True)
    right = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(thickness_range=(150.0, 300.0), **opts))
    wrong = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(thickness_range=(180.0, 196.0), **opts))
    assert abs(right.thickness_nm - 220.0) < 0.05 * 220.0
    assert not any("fringe minimum" in r for r in right.reasons)
    assert any("fringe minimum" in r for r in wrong.reasons) and not wrong.ok


def test_a_dip_on_a_bright_stretch_is_not_a_zero():
    # a 250 nm film: a zero at x = 2 (670 nm), a maximum at x = 3 (447 nm); a narrow dip
    # where R is two thirds of its peak (x = 2.6, 515 nm) is a minimum of the reading that
    # lies far above its floor, not a zero of R
    d = 250.0
    lam, y = _reading(d, seed=5)
    dip = 4.0 * N * d / 2.6
    y = y - 0.06 * np.exp(-(((lam - dip) / 6.0) ** 2))
    assert np.any(np.abs(fringe_extrema(lam, y) - dip) < 6.0)  # seen as an extremum
    minima = fringe_minima(lam, y)
    # the zero placed within 0.05 in x (the stray light's slope moves it by ~0.01, the noise
    # at the red end by a few nm)
    assert len(minima) == 1
    assert minima_phase(d, minima, lambda x: np.full_like(x, N)) < 0.05
