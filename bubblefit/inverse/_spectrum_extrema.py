"""The extrema phase test: does a thickness put a reading's fringe extrema where they are?

At normal incidence the reflectance of a film in air is extremal where its phase
``4 pi n d / lambda`` is a whole multiple of pi (Born & Wolf, *Principles of Optics*, 7th
ed., sec. 7.6.1), so at the wavelengths of a reading's extrema ``x = 4 n(lambda) d / lambda``
is a whole number. The score of a thickness is the rms distance of ``x`` from the nearest
whole number there: 0 for a thickness that puts every extremum where it is, ``1/sqrt(12)``
(0.289) on average for one unrelated to the fringes. It uses no lamp model and no fit, so
it can question a thickness stated by someone else (or by the fit): indicative, not a
measurement (a sloping lamp and the smoothing move low-contrast extrema a little).

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import find_peaks, savgol_filter

__all__ = ["fringe_extrema", "fringe_minima", "extrema_phase", "minima_phase", "RANDOM_PHASE", "MIN_EXTREMA"]

#: The score of a thickness unrelated to the fringes: rms distance of a uniform number
#: from the nearest integer.
RANDOM_PHASE = 1.0 / np.sqrt(12.0)
#: Fewest extrema for a score (with fewer, many thicknesses fit them).
MIN_EXTREMA = 3


#: A minimum is taken for a zero of ``R`` only when the smoothed reading there lies within
#: this fraction of its swing above its lowest value: at a zero the reading is the stray
#: light alone, near the floor of the whole reading. A dip on a bright stretch is noise or
#: the lamp's structure (chosen on optifik's spectraVictor2, orders 1-3: the noisy blue end
#: of order-2 and order-3 readings dips half-way up their swing, the zeros of order 1 lie
#: within 0.1 of the floor).
ZERO_DEPTH = 0.25


def _peaks_and_troughs(y: np.ndarray, window: int, prominence: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the smoothed reading's maxima and of its minima (Savitzky-Golay, cubic,
    ``window`` samples) whose prominence is at least ``prominence`` of its mean level, and
    the smoothed reading."""
    y = np.asarray(y, np.float64)
    win = min(window, len(y) // 2 * 2 - 1)
    if win < 5:
        return np.array([], int), np.array([], int), y
    smooth = savgol_filter(y, win, 3)
    p = prominence * float(np.mean(np.abs(smooth)))
    return find_peaks(smooth, prominence=p)[0], find_peaks(-smooth, prominence=p)[0], smooth


def fringe_extrema(wavelength_nm: np.ndarray, y: np.ndarray, window: int = 51, prominence: float = 0.05) -> np.ndarray:
    """Wavelengths of the smoothed reading's maxima and minima (Savitzky-Golay, cubic,
    ``window`` samples) whose prominence is at least ``prominence`` of its mean level (a
    fraction of its range would count the wiggles of a reading without fringes)."""
    peaks, troughs, _ = _peaks_and_troughs(y, window, prominence)
    return np.sort(np.asarray(wavelength_nm)[np.r_[peaks, troughs]])


def fringe_minima(wavelength_nm: np.ndarray, y: np.ndarray, window: int = 51, prominence: float = 0.05) -> np.ndarray:
    """Wavelengths of the clear minima among :func:`fringe_extrema` that lie near the
    reading's floor (within :data:`ZERO_DEPTH` of its swing): the candidates for zeros of ``R``."""
    _, troughs, smooth = _peaks_and_troughs(y, window, prominence)
    if not len(troughs):
        return np.array([])
    lo, hi = float(smooth.min()), float(smooth.max())
    deep = troughs[smooth[troughs] - lo <= ZERO_DEPTH * (hi - lo)]
    return np.sort(np.asarray(wavelength_nm)[deep])


def minima_phase(thickness_nm: float, minima_nm: np.ndarray, n_at) -> float:
    """Smallest distance of ``4 n d / lambda`` from the nearest even number at the reading's
    fringe minima ``minima_nm``; NaN for no thickness or no minimum.

    A film in air reflects nothing where ``2 n d / lambda`` is whole (Born & Wolf, sec.
    7.6.1: ``R = F sin^2(delta/2) / (1 + F sin^2(delta/2))``, ``delta = 4 pi n d / lambda``),
    and a reading ``I = L R + S`` has its minimum there whatever the lamp ``L``: at a zero
    of ``R`` (and of its slope) ``dI/dlambda = dS/dlambda``, so only the stray light's slope
    moves the minimum, by ``-S' / (L R'')``. One clear minimum thus places the thickness
    within its order without any lamp model, which the rms of :func:`extrema_phase` needs
    three extrema for. Even numbers, not whole ones: a thickness that puts a maximum of ``R``
    where the reading has its minimum scores 1. The smallest distance over the minima, not
    the largest: one zero placed suffices, and a minimum at the dim blue end of a divided
    reading may lie displaced (optifik's spectraVictor2 order 3: 17 nm at 436 nm, with its
    other minimum placed within 0.04).
    """
    if thickness_nm is None or not np.isfinite(thickness_nm) or len(minima_nm) == 0:
        return float("nan")
    lam = np.asarray(minima_nm, np.float64)
    x = 4.0 * np.asarray(n_at(lam)) * thickness_nm / lam
    return float(np.min(np.abs(x - 2.0 * np.round(x / 2.0))))


def extrema_phase(thickness_nm: float, extrema_nm: np.ndarray, n_at) -> float:
    """RMS distance of ``4 n d / lambda`` from the nearest whole number at ``extrema_nm``
    (``n_at(lambda)`` the film's index); NaN for no thickness or fewer than
    :data:`MIN_EXTREMA` extrema."""
    if thickness_nm is None or not np.isfinite(thickness_nm) or len(extrema_nm) < MIN_EXTREMA:
        return float("nan")
    lam = np.asarray(extrema_nm, np.float64)
    x = 4.0 * np.asarray(n_at(lam)) * thickness_nm / lam
    return float(np.sqrt(np.mean((x - np.round(x)) ** 2)))
