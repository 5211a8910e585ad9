"""The fit's forward model under a scene's (or the command line's) light, camera and film.

``bubblefit fit`` evaluates the model with the illuminant, camera response, white balance,
dispersion law and rays per pixel of the scene or of its flags (command line first), in
every stage: the global search's candidates, the local solves, the map and the final
render (:func:`bubblefit.inverse._setup.setup`, :func:`~bubblefit.inverse._setup.colour_settings`).
Photos are 48 px renders with noise and 8-bit sRGB quantisation, as in tests/test_fit.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

N = 48
DISC = (N / 2, N / 2, 0.42 * N)
CAMERA = "Nikon 5100 (NPL)"  # measured raw sensitivities shipped with colour-science
SOAP = [1.324188, 3102.06]  # a soap film's Cauchy law (bubblefit.optics.dispersion.PRESETS)


def _env(px):
    from bubblefit.lighting.envmap import EnvMap

    return EnvMap.from_array(px)


@pytest.fixture(scope="module")
def env(small_courtyard):
    return _env(small_courtyard)


def _quantise(img, rng, sigma=0.003):
    """Read and shot noise, then 8-bit sRGB and back to linear."""
    from bubblefit.io.images import srgb_decode, srgb_encode

    noisy = img + rng.normal(0.0, 1.0, img.shape) * np.sqrt(sigma**2 + 1e-4 * np.clip(img, 0, None))
    return srgb_decode(np.round(srgb_encode(noisy) * 255) / 255)


def _camera_scene(**bubble):
    """A scene under illuminant E seen by a measured camera, with a dispersive soap film."""
    from bubblefit.model.scene import Scene

    return Scene.from_dict({
        "camera": {"width": N, "height": N, "disc": list(DISC), "response": CAMERA},
        "bubble": {"n_film": {"cauchy": SOAP}, **bubble},
        "lighting": {"envmap": "unused.exr", "illuminant": "E"},
        "effects": {"model": "paper", "transmission_tint": True, "spectral": {"method": "uniform", "samples": 48}},
    })


@pytest.mark.slow
def test_fit_uses_the_scenes_camera_light_and_dispersion(env):
    """Matched: thickness within 5 nm. The same photo fitted as D65/sRGB with a constant index
    (the law's value at 589.3 nm) lands further away, with a worse chi^2."""
    from scipy import ndimage as ndi

    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts
    from bubblefit.model.scene import render_scene
    from bubblefit.optics.dispersion import Cauchy, refractive_index

    truth = 600.0
    rng = np.random.default_rng(11)
    bg = ndi.gaussian_filter(rng.uniform(0.15, 0.6, (N, N, 3)), (2.5, 2.5, 0))
    photo = _quantise(render_scene(_camera_scene(t=0.972, roughness=0.08, f=0.3, thickness_nm=truth), bg, env=env),
                      rng)
    bgq = _quantise(bg, rng)
    base = dict(disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", view=ORTHOGRAPHIC)  # the fit's default spectral quadrature
    matched = fit_photo(photo, env, options=FitOptions(**base), background=bgq, scene=_camera_scene())
    n_d = float(refractive_index(Cauchy(tuple(SOAP)), 589.3))
    plain = fit_photo(photo, env, options=FitOptions(**base, n_film=n_d), background=bgq)
    err_m = abs(matched.params["thickness_nm"] - truth)
    err_p = abs(plain.params["thickness_nm"] - truth)
    assert matched.converged and err_m < 5.0, (matched.params, matched.message)
    assert err_p > err_m and plain.reduced_chi2 > matched.reduced_chi2, (plain.params, plain.reduced_chi2)
    assert matched.params["n_film"] == pytest.approx(n_d, abs=1e-6)
    col = matched.to_json()["colour"]
    assert col == {"illuminant": "E", "response": CAMERA, "white_balance": "illuminant",
                   "n_film": "soap", "dispersive": True, "samples_per_pixel": 1, "film_rgb": "spectral"}
    assert plain.to_json()["colour"]["illuminant"] == "D65" and not plain.to_json()["colour"]["dispersive"]


def _setup(env, scene=None, **kw):
    from bubblefit.inverse.fit import FitOptions
    from bubblefit.inverse import starts
    from bubblefit.inverse import setup

    rng = np.random.default_rng(0)
    background = rng.uniform(0.2, 0.5, (N, N, 3))
    # a pair the fit accepts: the same view off the bubble, and on it the background seen
    # through the films (t^2 ~ 0.9) plus a reflection
    yy, xx = np.mgrid[0:N, 0:N]
    on = (xx - DISC[0]) ** 2 + (yy - DISC[1]) ** 2 <= DISC[2] ** 2
    photo = np.where(on[..., None], 0.9 * background + rng.uniform(0.02, 0.08, (N, N, 3)), background)
    opts = FitOptions(**{"model": "paper", **kw}, disc=DISC, parameters=starts(t=0.968, roughness=0.04))
    return setup(photo, env, opts, background, None, scene, None), opts


def test_settings_reach_every_render_config(env):
    """samples_per_pixel, the dispersion law and the coloured basis are in the configurations
    every stage renders with; the options (command line) win over the scene."""
    from bubblefit.inverse import search
    from bubblefit.optics.dispersion import Cauchy

    st, opts = _setup(env, samples_per_pixel=4)
    for cfg in (st.base_cfg, st.map_cfg, st.lev_fit.cfg, st.level(st.k_search, opts).cfg, st.level(1, opts).cfg):
        assert cfg.samples_per_pixel == 4
    assert not search.exact_paper_search(st.base_cfg)  # box-filtered pixels render their candidates
    st, opts = _setup(env, _camera_scene())
    assert st.base_cfg.dispersion == Cauchy(tuple(SOAP)) and st.map_cfg.dispersion == st.base_cfg.dispersion
    b = st.lev_fit.cfg.effects.spectral
    assert (b.illuminant, b.response, b.white_balance) == ("E", CAMERA, "illuminant")
    assert search.exact_paper_search(st.base_cfg)
    scene = _camera_scene()
    scene.data["camera"].update(samples_per_pixel=9, white_balance=[1.5, 1.0, 2.0])
    st, _ = _setup(env, scene, illuminant="A", camera_response="srgb", n_film=1.36)
    b = st.base_cfg.effects.spectral
    assert (b.illuminant, b.response, b.white_balance) == ("A", "srgb", (1.5, 1.0, 2.0))
    assert st.base_cfg.samples_per_pixel == 9 and st.base_cfg.dispersion is None
    assert st.vals["n_film"] == pytest.approx(1.36)
    assert st.base_cfg.film_rgb == "spectral" and not any("film_rgb" in w for w in st.warnings)
    # the film coloured as Cycles colours it: the scene's [film] film_rgb, or the option
    st, opts = _setup(env, film_rgb="clamped", model="physical")
    for cfg in (st.base_cfg, st.map_cfg, st.lev_fit.cfg, st.level(st.k_search, opts).cfg):
        assert cfg.film_rgb == "clamped"
    assert st.colour.to_json()["film_rgb"] == "clamped" and not any("film_rgb" in w for w in st.warnings)
    scene.data["film"] = {"film_rgb": "clamped"}   # the scene's, under the paper model, which ignores it
    st, _ = _setup(env, scene)
    assert st.base_cfg.film_rgb == "clamped" and any("film_rgb clamped is ignored" in w for w in st.warnings)


def test_fast_candidates_equal_rendered_ones_with_colour_and_dispersion(env):
    """The paper model's tabulated candidates (index per wavelength for a dispersive film,
    weights of the camera under E) equal candidates rendered by the forward model."""
    from bubblefit.inverse import search

    st, opts = _setup(env, _camera_scene(), effects=(("transmission_tint", False),))
    lev = st.level(st.k_search, opts)
    grid = search.thickness_grid(100.0, 2000.0, 50.0)
    fast, fast_back = search._candidates_paper(lev, st.table, st.vals, grid, env)
    slow, slow_back = search._candidates_generic(lev, st.table, st.vals, grid, env)
    scale = float(np.abs(np.asarray(slow)).max())
    assert np.abs(np.asarray(fast) - np.asarray(slow)).max() < 2e-4 * scale
    assert np.abs(np.asarray(fast_back) - np.asarray(slow_back)).max() < 2e-4 * scale
    # not vacuous: without the law's dispersion the candidates differ
    plain = replace(lev, cfg=replace(lev.cfg, dispersion=None))
    other, _ = search._candidates_paper(plain, st.table, st.vals, grid, env)
    assert np.abs(np.asarray(other) - np.asarray(slow)).max() > 20 * np.abs(np.asarray(fast) - np.asarray(slow)).max()


# --------------------------------------------------------------------------------------
# the command line
# --------------------------------------------------------------------------------------
FLAGS = ["--illuminant", "E", "--camera-response", CAMERA, "--cauchy", "1.324188,3102.06", "--samples-per-pixel", "4",
         "--film-rgb", "clamped"]


def test_cli_flags_parse_and_win_over_the_scene(env, tmp_path, monkeypatch):
    import bubblefit.inverse.fit as fit_module
    from bubblefit.cli import build_parser, main
    from bubblefit.cli.fit import fit_option_values
    from bubblefit.inverse import colour_settings
    from bubblefit.io.images import write_image
    from bubblefit.optics.dispersion import Cauchy

    args = build_parser().parse_args(["fit", "p.png", "--envmap", "e.exr", *FLAGS])
    kw = fit_option_values(args)
    assert (kw["illuminant"], kw["camera_response"], kw["samples_per_pixel"], kw["film_rgb"]) == ("E", CAMERA, 4,
                                                                                                   "clamped")
    assert kw["n_film"] == Cauchy(tuple(SOAP))
    args = build_parser().parse_args(["fit-sequence", "p.png", "--envmap", "e.exr", "-o", "out", "--n-film", "water",
                                      "--film-rgb", "clamped"])
    assert fit_option_values(args)["n_film"].coefficients[0] == pytest.approx(1.31984)
    assert fit_option_values(args)["film_rgb"] == "clamped"
    # through `bubblefit fit`: the flags reach fit_photo and override the scene
    photo, envfile, scene = tmp_path / "p.exr", tmp_path / "e.exr", tmp_path / "s.toml"
    write_image(photo, np.full((N, N, 3), 0.3))
    write_image(envfile, np.full((8, 16, 3), 0.5))
    scene.write_text('[camera]\nwidth = 48\nheight = 48\nresponse = "srgb"\nsamples_per_pixel = 9\n'
                     '[lighting]\nilluminant = "A"\n[bubble]\nn_film = 1.33\n[film]\nfilm_rgb = "spectral"\n')
    seen = {}

    class Stop(Exception):
        pass

    def fake_fit(photo, env, *, options, scene=None, **_):
        seen.update(colour=colour_settings(scene, options, 1.33))
        raise Stop

    monkeypatch.setattr(fit_module, "fit_photo", fake_fit)
    main(["fit", str(photo), "--envmap", str(envfile), "--scene", str(scene), *FLAGS])  # stops in fake_fit
    c = seen["colour"]
    assert (c.illuminant, c.response, c.samples_per_pixel, c.n_film) == ("E", CAMERA, 4, Cauchy(tuple(SOAP)))
    assert c.film_rgb == "clamped"


def test_render_film_rgb_option_reaches_the_scene(tmp_path, monkeypatch):
    """``render --film-rgb`` sets the scene's [film] film_rgb, which every part of the
    scene's plan renders with; a bad value in the scene file is one line."""
    import bubblefit.model.scene as scene_module
    from bubblefit.cli import main
    from bubblefit.errors import InputError

    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\nwidth = 16\nheight = 16\n[lighting]\nenvmap = "courtyard.exr"\n'
                     '[effects]\nmodel = "physical"\n')
    seen = {}

    class Stop(Exception):
        pass

    def fake_render(s, **_):
        seen["film_rgb"] = s.film_rgb
        raise Stop

    monkeypatch.setattr(scene_module, "render_scene", fake_render)
    for flags, want in (([], "spectral"), (["--film-rgb", "clamped"], "clamped")):
        main(["render", str(scene), "-o", str(tmp_path / "out.exr"), *flags])  # stops in fake_render
        assert seen.pop("film_rgb") == want
    scene.write_text('[film]\nfilm_rgb = "srgb"\n')
    with pytest.raises(InputError, match="film.film_rgb"):
        scene_module.load_scene(scene)


@pytest.mark.parametrize("bad", [["--samples-per-pixel", "3"], ["--samples-per-pixel", "x"],
                                 ["--illuminant", "no_such_light"], ["--camera-response", "Canon 5D"],
                                 ["--n-film", "0.5"], ["--n-film", "glass"], ["--cauchy", "1.3"],
                                 ["--cauchy", "a,b"], ["--n-film", "1.33", "--cauchy", "1.3,3000"],
                                 ["--film-rgb", "srgb"]])
@pytest.mark.parametrize("command", ["fit", "fit-sequence"])
def test_cli_bad_flags_are_one_line(command, bad, tmp_path, capsys):
    from bubblefit.io.images import write_image

    from test_cli_errors import assert_one_line_error, run_cli

    photo, envfile = tmp_path / "p.exr", tmp_path / "e.exr"
    write_image(photo, np.full((16, 16, 3), 0.3))
    write_image(envfile, np.full((8, 16, 3), 0.5))
    extra = ["-o", tmp_path / "seq", "--workers", "0", "--no-progress"] if command == "fit-sequence" else []
    rc, _, err = run_cli(capsys, [command, photo, "--envmap", envfile, *extra, *bad])
    line = assert_one_line_error(rc, err)
    assert any(flag.lstrip("-") in line for flag in bad if flag.startswith("--")) or "index" in line, line
