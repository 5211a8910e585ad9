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
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions
    from bubblefit.inverse import starts

    # 48 uniform spectral samples resolve films up to ~1500 nm (Nyquist) and keep the tests fast
    base = dict(disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", view=ORTHOGRAPHIC,
                effects=(("spectral", {"method": "uniform", "samples": 48}),))
    base.update(kw)
    return FitOptions(**base)


@pytest.mark.slow
@pytest.mark.parametrize("seed,thickness,tint", [(0, 150.0, True), (1, 720.0, False), (2, 1400.0, True)])
def test_constant_recovery(env, seed, thickness, tint, monkeypatch):
    """t within 0.003, thickness within 5 nm, roughness within 15%, errors that cover; the
    solve's and the standard errors' programs compiled in the background are the ones run."""
    from bubblefit.inverse.fit import fit_photo
    from bubblefit.io import executables

    prepared, prepare = [], executables.Stored.prepare
    monkeypatch.setattr(executables.Stored, "prepare", lambda self, *a: (prepared.append(self), prepare(self, *a)))

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
    # the standard errors are honest: the truth within 4 sigma for the thickness, and within
    # 3 for t, whose error bar carries the background photo's noise (errors in variables)
    assert abs(p["thickness_nm"] - thickness) < 4 * e["thickness_nm"] + 0.5
    assert abs(p["t"] - truth["t"]) < 3 * e["t"]
    names = [h[0] for h in res.held]
    assert "rotation_deg" in names and "thickness_nm" not in names
    js = res.to_json()
    for key in ("params", "stderr", "converged", "iterations", "residual_rms", "time_s", "ok", "warnings",
                "reduced_chi2", "disc", "covariance"):
        assert key in js
    # a photo of the model itself, within its noise: ok, and the covariance's diagonal is the errors
    assert js["ok"] is True and js["warnings"] == [], js["warnings"]
    assert js["reduced_chi2"] < 2.0
    assert js["disc"] == {"cx": DISC[0], "cy": DISC[1], "r": DISC[2]}
    cov = js["covariance"]
    assert "thickness_nm" in cov["names"] and "rotation_deg" not in cov["names"]
    i = cov["names"].index("thickness_nm")
    assert np.sqrt(cov["matrix"][i][i]) == pytest.approx(e["thickness_nm"], rel=1e-6)
    # the renderers' scatter (Type B) is on top of the photo's own error, in quadrature
    assert js["thickness_model_error_nm"] == pytest.approx(0.6) and e["thickness_nm"] > 0.6
    assert res.render.shape == photo.shape and res.residual.shape == photo.shape
    # a prepared program called with arguments of other shapes would be left waiting, unused
    ours = [s for s in prepared if s.name.startswith("inverse._programs")]
    assert {s.name for s in ours} == {"inverse._programs.solver", "inverse._programs.reporter",
                                      "inverse._programs.reporter_jacobian"}
    assert all(not s.pending for s in ours)


@pytest.fixture(scope="module")
def map_fit(env, tmp_path_factory):
    """A drainage profile plus a 40 nm bump (paper model), fitted with ``--thickness map``."""
    from bubblefit.inverse.fit import fit_photo
    from bubblefit.io.images import write_image
    from bubblefit.model.thickness import drainage_profile

    rng = np.random.default_rng(7)
    ii, jj = np.mgrid[0:N, 0:N] + 0.5
    y = -(ii - DISC[1]) / DISC[2]
    x = (jj - DISC[0]) / DISC[2]
    top, bottom, expo = 250.0, 1100.0, 1.4
    true = np.asarray(drainage_profile(y, top, bottom, expo)) + 40.0 * np.exp(-((x - 0.3) ** 2 + y**2) / 0.1)
    path = tmp_path_factory.mktemp("map") / "truth.exr"
    write_image(path, np.repeat(true[..., None], 3, axis=2), bit_depth=32)
    # A film transmits the complement of what it reflects: over a background as bright as
    # the reflected sky the two colours cancel (a film in uniform light is colourless) and
    # single pixels lose their thickness (median 12.5 nm at full brightness, 5.3 nm here).
    bg = 0.5 * _background(rng)
    photo = _quantise(_render(env, bg, {"t": 0.97, "roughness": 0.08,
                                        "thickness": {"profile": "map", "path": str(path)}}), rng)
    res = fit_photo(photo, env, options=_opts(thickness="map"), background=_quantise(bg, rng))
    return res, true, y, (top, bottom, expo)


