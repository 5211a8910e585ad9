"""The side of a maximum of R chosen by a draining series' thinning
(``bubblefit.inverse._spectrum_drain``).

The path is checked against a brute-force enumeration of every path written here; the
rule is checked on hand-made candidate sets (the twin of a film near the first maximum of
R, a film that thickens), and end to end on synthetic series of readings made by the
independent Airy formula of ``test_spectrum.py`` (a lamp, its drift, stray light, noise).
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from bubblefit.inverse import candidate_stderr, drain_path, series_sides


def _brute(d, c, s):
    """Every path's cost, written from the definition: the candidates' chi2 plus, for each
    step, the squared thickening over the summed variances."""
    best, arg = np.inf, None
    for ks in itertools.product(*[range(len(x)) for x in d]):
        cost = sum(c[i][k] for i, k in enumerate(ks))
        for i in range(1, len(ks)):
            rise = d[i][ks[i]] - d[i - 1][ks[i - 1]]
            if rise > 0:
                cost += rise**2 / (s[i] ** 2 + s[i - 1] ** 2)
        if cost < best:
            best, arg = cost, ks
    return best, list(arg)


@pytest.mark.parametrize("seed", range(5))
def test_path_is_the_least_cost_path(seed):
    rng = np.random.default_rng(seed)
    n = 6
    d = [np.sort(rng.uniform(60, 160, rng.integers(1, 4)))[::-1] for _ in range(n)]
    c = [np.concatenate([[0.0], rng.uniform(0, 30, len(x) - 1)]) for x in d]
    s = list(rng.uniform(2, 10, n))
    path = drain_path(d, c, s)
    cost, choice = _brute(d, c, s)
    assert path.cost == pytest.approx(cost)
    assert path.choice == choice
    # the max-marginal of each candidate is the least cost of the paths through it
    for i in range(n):
        for k in range(len(d[i])):
            held = [x if j != i else x[k:k + 1] for j, x in enumerate(d)]
            heldc = [x if j != i else x[k:k + 1] for j, x in enumerate(c)]
            assert path.through[i][k] == pytest.approx(_brute(held, heldc, s)[0] - cost)


def test_mixture_error_covers_the_twin():
    """Two candidates 40 nm apart, equally likely: the rms distance from the chosen one is
    sqrt(s^2 + 40^2 / 2); a twin excluded by 100 in chi2 adds nothing measurable."""
    assert candidate_stderr(np.array([100.0, 140.0]), np.array([0.0, 0.0]), 0, 3.0) == pytest.approx(
        np.sqrt(9.0 + 800.0))
    assert candidate_stderr(np.array([100.0, 140.0]), np.array([0.0, 100.0]), 0, 3.0) == pytest.approx(3.0, rel=1e-6)


def _r(cands, stderr=3.0, ok=True, reasons=()):
    """A reading's result: its best first among ``cands`` ((thickness, chi2) pairs)."""
    return SimpleNamespace(thickness_nm=cands[0][0], thickness_nm_stderr=stderr, candidates=list(cands), ok=ok,
                           reasons=list(reasons))


def test_readings_on_the_wrong_side_are_moved_by_the_thinning():
    """A film thinning 124 -> 82 nm past the first maximum (~100 nm): each reading's twin is
    about 200 - d. Three readings prefer their twin a little (chi2 1); the path thins
    only through the true sides, and the moved readings say so."""
    true = [124.0, 116.0, 108.0, 98.0, 90.0, 82.0]
    prefer_twin = {1, 2, 4}
    series = []
    for i, d in enumerate(true):
        twin = 200.0 - d
        series.append(_r([(twin, 0.0), (d, 1.0)] if i in prefer_twin else [(d, 0.0), (twin, 1.0)],
                         reasons=["interference order ambiguous: ..."]))
    out = series_sides(series, 10.0)
    assert [v.thickness_nm for v in out] == true
    assert [v.moved for v in out] == [i in prefer_twin for i in range(len(true))]
    # the ends of the series are not settled by their neighbours as firmly as the middle,
    # but every reading's error bar covers its twin's weight
    for v in out:
        assert v.stderr_nm >= 3.0


