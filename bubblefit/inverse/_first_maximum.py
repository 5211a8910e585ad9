"""The lamp and stray light of a draining series' order-0 films from the series' own first
interference maximum (Scheludko's interferometric method).

A film thinner than the first zero of ``R`` at every wavelength of the reading (its phase
``4 n d / lambda`` below 2: the first lobe of ``R``) has no fringe minimum to pin a lamp,
and is read from its brightness with a lamp and stray light held. Those the thicker films
of the series pin (:mod:`._shared_lamp`) are the lamp and zero of another time of a
lamp-divided series: on optifik's ``spectraVictor2`` the order-1 pins' lamp is 5-8 % too
dim for its order-0 films and their stray light (the level of the order-1 fringe minima)
lies above the black film's whole reading (``experiments/spectrum_order0_bias.py``).

Scheludko's method calibrates such a film by the series itself. As a film drains through
the first maximum of ``R`` (``4 n d / lambda = 1``) each wavelength passes through the
brightest it reflects, ``I_max(lambda) = L(lambda) R_max(lambda) + S(lambda)``, with
``R_max`` the Airy maximum of a single film of the known index (Born & Wolf 7.6(13): for a
lossless film in air ``R_max = 4 r^2 / (1 + r^2)^2``, ``r = (n - 1) / (n + 1)``). The
envelope of the series' first-lobe readings therefore fixes ``L R_max + S`` at every
wavelength the series has passed through the maximum; the black film (``R`` about 0) fixes
``S``, and a film between reads ``(I - S) / (I_max - S) = R(d) / R_max``.

Here ``S`` is the instrument's smooth stray light (the series' stray-light columns,
:func:`bubblefit.inverse.spectrum.stray_basis`) fitted to all the series' order-0 readings
at once with the lamp ``L = (I_max - S) / R_max`` that the envelope implies for it (the
readings' thicknesses profiled out): one ``S`` for many films of different thickness is
fixed by how their spectra change with thickness, which one reading's own offset and tilt
cannot be. It is kept at or below the darkest reading of the series at every wavelength (a
reading is ``L R + S`` with ``L R >= 0``), the bound the black film sets when the series
holds it.

References
----------
A. Scheludko, Adv. Colloid Interface Sci. 1, 391-464 (1967): a thin film's thickness from
its intensity between the black film's and the first maximum's.
Born & Wolf, *Principles of Optics*, 7th ed., eq. 7.6(13) (Airy reflectance of a single film).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.signal import savgol_filter

__all__ = ["FirstMaximum", "first_lobe", "first_maximum_envelope", "first_maximum_lamp"]

#: Samples of the cubic Savitzky-Golay filter a reading is smoothed by before its envelope is
#: taken (optifik's smoothing of these readings, 11 samples: 3.8 nm at 0.34 nm a sample,
#: against the ~600 nm period in wavelength of ``R`` of a first-lobe film, so the filter
#: leaves ``R`` as it is and takes the maximum over readings of the noise down).
SMOOTHING_SAMPLES = 11


@dataclass(frozen=True)
class FirstMaximum:
    """The lamp ``lamp`` (N,) and stray light ``stray`` (N,) of a series' order-0 readings,
    at the wavelengths ``covered`` (N,) where the series has passed through the first
    maximum of ``R`` (elsewhere its envelope does not fix the lamp); ``stray_coefficients``
    on the series' stray-light columns; ``readings`` the order-0 readings they were fitted
    to (indices into the series)."""

    lamp: np.ndarray
    stray: np.ndarray
    covered: np.ndarray
    stray_coefficients: np.ndarray
    readings: tuple[int, ...]


def first_lobe(thickness_nm: float, wavelength_nm: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The phase ``4 n d / lambda`` (N,) of a film of ``thickness_nm`` at each wavelength
    (Born & Wolf 7.6: ``R`` is zero at even phases, at its maximum at odd ones): the film is
    in the first lobe of ``R`` where it lies in (0, 2)."""
    return 4.0 * np.asarray(n) * float(thickness_nm) / np.asarray(wavelength_nm)


