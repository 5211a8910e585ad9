"""A whole bubble under an area light, against references written here.

* A numpy ray trace of a sphere and a rectangle (the ray-sphere quadratic, the mirror law,
  the ray-plane intersection and the rectangle's outline), with the Airy sum of a film in
  air per polarisation (Born & Wolf 1.5.2 and 7.6.1): the render's pixels, front film, rear
  film and the light straight through.
* A closed form: an orthographic view of a mirror sphere along -z sends the ray that meets
  it at the unit normal ``n`` into ``(2 n_z n_x, 2 n_z n_y, 2 n_z^2 - 1)``, so a distant disc
  light on the axis, seen within a cone of half-angle ``alpha``, lights exactly the image
  points within ``sin(alpha / 2)`` of the sphere's radius from the centre.
* A rough film's share of the light against a Monte Carlo integral of Ward's lobe
  (half-vector slopes drawn as Ward's Gaussian) over the rectangle.
* The scene file's bad inputs: one line, exit status 2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import airy_reflectance, pinhole_ray

from bubblefit.lighting.area import Patch, patch_coverage
from bubblefit.lighting.envmap import dark_room
from bubblefit.lighting.filtering import FilterConfig
from bubblefit.model.cap_render import CapConfig, render_cap
from bubblefit.model.effects import Effects
from bubblefit.model.geometry import OrthographicCamera, PerspectiveCamera
from bubblefit.model.render import Params, RenderConfig
from bubblefit.optics import spectral

N_FILM, D_NM = 1.4, 380.0
W = H = 48
PANEL = dict(center=(0.2, 0.3, 4.4), normal=(0.0, 0.0, -1.0), up=(0.0, 1.0, 0.0), size=(5.0, 3.0), radiance=2.0)


def _film_r(cos_i, lam):
    """Airy reflectance of a film of N_FILM and D_NM in air, (K, 2) per polarisation."""
    return airy_reflectance(np.full(len(lam), cos_i), N_FILM, D_NM, lam)


def _panel(o, w):
    """(radiance, distance of the hit to the outline) of the rectangle along o + s w, s > 0;
    it emits towards -z only."""
    c = np.asarray(PANEL["center"])
    if w[2] <= 0:
        return 0.0, np.inf
    s = (c[2] - o[2]) / w[2]
    if s <= 0:
        return 0.0, np.inf
    x, y = (o + s * w - c)[:2]
    hw, hh = PANEL["size"][0] / 2, PANEL["size"][1] / 2
    margin = min(abs(abs(x) - hw), abs(abs(y) - hh))
    return (PANEL["radiance"] if abs(x) <= hw and abs(y) <= hh else 0.0), margin


def _reference(cam, i, j, basis):
    """The pixel's radiance: front film, one rear reflection, the light straight through;
    None off the sphere or within 1e-3 of the light's outline (float32 rays may fall on
    either side there)."""
    o, d = pinhole_ray(cam, i, j)
    b = o @ d
    disc = b * b - (o @ o - 1.0)
    if disc <= 0:
        return None
    p0, p1 = o + (-b - math.sqrt(disc)) * d, o + (-b + math.sqrt(disc)) * d
    cos = abs(p0 @ d)
    R = _film_r(cos, np.asarray(basis.wavelengths))
    T = 1 - R
    rgb = lambda spec: spec.mean(-1) @ np.asarray(basis.weights)
    lf, mf = _panel(p0, d - 2 * (d @ p0) * p0)
    lr, mr = _panel(p1, d - 2 * (d @ p1) * p1)
    lb, mb = _panel(o, d)
    if min(mf, mr, mb) < 1e-3:
        return None
    kinds = {k for k, v in (("front", lf), ("rear", lr), ("through", lb)) if v > 0} or {"dark"}
    return rgb(R) * lf + rgb(T * R * T) * lr + rgb(T * T) * lb, kinds


def _config(camera, bounces=1, **fx):
    basis = spectral.spectral_basis("uniform", 24, illuminant="E")
    effects = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                      spectral=basis, bounces=bounces, thickness="constant", **fx)
    return CapConfig.sphere(RenderConfig(effects=effects, camera=camera), Patch(**PANEL)), basis


def test_sphere_under_a_panel_matches_an_independent_trace():
    """Front film, rear film and straight through, each seeing the panel or not, from the
    film's own point (the panel is 4 radii away: the point matters)."""
    cam = PerspectiveCamera(W, H, origin=(0.3, 0.2, 3.8), target=(0.0, 0.0, 0.0), fov_deg=40.0)
    cfg, basis = _config(cam)
    img = np.asarray(render_cap(Params.make(thickness=D_NM, n_film=N_FILM, exposure=1.0, roughness=0.0), cfg,
                                dark_room()))
    seen = {}
    for i in range(H):
        for j in range(W):
            ref = _reference(cam, i, j, basis)
            if ref is None:
                continue
            # float32 rays and film optics: a few 1e-5 relative
            np.testing.assert_allclose(img[i, j], ref[0], rtol=1e-3, atol=1e-5, err_msg=f"pixel {i},{j}")
            for k in ref[1]:
                seen[k] = seen.get(k, 0) + 1
    # every kind of pixel was compared: the panel in the front film, in the rear film, dark film
    assert seen.get("front", 0) > 40 and seen.get("rear", 0) > 10 and seen.get("dark", 0) > 100, seen


