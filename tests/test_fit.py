"""Synthetic recovery tests of :mod:`bubblefit.inverse.fit`.

Photos are rendered from a scene with known parameters in the shipped courtyard map
(downsampled to 64x128), with Gaussian noise and 8-bit sRGB quantisation, and fitted
back. Images are 48 px so that every fit shares one compiled solver. Paper-model photos
carry the film's transmission tint (``effects.transmission_tint``), as fits assume by
default; one case renders eq. (11) as written and fits it with the tint off.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

N = 48
DISC = (N / 2, N / 2, 0.42 * N)


def _env(px):
    from bubblefit.lighting.envmap import EnvMap

    return EnvMap.from_array(px)


def _quantise(img, rng, sigma=0.003):
    """Add read noise and shot noise, then store as 8-bit sRGB and decode back to linear."""
    from bubblefit.io.images import srgb_decode, srgb_encode

    noisy = img + rng.normal(0.0, 1.0, img.shape) * np.sqrt(sigma**2 + 1e-4 * np.clip(img, 0, None))
    return srgb_decode(np.round(srgb_encode(noisy) * 255) / 255)


def _background(rng):
    from scipy import ndimage as ndi

    bg = rng.uniform(0.15, 0.6, (N, N, 3))
    return ndi.gaussian_filter(bg, (2.5, 2.5, 0))


def _render(env, bg, bubble, model="paper", base_dir=".", tint=True):
    from bubblefit.model.scene import Scene, render_scene

    effects = {"model": model, **({"transmission_tint": tint} if model == "paper" else {})}
    scene = Scene.from_dict({"camera": {"width": N, "height": N, "disc": list(DISC)}, "bubble": bubble,
                             "lighting": {"envmap": "unused.exr"}, "effects": effects}, base_dir=base_dir)
    return render_scene(scene, bg, env=env)


@pytest.fixture(scope="module")
def env(small_courtyard):
    return _env(small_courtyard)


def _opts(**kw):
    from bubblefit.inverse.fit import FitOptions

    # 48 uniform spectral samples resolve films up to ~1500 nm (Nyquist) and keep the tests fast
    base = dict(disc=DISC, t_init=0.968, roughness_init=0.04,
                effects=(("spectral", {"method": "uniform", "samples": 48}),))
    base.update(kw)
    return FitOptions(**base)


@pytest.mark.parametrize("seed,thickness,tint", [(0, 150.0, True), (1, 720.0, False), (2, 1400.0, True)])
def test_constant_recovery(env, seed, thickness, tint):
    """t within 0.003, thickness within 5 nm, roughness within 15%, errors that cover."""
    from bubblefit.inverse.fit import fit_photo

    rng = np.random.default_rng(seed)
    truth = dict(t=0.972 + 0.004 * (seed - 1), roughness=0.08, f=0.3, thickness_nm=thickness)
    bg = _background(rng)
    photo = _quantise(_render(env, bg, truth, tint=tint), rng)
    bgq = _quantise(bg, rng)
    spectral = _opts().effects
    res = fit_photo(photo, env, options=_opts(effects=spectral + (("transmission_tint", tint),)), background=bgq)
    assert any(d.effect == "transmission_tint" and d.simulated == tint for d in res.effects)
    p, e = res.params, res.stderr
    assert res.converged, res.message
    assert abs(p["thickness_nm"] - thickness) < 5.0
    assert abs(p["t"] - truth["t"]) < 0.003
    assert abs(p["roughness"] / truth["roughness"] - 1) < 0.15
    # the standard errors are honest: the truth within 4 sigma for t and thickness
    assert abs(p["thickness_nm"] - thickness) < 4 * e["thickness_nm"] + 0.5
    assert abs(p["t"] - truth["t"]) < 4 * e["t"] + 2e-4
    names = [h[0] for h in res.held]
    assert "rotation_deg" in names and "thickness_nm" not in names
    js = res.to_json()
    for key in ("params", "stderr", "converged", "iterations", "residual_rms", "time_s"):
        assert key in js
    assert res.render.shape == photo.shape and res.residual.shape == photo.shape


def test_drainage_and_map(env, tmp_path):
    """A drainage profile plus a bump: the profile's parameters and the map (< 10 nm median)."""
    from bubblefit.inverse.fit import fit_photo
    from bubblefit.io.images import write_image
    from bubblefit.model.thickness import drainage_profile

    rng = np.random.default_rng(7)
    ii, jj = np.mgrid[0:N, 0:N] + 0.5
    y = -(ii - DISC[1]) / DISC[2]
    x = (jj - DISC[0]) / DISC[2]
    top, bottom, expo = 250.0, 1100.0, 1.4
    true = np.asarray(drainage_profile(y, top, bottom, expo)) + 40.0 * np.exp(-((x - 0.3) ** 2 + y**2) / 0.1)
    path = tmp_path / "truth.exr"
    write_image(path, np.repeat(true[..., None], 3, axis=2), bit_depth=32)
    # A film transmits the complement of what it reflects: over a background as bright as
    # the reflected sky the two colours cancel (a film in uniform light is colourless) and
    # single pixels lose their thickness (median 12.5 nm at full brightness, 5.3 nm here).
    bg = 0.5 * _background(rng)
    photo = _quantise(_render(env, bg, {"t": 0.97, "roughness": 0.08,
                                        "thickness": {"profile": "map", "path": str(path)}}), rng)
    res = fit_photo(photo, env, options=_opts(thickness="map"), background=_quantise(bg, rng))
    p = res.params
    assert res.converged, res.message
    # the profile the map starts from follows the truth's trend
    assert abs(p["top_nm"] - top) < 60 and abs(p["bottom_nm"] - bottom) < 60
    m = res.thickness_map
    used = np.isfinite(res.thickness_stderr_map)
    err = np.abs(m - true)[used]
    assert used.sum() > 0.5 * np.pi * DISC[2] ** 2
    assert np.median(err) < 10.0
    assert np.isnan(m[0, 0])  # outside the bubble


