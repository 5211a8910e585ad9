"""The view a photo was taken with (bubblefit.capture.view): fields of view from focal
lengths and EXIF, and the perspective camera the disc fixes, against an independent
pinhole projection of a sphere."""

from __future__ import annotations

import collections
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bubblefit.capture import view as V
from bubblefit.errors import InputError

DATA = Path(__file__).resolve().parents[1] / "experiments" / "validation" / "data"


def _outline(center, radius, width, height, fov_deg, n=2000):
    """Pixel coordinates of a sphere's outline through a pinhole at the origin looking
    along -z (up +y): the generators of the cone tangent to the sphere, projected with
    x_px = W/2 + f X/(-Z), y_px = H/2 - f Y/(-Z). Written from the cone, not the module."""
    c = np.asarray(center, float)
    dist = np.linalg.norm(c)
    u = c / dist
    alpha = math.asin(radius / dist)
    p = np.cross(u, [0.0, 1.0, 0.0])
    p /= np.linalg.norm(p)
    q = np.cross(u, p)
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = math.cos(alpha) * u + math.sin(alpha) * (np.cos(phi)[:, None] * p + np.sin(phi)[:, None] * q)
    f = width / (2 * math.tan(math.radians(fov_deg) / 2))
    return width / 2 + f * v[:, 0] / -v[:, 2], height / 2 - f * v[:, 1] / -v[:, 2]


def _kasa(x, y):
    """Least-squares circle (Kasa 1976): x^2 + y^2 = 2 cx x + 2 cy y + k."""
    A = np.stack([2 * x, 2 * y, np.ones_like(x)], axis=1)
    (cx, cy, k), *_ = np.linalg.lstsq(A, x * x + y * y, rcond=None)
    return cx, cy, math.sqrt(k + cx * cx + cy * cy)


@pytest.mark.parametrize("center,fov", [((0.0, 0.0, -4.0), 40.0), ((1.1, -0.7, -5.0), 40.0),
                                        ((2.5, 1.2, -9.0), 60.0), ((-0.3, 0.2, -20.0), 12.0)])