def test_mirror_sphere_lights_the_closed_form_disc():
    """Orthographic view, distant disc light on the axis: the lit pixels are those within
    ``sin(alpha / 2)`` of the sphere's radius from its centre (module docstring)."""
    alpha = math.radians(50.0)
    dist = 1e4   # the light's distance in radii: the film's offset from the centre moves the cone by 1e-4
    cam = OrthographicCamera(96, 96, cx=48.0, cy=48.0, r=40.0)
    basis = spectral.spectral_basis("uniform", 24, illuminant="E")
    effects = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                      spectral=basis, bounces=1, thickness="constant", rear_reflection=False, transmission=False)
    light = Patch(center=(0.0, 0.0, dist), normal=(0.0, 0.0, -1.0), size=(dist * math.tan(alpha),) * 2, shape="disc")
    cfg = CapConfig.sphere(RenderConfig(effects=effects, camera=cam), light)
    img = np.asarray(render_cap(Params.make(thickness=D_NM, n_film=N_FILM, roughness=0.0), cfg, dark_room()))
    i, j = np.mgrid[0:96, 0:96]
    rho = np.hypot((j + 0.5 - 48.0) / 40.0, (i + 0.5 - 48.0) / 40.0)
    edge = np.abs(rho - math.sin(alpha / 2)) < 2e-3        # centres on the closed form's circle: either side
    expect = rho <= math.sin(alpha / 2)
    got = img.max(-1) > 0
    assert np.array_equal(got[~edge], expect[~edge])
    assert expect.sum() > 800   # a disc of about 17 pixels' radius


@pytest.mark.parametrize("offset", [0.0, 1.9, 2.5, 3.1])
def test_rough_share_of_the_panel_against_monte_carlo(offset):
    """A film point 4 units from a 5 x 3 panel, its mirror ray aimed ``offset`` from the
    panel's centre along x (inside, near the edge, at it, beyond it), Ward's ``a`` = 0.05:
    the Gaussian share within 0.02 of a Monte Carlo over the lobe's half-vectors."""
    a, n_mc = 0.05, 200_000
    light = Patch(center=(0.0, 0.0, 4.0), normal=(0.0, 0.0, -1.0), size=(5.0, 3.0))
    o = np.zeros(3)
    w = np.array([offset, 0.0, 4.0])
    w /= np.linalg.norm(w)
    n = np.array([0.0, 0.0, 1.0])
    wo = 2 * (w @ n) * n - w                     # the viewer's direction whose mirror ray is w
    rng = np.random.default_rng(3)
    # Ward's lobe exp(-tan^2 / a^2): the half-vector's slopes are Gaussian with variance a^2 / 2,
    # about the normal, in a frame where the mirror half-vector is n
    sx, sy = rng.normal(0.0, a / math.sqrt(2), (2, n_mc))
    h = np.stack([sx, sy, np.ones(n_mc)], -1)
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    wr = 2 * (h @ wo)[:, None] * h - wo
    s = 4.0 / wr[:, 2]
    x, y = s * wr[:, 0], s * wr[:, 1]
    mc = np.mean((np.abs(x) <= 2.5) & (np.abs(y) <= 1.5) & (wr[:, 2] > 0))
    got = float(patch_coverage(light, np.asarray([o], np.float32), np.asarray([w], np.float32), 0.05)[0])
    assert abs(got - mc) < 0.02, (got, mc)
    mirror = float(patch_coverage(light, np.asarray([o], np.float32), np.asarray([w], np.float32), 0.0)[0])
    assert mirror == (1.0 if offset < 2.5 else 0.0) or offset == 2.5


