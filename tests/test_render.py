"""Compositing (bubblefit.model.render): an independent numpy ray tracer, paper vs physical,
gradients against finite differences, and the render CLI's handling of bad input."""

from __future__ import annotations

import dataclasses

import numpy as np


# Fresnel's equations and the map lookup of docs/design.md's convention, written in
# tests/helpers.py; test_render_reference.test_map_convention_is_mitsubas anchors the
# convention to Mitsuba 3's renders of a mirror sphere.
from helpers import equirect_lookup as _env_lookup  # noqa: E402
from helpers import fresnel_rs_rp as _fresnel_rs_rp  # noqa: E402


def _slab(cos_i, n, depth=200):
    """Reflectance and transmittance (..., 2) of a film with incoherent internal bounces,
    by following each of the film's internal reflections explicitly (not a closed form)."""
    r = _fresnel_rs_rp(cos_i, n)
    refl = r.copy()
    trans = np.zeros_like(r)
    inner = (1 - r)  # power entering the film
    for _ in range(depth):
        trans += inner * (1 - r)  # leaves through the far face
        inner = inner * r  # reflected back inside
        refl += inner * (1 - r)  # leaves through the near face
        inner = inner * r
    return refl, trans


def trace_reference(px, cam, n, center=(0.0, 0.0, 0.0), radius=1.0, tol=1e-9, average_first=False):
    """Radiance (H, W, 3) of a smooth bubble of two incoherent films, traced ray by ray.

    Every camera ray that hits the sphere is split at each film into a reflected and a
    transmitted part, per polarisation (s and p stay s and p: a sphere keeps the plane of
    incidence); rays inside the bubble are followed from film to film until their weight
    is below ``tol``. Rays that leave read the map in their direction.
    ``average_first`` builds the thin-sheet shortcut instead: the film's reflectance is
    averaged over s and p before the bounces are multiplied (not the same at the rim).
    """
    slab = _slab
    if average_first:
        def slab(cos_i, n):
            rr, tt = _slab(cos_i, n)
            return (np.repeat(rr.mean(-1, keepdims=True), 2, -1), np.repeat(tt.mean(-1, keepdims=True), 2, -1))
    h, w = cam.height, cam.width
    cx, cy, r = cam.disc()
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x = (jj - cx) / r
    y = -(ii - cy) / r
    c = np.asarray(center, dtype=float)
    out = _env_lookup(px, np.broadcast_to([0.0, 0.0, -1.0], (h, w, 3)))
    hit = x**2 + y**2 < 1
    pts = np.stack([x[hit], y[hit], np.zeros(hit.sum())], axis=-1)
    d = np.broadcast_to([0.0, 0.0, -1.0], pts.shape).copy()
    # front hit point: p = c + R (x, y, sqrt(1 - x^2 - y^2))
    p = c + radius * np.stack([x[hit], y[hit], np.sqrt(1 - x[hit] ** 2 - y[hit] ** 2)], axis=-1)
    nrm = (p - c) / radius
    cos_i = np.abs(np.sum(nrm * d, axis=-1))
    refl, trans = slab(cos_i, n)
    col = _env_lookup(px, d - 2 * np.sum(d * nrm, -1, keepdims=True) * nrm)
    acc = np.zeros(pts.shape[:1] + (2, 3))
    acc += refl[..., None] * col[:, None, :]
    weight = trans.copy()  # (N, 2) inside the bubble, travelling along d from p
    for _ in range(10000):
        if weight.max() <= tol:
            break
        # next film: the chord from p along d
        s = -2 * np.sum((p - c) * d, axis=-1)
        p = p + s[:, None] * d
        nrm = (p - c) / np.linalg.norm(p - c, axis=-1, keepdims=True)
        p = c + radius * nrm
        cos_i = np.abs(np.sum(nrm * d, axis=-1))
        refl, trans = slab(cos_i, n)
        acc += (weight * trans)[..., None] * _env_lookup(px, d)[:, None, :]
        d = d - 2 * np.sum(d * nrm, -1, keepdims=True) * nrm
        weight = weight * refl
    out = out.copy()
    out[hit] = acc.mean(axis=1)
    return out