def test_a_thickening_film_is_not_read_as_draining():
    """A film that thickens 90 -> 120 nm (a thicker patch drifting into the spot), each
    reading sure of its side (twin at chi2 60): the path keeps the readings' own sides,
    and the readings around the rise are not ok, with the reason."""
    true = [130.0, 110.0, 90.0, 120.0, 100.0]
    series = [_r([(d, 0.0), (200.0 - d, 60.0)]) for d in true]
    out = series_sides(series, 10.0)
    assert [v.thickness_nm for v in out] == true
    bad = [v.index for v in out if v.reasons]
    assert bad == [2, 3]
    assert "rise from 90.0 to 120.0 nm" in out[2].reasons[0]


def test_a_reading_that_cannot_tell_its_side_is_not_ok_with_a_wide_error():
    """Two readings of the same film on either side of a 95-105 nm pair, no preference:
    the path cannot choose either, both are not ok, their error bars cover the twin."""
    series = [_r([(140.0, 0.0)]), _r([(105.0, 0.0), (95.0, 0.5)], reasons=["interference order ambiguous: x"]),
              _r([(60.0, 0.0)])]
    out = series_sides(series, 10.0)
    mid = out[1]
    assert mid.reasons and "neither the reading nor" in mid.reasons[0]
    assert mid.stderr_nm > 5.0


def test_other_reasons_keep_a_reading_out_of_the_path():
    """A reading not ok for another reason (its misfit) neither takes part nor is judged."""
    series = [_r([(130.0, 0.0)]), _r([(300.0, 0.0)], ok=False, reasons=["the model does not explain"]),
              _r([(90.0, 0.0)])]
    out = series_sides(series, 10.0)
    assert [v.index for v in out] == [0, 2]
    assert not any(v.reasons for v in out)


def test_isotonic_blocks_pool_the_rises():
    """A thinning series with one rise (92 -> 100) pools those two readings at their
    weighted mean, chi2 about it as written out here; a steadily thinning one pools none."""
    from bubblefit.inverse import isotonic_blocks

    d = np.array([130.0, 110.0, 92.0, 100.0, 80.0])
    s = np.array([2.0, 2.0, 2.0, 4.0, 2.0])
    blocks = isotonic_blocks(d, s)
    pooled = [b for b in blocks if b[1] - b[0] > 1]
    assert len(pooled) == 1 and pooled[0][:2] == (2, 4)
    w = 1.0 / s[2:4] ** 2
    level = float(np.sum(w * d[2:4]) / np.sum(w))
    assert pooled[0][2] == pytest.approx(level)
    assert pooled[0][3] == pytest.approx(float(np.sum(w * (d[2:4] - level) ** 2)))
    assert all(b - a == 1 for a, b, _, _ in isotonic_blocks(np.array([130.0, 120.0, 90.0]), np.ones(3)))


# ----------------------------------------------------------------------------- end to end
#: Films read by their fringes (they pin the series' lamp), then order-0 films.
PINS = (600.0, 450.0, 330.0, 250.0)


def _divided_series(thickness, seed, *, drift=0.03, tilt=0.02, noise=0.002, stray=0.01, stray_colour=3000.0,
                    level=None):
    """Readings of films of ``thickness`` nm in time order (420-800 nm, 1 nm steps), each
    under the 3000 K lamp of ``test_spectrum.py`` whose brightness and colour (a tilt from
    red to blue) change by one normal draw each of relative size ``drift`` and ``tilt``
    (times ``level[k]`` for reading ``k`` when given: a lamp that changes over the series),
    with stray light of the lamp's colour, or of a light of colour temperature
    ``stray_colour`` (room light reaching the spectrometer; the same in every reading) and
    noise growing where the lamp is dim, then divided by the lamp as read once (an
    experimenter's division)."""
    from test_spectrum import airy, lamp, soap_index

    from bubblefit.io.spectra import Spectrum

    rng = np.random.default_rng(seed)
    lam = np.arange(420.0, 800.0 + 1e-9, 1.0)
    u = (1.0 / lam - 1.0 / 600.0) / (1.0 / 420.0 - 1.0 / 800.0) * 2.0
    out = []
    for k, d in enumerate(thickness):
        bright = (1.0 + drift * rng.standard_normal()) * (1.0 + tilt * rng.standard_normal() * u)
        bright = bright * (1.0 if level is None else level[k])
        raw = bright * lamp(lam) * airy(d, lam, soap_index(lam)) + stray * 0.08 * lamp(lam, stray_colour)
        raw = raw + noise * 0.08 * rng.standard_normal(lam.shape) * np.sqrt(lamp(lam))
        out.append(Spectrum(lam, raw / lamp(lam) / 0.08, path=f"t{k:03d}.xy"))
    return out


