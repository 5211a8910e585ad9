"""Right by default: what a set of readings is, read from the readings
(``bubblefit.inverse._spectrum_defaults``), and a draining series read with the defaults.

Readings are synthesised by the numpy code of ``test_spectrum.py`` (raw readings under a
3000 K lamp) and ``test_spectrum_normalised.py`` (readings divided by their lamp, with a
residual tilt, light that does not interfere, stray light and noise), both independent of
bubblefit.
"""

from __future__ import annotations

import os
from types import SimpleNamespace

import numpy as np
import pytest

from bubblefit.cli import main
from bubblefit.inverse import (DIVIDED_NOISE_RATIO, SpectrumOptions, fit_spectrum, in_time_order, looks_normalised,
                               noise_says_divided, same_grid, series_departures)
from bubblefit.io.spectra import Spectrum

from test_spectrum import _write, airy, lamp, soap_index, synth
from test_spectrum_normalised import divided


@pytest.mark.parametrize("d", [1500.0, 4000.0, 8000.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_divided_and_raw_readings_are_told_apart(d, seed):
    """A raw reading's envelope is the lamp's hump (45 % off a line here); a divided one's is
    flat up to its 40 % tilt. Films of 1.5 um and more have fringes enough for three windows or more."""
    lam, y, _ = synth(d, seed=seed)
    assert looks_normalised(lam, y)[0] is False
    lam, y = divided(d, seed=seed)
    assert looks_normalised(lam, y)[0] is True


def test_a_reading_without_fringes_is_not_judged():
    lam = np.linspace(450.0, 800.0, 1000)
    assert looks_normalised(lam, 1.0 + 0.2 * (lam - 450.0) / 350.0)[0] is None


def _planck(lam, temperature=3000.0):
    """Planck's law (relative), lambda in nm: a halogen lamp."""
    return lam**-5.0 / np.expm1(1.4388e7 / (lam * temperature))


def _tilted_divided(d, noise_from_lamp, seed=0, lo=400.0, hi=800.0):
    """A reading divided by a lamp that drifted: the residual gain doubles across the range
    (beyond the slow slope a flat envelope allows), a light that does not interfere and stray
    light. The noise is that of the raw counts divided by the 3000 K lamp (``~ 1 / L``, 15x
    from red to blue), or of constant deviation (a reading that carries no trace of it)."""
    rng = np.random.default_rng(seed)
    lam = np.arange(lo, hi, 0.35)
    gain = 0.5 + (lam - lo) / (hi - lo)
    lamp = _planck(lam) / _planck(hi)
    sigma = 0.004 / lamp if noise_from_lamp else np.full_like(lam, 0.01)
    y = 5.0 * gain * (airy(d, lam, soap_index(lam)) + 0.04) + 0.02 + sigma * rng.standard_normal(lam.shape)
    return lam, y


def _raw_shot(d, seed=0, lo=400.0, hi=800.0):
    """A raw reading under a bare 3000 K lamp (monotone, rising 7x to the red), shot noise
    ``~ sqrt(counts)`` and a read-noise floor."""
    rng = np.random.default_rng(seed)
    lam = np.arange(lo, hi, 0.35)
    counts = 4.0e4 * _planck(lam) / _planck(hi) * (airy(d, lam, soap_index(lam)) + 0.01) + 200.0
    return lam, counts + np.sqrt(counts + 25.0) * rng.standard_normal(lam.shape)


@pytest.mark.parametrize("d", [450.0, 1500.0, 4000.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_steeply_tilted_divided_reading_is_told_by_its_noise(d, seed):
    """A divided reading whose envelope doubles across the range is not flat enough for the
    envelope test; its noise, 15 times larger at the 400 nm end where the lamp was dim, says it
    was divided, with few fringes (450 nm: about one) as with many. The same reading with a
    noise of constant deviation is not taken for divided, nor is a raw reading under a lamp
    that rises as steeply, whose shot noise follows its light."""
    lam, y = _tilted_divided(d, True, seed)
    flat, why = looks_normalised(lam, y)
    assert flat is True, why
    assert noise_says_divided(lam, y)[1] > DIVIDED_NOISE_RATIO
    lam, y = _tilted_divided(d, False, seed)
    assert looks_normalised(lam, y)[0] is not True
    lam, y = _raw_shot(d, seed)
    assert looks_normalised(lam, y)[0] is not True
    # a raw reading's noise grows no faster than its light: the ratio stays near 1 or below
    assert noise_says_divided(lam, y)[1] < DIVIDED_NOISE_RATIO


def test_fringes_washed_out_by_a_thickness_spread_are_not_ok():
    """A 2 um film whose thickness varies over the spot (Gaussian, 60 nm deviation): its
    fringes lose 80 % of their contrast at 550 nm (``exp(-(4 pi n sigma / lambda)^2 / 2)``),
    where a 10 nm resolution would wash out only 10 % of fringes 56 nm apart. The model's
    resolution stops at its bound and the reading is not ok, with the reason; the same film
    of one thickness is read ok."""
    rng = np.random.default_rng(3)
    lam = np.arange(400.0, 800.0, 0.5)
    n = soap_index(lam)
    spread = 2000.0 + 60.0 * np.linspace(-3.0, 3.0, 61)
    w = np.exp(-0.5 * np.linspace(-3.0, 3.0, 61) ** 2)
    washed = (w[:, None] * airy(spread[:, None], lam[None, :], n[None, :])).sum(0) / w.sum()
    peak = float(lamp(lam).max() * 0.08)
    for film, expect_ok in ((washed, False), (airy(2000.0, lam, n), True)):
        y = lamp(lam) * film + 0.02 * peak + 0.005 * peak * rng.standard_normal(lam.shape)
        res = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(thickness_range=(0.0, 5000.0)))
        assert res.ok is expect_ok, res.reasons
        assert any("washed out" in r for r in res.reasons) is not expect_ok


def test_same_grid_and_time_order(tmp_path):
    lam = np.linspace(400.0, 800.0, 100)
    a, b = Spectrum(lam, np.ones(100)), Spectrum(lam + 0.5, np.ones(100))
    assert same_grid([a, a]) and not same_grid([a, b])
    names = ["t_2.csv", "t_10.csv", "t_1.csv"]
    for k, name in enumerate(names):
        (tmp_path / name).write_text("x")
        os.utime(tmp_path / name, (1000.0 + k, 1000.0 + k))
    assert in_time_order([str(tmp_path / n) for n in ("t_1.csv", "t_2.csv", "t_10.csv")])[0]
    assert in_time_order([str(tmp_path / n) for n in names])[0]  # by modification time
    os.utime(tmp_path / "t_2.csv", (2000.0, 2000.0))
    assert not in_time_order([str(tmp_path / n) for n in names])[0]


def test_a_washed_out_thick_film_read_thin_by_its_brightness_is_flagged():
    """A draining series whose first reading (a 2.5 um film, its fringes washed out) was read
    from its brightness as 110 nm, before readings of 1.7-1.4 um read by their own fringes:
    a draining film does not thicken. A later reading read from its brightness near its
    neighbours, and the thin end of a series read from brightness after thicker pinning
    readings, are left alone; so is an off reading read by its own fringes."""
    def r(d, stderr=2.0, ok=True):
        return SimpleNamespace(thickness_nm=d, thickness_nm_stderr=stderr, ok=ok)

    series = [r(110.0, 16.0), r(1705.0), r(1590.0), r(1480.0, 3.0), r(1380.0), r(1450.0, ok=False)]
    alone = {1, 2, 4, 5}
    flagged = series_departures(series, [230.0] * len(series), alone)
    assert [i for i, _, _ in flagged] == [0]
    assert flagged[0][1] == 1705.0 and "1705 nm" in flagged[0][2]
    assert series_departures(series, [230.0] * len(series), alone | {0}) == []
    # a film draining from 250 nm (pinned by its fringes) to 120 nm (read from brightness)
    thin = [r(250.0), r(230.0), r(200.0, 8.0), r(160.0, 6.0), r(120.0, 5.0)]
    assert series_departures(thin, [200.0] * 5, {0, 1}) == []


@pytest.mark.slow
def test_cli_reads_a_divided_series_right_by_default(tmp_path, capsys):
    """Eight divided readings of a film draining from 4 um to 2.2 um, in time order, read by
    ``fit-spectrum`` with no switch: read as divided and as one series (said), every reading
    within 10 % or 3 standard errors when called ok, and most called ok."""
    truth = np.linspace(4000.0, 2200.0, 8)
    paths = []
    for k, d in enumerate(truth):
        lam, y = divided(d, seed=k)
        p = tmp_path / f"film_{k:03d}.csv"
        _write(p, lam, y)
        paths.append(str(p))
    assert main(["fit-spectrum", *paths, "--json", str(tmp_path / "o.json")]) == 0
    out = capsys.readouterr().out
    assert "read as one series" in out and "divided by their lamp" in out
    import json

    rows = json.loads((tmp_path / "o.json").read_text())["spectra"]
    got = np.array([r["thickness_nm"] for r in rows])
    err = np.array([r["thickness_nm_stderr"] for r in rows])
    ok = np.array([r["ok"] for r in rows])
    assert all(r["normalised"] for r in rows)
    off = np.abs(got - truth)
    assert not np.any(ok & (off > 0.1 * truth) & (off > 3 * err))
    assert ok.sum() >= 6