def test_camera_from_disc_matches_a_pinhole_projection(center, fov):
    """The camera built from the outline's fitted circle puts the sphere where it was:
    distance within 0.05 % (the circle stands for an ellipse whose axes differ by up to
    sin^2(theta)/2 = 5 % here: the correction leaves its square), direction within 0.01 deg."""
    W, H = 320, 240
    disc = _kasa(*_outline(center, 1.0, W, H, fov))
    cam, sph, R = V.perspective_from_disc(disc, W, H, fov)
    o = np.asarray(cam.origin)
    rel = np.asarray(sph) - o  # the sphere's centre seen from the camera
    truth = np.asarray(center)
    assert np.linalg.norm(rel) == pytest.approx(np.linalg.norm(truth), rel=5e-4)
    cosang = rel @ truth / (np.linalg.norm(rel) * np.linalg.norm(truth))
    assert math.degrees(math.acos(min(1.0, cosang))) < 0.01
    # the camera's orientation is the map's frame: looking along -z, up +y
    _, fwd, right, up = cam.basis()
    np.testing.assert_allclose(fwd, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(up, [0, 1, 0], atol=1e-12)


def test_outline_axes_match_the_projected_cone():
    """outline_axes' closed forms against the sampled outline's extent along and across the
    radial direction."""
    W, H, fov = 400, 400, 50.0
    center = (2.0, 0.0, -6.0)  # off-axis along +x: the radial direction is the image's x
    x, y = _outline(center, 1.0, W, H, fov, n=20000)
    f = W / (2 * math.tan(math.radians(fov) / 2))
    dist = np.linalg.norm(center)
    theta, alpha = math.atan2(2.0, 6.0), math.asin(1.0 / dist)
    rho, a, b = V.outline_axes(theta, alpha, f)
    assert (x.max() + x.min()) / 2 - W / 2 == pytest.approx(rho, rel=1e-9)
    assert (x.max() - x.min()) / 2 == pytest.approx(a, rel=1e-9)
    assert (y.max() - y.min()) / 2 == pytest.approx(b, rel=1e-6)


def test_camera_of_a_validation_scene():
    """ref_const620_sunrise_persp: a 40 degree camera at (0, 0, 4) seeing a unit sphere at the
    origin (its scene file); the disc of its truth gives that camera back."""
    case = DATA / "ref_const620_sunrise_persp"
    truth = json.loads((case / "truth.json").read_text())
    d, cam = truth["disc"], truth["camera"]
    got, _, _ = V.perspective_from_disc((d["cx"], d["cy"], d["r"]), cam["width"], cam["height"], cam["fov_deg"])
    np.testing.assert_allclose(got.origin, cam["origin"], atol=0.02)


def test_field_of_view_from_focal_lengths():
    # a 50 mm lens on a 36 mm wide sensor: 2 atan(18/50) = 39.60 degrees
    assert V.fov_from_focal(50.0, 36.0) == pytest.approx(39.5978, abs=1e-3)
    # 35 mm terms on a 3:2 frame are the full frame's width: the same angle
    assert V.fov_from_35mm(50.0, 3000, 2000) == pytest.approx(V.fov_from_focal(50.0, 36.0), rel=1e-3)
    # a square photo is narrower across its width than the 3:2 frame of the same diagonal
    assert V.fov_from_35mm(50.0, 1000, 1000) < V.fov_from_35mm(50.0, 3000, 2000)


def test_view_sources():
    assert V.resolve_view(fov_deg=12.0, width=100, height=100).to_json() == {
        "kind": "perspective", "fov_deg": 12.0, "source": "option", "detail": "--fov 12"}
    assert V.resolve_view(fov_deg=0.0, width=100, height=100).kind == "orthographic"
    v = V.resolve_view(focal_length_mm=25.0, sensor_width_mm=23.5, width=100, height=100)
    assert v.fov_deg == pytest.approx(math.degrees(2 * math.atan(23.5 / 50.0)))
    exif = {"Exif:FocalLength": 4.2, "Exif:FocalLengthIn35mmFilm": 26}
    assert V.resolve_view(metadata=exif, width=4032, height=3024).fov_deg == pytest.approx(
        V.fov_from_35mm(26.0, 4032, 3024))
    # focal length with the focal plane's resolution: 6000 px at 4000 px/inch = 38.1 mm
    exif = {"Exif:FocalLength": 50.0, "Exif:FocalPlaneXResolution": 4000.0, "Exif:FocalPlaneResolutionUnit": 2,
            "Exif:PixelXDimension": 6000}
    assert V.resolve_view(metadata=exif, width=600, height=400).fov_deg == pytest.approx(
        V.fov_from_focal(50.0, 38.1))
    assert V.resolve_view(fov_deg=30.0, metadata=exif, width=600, height=400).source == "option"
    assert V.resolve_view(metadata={"Exif:FocalLength": 50.0}, width=6, height=4).source == "assumed"
    for bad in (dict(fov_deg=10.0, focal_length_35mm=50.0), dict(focal_length_mm=50.0),
                dict(sensor_width_mm=36.0), dict(fov_deg=190.0), dict(fov_deg=-3.0)):
        with pytest.raises(InputError):
            V.resolve_view(width=100, height=100, **bad)


def _result(params, stderr, converged=True):
    from bubblefit.inverse import FitResult

    z = np.zeros((2, 2, 3))
    return FitResult(params=dict(params), stderr=dict(stderr), held=[], converged=converged, message="",
                     iterations=1, residual_rms=0.0, time_s=0.0, effects=[], render=z, residual=z,
                     names=("thickness_nm",), covariance=np.array([[stderr["thickness_nm"] ** 2]]),
                     camera={"kind": "orthographic", "fov_deg": None, "source": "assumed", "detail": ""})


def test_an_assumed_view_widens_each_error_by_the_lens_shift():
    """|Delta|/sqrt(3) in quadrature (GUM 4.3.7): a 12 nm shift on a 2 nm error gives
    sqrt(4 + 48) nm; the covariance's diagonal agrees; the warning names the shift."""
    from bubblefit.inverse import widen_for_view

    ortho = _result({"thickness_nm": 612.0, "exposure": 1.2}, {"thickness_nm": 2.0, "exposure": 0.01})
    lens_fit = _result({"thickness_nm": 600.0, "exposure": 1.2}, {"thickness_nm": 2.0, "exposure": 0.01})
    out = widen_for_view(ortho, lens_fit, V.assumed_lens(160, 160))
    assert out.stderr["thickness_nm"] == pytest.approx(math.sqrt(4.0 + 144.0 / 3.0))
    assert out.stderr["exposure"] == pytest.approx(0.01)
    assert out.covariance[0, 0] == pytest.approx(out.stderr["thickness_nm"] ** 2)
    assert out.params == ortho.params and ortho.stderr["thickness_nm"] == 2.0  # the input is not changed
    assert out.camera["source"] == "assumed" and out.camera["view_uncertainty"]["thickness_nm"] == pytest.approx(
        12.0 / math.sqrt(3.0))
    assert any("thickness_nm by 12" in w and "fitted as orthographic" in w for w in out.warnings), out.warnings
    failed = widen_for_view(ortho, _result(lens_fit.params, lens_fit.stderr, converged=False),
                            V.assumed_lens(160, 160))
    assert failed.stderr == ortho.stderr and any("did not converge" in w for w in failed.warnings)


def test_a_lens_that_explains_the_photo_better_is_kept_and_widened():
    from bubblefit.inverse import widen_for_view

    lens = V.assumed_lens(160, 160)
    ortho = _result({"thickness_nm": 612.0}, {"thickness_nm": 2.0})
    kept = _result({"thickness_nm": 603.0}, {"thickness_nm": 1.5})
    kept.camera = lens.to_json()
    out = widen_for_view(kept, ortho, lens)
    assert out.params["thickness_nm"] == 603.0 and out.camera["kind"] == "perspective"
    assert out.stderr["thickness_nm"] == pytest.approx(math.hypot(1.5, 9.0 / math.sqrt(3.0)))
    assert any("kept the perspective view" in w for w in out.warnings), out.warnings


def test_fit_view_prefers_the_scene_and_refuses_a_contradiction():
    from bubblefit.inverse import FitOptions
    from bubblefit.inverse import fit_view
    from bubblefit.model.scene import Scene

    persp = Scene.from_dict({"camera": {"type": "perspective", "width": 64, "height": 48, "fov_deg": 40.0}})
    assert fit_view(FitOptions(), persp).to_json()["source"] == "scene"
    assert fit_view(FitOptions(), None).source == "assumed"
    exif = V.View("perspective", 30.0, "EXIF")
    assert fit_view(FitOptions(view=exif), persp).fov_deg == 40.0  # the scene over the EXIF
    with pytest.raises(InputError, match="given twice"):
        fit_view(FitOptions(view=V.View("perspective", 30.0, "option")), persp)


def _binned_copy(case: str, dest: Path) -> Path:
    """A copy of a validation case's photo and background binned 2x2 (each pixel the mean
    of four in linear light, re-encoded as 8-bit sRGB; a block with a saturated pixel
    stays saturated), in ``dest``: the same scene through the same view at half the
    pixels across, which leaves the field of view (an angle) and the disc's place as
    fractions of the width unchanged."""
    from bubblefit.io.images import read_image, write_image

    dest.mkdir(parents=True, exist_ok=True)
    for name in ("photo.png", "background.png"):
        img = read_image(DATA / case / name)
        p = img.pixels
        h, w, c = p.shape
        b = p[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2, c).mean(axis=(1, 3))
        sat = img.saturated[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2).any(axis=(1, 3))
        b[sat] = 1.0
        write_image(dest / name, b)
    return dest


def _fit_cli(tmp_path, case, *flags, binned=False):
    """``bubblefit fit`` of a validation case in a subprocess (``binned``: its 2x2-binned
    copy, :func:`_binned_copy`); its JSON."""
    import subprocess
    import sys

    d = DATA / case
    truth = json.loads((d / "truth.json").read_text())
    if binned:
        d = _binned_copy(case, tmp_path / f"{case}_binned")
    out = tmp_path / f"{case}{'_'.join(flags)}.json"
    args = [sys.executable, "-m", "bubblefit", "fit", str(d / "photo.png"), "--envmap", str(DATA / truth["envmap"]),
            "--background", str(d / "background.png"), "--json", str(out), *flags]
    if truth["thickness"]["profile"] != "constant":
        args += ["--thickness", "drainage"]
    proc = subprocess.run(args, capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, proc.stderr
    return truth, json.loads(out.read_text())


@pytest.mark.slow
def test_a_perspective_photo_without_its_view(tmp_path):
    """ref_const620_sunrise_persp (an independent spectral renderer, a 40 degree pinhole,
    8-bit sRGB), binned 2x2 to 88x72 (both photo and background: a copy in tmp_path) to
    keep the test short, fitted by the command line with nothing about the view: the
    view's divergence is fitted and its field of view covers 40 degrees within 3 of its
    standard errors (or, where the photo does not fix it, the view is assumed, compared
    with a lens, and said so), and the thickness covers the truth within 3 of its
    standard errors, which include what the view changes. A fitted view renders through
    a pinhole as ``--fov`` does (``View("perspective", fov)``, the camera from the disc:
    :func:`test_camera_of_a_validation_scene`, :func:`test_view_sources`).

    The physical model is named (``--model physical``): ``auto`` keeps it on this photo
    (the paper model's reduced chi^2 3.61 against 1.07,
    experiments/results/auto_kept_model_validation.json), and named it is the one model
    solved through each view instead of both; ``auto``'s choice is tested on the validation
    cases (tests/test_validation.py)."""
    truth, unknown = _fit_cli(tmp_path, "ref_const620_sunrise_persp", "--model", "physical", binned=True)
    true_nm = truth["thickness"]["thickness_nm"]
    cam = unknown["camera"]
    assert any("view was not given" in w for w in unknown["warnings"]), unknown["warnings"]
    assert cam["source"] in ("fitted", "assumed") and len(cam["divergence_profile"]) >= 3, cam
    if cam["source"] == "fitted":
        assert cam["kind"] == "perspective" and abs(cam["fitted_fov_deg"] - 40.0) < 3 * cam["fov_stderr_deg"], cam
        assert "fov_deg" in unknown["covariance"]["names"], unknown["covariance"]
    else:
        assert cam["compared_fov_deg"] > 30, cam
    err = abs(unknown["params"]["thickness_nm"] - true_nm)
    assert err < 3 * unknown["stderr"]["thickness_nm"], (unknown["params"], unknown["stderr"], cam)


@pytest.mark.slow
def test_the_python_default_fits_as_the_command_line(tmp_path, small_courtyard):
    """FitOptions() and ``bubblefit fit`` choose the same model (auto) and so the same result
    on the same photo (8-bit sRGB, read back as the command line reads it)."""
    import test_fit as tf

    from bubblefit.cli import main
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.io.images import read_image, write_image

    env = tf._env(small_courtyard)
    rng = np.random.default_rng(5)
    bg = tf._background(rng)
    photo = tf._quantise(tf._render(env, bg, {"t": 0.97, "roughness": 0.08, "thickness_nm": 420.0}), rng)
    write_image(tmp_path / "photo.png", photo)
    write_image(tmp_path / "before.png", bg)
    write_image(tmp_path / "env.exr", small_courtyard, bit_depth=32)
    disc = ",".join(str(v) for v in tf.DISC)
    assert main(["fit", str(tmp_path / "photo.png"), "--envmap", str(tmp_path / "env.exr"), "--background",
                 str(tmp_path / "before.png"), "--disc", disc, "--fov", "0", "--json", str(tmp_path / "fit.json")]) == 0
    cli = json.loads((tmp_path / "fit.json").read_text())
    img = read_image(tmp_path / "photo.png", dtype=np.float32)
    py = fit_photo(img.pixels, env, options=FitOptions(disc=tf.DISC, view=V.ORTHOGRAPHIC),
                   background=read_image(tmp_path / "before.png", dtype=np.float32).pixels, saturated=img.saturated)
    assert FitOptions().model == "auto" and py.model == cli["model"]
    assert abs(py.params["thickness_nm"] - cli["params"]["thickness_nm"]) < 0.01 * cli["stderr"]["thickness_nm"]


@pytest.mark.parametrize("disc", [(24.0, 24.0, 20.0), (30.5, 19.0, 14.0)])
def test_the_divergence_parametrisation_is_smooth_through_orthographic(disc):
    """u = tan(fov/2) -> rays (capture.view.divergent_rays): at u = 0 the orthographic
    camera's rays; for u > 0 the rays of perspective_from_disc's pinhole (same directions,
    each origin on its ray); continuous (a step of 1e-4 in u moves a ray by O(1e-4), in
    float64) with a finite derivative at u = 0 that agrees with a one-sided difference."""
    import jax
    import jax.numpy as jnp

    from bubblefit.model.geometry import OrthographicCamera

    jax.config.update("jax_enable_x64", True)
    try:
        W, H = 48, 40
        rows, cols = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
        o0, d0 = V.divergent_rays(0.0, disc, W, H, rows, cols, xp=np)
        oo, do = OrthographicCamera(W, H, *disc).rays(jnp.asarray(rows), jnp.asarray(cols), (0.0, 0.0, 0.0), 1.0)
        np.testing.assert_allclose(d0, np.broadcast_to(np.asarray(do), d0.shape), atol=1e-12)
        np.testing.assert_allclose(o0, np.asarray(oo), atol=1e-9)
        for fov in (12.0, 34.0, 60.0):
            u = V.divergence(fov)
            assert V.fov_of_divergence(u) == pytest.approx(fov)
            o, d = V.divergent_rays(u, disc, W, H, rows, cols, xp=np)
            cam, _, _ = V.perspective_from_disc(disc, W, H, fov)
            po, pd = cam.rays(jnp.asarray(rows), jnp.asarray(cols))
            np.testing.assert_allclose(d, np.asarray(pd), atol=1e-9)
            # the origin lies on the pinhole's ray: (o - pinhole) parallel to d
            rel = o - np.asarray(po)
            np.testing.assert_allclose(np.cross(rel, d), 0.0, atol=1e-7 * np.linalg.norm(cam.origin))
        f = lambda u: jnp.concatenate([a.ravel() for a in V.divergent_rays(u, disc, W, H, rows, cols)])
        jac = np.asarray(jax.jacfwd(f)(0.0))
        assert np.all(np.isfinite(jac)) and np.abs(jac).max() > 0
        h = 1e-5
        np.testing.assert_allclose((np.asarray(f(h)) - np.asarray(f(0.0))) / h, jac, atol=1e-3 * max(1, np.abs(jac).max()))
        assert np.abs(np.asarray(f(1e-4)) - np.asarray(f(0.0))).max() < 2e-4 * max(1.0, np.abs(jac).max())
    finally:
        jax.config.update("jax_enable_x64", False)


@pytest.mark.parametrize("disc", [(16.0, 12.0, 9.0), (19.5, 10.0, 7.0)])
def test_a_traced_view_renders_as_the_pinhole_of_that_view(x64, small_courtyard, disc):
    """DivergentCamera with the view's divergence as data (Params.view) renders what the
    pinhole perspective_from_disc builds for the same field of view renders, through one
    compiled program for every view. Both trace the same ray directions and their origins
    lie on the same rays (4 radii from the closest approach, or at the pinhole up to
    1/sin(alpha) ~ 10 radii away): in float64 a hit's incidence cosine is rounded to
    ~eps D^2 / cos ~ 1e-12 at the smallest cosine kept (0.01; nearer the outline
    ``d cos / d x`` grows without bound), and the images agree to 1e-9 of their largest
    value. (In float32 the pinhole's own rounding, eps D^2 / cos ~ 3e-5 in the cosine at
    20 degrees, moves a film's colour by ~1e-4.)"""
    import jax.numpy as jnp

    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.model.effects import Effects
    from bubblefit.model.geometry import DivergentCamera, front_hits
    from bubblefit.model.render import Params, RenderConfig, render
    from bubblefit.optics.spectral import spectral_basis

    W, H = 32, 24
    env = EnvMap.from_array(small_courtyard, dtype=jnp.float64)
    fx = Effects(model="physical", interference="airy", spectral=spectral_basis("harmonic", 8), bounces=1)
    div = RenderConfig(effects=fx, camera=DivergentCamera(W, H, *disc), chunk=256, pixel_footprint=False)
    params = lambda u: Params.make(roughness=0.05, thickness=640.0, view=u, dtype=jnp.float64)
    before = render._cache_size()
    for i, fov in enumerate((20.0, 40.0, 67.6)):
        u = V.divergence(fov)
        cam, center, radius = V.perspective_from_disc(disc, W, H, fov)
        pin = RenderConfig(effects=fx, camera=cam, center=center, radius=radius, chunk=256, pixel_footprint=False)
        got = np.asarray(render(params(u), div, env))
        if i == 0:
            compiled = render._cache_size()
        want = np.asarray(render(params(0.0), pin, env))
        cos = np.asarray(front_hits(cam, center, radius)[1]).reshape(H, W)
        keep = (cos > 1e-2) | (cos == 0)
        assert 0 < np.count_nonzero(cos) < W * H
        np.testing.assert_allclose(got[keep], want[keep], atol=1e-9 * want.max(), rtol=0)
    assert compiled == before + 1
    # one program for every view of the divergent camera, one per pinhole
    assert render._cache_size() == compiled + 3


def test_a_traced_view_hits_and_traces_as_the_pinhole_of_that_view(small_courtyard):
    """front_hits and the effect footprint's trace (model.footprint) take a divergent
    camera's view as data: at 20, 40 and 67.6 degrees their hits are the pinhole's
    (float32: the pinhole's hit rounds ``b^2 - |o|^2 + 1`` at ``|o|^2 = D^2``, D up to 10
    radii, so the incidence cosines agree to a few eps D^2 / cos; which pixels hit may
    differ only where the ray grazes, cos < 1e-2), through one program each for every view."""
    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.model import geometry as G
    from bubblefit.model.footprint import footprint, jitted_trace

    W, H, disc = 32, 24, (16.0, 12.0, 9.0)
    cam = G.DivergentCamera(W, H, *disc)
    env = EnvMap.from_array(small_courtyard)
    common = dict(model="physical", roughness=0.05, env=env, rotation=0.0, lights=(), background=None,
                  background_kind="envmap", thickness_kind="constant", thickness_values=640.0)
    sizes = []
    for fov in (20.0, 40.0, 67.6):
        u = V.divergence(fov)
        pin, center, radius = V.perspective_from_disc(disc, W, H, fov)
        got = [np.asarray(a) for a in G.front_hits(cam, center, radius, u)]
        want = [np.asarray(a) for a in G.front_hits(pin, center, radius)]
        graze = np.minimum(got[1], want[1]) < 1e-2
        assert np.all((got[0] == want[0]) | graze) and got[0].sum() > 0
        far = ~graze & got[0]
        bound = 16 * np.finfo(np.float32).eps * np.dot(pin.origin, pin.origin) / want[1][far]
        assert np.all(np.abs(got[1][far] - want[1][far]) <= bound)
        fp = footprint(camera=cam, center=center, radius=radius, view=u, **common)
        fq = footprint(camera=pin, center=center, radius=radius, **common)
        both = np.intersect1d(fp.pixels, fq.pixels)
        a, b = fp.cos[np.searchsorted(fp.pixels, both)], fq.cos[np.searchsorted(fq.pixels, both)]
        ok = np.minimum(a, b) > 1e-2
        assert np.all(np.abs(a[ok] - b[ok]) <= 16 * np.finfo(np.float32).eps * np.dot(pin.origin, pin.origin) / b[ok])
        sizes.append(G._front_hits._cache_size())
    # the pinholes compile a program each; the divergent camera's is the first view's
    assert sizes[2] - sizes[0] == 2
    trace = jitted_trace(cam, (0.0, 0.0, 0.0), 1.0, "physical", (), "envmap", "constant")
    assert trace._cache_size() == 1


def test_a_traced_view_renders_by_regions(small_courtyard):
    """model.regions through a divergent camera: the plan's image at a view (the bubble's
    pixels through that view, shaded from the footprint traced through it, or traced
    afresh) is the whole-image render at that view: traced, to rtol 2e-5 (the same float32
    values, summed in other chunks); shaded from the footprint, whose rays another program
    traced, to 1e-4 of the image's largest value (a few float32 ulps in a hit's cosine,
    times ``d colour / d cos``, which grows as 1 / cos toward the outline). A footprint
    traced through another view is not used."""
    import jax.numpy as jnp

    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.model.effects import Effects
    from bubblefit.model.footprint import footprint
    from bubblefit.model.geometry import DivergentCamera
    from bubblefit.model.regions import lit_usable, render_plan
    from bubblefit.model.render import Params, RenderConfig, render
    from bubblefit.optics.spectral import spectral_basis

    W, H, disc = 32, 24, (16.0, 12.0, 9.0)
    env = EnvMap.from_array(small_courtyard)
    fx = Effects(model="physical", interference="airy", spectral=spectral_basis("harmonic", 8), bounces=1)
    cfg = RenderConfig(effects=fx, camera=DivergentCamera(W, H, *disc), chunk=256, pixel_footprint=False)
    fps = {}
    for fov in (20.0, 67.6):
        u = V.divergence(fov)
        p = Params.make(roughness=0.05, thickness=640.0, view=u)
        fps[fov] = footprint(camera=cfg.camera, center=(0.0, 0.0, 0.0), radius=1.0, model="physical", roughness=0.05,
                             env=env, rotation=0.0, lights=(), background=None, background_kind="envmap",
                             thickness_kind="constant", thickness_values=np.float32(640.0), view=u)
        assert lit_usable(fps[fov], p, cfg)
        whole = np.asarray(render(p, cfg, env))
        np.testing.assert_allclose(render_plan(p, [(cfg, None)], env), whole, rtol=2e-5, atol=2e-6)
        lit = render_plan(p, [(cfg, None)], env, footprint=fps[fov])
        np.testing.assert_allclose(lit, whole, rtol=0, atol=1e-4 * whole.max())
    assert not lit_usable(fps[20.0], Params.make(roughness=0.05, thickness=640.0, view=V.divergence(67.6)), cfg)


def test_a_divergent_cameras_record_gives_the_pinholes_distance():
    """camera_record of a DivergentCamera at a view: the distance (sphere radii) of the
    pinhole perspective_from_disc places for that view (to float64 rounding)."""
    from bubblefit.inverse._view import camera_record
    from bubblefit.model.geometry import DivergentCamera

    for disc, fov in [((16.0, 12.0, 9.0), 20.0), ((30.5, 19.0, 14.0), 67.6)]:
        pin, _, _ = V.perspective_from_disc(disc, 48, 40, fov)
        view = V.View("perspective", fov, "fitted")
        got = camera_record(view, DivergentCamera(48, 40, *disc))["distance_radii"]
        assert got == pytest.approx(camera_record(view, pin)["distance_radii"], rel=1e-12)


def _profiled(u0, s, slope, n_pix=400, quartic=None, map_slope=None, linear_below=None):
    """A refit through a view of divergence u whose total chi^2 is the parabola
    nu + ((u - u0)/s)^2 (plus ((u - u0)/quartic)^4 when given) and whose thickness moves
    by ``slope`` per unit u (nm): what fit_divergence sees from a photo that fixes the
    view to s. With ``linear_below`` (w) the parabola is continued below u0 - w by its
    tangent there (the same value and slope: a profile that rises more slowly toward
    parallel rays than toward wide lenses). With ``map_slope`` (a 2x2 array, nm per unit
    u) each refit carries a thickness map moving by it and a map of 2 nm errors."""
    from dataclasses import replace

    nu = 3 * n_pix - 1

    def excess(u):
        if linear_below is not None and u < u0 - linear_below:
            w = linear_below
            return (w * w + 2 * w * (u0 - w - u)) / s**2
        return ((u - u0) / s) ** 2 + (((u - u0) / quartic) ** 4 if quartic else 0.0)

    def at(u):
        r = _result({"thickness_nm": 600.0 + slope * u}, {"thickness_nm": 2.0})
        chi2 = nu + excess(u) if s else float(nu)
        r = replace(r, chi2_capped=chi2 / nu, pixels_used=n_pix, status="ok")
        if map_slope is not None:
            r = replace(r, thickness_map=600.0 + map_slope * u, thickness_stderr_map=np.full((2, 2), 2.0))
        return r

    return at


def _divergence_fit(at, lens):
    """fit_divergence of the profile ``at`` (:func:`_profiled`) bracketed by ``lens``; the
    result and the divergences it refitted at, in order."""
    from bubblefit.inverse import fit_divergence

    tried = []

    def refit(view, start):
        tried.append(V.divergence(view.fov_deg))
        return at(tried[-1])

    return fit_divergence(at(0.0), at(V.divergence(lens.fov_deg)), lens, refit), tried


def test_a_photo_that_fixes_the_view_gets_its_divergence_fitted():
    """A chi^2 profile exact in u = tan(fov/2): the minimum and its standard error
    (Delta chi^2 = 1: the parabola's reduced chi^2 is 1 at its minimum) come back from the
    bracket and the refits about its minimum (one reused: it lies within a quarter of a
    standard error of the first interval's end); the thickness's error gains
    (dp/du)^2 var(u), per pixel for the map; the covariance holds the view; the record
    says fitted."""
    from bubblefit.inverse import fit_divergence

    slope_map = np.array([[50.0, -20.0], [0.0, 80.0]])
    at = _profiled(0.12, 0.03, 50.0, map_slope=slope_map)
    lens = V.assumed_lens(48, 48)
    tried = []

    def refit(view, start):
        tried.append(view.fov_deg)
        assert view.source == "fitted" and "thickness_nm" in start
        return at(V.divergence(view.fov_deg))

    out = fit_divergence(at(0.0), at(V.divergence(lens.fov_deg)), lens, refit)
    cam = out.camera
    assert cam["source"] == "fitted" and cam["kind"] == "perspective"
    assert cam["fitted_fov_deg"] == pytest.approx(V.fov_of_divergence(0.12), rel=1e-6)
    se_u = 0.03
    dfov = math.degrees(2 / (1 + 0.12**2))
    assert cam["fov_stderr_deg"] == pytest.approx(dfov * se_u, rel=1e-6)
    assert cam["fov_interval_deg"] == pytest.approx([V.fov_of_divergence(0.09), V.fov_of_divergence(0.15)], rel=1e-6)
    assert out.params["thickness_nm"] == pytest.approx(600.0 + 50.0 * 0.12)
    assert out.stderr["thickness_nm"] == pytest.approx(math.hypot(2.0, 50.0 * se_u), rel=1e-6)
    np.testing.assert_allclose(out.thickness_stderr_map, np.hypot(2.0, slope_map * se_u), rtol=1e-6)
    assert out.names == ("thickness_nm", "fov_deg") and out.covariance.shape == (2, 2)
    assert out.covariance[0, 1] == pytest.approx(50.0 * se_u**2 * dfov, rel=1e-6)
    # the half lens, the first minimum and the far end of its interval (the near end is the half lens's refit)
    assert len(tried) == 3 and any("divergence fitted" in w for w in out.warnings), (tried, out.warnings)


def test_near_parallel_rays_the_orthographic_fit_stands_for_the_intervals_near_end():
    """A minimum a third of a standard error above u = 0: the refit at the interval's near
    end (below 0) is the orthographic fit's, the parabola through u = 0 and the refits
    about the minimum is still the exact profile, and the interval stops at parallel rays."""

    at = _profiled(0.01, 0.03, 50.0)
    lens = V.assumed_lens(48, 48)
    out, tried = _divergence_fit(at, lens)
    cam = out.camera
    assert cam["source"] == "fitted" and all(u > 0 for u in tried), tried
    assert V.divergence(cam["fitted_fov_deg"]) == pytest.approx(0.01, rel=1e-6)
    assert cam["fov_stderr_deg"] == pytest.approx(math.degrees(2 / (1 + 0.01**2)) * 0.03, rel=1e-6)
    assert cam["fov_interval_deg"][0] == 0.0
    assert out.stderr["thickness_nm"] == pytest.approx(math.hypot(2.0, 50.0 * 0.03), rel=1e-6)


def test_the_standard_error_is_the_profiles_curvature_near_its_minimum():
    """A profile steeper away from its minimum than near it (a quartic term, 1 % of the
    quadratic one at two standard errors, 87 % at the bracket's far point): the parabola
    through the bracket overstates the curvature, the refits near the minimum do not.
    Through points within 2 s of the minimum the quartic adds at most 6 (2 s)^2 / q^4 to
    the parabola's leading coefficient 1/s^2 (the second divided difference of x^4 is
    x1^2 + x2^2 + x3^2 + x1 x2 + x1 x3 + x2 x3), so the error lies within
    [s / sqrt(1.06), s], widened by the Birge ratio of the refit at the minimum."""
    from bubblefit.inverse import divergence_profile

    s, u0 = 0.01, 0.12
    q = s * 400**0.25  # (x/q)^4 = 0.01 (x/s)^2 at x = 2 s
    at = _profiled(u0, s, 50.0, quartic=q)
    lens = V.assumed_lens(48, 48)
    u_lens = V.divergence(lens.fov_deg)
    out, tried = _divergence_fit(at, lens)
    bracket = [0.0, u_lens / 2, u_lens]
    coarse = divergence_profile(bracket, [at(u).chi2_capped * (3 * 400 - 1) for u in bracket])
    se = out.camera["fov_stderr_deg"] / math.degrees(2 / (1 + V.divergence(out.camera["fitted_fov_deg"]) ** 2))
    near = [u for u in tried if abs(u - u0) <= 2 * s]
    birge = math.sqrt(min(at(u).chi2_capped for u in near))
    assert len(near) >= 2, tried
    assert s / math.sqrt(1.06) * (1 - 1e-6) <= se <= s * birge * (1 + 1e-6), (se, tried)
    assert coarse.stderr < s / 1.2, coarse  # what the bracket alone would have said
    assert abs(V.divergence(out.camera["fitted_fov_deg"]) - u0) < 0.25 * s


def test_a_flat_profile_falls_back_to_the_widened_errors():
    """chi^2 the same through every view: the photo does not fix it, so the better of the
    orthographic and lens fits is kept, widened by their shift (GUM 4.3.7), and the
    warning says the photo does not fix the view."""
    from bubblefit.inverse import fit_divergence

    at = _profiled(0.0, 0.0, 30.0)
    lens = V.assumed_lens(48, 48)
    u_lens = V.divergence(lens.fov_deg)
    out = fit_divergence(at(0.0), at(u_lens), lens, lambda view, start: at(V.divergence(view.fov_deg)))
    assert out.camera["source"] == "assumed" and "divergence_profile" in out.camera
    assert out.stderr["thickness_nm"] == pytest.approx(math.hypot(2.0, 30.0 * u_lens / math.sqrt(3.0)))
    assert any("does not fix the view" in w for w in out.warnings), out.warnings


def _vertex(p0, p1, p2):
    """The abscissa of the parabola through three points (Numerical Recipes eq. 10.3.1),
    and its leading coefficient (the second divided difference)."""
    (a, fa), (b, fb), (c, fc) = p0, p1, p2
    x = b - 0.5 * ((b - a) ** 2 * (fb - fc) - (b - c) ** 2 * (fb - fa)) / ((b - a) * (fb - fc) - (b - c) * (fb - fa))
    return x, ((fc - fb) / (c - b) - (fb - fa) / (b - a)) / (c - a)


def test_the_parabola_goes_through_the_least_point_and_its_neighbours():
    """The views tried on a development photo fitted without its view
    (ref_const620_sunrise_persp, 40 degrees): capped reduced chi^2 2.16, 1.34, 0.48, 2.49
    at 0, 19.0, 37.0 and 67.6 degrees. The three lowest (0, 19, 37) have their least at
    their end; the least (37) and its neighbours in u (19, 67.6) bracket a minimum, which
    the parabola through them gives with Delta chi^2 = 1 (the reduced chi^2 is below 1
    there, so no Birge ratio), in whatever order the points come."""
    from bubblefit.inverse import divergence_profile

    dof = 3 * 20000  # reduced x degrees of freedom (~the pixels in use): the minimum does not depend on it
    fovs, red = [67.6, 0.0, 37.0, 19.0], [2.49, 2.16, 0.48, 1.34]
    us = [V.divergence(f) for f in fovs]
    prof = divergence_profile(us, [r * dof for r in red])
    x, a = _vertex(*[(V.divergence(f), r * dof) for f, r in ((19.0, 1.34), (37.0, 0.48), (67.6, 2.49))])
    assert prof.constrained and not prof.above, prof
    assert sorted(prof.points) == pytest.approx(sorted(V.divergence(f) for f in (19.0, 37.0, 67.6)))
    assert V.divergence(19.0) < prof.u < V.divergence(67.6)
    assert prof.u == pytest.approx(x, rel=1e-9) and prof.stderr == pytest.approx(1 / math.sqrt(a), rel=1e-9)


def test_a_least_point_at_the_widest_view_is_not_bracketed():
    """The least chi^2 at the largest u tried: the parabola goes through it and its two
    lower neighbours, and the minimum is not bracketed whatever the parabola says (not
    constrained, ``above``). At u = 0 the orthographic boundary closes the bracket."""
    from bubblefit.inverse import divergence_profile

    us = [0.0, 0.1, 0.2, 0.3]
    prof = divergence_profile(us, [10.0, 6.0, 3.0, 2.9])  # convex, its vertex between 0.2 and 0.3
    assert not prof.constrained and prof.above and sorted(prof.points) == pytest.approx([0.1, 0.2, 0.3]), prof
    low = divergence_profile(us, [100.0, 400.0, 900.0, 1600.0])  # (100 (u + 0.1))^2: least at u = 0
    x, a = _vertex((0.0, 100.0), (0.1, 400.0), (0.2, 900.0))
    assert low.constrained and not low.above and low.u == 0.0 and x < 0, low
    assert low.stderr == pytest.approx(1 / math.sqrt(a), rel=1e-9)


def test_a_minimum_past_the_lens_steeper_above_than_below_is_fitted():
    """A profile exact as a parabola about 40 degrees (u0 = tan 20 deg) from u0 - 0.1 up,
    continued below by its tangent: on a 176x144 photo the bracket (0, 19.0, 37.0 and,
    as the lens's refit is the least, 67.6 degrees) has its three lowest at 0, 19 and 37,
    least at their end, as on the development photo. The least point (37) and its
    neighbours bracket the minimum; the refits about it lie in the parabolic part, so the
    fitted view and its standard error are the parabola's: u0 and s (Delta chi^2 = 1,
    the reduced chi^2 1 at the minimum)."""

    u0, s = V.divergence(40.0), 0.01
    at = _profiled(u0, s, 50.0, linear_below=0.1)
    lens = V.assumed_lens(176, 144)
    u_lens = V.divergence(lens.fov_deg)
    out, tried = _divergence_fit(at, lens)
    bracket = sorted([(at(u).chi2_capped, u) for u in (0.0, u_lens / 2, u_lens, tried[1])])
    assert [u for _, u in bracket[:3]] == [u_lens, u_lens / 2, 0.0], bracket  # the old reading's three
    assert all(u >= u0 - 0.1 for u in tried[2:]), tried
    cam = out.camera
    assert cam["source"] == "fitted", (cam, out.warnings)
    assert cam["fitted_fov_deg"] == pytest.approx(40.0, rel=1e-6)
    assert cam["fov_stderr_deg"] == pytest.approx(math.degrees(2 / (1 + u0**2)) * s, rel=1e-6)


def test_a_skewed_profile_is_minimised_to_its_minimum_and_curvature():
    """A profile that is a parabola only near its minimum: excess chi^2
    g(d) = k^2 tanh^2(d / k) in d = (u - u0) / s (k = 20 below the minimum, 40 above: it
    levels off, as the capped chi^2 does, at 400 and 1600, so the bracket's points, tens
    of s away, are far from a parabola and lopsided), plus a convergence noise of at most
    eps = 1e-3 on each refit's chi^2, on a photo that fixes the view to s = 0.002 (0.23
    degrees at 35). Near the minimum g = d^2 - (2/3) d^4 / k^2 + ..., so over the
    parabola's points (within 3 s of its minimum, the refit nearest within s / 4) its
    second divided difference lies within 1 -+ (36 / k^2 + delta), delta = 48 eps the
    noise's with the points s / 4 apart at the least, and the standard error within
    [s / sqrt(1 + delta), s / sqrt(1 - 36 / k^2 - delta)]; the vertex, where
    2 d + P(g - d^2)'(d) = 0, lies within (|g'| + 6 |g''| / 2 + delta) / 2 <= 0.41 s of
    the minimum (|g'| <= 8 d^3 / (3 k^2), |g''| / 2 <= 4 d^2 / k^2 at d = 3). The view
    reported is that vertex, not a refit's."""
    from dataclasses import replace

    u0, s, n_pix, eps = V.divergence(35.0), 0.002, 4000, 1e-3
    nu = 3 * n_pix - 1
    rng = np.random.default_rng(1)

    def at(u):
        d = (u - u0) / s
        k = 20.0 if d < 0 else 40.0
        chi2 = nu + k * k * math.tanh(d / k) ** 2 + rng.uniform(-eps, eps)
        r = _result({"thickness_nm": 850.0 + 40.0 * u}, {"thickness_nm": 0.6})
        return replace(r, chi2_capped=chi2 / nu, pixels_used=n_pix, status="ok")

    out, tried = _divergence_fit(at, V.assumed_lens(600, 400))
    cam = out.camera
    u = V.divergence(cam["fitted_fov_deg"])
    se = cam["fov_stderr_deg"] / math.degrees(2 / (1 + u * u))
    delta = 48 * eps
    assert cam["source"] == "fitted" and not any("did not converge" in w for w in out.warnings), out.warnings
    assert s / math.sqrt(1 + delta) <= se <= s / math.sqrt(1 - 36 / 20**2 - delta), (se / s, tried)
    assert abs(u - u0) <= 0.41 * s, ((u - u0) / s, tried)
    assert min(abs(t - u) for t in tried) <= 0.25 * se and len(tried) <= 3 + 13, tried
    assert out.params["thickness_nm"] == pytest.approx(850.0 + 40.0 * V.divergence(cam["refit_fov_deg"]))


def test_a_profile_that_does_not_settle_stops_at_the_cap_and_says_so():
    """A profile whose minimum jumps by 0.8 s further each refit (a parabola about
    u0 +- 0.8 s n at the n-th refit): no parabola's minimum ever gets a refit within
    s / 4 that agrees, so the refits stop at the cap (MAX_REFINE after the bracket's), a
    warning says the view's profile did not converge, and the view's standard error is at
    least the distance from the reported view to the kept refit's."""
    from dataclasses import replace

    from bubblefit.inverse._view import MAX_REFINE

    u0, s, n_pix = V.divergence(30.0), 0.005, 400
    nu = 3 * n_pix - 1
    calls = []

    def at(u):
        calls.append(u)
        c = u0 + 0.8 * s * len(calls) * (-1) ** len(calls)
        r = _result({"thickness_nm": 600.0 + 50.0 * u}, {"thickness_nm": 2.0})
        return replace(r, chi2_capped=(nu + ((u - c) / s) ** 2) / nu, pixels_used=n_pix, status="ok")

    out, tried = _divergence_fit(at, V.assumed_lens(48, 48))
    cam = out.camera
    assert len(tried) == 2 + MAX_REFINE and any("did not converge" in w for w in out.warnings), (tried, out.warnings)
    u, u_kept = V.divergence(cam["fitted_fov_deg"]), V.divergence(cam["refit_fov_deg"])
    assert cam["fov_stderr_deg"] >= math.degrees(2 / (1 + u * u)) * abs(u - u_kept) * (1 - 1e-9)


@pytest.mark.slow
def test_the_view_of_a_perspective_photo_is_fitted(small_courtyard):
    """A 48 px photo rendered by the package through a 25 degree pinhole (camera 4.6 radii
    away: the disc 0.42 of the width), with read and shot noise and 8-bit sRGB, fitted with
    no view stated: the fitted field of view covers 25 degrees within 3 of its standard
    errors, the thickness the truth within 3 of its, and the record says the view was
    fitted."""
    import test_fit as tf

    from bubblefit.inverse import FitOptions, fit_photo
    from bubblefit.model.scene import Scene, render_scene

    fov, N = 25.0, tf.N
    u = V.divergence(fov)
    dist = 1.0 / math.sin(math.atan(0.42 * N * 2 * u / N))  # the sphere subtends the disc's half-angle
    rng = np.random.default_rng(11)
    bg = tf._background(rng)
    scene = Scene.from_dict({"camera": {"type": "perspective", "width": N, "height": N, "origin": [0, 0, dist],
                                        "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": fov},
                             "bubble": {"thickness_nm": 520.0, "t": 0.97, "roughness": 0.06},
                             "lighting": {"envmap": "unused.exr"}, "effects": {"model": "paper",
                                                                               "transmission_tint": True}})
    env = tf._env(small_courtyard)
    photo = tf._quantise(np.asarray(render_scene(scene, bg, env=env)), rng)
    # on the axis the outline is the circle of radius f tan(alpha) = 0.42 N: the disc given
    out = fit_photo(photo, env, options=FitOptions(model="paper", disc=tf.DISC), background=bg)
    cam = out.camera
    assert cam["source"] == "fitted", (cam, out.warnings)
    assert abs(cam["fitted_fov_deg"] - fov) < 3 * cam["fov_stderr_deg"], cam
    assert abs(out.params["thickness_nm"] - 520.0) < 3 * out.stderr["thickness_nm"], (out.params, out.stderr)
    assert "fov_deg" in out.names and np.all(np.isfinite(out.covariance))


def _smoothed_noise(rng, h, w, kernel):
    """White noise of ``(h, w)`` convolved with ``kernel`` (no wrap: cut from a larger field)."""
    kh, kw = kernel.shape
    z = rng.standard_normal((h + kh, w + kw))
    f = np.fft.irfft2(np.fft.rfft2(z) * np.fft.rfft2(kernel, s=z.shape), s=z.shape)
    return f[kh:, kw:]


def _summed_variance(rho, radius, n):
    """Bartlett's large-sample variance of the sample autocorrelation summed over the lags
    within ``radius`` (rings rounded as correlation_area rounds them), ``n`` data:
    ``(2/n) sum_{k,k' in W} (rho * rho)(k - k')`` (M. S. Bartlett 1946), with ``rho`` the
    true autocorrelation on a lag grid centred at its middle."""
    c = np.array(rho.shape) // 2
    yy, xx = np.indices(rho.shape)
    win = (np.rint(np.hypot(yy - c[0], xx - c[1])) <= radius).astype(float)
    s = [2 * d for d in rho.shape]
    auto = lambda a: np.fft.irfft2(np.abs(np.fft.rfft2(a, s=s)) ** 2, s=s)
    return 2.0 / n * float(np.sum(auto(rho) * auto(win)))


@pytest.mark.parametrize("shared", [False, True])
def test_the_correlation_area_of_a_field_of_known_correlation(shared):
    """A residual field of white noise smoothed by a Gaussian kernel K (width 2 px) has the
    autocorrelation K * K / sum K^2, whose sum over lags is (sum K)^2 / sum K^2 (50.3 px):
    correlation_area gives it within 4 of its sampling errors (Bartlett's variance of the
    summed sample autocorrelation over the lags summed, plus the truncated tail). Three
    independent channels give that area (their cross terms vanish; the estimate averages
    three); one field in all three channels gives three times it (each datum has two
    copies). White noise gives 1."""
    from bubblefit.inverse._uncertainty import correlation_area

    rng = np.random.default_rng(7)
    h, w, width = 160, 200, 2.0
    r = np.arange(-8, 9)
    k1 = np.exp(-(r**2) / (2 * width**2))
    kernel = np.outer(k1, k1)
    area = kernel.sum() ** 2 / np.sum(kernel**2)
    rho = np.fft.fftshift(np.fft.irfft2(np.abs(np.fft.rfft2(kernel, s=(34, 34))) ** 2, s=(34, 34)))
    rho /= rho.max()
    if shared:
        one = _smoothed_noise(rng, h, w, kernel)
        field, factor, copies = np.repeat(one[..., None], 3, axis=-1), 3.0, 1
    else:
        field, factor, copies = np.stack([_smoothed_noise(rng, h, w, kernel) for _ in range(3)], -1), 1.0, 3
    got, radius = correlation_area(field, np.ones(field.shape, bool))
    yy, xx = np.indices(rho.shape)
    tail = float(rho[np.rint(np.hypot(yy - 17, xx - 17)) > radius].sum())
    sd = factor * math.sqrt(_summed_variance(rho, radius, h * w) / copies)
    assert radius >= 3, radius
    assert abs(got - factor * area) < 4 * sd + factor * tail, (got, factor * area, sd, radius)
    white, k_white = correlation_area(rng.standard_normal((h, w, 3)), np.ones((h, w, 3), bool))
    assert abs(white - 1.0) < 4 * math.sqrt(_summed_variance(np.pad([[1.0]], 16), k_white, h * w) / 3) + 1e-9


def test_the_pair_counts_of_a_mask_are_counted_once(monkeypatch):
    """Two residuals over one mask (a disc, a corner of it left out in one channel) count
    the mask's pairs once (the second reads them), with the areas of a fresh count; the
    counts are whole pairs: at lag 0 each channel pair's shared entries, and nowhere more
    than the mask holds. Counts larger than the kept bytes are counted afresh each time."""
    from bubblefit.inverse import _uncertainty as U

    rng = np.random.default_rng(5)
    ii, jj = np.mgrid[0:40, 0:48]
    used = np.repeat((((ii - 20) ** 2 + (jj - 24) ** 2) < 17**2)[..., None], 3, axis=2)
    used[:8, :8, 1] = False
    fields = [rng.standard_normal(used.shape) for _ in range(2)]
    monkeypatch.setattr(U, "_PAIRS", collections.OrderedDict())
    fresh = []
    for f in fields:
        fresh.append(U.correlation_area(f, used))
        U._PAIRS.clear()
    got = [U.correlation_area(f, used) for f in fields]
    assert got == fresh
    key = np.packbits(used).tobytes()
    pairs = U._pair_counts(used.shape, key)
    assert len(U._PAIRS) == 1 and pairs is U._pair_counts(used.shape, key)
    lag0 = np.einsum("hwa,hwb->ab", used.astype(float), used.astype(float))
    np.testing.assert_array_equal(pairs[0, 0], lag0)
    assert pairs.max() == lag0.max()
    monkeypatch.setattr(U, "_PAIRS", collections.OrderedDict())
    monkeypatch.setattr(U, "PAIR_CACHE_BYTES", pairs.nbytes - 1)
    again = U._pair_counts(used.shape, key)
    assert len(U._PAIRS) == 0 and again is not pairs
    np.testing.assert_array_equal(again, pairs)


def test_a_correlated_residual_widens_the_views_error():
    """divergence_profile with a correlation area A: Delta chi^2 = A (n data carry the
    information of n / A independent ones), so the standard error is sqrt(A) times the
    independent one; an area below 1 never narrows it."""
    from bubblefit.inverse import divergence_profile

    us, chi2 = [0.0, 0.1, 0.2], [400.0, 100.0, 400.0]  # 3e4 (u - 0.1)^2 + 100
    base = divergence_profile(us, chi2)
    assert base.stderr == pytest.approx(1 / math.sqrt(3e4), rel=1e-9)
    assert divergence_profile(us, chi2, area=25.0).stderr == pytest.approx(5 * base.stderr, rel=1e-9)
    assert divergence_profile(us, chi2, area=0.5).stderr == pytest.approx(base.stderr, rel=1e-9)
