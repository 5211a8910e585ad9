"""Spectral integration to linear sRGB and the soap-film colour chart.

Checks: a spectrally flat reflectance maps to grey; the quadrature agrees with an
independent integration by colour-science (CIE 1931 2-degree observer, D65, sRGB matrix);
the chart reproduces the known sequence of soap-film colours in reflection (black,
white/silver, first-order yellow, red, blue, then the second order green, yellow, red...),
as in the Michel-Levy chart and Isenberg, *The Science of Soap Films and Soap Bubbles*
(1992), ch. 3; and the ``bubblefit chart`` CLI writes the CSV columns of docs/design.md.
"""

from __future__ import annotations

import colorsys
import csv

import colour
import numpy as np
import pytest

from bubblefit.optics import spectral
from bubblefit.optics.chart import interference_colours


@pytest.mark.parametrize("method,samples", [("uniform", 1), ("uniform", 10), ("uniform", 30), ("uniform", 100),
                                            ("reference", 0)])
@pytest.mark.parametrize("illuminant", ["D65", "A", "E"])
def test_flat_reflectance_is_grey(method, samples, illuminant):
    basis = spectral.spectral_basis(method, samples or 30, illuminant)
    assert basis.weights.shape == (basis.samples, 3)
    assert np.all((basis.wavelengths > 380) & (basis.wavelengths < 780))
    for c in [0.0, 0.04, 0.5, 1.0]:
        rgb = np.asarray(spectral.integrate(np.full((2, basis.samples), c), basis))
        np.testing.assert_allclose(rgb, c, atol=3e-6)  # float32 sums of up to 800 weights


def _colour_science_rgb(values_fn):
    """White-balanced linear sRGB of a reflectance spectrum, integrated by colour-science at 1 nm."""
    lam = np.arange(380, 781, 1.0)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(colour.SpectralShape(380, 780, 1))
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(380, 780, 1))
    m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB)

    def rgb(vals):
        sd = colour.SpectralDistribution(dict(zip(lam, vals)))
        xyz = colour.sd_to_XYZ(sd, cmfs, ill, method="Integration")
        return m @ xyz

    white = rgb(np.ones_like(lam))
    return rgb(values_fn(lam)) / white


@pytest.mark.parametrize("name,fn", [
    ("ramp", lambda lam: (lam - 380) / 400),
    ("bump", lambda lam: np.exp(-0.5 * ((lam - 520) / 30) ** 2)),
    ("red edge", lambda lam: 1 / (1 + np.exp(-(lam - 600) / 10))),
])
def test_integration_agrees_with_colour_science(name, fn):
    ref = _colour_science_rgb(fn)
    for samples, tol in [(100, 0.01), (800, 2e-3)]:
        basis = spectral.spectral_basis("uniform", samples)
        got = np.asarray(spectral.integrate(fn(basis.wavelengths), basis))
        np.testing.assert_allclose(got, ref, atol=tol, err_msg=f"{name}, {samples} samples")


def _label(rgb, peak_lum):
    """Name of a linear-sRGB colour: dark, white, or a hue name when saturated, else None."""
    lum = float(rgb @ [0.2126, 0.7152, 0.0722])
    if lum < 0.2 * peak_lum:
        return "dark"
    top = rgb.max()
    sat = (top - rgb.min()) / top
    if sat < 0.2 and lum > 0.6 * peak_lum:
        return "white"
    if sat < 0.6:
        return None
    hue = colorsys.rgb_to_hsv(*np.clip(rgb / top, 0, 1))[0] * 360
    if hue >= 330 or hue < 25:
        return "red"
    if 35 <= hue < 75:
        return "yellow"
    if 90 <= hue < 165:
        return "green"
    if 200 <= hue < 290:
        return "blue"
    return None


def _sequence(rgb):
    peak = float(np.max(rgb @ [0.2126, 0.7152, 0.0722]))
    seq = []
    for c in rgb:
        lab = _label(c, peak)
        if lab == "dark":  # dark before any colour is the black film; later, a dim transition
            lab = "black" if not seq or seq == ["black"] else None
        if lab is not None and (not seq or seq[-1] != lab):
            seq.append(lab)
    return seq


