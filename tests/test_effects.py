"""Effects a scene simulates (bubblefit.model.auto and .effects): auto against all-on, traces, --explain.

A representative subset of the benchmark's scenes (experiments/bench_effects.py: a dark
box, a lamp in a dark room, a mirror bubble with a 6 um film in the sunrise map with its
sun, a thick film, a rough film, the physical model with a point light at night) is
rendered small with ``auto`` and with everything on
(:func:`bubblefit.model.effects.all_on_settings`). In every pixel of the bubble the
difference must stay within the budget ``auto`` promises (a fraction ``tolerance`` of the
pixel plus a tenth of that of the bright level, measured here on the all-on image), and
the skipped terms must not be traced at all.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import jax
import numpy as np
import pytest

R = importlib.import_module("bubblefit.model.render")  # the module (bubblefit.model.render is also a function)
from bubblefit.model.auto import DEFAULT_TOLERANCE
from bubblefit.model.effects import all_on_settings

_BENCH = Path(__file__).resolve().parent.parent / "experiments" / "bench_effects.py"
_spec = importlib.util.spec_from_file_location("bench_effects", _BENCH)
B = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(B)

SIZE = 32
MAP_HEIGHT = 64

#: What auto must skip (or choose) per scene: effect -> simulated.
EXPECTED = {
    "dark_box": {"front_reflection": False, "rear_reflection": False, "interference": False,
                 "transmission": True, "diffuse": False, "roughness_filtering": False},
    "point_light": {"roughness_filtering": False, "transmission": False, "interference": True,
                    "diffuse": True, "front_reflection": True},
    "sunrise_mirror_6um": {"diffuse": False, "interference": True},
    "courtyard_thick": {"interference": False, "spectral": False},
    "city_rough": {"roughness_filtering": True, "interference": True, "diffuse": True},
    "night_physical_light": {"fresnel": True, "interference": True, "point_lights": True},
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


@pytest.mark.slow
@pytest.mark.parametrize("name", list(EXPECTED))
def test_auto_within_budget_of_all_on(name, maps):
    """Every bubble pixel of auto is within its budget of all-on, and auto skipped what the scene does not need."""
    data, bg, env = _scene(name, maps)
    p, parts, decisions, bgr = B.prepare(data, bg, env)
    p_on, parts_on, _, bgr_on = B.prepare(B.all_on(data), bg, env)
    got = {d.effect: d.simulated for d in decisions}
    for effect, simulated in EXPECTED[name].items():
        assert got[effect] == simulated, f"{name}: {effect} -> {got[effect]}: {[d.line() for d in decisions]}"
    fx = parts_on[0][0].effects  # all-on really is all on, in one region
    assert len(parts_on) == 1 and fx.front_reflection and fx.rear_reflection and fx.transmission and fx.diffuse
    assert fx.interference in ("two_beam", "airy") and fx.spectral.samples == 800
    img = B.render_parts(p, parts, env, bgr)
    ref = B.render_parts(p_on, parts_on, env, bgr_on)
    assert np.all(np.isfinite(img)) and ref.max() > 0.02
    # The all-on reference is a float32 render too: where a mirror sees the sun's edge two
    # compilations of it differ by a few percent. That rounding, measured on all-on itself
    # (rendered again in other chunks), is taken off every pixel's difference: one check,
    # the same for every scene.
    noise = B.reproducibility(p_on, parts_on, env, bgr_on, ref)
    share = B.budget_share(img, ref, DEFAULT_TOLERANCE, noise)
    assert share <= 1.0, f"{name}: auto uses {share:.2f} of its budget: {[d.line() for d in decisions]}"


def test_sunny_mirror_bubble_is_cheapened_where_the_sun_is_not(maps):
    """The issue's scene (a = 5e-4, r_d = 0, 6 um, physical, sunrise with its sun): the
    sun's glint gets the filtered lookup, the rest of the bubble the mirror lookup and
    fewer spectral samples than the 800-sample reference; --explain says so per region."""
    data, bg, env = _scene("sunrise_mirror_6um", maps, 40)
    _, parts, decisions, _ = B.prepare(data, bg, env)
    d = {x.effect: x for x in decisions}
    rest = parts[0][0].effects
    assert rest.filtering.method == "mirror" and rest.spectral.samples < 800 and rest.bounces <= 8
    # one thickness, no dispersion: the phase samples, exact for any thickness, beat 100 uniform ones
    assert rest.spectral.method == "harmonic" and rest.spectral.samples < 100
    assert "mirror" in d["roughness_filtering"].setting and "of the filtering share" in d["roughness_filtering"].reason
    assert all(0 <= x.budget_used <= 1.0 for x in decisions if x.budget_used is not None and x.effect != "internal_bounces")
    n_px = 40 * 40
    assert sum(len(px) for _, px in parts[1:]) < 0.25 * n_px


def test_tolerance_is_relative_and_tighter_costs_more(maps):
    data, bg, env = _scene("courtyard_thick", maps)
    _, parts, decisions, _ = B.prepare(data, bg, env)
    d = {x.effect: x for x in decisions}
    assert parts[0][0].effects.interference == "incoherent" and "budget" in d["interference"].reason
    tight = dict(data, effects={"tolerance": 1e-5})
    _, parts_t, _, _ = B.prepare(tight, bg, env)
    assert parts_t[0][0].effects.interference == "two_beam"


def _traced(data, bg, env):
    """Names traced while building the jaxpr of one render, and the jaxpr."""
    p, parts, _, bgr = B.prepare(data, bg, env)
    cfg = parts[0][0]
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
    # Mirror bubble (roughness 0): a mirror lookup, no filter, no irradiance.
    data, bg, env = _scene("interior_mirror", maps, 16)
    traced, _, _ = _traced(data, bg, env)
    assert "filter_mirror" in traced and not traced & {"filter_mipmap", "diffuse"}
    # Thick film: no interference, no spectral loop; the jaxpr has no spectral axis.
    data, bg, env = _scene("courtyard_thick", maps, 16)
    traced, jaxpr, cfg = _traced(data, bg, env)
    assert cfg.effects.spectral is None and not traced & {"interference", "spectral"}
    traced_on, jaxpr_on, cfg_on = _traced(B.all_on(data), bg, env)
    k = cfg_on.effects.spectral.samples
    assert {"interference", "spectral"} <= traced_on
    has_k = lambda shapes: any(k in s for s in shapes)
    assert has_k(_shapes(jaxpr_on)) and not has_k(_shapes(jaxpr))


def test_explicit_settings_override_auto(maps):
    data, bg, env = _scene("interior_mirror", maps, 16)
    data = dict(data, bubble=dict(data["bubble"], roughness=1e-7))
    forced = dict(data, effects={"filtering": "mipmap", "diffuse": True, "interference": "off"})
    _, parts, decisions, _ = B.prepare(forced, bg, env)
    cfg = parts[0][0]
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
    assert "simulated" in lines["interference"] and "budget" in lines["interference"]
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


@pytest.mark.slow
def test_window_below_a_texel_is_the_bilinear_lookup():
    """Eq. (13)'s window at a = 5e-4 on a 2k-wide map (a lobe inside one texel) returns the
    bilinear mirror lookup, not a nearest-texel sum; a wide lobe still sums its window."""
    import jax.numpy as jnp

    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.lighting.filtering import specular_mirror, specular_window

    rng = np.random.default_rng(3)
    h = 1024
    px = rng.uniform(0.1, 1.0, (h, 2 * h, 3))
    env = EnvMap.from_array(px)
    n = jnp.asarray(rng.normal(size=(64, 3)))
    n = n / jnp.linalg.norm(n, axis=-1, keepdims=True)
    wo = n  # normal incidence: the mirror direction is the normal
    for normalize in (True, False):
        mirror = np.asarray(specular_mirror(env, n, wo, normalize=normalize))
        narrow = np.asarray(specular_window(env, n, wo, jnp.float32(5e-4), window=2, level=0, normalize=normalize))
        np.testing.assert_allclose(narrow, mirror, rtol=1e-6)
        wide = np.asarray(specular_window(env, n, wo, jnp.float32(0.02), window=8, level=0, normalize=normalize))
        assert np.max(np.abs(wide - mirror)) > 1e-3  # a real window sum averages the noise


@pytest.mark.slow
def test_perfect_mirror_and_messages():
    """roughness = 0 is a perfect mirror (mirror lookup, finite gradients); r_d alone is
    fine in the physical model; radius 0 says what is wrong."""
    import jax

    from bubblefit.errors import InputError
    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.model.render import render
    from bubblefit.model.scene import Scene

    env = EnvMap.from_array(np.random.default_rng(0).uniform(0.2, 1.0, (16, 32, 3)))
    lamp = [{"direction": [0.3, 0.5, 1.0], "radiance": [1.0, 1.0, 1.0]}]
    for model in ("paper", "physical"):
        for filtering in ("auto", "mipmap", "window"):
            sc = Scene.from_dict({"camera": {"width": 12, "height": 12}, "bubble": {"roughness": 0.0},
                                  "lighting": {"envmap": "unused.exr", "point_lights": lamp},
                                  "effects": {"model": model, "filtering": filtering}})
            parts, decisions = sc.plan(env)
            cfg = parts[0][0]
            d = {x.effect: x for x in decisions}
            assert cfg.effects.filtering.method == "mirror" and "perfect mirror" in d["roughness_filtering"].reason
            grad = jax.grad(lambda q: render(q, cfg, env).sum())(sc.params())
            assert all(np.all(np.isfinite(np.asarray(g))) for g in jax.tree_util.tree_leaves(grad))
    sc = Scene.from_dict({"bubble": {"r_d": 0.0}, "effects": {"model": "physical"}})
    assert float(sc.params().r_d) == 0.0
    with pytest.raises(InputError, match="physical model takes r_d alone"):
        Scene.from_dict({"bubble": {"r_d": 0.0}})
    with pytest.raises(InputError, match=r"radius = 0 is out of range \(0, inf\]: the bubble's radius must be positive"):
        Scene.from_dict({"bubble": {"radius": 0.0}})
    with pytest.raises(InputError, match=r"roughness = -1 is out of range \[0, 10\]"):
        Scene.from_dict({"bubble": {"roughness": -1.0}})


def test_render_tolerance_flag(tmp_path, capsys):
    from bubblefit.cli import main

    scene = tmp_path / "lamp.toml"
    scene.write_text("[camera]\nwidth = 16\nheight = 16\n[bubble]\nthickness_nm = 400\nroughness = 0.08\n"
                     "[lighting]\nbackground = \"black\"\n"
                     "point_lights = [{direction = [0.5, 0.6, 1.0], radiance = [0.5, 0.5, 0.5]}]\n")
    samples = {}
    for tol in ("0.1", "0.0001"):
        js = tmp_path / f"r{tol}.json"
        assert main(["render", str(scene), "-o", str(tmp_path / "o.exr"), "--tolerance", tol, "--json", str(js)]) == 0
        eff = {e["effect"]: e for e in json.loads(js.read_text())["effects"]}
        samples[tol] = eff["spectral"]["setting"]
    capsys.readouterr()
    assert samples["0.1"] != samples["0.0001"]
    rc = main(["render", str(scene), "-o", str(tmp_path / "o.exr"), "--tolerance", "-1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--tolerance" in err[0]


@pytest.mark.slow
def test_harmonic_basis_only_where_it_is_exact(maps):
    """``harmonic`` needs one thickness and a non-dispersive index: a drainage film or a
    Cauchy index asked for it is one clear error; ``auto`` does not offer it there."""
    from bubblefit.errors import InputError
    from bubblefit.model.scene import Scene

    data, bg, env = _scene("sunrise_mirror_6um", maps, 24)
    harm = {"spectral": {"method": "harmonic", "samples": 16}}
    drain = {"profile": "drainage", "top_nm": 150.0, "bottom_nm": 900.0, "exponent": 1.5}
    for bubble in ({"thickness": drain}, {"n_film": {"cauchy": [1.324188, 3102.06]}}):
        bad = dict(data, bubble=dict(data["bubble"], **bubble), effects=dict(data["effects"], **harm))
        with pytest.raises(InputError, match="harmonic"):
            Scene.from_dict(bad).plan(env)
        auto = dict(data, bubble=dict(data["bubble"], **bubble))
        parts, _ = Scene.from_dict(auto).plan(env)
        assert all(cfg.effects.spectral is None or cfg.effects.spectral.method != "harmonic" for cfg, _ in parts)
    parts, _ = Scene.from_dict(dict(data, effects=dict(data["effects"], **harm))).plan(env)
    assert parts[0][0].effects.spectral.method == "harmonic"


def test_range_max_equals_the_direct_maximum():
    """The sparse table behind a thickness field's cells: max over rows lo..hi, one column."""
    from bubblefit.model.auto import _range_max

    rng = np.random.default_rng(3)
    q = rng.random((37, 5, 3))
    lo = rng.integers(0, 37, 400)
    hi = np.minimum(36, lo + rng.integers(0, 37, 400))
    col = rng.integers(0, 5, 400)
    direct = np.stack([q[a: b + 1, c].max(axis=0) for a, b, c in zip(lo, hi, col)])
    np.testing.assert_array_equal(_range_max(q, lo, hi, col), direct)
