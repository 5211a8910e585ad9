"""A series of readings under one lamp (``fit_spectrum_series``, ``fit-spectrum --shared-lamp``).

A draining film read at intervals by the same spectrometer and lamp: the thick readings
have fringes and are read alone; the thin ones (order 0, no extremum in the visible) are
read from their brightness with the lamp the thick ones fix. The readings are synthesised
by the independent Airy formula of ``test_spectrum.py`` under a 3000 K halogen-like lamp
(not a polynomial, so the shared lamp's Legendre series only approximates it), each with
its own small change of brightness (a lamp's drift), stray light, a dark offset and noise.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from bubblefit.cli import main
from bubblefit.inverse.spectrum import SpectrumOptions
from bubblefit.inverse.spectrum_series import fit_spectrum_series
from bubblefit.io.spectra import Spectrum
from test_spectrum import _write, airy, lamp, soap_index

THICK = (1400.0, 1000.0, 700.0, 500.0, 350.0, 260.0)
THIN = (120.0, 90.0, 60.0, 40.0, 25.0)
DARK = 0.02


def reading(d, rng, *, drift=0.03, noise=0.004, stray=0.01, tilt=0.0, draws=None):
    """A reading of a film of ``d`` nm (400-800 nm, 0.5 nm steps), the lamp's brightness
    changed by a relative ``drift`` and its colour by a relative ``tilt`` from red to blue
    (one standard normal draw each, appended to ``draws`` when given), the stray light and
    dark added."""
    lam = np.arange(400.0, 800.0 + 1e-9, 0.5)
    g_bright = rng.standard_normal()
    bright = 1.0 + drift * g_bright
    u = (1.0 / lam - 1.0 / 600.0) / (1.0 / 400.0 - 1.0 / 800.0) * 2.0  # -1 at 800 nm, +1.3 at 400 nm
    g_tilt = rng.standard_normal()
    bright = bright * (1.0 + tilt * g_tilt * u)
    if draws is not None:
        draws.append((g_bright, g_tilt))
    y = bright * lamp(lam) * airy(d, lam, soap_index(lam))
    y = y + stray * 0.08 + DARK + noise * 0.08 * rng.standard_normal(lam.shape)
    return Spectrum(lam, y, path=f"d{d:g}.xy")


def series(thicknesses, seed=0, **kw):
    rng = np.random.default_rng(seed)
    return [reading(d, rng, **kw) for d in thicknesses]


@pytest.fixture(scope="module")
def draining():
    spectra = series(THICK + THIN)
    dark = Spectrum(spectra[0].wavelength_nm, np.full_like(spectra[0].wavelength_nm, DARK))
    stages = []
    fitted = fit_spectrum_series(spectra, dark=dark, progress=lambda stage, k, n: stages.append((stage, k, n)))
    n = len(spectra)
    assert stages == [("alone", k, n) for k in range(n)] + [("shared lamp", k, n) for k in range(n)]
    return spectra, dark, fitted


def test_thick_readings_pin_the_lamp(draining):
    _, _, (results, lamp_) = draining
    assert lamp_ is not None
    assert set(lamp_.pinning) >= {0, 1, 2, 3}  # the readings with several fringes
    assert 0.0 < lamp_.scale_spread < 0.15  # the drawn drift is 3 %
    for i in lamp_.pinning:
        assert results[i].ok and abs(results[i].thickness_nm - (THICK + THIN)[i]) < 0.03 * (THICK + THIN)[i]


def test_thin_films_are_read_from_their_brightness_with_honest_errors(draining):
    spectra, dark, (results, lamp_) = draining
    thin = [(d, r) for d, r in zip(THICK + THIN, results) if d in THIN]
    for d, r in thin:
        err = r.thickness_nm - d
        assert abs(err) <= 3.0 * r.thickness_nm_stderr + 1.0, (d, r.thickness_nm, r.thickness_nm_stderr)
        if r.ok:
            assert abs(err) <= 0.1 * d + 2.0, (d, r.thickness_nm)
        assert any("shared by" in w for w in r.warnings)
    assert sum(r.ok for _, r in thin) >= 3


#: The seeds of the lamp-colour series: the first six, none left out.
COLOUR_SEEDS = range(6)


@functools.lru_cache(maxsize=None)
def _colour_series(seed):
    """One lamp-colour series (see :func:`test_a_lamp_changing_colour_is_flagged_or_covered`),
    checked; returns the error / error bar of each ok thin film whose lamp is like the
    series' (covered, a tuple), and how many had a lamp beyond it. A seed's series is
    synthesised and fitted once per session (the same draws, the same fit: deterministic),
    so that the fast test's first seed is not fitted again by the slow test."""
    thick = (1400.0, 1200.0, 1000.0, 850.0, 700.0, 600.0, 500.0, 420.0, 350.0, 300.0, 260.0, 220.0)
    thin = (110.0, 95.0, 85.0, 75.0, 65.0, 50.0)
    rng = np.random.default_rng(seed)
    spectra, draws = [], []
    for d in thick + thin:
        s = reading(d, rng, drift=0.1, tilt=0.2, noise=0.003, stray=0.0, draws=draws)
        keep = s.wavelength_nm >= 450.0
        divided = (s.intensity[keep] - DARK) / lamp(s.wavelength_nm[keep]) / 0.08  # the experimenter's division
        spectra.append(Spectrum(s.wavelength_nm[keep], divided, path=s.path))
    results, lamp_ = fit_spectrum_series(spectra, options=SpectrumOptions(normalised=True))
    assert lamp_ is not None and len(lamp_.pinning) >= 8, seed
    assert all(r.normalised for r in results)  # the readings read with the shared lamp say so too
    pinned = np.array([draws[i] for i in lamp_.pinning])
    mean, sd = pinned.mean(axis=0), pinned.std(axis=0, ddof=1)
    covered, outside = [], 0
    for i, (d, r) in enumerate(zip(thick + thin, results)):
        if d not in thin or not r.ok:
            continue
        assert np.isfinite(r.thickness_nm_stderr) and r.thickness_nm_stderr > 0, (seed, d)
        if np.all(np.abs(np.asarray(draws[i]) - mean) <= 2.0 * sd):  # a lamp like the series'
            assert abs(r.thickness_nm - d) <= 3.0 * r.thickness_nm_stderr + 1.0, (
                seed, d, r.thickness_nm, r.thickness_nm_stderr)
            covered.append((r.thickness_nm - d) / r.thickness_nm_stderr)
        else:
            outside += 1
    # The series' stray light is held in the thin films' reads (the instrument's, fitted with
    # the lamp): a film whose lamp changed colour by its own 20 % draw keeps that change in its
    # residual, which may flag it; a lamp like the series' (about 90 % of draws, see below)
    # leaves it ok, so that of six thin films at least two must be.
    assert sum(r.ok for d, r in zip(thick + thin, results) if d in thin) >= 2, seed
    return tuple(covered), outside


