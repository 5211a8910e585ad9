"""The lamp and stray light of a draining series' order-0 films from the series' own first
interference maximum (``bubblefit.inverse._first_maximum``, Scheludko 1967).

Readings are made by the independent Airy formula of ``test_spectrum.py`` (Born & Wolf
7.6(13)) under a known lamp and stray light with noise; the envelope and the fit must
return that lamp and stray light within what the noise and the series' thickness steps
leave (arithmetic below, not one run's numbers).
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre
from scipy.signal import savgol_coeffs
from test_spectrum import airy, soap_index

from bubblefit.inverse._first_maximum import SMOOTHING_SAMPLES, first_maximum_envelope, first_maximum_lamp
from bubblefit.inverse.spectrum import reflector

LAM = np.arange(420.0, 800.0 + 1e-9, 1.0)
U = 2.0 * (1.0 / LAM - 1.0 / 800.0) / (1.0 / 420.0 - 1.0 / 800.0) - 1.0
STRAY_COLUMNS = legendre.legvander(U, 1)
LAMP = legendre.legvander(U, 2) @ np.array([12.0, 1.5, -0.6])
STRAY = STRAY_COLUMNS @ np.array([0.05, 0.012])
NOISE = 0.002
STEP = 4.0  # nm between readings of the draining film


def _series(seed=0):
    """A film draining from 250 to 60 nm in STEP-nm steps (through the first maximum of R at
    every wavelength here: 4 n d / lambda = 1 at 78-150 nm), each reading ``L R + S`` plus
    white noise of deviation NOISE."""
    rng = np.random.default_rng(seed)
    d = np.arange(250.0, 59.0, -STEP)
    n = soap_index(LAM)
    y = np.array([LAMP * airy(x, LAM, n) + STRAY + NOISE * rng.standard_normal(LAM.shape) for x in d])
    return d, n, y


def _tolerance(n):
    """How far the envelope may lie from ``L R_max + S`` (N,): three deviations of the
    smoothed noise (the Savitzky-Golay filter's noise gain, the square root of the sum of its
    squared coefficients), plus the dip between two readings STEP nm apart on either side of
    the maximum (``R / R_max = sin^2(pi phase / 2)`` at half a step's phase from 1)."""
    gain = float(np.sqrt(np.sum(savgol_coeffs(SMOOTHING_SAMPLES, 3) ** 2)))
    half = 0.5 * 4.0 * n * STEP / LAM
    r_max = airy(LAM / (4.0 * n), LAM, n)
    return 3.0 * NOISE * gain + LAMP * r_max * (1.0 - np.cos(0.5 * np.pi * half) ** 2)


def test_envelope_is_the_first_maximum():
    """The envelope is ``L R_max + S`` wherever the film drained through the maximum, within
    the noise and the dip between readings (it can only lie below by the dip, above by the
    smoothed noise's maximum)."""
    d, n, y = _series()
    env, covered = first_maximum_envelope(LAM, n, y, d)
    assert covered.all()
    truth = LAMP * airy(LAM / (4.0 * n), LAM, n) + STRAY
    assert np.all(np.abs(env - truth) <= _tolerance(n))


def test_envelope_not_covered_where_the_film_did_not_reach_the_maximum():
    """A series that stops at 110 nm never reaches the first maximum at wavelengths below
    4 n 110 nm (about 590 nm): those are not covered."""
    d, n, y = _series()
    keep = d >= 110.0
    _, covered = first_maximum_envelope(LAM, n, y[keep], d[keep])
    assert not covered[LAM < 4.0 * n * 110.0 - 1.0].any()
    assert covered[LAM > 4.0 * n * 110.0 + 1.0].all()


def test_lamp_and_stray_light_of_the_order0_films():
    """Started from a stray light three times too bright (as the order-1 fringe minima of a
    real series put it), the fit over the order-0 readings (those below the first zero of
    R at 420 nm) returns the stray light and the lamp within the envelope's tolerance: the
    lamp ``(I_max - S) / R_max`` is off by at most (tolerance + the stray light's error) over
    ``R_max``, and the stray light is fixed to the envelope's tolerance by many films of
    different thickness."""
    d, n, y = _series()
    order0 = [k for k, x in enumerate(d) if np.all(4.0 * n * x / LAM < 2.0)]
    grid = np.arange(0.0, 400.0, 0.25)
    fm = first_maximum_lamp(LAM, n, y, d, order0, np.ones_like(y), reflector(LAM, n), grid,
                            STRAY_COLUMNS, np.array([0.15, 0.0]))
    assert fm is not None and fm.covered.all() and fm.readings == tuple(order0)
    tol = _tolerance(n)
    assert np.all(np.abs(fm.stray - STRAY) <= tol)
    r_max = airy(LAM / (4.0 * n), LAM, n)
    assert np.all(np.abs(fm.lamp - LAMP) <= 2.0 * tol / r_max)


def test_stray_light_kept_below_the_darkest_reading():
    """The stray light never exceeds the darkest smoothed reading: with a black film (R about
    0) in the series the fit cannot put the zero above it, even started there."""
    d, n, y = _series()
    d = np.append(d, 5.0)
    y = np.vstack([y, LAMP * airy(5.0, LAM, n) + STRAY])
    order0 = [k for k, x in enumerate(d) if np.all(4.0 * n * x / LAM < 2.0)]
    fm = first_maximum_lamp(LAM, n, y, d, order0, np.ones_like(y), reflector(LAM, n), np.arange(0.0, 400.0, 0.25),
                            STRAY_COLUMNS, np.array([0.3, 0.0]))
    assert np.all(fm.stray <= y[-1] + 1e-9)  # (the filter's rounding)
    assert np.all(np.abs(fm.stray - STRAY) <= _tolerance(n))