def _read(thickness, seed, **kw):
    from bubblefit.inverse.spectrum import SpectrumOptions
    from bubblefit.inverse.spectrum_series import fit_spectrum_series

    results, lamp_ = fit_spectrum_series(_divided_series(thickness, seed, **kw), time_ordered=True,
                                         options=SpectrumOptions(normalised=True, thickness_range=(0.0, 3000.0)))
    assert lamp_ is not None and len(lamp_.pinning) >= 3
    return results


def _wrong(d, r) -> bool:
    """Called ok, yet more than 10 % and 3 standard errors off."""
    return bool(r.ok) and abs(r.thickness_nm - d) > 0.1 * d and abs(r.thickness_nm - d) > 3.0 * r.thickness_nm_stderr


@pytest.mark.slow
@pytest.mark.parametrize("seed, drift, tilt, least_ok", [(1, 0.03, 0.02, 5), (3, 0.1, 0.2, 0)])
def test_order0_films_draining_through_the_first_maximum(seed, drift, tilt, least_ok):
    """A film thinning from 140 to 70 nm in 6 nm steps, through the first maximum of R
    (~100 nm in this range), read with the lamp that four thicker films pin. Under a lamp
    that changes little from reading to reading (3 % brightness, 2 % colour) and one that
    changes much (10 %, 20 %: reads of one film then move by ~20 nm), no reading is called
    ok that is more than 10 % and 3 standard errors off. Under the steady lamp most thin
    films are read (at least 5 of 12); under the unsteady one none need be (four pinning
    readings cannot tell what lamp a fifth had), but none may be wrong."""
    thin = tuple(np.arange(140.0, 69.0, -6.0))
    truth = PINS + thin
    results = _read(truth, seed, drift=drift, tilt=tilt)
    assert not [(d, r.thickness_nm, r.thickness_nm_stderr) for d, r in zip(truth, results) if _wrong(d, r)]
    ok_thin = [r for d, r in zip(truth, results) if d in thin and r.ok]
    assert len(ok_thin) >= least_ok
    assert all(np.isfinite(r.thickness_nm_stderr) and r.thickness_nm_stderr > 0 for r in ok_thin)


@pytest.mark.slow
def test_order0_films_under_stray_light_of_another_colour_are_read_as_they_thin():
    """A film thinning from 136 to 76 nm in 6 nm steps through the first maximum of R, under
    a steady lamp (3 % brightness, 2 % colour), with stray light of another colour than the
    lamp's (a 5000 K light, 0.2 of the first maximum's brightness at its peak, the same in
    every reading: curved in wavenumber once divided by the 3000 K lamp, which an offset and
    a tilt do not describe). A film of order 0 tells its thickness by the level and slope of
    its reflectance (``R ~ sin^2(2 pi n d / lambda)``: its maximum moves from 720 nm to
    400 nm over these films); with an offset and a tilt of stray light free in each reading
    only the curvature of ``R`` is left, which the stray light's own curvature bends, and
    the films are read 10-45 nm off, on either side of the maximum. Held at the
    series' stray light, fitted with the lamp on the pinning readings, each film is read
    within 10 % (the criterion of optifik's tests and of ``docs/spectra.md``'s table; the
    lamp's 3 % drift alone moves a read by about 1.5 %, ``R ~ d^2`` below the maximum), and
    none is called ok further off than that and 3 standard errors."""
    thin = tuple(np.arange(136.0, 75.0, -6.0))
    truth = PINS + thin
    results = _read(truth, 1, stray=0.2, stray_colour=5000.0, noise=0.004)
    assert not [(d, r.thickness_nm, r.thickness_nm_stderr) for d, r in zip(truth, results) if _wrong(d, r)]
    off = [(d, round(r.thickness_nm, 1)) for d, r in zip(truth, results) if d in thin
           and abs(r.thickness_nm - d) > 0.1 * d]
    assert not off


