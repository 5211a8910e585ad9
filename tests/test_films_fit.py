"""Flat films and gaps fitted from photos the package did not make.

The photos come from ``experiments/validation/reference_films.py`` (numpy and
colour-science only: complex Airy sum with three media, water from Daimon & Masumura's
Sellmeier law, CIE 1931 observer, a cone average with 64 midpoint nodes, Poisson-Gaussian
noise and 8-bit sRGB), rendered by ``make_films.py`` into
``experiments/validation/data/film_*``. Tolerances are the targets of the validation
set: Newton's rings R within 1 %, the gap within 5 % up to 1.5 um with no order error;
a drainage map with median error <= 15 nm, >= 90 % of pixels within 15 nm, no order hops.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "experiments" / "validation" / "data"


def _fit(case: str, tmp_path, *extra):
    out = tmp_path / "out"
    js = tmp_path / "r.json"
    cmd = [sys.executable, "-m", "bubblefit", "fit", str(DATA / case / "photo.png"), "--scene",
           str(DATA / case / "scene.toml"), "-o", str(out), "--json", str(js), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1200, env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr
    return json.loads(js.read_text()), _exr(f"{out}_thickness.exr"), _exr(DATA / case / "thickness_true.exr")


def _exr(path) -> np.ndarray:
    """First channel of an EXR with its NaNs (off the film), read by OpenImageIO directly."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    data = np.asarray(inp.read_image(0, 0, 0, 1, oiio.FLOAT), np.float64)
    inp.close()
    return data.reshape(data.shape[0], data.shape[1], -1)[..., 0]


@pytest.mark.slow
def test_newton_rings(tmp_path):
    truth = json.loads((DATA / "film_newton_bk7_na010" / "truth.json").read_text())
    res, tmap, true = _fit("film_newton_bk7_na010", tmp_path)
    assert res["ok"] and res["kind"] == "newton"
    assert abs(res["params"]["radius_mm"] / truth["radius_mm"] - 1) < 0.01
    near = true <= 1500.0
    err = np.abs(tmap - true)[near]
    assert np.all(err <= np.maximum(0.05 * true[near], 5.0))  # 5 %, and 5 nm at the contact
    cx = truth["center_px"][0] * truth["pixel_um"]
    assert abs(res["params"]["center_x_um"] - cx) < truth["pixel_um"]


@pytest.mark.slow
def test_drainage_film_under_a_panel(tmp_path):
    # the top three rows of the film, 20 pixels wide: 126 nm (the rendered truth's mean there)
    res, tmap, true = _fit("film_drain_water_area", tmp_path, "--reference-region", "54,28,74,31=126")
    on = np.isfinite(true) & np.isfinite(tmap)
    assert on.sum() > 0.9 * np.isfinite(true).sum()
    err = np.abs(tmap - true)[on]
    assert np.median(err) <= 15.0 and np.mean(err <= 15.0) >= 0.9
    assert res["order_hops"] == 0 and res["ok"]


@pytest.mark.slow
@pytest.mark.parametrize("case", ["cyc_film_drain_panel", "cyc_film_drain_offaxis_panel"])
def test_cycles_draining_film_profile(tmp_path, case):
    """Blender Cycles' thin film (make_films_cycles.py): a framed vertical film under a panel,
    fitted as a drainage profile: the ends within 3 standard errors, the profile's map
    within the map targets."""
    truth = json.loads((DATA / case / "truth.json").read_text())
    res, tmap, true = _fit(case, tmp_path, "--thickness", "drainage")
    assert res["ok"] and res["kind"] == "drainage", res["warnings"]
    for end in ("top_nm", "bottom_nm"):
        assert abs(res["params"][end] - truth[end]) <= 3.0 * res["stderr"][end], (end, res["params"], res["stderr"])
    on = np.isfinite(true) & np.isfinite(tmap)
    assert on.sum() > 0.9 * np.isfinite(true).sum()
    err = np.abs(tmap - true)[on]
    assert np.median(err) <= 15.0 and np.mean(err <= 15.0) >= 0.9


