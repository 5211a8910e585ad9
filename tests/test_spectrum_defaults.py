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
from bubblefit.inverse import in_time_order, looks_normalised, same_grid, series_twins
from bubblefit.io.spectra import Spectrum

from test_spectrum import _write, synth
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


def test_a_jump_to_the_twin_is_flagged():
    """Neighbours thinning through 150-130 nm, one reading at its twin 260 nm with its second
    minimum at 140 nm: flagged, naming the neighbours' value; a reading whose second minimum
    is elsewhere is left alone."""
    def r(d, second, ok=True, dchi2=3.0):
        return SimpleNamespace(thickness_nm=d, second_minimum_nm=second, delta_chi2=dchi2, ok=ok)

    series = [r(150, np.nan), r(145, np.nan), r(260, 141), r(135, np.nan), r(130, np.nan), r(420, 600)]
    flagged = series_twins(series, [200.0] * len(series))
    assert [i for i, _, _ in flagged] == [2]
    assert "140 nm" in flagged[0][2]
    # a twin the reading itself excludes (delta chi2 1e4) is no jump; nor is a fast-thinning
    # series' first reading, which lies on the line through its neighbours
    series[2] = r(260, 141, dchi2=1e4)
    assert series_twins(series, [200.0] * len(series)) == []
    fast = [r(1500, 1255), r(1329, np.nan), r(1177, np.nan), r(1043, np.nan)]
    assert series_twins(fast, [200.0] * 4) == []


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