@pytest.mark.parametrize("n_film", [1.33, 1.4])
def test_chart_reproduces_soap_film_colour_sequence(n_film):
    d = np.arange(0.0, 700.0, 5.0)
    rgb = interference_colours(d, n_film=n_film)
    assert rgb.shape == (len(d), 3)
    seq = _sequence(rgb)
    expected = ["black", "white", "yellow", "red", "blue", "green", "yellow", "red", "blue", "green"]
    assert seq[: len(expected)] == expected, seq
    # The first-order white is where the film is brightest (a quarter-wave film at ~550 nm).
    lum = rgb @ [0.2126, 0.7152, 0.0722]
    d_bright = d[np.argmax(lum[d < 200])]
    assert abs(d_bright - 550 / (4 * n_film)) < 20


def test_chart_sequence_shifts_with_angle():
    """Oblique incidence shortens the optical path (cos th_t): the sequence moves to thicker films."""
    d = np.arange(0.0, 400.0, 2.0)
    lum0 = interference_colours(d) @ [0.2126, 0.7152, 0.0722]
    lum60 = interference_colours(d, angle_deg=60.0) @ [0.2126, 0.7152, 0.0722]
    cos_t = np.sqrt(1 - (np.sin(np.radians(60.0)) / 1.4) ** 2)
    d0 = d[np.argmax(lum0[d < 200])]
    d60 = d[np.argmax(lum60[d < 300])]
    assert d60 / d0 == pytest.approx(1 / cos_t, rel=0.05)


def test_chart_models_agree_where_they_should():
    d = np.arange(0.0, 2000.0, 25.0)
    airy = interference_colours(d, model="airy")
    two = interference_colours(d, model="two_beam")
    inc = interference_colours(d, model="incoherent")
    paper = interference_colours(d, model="paper", t=1.0)
    assert np.abs(airy - two).max() < 4 * (0.04 / 1.04) ** 2 + 1e-6  # O(R1^2), R1 = ((n-1)/(n+1))^2
    np.testing.assert_allclose(inc, np.broadcast_to(inc[:1], inc.shape), rtol=1e-5)  # no interference: one grey
    # Eq. (10) at t = 1 is the two-beam fringe pattern (1 + cos) without the Fresnel scale.
    r1 = (0.4 / 2.4) ** 2
    corr = np.corrcoef(paper.ravel(), two.ravel())[0, 1]
    assert corr > 0.99
    np.testing.assert_allclose(paper.mean(0) * r1 / 2 * 2, two.mean(0), rtol=0.1)


def test_chart_cli_writes_csv_columns(tmp_path):
    from bubblefit.cli import main

    out = tmp_path / "chart.png"
    table = tmp_path / "chart.csv"
    rc = main(["chart", "--thickness", "0:600:20", "-o", str(out), "--csv", str(table)])
    assert rc == 0
    assert out.stat().st_size > 1000
    with open(table, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:4] == ["thickness_nm", "r", "g", "b"]
    data = np.array(rows[1:], dtype=float)
    np.testing.assert_allclose(data[:, 0], np.arange(0, 601, 20.0))
    np.testing.assert_allclose(data[:, 1:4], interference_colours(data[:, 0]), atol=1e-8)


