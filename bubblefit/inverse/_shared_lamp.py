"""Readings of one series under one lamp: the lamp from the readings whose fringes pin it,
every film read with it.

A single reading of a film thinner than about a quarter wave (no extremum of ``R`` in the
visible: interference order 0, below ~80 nm) cannot be read on its own: its reflectance
``R(d, nu)`` is then close to ``(4 pi n d nu)^2 R_1``, a smooth ramp whose shape barely
depends on ``d``, so that an unknown smooth lamp takes it up and only the brightness would
tell the thickness (:func:`bubblefit.inverse.spectrum.min_fringes`). A draining film is
read as a series, from many fringes down to the black film, with the same lamp and
spectrometer. The readings that can be read alone (``ok``) fix the lamp, shape and
scale, ``L(nu) = sum_j a_j P_j(nu)`` (the Legendre series of
:func:`bubblefit.inverse.spectrum._lamp_basis`, on one wavenumber range for the whole
series), and with it the instrument's stray light ``S`` (the offset and background terms
on the same range, :func:`bubblefit.inverse.spectrum.stray_basis`); each reading of the
series is then the known ``L R(d) + S`` with only its thickness free, and a thin film's
brightness and colour give its thickness. ``S`` is held, not refitted per reading: a
film of order 0 reflects ``R ~ sin^2(2 pi n d nu)``, whose level and slope over the range
are what tell its thickness (the maximum of ``R`` moves across the visible as it thins
through ~100 nm); a stray light with its own offset and tilt in each reading takes both
up and leaves the curvature of ``R``, which a small error in the colour of the lamp or of
the stray light bends as much as the thickness does, so that a film can be read as its
twin across the first maximum.
Scheludko's method holds the stray light too (read on the black film).

The lamp is found by alternating (block coordinate descent, each step lowering the total
weighted RSS): with the pinning readings' thicknesses and scales held, the lamp's
coefficients solve one linear least-squares problem over all of them (their stray light
projected out); with the lamp held, each pinning reading's thickness (near its own,
within a quarter order) and its scale ``s_f`` are refined. The scales are normalised to a
mean of 1; their spread ``sigma_s`` (relative standard deviation) measures how much the
lamp changes from reading to reading. Each pinning reading also implies a lamp of its own
(its coefficients alone, its thickness held); a film read with the shared lamp is read
again with each of those, by a global search, and the standard deviation of the
thicknesses is its systematic error, added in quadrature to the statistical one (for a film of order 0, ``R ~ d^2``, a
lamp ``sigma_s`` brighter moves the thickness by about ``sigma_s / 2`` of itself).

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1 (Airy reflectance).
A. Scheludko, Adv. Colloid Interface Sci. 1, 391-464 (1967): a thin film's thickness from
its brightness between the black film's and the first maximum's, which calibrate it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.polynomial import legendre
from scipy import stats

from ._spectrum_drain import profile_candidates
from ._spectrum_profile import (ProfileProblem, profile_variance, refine_d, refine_near, residual_correlation,
                                second_difference_noise, second_minimum)

__all__ = ["SharedLamp", "FixedLampProblem", "MIN_PINNING_READINGS", "MAX_ALTERNATIVE_LAMPS", "shared_lamp",
           "read_with_lamp", "alternative_lamps"]

#: The fewest readings that must be read alone (``ok``) for a shared lamp: with fewer the
#: spread of their scales, which sizes every thin film's error bar, is not measured.
MIN_PINNING_READINGS = 3

#: A reading read with the series' lamp is not ok when its residual exceeds this many times
#: its noise, with no model-error floor: the lamp's error goes straight into the thickness of
#: a film read from its brightness, so structure the lamp leaves is not forgiven.
SHARED_MISFIT_RATIO = 2.0

#: The probability within one standard deviation of a normal variable's mean, one-sided.
_ONE_SIGMA = 0.5 * (1.0 + math.erf(1.0 / math.sqrt(2.0)))

#: Most of the pinning readings' own lamps a film read with the shared lamp is read again
#: with (its systematic error): each is one global search, so that a series of many pinning
#: readings (spectraVictor2, six folders, 150 of them) would cost each reading 150 searches.
#: Sixteen spread evenly over the series sample the lamp's changes from start to end; the
#: Student-t factor of :func:`read_with_lamp` for 15 degrees of freedom is 3 % above the
#: normal one (1.034 against 1).
MAX_ALTERNATIVE_LAMPS = 16

#: Most rounds of the alternation, and the relative change of the lamp that ends it.
ROUNDS = 12
LAMP_TOLERANCE = 1e-4


@dataclass(frozen=True)
class SharedLamp:
    """The lamp of a series: Legendre coefficients in wavenumber mapped from ``nu_range``
    (1/nm, (min, max)) onto [-1, 1], the relative spread of the pinning readings' own
    scales, which readings (indices into the series) pinned it, and the lamp each of
    them implies alone (``each``, (K, J): its own coefficients with its thickness held),
    whose differences measure how well the series shares one lamp, and their brightness
    against the shared lamp (``scales``, mean 1). With the stray light shared too
    (:func:`shared_lamp`'s ``stray_basis``), ``stray`` (S,) are its coefficients and
    ``each_stray`` (K, S) each pinning reading's own, fitted with its own lamp."""

    coefficients: np.ndarray
    nu_range: tuple[float, float]
    scale_spread: float
    pinning: tuple[int, ...]
    each: np.ndarray | None = None
    scales: tuple[float, ...] = ()
    stray: np.ndarray | None = None
    each_stray: np.ndarray | None = None

    def basis(self, wavelength_nm: np.ndarray) -> np.ndarray:
        """(N, J) Legendre polynomials of the series' wavenumber range at ``wavelength_nm``."""
        lo, hi = self.nu_range
        u = 2.0 * (1.0 / np.asarray(wavelength_nm) - lo) / max(hi - lo, 1e-30) - 1.0
        return legendre.legvander(u, len(self.coefficients) - 1)

    def __call__(self, wavelength_nm: np.ndarray) -> np.ndarray:
        """The lamp ``L`` (N,) at ``wavelength_nm``."""
        return self.basis(wavelength_nm) @ self.coefficients


@dataclass
class FixedLampProblem:
    """A reading ``y`` with a known lamp ``lamp`` (N,): ``y = lamp R(d) + S``, with the
    stray light ``S`` (columns ``additive`` (N, K)) solved by weighted least squares at
    every thickness. The same interface as :class:`ProfileProblem` for the refinements
    (``rss``, ``model``, ``positive``)."""

    y: np.ndarray
    lamp: np.ndarray
    additive: np.ndarray
    reflect: object
    weight: np.ndarray
    positive: bool = False

    def __post_init__(self):
        w = self.weight
        self._q = np.linalg.qr(self.additive * w[:, None])[0] if self.additive.shape[1] else None
        self._yw = self._project(self.y * w)

    def _project(self, v: np.ndarray) -> np.ndarray:
        """``v`` (.., N) with the weighted additive columns projected out."""
        if self._q is None:
            return v
        return v - (v @ self._q) @ self._q.T

    def rss_grid(self, thickness: np.ndarray, w: float, chunk: int = 256) -> np.ndarray:
        return self.rss_lamps(thickness, w, self.lamp[None, :], chunk)[0]

    def rss_lamps(self, thickness: np.ndarray, w: float, lamps: np.ndarray, chunk: int = 512,
                  readings: np.ndarray | None = None) -> np.ndarray:
        """(K, D) weighted RSS at each thickness with each of the lamps ``lamps`` (K, N)
        in place of ``lamp`` (the film's reflectance computed once for all of them), and,
        with ``readings`` (K, N), each lamp's own reading in place of ``y`` (the reading less
        each lamp's own held stray light, :func:`shared_lamp`).

        With ``P`` the projector that removes the weighted stray-light columns ``Q`` and
        ``m = L R`` (weighted), ``|P (y - m)|^2 = |P y|^2 - 2 (P y) . m + |m|^2 - |Q^T m|^2``:
        every term is a matrix product of the lamps with the reflectance rows, so no (K, D, N)
        array is formed."""
        out = np.empty((len(lamps), len(thickness)))
        lw = lamps * self.weight[None, :]
        yw = self._yw[None, :] if readings is None else self._project(np.asarray(readings) * self.weight[None, :])
        cross = lw * yw  # (K, N): (P y) . (L R) = sum_n (P y)_n L_n R_n
        square = lw * lw
        qs = [lw * self._q[:, j][None, :] for j in range(self._q.shape[1])] if self._q is not None else []
        yy = np.sum(yw * yw, axis=1)[:, None]  # (K, 1), or (1, 1) for the one reading
        for s in range(0, len(thickness), chunk):
            r = self.reflect(thickness[s:s + chunk], w)  # (C, N)
            part = yy - 2.0 * (cross @ r.T) + square @ (r * r).T
            for q in qs:
                part -= (q @ r.T) ** 2
            out[:, s:s + len(r)] = np.maximum(part, 0.0)
        return out

    def rss(self, d: float, w: float) -> float:
        return float(self.rss_grid(np.array([d]), w)[0])

    def model(self, d: float, w: float) -> np.ndarray:
        film = self.lamp * self.reflect(np.array([d]), w)[0]
        if not self.additive.shape[1]:
            return film
        wt = self.weight
        coef, *_ = np.linalg.lstsq(self.additive * wt[:, None], (self.y - film) * wt, rcond=None)
        return film + self.additive @ coef


def _lamp_coefficients(problems, thickness, scale, resolution, lamp_basis, stray_basis=None) -> np.ndarray:
    """The lamp's coefficients (J,) that minimise the pinning readings' total weighted RSS
    with their thicknesses, scales and resolutions held and each one's stray light solved;
    with ``stray_basis`` (one (N, S) array per reading) the stray light is one for all of
    them, ``S = stray_basis @ e``, solved with the lamp: (J + S,) coefficients, the lamp's
    first."""
    j = lamp_basis[0].shape[1] + (stray_basis[0].shape[1] if stray_basis is not None else 0)
    gram, rhs = np.zeros((j, j)), np.zeros(j)
    for k, (p, d, s, w, b) in enumerate(zip(problems, thickness, scale, resolution, lamp_basis)):
        wt = p.weight
        x = s * b * (p.reflect(np.array([d]), w)[0] * wt)[:, None]
        y = p.y * wt
        if stray_basis is not None:
            x = np.column_stack([x, stray_basis[k] * wt[:, None]])
        else:
            add = p.additive * wt[:, None]
            if add.shape[1]:
                q = np.linalg.qr(add)[0]
                x, y = x - q @ (q.T @ x), y - q @ (q.T @ y)
        gram += x.T @ x
        rhs += x.T @ y
    return np.linalg.lstsq(gram, rhs, rcond=None)[0]


def shared_lamp(problems: list[ProfileProblem], alone: list, lamp_basis: list[np.ndarray], nu_range,
                grids: list[np.ndarray], orders: list[float], stray_basis: list[np.ndarray] | None = None) -> SharedLamp:
    """The lamp of the pinning readings (:class:`ProfileProblem` each, their ``alone`` fits
    giving the starting thicknesses and resolutions), by alternation (see the module).

    With ``stray_basis`` (each reading's (N, S) stray-light columns on the series'
    wavenumber range) the stray light is the instrument's, shared like the lamp: the
    alternation solves the lamp and one stray light ``S`` together over all the pinning
    readings (:func:`_lamp_coefficients`) and refines each reading's thickness and scale
    with both held; each reading's own lamp and stray light are then solved with its
    thickness held (``each``, ``each_stray``).
    A film read with the shared lamp then keeps ``S`` held (see the module)."""
    d = np.array([r.thickness_nm for r in alone])
    w = np.array([r.resolution_nm for r in alone])
    s = np.ones(len(problems))
    j = lamp_basis[0].shape[1]
    coef = _lamp_coefficients(problems, d, s, w, lamp_basis, stray_basis)
    for _ in range(ROUNDS):
        for i, (p, b) in enumerate(zip(problems, lamp_basis)):
            one = replace(p, basis=(b @ coef[:j])[:, None], positive=False)
            if stray_basis is not None:  # the shared stray light held, none of the reading's own
                one = replace(one, y=p.y - stray_basis[i] @ coef[j:], offset=False, background=None)
            d[i] = refine_near(one, d[i], w[i], 0.25 * orders[i], grids[i])
            s[i] = float(one.solve(d[i], w[i])[0][0])
        mean = float(np.mean(s))
        if not mean > 0:
            break
        s /= mean
        new = _lamp_coefficients(problems, d, s, w, lamp_basis, stray_basis)
        change = float(np.max(np.abs(new - coef)) / max(np.max(np.abs(coef)), 1e-300))
        coef = new
        if change < LAMP_TOLERANCE:
            break
    spread = float(np.std(s, ddof=1)) if len(s) > 1 else float("inf")
    strays = stray_basis if stray_basis is not None else [None] * len(problems)
    each = np.array([_lamp_coefficients([p], [x], [1.0], [v], [b], None if e is None else [e])
                     for p, x, v, b, e in zip(problems, d, w, lamp_basis, strays)])
    shared = dict(stray=coef[j:], each_stray=each[:, j:]) if stray_basis is not None else {}
    return SharedLamp(coefficients=coef[:j], nu_range=nu_range, scale_spread=spread, pinning=(), each=each[:, :j],
                      scales=tuple(float(x) for x in s), **shared)


def alternative_lamps(each: np.ndarray, most: int = MAX_ALTERNATIVE_LAMPS) -> np.ndarray:
    """At most ``most`` rows of the pinning readings' own lamps ``each`` (K, J), evenly
    spread over the series' order (all of them when there are no more)."""
    if len(each) <= most:
        return each
    return each[np.unique(np.round(np.linspace(0, len(each) - 1, most)).astype(int))]


def read_with_lamp(prob: FixedLampProblem, grid: np.ndarray, alternatives) -> dict:
    """A reading's thickness with the lamp known: the global minimum of the profile over
    ``grid`` (refined within a step), the best other minimum and its ``chi^2`` above, the
    statistical standard error from the profile's curvature (the residuals' lag-1
    correlation widening it, as :func:`bubblefit.inverse.spectrum.fit_spectrum` does), and
    the standard deviation of the thicknesses read, each by its own global search, with
    each of the problems of ``alternatives`` (the lamps the pinning readings imply one by
    one): how much the thickness depends on which of the series' lamps is the right one.
    The search is global because a film near the first maximum of ``R`` (a quarter wave,
    ~100 nm) has a twin on the other side of it whose spectrum differs from its own by
    about as much as the lamps do."""
    step = grid[1] - grid[0]
    rss = prob.rss_grid(grid, 0.0)
    minima = refine_d(prob, grid, rss, 0.0)
    d, rss_best = minima[0]
    dof = max(len(prob.y) - prob.additive.shape[1] - 1, 1)
    resid = (prob.y - prob.model(d, 0.0)) * prob.weight
    rho = residual_correlation(resid)
    s2 = rss_best / dof * (1.0 + rho) / (1.0 - rho)
    var = profile_variance(prob, d, 0.0, step, fit_w=False)
    stat = float(np.sqrt(2.0 * s2 * var)) if np.isfinite(var) and var > 0 else float("inf")
    second, dchi2 = second_minimum(minima, d, step, s2)
    alt = []
    if len(alternatives):
        rows = prob.rss_lamps(grid, 0.0, np.array([p.lamp for p in alternatives]),
                              readings=np.array([p.y for p in alternatives]))
        alt = [refine_d(p, grid, row, 0.0, keep=1)[0][0] for p, row in zip(alternatives, rows)]
    candidates = profile_candidates(minima, step, s2)
    sys_nm = 0.0
    if len(alt) > 1:
        # This reading's lamp is one more draw from the lamps the K pinning readings sample:
        # the one-sigma half-width of a prediction interval (Student's t, K - 1 degrees of
        # freedom, and the uncertainty of their mean).
        k = len(alt)
        sys_nm = float(np.std(alt, ddof=1) * np.sqrt(1.0 + 1.0 / k) * stats.t.ppf(_ONE_SIGMA, k - 1))
    return dict(d=d, rss=rss_best, dof=dof, rho=rho, s2=s2, stat=stat, sys=sys_nm, second=second,
                dchi2=dchi2, profile=(rss - rss_best) / s2, noise=second_difference_noise(prob.y),
                candidates=candidates)
