"""Film thickness from spectrometer readings (bubblefit.inverse.spectrum, ``bubblefit fit-spectrum``).

Every spectrum here is synthesised by numpy code written in this file, independent of
bubblefit: the Airy reflectance of a film in air (Born & Wolf 7.6(13)), ``R = F sin^2(beta)
/ (1 + F sin^2(beta))``, ``F = 4 R1 / (1 - R1)^2``, ``beta = 2 pi n(lambda) d / lambda``,
under a halogen-like lamp (a 3000 K Planck spectrum times a Gaussian spectrometer
response), computed on a fine grid, convolved with the spectrometer's resolution,
resampled, with stray light, a dark offset and noise added.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bubblefit.cli import main
from bubblefit.errors import InputError
from bubblefit.inverse.spectrum import SpectrumOptions, film_reflectance, fit_spectrum
from bubblefit.io.spectra import Spectrum, read_spectrum


def soap_index(lam):
    return 1.324188 + 3102.06 / lam**2


def airy(d, lam, n):
    r1 = ((n - 1.0) / (n + 1.0)) ** 2
    f = 4.0 * r1 / (1.0 - r1) ** 2
    s = np.sin(2.0 * np.pi * n * d / lam) ** 2
    return f * s / (1.0 + f * s)


def lamp(lam, temperature=3000.0):
    h, c, k = 6.62607e-34, 2.99792e8, 1.380649e-23
    m = lam * 1e-9
    planck = 1.0 / (m**5 * (np.exp(h * c / (m * k * temperature)) - 1.0))
    v = planck * np.exp(-0.5 * ((lam - 600.0) / 150.0) ** 2)
    return v / v.max()


def synth(d, *, n=soap_index, lo=400.0, hi=800.0, step=0.5, noise=0.01, stray=0.03, dark=0.02, fwhm=0.0,
          seed=0):
    """(wavelengths, reading) of a film of thickness ``d`` nm, and the lamp on the same grid."""
    rng = np.random.default_rng(seed)
    lam = np.arange(lo, hi + 1e-9, step)
    fine_step = 0.02
    fine = np.arange(lo - 15.0, hi + 15.0, fine_step)
    s = lamp(fine) * airy(d, fine, n(fine))
    if fwhm > 0:
        sig = fwhm / 2.354820
        m = int(5 * sig / fine_step)
        g = np.exp(-0.5 * (np.arange(-m, m + 1) * fine_step / sig) ** 2)
        s = np.convolve(s, g / g.sum(), mode="same")
    y = np.interp(lam, fine, s)
    peak = y.max()
    y = y + stray * peak + dark + noise * peak * rng.standard_normal(lam.shape)
    return lam, y, lamp(lam)


def test_film_reflectance_is_the_airy_formula_with_dispersion():
    lam = np.linspace(380.0, 1000.0, 157)
    d = np.array([0.0, 37.0, 512.0, 4321.0, 12000.0])
    got = film_reflectance(d, lam, soap_index(lam))
    ref = airy(d[:, None], lam[None, :], soap_index(lam)[None, :])
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize("d,fwhm,use_ref", [
    (80.0, 0.0, True),      # order 0: no fringe in the visible, needs the lamp
    (450.0, 1.0, False),    # one fringe
    (1300.0, 1.0, False),
    (4000.0, 1.5, False),
    (10000.0, 1.5, False),  # ~35 fringes, washed out by the resolution in the blue
])
def test_recovers_thickness_with_honest_error(d, fwhm, use_ref):
    lam, y, ref = synth(d, fwhm=fwhm, seed=int(d))
    res = fit_spectrum(Spectrum(lam, y), reference=Spectrum(lam, ref + 0.02) if use_ref else None,
                       dark=Spectrum(lam, np.full_like(lam, 0.02)) if use_ref else None)
    assert res.ok, res.reasons
    err = res.thickness_nm - d
    assert abs(err) < 3.0 * res.thickness_nm_stderr + 0.05, (err, res.thickness_nm_stderr)
    assert res.thickness_nm_stderr < 0.1 * d
    assert res.order == int(np.floor(2 * soap_index(600.0) * d / 600.0 + 0.02)) or abs(err) < 5
    if d >= 10000:  # many fine fringes: their contrast measures the resolution
        assert abs(res.resolution_nm - fwhm) < 0.5


def test_error_bar_covers_the_scatter_over_noise():
    """Over noise realisations the errors scatter like the stated standard errors."""
    z = []
    for seed in range(8):
        lam, y, _ = synth(2000.0, noise=0.02, fwhm=1.0, seed=100 + seed)
        res = fit_spectrum(Spectrum(lam, y))
        z.append((res.thickness_nm - 2000.0) / res.thickness_nm_stderr)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.2 < rms < 2.0, z


def test_thin_film_without_reference_is_not_claimed():
    """Without a reference an order-0 film is degenerate with the unknown lamp: the result
    is either flagged or right within its error bar, never confidently wrong."""
    lam, y, _ = synth(80.0, seed=5)
    res = fit_spectrum(Spectrum(lam, y))
    assert (not res.ok) or abs(res.thickness_nm - 80.0) < 3 * res.thickness_nm_stderr
    assert not res.ok and res.reasons


def test_narrow_range_makes_the_order_ambiguous():
    """A 30 nm window on a 5 um film holds a few fringes; neighbouring orders fit as well."""
    lam, y, _ = synth(5000.0, lo=600.0, hi=630.0, step=0.2, noise=0.02, seed=7)
    res = fit_spectrum(Spectrum(lam, y))
    assert not res.ok
    assert any("ambiguous" in r for r in res.reasons)
    assert np.isfinite(res.second_minimum_nm) and res.delta_chi2 < 10


def test_dispersion_is_used():
    """Fitting with a constant n = 1.4 scales the thickness by ~n_soap/1.4 and fits worse."""
    lam, y, _ = synth(3000.0, noise=0.005, seed=11)
    good = fit_spectrum(Spectrum(lam, y))
    flat = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(n_film=1.4))
    assert abs(good.thickness_nm - 3000.0) < 3 * good.thickness_nm_stderr + 0.05
    assert abs(flat.thickness_nm / 3000.0 - 1.333 / 1.4) < 0.01
    assert flat.reduced_chi2 > 2 * good.reduced_chi2


def test_thickness_range_bound_is_reported():
    lam, y, _ = synth(3000.0, seed=3)
    res = fit_spectrum(Spectrum(lam, y), options=SpectrumOptions(thickness_range=(100.0, 2900.0)))
    assert not res.ok


# --- reading files -------------------------------------------------------------------------

def test_reads_headers_comments_footers_and_separators(tmp_path):
    lam = np.arange(400.0, 420.0, 0.5)
    val = np.sin(lam)
    body = "\n".join(f"{a}\t{b}" for a, b in zip(lam[::-1], val[::-1]))
    (tmp_path / "ocean.txt").write_text("Data from x\nIntegration Time (sec): 0.1\n>>>>>Begin Spectral Data<<<<<\n"
                                        + body + "\n>>>>>End Spectral Data<<<<<\n")
    (tmp_path / "c.csv").write_text("# comment\nwavelength_nm,intensity\n"
                                    + "\n".join(f"{a},{b}" for a, b in zip(lam, val)) + "\n")
    # decimal commas, as spreadsheet and instrument software write them in many locales
    (tmp_path / "semicolon.csv").write_text("Wave;Sample\n" + "\n".join(
        f"{a:.2f};{b:.6f}".replace(".", ",") for a, b in zip(lam, val)) + "\n")
    (tmp_path / "tabs.txt").write_text("\n".join(f"{a:.2f}\t{b:.6f}".replace(".", ",") for a, b in zip(lam, val)))
    for name in ("ocean.txt", "c.csv", "semicolon.csv", "tabs.txt"):
        s = read_spectrum(tmp_path / name)
        np.testing.assert_allclose(s.wavelength_nm, lam)
        np.testing.assert_allclose(s.intensity, val, atol=1e-6)


def test_non_finite_rows_are_skipped_and_counted(tmp_path):
    lam = np.arange(400.0, 440.0, 1.0)
    rows = [f"{a},{'nan' if i < 3 else ('inf' if i == 20 else np.cos(a))}" for i, a in enumerate(lam)]
    (tmp_path / "edges.csv").write_text("wavelength_nm,intensity\n" + "\n".join(rows) + "\n")
    s = read_spectrum(tmp_path / "edges.csv")
    keep = np.ones(len(lam), bool)
    keep[[0, 1, 2, 20]] = False
    assert s.skipped == 4
    np.testing.assert_allclose(s.wavelength_nm, lam[keep])
    np.testing.assert_allclose(s.intensity, np.cos(lam[keep]))


@pytest.mark.parametrize("text,match", [
    ("", "need at least"),
    ("400,1\n401,2\nfoo\n402,3\n" + "\n".join(f"{403 + i},1" for i in range(20)), "line 3"),
    ("\n".join(f"{40 + i * 0.1},{i % 3}" for i in range(30)), "in no unit's range"),
    ("\n".join(f"{400 + i},nan" for i in range(30)), "0 of its 30 rows are finite"),
    ("\n".join(f"{400 + i},0" for i in range(30)), "every intensity is 0"),
    ("\n".join(f"{400 + i},{1e302 * (1 + i % 2)}" for i in range(30)), "beyond any detector's range"),
    ("\n".join(f"{400 + i * 1e-3:.4f},{i % 5}" for i in range(20001)), "more than 20000 rows"),
])
def test_bad_spectrum_files(tmp_path, text, match):
    """Each refusal is one line naming the file (the CLI prints it and exits 2)."""
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        read_spectrum(p)


@pytest.mark.parametrize("text,match", [
    ("\n".join(f"{400 + i},0" for i in range(30)), "every intensity is 0"),
    ("\n".join(f"{400 + i},{1e302 * (1 + i % 2)}" for i in range(30)), "beyond any detector's range"),
    ("\n".join(f"{400 + i * 1e-3:.4f},{i % 5}" for i in range(20001)), "more than 20000 rows"),
    ("\n".join(f"{40 + i * 0.1},{i % 3}" for i in range(30)), "--wavelength-unit"),
])
def test_cli_bad_readings_one_line_exit_2(tmp_path, capsys, text, match):
    """What made the command crash or run for minutes before: one line, exit 2, no output."""
    (tmp_path / "bad.csv").write_text(text)
    assert main(["fit-spectrum", str(tmp_path / "bad.csv"), "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0] and "bad.csv" in err[0]
    assert not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("factor,unit", [(1.0, "nm"), (10.0, "Angstrom"), (1e-3, "um"), (1e-9, "m")])
def test_wavelength_unit_is_read_from_the_range(tmp_path, factor, unit):
    """400-800 nm written in another unit is read back in nm and the unit is said."""
    lam = np.linspace(400.0, 800.0, 200)
    y = 1.0 + 0.1 * np.sin(lam / 7.0)
    p = tmp_path / "u.txt"
    np.savetxt(p, np.column_stack([lam * factor, y]), delimiter=",", fmt="%.12g")
    s = read_spectrum(p)
    assert s.unit == unit
    np.testing.assert_allclose(s.wavelength_nm, lam, rtol=1e-9)
    forced = read_spectrum(p, unit=unit)
    np.testing.assert_allclose(forced.wavelength_nm, lam, rtol=1e-9)


# --- command line ----------------------------------------------------------------------------

def _write(path, lam, y):
    np.savetxt(path, np.column_stack([lam, y]), delimiter=",", header="wavelength_nm,intensity", comments="")


def test_cli_writes_csv_json_and_plots(tmp_path, capsys):
    lam, y, ref = synth(1500.0, seed=1)
    lam2, y2, _ = synth(700.0, seed=2)
    _write(tmp_path / "a.csv", lam, y)
    _write(tmp_path / "b.csv", lam2, y2)
    _write(tmp_path / "dark.csv", lam, np.full_like(lam, 0.02))
    code = main([
        "fit-spectrum", str(tmp_path / "a.csv"), str(tmp_path / "b.csv"), "--dark", str(tmp_path / "dark.csv"),
        "--n-film", "soap", "--thickness-range", "50,5000", "--csv", str(tmp_path / "out.csv"),
        "--json", str(tmp_path / "out.json"), "-o", str(tmp_path / "plot")])
    assert code == 0
    rows = (tmp_path / "out.csv").read_text().splitlines()
    assert rows[0].startswith("file,thickness_nm,thickness_nm_stderr,ok,")
    assert len(rows) == 3
    data = json.loads((tmp_path / "out.json").read_text())
    got = [s["thickness_nm"] for s in data["spectra"]]
    assert abs(got[0] - 1500) < 2 and abs(got[1] - 700) < 2
    assert all(s["ok"] for s in data["spectra"])
    assert (tmp_path / "plot_a.png").stat().st_size > 1000 and (tmp_path / "plot_b.png").exists()


def test_cli_cauchy_option(tmp_path, capsys):
    lam, y, _ = synth(2500.0, n=lambda l: 1.33 + 4000.0 / l**2, seed=4)
    _write(tmp_path / "a.csv", lam, y)
    assert main(["fit-spectrum", str(tmp_path / "a.csv"), "--cauchy", "1.33,4000", "--json",
                 str(tmp_path / "o.json")]) == 0
    res = json.loads((tmp_path / "o.json").read_text())["spectra"][0]
    assert abs(res["thickness_nm"] - 2500.0) < 3 * res["thickness_nm_stderr"] + 0.05


@pytest.mark.parametrize("argv_tail,match", [
    (["--cauchy", "1.3"], "--cauchy"),
    (["--n-film", "honey"], "preset"),
    (["--thickness-range", "100"], "--thickness-range"),
    (["--wavelength-range", "700,600"], "--wavelength-range"),
    (["--dark", "{missing}"], "no such file"),
])
def test_cli_bad_options_one_line_exit_2(tmp_path, capsys, argv_tail, match):
    lam, y, _ = synth(1000.0, seed=1)
    _write(tmp_path / "a.csv", lam, y)
    tail = [a.replace("{missing}", str(tmp_path / "nope.csv")) for a in argv_tail]
    assert main(["fit-spectrum", str(tmp_path / "a.csv"), *tail]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0]


def test_cli_bad_file_one_line_exit_2(tmp_path, capsys):
    (tmp_path / "bad.csv").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00binary")
    assert main(["fit-spectrum", str(tmp_path / "bad.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.csv" in err[0]


def test_cli_never_overwrites_an_input(tmp_path, capsys):
    lam, y, _ = synth(1000.0, seed=1)
    _write(tmp_path / "a.csv", lam, y)
    before = (tmp_path / "a.csv").read_bytes()
    assert main(["fit-spectrum", str(tmp_path / "a.csv"), "--csv", str(tmp_path / "a.csv")]) == 2
    assert "it is the input" in capsys.readouterr().err
    assert (tmp_path / "a.csv").read_bytes() == before


# ------------------------------------------------------------------ real detectors' readings
def test_local_noise_follows_the_noise_and_not_the_fringes():
    """A reading whose noise grows tenfold from red to blue, over fringes of 40 samples per
    period and 5-50 times the noise's size: the local estimate follows the noise (median
    error under 12 %, none over 40 %)."""
    from bubblefit.inverse import local_noise

    rng = np.random.default_rng(3)
    lam = np.arange(400.0, 900.0, 0.25)
    sigma = 0.001 * (1.0 + 9.0 * (900.0 - lam) / 500.0)
    y = 0.3 + 0.05 * np.sin(2.0 * np.pi * lam / 10.0) + sigma * rng.standard_normal(lam.shape)
    est = local_noise(y)
    inner = slice(100, -100)
    ratio = est[inner] / sigma[inner]
    assert np.median(np.abs(ratio - 1.0)) < 0.12
    assert np.all((ratio > 0.6) & (ratio < 1.4))


def test_detector_limits_are_found_and_only_they():
    from bubblefit.inverse.spectrum import detector_limits

    rng = np.random.default_rng(0)
    y = 0.5 + 0.2 * np.sin(np.linspace(0, 20, 500)) + 0.01 * rng.standard_normal(500)
    assert not detector_limits(y).any()
    sat = y.copy()
    sat[100:110] = 1.0                     # a saturated peak reads the full scale
    sat[:5] = 0.0                          # and the dark end is clipped at zero
    found = detector_limits(sat)
    assert found[100:110].all() and found[:5].all() and found.sum() == 15


def _divided_reading(d, seed=0):
    """A reading divided by the lamp (a flat envelope), where the lamp gives almost no light
    below 440 nm: there the division jumps between the detector's floor and its ceiling,
    as a real divided reading does."""
    rng = np.random.default_rng(seed)
    lam = np.arange(400.0, 900.0, 0.4)
    light = lamp(lam) * (1.0 - np.exp(-np.clip(lam - 430.0, 0.0, None) / 15.0))
    signal = 5.0 * airy(d, lam, soap_index(lam)) + 0.02
    counts = signal * light + 0.004 * rng.standard_normal(lam.shape)
    y = np.clip(counts / np.maximum(light, 1e-3), 0.0, 1.0)
    return lam, y


@pytest.mark.parametrize("d", [900.0, 2400.0])
def test_a_noisy_dark_end_does_not_decide_the_fit(d):
    """The garbage at the dark end weighs by its own noise (the fit is weighted by the local
    noise, with the model-error floor) and the clipped samples are left out: the thickness
    is read from the rest, ok, within 1 nm and its error bar. (Unweighted, 900 nm read
    893 +- 6 nm, not ok.)"""
    lam, y = _divided_reading(d)
    r = fit_spectrum(Spectrum(lam, y, "divided.csv"))
    assert r.ok, r.reasons
    assert abs(r.thickness_nm - d) < min(max(3.0 * r.thickness_nm_stderr, 0.5), 1.0)
    assert any("saturated" in w for w in r.warnings)


def test_a_coarsely_quantised_reading_has_a_finite_noise():
    """A reading quantised more coarsely than its noise: the misfit is measured against the
    rounding's noise, never reported as nan."""
    lam, y, _ = synth(1200.0, noise=0.0005)
    y = np.round(y / y.max() * 255.0)
    r = fit_spectrum(Spectrum(lam, y, "8bit.csv"))
    assert np.isfinite(r.reduced_chi2)
    assert abs(r.thickness_nm - 1200.0) < 5.0


def test_a_saturated_reference_is_not_divided_by():
    """The lamp read at full scale over its peak (a common way to record it): where the
    reference is saturated the reading is left out, and the thickness is read from the rest."""
    lam, y, lamp_ref = synth(1500.0, noise=0.002, stray=0.0, dark=0.0)
    ref = np.minimum(lamp_ref, 0.8)
    r = fit_spectrum(Spectrum(lam, y, "film.csv"), reference=Spectrum(lam, ref, "lamp.csv"))
    assert any("reference is saturated" in w for w in r.warnings)
    assert r.ok, r.reasons
    assert abs(r.thickness_nm - 1500.0) < max(3.0 * r.thickness_nm_stderr, 0.5)