@pytest.mark.slow
def test_drainage_and_map(map_fit):
    """The profile's parameters and the map (< 10 nm median), with per-pixel errors."""
    res, true, _, (top, bottom, _) = map_fit
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
    assert np.all(res.thickness_stderr_map[used] > 0)


@pytest.mark.slow
@pytest.mark.xfail(reason="not met on this 48 px photo: 89.6% of pixels within 15 nm (not 90%), and the 40 nm "
                          "bump recovered as 21 nm over the fitted profile (no order hop: neighbours differ by 32 nm "
                          "at most)",
                   strict=True)
def test_map_meets_order_targets(map_fit):
    """The targets for thickness maps: >= 90% of pixels within 15 nm, no order hops, the 40 nm bump kept."""
    from bubblefit.model.thickness import drainage_profile

    res, true, y, _ = map_fit
    p = res.params
    m = res.thickness_map
    used = np.isfinite(res.thickness_stderr_map)
    err = np.abs(m - true)[used]
    within = float(np.mean(err < 15.0))
    # no order hops: neighbours never differ by a colour order (~200 nm) where the truth is smooth
    hop = 0.0
    for ax in (0, 1):
        jump = np.abs(np.diff(m, axis=ax))
        both = np.take(used, range(used.shape[ax] - 1), axis=ax) & np.take(used, range(1, used.shape[ax]), axis=ax)
        hop = max(hop, float(np.nanmax(np.where(both, jump, 0.0))))
    jc, ic = int(DISC[0] + 0.3 * DISC[2]), int(DISC[1])
    prof = np.asarray(drainage_profile(y, p["top_nm"], p["bottom_nm"], p["exponent"]))
    bump = float((m - prof)[ic - 1:ic + 2, jc - 1:jc + 2].mean())
    # all three measured before the verdict, so that a failure states each
    assert within > 0.9 and hop < 100.0 and abs(bump - 40.0) < 15.0, dict(within_15nm=within, hop_nm=hop,
                                                                           bump_nm=bump)


@pytest.mark.slow
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


@pytest.mark.slow
def test_failed_fit_is_reported_and_skipped_effects_held(env):
    """A fit stopped after 2 steps says it did not converge (and why); with the diffuse
    term off, the split is held and reported without an error bar."""
    from bubblefit.inverse.fit import SolverSettings, fit_photo

    rng = np.random.default_rng(3)
    bg = _background(rng)
    photo = _quantise(_render(env, bg, {"roughness": 0.08, "thickness_nm": 900.0}), rng)
    res = fit_photo(photo, env, options=_opts(solver=SolverSettings(max_steps=2, search_steps=2),
                                              effects=(("diffuse", False),)),
                    background=bg)
    assert not res.converged
    assert "solver" in res.message
    assert res.to_json()["converged"] is False
    assert res.status == "max_steps" and res.to_json()["ok"] is False
    assert any("did not converge" in w for w in res.warnings)
    # a parameter that was fitted is never reported as held
    report = res.report()
    for line in report.splitlines():
        if line.startswith(("t ", "thickness_nm", "exposure")):
            assert "held" not in line, line
    held = dict(res.held)
    assert "split" in held and "diffuse" in held["split"]
    assert res.to_json()["stderr"]["f"] is None
    assert any(d.effect == "diffuse" and not d.simulated for d in res.effects)