@pytest.mark.slow
def test_a_lamp_changing_colour_is_flagged_or_covered():
    """Readings divided by a lamp (``--normalised``) whose colour then drifts from reading to
    reading (20 % from red to blue, and 10 % in brightness, one draw each): the shared lamp
    is wrong for every thin film by that film's own draw. Series of seeds 0-5, every one.

    What the error bar is: a thin film is read again with each lamp that a pinning reading
    implies, and the spread of those reads (a prediction interval: this film's lamp is one
    more draw like theirs) is its systematic error. It covers a film whose own lamp is like
    the ones the series showed: a film whose brightness and colour draws are each within
    2 sample standard deviations of the pinning readings' (at most 2.8 in all, within 3
    error bars where the read moves linearly with the lamp) must be within 3 error bars
    (+1 nm), and the rms of those films' error / error bar must be that of a one-sigma
    error bar (below the 99.9 % point of chi-square over their number). It does not cover
    a lamp the series never showed: near the first maximum of R (a quarter wave, ~100 nm)
    the brightness no longer grows with the thickness, so a lamp beyond the pinning lamps
    moves the read far more than the spread of their reads, up to the film's twin on the
    other side of the maximum (seed 2: a 95 nm film under a lamp 2.3 standard deviations
    off in colour reads 133 nm, 4.5 error bars off; a 110 nm film under a lamp 2.6
    standard deviations brighter reads 131 nm). Those films are checked only to have finite
    error bars, and counted: a new lamp lies within 2 standard deviations in both draws
    about 90 % of the time, so at least half the ok thin films must be covered."""
    from scipy import stats

    covered, outside = [], 0
    for seed in COLOUR_SEEDS:
        z, n_out = _colour_series(seed)
        covered += z
        outside += n_out
    n = len(covered)
    assert n >= 0.5 * (n + outside), (n, outside)
    rms = float(np.sqrt(np.mean(np.square(covered))))
    assert rms <= np.sqrt(stats.chi2.ppf(0.999, n) / n), (rms, n)


def test_a_lamp_changing_colour_first_seed():
    """The fast part's run of the series above: its first seed, with the same checks."""
    covered, _ = _colour_series(COLOUR_SEEDS[0])
    assert len(covered) >= 1


def test_thin_films_alone_are_not_claimed(draining):
    """Without the series' lamp the order-0 films cannot be read: each alone is flagged."""
    from bubblefit.inverse.spectrum import fit_spectrum

    spectra, dark, _ = draining
    for d, spec in zip(THICK + THIN, spectra):
        if d <= 60.0:
            assert not fit_spectrum(spec, dark=dark).ok


def test_without_enough_pinning_readings_each_is_read_alone():
    spectra = series((500.0, 60.0, 40.0), seed=3)
    results, lamp_ = fit_spectrum_series(spectra)
    assert lamp_ is None
    assert all(any("no shared lamp" in w for w in r.warnings) for r in results if not r.ok)


@pytest.mark.slow
def test_cli_shared_lamp_writes_the_series(tmp_path, capsys):
    spectra = series(THICK[:4] + THIN[:3], seed=5)
    files = []
    for s in spectra:
        p = tmp_path / s.path
        _write(p, s.wavelength_nm, s.intensity)
        files.append(str(p))
    dark = tmp_path / "dark.xy"
    _write(dark, spectra[0].wavelength_nm, np.full_like(spectra[0].wavelength_nm, DARK))
    out = tmp_path / "r.json"
    rc = main(["fit-spectrum", *files, "--dark", str(dark), "--shared-lamp", "--json", str(out),
               "--csv", str(tmp_path / "r.csv"), "-o", str(tmp_path / "plot")])
    assert rc == 0
    data = json.loads(out.read_text())
    assert len(data["shared_lamp"]["pinning"]) >= 3
    assert len(data["spectra"]) == len(files)
    assert (tmp_path / "plot_series.png").stat().st_size > 0
    assert "shared lamp: fitted to" in capsys.readouterr().out