@pytest.mark.slow
def test_a_film_that_thickens_is_not_read_as_draining():
    """A film thinning from 140 to 84 nm, then thickening back to 128 nm (a thicker patch
    drifting into the spot) and thinning again: the rise is not hidden by moving readings to
    their twins; the readings of the rise are not ok and say that the series rose where a
    draining film thins, and none is called ok more than 10 % and 3 standard errors off."""
    film = (140.0, 128.0, 116.0, 104.0, 92.0, 84.0, 92.0, 104.0, 116.0, 128.0, 116.0, 104.0, 92.0)
    truth = PINS + film
    results = _read(truth, 1)
    assert not [(d, r.thickness_nm) for d, r in zip(truth, results) if _wrong(d, r)]
    rise = [r for k, r in enumerate(results) if len(PINS) + 5 <= k <= len(PINS) + 9]
    assert all(not r.ok for r in rise)
    assert any(any("where a draining film thins" in x for x in r.reasons) for r in rise)


@pytest.mark.slow
def test_order0_films_under_a_brighter_lamp_than_the_pins_are_read_by_the_first_maximum():
    """A lamp-divided series whose lamp is 8 % brighter for its order-0 films than for the
    four thicker films that pin it (the level of a divided reading's lamp changes over a
    series: 5-8 % on optifik's spectraVictor2 between order 1 and order 0), with stray light
    of another colour (5000 K, 0.2 of the first maximum), a lamp steady from one reading to
    the next (0.5 % brightness and colour) and noise. The film drains from 154 to 70 nm in
    6 nm steps, through the first maximum at every wavelength of 420-800 nm. Read with the
    pins' lamp, a film below the maximum (``R ~ d^2``) comes out about 4 % thick (half the
    lamp's 8 %; near the maximum, where ``R`` is flat in ``d``, the held lamp's colour moves
    it either way). Read with the series' own first maximum (Scheludko's envelope), the
    films are right within what the noise and the lamp's steadiness leave: a film's relative
    error is half its lamp's (``R ~ d^2``), and its lamp's error is its own reading's draw
    plus the envelope's (one reading's draw), so each film lies within 3 times its
    statistical error (the reading's noise) and ``drift d`` added in quadrature, the median
    of the relative errors within ``drift``, and none is called ok and wrong."""
    from test_spectrum import soap_index

    drift = 0.005
    thin = tuple(np.arange(154.0, 69.0, -6.0))
    truth = PINS + thin
    level = [1.0] * len(PINS) + [1.08] * len(thin)
    results = _read(truth, 2, drift=drift, tilt=drift, stray=0.2, stray_colour=5000.0, noise=0.002, level=level)
    lam = np.arange(420.0, 800.0 + 1e-9, 1.0)
    order0 = [k for k, d in enumerate(truth) if np.all(4.0 * soap_index(lam) * d / lam < 2.0)]
    assert [truth[k] for k in order0] == list(thin)
    rel = np.array([results[k].thickness_nm / truth[k] - 1.0 for k in order0])
    assert abs(float(np.median(rel))) <= drift
    for k in order0:
        r, d = results[k], truth[k]
        assert abs(r.thickness_nm - d) <= 3.0 * np.hypot(r.stderr_statistical_nm, drift * d)
    assert not [(d, r.thickness_nm) for d, r in zip(truth, results) if _wrong(d, r)]
    assert all(any("first interference maximum" in w for w in results[k].warnings) for k in order0)
