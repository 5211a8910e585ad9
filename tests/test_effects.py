"""Effects a scene simulates (bubblefit.model.effects): auto against all-on, traces, --explain.

The scene set (experiments/bench_effects.py) has one scene per subset of the model: a
dark-box calibration, a point light in a dark room, a mirror bubble in a map, a thick
film, a rough film and the full physical model. Each is rendered with ``auto`` and with
everything on (:func:`bubblefit.model.effects.all_on_settings`); the largest pixel difference
must stay below the tolerance the decisions were made with, and the skipped terms must
not be traced at all.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import jax
import numpy as np
import pytest

R = importlib.import_module("bubblefit.model.render")  # the module (bubblefit.model.render is also a function)
from bubblefit.model.effects import DEFAULT_TOLERANCE, all_on_settings

_BENCH = Path(__file__).resolve().parent.parent / "experiments" / "bench_effects.py"
_spec = importlib.util.spec_from_file_location("bench_effects", _BENCH)
B = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(B)

SIZE = 64
MAP_HEIGHT = 64

#: What auto must skip (or downgrade) per scene: effect -> (simulated, setting or None).
EXPECTED = {
    "dark_box": {"front_reflection": False, "rear_reflection": False, "interference": False,
                 "transmission": True, "diffuse": False, "roughness_filtering": False},
    "point_light": {"roughness_filtering": False, "transmission": False, "interference": True,
                    "diffuse": True, "front_reflection": True},
    "mirror_bubble": {"roughness_filtering": False, "diffuse": False, "interference": True},
    "thick_film": {"interference": False, "spectral": False, "roughness_filtering": True},
    "rough_film": {"roughness_filtering": True, "interference": True, "diffuse": True},
    "full_model": {"fresnel": True, "interference": True, "internal_bounces": True, "point_lights": True},
}


@pytest.fixture(scope="module")
def maps():
    cache = {}

    def get(name, scale):
        if (name, scale) not in cache:
            cache[(name, scale)] = B.load_map(name, MAP_HEIGHT, scale)
        return cache[(name, scale)]

    return get


def _scene(name, maps, size=SIZE):
    data, bg, mapname = B.scene_set(size)[name]
    env = maps(mapname, float(data["lighting"].get("scale", 1.0)))
    return data, bg, env


@pytest.mark.parametrize("name", B.SCENE_NAMES)
def test_auto_matches_all_on_within_tolerance(name, maps):
    """max |auto - all-on| < tolerance, and auto skipped what this scene does not need."""
    size = 32 if name == "full_model" else SIZE  # the all-on physical model is the slowest render
    data, bg, env = _scene(name, maps, size)
    p, cfg, decisions, bgr = B.prepare(data, bg, env)
    p_on, cfg_on, dec_on, bgr_on = B.prepare(B.all_on(data), bg, env)
    got = {d.effect: d.simulated for d in decisions}
    for effect, simulated in EXPECTED[name].items():
        assert got[effect] == simulated, f"{name}: {effect} -> {got[effect]}: {[d.line() for d in decisions]}"
    # all-on really is all on.
    fx = cfg_on.effects
    assert fx.front_reflection and fx.rear_reflection and fx.transmission and fx.diffuse
    assert fx.interference in ("two_beam", "airy") and fx.spectral.samples == 800
    img = np.asarray(R.render(p, cfg, env, bgr), dtype=np.float64)
    ref = np.asarray(R.render(p_on, cfg_on, env, bgr_on), dtype=np.float64)
    assert np.all(np.isfinite(img)) and np.all(np.isfinite(ref))
    assert ref.max() > 0.02  # the scene shows something
    diff = float(np.max(np.abs(img - ref)))
    assert diff < DEFAULT_TOLERANCE, f"{name}: max |auto - all-on| = {diff:.3e}"
    if name == "thick_film":
        # The same scene with a thinner film keeps interference, and then grey would be wrong.
        thin = dict(data, bubble=dict(data["bubble"], thickness_nm=600.0))
        _, cfg_thin, dec_thin, _ = B.prepare(thin, None, env)
        assert cfg_thin.effects.interference == "two_beam"


def test_reasons_state_bound_and_value(maps):
    data, bg, env = _scene("thick_film", maps)
    _, cfg, decisions, _ = B.prepare(data, bg, env)
    d = {x.effect: x for x in decisions}
    assert "< tolerance 0.001" in d["interference"].reason and "e-0" in d["interference"].reason
    assert "tolerance" in d["front_reflection"].reason
    # A tighter tolerance brings the colours back (the decision follows the bound).
    tight = dict(data, effects={"tolerance": 1e-5})
    _, cfg_t, dec_t, _ = B.prepare(tight, bg, env)
    assert cfg_t.effects.interference == "two_beam" and cfg.effects.interference == "incoherent"


def _traced(data, bg, env):
    """Names traced while building the jaxpr of one render, and the jaxpr."""
    p, cfg, _, bgr = B.prepare(data, bg, env)
    R.TRACE_COUNTS.clear()
    jaxpr = jax.make_jaxpr(lambda q: R.render_terms(q, cfg, env, bgr)[0])(p)
    return {k for k, v in R.TRACE_COUNTS.items() if v}, jaxpr, cfg


def _shapes(jaxpr):
    out = set()

    def walk(jp):
        for eqn in jp.eqns:
            for v in eqn.outvars:
                out.add(tuple(getattr(v.aval, "shape", ())))
            for sub in jax.core.subjaxprs(eqn) if hasattr(jax.core, "subjaxprs") else []:
                walk(sub)
            for param in eqn.params.values():
                inner = getattr(param, "jaxpr", None)
                if inner is not None:
                    walk(getattr(inner, "jaxpr", inner))

    walk(jaxpr.jaxpr)
    return out


def test_skipped_effects_are_not_traced(maps):
    # Dark box: only the background transmission.
    data, bg, env = _scene("dark_box", maps, 16)
    traced, _, _ = _traced(data, bg, env)
    assert "transmission" in traced
    assert not traced & {"front_reflection", "rear_reflection", "interference", "spectral", "diffuse",
                         "point_lights", "filter_mipmap", "filter_mirror"}
    # Point light: eq. (3), no environment filtering, no background.
    data, bg, env = _scene("point_light", maps, 16)
    traced, _, _ = _traced(data, bg, env)
    assert {"point_lights", "interference", "spectral", "diffuse"} <= traced
    assert not traced & {"filter_mipmap", "filter_mirror", "transmission", "background_lookup"}
    # Mirror bubble: a mirror lookup, no filter, no irradiance.
    data, bg, env = _scene("mirror_bubble", maps, 16)
    traced, _, _ = _traced(data, bg, env)
    assert "filter_mirror" in traced and not traced & {"filter_mipmap", "diffuse"}
    # Thick film: no interference, no spectral loop; the jaxpr has no spectral axis.
    data, bg, env = _scene("thick_film", maps, 16)
    traced, jaxpr, cfg = _traced(data, bg, env)
    assert cfg.effects.spectral is None and not traced & {"interference", "spectral"}
    traced_on, jaxpr_on, cfg_on = _traced(B.all_on(data), bg, env)
    k = cfg_on.effects.spectral.samples
    assert {"interference", "spectral"} <= traced_on
    has_k = lambda shapes: any(k in s for s in shapes)
    assert has_k(_shapes(jaxpr_on)) and not has_k(_shapes(jaxpr))


def test_explicit_settings_override_auto(maps):
    data, bg, env = _scene("mirror_bubble", maps, 16)
    forced = dict(data, effects={"filtering": "mipmap", "diffuse": True, "interference": "off"})
    _, cfg, decisions, _ = B.prepare(forced, bg, env)
    d = {x.effect: x for x in decisions}
    assert cfg.effects.filtering.method == "mipmap" and cfg.effects.diffuse
    assert cfg.effects.interference == "off" and cfg.effects.spectral is None
    assert d["diffuse"].reason == "set by the scene"
    on = all_on_settings("physical")
    assert on["interference"] == "airy" and on["bounces"] >= 2 and on["spectral"] == {"method": "reference"}


def test_render_explain_cli(tmp_path, capsys):
    from bubblefit.cli import main

    scene = tmp_path / "lamp.toml"
    scene.write_text(
        "[camera]\nwidth = 24\nheight = 24\n"
        "[bubble]\nthickness_nm = 400\nroughness = 0.08\n"
        "[lighting]\nbackground = \"black\"\n"
        "point_lights = [{direction = [0.5, 0.6, 1.0], radiance = [0.5, 0.5, 0.5]}]\n"
    )
    out = tmp_path / "lamp.exr"
    rc = main(["render", str(scene), "-o", str(out), "--explain", "--json", str(tmp_path / "r.json")])
    assert rc == 0 and out.exists()
    text = capsys.readouterr().out
    lines = {ln.split()[0]: ln for ln in text.splitlines() if ln.strip()}
    assert "skipped" in lines["transmission"] and "black background" in lines["transmission"]
    assert "skipped" in lines["roughness_filtering"] and "no environment map" in lines["roughness_filtering"]
    assert "simulated" in lines["point_lights"] and "eq. (3)" in lines["point_lights"]
    assert "simulated" in lines["interference"] and "tolerance 0.001" in lines["interference"]
    effects = {e["effect"]: e for e in json.loads((tmp_path / "r.json").read_text())["effects"]}
    assert effects["transmission"]["simulated"] is False and effects["spectral"]["simulated"] is True
    # A bad effects value is one line on stderr and exit 2.
    bad = tmp_path / "bad.toml"
    bad.write_text("[effects]\ninterference = \"sometimes\"\n")
    with pytest.raises(SystemExit) as exc:
        code = main(["render", str(bad), "-o", str(tmp_path / "x.exr")])
        raise SystemExit(code)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bubblefit: error:")


def test_transmission_tint_decisions():
    """The paper model keeps eq. (11)'s grey t^4 unless asked, and says what the tint
    would change; asked, it is simulated (and traced); the physical model always has it;
    a grey film (no interference) or a black background has nothing to tint."""
    import jax

    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.errors import InputError
    from bubblefit.model.render import TRACE_COUNTS, render
    from bubblefit.model.scene import Scene

    env = EnvMap.from_array(np.full((8, 16, 3), 0.5))

    def decide(**effects):
        sc = Scene.from_dict({"camera": {"width": 8, "height": 8}, "bubble": {"thickness_nm": 400.0},
                              "lighting": {"envmap": "unused.exr"}, "effects": effects})
        cfg, decisions = sc.config(env)
        return sc, cfg, {d.effect: d for d in decisions}["transmission_tint"]

    _, cfg, d = decide(model="paper")
    assert not cfg.effects.tint and not d.simulated and "eq. (11)" in d.reason and "e-" in d.reason
    sc, cfg, d = decide(model="paper", transmission_tint=True)
    assert cfg.effects.tint and d.simulated
    TRACE_COUNTS.clear()
    jax.make_jaxpr(lambda p: render(p, cfg, env))(sc.params())
    assert TRACE_COUNTS["transmission_tint"] >= 1
    assert decide(model="physical")[2].simulated
    assert not decide(model="paper", transmission_tint=True, interference="off")[1].effects.tint
    with pytest.raises(InputError, match="transmission_tint"):
        decide(model="paper", transmission_tint="sometimes")
