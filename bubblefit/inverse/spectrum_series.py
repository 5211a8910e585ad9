"""A series of readings under one lamp: each read alone, the lamp shared by those that can
be, the others read with it (:mod:`._shared_lamp` holds the shared lamp's fit), and the
order-0 films of a draining series read with its own first interference maximum
(:mod:`._first_maximum`, Scheludko's method).

This module sits above both :mod:`.spectrum` (one reading) and :mod:`._shared_lamp` (the
series' lamp), so that neither of those imports the other.

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1 (Airy reflectance).
A. Scheludko, Adv. Colloid Interface Sci. 1, 391-464 (1967).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..io.spectra import Spectrum
from . import spectrum as sp
from ._spectrum_defaults import SeriesGroup, series_departures, series_normalised
from ._spectrum_drain import AMBIGUOUS_REASON, series_sides
from ._first_maximum import first_lobe, first_maximum_lamp
from ._shared_lamp import (MAX_ALTERNATIVE_LAMPS, MIN_PINNING_READINGS, SHARED_MISFIT_RATIO, FixedLampProblem,
                           SharedLamp, alternative_lamps, read_with_lamp, shared_lamp)

__all__ = ["fit_spectrum_series", "read_with_shared_lamp", "series_brightness", "SeriesBrightness", "nearest_pins"]


def fit_spectrum_series(spectra: list[Spectrum], *, dark=None, reference=None, options=None,
                        progress=None, time_ordered: bool = False,
                        groups: list[SeriesGroup] | None = None) -> tuple[list, SharedLamp | None]:
    """Fit every reading of ``spectra`` with one lamp shared by the series (see the module).

    With ``options.normalised`` None the series is read as divided by its lamp or not by
    the majority of its readings (:func:`._spectrum_defaults.series_normalised`). With
    ``time_ordered`` (the readings in time order, a draining film) a reading read with the
    shared lamp that is thinner than a later reading read by its own fringes is not ok
    (:func:`._spectrum_defaults.series_departures`: a draining film does not thicken), and
    every other reading is put on the side of a maximum of ``R`` that the series' thinning
    says, or is not ok with the reason (:func:`._spectrum_drain.series_sides`).

    Each reading is first read alone (:func:`bubblefit.inverse.spectrum.fit_spectrum`).
    With at least :data:`MIN_PINNING_READINGS` of them ``ok`` the shared lamp is fitted to
    those, with the instrument's stray light, and every other reading is read again with both
    held (:mod:`._shared_lamp`: only its thickness free); the
    pinning readings keep their own results; in a series in time order those read in the
    first lobe of ``R`` (order 0) are then read with the series' own first maximum
    (:func:`_read_order0`). With fewer, every reading keeps its own
    result and the others get a warning saying why. ``progress(stage, k, n)`` is called
    before each reading of each stage (``"alone"``, then ``"shared lamp"``).

    ``groups`` splits the readings into several series on one instrument
    (:func:`._spectrum_defaults.series_groups`: several folders or name stems, several
    films): the lamp is fitted to the pinning readings of all of them, and each series' own
    time order (its ``ordered``) is used within it only; ``time_ordered`` is then not used.
    A series is read at its own brightness where it has pinning readings enough
    (:func:`series_brightness`), and a film of a long series in time order with the lamp of
    the pinning readings nearest it in time (:func:`nearest_pins`). Without
    ``groups`` the readings are one series, in time order when ``time_ordered``. Returns the :class:`~bubblefit.inverse.spectrum.SpectrumFit` of
    each reading, in order, and the :class:`SharedLamp` (None when there was none).
    """
    options = options or sp.SpectrumOptions()
    why = ""
    if options.normalised is None:
        flat, why = (False, "not divided: a reference reading was given") if reference is not None else \
            series_normalised(spectra, dark)
        options = replace(options, normalised=flat)
    if groups is None:
        groups = [SeriesGroup(tuple(range(len(spectra))), "given", "", bool(time_ordered), "")]
    out, lamp = _fit_series(spectra, dark, reference, options, progress, groups)
    for r in out:
        if why:
            r.normalised_why = why
    alone = set(lamp.pinning) if lamp is not None else set(range(len(out)))
    for g in groups:
        if not g.ordered:
            continue
        sub = [out[i] for i in g.indices]
        spacing = [sp._order_spacing(r.wavelength_nm, sp.dispersion.refractive_index(options.n_film, r.wavelength_nm))
                   for r in sub]
        for k, _, reason in series_departures(sub, spacing, {k for k, i in enumerate(g.indices) if i in alone}):
            sub[k].ok = False
            sub[k].reasons.append(reason)
        _take_sides(sub, options)
    return out, lamp


def _take_sides(out: list, options) -> None:
    """Each reading of a draining series on the side of a maximum of ``R`` its thinning says
    (:func:`._spectrum_drain.series_sides`), in place: its thickness, its error bar (the
    twin's weight in it), its order, and its reasons (the series' own replace "interference
    order ambiguous", which the path settles or restates)."""
    for v in series_sides(out, options.ambiguity_dchi2):
        r = out[v.index]
        r.thickness_nm, r.thickness_nm_stderr = v.thickness_nm, v.stderr_nm
        if v.moved:
            r.order, r.fringes = sp.interference_order(v.thickness_nm, r.wavelength_nm,
                                                       sp.dispersion.refractive_index(options.n_film, r.wavelength_nm))
        r.reasons = [x for x in r.reasons if not x.startswith(AMBIGUOUS_REASON)] + v.reasons
        if v.warning:
            r.warnings.append(v.warning)
        r.ok = not r.reasons


def _fit_series(spectra, dark, reference, options, progress, groups):
    """:func:`fit_spectrum_series` with ``options.normalised`` decided; ``groups`` the series
    (:func:`series_brightness`)."""
    alone = []
    for k, spec in enumerate(spectra):
        if progress is not None:
            progress("alone", k, len(spectra))
        alone.append(sp.fit_spectrum(spec, dark=dark, reference=reference, options=options))
    pins = [i for i, r in enumerate(alone) if r.ok]
    if len(pins) < MIN_PINNING_READINGS:
        why = (f"no shared lamp: only {len(pins)} of the {len(spectra)} readings can be read alone (at least "
               f"{MIN_PINNING_READINGS} must, to fit the lamp and measure its spread)")
        for r in alone:
            if not r.ok:
                r.warnings.append(why)
        return alone, None
    prepared = [sp.prepared_problem(spec, dark, reference, options) for spec in spectra]
    nu = np.concatenate([1.0 / p.wavelength_nm for p in prepared])
    nu_range = (float(nu.min()), float(nu.max()))
    terms = prepared[0].problem.basis.shape[1]
    probe = SharedLamp(np.zeros(terms), nu_range, 0.0, ())
    bases = [probe.basis(p.wavelength_nm) * (p.reference[:, None] if p.reference is not None else 1.0)
             for p in prepared]
    strays = [sp.stray_basis(p, nu_range) for p in prepared]
    lamp = shared_lamp([prepared[i].problem for i in pins], [alone[i] for i in pins], [bases[i] for i in pins],
                       nu_range, [prepared[i].grid for i in pins], [prepared[i].order_spacing for i in pins],
                       [strays[i] for i in pins])
    lamp = replace(lamp, pinning=tuple(pins))
    bright = series_brightness(lamp, groups)
    local: dict[tuple[int, ...], SharedLamp] = {}
    held: dict[int, tuple] = {}
    out = []
    for i, (r, p) in enumerate(zip(alone, prepared)):
        if progress is not None:
            progress("shared lamp", i, len(spectra))
        if i in pins:
            r.warnings.append(f"pinned the shared lamp ({len(pins)} readings)")
            out.append(r)
            continue
        b = bright[i]
        coef, each, why = b.scale * lamp.coefficients, b.each, b.why
        stray, each_stray = lamp.stray, b.each_stray
        near = nearest_pins(lamp, groups, i)
        if near is not None:
            key = tuple(near)
            if key not in local:
                local[key] = shared_lamp([prepared[j].problem for j in near], [alone[j] for j in near],
                                         [bases[j] for j in near], nu_range, [prepared[j].grid for j in near],
                                         [prepared[j].order_spacing for j in near], [strays[j] for j in near])
            coef, each = local[key].coefficients, local[key].each
            stray, each_stray = local[key].stray, local[key].each_stray
            why = (f"the lamp and stray light of the {len(near)} of them in its own series nearest it in time (readings "
                   f"{min(near) + 1}-{max(near) + 1} of the set; their brightness spreads by "
                   f"{local[key].scale_spread:.1%})")
        note = (f"read with the lamp shared by {len(pins)} readings that can be read alone, at {why} (its "
                f"series' readings' brightness spreads by {b.spread:.1%}; the thickness's spread over their own lamps "
                "is in the error bar)")
        held[i] = (bases[i] @ coef, bases[i] @ each.T, strays[i] @ stray, strays[i] @ each_stray.T)
        out.append(read_with_shared_lamp(p, *held[i][:2], options, note, r, *held[i][2:]))
    for g in groups:
        if g.ordered:
            _read_order0(g, out, alone, prepared, bases, strays, held, options)
    return out, lamp


def _read_order0(group: SeriesGroup, out: list, alone: list, prepared: list, bases: list, strays: list,
                 held: dict, options) -> None:
    """The order-0 readings of a draining series read again, in place, with the lamp and
    stray light of the series' own first interference maximum (Scheludko 1967,
    :func:`._first_maximum.first_maximum_lamp`) instead of those the thicker films pin.

    A reading is of order 0 when the series read it (with the held lamp) in the first lobe of
    ``R`` at every wavelength (:func:`._first_maximum.first_lobe`: phase below 2, no zero of
    ``R`` in the reading) and it does not pin the lamp. The envelope is taken over the
    series' readings on the same wavelengths; at least :data:`MIN_PINNING_READINGS` order-0
    readings must share the stray light's fit. Each is read at the wavelengths where the
    series passed through the first maximum, its lamp's error from the pinning readings' own
    lamps and stray light as they differ from the held ones (each alternative lamp times the
    envelope's over the held one, each alternative stray light moved as the fitted one is),
    their departures from the envelope's widened by ``sqrt(2)``: the envelope is itself one
    reading's lamp (the brightest at each wavelength), so the reading's lamp and the
    envelope's are two draws, whose difference spreads ``sqrt(2)`` times one draw's."""
    first = prepared[group.indices[0]]
    same = [i for i in group.indices if np.array_equal(prepared[i].wavelength_nm, first.wavelength_nm)]
    lam, n = first.wavelength_nm, first.n
    order0 = [i for i in same if i in held and 0.0 < out[i].thickness_nm
              and np.all(first_lobe(out[i].thickness_nm, lam, n) < 2.0)]
    if len(order0) < MIN_PINNING_READINGS:
        return
    at = {i: k for k, i in enumerate(same)}
    h0 = held[order0[0]]
    start = np.linalg.lstsq(strays[order0[0]], h0[2], rcond=None)[0]
    fm = first_maximum_lamp(lam, n, np.array([prepared[i].y for i in same]),
                            np.array([out[i].thickness_nm for i in same]), [at[i] for i in order0],
                            np.array([prepared[i].problem.weight for i in same]), first.problem.reflect, first.grid,
                            strays[order0[0]], start)
    if fm is None:
        return
    keep = fm.covered
    lo, hi = float(lam[keep].min()), float(lam[keep].max())
    note = (f"read as a film of order 0 of its series with the lamp and stray light of the series' own first "
            f"interference maximum (Scheludko's envelope of {len(same)} readings, {lo:.0f}-{hi:.0f} nm where the "
            f"film drained through it; stray light fitted to its {len(order0)} order-0 readings)")
    for i in order0:
        lamp_i, alts, stray_i, stray_alts = held[i]
        ratio = fm.lamp / np.where(lamp_i != 0.0, lamp_i, 1.0)
        p = _covered(prepared[i], keep)
        prior = out[i]
        lamps = fm.lamp[:, None] + _TWO_DRAWS * (alts * ratio[:, None] - fm.lamp[:, None])
        strays_k = fm.stray[:, None] + _TWO_DRAWS * (stray_alts - stray_i[:, None])
        r = read_with_shared_lamp(p, fm.lamp[keep], lamps[keep], options, note, alone[i], fm.stray[keep], strays_k[keep])
        r.warnings.append(f"read with the held lamp: {prior.thickness_nm:.1f} nm")
        out[i] = r


#: The spread of the difference of two independent draws over one draw's (see :func:`_read_order0`).
_TWO_DRAWS = float(np.sqrt(2.0))


def _covered(p, keep: np.ndarray):
    """The prepared reading ``p`` at the wavelengths ``keep`` only (the same model, eq. of
    :func:`bubblefit.inverse.spectrum.prepared_problem`, on fewer wavelengths)."""
    reflect, prob = p.problem.reflect, p.problem
    bg = None if prob.background is None else np.asarray(prob.background)[keep]
    sub = replace(prob, y=p.y[keep], basis=prob.basis[keep], background=bg, weight=prob.weight[keep],
                  reflect=lambda d, w: reflect(d, w)[:, keep])
    return replace(p, wavelength_nm=p.wavelength_nm[keep], y=p.y[keep], n=p.n[keep], problem=sub,
                   reference=None if p.reference is None else p.reference[keep])


#: Pinning readings nearest in time whose lamp reads a film of a long series: the order-1
#: films of ``spectraVictor2`` (development) read with the 16 nearest (its 9 order-1 pins and
#: 7 order-2 ones) gave 4 readings called ok and more than 10 % and 3 standard errors off
#: their stated values (which their fringe minima support); with the 8 nearest (order 1's
#: own) none, 64 of the 66 called ok and 63 of them within 10 %, as when order 1 alone
#: pinned the lamp.
LOCAL_PINS = 8


def nearest_pins(lamp: SharedLamp, groups: list[SeriesGroup], i: int) -> list[int] | None:
    """The :data:`LOCAL_PINS` pinning readings nearest reading ``i`` in its series' time
    order, when the series is in time order and has more pinning readings than that (None
    otherwise: it is read with the shared lamp at its series' brightness,
    :func:`series_brightness`). The reading is then read with the lamp fitted to those
    readings alone, as the shared lamp is fitted (:func:`._shared_lamp.shared_lamp`), its
    error from their own lamps.

    A lamp-divided reading's lamp is not one lamp over a long series: the level of the
    lamp that the films of one interference order pin changes from order to order
    (``spectraVictor2``, one film in one series: 0.78 of the shared lamp for its order-5
    readings, 0.96, 1.13, 1.11 and 1.09 for orders 4 to 1), so a thin film is read with the
    lamps of the readings taken just before and after it, the lamp's error from their
    scatter.

    One of several series (``groups``) with at least :data:`MIN_PINNING_READINGS` pinning
    readings of its own and no more than :data:`LOCAL_PINS` (or not in time order) is read
    with the lamp and stray light of all of them: a lamp-divided reading's stray light, as
    its brightness, is set by the reading it was divided by (``spectraVictor1``'s pinning
    readings put it at 0.26 - 0.13 P_1 alone, against 0.16 + 0.04 P_1 shared with
    ``spectraVictor2``'s; held at the shared one, three of its washed-out readings of
    1290-1390 nm as stated were read as films of 62-170 nm, at its own as 1150-1250 nm)."""
    g = next(g for g in groups if i in g.indices)
    own = [j for j in g.indices if j in set(lamp.pinning)]
    if len(groups) > 1 and len(own) >= MIN_PINNING_READINGS and (not g.ordered or len(own) <= LOCAL_PINS):
        return own  # one of several series: its own lamp and stray light (see above)
    if not g.ordered or len(own) <= LOCAL_PINS:
        return None
    at = {j: k for k, j in enumerate(g.indices)}
    return sorted(sorted(own, key=lambda j: (abs(at[j] - at[i]), at[j]))[:LOCAL_PINS])


@dataclass(frozen=True)
class SeriesBrightness:
    """The shared lamp's brightness for the readings of one series: its scale (the shared
    lamp's is 1), the relative spread of the pinning readings it comes from, the lamps of
    (at most :data:`._shared_lamp.MAX_ALTERNATIVE_LAMPS` of) those readings, (K, J), what
    it was taken from, and those readings' own stray light (K, S) when the series shares
    its stray light (:func:`._shared_lamp.shared_lamp`)."""

    scale: float
    spread: float
    each: np.ndarray
    why: str
    each_stray: np.ndarray | None = None


def series_brightness(lamp: SharedLamp, groups: list[SeriesGroup]) -> dict[int, SeriesBrightness]:
    """Each reading's :class:`SeriesBrightness` (by its index in the series).

    Several series on one instrument share the lamp's shape, but a lamp-divided reading's
    level is set by the reading it was divided by, taken once per run: the pinning
    readings of ``spectraVictor1`` and ``spectraVictor2`` (optifik's data, one
    spectrometer) read with one lamp spread by 23 % in brightness, against 4-10 % within
    one folder. A series with at least :data:`MIN_PINNING_READINGS` pinning readings of its
    own is read at their mean brightness, its lamp's error from their own lamps; a series
    with fewer at the brightness of all the pinning readings, its error from all of their
    lamps (the spread between series then widens it)."""
    scales = np.asarray(lamp.scales, dtype=np.float64)
    j = lamp.each.shape[1]
    both = lamp.each if lamp.each_stray is None else np.column_stack([lamp.each, lamp.each_stray])

    def pick(rows):
        got = alternative_lamps(both[rows])
        return got[:, :j], (None if lamp.each_stray is None else got[:, j:])

    each, each_stray = pick(slice(None))
    everyone = SeriesBrightness(1.0, lamp.scale_spread, each, f"the brightness of all {len(lamp.pinning)} of them",
                                each_stray)
    out = {}
    for g in groups:
        own = [k for k, i in enumerate(lamp.pinning) if i in set(g.indices)]
        b = everyone
        if len(groups) > 1 and len(own) >= MIN_PINNING_READINGS:
            level = float(np.mean(scales[own]))
            each, each_stray = pick(own)
            b = SeriesBrightness(level, float(np.std(scales[own], ddof=1) / level), each,
                                 f"the brightness of the {len(own)} of its own series ({level:.3f} of the shared lamp's)",
                                 each_stray)
        out.update(dict.fromkeys(g.indices, b))
    return out


def lamp_residual(others: list, prob, d: float) -> float:
    """The mean square (weighted, as the fit's residual) that a reading read with the series'
    lamp at thickness ``d`` keeps because its own lamp is one more draw like the pinning
    readings' own: the variance over ``others`` (the :class:`FixedLampProblem` of each of
    their lamps and stray light) of the model ``L_k R(d) + S_k``, mean over the range
    (0 with fewer than two). The spread of lamps that sizes the error bar's lamp part
    (:func:`._shared_lamp.read_with_lamp`), seen in the reading's residual."""
    if len(others) < 2:
        return 0.0
    r = prob.reflect(np.array([d]), 0.0)[0]
    models = np.array([(o.lamp * r + (prob.y - o.y)) * o.weight for o in others])
    return float(np.mean(np.var(models, axis=0, ddof=1)))


def read_with_shared_lamp(p, lamp: np.ndarray, alternatives: np.ndarray, options, note: str, alone,
                          stray: np.ndarray | None = None, stray_alternatives: np.ndarray | None = None):
    """The :class:`~bubblefit.inverse.spectrum.SpectrumFit` of a prepared reading ``p``
    (:func:`bubblefit.inverse.spectrum.prepared_problem`) with the lamp ``lamp`` (N,), its
    systematic error from the lamps of ``alternatives`` (N, K); ``alone`` is its own fit,
    named in a warning. With ``stray`` (N,) the series' stray light is held
    (:func:`._shared_lamp.shared_lamp`), each alternative lamp with its own stray light
    (``stray_alternatives``, (N, K)); without, the reading's own stray light is fitted."""
    if stray is None:
        prob = FixedLampProblem(p.y, lamp, p.problem.additive, p.problem.reflect, p.problem.weight)
        others = [replace(prob, lamp=col) for col in alternatives.T]
        stray = 0.0
    else:
        prob = FixedLampProblem(p.y - stray, lamp, np.zeros((len(p.y), 0)), p.problem.reflect, p.problem.weight)
        others = [replace(prob, y=p.y - s, lamp=col) for col, s in zip(alternatives.T, stray_alternatives.T)]
    r = read_with_lamp(prob, p.grid, others)
    lam, n, d = p.wavelength_nm, p.n, r["d"]
    stderr = float(np.hypot(r["stat"], r["sys"]))
    order, fringes = sp.interference_order(d, lam, n)
    reasons = sp._verdict(d, stderr, r["second"], r["dchi2"], p.grid, lam, n, True, options)
    warnings = [*p.warnings, note, f"read alone: {alone.thickness_nm:.1f} nm, " + ("ok" if alone.ok else "not ok")]
    level = float(np.mean(np.abs(p.y))) or 1.0
    flagged = len(reasons)
    # A lamp like the series' (one more draw like the pinning readings' own, whose spread of
    # reads is already the error bar's lamp part) leaves the difference between it and the
    # shared lamp in the residual: the noise the misfit tests judge by includes the spread of
    # the pinning readings' own models at this thickness (their variance, mean over the range).
    lamp_ms = lamp_residual(others, prob, d)
    scatter = float(np.sqrt(r["noise"] ** 2 + lamp_ms))
    sp._misfit(r["rss"] / r["dof"], scatter, level, reasons, warnings,
               "the reading's noise and the spread of the pinning readings' own lamps")
    fitted = prob.model(d, 0.0) + stray
    red = float(r["rss"] / r["dof"] / r["noise"] ** 2) if r["noise"] > 0 else float("nan")
    beyond = float(r["rss"] / r["dof"] / scatter**2) if scatter > 0 else float("nan")
    if len(reasons) == flagged and beyond > SHARED_MISFIT_RATIO**2:
        reasons.append(f"the series' lamp leaves structure in this reading (the residual is {np.sqrt(red):.1f} times "
                       f"its noise, {np.sqrt(beyond):.1f} times its noise and the pinning readings' own lamps' "
                       "spread): its own lamp differs from the series', and a film read from its brightness "
                       "takes the difference for thickness")
    phase, count = sp.extrema_verdict(lam, p.y, d, options.n_film, reasons)
    return sp.SpectrumFit(
        thickness_nm=float(d), thickness_nm_stderr=stderr, stderr_statistical_nm=r["stat"], stderr_lamp_nm=r["sys"],
        ok=not reasons, order=order, fringes=fringes, resolution_nm=0.0, reduced_chi2=red,
        residual_rms=float(np.sqrt(np.mean((p.y - fitted) ** 2)) / level),
        n_film=float(np.interp(0.5 * (lam.min() + lam.max()), lam, n)), second_minimum_nm=r["second"],
        delta_chi2=r["dchi2"], reasons=reasons, warnings=warnings, wavelength_nm=lam, measured=p.y, fitted=fitted,
        profile_nm=p.grid, profile_chi2=r["profile"], normalised=bool(options.normalised),
        normalised_why=alone.normalised_why, candidates=r["candidates"], shared_lamp=True, extrema_phase=phase,
        extrema=count)
