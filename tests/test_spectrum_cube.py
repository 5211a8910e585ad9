"""Thickness maps from spectral images (``bubblefit.inverse.spectral_map``, ``bubblefit.io.cubes``,
``bubblefit fit-spectrum CUBE``).

The cubes are synthesised here, independently of bubblefit: the Airy reflectance of a soap
film in air written out (Born & Wolf 7.6(13), ``R = F sin^2(beta) / (1 + F sin^2(beta))``,
``F = 4 R1 / (1 - R1)^2``, ``beta = 2 pi n(lambda) d / lambda``, ``n`` the soap solution's
Cauchy law), under a 3000 K Planck lamp times a Gaussian camera response, an illumination
that varies over the image, stray light, and Gaussian noise; thicknesses from order 0
(~100 nm) to 10 um.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bubblefit.cli import main
from bubblefit.errors import InputError
from bubblefit.inverse.spectral_map import MapOptions, count_order_hops, fit_cube
from bubblefit.io.cubes import SpectralCube, read_cube

from test_spectrum import airy, lamp, soap_index


def synth_cube(h, w, bands, *, dmin=100.0, dmax=10000.0, noise=0.01, stray=0.04, seed=0):
    """(wavelengths, cube (h, w, bands) float32, true thickness (h, w)): a film thickening
    smoothly from ``dmin`` at one corner to ``dmax`` at the other (a draining film's wedge),
    noise ``noise`` of the brightest fringe."""
    rng = np.random.default_rng(seed)
    lam = np.linspace(420.0, 780.0, bands)
    yy, xx = np.mgrid[0:h, 0:w]
    u = 0.75 * (xx / max(w - 1, 1)) ** 1.5 + 0.25 * (yy / max(h - 1, 1))
    t = dmin + (dmax - dmin) * u
    illum = 0.7 + 0.3 * np.cos(2.0 * xx / w) * np.cos(yy / h)
    peak = float(np.max(airy(np.linspace(80, 130, 50)[:, None], lam, soap_index(lam)) * lamp(lam)))
    r = airy(t[..., None], lam, soap_index(lam))
    cube = illum[..., None] * lamp(lam) * r + stray * peak + noise * peak * rng.standard_normal(r.shape)
    return lam, cube.astype(np.float32), t


@pytest.fixture(scope="module")
def wedge():
    lam, cube, t = synth_cube(48, 48, 96, seed=3)
    result = fit_cube(SpectralCube(lam, cube, (0, 1, 2), "wedge"), options=MapOptions(thickness_range=(0.0, 12000.0)))
    return lam, cube, t, result


def test_map_of_a_wedge_from_order_0_to_10_um(wedge):
    """Median error <= 2 nm (the noise alone gives ~0.2 nm at 96 bands); no pixel called ok
    more than half an order off (an order hop); at least 95 % of the pixels ok."""
    lam, cube, t, m = wedge
    err = m.thickness_nm - t
    assert np.nanmedian(np.abs(err)) <= 2.0
    assert count_order_hops(np.where(m.ok, m.thickness_nm, t), t, m.order_spacing_nm) == 0
    assert m.ok.mean() >= 0.95


def test_map_error_bars_cover_the_errors(wedge):
    """On ok pixels the errors over their standard errors: median |pull| within 0.45-1.0
    (0.674 for a normal deviate), and no ok pixel more than 10 % and 3 standard errors off."""
    _, _, t, m = wedge
    pull = np.abs(m.thickness_nm - t)[m.ok] / m.stderr_nm[m.ok]
    assert 0.45 <= np.median(pull) <= 1.0
    off = np.abs(m.thickness_nm - t)
    assert not np.any(m.ok & (off > 0.1 * t) & (off > 3 * m.stderr_nm))


def test_reference_lamp_gives_the_same_map(tmp_path):
    """With the lamp read (a reference spectrum) instead of fitted, the map agrees."""
    from bubblefit.io.spectra import Spectrum

    lam, cube, t = synth_cube(24, 24, 96, dmin=400.0, dmax=4000.0, seed=5)
    ref = Spectrum(lam, lamp(lam), "lamp")
    m = fit_cube(SpectralCube(lam, cube, (0, 1, 2), "c"), reference=ref, options=MapOptions(thickness_range=(0, 6000)))
    assert np.nanmedian(np.abs(m.thickness_nm - t)) <= 2.0
    assert count_order_hops(m.thickness_nm, t, m.order_spacing_nm) == 0


def test_pixels_the_model_cannot_explain_are_not_ok():
    """Pixels whose spectrum is something else (a smooth bump and noise, e.g. a dust speck
    or the frame) are not ok; the film's pixels around them stay ok and right."""
    lam, cube, t = synth_cube(24, 24, 96, dmin=400.0, dmax=4000.0, seed=19)
    rng = np.random.default_rng(3)
    bad = np.zeros((24, 24), bool)
    bad[5:8, 10:13] = True
    bump = 0.05 * np.exp(-0.5 * ((lam - 550.0) / 40.0) ** 2)
    cube[bad] = (bump + 0.02 + 0.003 * rng.standard_normal((bad.sum(), lam.size))).astype(np.float32)
    m = fit_cube(SpectralCube(lam, cube, (0, 1, 2), "c"), options=MapOptions(thickness_range=(0, 6000)))
    assert not m.ok[bad].any()
    assert m.ok[~bad].mean() >= 0.95
    assert np.nanmedian(np.abs(m.thickness_nm - t)[~bad]) <= 2.0


def test_line_scan_is_a_map_one_pixel_wide():
    lam, cube, t = synth_cube(64, 1, 96, dmin=300.0, dmax=3000.0, seed=7)
    line = cube[:, 0, :]
    m = fit_cube(SpectralCube(lam, line, (0, None, 1), "line"), options=MapOptions(thickness_range=(0, 6000)))
    assert m.thickness_nm.shape == (64, 1)
    assert np.nanmedian(np.abs(m.thickness_nm - t)) <= 2.0


# ------------------------------------------------------------------------------- formats
def _write_envi(path, cube, lam, interleave="bil", unit_line="wavelength units = Nanometers\n"):
    h, w, b = cube.shape
    arr = {"bsq": cube.transpose(2, 0, 1), "bil": cube.transpose(0, 2, 1), "bip": cube}[interleave]
    np.ascontiguousarray(arr, dtype="<f4").tofile(path.with_suffix(".img"))
    path.write_text(f"ENVI\nsamples = {w}\nlines = {h}\nbands = {b}\nheader offset = 0\ndata type = 4\n"
                    f"interleave = {interleave}\nbyte order = 0\n{unit_line}"
                    "wavelength = {" + ", ".join(f"{v:.4f}" for v in lam) + "}\n")


@pytest.mark.parametrize("fmt", ["bsq", "bil", "bip", "npy", "npz", "h5", "zarr", "bands_first_npz"])
def test_every_format_reads_the_same_cube(tmp_path, fmt):
    rng = np.random.default_rng(1)
    lam = np.linspace(420.0, 780.0, 20)
    cube = rng.random((5, 7, 20)).astype(np.float32)
    if fmt in ("bsq", "bil", "bip"):
        path = tmp_path / "c.hdr"
        _write_envi(path, cube, lam, fmt)
        c = read_cube(path)
    elif fmt == "npy":
        np.save(tmp_path / "c.npy", cube)
        np.savetxt(tmp_path / "w.txt", lam)
        c = read_cube(tmp_path / "c.npy", wavelengths=tmp_path / "w.txt")
    elif fmt == "npz":
        np.savez(tmp_path / "c.npz", cube=cube, wavelength_nm=lam)
        c = read_cube(tmp_path / "c.npz")
    elif fmt == "bands_first_npz":
        np.savez(tmp_path / "c.npz", cube=cube.transpose(2, 0, 1), wavelength_nm=lam)
        c = read_cube(tmp_path / "c.npz")
    elif fmt == "h5":
        h5py = pytest.importorskip("h5py")
        with h5py.File(tmp_path / "c.h5", "w") as f:
            f["data/cube"] = cube
            f["data/cube"].attrs["wavelength_nm"] = lam
        c = read_cube(tmp_path / "c.h5")
    else:
        zarr = pytest.importorskip("zarr")
        g = zarr.open_group(str(tmp_path / "c.zarr"), mode="w")
        g.create_array("cube", shape=cube.shape, dtype="f4", chunks=(2, 7, 20))[...] = cube
        g.create_array("wavelength_nm", shape=lam.shape, dtype="f8")[...] = lam
        c = read_cube(tmp_path / "c.zarr")
    assert c.shape == (5, 7)
    np.testing.assert_allclose(c.wavelength_nm, lam, rtol=1e-6)
    np.testing.assert_array_equal(c.rows(1, 4), cube[1:4].astype(np.float64))


def test_angstrom_cube_is_converted(tmp_path):
    lam = np.linspace(4200.0, 7800.0, 20)
    np.savez(tmp_path / "a.npz", cube=np.ones((3, 3, 20)), wavelength=lam)
    c = read_cube(tmp_path / "a.npz")
    assert c.unit == "Angstrom"
    np.testing.assert_allclose(c.wavelength_nm, lam / 10.0)


@pytest.mark.parametrize("make,match", [
    (lambda p: np.savez(p / "c.npz", cube=np.ones((3, 3, 20))), "no wavelength axis"),
    (lambda p: np.savez(p / "c.npz", cube=np.ones((3, 3, 20)), wavelength_nm=np.linspace(780, 420, 20)),
     "do not increase"),
    (lambda p: np.savez(p / "c.npz", cube=np.ones((3, 3, 20)), wavelength_nm=np.linspace(42, 78, 20)),
     "no unit's range"),
    (lambda p: np.savez(p / "c.npz", cube=np.ones((3, 3, 21)), wavelength_nm=np.linspace(420, 780, 20)),
     "has the 20 wavelengths"),
    (lambda p: np.save(p / "c.npy", np.ones((3, 3, 20))), "--wavelengths"),
])
def test_bad_cubes_are_refused_in_one_line(tmp_path, capsys, make, match):
    make(tmp_path)
    path = next(tmp_path.glob("c.*"))
    with pytest.raises(InputError, match=match):
        read_cube(path)
    assert main(["fit-spectrum", str(path), "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match.strip("-") in err[0]
    assert not (tmp_path / "o.json").exists()


@pytest.mark.slow
def test_cli_writes_the_maps(tmp_path, capsys):
    lam, cube, t = synth_cube(32, 32, 96, dmin=200.0, dmax=5000.0, seed=11)
    _write_envi(tmp_path / "c.hdr", cube, lam)
    out = tmp_path / "m"
    assert main(["fit-spectrum", str(tmp_path / "c.hdr"), "-o", str(out), "--json", str(tmp_path / "m.json"),
                 "--thickness-range", "0,8000"]) == 0
    for name in ("thickness", "thickness_stderr"):
        assert (tmp_path / f"m_{name}.exr").stat().st_size > 1000
        assert (tmp_path / f"m_{name}.png").stat().st_size > 1000
    from bubblefit.io.images import read_image

    got = read_image(tmp_path / "m_thickness.exr").pixels[..., 0]
    assert np.nanmedian(np.abs(got - t)) <= 2.0
    summary = json.loads((tmp_path / "m.json").read_text())
    assert summary["fraction_ok"] >= 0.95 and summary["order_hops"] == 0


@pytest.mark.slow
def test_blocks_on_a_dask_cluster_give_the_same_map(tmp_path):
    """The blocks sent to a Dask cluster's workers (which open the file themselves) give
    the map the local run gives."""
    distributed = pytest.importorskip("distributed")
    lam, cube, t = synth_cube(16, 16, 64, dmin=300.0, dmax=3000.0, seed=13)
    np.save(tmp_path / "c.npy", cube)
    np.savetxt(tmp_path / "w.txt", lam)
    c = read_cube(tmp_path / "c.npy", wavelengths=tmp_path / "w.txt")
    opts = MapOptions(thickness_range=(0.0, 5000.0), block_pixels=64)
    local = fit_cube(c, options=opts)
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        remote = fit_cube(c, options=opts, scheduler=client.scheduler.address)
    np.testing.assert_allclose(remote.thickness_nm, local.thickness_nm, rtol=0, atol=1e-3)
    assert np.nanmedian(np.abs(local.thickness_nm - t)) <= 2.0


@pytest.mark.slow
def test_cli_line_scan_writes_its_profile(tmp_path, capsys):
    lam, cube, t = synth_cube(40, 1, 96, dmin=300.0, dmax=3000.0, seed=17)
    np.savez(tmp_path / "scan.npz", scan=cube[:, 0, :], wavelength_nm=lam)
    assert main(["fit-spectrum", str(tmp_path / "scan.npz"), "-o", str(tmp_path / "s"),
                 "--thickness-range", "0,6000"]) == 0
    assert "line scan 40x1x96" in capsys.readouterr().out
    rows = (tmp_path / "s_profile.csv").read_text().splitlines()
    assert rows[0] == "row,thickness_nm,thickness_nm_stderr,ok" and len(rows) == 41
    got = np.array([float(r.split(",")[1]) for r in rows[1:]])
    assert np.median(np.abs(got - t[:, 0])) <= 2.0
    assert (tmp_path / "s_profile.png").stat().st_size > 1000