SCENE = """
[film]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
n = 1.4
thickness = "constant"
range_nm = [0.0, 1200.0]

[light]
type = "area"
shape = "rect"
center = [0.0, 0.0, 4.4]
normal = NORMAL
size = SIZE
lamp = "E"

[camera]
type = "perspective"
width = 40
height = 40
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov_deg = 34.0
"""


@pytest.mark.parametrize("normal, size, message", [
    ("[0.0, 0.0, 1.0]", "[4.0, 4.0]", "faces away from the bubble"),
    ("[0.0, 0.0, -1.0]", "[0.0, 4.0]", "has no size"),
])
def test_bad_area_light_is_one_line(tmp_path, normal, size, message):
    """A light turned away from the bubble or of zero size: one line, exit 2, nothing written."""
    from bubblefit.cli import main

    (tmp_path / "scene.toml").write_text(SCENE.replace("NORMAL", normal).replace("SIZE", size))
    from PIL import Image

    Image.fromarray(np.zeros((40, 40, 3), np.uint8)).save(tmp_path / "photo.png")
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            code = main(["fit", str(tmp_path / "photo.png"), "--scene", str(tmp_path / "scene.toml"),
                         "--json", str(tmp_path / "out.json")])
        except SystemExit as exc:
            code = exc.code
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert code == 2
    assert len(lines) == 1 and message in lines[0], lines
    assert not (tmp_path / "out.json").exists()


def _scene_text(size=56, thickness="constant"):
    return (SCENE.replace("NORMAL", "[0.0, 0.0, -1.0]").replace("SIZE", "[6.0, 4.0]")
            .replace("center = [0.0, 0.0, 4.4]", "center = [0.0, 0.4, 4.6]")
            .replace("width = 40\nheight = 40", f"width = {size}\nheight = {size}")
            .replace("origin = [0.0, 0.0, 4.0]", "origin = [0.25, 0.3, 4.0]")
            .replace('thickness = "constant"', f'thickness = "{thickness}"'))


@pytest.mark.slow
@pytest.mark.parametrize("truth_nm", [430.0, 905.0])
def test_fit_of_a_bubble_under_a_panel_from_a_noisy_8bit_render(tmp_path, truth_nm):
    """Known film -> render (16 rays per pixel) -> Poisson-Gaussian noise and 8-bit sRGB ->
    the ``fit`` command -> the thickness within 3 of its standard errors, and ok. The
    standard error (0.6 nm, mostly the model-error term) bounds a mismatch of the 4-ray
    fit against the 16-ray photo at the light's outline, which the fitted pixels avoid."""
    import tomllib

    from helpers import fit_scene_photo

    from bubblefit.inverse.cap_fit import cap_config
    from bubblefit.model.cap_scene import parse_cap_scene

    text = _scene_text()
    (tmp_path / "scene.toml").write_text(text)
    scene = parse_cap_scene(tomllib.loads(text), tmp_path)
    img = np.asarray(render_cap(Params.make(thickness=truth_nm, n_film=1.4, exposure=1.0, roughness=0.0),
                                cap_config(scene, "constant", samples_per_pixel=16), dark_room()))
    img = img * 0.9 / np.percentile(img, 99.5)
    res = fit_scene_photo(img, tmp_path, seed=11, timeout=900)
    assert res["shape"] == "sphere" and res["pixels_direct"] > 50
    assert res["traced_light_paths"] and res["skipped_light_paths"]   # what the scene simulates and skips
    d, se = res["params"]["thickness_nm"], res["stderr"]["thickness_nm"]
    assert abs(d - truth_nm) <= 3 * se, (d, se)
    assert res["ok"], res["warnings"]