@pytest.mark.parametrize("argv", [
    ["--thickness", "0:oops:5"],
    ["--thickness", "100:0:5"],
    ["--angle-deg", "120"],
])
def test_chart_cli_bad_input(tmp_path, capsys, argv):
    from bubblefit.cli import main

    rc = main(["chart", *argv, "-o", str(tmp_path / "c.png")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("bubblefit: error:") and err.count("\n") == 1
    assert not (tmp_path / "c.png").exists()


# --- illuminants, camera responses and white balance ----------------------------------------

CAMERAS = list(colour.MSDS_CAMERA_SENSITIVITIES)


def _write_csv(path, columns):
    np.savetxt(path, np.column_stack(columns), delimiter=",", header="wavelength_nm,values", comments="")
    return str(path)


@pytest.mark.parametrize("illuminant", ["D65", "E", "A", "csv"])
@pytest.mark.parametrize("response", ["srgb", *CAMERAS, "csv"])
@pytest.mark.parametrize("method", ["uniform", "reference", "fourier"])
def test_flat_reflectance_is_white_under_every_combination(illuminant, response, method, tmp_path):
    lam = np.arange(360.0, 831.0, 5.0)
    if illuminant == "csv":  # a cool LED-like illuminant
        illuminant = _write_csv(tmp_path / "ill.csv", [lam, np.exp(-0.5 * ((lam - 450) / 12) ** 2) + 0.6
                                                       * np.exp(-0.5 * ((lam - 570) / 60) ** 2)])
    if response == "csv":
        response = _write_csv(tmp_path / "resp.csv", [lam] + [np.exp(-0.5 * ((lam - c) / 40) ** 2) for c in (600, 540, 450)])
    basis = spectral.spectral_basis(method, 8 if method == "fourier" else 40, illuminant, response)
    for c in (0.0, 0.3, 1.0):
        rgb = np.asarray(spectral.integrate(np.full((1, basis.samples), c), basis))
        np.testing.assert_allclose(rgb, c, atol=3e-6)


@pytest.mark.parametrize("illuminant", ["D65", "E", "A"])
@pytest.mark.parametrize("name,fn", [
    ("ramp", lambda lam: (lam - 380) / 400),
    ("bump", lambda lam: np.exp(-0.5 * ((lam - 520) / 30) ** 2)),
    ("film", lambda lam: np.sin(2 * np.pi * 1.33 * 700 / lam) ** 2),
])
def test_srgb_response_agrees_with_colour_science_under_each_illuminant(illuminant, name, fn):
    """White-balanced linear sRGB: ``M XYZ(S) / M XYZ(1)`` per channel, with XYZ from
    ``colour.sd_to_XYZ`` (1 nm integration) and ``M`` applied by ``colour.XYZ_to_RGB``."""
    shape = colour.SpectralShape(380, 780, 1)
    lam = np.arange(380, 781, 1.0)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ill = (colour.sd_ones(shape) if illuminant == "E" else colour.SDS_ILLUMINANTS[illuminant].copy().align(shape))

    def rgb(vals):
        xyz = colour.sd_to_XYZ(colour.SpectralDistribution(dict(zip(lam, vals))), cmfs, ill, method="Integration")
        return colour.XYZ_to_RGB(xyz, "sRGB", illuminant=None, chromatic_adaptation_transform=None)

    ref = rgb(fn(lam)) / rgb(np.ones_like(lam))
    basis = spectral.spectral_basis("reference", illuminant=illuminant)
    got = np.asarray(spectral.integrate(fn(basis.wavelengths)[None], basis))[0]
    np.testing.assert_allclose(got, ref, atol=2e-3)
    if illuminant != "D65":  # the illuminant matters, and the comparison sees it
        d65 = np.asarray(spectral.integrate(fn(basis.wavelengths)[None], spectral.spectral_basis("reference")))[0]
        assert np.abs(d65 - ref).max() > 5e-3 or name == "ramp"


@pytest.mark.parametrize("camera", CAMERAS)
def test_camera_response_agrees_with_direct_integration(camera):
    """Raw camera channels (white-balanced) against the sensitivities integrated with numpy."""
    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    lam = np.arange(380.0, 781.0, 0.25)
    sens = np.stack([np.interp(lam, msds.wavelengths, msds.values[:, c], left=0, right=0) for c in range(3)], 1)
    a = colour.SDS_ILLUMINANTS["A"]
    ill = np.interp(lam, a.wavelengths, a.values)
    refl = np.sin(2 * np.pi * 1.33 * 900 / lam) ** 2
    ref = (sens * (ill * refl)[:, None]).sum(0) / (sens * ill[:, None]).sum(0)
    basis = spectral.spectral_basis("reference", illuminant="A", response=camera)
    got = np.asarray(spectral.integrate(np.sin(2 * np.pi * 1.33 * 900 / basis.wavelengths) ** 2, basis))
    np.testing.assert_allclose(got, ref, atol=3e-3)
    srgb = np.asarray(spectral.integrate(np.sin(2 * np.pi * 1.33 * 900 / basis.wavelengths) ** 2,
                                         spectral.spectral_basis("reference", illuminant="A")))
    assert np.abs(srgb - got).max() > 5e-3  # a camera is not the sRGB observer


@pytest.mark.parametrize("illuminant", ["D65", "3200K"])
@pytest.mark.parametrize("samples", [80, 800])
def test_uniform_weights_are_centred_on_their_samples(illuminant, samples):
    """Each channel's weights, placed at their samples, have the centroid of the channel's
    density (its effective wavelength), integrated independently here (trapezoid rule every
    0.01 nm on the table's piecewise-linear curve, exact on it). A shift ``dl`` of it
    reads every gap ``dl / lambda`` off: the validation's Newton photo
    (experiments/validation/data/film_newton_bk7_na010) measures its lens's radius to 3e-5,
    so the shift must stay under a tenth of that, 3e-6 x 415 nm = 1.2e-3 nm at the blue
    centroid. The midpoint rule's own shift, ``(h^2 / 12) (rho(780) - rho(380)) / int rho``
    for bins ``h`` wide, is 7e-5 nm at 5 nm bins; weights summed from points of each bin's
    left side only were 0.05 nm short."""
    dens = spectral.channel_density(illuminant, "srgb")
    lam = np.arange(380.0, 780.0 + 1e-9, 0.01)
    rho = np.stack([np.interp(lam, spectral.TABLE_GRID, dens[:, c]) for c in range(3)], axis=1)
    centroid = np.trapezoid(lam[:, None] * rho, lam, axis=0) / np.trapezoid(rho, lam, axis=0)
    basis = spectral.spectral_basis("uniform", samples, illuminant=illuminant)
    w = np.asarray(basis.weights)
    got = (np.asarray(basis.wavelengths)[:, None] * w).sum(axis=0) / w.sum(axis=0)
    np.testing.assert_array_less(np.abs(got - centroid), 1.2e-3)


def test_explicit_white_balance_gains():
    """Gains multiply raw channels normalised so that green reads 1 on a white reflector."""
    plain = spectral.spectral_basis("uniform", 40, "A", "srgb")
    gains = spectral.spectral_basis("uniform", 40, "A", "srgb", (2.0, 1.0, 0.5))
    raw = spectral.spectral_basis("uniform", 40, "A", "srgb", (1.0, 1.0, 1.0))
    white = raw.weights.sum(axis=0)
    assert abs(white[1] - 1.0) < 1e-12 and white[0] > 1.5 > 0.6 > white[2]  # A is red
    np.testing.assert_allclose(gains.weights, raw.weights * [2.0, 1.0, 0.5], rtol=1e-12)
    np.testing.assert_allclose(plain.weights, raw.weights / white, rtol=1e-12)


@pytest.mark.parametrize("text", ["", "wavelength,power\n", "500,1\n500,2\n", "500,1\nabc,2\n600,3\n", "500,-1\n600,1\n"])
def test_bad_illuminant_csv(tmp_path, text):
    from bubblefit.errors import InputError

    p = tmp_path / "ill.csv"
    p.write_text(text)
    with pytest.raises(InputError):
        spectral.illuminant_spectrum(str(p))


def _lines_csv(path, centres, sigma=0.05, step=0.01):
    """A spectrometer's CSV of Gaussian lines (unit peak) sampled every ``step`` nm."""
    lam = np.arange(380.0, 780.0 + step / 2, step)
    power = sum(np.exp(-0.5 * ((lam - c) / sigma) ** 2) for c in centres)
    np.savetxt(path, np.column_stack([lam, power]), delimiter=",", header="wavelength_nm,power", comments="")
    return sigma * np.sqrt(2.0 * np.pi)  # each line's power


def test_lamp_csv_finer_than_the_grid_keeps_each_lines_power(tmp_path):
    """Lines 0.05 nm wide (a sodium or mercury lamp read by a spectrometer): each 1 nm
    sample carries the power of its nanometre. The line at 591.7 nm lies 6 sigma from the
    nearest grid point (point sampling kept exp(-18) of it); its cell [591.5, 592.5] holds
    it but the tail beyond 4 sigma (3e-5 of it); the trapezoid rule on a Gaussian sampled
    at sigma / 5 is exact to far below that."""
    power = _lines_csv(tmp_path / "lines.csv", [589.0, 591.7])
    spd = spectral.illuminant_spectrum(str(tmp_path / "lines.csv"))
    grid = spectral.TABLE_GRID
    assert abs(spd.sum() - 2 * power) <= 1e-6 * power
    assert abs(spd[grid == 589.0][0] - power) <= 1e-6 * power
    assert abs(spd[grid == 592.0][0] - power) <= 4e-5 * power


def test_lamp_csv_on_a_coarse_grid_is_its_points(tmp_path):
    """A CSV sampled every 5 nm along a straight line: the mean over each 1 nm cell of a
    straight line is its value at the cell's centre, so the grid's values are the line's
    (to rounding), and zero outside the CSV's range."""
    lam = np.arange(400.0, 701.0, 5.0)
    np.savetxt(tmp_path / "ramp.csv", np.column_stack([lam, 0.2 + 0.003 * (lam - 400.0)]), delimiter=",")
    spd = spectral.illuminant_spectrum(str(tmp_path / "ramp.csv"))
    grid = spectral.TABLE_GRID
    inner = (grid > 400.0) & (grid < 700.0)
    np.testing.assert_allclose(spd[inner], 0.2 + 0.003 * (grid[inner] - 400.0), rtol=1e-12)
    assert np.all(spd[(grid < 400.0) | (grid > 700.0)] == 0.0)


def test_narrow_band_lamp_names_the_dark_channel(tmp_path):
    """A sodium lamp (589 nm) seen through sRGB's response: blue gets no light (sRGB's blue
    is negative there); refused in one line that names the channel."""
    from bubblefit.errors import InputError

    _lines_csv(tmp_path / "na.csv", [588.995, 589.592])
    with pytest.raises(InputError, match="blue channel") as exc:
        spectral.channel_density(str(tmp_path / "na.csv"), "srgb")
    assert "\n" not in str(exc.value) and "red" not in str(exc.value)


def test_unknown_names():
    from bubblefit.errors import InputError

    with pytest.raises(InputError, match="illuminant"):
        spectral.spectral_basis("uniform", 10, "D93")
    with pytest.raises(InputError, match="camera response"):
        spectral.spectral_basis("uniform", 10, "D65", "Canon 5D")


def test_chart_cli_with_illuminant_and_response(tmp_path, capsys):
    from bubblefit.cli import main

    out = tmp_path / "c.png"
    assert main(["chart", "--thickness", "0:1000:50", "-o", str(out), "--csv", str(tmp_path / "c.csv"),
                 "--illuminant", "E", "--camera-response", CAMERAS[0], "--n-film", "water"]) == 0
    e = np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)
    assert main(["chart", "--thickness", "0:1000:50", "-o", str(out), "--csv", str(tmp_path / "d.csv"),
                 "--n-film", "water"]) == 0
    d = np.loadtxt(tmp_path / "d.csv", delimiter=",", skiprows=1)
    assert e.shape == d.shape and np.abs(e[:, 1:] - d[:, 1:]).max() > 1e-3
    assert main(["chart", "-o", str(out), "--camera-response", "nope"]) == 2
    assert "--camera-response" in capsys.readouterr().err


def test_scene_colour_keys(tmp_path):
    from bubblefit.errors import InputError
    from bubblefit.model.scene import Scene

    lam = np.arange(380.0, 781.0, 10.0)
    _write_csv(tmp_path / "lamp.csv", [lam, 1 + lam / 800])
    sc = Scene.from_dict({"camera": {"width": 8, "height": 8, "response": CAMERAS[0], "white_balance": [1.5, 1, 2]},
                          "lighting": {"illuminant": "lamp.csv", "point_lights": [{"direction": [0, 0, 1]}]},
                          "bubble": {"thickness_nm": 600.0},
                          "effects": {"model": "physical", "interference": "airy",
                                      "spectral": {"method": "uniform", "samples": 20}}},
                         base_dir=tmp_path)
    cfg, _ = sc.config()
    b = cfg.effects.spectral
    assert b.response == CAMERAS[0] and b.illuminant == str(tmp_path / "lamp.csv") and b.white_balance == (1.5, 1.0, 2.0)
    assert b.samples == 20 and b.method == "uniform"
    for bad in ({"camera": {"white_balance": "auto"}}, {"camera": {"white_balance": [1, 0, 1]}},
                {"camera": {"response": "Canon 5D"}}, {"lighting": {"illuminant": "missing.csv"}}):
        with pytest.raises(InputError):
            Scene.from_dict(bad).config()


def test_shipped_colour_tables_equal_colour_science():
    """The observer, D65 and A that bubblefit ships (so that the default path needs no
    colour-science import) are colour-science's datasets, value for value, and the sRGB
    matrix is colour-science's."""
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    cmf = np.stack([np.interp(spectral.TABLE_GRID, cmfs.wavelengths, cmfs.values[:, c]) for c in range(3)], axis=1)
    m = colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB
    np.testing.assert_array_equal(spectral.response_functions("srgb"), cmf @ np.asarray(m).T)
    for name in ("D65", "A"):
        sd = colour.SDS_ILLUMINANTS[name]
        np.testing.assert_array_equal(spectral.illuminant_spectrum(name),
                                      np.interp(spectral.TABLE_GRID, sd.wavelengths, sd.values))
    assert spectral.is_named_illuminant("D50") and not spectral.is_named_illuminant("nowhere.csv")


def test_default_colour_path_does_not_import_colour_science():
    """Rendering sRGB under D65 reads shipped tables: colour-science (about a second to import)
    stays out of the process."""
    import subprocess
    import sys

    code = ("import sys; from bubblefit.optics import spectral; spectral.spectral_basis('fourier', 8, 'D65'); "
            "from bubblefit.io import images; images.srgb_encode(0.5); "
            "import bubblefit.inverse.fit, bubblefit.model.scene; print('colour' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_srgb_transfer_functions_agree_with_colour_science():
    v = np.linspace(0.0, 1.0, 20001)
    from bubblefit.io.images import srgb_decode, srgb_encode, srgb_slope

    np.testing.assert_allclose(srgb_decode(v), colour.cctf_decoding(v, function="sRGB"), atol=1e-8)
    np.testing.assert_allclose(srgb_encode(v), colour.cctf_encoding(v, function="sRGB"), atol=1e-12)
    np.testing.assert_allclose(srgb_decode(srgb_encode(v)), v, atol=1e-12)
    h = 1e-6  # the slope is the derivative of the decoding, away from the joint at 0.04045
    inner = (v > h) & (v < 1 - h) & (np.abs(v - 0.04045) > 2 * h)
    numeric = (srgb_decode(v + h) - srgb_decode(v - h)) / (2 * h)
    np.testing.assert_allclose(srgb_slope(v)[inner], numeric[inner], rtol=1e-6)


# --- the harmonic basis: samples in phase, exact for a film of one thickness ---------------

def _airy_in_numpy(lam, d, n, cos_i):
    """Airy reflectance of a film in air, s and p averaged (Born & Wolf 7.6), written here."""
    cos_t = np.sqrt(1 - (1 - cos_i**2) / n**2)
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    beta = 2 * np.pi * n * d * cos_t / lam
    out = 0.0
    for r in (rs, rp):
        f = 4 * r**2 / (1 - r**2) ** 2
        out = out + 0.5 * f * np.sin(beta) ** 2 / (1 + f * np.sin(beta) ** 2)
    return out


@pytest.mark.parametrize("d", [0.0, 80.0, 450.0, 1500.0, 6000.0, 20000.0])
@pytest.mark.parametrize("cos_i", [1.0, 0.5, 0.2])
def test_harmonic_basis_agrees_with_colour_science_at_any_thickness(d, cos_i):
    """The film colour from 32 phase samples equals colour-science's integration of the
    Airy spectrum (written in this test) at 0.1 nm, from a black film to 20 um (dozens of
    fringes across the visible), where 100 uniform samples alias."""
    import jax.numpy as jnp

    from bubblefit.optics import film

    n = 1.4
    lam = np.arange(380, 780.01, 0.1)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(colour.SpectralShape(380, 780, 1))
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(380, 780, 1))
    xyz = np.stack([np.interp(lam, cmfs.wavelengths, cmfs.values[:, c]) for c in range(3)], axis=1)
    dens = (xyz * np.interp(lam, ill.wavelengths, ill.values)[:, None]) @ np.asarray(
        colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB).T
    ref = (dens * _airy_in_numpy(lam, d, n, cos_i)[:, None]).sum(0) / dens.sum(0)
    basis = spectral.spectral_basis("harmonic", 32)
    assert basis.wavelengths is None and basis.phases.shape == (32,)
    w = np.asarray(spectral.harmonic_weights(np.float64(film.optical_path(d, n, cos_i)), basis))
    g = np.asarray(film.airy_at_phase(jnp.asarray(basis.phases), n, cos_i)).mean(-1)
    np.testing.assert_allclose(g @ w, ref, atol=3e-4)
    if d >= 6000:  # where uniform sampling aliases, the phase samples do not
        uni = spectral.spectral_basis("uniform", 100)
        got_u = np.asarray(film.airy_reflectance(d, uni.wavelengths, n, cos_i)).mean(-1) @ uni.weights
        assert np.abs(g @ w - ref).max() < 0.2 * np.abs(got_u - ref).max()


def test_harmonic_basis_integrates_the_paper_factor_with_four_samples():
    """Eq. (10)'s factor 2 t^2 (1 + cos delta) has two harmonics: K = 4 is exact."""
    import jax.numpy as jnp

    from bubblefit.optics import film

    ref_b = spectral.spectral_basis("reference")
    h = spectral.spectral_basis("harmonic", 4)
    for d in (0.0, 300.0, 2500.0, 9000.0):
        ref = np.asarray(film.paper_interference_factor(d, ref_b.wavelengths, 1.33, 0.7, 0.97)) @ ref_b.weights
        w = np.asarray(spectral.harmonic_weights(np.float64(film.optical_path(d, 1.33, 0.7)), h))
        got = np.asarray(film.paper_factor_at_phase(jnp.asarray(h.phases), 0.97)) @ w
        np.testing.assert_allclose(got, ref, atol=2e-4 * 4 * 0.97**2)


def test_harmonic_weights_are_differentiable_and_finite():
    import jax
    import jax.numpy as jnp

    basis = spectral.spectral_basis("harmonic", 16)
    weights = lambda v: spectral.harmonic_weights(v, basis)
    # compiled, as the renderer runs them (eagerly, each operation compiles on its own)
    weights_c, jac_c = jax.jit(weights), jax.jit(jax.jacfwd(weights))
    for x in (0.0, 1e-3, 850.0, 16800.0, 1e6):  # beyond the table the harmonics vanish
        jac = jac_c(jnp.float32(x))
        val = weights_c(jnp.float32(x))
        assert np.all(np.isfinite(np.asarray(jac))) and np.all(np.isfinite(np.asarray(val)))
        np.testing.assert_allclose(np.asarray(val).sum(0), 1.0, atol=1e-5)  # a flat spectrum stays white