@pytest.mark.slow
def test_cli_fit(env, small_courtyard, tmp_path, capsys):
    from bubblefit.cli import main
    from bubblefit.io.images import read_image, write_image

    rng = np.random.default_rng(5)
    bg = _background(rng)
    photo = _render(env, bg, {"t": 0.97, "roughness": 0.08, "thickness_nm": 420.0})
    write_image(tmp_path / "photo.png", photo)
    write_image(tmp_path / "before.png", bg)
    write_image(tmp_path / "env.exr", small_courtyard, bit_depth=32)
    (tmp_path / "cal.json").write_text(json.dumps({"t": 0.968, "bubble": {"cx": DISC[0], "cy": DISC[1], "r": DISC[2]},
                                                   "image_size": [N, N]}))
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
    # the calibration's disc, checked against the photo, then refined: the photo's own
    d = out["disc"]
    assert np.allclose([d["cx"], d["cy"], d["r"]], DISC, atol=0.1), d
    assert all(out["disc_stderr"][k] > 0 for k in ("cx", "cy", "r"))
    summary = [line for line in capsys.readouterr().out.splitlines() if "reduced chi^2" in line]
    shown = "disc ({:.2f}, {:.2f}, r {:.2f}, refined)".format(d["cx"], d["cy"], d["r"])
    assert len(summary) == 1 and summary[0].startswith("ok ") and shown in summary[0]
    assert out["ok"] == summary[0].startswith("ok yes")

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