@pytest.mark.parametrize("rim", [0.75, 0.5])
def test_model_mismatch(env, rim):
    """Paper-model fit of a physical-model photo (Fresnel, Airy, bounces), cold start:
    thickness within 15 nm.

    The physical film tints the bright background behind it with the complement of its
    reflected colour; with the transmission tint (the fit's default) the paper model
    finds the right colour order from a global search. Negative control: eq. (11)'s grey
    t^4 makes the search settle in another order on the same photo.
    """
    from bubblefit.inverse.fit import fit_photo

    rng = np.random.default_rng(11)
    bg = _background(rng)
    photo = _quantise(_render(env, bg, {"roughness": 0.08, "thickness_nm": 560.0}, model="physical"), rng)
    bgq = _quantise(bg, rng)
    res = fit_photo(photo, env, options=_opts(rim=rim), background=bgq)
    assert res.converged, res.message
    assert abs(res.params["thickness_nm"] - 560.0) < 15.0
    if rim == 0.75:
        grey = fit_photo(photo, env, options=_opts(rim=rim, effects=_opts().effects + (("transmission_tint", False),)),
                         background=bgq)
        assert abs(grey.params["thickness_nm"] - 560.0) > 50.0


def test_failed_fit_is_reported_and_skipped_effects_held(env):
    """A fit stopped after 2 steps says it did not converge (and why); with the diffuse
    term off, the split is held and reported without an error bar."""
    from bubblefit.inverse.fit import fit_photo

    rng = np.random.default_rng(3)
    bg = _background(rng)
    photo = _quantise(_render(env, bg, {"roughness": 0.08, "thickness_nm": 900.0}), rng)
    res = fit_photo(photo, env, options=_opts(max_steps=2, search_steps=2, effects=(("diffuse", False),)),
                    background=bg)
    assert not res.converged
    assert "solver" in res.message
    assert res.to_json()["converged"] is False
    held = dict(res.held)
    assert "split" in held and "diffuse" in held["split"]
    assert res.to_json()["stderr"]["f"] is None
    assert any(d.effect == "diffuse" and not d.simulated for d in res.effects)


def test_cli_fit(env, small_courtyard, tmp_path, capsys):
    from bubblefit.cli import main
    from bubblefit.io.images import read_image, write_image

    rng = np.random.default_rng(5)
    bg = _background(rng)
    photo = _render(env, bg, {"t": 0.97, "roughness": 0.08, "thickness_nm": 420.0})
    write_image(tmp_path / "photo.png", photo)
    write_image(tmp_path / "before.png", bg)
    write_image(tmp_path / "env.exr", small_courtyard, bit_depth=32)
    (tmp_path / "cal.json").write_text(json.dumps({"t": 0.968, "bubble": {"cx": DISC[0], "cy": DISC[1], "r": DISC[2]}}))
    args = ["fit", str(tmp_path / "photo.png"), "--envmap", str(tmp_path / "env.exr"), "--background",
            str(tmp_path / "before.png"), "--calibration", str(tmp_path / "cal.json"),
            "--json", str(tmp_path / "out.json"), "-o", str(tmp_path / "fit")]
    assert main(args) == 0
    out = json.loads((tmp_path / "out.json").read_text())
    assert out["converged"] is True
    assert abs(out["params"]["thickness_nm"] - 420.0) < 5.0
    for key in ("t", "r_d", "r_s", "f", "roughness", "thickness_nm", "exposure"):
        assert key in out["params"] and key in out["stderr"]
    assert read_image(tmp_path / "fit_render.exr").pixels.shape == (N, N, 3)
    assert (tmp_path / "fit_residual.png").exists()
    capsys.readouterr()

    # bad inputs: one clear line, exit 2
    (tmp_path / "bad.json").write_text(json.dumps({"bubble": {}}))
    assert main(args[:6] + ["--calibration", str(tmp_path / "bad.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'t'" in err[0]
    write_image(tmp_path / "small.png", bg[:20, :20])
    bad = ["fit", str(tmp_path / "photo.png"), "--envmap", str(tmp_path / "env.exr"), "--background",
           str(tmp_path / "small.png"), "--t", "0.97"]
    assert main(bad) == 2
    assert "background" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "missing.png"), "--envmap", str(tmp_path / "env.exr")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