@pytest.mark.slow
def test_cycles_draining_film_map_without_black_film(tmp_path):
    """The same film as a per-pixel map: no black film (30 nm at the top reflects a fifth of
    the brightest colour), so the order comes from the drainage profile."""
    res, tmap, true = _fit("cyc_film_drain_panel", tmp_path, "--thickness", "map")
    assert res["ok"] and res["order_hops"] == 0 and res["order_from"] == "drainage profile"
    on = np.isfinite(true) & np.isfinite(tmap)
    err = np.abs(tmap - true)[on]
    assert np.median(err) <= 15.0 and np.mean(err <= 15.0) >= 0.9


@pytest.mark.slow
def test_cycles_constant_film_with_a_clipped_channel(tmp_path):
    """480 nm of water in Cycles: red clipped at black; the third order (672 nm) has nearly the
    same hue, so the clipped channel must not decide the order."""
    res, _, _ = _fit("cyc_film_const_panel", tmp_path, "--thickness", "constant")
    assert res["ok"], res["warnings"]
    assert abs(res["params"]["thickness_nm"] - 480.0) <= 5.0


@pytest.mark.slow
def test_a_film_turned_sideways_is_not_a_drainage_profile():
    """The Cycles draining film turned by 90 degrees (gravity along the frame's width): no
    profile along the scene's up direction explains it, and the fit must say so."""
    from bubblefit.inverse.planar import fit_planar
    from bubblefit.io.images import read_image
    from bubblefit.model.planar_scene import load_planar

    photo = read_image(DATA / "cyc_film_drain_panel" / "photo.png", dtype=np.float64).pixels[..., :3]
    scene = load_planar(DATA / "cyc_film_drain_panel" / "scene.toml")
    res = fit_planar(np.rot90(photo).copy(), scene, kind="drainage", clip_high=1.0)
    assert not res.ok and res.reduced_chi2_floor > 4.0, res.report()


def _run(args, tmp_path):
    return subprocess.run([sys.executable, "-m", "bubblefit", *args], capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)


def _area_scene(tmp_path, target=(0.0, 0.0, 0.0), origin=(0.0, 0.0, 0.6), normal=(0.0, 0.0, 1.0)) -> Path:
    text = (DATA / "film_drain_water_area" / "scene.toml").read_text()
    text = text.replace("origin = [0.0, 0.0, 0.6]", f"origin = {list(origin)}")
    text = text.replace("target = [0.0, 0.0, 0.0]", f"target = {list(target)}")
    text = text.replace("normal = [0.0, 0.0, 1.0]", f"normal = {list(normal)}", 1)
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return p