@pytest.mark.slow
def test_wrong_map_is_not_ok(env, small_courtyard):
    """The right photo fitted with another environment (the map turned by 90 degrees):
    the fit may converge, but it is not ok, and a warning says the model does not explain
    the photo."""
    from bubblefit.inverse.fit import fit_photo

    rng = np.random.default_rng(13)
    bg = _background(rng)
    photo = _quantise(_render(env, bg, {"t": 0.97, "roughness": 0.08, "thickness_nm": 480.0}), rng)
    wrong = _env(np.roll(small_courtyard, small_courtyard.shape[1] // 4, axis=1))
    res = fit_photo(photo, wrong, options=_opts(), background=_quantise(bg, rng))
    js = res.to_json()
    assert js["ok"] is False
    assert js["reduced_chi2_floor"] > 3.0
    assert any("does not explain" in w for w in js["warnings"]), js["warnings"]


def test_no_bubble_is_refused(env, small_courtyard, tmp_path, capsys):
    """The background photo passed as the photo (another exposure of the same view): no
    bubble, one clear line, non-zero exit; no fit is attempted."""
    from bubblefit.cli import main
    from bubblefit.errors import InputError
    from bubblefit.inverse.fit import fit_photo
    from bubblefit.io.images import write_image

    rng = np.random.default_rng(17)
    bg = _background(rng)
    photo, before = _quantise(bg, rng), _quantise(bg, rng)
    with pytest.raises(InputError, match="no bubble"):
        fit_photo(photo, env, options=_opts(disc=None), background=before)
    write_image(tmp_path / "photo.png", photo)
    write_image(tmp_path / "before.png", before)
    write_image(tmp_path / "env.exr", small_courtyard, bit_depth=32)
    code = main(["fit", str(tmp_path / "photo.png"), "--envmap", str(tmp_path / "env.exr"), "--background",
                 str(tmp_path / "before.png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "no bubble" in err[0]


def test_calibration_disc_is_checked_against_the_photo():
    """A calibration's disc is used only for a photo of its frame's size whose bubble it
    matches; otherwise the disc found in the photo is used, with a warning."""
    from bubblefit.inverse import resolve_disc
    from bubblefit.model.scene import Scene, render_scene

    rng = np.random.default_rng(19)
    bg = _background(rng)
    scene = Scene.from_dict({"camera": {"width": N, "height": N, "disc": list(DISC)},
                             "bubble": {"t": 0.97, "thickness_nm": 400.0}, "lighting": {"background": "black"},
                             "effects": {"model": "paper"}})
    photo = _quantise(np.asarray(render_scene(scene, background=bg)), rng)
    before = _quantise(bg, rng)
    near = (DISC[0] + 0.5, DISC[1] - 0.5, DISC[2] + 0.3)
    disc, warn = resolve_disc(photo, before, _opts(disc=None, calibration_disc=near, calibration_size=(N, N)))
    assert disc == near and warn == []
    for cal, size, why in [((200.0, 150.0, 80.0), (512, 384), "frame"), ((10.0, 12.0, 6.0), (N, N), "disagrees"),
                           ((10.0, 12.0, 6.0), None, "disagrees")]:
        disc, warn = resolve_disc(photo, before, _opts(disc=None, calibration_disc=cal, calibration_size=size))
        assert np.hypot(disc[0] - DISC[0], disc[1] - DISC[1]) < 1.5 and abs(disc[2] - DISC[2]) < 1.5, disc
        assert len(warn) == 1 and why in warn[0]


def test_a_guessed_disc_never_replaces_the_calibrations(monkeypatch):
    """Where the detector does not find the rim, the simpler detector's guess (a disc with
    a note) neither replaces the calibration's disc nor is fitted on another frame."""
    from bubblefit.capture.disc import Disc
    from bubblefit.errors import InputError
    from bubblefit.inverse import _observation, resolve_disc

    guess = Disc(10.0, 12.0, 6.0, True, reason="the bubble's rim is not clear; the disc comes from the simpler detector")
    monkeypatch.setattr(_observation, "_detect", lambda *a: guess)
    photo = np.full((N, N, 3), 0.3)
    disc, warn = resolve_disc(photo, None, _opts(disc=None, calibration_disc=DISC, calibration_size=(N, N)))
    assert disc == DISC and len(warn) == 1 and "could not be checked" in warn[0]
    with pytest.raises(InputError, match="--disc"):
        resolve_disc(photo, None, _opts(disc=None, calibration_disc=DISC, calibration_size=(2 * N, N)))


def test_large_photo_is_cropped_to_the_bubble():
    """A photo larger than ``ImageSizes.analysis`` is analysed as a crop around the bubble,
    block-averaged to at most that size, with the disc mapped back to the photo's pixels."""
    from bubblefit.inverse import ImageSizes, analysis_frame

    H, W = 1200, 1800
    photo = np.full((H, W, 3), 0.3)
    sat = np.zeros((H, W), bool)
    disc = (1100.5, 500.25, 300.0)
    fr = analysis_frame(photo, photo, sat, disc, _opts(sizes=ImageSizes(analysis=256)))
    assert max(fr.photo.shape[:2]) <= 256 and fr.k == 3
    assert fr.sigma.shape == fr.photo.shape and fr.background.shape == fr.photo.shape
    assert fr.to_photo(fr.disc) == pytest.approx(disc)
    small = analysis_frame(photo[:200, :200], None, sat[:200, :200], (100, 100, 50),
                           _opts(sizes=ImageSizes(analysis=256)))
    assert small.whole and small.photo.shape == (200, 200, 3)


def test_cli_thickness_range_must_be_finite(tmp_path, capsys):
    from bubblefit.cli import main
    from bubblefit.io.images import write_image

    write_image(tmp_path / "photo.png", np.full((N, N, 3), 0.3))
    write_image(tmp_path / "env.exr", np.full((8, 16, 3), 0.5, np.float32), bit_depth=32)
    code = main(["fit", str(tmp_path / "photo.png"), "--envmap", str(tmp_path / "env.exr"), "--disc", "24,24,20",
                 "--thickness-range", "0,inf"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "thickness-range" in err[0]


@pytest.mark.slow
def test_padded_level_renders_the_level_and_serves_every_framing(env):
    """A level's padded program (canonical camera, disc passed as data) renders the
    level's own image, with and without a disc refinement, and a photo framed otherwise
    reuses the compiled solves: the next photo compiles nothing new."""
    import jax.numpy as jnp

    from dataclasses import replace

    from bubblefit.inverse import column_jacobian, solver
    from bubblefit.inverse import Level, fitted_pixels, padded, padded_size, pixel_bucket, solve_pixels
    from bubblefit.inverse._programs import SOLVE_BUCKETS_PER_OCTAVE
    from bubblefit.inverse import render_level
    from bubblefit.model.geometry import compose_shift
    from bubblefit.inverse.fit import fit_photo
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.lighting.filtering import FilterConfig
    from bubblefit.model.effects import Effects
    from bubblefit.model.render import Params, RenderConfig, render, render_pixels
    from bubblefit.optics.spectral import spectral_basis

    assert [padded_size(n) for n in (45, 48, 80, 90, 255, 320, 1000)] == [48, 48, 80, 96, 256, 320, 1024]
    fx = Effects(model="paper", interference="airy", filtering=FilterConfig("mipmap", nodes=2),
                 spectral=spectral_basis("uniform", 16))
    rng = np.random.default_rng(3)
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(45, 37, 20.3, 17.9, 15.2))
    bg = rng.uniform(0.1, 0.5, (37, 45, 3)).astype(np.float32)
    lev = Level(1, cfg, np.zeros((37, 45, 3), np.float32), np.ones((37, 45, 3), np.float32), bg,
                np.ones((37, 45), bool), np.ones((37, 45), bool), np.ones((37, 45)), np.zeros((37, 45)))
    pad = padded(lev)
    assert pad.cfg.shape == (48, 48) and pad.y.shape == (48, 48, 3)
    assert float(jnp.sum(pad.w[37:])) == 0.0 and float(jnp.sum(pad.w[:, 45:])) == 0.0
    for shift in ((0.0, 0.0, 0.0), (0.03, -0.02, 0.05)):
        p = Params.make(thickness=640.0, roughness=0.05, disc=shift)
        want = np.asarray(render(p, cfg, env, jnp.asarray(bg)))
        got = render_level(p, lev, env)
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, atol=2e-5)

    # the final render of the bubble's pixels alone, the background photo elsewhere: the
    # whole render's values, with the disc at the refinement's limits too
    from bubblefit.inverse import bubble_list as _bubble_list, render_bubble

    photo_fx = replace(fx, background="photo")
    lev_p = replace(lev, cfg=replace(cfg, effects=photo_fx))
    for shift in ((0.0, 0.0, 0.0), (0.1, -0.1, 0.1), (-0.1, 0.1, -0.1)):
        p = Params.make(thickness=640.0, roughness=0.05, disc=shift)
        want = np.asarray(render(p, replace(cfg, effects=photo_fx), env, jnp.asarray(bg)))
        got = render_bubble(p, lev_p, env)
        np.testing.assert_allclose(got, want, atol=2e-5)
        listed = _bubble_list(p, lev_p)[1].flat.size
        assert np.count_nonzero(np.any(want != bg, axis=-1)) <= listed < want.shape[0] * want.shape[1]

    # the solver's pixel list: the fitted pixels alone, scattered back to the level's residual
    mask = np.zeros((37, 45), bool)
    mask[5:30, 8:40] = rng.uniform(size=(25, 32)) < 0.7
    lev.mask = mask
    lev.w = np.repeat(mask[..., None], 3, axis=-1).astype(np.float32)
    px = fitted_pixels(lev, 256)
    n = pixel_bucket(int(mask.sum()), SOLVE_BUCKETS_PER_OCTAVE)  # in equal chunks of at most 256
    assert px.rows.shape[1] <= 256 and n <= px.rows.size < n + px.rows.shape[0]
    for n in (1, 64, 65, 700, 1024, 1025, 1554, 2104, 5000, 28851):
        assert max(n, 64) <= pixel_bucket(n) <= max(1.25 * n, 64)  # the padding costs at most a quarter
        fine = pixel_bucket(n, SOLVE_BUCKETS_PER_OCTAVE)  # a solve's list: at most 1 / per_octave
        assert max(n, 64) <= fine <= max((1 + 1 / SOLVE_BUCKETS_PER_OCTAVE) * n, 64)
    assert len({pixel_bucket(n) for n in range(1025, 2049)}) == 4  # four lengths per octave
    assert len({pixel_bucket(n, SOLVE_BUCKETS_PER_OCTAVE) for n in range(1025, 2049)}) == SOLVE_BUCKETS_PER_OCTAVE
    # docs/speed.md's 320x320 photo: its fit level's 1554 pixels, its final render's 28,851
    assert [pixel_bucket(n, SOLVE_BUCKETS_PER_OCTAVE) for n in (1554, 28851)] == [1664, 30720]
    p = Params.make(thickness=640.0, roughness=0.05, disc=(0.03, -0.02, 0.05))
    vals = render_pixels(replace(p, disc=compose_shift(px.padded.base, np.asarray(p.disc))), px.padded.cfg, env,
                         px.padded.bg, px.rows, px.cols, px.idx)
    full = px.scatter(lev, np.asarray(vals * px.w).reshape(-1)).reshape(37, 45, 3)
    want = np.asarray(render(p, cfg, env, jnp.asarray(bg))) * lev.w
    np.testing.assert_allclose(full, want, atol=2e-5)

    # the solver's Jacobian, by groups of columns, is jax.jacfwd's
    import jax

    from bubblefit.inverse import ParameterTable

    table = ParameterTable(free=("t", "split", "roughness", "exposure", "thickness_nm", "disc_x", "disc_y", "disc_r"))
    start = {"t": 0.9, "split": 0.7, "roughness": 0.05, "exposure": 1.1, "thickness_nm": 640.0, "disc_x": 0.01,
             "disc_y": -0.02, "disc_r": 0.03}
    lev.y = np.asarray(render_level(Params.make(thickness=655.0, roughness=0.04), lev, env), np.float32)
    # the solve's rays: the rim's blocks with 2 x 2 (Gauss) rays each, the others with one, in one list
    lev.inside = np.hypot(np.arange(45) + 0.5 - 20.3, (np.arange(37) + 0.5 - 17.9)[:, None]) < 15.2
    px = solve_pixels(lev, 256)
    assert px.samples == 4 and px.flat.size < px.rays[0].size < 4 * px.flat.size
    _, resid = solver(px.padded.cfg, table, 3.0, 20, 1e-5, 1e-6, rim=(px.samples, "gauss"))
    z = table.unconstrained(start)
    fixed = {"n_film": jnp.float32(1.33), "rotation_deg": jnp.float32(0.0)}
    # with the background photo's noise (0.01, a 8-bit photo's order) widening the weights
    # through the model's transmission: its Jacobian too is jax.jacfwd's
    bg_sigma = 0.01 * jnp.ones_like(px.padded.bg)
    args = (fixed, env, px.padded.bg, bg_sigma, px.y, px.w, px.padded.base, px.rays)
    want = np.asarray(jax.jacfwd(resid)(z, args))
    assert table.jacobian_groups == ((0, 1, 3), (2,), (4,), (5, 6, 7))  # weights, light, film, disc
    got = np.asarray(jax.jit(lambda z, a: column_jacobian(resid, table.jacobian_groups, z, a))(z, args))
    assert got.shape == want.shape == (np.asarray(resid(z, args)).size, len(table.free))
    assert np.all(np.abs(want).max(axis=0) > 0)  # every parameter moves the render
    np.testing.assert_allclose(got, want, atol=1e-4 * np.abs(want).max())

    # the same bubble framed otherwise (disc moved, radius changed): no new solve compiled
    rng = np.random.default_rng(7)
    bgp = _background(rng)
    truth = dict(t=0.972, roughness=0.08, f=0.3, thickness_nm=500.0)
    from bubblefit.model.scene import Scene, render_scene

    def photo(disc):
        scene = Scene.from_dict({"camera": {"width": N, "height": N, "disc": list(disc)}, "bubble": truth,
                                 "lighting": {"envmap": "unused.exr"}, "effects": {"transmission_tint": True}})
        return _quantise(render_scene(scene, bgp, env=env), rng)

    first = fit_photo(photo(DISC), env, options=_opts(), background=bgp)
    misses = solver.cache_info().misses
    moved = (DISC[0] + 1.3, DISC[1] - 0.7, 0.93 * DISC[2])
    second = fit_photo(photo(moved), env, options=_opts(disc=moved), background=bgp)
    assert solver.cache_info().misses == misses
    for res in (first, second):
        assert res.ok and abs(res.params["thickness_nm"] - 500.0) < 5.0