@pytest.mark.slow
def test_cycles_bubble_under_a_panel(tmp_path):
    """The held-out Blender Cycles case (experiments/validation/data/cyc_sphere_const_panel):
    590 nm within the validation target (5 nm) and 3 of its standard errors."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    case = Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data" / "cyc_sphere_const_panel"
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(case / "photo.png"), "--scene",
                           str(case / "scene.toml"), "--json", str(tmp_path / "r.json")],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    res = json.loads((tmp_path / "r.json").read_text())
    d, se = res["params"]["thickness_nm"], res["stderr"]["thickness_nm"]
    assert abs(d - 590.0) <= min(5.0, 3 * se), (d, se)


@pytest.mark.parametrize("edit, message", [
    (("normal = [0.0, 0.0, -1.0]", "normal = [0.0, 0.0, 1.0]"), "faces away from the film"),
    (("size = [1.0, 1.0]", "size = [1.0, 0.0]"), "has no size"),
])
def test_flat_film_panel_facing_away_or_of_no_size_is_refused(edit, message):
    """The flat film reads the same [light] table: the same two refusals."""
    import tomllib
    from pathlib import Path

    from bubblefit.errors import InputError
    from bubblefit.model.planar_scene import parse_planar

    case = Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data" / "film_drain_water_area"
    text = (case / "scene.toml").read_text()
    assert edit[0] in text
    with pytest.raises(InputError, match=message):
        parse_planar(tomllib.loads(text.replace(*edit)), case)


def _cli(args):
    import contextlib
    import io

    from bubblefit.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(args)
        except SystemExit as exc:
            code = exc.code
    return code, out.getvalue(), err.getvalue()


def test_render_command_draws_the_panel_in_the_bubble_and_explains(tmp_path):
    """``bubblefit render`` of a whole bubble under a panel: the panel's mirror image in the
    middle of the bubble (the mirror ray of the centre pixel goes back to the camera, and the
    panel lies behind it), dark beside the bubble; ``--explain`` names the traced and skipped
    paths; a scene without the thickness to render is one line, exit 2."""
    from bubblefit.io.images import read_image

    text = _scene_text(size=24).replace('thickness = "constant"', 'thickness = "constant"\nthickness_nm = 500.0')
    (tmp_path / "scene.toml").write_text(text.replace("origin = [0.25, 0.3, 4.0]", "origin = [0.0, 0.0, 4.0]")
                                         .replace("center = [0.0, 0.4, 4.6]", "center = [0.0, 0.0, 4.6]"))
    code, out, err = _cli(["render", str(tmp_path / "scene.toml"), "-o", str(tmp_path / "r.exr"), "--explain"])
    assert code == 0, err
    assert "traced   the front film's reflection" in out and "skipped  " in out
    img = read_image(tmp_path / "r.exr").pixels[..., :3]
    assert img[11:13, 11:13].min() > 0.01 and img[0, 0].max() == 0.0
    (tmp_path / "bad.toml").write_text(text.replace("thickness_nm = 500.0\n", ""))
    code, _, err = _cli(["render", str(tmp_path / "bad.toml"), "-o", str(tmp_path / "b.exr")])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "thickness_nm" in lines[0], lines
    assert not (tmp_path / "b.exr").exists()


@pytest.mark.slow
def test_drainage_of_a_bubble_under_a_panel_from_a_noisy_8bit_render(tmp_path):
    """The sphere's drainage profile (250 -> 950 nm, exponent 1.4) seen only where the panel
    is mirrored (the middle third of the bubble's height): the ends, extrapolated from
    there, within 3 of their standard errors, and ok."""
    import tomllib

    from helpers import fit_scene_photo

    from bubblefit.inverse.cap_fit import cap_config
    from bubblefit.model.cap_scene import parse_cap_scene

    text = _scene_text(thickness="drainage")
    (tmp_path / "scene.toml").write_text(text)
    scene = parse_cap_scene(tomllib.loads(text), tmp_path)
    truth = np.array([250.0, 950.0, 1.4])
    img = np.asarray(render_cap(Params.make(thickness=truth, n_film=1.4, exposure=1.0, roughness=0.0),
                                cap_config(scene, "drainage", samples_per_pixel=16), dark_room()))
    res = fit_scene_photo(img * 0.9 / np.percentile(img, 99.5), tmp_path, seed=5, timeout=1200)
    for name, value in zip(("top_nm", "bottom_nm", "exponent"), truth):
        assert abs(res["params"][name] - value) <= 3 * res["stderr"][name], (name, res["params"], res["stderr"])
    assert res["ok"], res["warnings"]