def _smoothed(y: np.ndarray) -> np.ndarray:
    """The reading through the cubic Savitzky-Golay filter of :data:`SMOOTHING_SAMPLES`
    (A. Savitzky & M. J. E. Golay, Anal. Chem. 36, 1627 (1964); optifik smooths these readings
    so before reading them by Scheludko's method)."""
    win = min(SMOOTHING_SAMPLES, len(y) // 2 * 2 - 1)
    return savgol_filter(y, win, 3) if win >= 5 else np.asarray(y, np.float64)


def first_maximum_envelope(wavelength_nm: np.ndarray, n: np.ndarray, readings: np.ndarray,
                           thickness_nm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scheludko's envelope ``I_max(lambda)`` (N,) of a draining series' readings (K, N), read
    at ``thickness_nm`` (K,): at each wavelength the brightest smoothed reading of those in
    the first lobe of ``R`` there (:func:`first_lobe`), and where it is the first maximum
    (N,): at least one of them on each side of the maximum (phase at most 1 and at least 1),
    so that the film drained through it."""
    phase = np.array([first_lobe(d, wavelength_nm, n) for d in thickness_nm])
    lobe = (phase > 0.0) & (phase < 2.0)
    smooth = np.array([_smoothed(y) for y in readings])
    env = np.where(lobe, smooth, -np.inf).max(axis=0)
    covered = np.any(lobe & (phase <= 1.0), axis=0) & np.any(lobe & (phase >= 1.0), axis=0)
    return np.where(covered, env, np.nan), covered


def first_maximum_lamp(wavelength_nm: np.ndarray, n: np.ndarray, readings: np.ndarray, thickness_nm: np.ndarray,
                       order0: list[int], weights: np.ndarray, reflect, grid: np.ndarray, stray_columns: np.ndarray,
                       stray_start: np.ndarray) -> FirstMaximum | None:
    """The lamp and stray light of the order-0 readings ``order0`` (indices into ``readings``,
    (K, N), all on ``wavelength_nm``; ``thickness_nm`` (K,) each reading's thickness as the
    series read it) from the series' first-maximum envelope (see the module: Scheludko 1967,
    with ``R`` the Airy reflectance of a single film, Born & Wolf 7.6(13)).

    ``weights`` (K, N) are the readings' least-squares weights, ``reflect(d, w)`` the Airy
    reflectance (D, N) at their wavelengths, ``grid`` the thicknesses searched,
    ``stray_columns`` (N, S) the series' stray-light columns, ``stray_start`` (S,) the held
    stray light's coefficients the fit starts from. The lamp is Scheludko's, wavelength by
    wavelength, ``L = (I_max - S) / R_max`` at the covered wavelengths (0 elsewhere): the
    envelope carries the structure of a lamp-divided reading's lamp that a few smooth terms
    do not. The stray light minimises the order-0 readings' total weighted RSS, each at its
    own best thickness on ``grid`` within the first lobe, and is kept at or below the darkest
    smoothed reading of the series. None when no order-0 reading is given or fewer
    wavelengths are covered than twice the stray light's unknowns."""
    env, covered = first_maximum_envelope(wavelength_nm, n, readings, thickness_nm)
    s = stray_columns.shape[1]
    if not order0 or covered.sum() < 2 * s:
        return None
    lobe_max = float(np.min(wavelength_nm / (2.0 * n)))  # the first zero of R at the shortest wavelength
    g = grid[(grid > 0.0) & (grid < lobe_max)]
    r = reflect(g, 0.0)[:, covered]  # (D, C)
    r_max = np.diag(reflect(wavelength_nm / (4.0 * n), 0.0)).copy()  # R at the first maximum, 4 n d / lambda = 1
    floor = np.min(np.array([_smoothed(y) for y in readings]), axis=0)
    y = readings[order0][:, covered]
    w2 = weights[order0][:, covered] ** 2

    def lamp_and_stray(c):
        stray = np.minimum(stray_columns @ c, floor)
        return np.where(covered, (np.nan_to_num(env) - stray) / r_max, 0.0), stray

    def total(c):
        lamp, stray = lamp_and_stray(c)
        resid = y - stray[covered][None, :]
        lw = lamp[covered][None, :] * w2
        rss = (np.sum(resid * resid * w2, axis=1)[:, None] - 2.0 * (resid * lw) @ r.T
               + (lamp[covered][None, :] * lw) @ (r * r).T)
        return float(np.sum(np.min(rss, axis=1)))

    # start from the held stray light brought under the darkest reading (where it lies above,
    # the clipped objective is flat in the start's neighbourhood)
    stray_start = np.linalg.lstsq(stray_columns, np.minimum(stray_columns @ stray_start, floor), rcond=None)[0]
    scale = max(float(np.max(np.abs(stray_start))), 1e-3)
    simplex = np.vstack([stray_start, stray_start + 0.25 * scale * np.eye(s)])
    fit = minimize(total, stray_start, method="Nelder-Mead",
                   options=dict(initial_simplex=simplex, xatol=1e-5 * scale, fatol=1e-9 * total(stray_start),
                                maxiter=400 * s))
    lamp, stray = lamp_and_stray(fit.x)
    return FirstMaximum(lamp, stray, covered, np.asarray(fit.x), tuple(order0))