import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import pytest  # noqa: E402

from bubblefit.model.effects import Effects  # noqa: E402
from bubblefit.lighting.envmap import EnvMap  # noqa: E402
from bubblefit.lighting.filtering import FilterConfig  # noqa: E402
from bubblefit.model.geometry import OrthographicCamera  # noqa: E402
from bubblefit.model.render import Params, RenderConfig, render, render_terms  # noqa: E402
from bubblefit.optics.spectral import spectral_basis  # noqa: E402

# render_terms is not jitted itself (render is, around it): called eagerly, its chunk loop
# (a lax.map) is compiled afresh on every call; jitted once per configuration here, a test
# that renders one configuration at several thicknesses compiles it once
_terms = jax.jit(render_terms, static_argnames=("cfg",))

CAM = OrthographicCamera(40, 40, 20.0, 20.0, 18.0)


@pytest.fixture(scope="module")
def env64(small_courtyard):
    with jax.enable_x64(True):
        return EnvMap.from_array(small_courtyard, dtype=jnp.float64), small_courtyard


def _disc(cam):
    cx, cy, r = cam.disc()
    jj, ii = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    return np.hypot(jj - cx, ii - cy) / r


def test_physical_model_matches_ray_traced_reference(x64, env64):
    env, px = env64
    ref = trace_reference(px, CAM, 1.4)
    rho = _disc(CAM)
    inside = rho < 1
    p = Params.make(t=0.97, roughness=1e-3, n_film=1.4, dtype=jnp.float64)
    errs = {}
    for bounces in (1, 24):
        fx = Effects(model="physical", interference="off", filtering=FilterConfig("mirror"), diffuse=False,
                     bounces=bounces)
        # the reference traces each pixel's centre ray: so does the model here (no footprint)
        img = np.asarray(render(p, RenderConfig(effects=fx, camera=CAM, chunk=800, pixel_footprint=False), env))
        errs[bounces] = np.abs(img - ref).sum(-1) / np.abs(ref).sum(-1)
        np.testing.assert_allclose(img[~inside], ref[~inside], rtol=1e-9)  # the map behind
    # Every bounce followed: within 1% everywhere, rim included (incidence up to ~84 deg).
    assert errs[24][inside].max() < 0.01, errs[24][inside].max()
    # One rear reflection (eq. 11's) is fine in the centre but misses light at the rim.
    assert errs[1][rho < 0.5].max() < 0.03
    assert errs[1][inside].max() > 0.05
    # Averaging Fresnel over polarisation before the bounces is a different model at the rim.
    avg = trace_reference(px, CAM, 1.4, average_first=True)
    diff = np.abs(avg - ref).sum(-1) / np.abs(ref).sum(-1)
    assert diff[inside].max() > 0.02 and diff[rho < 0.3].max() < 1e-3


def test_paper_and_physical_agree_in_centre_differ_at_rim(x64, env64):
    env, _ = env64
    rho = _disc(CAM)
    # Paper parameters matched to the film at normal incidence: r_s = R_film(0), t^2 = 1 - R_film(0).
    r1 = (0.4 / 2.4) ** 2
    r_film = 2 * r1 / (1 + r1)
    p = Params.make(t=np.sqrt(1 - r_film), r_d=0.0, r_s=r_film, roughness=1e-3, n_film=1.4, dtype=jnp.float64)
    out = {}
    for model in ("paper", "physical"):
        fx = Effects(model=model, interference="off", filtering=FilterConfig("mirror"), diffuse=False, bounces=1)
        img, terms = render_terms(p, RenderConfig(effects=fx, camera=CAM, chunk=800), env)
        out[model] = (np.asarray(img), {k: np.asarray(v) for k, v in terms.items()})
    centre = rho < 0.2
    rim = (rho > 0.97) & (rho < 1)
    front_p, front_f = out["paper"][1]["front"].sum(-1), out["physical"][1]["front"].sum(-1)
    ratio = front_f / front_p
    assert np.abs(ratio[centre] - 1).max() < 0.03
    assert ratio[rim].min() > 3  # Fresnel grows to the rim; eq. (1)'s lobe falls with cos th_r
    total = np.abs(out["physical"][0] - out["paper"][0]).sum(-1) / out["paper"][0].sum(-1)
    assert total[centre].max() < 0.01
    assert total[rim].max() > 0.1
    # Weak reflections: the transmitted background dominates both and agrees.
    bg_p, bg_f = out["paper"][1]["background"].sum(-1), out["physical"][1]["background"].sum(-1)
    assert np.abs(bg_f[centre] / bg_p[centre] - 1).max() < 0.01


