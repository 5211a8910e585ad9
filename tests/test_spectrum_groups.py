"""Several series on one instrument: one lamp shared by all, each series' time order its own
(``series_groups``, ``fit_spectrum_series(groups=...)``, ``fit-spectrum`` given several folders).

Two films drained one after the other under the same lamp and spectrometer, each read from
its thick, fringed readings down to order-0 films (read from their brightness): the second
run starts thick after the first ended thin. Read as one series in time order, the first
run's thin films would be thinner than the later, thick readings of the second run, which a
draining film forbids; read as two series, each keeps its own order. The readings are the
lamp-divided ones of ``test_spectrum_drain.py`` (the independent Airy formula of
``test_spectrum.py``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bubblefit.cli import main
from bubblefit.inverse import MAX_ALTERNATIVE_LAMPS, FixedLampProblem, SeriesGroup, alternative_lamps, series_groups
from bubblefit.inverse.spectrum import reflector


def test_folders_split_the_series_each_in_its_own_time_order(tmp_path):
    paths = []
    for run, names in (("a", ("T0900", "T1000", "T1100")), ("b", ("T0100", "T0200"))):
        (tmp_path / run).mkdir()
        paths += [str(tmp_path / run / f"{n}.xy") for n in names]
    groups = series_groups(paths)
    assert [g.indices for g in groups] == [(0, 1, 2), (3, 4)]
    assert all(g.by == "folder" and g.ordered for g in groups)
    # as one series the names are not in order (run b's frames restart at 100)
    one = series_groups(paths, "one")
    assert len(one) == 1 and not one[0].ordered
    assert all(not g.ordered for g in series_groups(paths, ordered=False))


def test_name_stems_split_the_series_in_one_folder():
    paths = ["runA_001.xy", "runB_001.xy", "runA_002.xy", "runB_002.xy"]
    groups = series_groups(paths)
    assert [(g.key, g.indices) for g in groups] == [("runA_", (0, 2)), ("runB_", (1, 3))]
    assert all(g.by == "name" and g.ordered for g in groups)
    assert [g.indices for g in series_groups(["t1.xy", "t2.xy", "t3.xy"])] == [(0, 1, 2)]


def test_fixed_lamp_profile_matches_least_squares():
    """The weighted RSS of ``y = L R(d) + S`` with the stray light ``S`` (offset and tilt)
    solved at each thickness: the matrix-product form against ``numpy.linalg.lstsq`` of the
    stray light on ``y - L R(d)`` at each thickness, with a reflectance written here (Airy,
    Born & Wolf eq. 7.6(13), an air-film-air slab at normal incidence)."""
    lam = np.linspace(450.0, 800.0, 400)
    n = 1.33 + 3000.0 / lam**2
    rng = np.random.default_rng(2)

    def airy(d):
        r = (1.0 - n) / (1.0 + n)
        f = 4.0 * r**2 / (1.0 - r**2) ** 2
        return f * np.sin(2.0 * np.pi * n * d / lam) ** 2 / (1.0 + f * np.sin(2.0 * np.pi * n * d / lam) ** 2)

    lamp = 1.0 + 0.3 * np.sin(lam / 90.0)
    y = lamp * airy(420.0) + 0.01 + rng.normal(0.0, 1e-3, lam.size)
    add = np.column_stack([np.ones_like(lam), lam / 800.0])
    weight = 1.0 / (0.5 + lam / 800.0)
    prob = FixedLampProblem(y, lamp, add, reflector(lam, n), weight)
    grid = np.linspace(0.0, 1500.0, 301)
    lamps = np.array([lamp, 1.05 * lamp, lamp * (0.9 + 0.1 * lam / 800.0)])
    got = prob.rss_lamps(grid, 0.0, lamps, chunk=64)
    for k, lk in enumerate(lamps):
        for j in range(0, len(grid), 25):
            rest = (y - lk * airy(grid[j])) * weight
            coef, *_ = np.linalg.lstsq(add * weight[:, None], rest, rcond=None)
            want = float(np.sum((rest - add @ coef * weight) ** 2))
            assert got[k, j] == pytest.approx(want, rel=1e-7, abs=1e-12 * float(np.sum((y * weight) ** 2)))
    assert grid[np.argmin(got[0])] == pytest.approx(420.0, abs=grid[1] - grid[0])


def test_fixed_lamp_profile_with_each_lamps_own_reading():
    """``rss_lamps`` with ``readings``: each lamp with its own reading (the reading less that
    lamp's own held stray light) and no free stray light, against the weighted RSS written
    out here, ``sum w^2 (y_k - L_k R(d))^2``, with the Airy reflectance of an air-film-air
    slab (Born & Wolf eq. 7.6(13))."""
    lam = np.linspace(450.0, 800.0, 300)
    n = 1.33 + 3000.0 / lam**2
    rng = np.random.default_rng(5)
    r1 = ((n - 1.0) / (n + 1.0)) ** 2
    f = 4.0 * r1 / (1.0 - r1) ** 2

    def airy(d):
        s2 = np.sin(2.0 * np.pi * n * d / lam) ** 2
        return f * s2 / (1.0 + f * s2)

    lamp = 1.0 + 0.2 * lam / 800.0
    stray = 0.02 + 0.01 * lam / 800.0
    y = lamp * airy(110.0) + stray + rng.normal(0.0, 1e-4, lam.size)
    weight = 1.0 / (0.5 + lam / 800.0)
    prob = FixedLampProblem(y - stray, lamp, np.zeros((lam.size, 0)), reflector(lam, n), weight)
    grid = np.linspace(0.0, 400.0, 201)
    lamps = np.array([lamp, 1.05 * lamp, lamp * (0.9 + 0.1 * lam / 800.0)])
    readings = np.array([y - stray, y - 1.1 * stray, y - stray - 0.003])
    got = prob.rss_lamps(grid, 0.0, lamps, chunk=64, readings=readings)
    for k in range(len(lamps)):
        for j in range(0, len(grid), 20):
            want = float(np.sum(((readings[k] - lamps[k] * airy(grid[j])) * weight) ** 2))
            assert got[k, j] == pytest.approx(want, rel=1e-7, abs=1e-12 * float(np.sum((y * weight) ** 2)))
    assert grid[np.argmin(got[0])] == pytest.approx(110.0, abs=grid[1] - grid[0])


def test_shared_stray_light_is_recovered_from_the_pinning_readings():
    """Four films read by their fringes (250-600 nm) under one lamp and one stray light of
    their own colour (an offset and a tilt in wavenumber, as the basis), each reading
    brighter or dimmer by a few per cent: the series' stray light and lamp are solved with
    the pinning readings' thicknesses and scales, and are the ones the readings were made
    with, to the noise (1e-4 of readings of ~0.1: a few 1e-4 on coefficients of ~0.05)."""
    from test_spectrum import airy, soap_index

    from bubblefit.inverse import shared_lamp
    from bubblefit.inverse.spectrum import SpectrumOptions, prepared_problem, stray_basis
    from bubblefit.io.spectra import Spectrum

    lam = np.arange(420.0, 800.0 + 1e-9, 1.0)
    nu_range = (1.0 / 800.0, 1.0 / 420.0)
    u = 2.0 * (1.0 / lam - nu_range[0]) / (nu_range[1] - nu_range[0]) - 1.0
    lamp_true = 1.0 - 0.2 * u + 0.05 * (1.5 * u**2 - 0.5)  # Legendre P0 - 0.2 P1 + 0.05 P2
    stray_true = 0.03 + 0.01 * u
    rng = np.random.default_rng(7)
    thick, scales = (600.0, 450.0, 330.0, 250.0), (1.02, 0.97, 1.01, 1.0)
    opts = SpectrumOptions(normalised=True, thickness_range=(0.0, 1000.0))
    prepared = [prepared_problem(Spectrum(lam, s * lamp_true * airy(d, lam, soap_index(lam)) + stray_true
                                          + rng.normal(0.0, 1e-4, lam.size)), None, None, opts)
                for d, s in zip(thick, scales)]
    alone = [type("Alone", (), {"thickness_nm": d, "resolution_nm": 0.0})() for d in thick]
    probe = np.polynomial.legendre.legvander(u, 2)
    lamp_ = shared_lamp([p.problem for p in prepared], alone, [probe] * 4, nu_range, [p.grid for p in prepared],
                        [p.order_spacing for p in prepared], [stray_basis(p, nu_range) for p in prepared])
    mean = float(np.mean(scales))
    assert lamp_.coefficients == pytest.approx(mean * np.array([1.0, -0.2, 0.05]), abs=3e-3)
    assert lamp_.stray == pytest.approx([0.03, 0.01], abs=3e-4)
    assert lamp_.each_stray.shape == (4, 2) and lamp_.each.shape == (4, 3)


def test_alternative_lamps_are_bounded_and_spread():
    each = np.arange(150.0)[:, None] * np.ones((1, 3))
    picked = alternative_lamps(each)
    assert len(picked) == MAX_ALTERNATIVE_LAMPS
    assert picked[0, 0] == 0.0 and picked[-1, 0] == 149.0
    assert np.all(np.diff(picked[:, 0]) >= 9.0)  # about 150 / 15 apart
    assert alternative_lamps(each[:5]).shape == (5, 3)


def _wrong(d, r) -> bool:
    """Called ok, yet more than 10 % and 3 standard errors off."""
    return bool(r["ok"]) and abs(r["thickness_nm"] - d) > 0.1 * d and \
        abs(r["thickness_nm"] - d) > 3.0 * r["thickness_nm_stderr"]


@pytest.mark.slow
def test_two_runs_in_two_folders_share_the_lamp_not_the_time_order(tmp_path, capsys):
    from test_spectrum import _write
    from test_spectrum_drain import PINS, _divided_series

    thin = (120.0, 100.0, 85.0)
    truth = PINS + thin
    files = []
    for run, seed in (("run1", 1), ("run2", 2)):
        (tmp_path / run).mkdir()
        for k, s in enumerate(_divided_series(truth, seed)):
            p = tmp_path / run / f"t{k:03d}.xy"
            _write(p, s.wavelength_nm, s.intensity)
            files.append(str(p))
    common = ["--n-film", "soap", "--thickness-range", "0,3000"]
    out = tmp_path / "r.json"
    assert main(["fit-spectrum", *files, *common, "--json", str(out)]) == 0
    said = capsys.readouterr().out
    assert "2 series (one per folder)" in said
    data = json.loads(out.read_text())
    assert [len(g["files"]) for g in data["series"]] == [len(truth), len(truth)]
    assert all(g["time_ordered"] for g in data["series"])
    shared = data["shared_lamp"]
    assert shared["series_sharing"] == 2 and "2 series" in shared["why"]
    assert {f.split("/")[-2] for f in shared["pinning"]} == {"run1", "run2"}  # both runs pin the one lamp
    rows = data["spectra"]
    truths = list(truth) * 2
    assert not [(d, r["file"], r["thickness_nm"]) for d, r in zip(truths, rows) if _wrong(d, r)]
    assert sum(r["ok"] for d, r in zip(truths, rows) if d in thin) >= 3

    # the same files as one series: run 1's thin films are thinner than run 2's later, thick
    # readings, which a draining film in time order forbids
    one = tmp_path / "one.json"
    assert main(["fit-spectrum", *files, *common, "--series-by", "one", "--json", str(one)]) == 0
    first = json.loads(one.read_text())["spectra"][len(PINS):len(truth)]
    assert all(not r["ok"] and any("does not thicken" in x for x in r["reasons"]) for r in first)
    assert isinstance(series_groups(files)[0], SeriesGroup)


def test_each_series_is_read_at_its_own_brightness_where_it_measures_it():
    """Two runs divided by different readings (0.8 and 1.2 of the shared lamp, 2 % scatter
    within each) and a third run without pinning readings of its own: the first two are read
    at their own mean brightness with their own spread, the third at the shared lamp's with
    the spread of all of them."""
    from bubblefit.inverse import SharedLamp
    from bubblefit.inverse.spectrum_series import series_brightness

    rng = np.random.default_rng(4)
    scales = np.concatenate([0.8 * (1 + 0.02 * rng.standard_normal(4)), 1.2 * (1 + 0.02 * rng.standard_normal(4))])
    scales /= scales.mean()
    pins = (0, 1, 2, 3, 5, 6, 7, 8)
    lamp_ = SharedLamp(np.ones(3), (1 / 800, 1 / 400), float(np.std(scales, ddof=1)), pins,
                       each=scales[:, None] * np.ones((1, 3)), scales=tuple(scales))
    groups = [SeriesGroup((0, 1, 2, 3, 4), "folder", "a", True, ""), SeriesGroup((5, 6, 7, 8), "folder", "b", True, ""),
              SeriesGroup((9, 10), "folder", "c", True, "")]
    got = series_brightness(lamp_, groups)
    for idx, own in ((range(5), scales[:4]), (range(5, 9), scales[4:])):
        for i in idx:
            assert got[i].scale == pytest.approx(own.mean())
            assert got[i].spread == pytest.approx(own.std(ddof=1) / own.mean())
            assert np.allclose(np.sort(got[i].each[:, 0]), np.sort(own))
    assert got[9].scale == 1.0 and got[9].spread == pytest.approx(lamp_.scale_spread) and len(got[9].each) == 8
    assert got[9].spread > 5 * got[0].spread  # the runs' levels differ far beyond their scatter
    # one series: the shared lamp itself
    one = series_brightness(lamp_, [SeriesGroup(tuple(range(11)), "given", "", True, "")])
    assert one[0].scale == 1.0 and len(one[0].each) == 8


def test_folders_that_continue_one_another_are_one_series(tmp_path):
    """One film filed in folders by order, each ending on the frame the next begins with
    (``T9503`` and ``T09503``), is one series in frame order; a folder of another run is not
    joined."""
    layout = {"order2": ("T7652", "T8500", "T9503"), "order1": ("T09503", "T12000"), "other": ("T3817", "T4000")}
    paths = []
    for folder, names in layout.items():
        (tmp_path / folder).mkdir()
        paths += [str(tmp_path / folder / f"{n}.xy") for n in names]
    groups = series_groups(paths)
    assert len(groups) == 2
    film = next(g for g in groups if g.key.endswith("{order2,order1}"))
    assert [paths[i].split("/")[-1] for i in film.indices] == ["T7652.xy", "T8500.xy", "T9503.xy", "T09503.xy",
                                                              "T12000.xy"]
    assert film.ordered
    assert next(g for g in groups if g.key.endswith("other")).indices == (5, 6)
    # two runs each numbered from the same frame overlap, not continue: two series
    assert len(series_groups([str(tmp_path / "order2" / "T7652.xy"), str(tmp_path / "order2" / "T9503.xy"),
                              str(tmp_path / "other" / "T7652.xy"), str(tmp_path / "other" / "T9503.xy")])) == 2


def test_one_of_several_series_is_read_with_its_own_pinning_readings():
    """Which pinning readings' lamp and stray light read a film (``nearest_pins``): one of
    several series with 3 to 8 pinning readings of its own, all of them (its stray light
    and brightness are set by the reading it was divided by); one with fewer, the shared
    lamp (None); a long series in time order, the 8 nearest; a single series with few
    pinning readings, the shared lamp, which is theirs."""
    from bubblefit.inverse import SharedLamp
    from bubblefit.inverse.spectrum_series import nearest_pins

    pins = (0, 1, 2, 3, 5, 6) + tuple(range(10, 30))
    lamp_ = SharedLamp(np.ones(3), (1 / 800, 1 / 400), 0.1, pins)
    groups = [SeriesGroup((0, 1, 2, 3, 4), "folder", "a", True, ""), SeriesGroup((5, 6, 7), "folder", "b", True, ""),
              SeriesGroup(tuple(range(8, 31)), "folder", "c", True, "")]
    assert nearest_pins(lamp_, groups, 4) == [0, 1, 2, 3]
    assert nearest_pins(lamp_, groups, 7) is None
    assert nearest_pins(lamp_, groups, 30) == list(range(22, 30))
    assert nearest_pins(lamp_, [SeriesGroup(tuple(range(8)), "given", "", True, "")], 4) is None