@pytest.mark.slow
@pytest.mark.parametrize("what", ["edge_on", "region_outside", "dark_photo", "not_in_view"])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, what):
    photo = str(DATA / "film_drain_water_area" / "photo.png")
    extra = []
    if what == "edge_on":  # the film turned to face along +x: the camera on the z axis sees its edge
        scene = _area_scene(tmp_path, normal=(1.0, 0.0, 0.0))
    elif what == "not_in_view":  # the camera turned away from the film
        scene = _area_scene(tmp_path, target=(0.0, 0.0, 1.6))
    else:
        scene = _area_scene(tmp_path)
    if what == "region_outside":
        extra = ["--reference-region", "120,120,140,140=100"]
    if what == "dark_photo":
        import OpenImageIO as oiio

        dark = tmp_path / "dark.png"
        out = oiio.ImageOutput.create(str(dark))
        out.open(str(dark), oiio.ImageSpec(128, 128, 3, oiio.UINT8))
        out.write_image(np.zeros((128, 128, 3), np.uint8))
        out.close()
        photo = str(dark)
    proc = _run(["fit", photo, "--scene", str(scene), "-o", "res", "--json", "r.json", *extra], tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert not list(tmp_path.glob("res*")) and not (tmp_path / "r.json").exists()


@pytest.mark.slow
@pytest.mark.parametrize("d_true", [95.0, 430.0, 1210.0])
def test_constant_film_on_glass_under_coaxial_light(d_true):
    """A constant water film on BK7 (air | water | bk7), NA 0.25, 3200 K, rendered by the
    independent reference_films.py with noise and 8-bit sRGB, fitted within 5 nm, or
    reported ambiguous when its colour is a grey that another order also gives."""
    sys.path.insert(0, str(ROOT / "experiments" / "validation"))
    import reference_films as rf
    import vio

    from bubblefit.inverse.planar import fit_planar
    from bubblefit.io.images import srgb_decode
    from bubblefit.model.planar_scene import parse_planar

    rgb = rf.coaxial_rgb(np.full((24, 24), d_true), "3200K", ("air", "water", "bk7"), 0.25)
    exposure = 0.8 / rgb.max()
    codes = vio.add_noise_and_quantise(rgb * exposure, np.random.default_rng(int(d_true)))
    photo = srgb_decode(codes / 255.0)
    scene = parse_planar({"film": {"shape": "plane", "n": "water", "above": "air", "below": "bk7",
                                   "thickness": "constant", "range_nm": [0.0, 1600.0]},
                          "light": {"type": "coaxial", "na": 0.25, "lamp": "3200K"},
                          "camera": {"width": 24, "height": 24, "pixel_um": 2.0}})
    res = fit_planar(photo, scene, clip_high=1.0)
    if d_true < 150.0:
        # a near-neutral grey whose brightness the unknown exposure absorbs: another order
        # matches it as well, and the fit must say so rather than pick one
        assert not res.ok and any("another order" in w for w in res.warnings), res.warnings
        return
    assert res.ok, res.warnings
    assert abs(res.params["thickness_nm"] - d_true) < 5.0, res.params
    assert abs(res.gain / exposure - 1) < 0.03


@pytest.mark.slow
def test_flat_film_noise_and_map_errors_count_the_fitted_thickness():
    """A 40x40 colour photo of a constant 430 nm water film on BK7 (reference_films.py, NA
    0.25, 3200 K) with Gaussian noise of 0.01 per channel, fitted as a map: each pixel's
    own thickness takes one of its three readings' degrees of freedom, so the residuals
    alone read about 0.8 of the noise. The fit states the noise within 10 % (the median of
    1600 squared residuals, chi^2 of 2 degrees of freedom, has a relative standard error
    of 3 %, 1.5 % on sigma), a reduced chi^2 within 0.15 of 1 (its scatter 2.5 %, plus
    sigma's), and per-pixel standard errors that the map's errors fill: their RMS in
    standard errors within 0.12 of 1 (1600 draws: 2 %, plus sigma's)."""
    sys.path.insert(0, str(ROOT / "experiments" / "validation"))
    import reference_films as rf

    from bubblefit.inverse.planar import fit_planar
    from bubblefit.model.planar_scene import parse_planar

    d_true, sigma = 430.0, 0.01
    rgb = rf.coaxial_rgb(np.full((40, 40), d_true), "3200K", ("air", "water", "bk7"), 0.25)
    photo = 0.6 * rgb / rgb.max() + np.random.default_rng(1).normal(0.0, sigma, rgb.shape)
    scene = parse_planar({"film": {"shape": "plane", "n": "water", "above": "air", "below": "bk7",
                                   "thickness": "map", "range_nm": [0.0, 1600.0]},
                          "light": {"type": "coaxial", "na": 0.25, "lamp": "3200K"},
                          "camera": {"width": 40, "height": 40, "pixel_um": 2.0}})
    res = fit_planar(photo, scene, reference_region=(0, 0, 8, 8), reference_nm=d_true)
    assert res.sigma == pytest.approx(sigma, rel=0.10)
    assert abs(res.reduced_chi2 - 1.0) < 0.15
    z = (res.thickness_map - d_true) / res.thickness_stderr_map
    assert abs(float(np.sqrt(np.nanmean(z ** 2))) - 1.0) < 0.12