def _fd_check(p, cfg, env, names, rel=1e-6, rtol=2e-3):
    w = jnp.asarray(np.random.default_rng(1).uniform(0.5, 1.5, cfg.shape + (3,)))

    def loss(q):
        return jnp.sum(render(q, cfg, env) * w)

    # one compiled program gives the loss and its gradient (eagerly, the gradient's
    # forward and backward passes and the loss each compile a render of their own)
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    g = value_and_grad(p)[1]
    for name in names:
        v = getattr(p, name)
        h = rel * max(1.0, float(jnp.max(jnp.abs(v))))
        flat = np.asarray(v).ravel()
        for i in range(flat.size):
            e = np.zeros(flat.size)
            e[i] = h
            up = with_field(p, name, jnp.asarray(flat + e).reshape(v.shape))
            dn = with_field(p, name, jnp.asarray(flat - e).reshape(v.shape))
            fd = (float(value_and_grad(up)[0]) - float(value_and_grad(dn)[0])) / (2 * h)
            ad = float(np.asarray(getattr(g, name)).ravel()[i])
            assert np.isfinite(ad)
            assert ad == pytest.approx(fd, rel=rtol, abs=1e-6 * (1 + abs(fd))), (name, i, ad, fd)


def with_field(p, name, value):
    return dataclasses.replace(p, **{name: value})


@pytest.mark.slow
@pytest.mark.parametrize("model,interference,method", [
    ("paper", "two_beam", "mipmap"),
    ("physical", "airy", "mipmap"),
])
def test_gradients_match_finite_differences(x64, env64, model, interference, method):
    env, _ = env64
    cam = OrthographicCamera(12, 12, 6.0, 6.0, 5.0)
    fx = Effects(model=model, interference=interference, filtering=FilterConfig(method, nodes=2),
                 spectral=spectral_basis("uniform", 8), diffuse=True, bounces=2)
    cfg = RenderConfig(effects=fx, camera=cam, chunk=48)
    p = Params.make(t=0.95, r_d=0.01, r_s=0.04, roughness=0.12, thickness=430.0, n_film=1.38, exposure=1.3,
                    rotation=0.4, dtype=jnp.float64)
    _fd_check(p, cfg, env, ["t", "r_d", "r_s", "roughness", "thickness", "n_film", "exposure", "rotation"])


def test_gradients_drainage_thickness(x64, env64):
    env, _ = env64
    cam = OrthographicCamera(12, 12, 6.0, 6.0, 5.0)
    fx = Effects(model="physical", interference="airy", filtering=FilterConfig("mirror"),
                 spectral=spectral_basis("uniform", 8), diffuse=False, bounces=1, thickness="drainage")
    cfg = RenderConfig(effects=fx, camera=cam, chunk=48)
    p = Params.make(thickness=jnp.asarray([200.0, 900.0, 1.7]), dtype=jnp.float64)
    p = with_field(p, "thickness", jnp.asarray([200.0, 900.0, 1.7], dtype=jnp.float64))
    _fd_check(p, cfg, env, ["thickness"])


def _write_scene(tmp_path, text):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("case,text,needle", [
    ("missing envmap", '[lighting]\nenvmap = "nope.exr"\n', "nope.exr"),
    ("unreadable envmap", '[lighting]\nenvmap = "garbage.exr"\n', "garbage.exr"),
    ("unknown key", '[bubble]\ncolour = 3\n[lighting]\nenvmap = "ENV"\n', "bubble.colour"),
    ("negative thickness", '[bubble]\nthickness_nm = -5\n[lighting]\nenvmap = "ENV"\n', "thickness"),
    ("t above 1", '[bubble]\nt = 1.5\n[lighting]\nenvmap = "ENV"\n', "bubble.t"),
    ("t below 0", '[bubble]\nt = -0.1\n[lighting]\nenvmap = "ENV"\n', "bubble.t"),
])
def test_render_cli_bad_input(tmp_path, capsys, case, text, needle):
    from bubblefit.cli import main
    from bubblefit.model.scene import shipped_envmap

    (tmp_path / "garbage.exr").write_bytes(b"not an image at all")
    scene = _write_scene(tmp_path, text.replace("ENV", str(shipped_envmap("courtyard"))))
    out = tmp_path / "out.exr"
    rc = main(["render", str(scene), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc != 0 and rc == 2, case
    assert err.startswith("bubblefit: error:") and err.count("\n") == 1, err
    assert needle in err, err
    assert "Traceback" not in err
    assert not out.exists()


def test_render_cli_missing_scene(tmp_path, capsys):
    from bubblefit.cli import main

    rc = main(["render", str(tmp_path / "absent.toml"), "-o", str(tmp_path / "o.exr")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "absent.toml" in err


def test_transmission_tint_is_the_complement_of_the_reflection(x64):
    """Paper model with ``transmission_tint``: each film transmits t^2 - r_s (F - 2 t^2)
    per wavelength, F = 4 t^2 cos^2(delta/2) (eqs. 8-10). Checked at the disc centre
    (normal incidence) against that formula written here with numpy, for the background
    term; without the tint the background is eq. (11)'s grey t^4; and the tint's colour
    opposes the reflected one (energy conservation: what is not reflected goes through)."""
    from bubblefit.model.scene import Scene

    from bubblefit.lighting.envmap import EnvMap

    n, t, r_s, size = 1.4, 0.95, 0.04, 9
    env = EnvMap.from_array(np.ones((8, 16, 3)))  # white sky and white background
    for d in (120.0, 330.0, 560.0, 910.0):
        terms = {}
        for tint in (False, True):
            scene = Scene.from_dict({
                "camera": {"width": size, "height": size, "disc": [size / 2, size / 2, size / 2 - 0.5]},
                "bubble": {"t": t, "r_d": 0.0, "r_s": r_s, "roughness": 1e-4, "thickness_nm": d, "n_film": n},
                "lighting": {"envmap": "unused.exr"},
                "effects": {"model": "paper", "interference": "two_beam", "transmission_tint": tint,
                            "filtering": "mirror", "rear_reflection": False, "diffuse": False,
                            "spectral": {"method": "uniform", "samples": 64}}})
            cfg, _ = scene.config(env)
            _, tm = _terms(scene.params(dtype=np.float64), cfg, env)
            terms[tint] = {k: np.asarray(v)[size // 2, size // 2] for k, v in tm.items()}
        basis = cfg.effects.spectral
        lam = np.asarray(basis.wavelengths)
        w = np.asarray(basis.weights)
        f = 4 * t**2 * np.cos(0.5 * (4 * np.pi * n * d / lam + np.pi)) ** 2
        expect = ((t**2 - r_s * (f - 2 * t**2)) ** 2) @ w
        np.testing.assert_allclose(terms[False]["background"], t**4, rtol=1e-12)
        np.testing.assert_allclose(terms[True]["background"], expect, rtol=1e-9)
        np.testing.assert_allclose(terms[True]["front"], (r_s * f) @ w, rtol=1e-6)
        dev_r = terms[True]["front"] - np.mean(terms[True]["front"])
        dev_t = terms[True]["background"] - np.mean(terms[True]["background"])
        strong = np.abs(dev_r) > 0.2 * np.max(np.abs(dev_r))
        assert np.all(dev_r[strong] * dev_t[strong] < 0), (d, dev_r, dev_t)


@pytest.mark.parametrize("spp,camera", [(1, "orthographic"), (1, "perspective"), (4, "orthographic"),
                                        pytest.param(4, "perspective", marks=pytest.mark.slow)])
def test_render_plan_renders_the_bubble_and_its_backdrop(env64, camera, spp):
    """A plan shades only the pixels the bubble can touch and takes the backdrop elsewhere:
    the image equals the whole-image render, the rim's sub-pixel rays included."""
    from bubblefit.model.geometry import PerspectiveCamera
    from bubblefit.model.regions import bubble_pixels, render_plan

    env = EnvMap.from_array(env64[1])
    cam = (OrthographicCamera(32, 24, 15.0, 12.5, 9.0) if camera == "orthographic"
           else PerspectiveCamera(32, 24, fov_deg=40.0, origin=(0.0, 0.0, 4.0)))
    fx = Effects(model="physical", interference="airy", spectral=spectral_basis("harmonic", 16), bounces=3)
    cfg = RenderConfig(effects=fx, camera=cam, chunk=256, samples_per_pixel=spp)
    p = Params.make(roughness=0.05, thickness=640.0)
    whole = np.asarray(render(p, cfg, env))
    plan = render_plan(p, [(cfg, None)], env)
    np.testing.assert_allclose(plan, whole, rtol=2e-5, atol=2e-6)
    assert 0 < bubble_pixels(cfg).size < 32 * 24


def _sunny(pixels: np.ndarray) -> np.ndarray:
    """``pixels`` with a small sun 2000x the map's mean: a scene whose plan has regions."""
    px = np.array(pixels, dtype=np.float64)
    h, w = px.shape[:2]
    px[h // 3: h // 3 + 2, w // 2: w // 2 + 2] = 2000.0 * px.mean()
    return px


def _texel_steps(pixels: np.ndarray) -> np.ndarray:
    """Per texel and channel, the largest change of the map between neighbouring texels
    (x periodic, y clamped) within its 3x3 neighbourhood: a bound on how much a bilinear
    lookup anywhere in that neighbourhood moves when its position moves by one texel."""
    px = np.asarray(pixels, dtype=np.float64)
    dx = np.abs(np.roll(px, -1, axis=1) - px)
    dy = np.zeros_like(px)
    dy[:-1] = np.abs(px[1:] - px[:-1])
    step = np.maximum(np.maximum(dx, np.roll(dx, 1, axis=1)), np.maximum(dy, np.roll(dy, 1, axis=0)))
    out = step.copy()
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            out = np.maximum(out, np.roll(np.roll(step, a, axis=0), b, axis=1))
    return out


# Rounding budget of one float32 ray, in units of the unit roundoff u = 2^-24 (see the
# docstring below): about 32 roundings along the ray's path, amplified up to 5 times by the
# camera's distance (|o| / R = 4 plus the sphere's own 1) and up to 1.6 times by the film's
# incidence at the pixel centres nearest the rim.
RAY_ROUNDINGS = 32 * 5 * 1.6


@pytest.mark.parametrize("case", [pytest.param("physical_drainage_lamp_perspective", marks=pytest.mark.slow),
                                  "paper_photo", pytest.param("physical_mirror", marks=pytest.mark.slow),
                                  pytest.param("supersampled", marks=pytest.mark.slow)])
def test_render_plan_from_the_footprint_equals_the_traced_render(small_courtyard, case):
    """render_scene shades the bubble from the light its footprint read (one ray per pixel):
    the image equals the plan traced afresh, region by region, for both models, a thickness
    field, point lights, a background photo and a rotated map; with sub-pixel rays the
    footprint is not used.

    Both float32 images (traced, and shaded from the footprint, whose rays another program
    traced) are compared with the float64 render pixel by pixel, each pixel within what
    float32 arithmetic on its own inputs allows. With unit roundoff u = 2^-24 a pixel's
    value is a sum ``sum_k w_k L_k`` of map texels (bilinear and filter weights ``w_k``
    times film factors, all >= 0 for the physical model) plus lamp and backdrop terms.
    Its float32 error has two parts:

    * the values: each product and sum rounds with relative error <= u, so the sum is off
      by at most ``n u sum_k |w_k L_k| = n u |x|`` (Higham, Accuracy and Stability of
      Numerical Algorithms, 2002, eq. 3.4), with n the number of roundings on the path;
    * the positions: the ray's direction is off by ``delta <= n a u`` radians, where ``a``
      is the amplification of the hit point's rounding (the camera's distance over the
      bubble's radius plus 1, and 1 / cos of the film's incidence). The lookup position
      ``x = W phi / (2 pi)`` then moves by ``W delta_phi / (2 pi) < W delta`` texels (W the
      map's width; ``delta_phi = delta / sin(theta)`` and the sun's rows lie 60 degrees from
      the pole; the row ``y = H theta / pi`` moves less), and a bilinear (or filtered: an
      average of bilinear) lookup
      moves by at most that times the largest neighbour-to-neighbour step of the map
      around the lookup. Rendering the map of those steps (``_texel_steps``, >= 0) with
      the same weights gives the pixel's ``S = sum_k w_k step_k``.

    So ``|x32 - x64| <= n a u (|x64| + W S)`` per pixel and channel, with ``n a`` =
    ``RAY_ROUNDINGS``. A footprint that read the wrong light, or a region shaded with
    another region's settings, is off by a large part of ``|x64|`` and fails: the bound is
    256 u = 1.5e-5 of the value away from the sun's edge. The sun (2000 times the map's
    mean) makes the position term matter: there the worst pixels reach about 41 (shaded
    from the footprint) and 27 (traced) of the 256 allowed (measured on x86-64 CPUs)."""
    from bubblefit.model.regions import lit_usable, render_plan
    from bubblefit.model.scene import Scene

    sunny = _sunny(small_courtyard)
    env = EnvMap.from_array(sunny)
    lamp = [{"direction": [0.4, 0.6, 1.0], "radiance": [3.0, 3.0, 3.0]}]
    data = {"camera": {"width": 40, "height": 32}, "bubble": {"roughness": 0.02, "thickness_nm": 700.0},
            "lighting": {"envmap": "unused.exr", "rotation_deg": 30.0}, "effects": {"model": "physical"}}
    background = None
    if case == "physical_drainage_lamp_perspective":
        data["camera"].update(type="perspective", origin=[0.0, 0.0, 4.0], fov_deg=35.0)
        data["bubble"]["thickness"] = {"profile": "drainage", "top_nm": 150.0, "bottom_nm": 900.0, "exponent": 1.5}
        data["lighting"]["point_lights"] = lamp
    elif case == "paper_photo":
        data["effects"]["model"] = "paper"
        data["lighting"]["background"] = "photo"
        background = np.random.default_rng(3).uniform(0.1, 0.9, (32, 40, 3))
    elif case == "physical_mirror":
        data["bubble"]["roughness"] = 0.0
        data["effects"]["filtering"] = "mirror"
    else:
        data["camera"]["samples_per_pixel"] = 4
    scene = Scene.from_dict(data)
    parts, _, fp = scene.plan_with_footprint(env, background)
    p = scene.params()
    traced = render_plan(p, parts, env, background)
    lit = render_plan(p, parts, env, background, footprint=fp)
    usable = [lit_usable(fp, p, cfg) for cfg, _ in parts]
    assert all(usable) if case != "supersampled" else not any(usable)
    if case == "physical_drainage_lamp_perspective":
        assert len(parts) > 1 and parts[0][0].effects.point_lights

    def render64(pixels, bg):
        """The plan rendered in float64, region by region."""
        with jax.enable_x64(True):
            env64 = EnvMap.from_array(pixels, dtype=jnp.float64)
            p64 = scene.params(dtype=jnp.float64)
            bg64 = None if bg is None else jnp.asarray(bg)
            img = np.array(render(p64, parts[0][0], env64, bg64)).reshape(-1, 3)
            for cfg, px in parts[1:]:
                img[np.asarray(px)] = np.asarray(render(p64, cfg, env64, bg64)).reshape(-1, 3)[np.asarray(px)]
        return img.reshape(traced.shape)

    exact = render64(sunny, background)
    # the paper model's weights may be negative (eq. 10's r_s term): |S| there
    steps = np.abs(render64(_texel_steps(sunny), None if background is None else np.zeros_like(background)))
    u = 2.0**-24
    bound = RAY_ROUNDINGS * u * (np.abs(exact) + sunny.shape[1] * steps)
    for name, img in (("traced", traced), ("footprint", lit)):
        excess = np.abs(img - exact) / bound
        worst = np.unravel_index(np.argmax(excess), excess.shape)
        assert excess.max() <= 1.0, (name, worst, img[worst], exact[worst], bound[worst])
    other = dataclasses.replace(p, roughness=p.roughness + 0.01)  # not the footprint's parameters
    assert not lit_usable(fp, other, parts[0][0])


@pytest.mark.parametrize("camera", ["orthographic", pytest.param("perspective", marks=pytest.mark.slow)])
def test_a_map_keeps_its_profile_on_the_films_the_photo_does_not_show(env64, camera):
    """A drainage film given as a ``map`` of its front film, with the profile under it
    (``Params.profile``), renders as the drainage film itself, rear film and internal
    bounces included: their film points take the map's value changed by the profile
    between the heights. Without the profile they read the front's value at the pixel; in
    a perspective view the rear film of a pixel lies at another height (and in any view
    the bounces do), so the image is then wrong by percents."""
    from bubblefit.model.geometry import PerspectiveCamera, front_hits
    from bubblefit.model.render import NO_PROFILE
    from bubblefit.model.thickness import drainage_profile

    env = EnvMap.from_array(env64[1])
    cam = (OrthographicCamera(32, 32, 16.0, 16.0, 14.0) if camera == "orthographic"
           else PerspectiveCamera(32, 32, fov_deg=40.0, origin=(0.0, 0.0, 4.0)))
    prof = (150.0, 900.0, 1.0)
    inside, _, local0 = (np.asarray(v) for v in front_hits(cam, (0.0, 0.0, 0.0), 1.0))
    inside = inside.reshape(32, 32)
    front_map = np.asarray(drainage_profile(local0[:, 1], *prof), np.float32).reshape(32, 32)
    fx = Effects(model="physical", interference="airy", spectral=spectral_basis("uniform", 32), bounces=3)
    terms = lambda kind, th, pr=NO_PROFILE: {k: np.asarray(v) for k, v in _terms(
        Params.make(roughness=0.05, thickness=th, profile=pr),
        RenderConfig(effects=dataclasses.replace(fx, thickness=kind), camera=cam, chunk=256), env)[1].items()}
    total = lambda t: sum(t.values())
    truth = terms("drainage", prof)
    with_profile = terms("map", front_map, prof)
    np.testing.assert_allclose(total(with_profile)[inside], total(truth)[inside], rtol=2e-4, atol=1e-6)
    flat = np.abs(total(terms("map", front_map)) - total(truth))[inside] / np.maximum(total(truth)[inside], 1e-6)
    assert flat.max() > 0.02  # the films behind read the front's thickness without it
    # at points given by hand: the map's value plus the profile's change of height, or the
    # map's value alone without a profile (NaN)
    from bubblefit.model.thickness import thickness_at

    q = jnp.asarray([[0.0, 0.3, -0.95], [0.1, -0.6, -0.79]], jnp.float32)
    f = jnp.asarray([[0.0, 0.1, 0.99], [0.1, -0.2, 0.97]], jnp.float32)
    pix = jnp.asarray([16 * 32 + 16, 20 * 32 + 17])
    at_pix = front_map.reshape(-1)[np.asarray(pix)]
    dp = lambda y: np.asarray(drainage_profile(np.asarray(y), *prof))
    behind = thickness_at("map", jnp.asarray(front_map), q, pix, jnp.asarray(prof, jnp.float32), f)
    np.testing.assert_allclose(behind, at_pix + dp(q[:, 1]) - dp(f[:, 1]), rtol=1e-5)
    none = thickness_at("map", jnp.asarray(front_map), q, pix, jnp.asarray(NO_PROFILE, jnp.float32), f)
    np.testing.assert_allclose(none, at_pix)


@pytest.mark.parametrize("model,spp,photo", [("physical", 1, True), pytest.param("physical", 4, False, marks=pytest.mark.slow),
                                             ("paper", 1, True)])
def test_constant_films_at_many_thicknesses_equal_their_renders(env64, model, spp, photo):
    """render_pixels_at traces the rays and reads the map once for a list of thicknesses:
    each thickness's terms equal render_terms' at that thickness, on the listed pixels,
    for both models, sub-pixel rays and a background photo; a wrong thickness does not."""
    from bubblefit.model.render import pixel_chunks, render_pixels_at

    env = EnvMap.from_array(env64[1])
    cam = OrthographicCamera(24, 20, 12.0, 10.5, 8.0)
    fx = Effects(model=model, interference="airy", spectral=spectral_basis("fourier", 8), bounces=3,
                 background="photo" if photo else "envmap", diffuse=True)
    cfg = RenderConfig(effects=fx, camera=cam, chunk=128, samples_per_pixel=spp)
    bg = np.random.default_rng(1).uniform(0.1, 0.8, (20, 24, 3)).astype(np.float32) if photo else None
    p = Params.make(roughness=0.05, thickness=0.0, r_d=0.004, r_s=0.02)
    pixels = np.arange(0, 20 * 24, 3)  # every third pixel: rim, disc and outside
    rows, cols, idx, npix = pixel_chunks(cfg, pixels)
    thick = np.array([0.0, 90.0, 455.0, 1300.0], np.float32)
    many = render_pixels_at(p, cfg, env, bg, rows, cols, idx, thick)
    assert set(many) == ({"front", "rear", "background"})
    for g, d in enumerate(thick):
        _, terms = _terms(dataclasses.replace(p, thickness=jnp.float32(d)), cfg, env, bg)
        for name, v in terms.items():
            want = np.asarray(v).reshape(-1, 3)[pixels]
            got = np.asarray(many[name][g])[:npix]
            np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-6 * float(np.abs(want).max()), err_msg=name)
    front = np.asarray(many["front"])[:, :npix]
    assert np.abs(front[1] - front[2]).max() > 0.05 * np.abs(front).max()  # the thickness matters


def test_front_hits_of_an_orthographic_camera_are_its_disc_in_closed_form():
    """Each pixel centre ``(x, y)`` in units of the disc's radius (row-major) hits the
    unit sphere iff ``x^2 + y^2 < 1``, at the front point ``(x, y, sqrt(1 - x^2 - y^2))``
    whose normal's cosine with the view is that height (float64 here, independently of the
    renderer's rays). Every disc of a size is one compiled program: a fit's levels and
    each photo's own disc reuse it."""
    from bubblefit.model.geometry import _front_hits, front_hits

    rng = np.random.default_rng(3)
    compiled = _front_hits._cache_size()
    for _ in range(4):
        cx, cy, r = rng.uniform(8.0, 24.0), rng.uniform(6.0, 18.0), rng.uniform(3.0, 15.0)
        inside, cos, local0 = (np.asarray(v) for v in front_hits(OrthographicCamera(31, 23, cx, cy, r),
                                                                  (0.0, 0.0, 0.0), 1.0))
        rows, cols = np.divmod(np.arange(31 * 23), 31)
        x, y = (cols + 0.5 - cx) / r, -(rows + 0.5 - cy) / r
        rho2 = x * x + y * y
        clear = np.abs(rho2 - 1.0) > 1e-5  # pixel centres on the rim itself: either answer
        np.testing.assert_array_equal(inside[clear], (rho2 < 1.0)[clear])
        hit = inside & (rho2 < 1.0 - 1e-3)
        np.testing.assert_allclose(cos[hit], np.sqrt(1.0 - rho2[hit]), atol=2e-5)
        np.testing.assert_allclose(local0[hit], np.stack([x, y, np.sqrt(np.maximum(1.0 - rho2, 0.0))], -1)[hit], atol=2e-5)
        assert np.all(cos[~inside] == 0.0)
    assert _front_hits._cache_size() <= compiled + 1
