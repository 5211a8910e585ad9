"""Tests of ``bubblefit calibrate`` (paper sec. 3.3): t from shots with and without the bubble."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bubblefit.capture import calibrate as cal
from bubblefit.capture import circle, profile, ratio, registration
from bubblefit.io.images import Image, read_image, srgb_decode, srgb_encode, write_image

REPO = Path(__file__).resolve().parents[1]

# --------------------------------------------------------------------------------------
# Synthetic capture: dark box, checkered backdrop, bubble, camera shift, noise, 8-bit sRGB
# --------------------------------------------------------------------------------------

SIZE = 160
SQUARE = 14.0
WHITE = np.array([0.62, 0.60, 0.55])
BLACK = np.array([0.025, 0.025, 0.025])
BOX = 0.004


def _backdrop(shift=(0.0, 0.0), size=SIZE, phase=0.0, square=SQUARE, scale=1, m=64):
    """Checkerboard on a black box, integrated over each pixel's area, camera shifted by ``shift``.

    A point of the scene at (x, y) in the unshifted image appears at (x + dx, y + dy)
    (array coordinates of the ``size`` x ``size`` image). ``scale`` > 1 gives the same
    view on a ``scale`` times finer pixel grid. The board and its squares are separable,
    so the area integrals are products of 1-D integrals (``m`` samples per pixel per axis).
    """

    def axis(d, lo, hi):
        k = np.arange(size * scale)[:, None]
        u = (k + (np.arange(m) + 0.5) / m) / scale - 0.5  # array coordinates of the samples
        x = u - d - 0.5 * size
        on = ((x > lo * size) & (x < hi * size)).astype(float)
        sgn = 1.0 - 2.0 * (np.floor(x / square + phase) % 2)
        return on.mean(axis=1), (on * sgn).mean(axis=1)

    ox, sx = axis(shift[0], -0.42, 0.42)
    oy, sy = axis(shift[1], -0.45, 0.36)
    on = np.outer(oy, ox)[..., None]
    chk = np.outer(sy, sx)[..., None]
    return on * 0.5 * (WHITE + BLACK) + chk * 0.5 * (WHITE - BLACK) + (1.0 - on) * BOX


def _quantise(lin, rng, noise=0.01, bits=8):
    """Shot + read noise, sRGB encoding and integer quantisation: the codes of a photo."""
    sigma = np.sqrt((noise * lin) ** 2 + (0.1 * noise) ** 2)
    noisy = lin + rng.normal(size=lin.shape) * sigma
    maxcode = 2**bits - 1
    return np.round(srgb_encode(np.clip(noisy, 0, 1)) * maxcode)


def _image(codes, bits=8, name="x.png"):
    """An :class:`Image` as :func:`read_image` would return for these integer codes."""
    maxcode = 2**bits - 1
    return Image(
        pixels=srgb_decode(codes / maxcode), path=name, bit_depth=bits, linear_file=False,
        saturated=np.any(codes >= maxcode, axis=2),
    )


SS = 3  # the forward model samples pixel centres: render at 3x and average 3x3 (the sensor's area)


def render_after(background_hr, model, t, n, centre, r, size=SIZE, interference=None):
    """The project's forward model: the bubble over a background photo in a black box.

    ``centre`` and ``r`` in pixels of the final image (pixel centres at +1/2, the
    convention of :class:`bubblefit.model.geometry.OrthographicCamera`). The environment is
    black (the dark box): no reflections, only the background seen through both films.
    """
    from bubblefit.model.effects import Effects
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.model.render import Params, RenderConfig, render

    if interference is None:
        interference = "off" if model == "paper" else "incoherent"
    fx = Effects(model=model, front_reflection=False, rear_reflection=False, transmission=True,
                 interference=interference, diffuse=False, environment=False, background="photo")
    cam = OrthographicCamera(width=size * SS, height=size * SS, cx=centre[0] * SS, cy=centre[1] * SS, r=r * SS)
    img = np.asarray(render(Params.make(t=t, n_film=n), RenderConfig(effects=fx, camera=cam), None,
                            np.asarray(background_hr, np.float32)), dtype=np.float64)
    return img.reshape(size, SS, size, SS, 3).mean(axis=(1, 3))


def true_t(model, t, n):
    """t of the forward model at normal incidence: ``t`` (paper) or the Fresnel film's."""
    if model == "paper":
        return t
    return float(_two_films(0.0, n)) ** 0.25  # Fresnel's equations, written in tests/helpers.py


def make_pair(seed, model="paper", t=0.972, n=1.4, r=None, shift=None, noise=0.01, gain=1.0, bits=8):
    """A synthetic capture with known t, rendered by the forward model.

    Returns ``(before_codes, after_codes, truth)``: integer codes of the two shots (H, W, 3)
    and a dict with ``t``, the circle ``cx, cy, r`` (pixel centres at +1/2) and ``shift``.
    """
    rng = np.random.default_rng(seed)
    if shift is None:
        shift = tuple(rng.uniform(-3, 3, size=2))
    r = r if r is not None else rng.uniform(44, 52)
    centre_scene = np.array([SIZE / 2, SIZE / 2 - 6]) + rng.uniform(-4, 4, size=2)
    before = _backdrop((0.0, 0.0))
    bg_after_hr = _backdrop(shift, scale=SS)
    centre = centre_scene + np.asarray(shift)
    after = render_after(bg_after_hr, model, t, n, centre, r) * gain
    truth = {"t": true_t(model, t, n), "cx": centre[0], "cy": centre[1], "r": r, "shift": shift, "n": n}
    return _quantise(before, rng, noise, bits), _quantise(after, rng, noise, bits), truth


def numpy_pair(seed, model="paper", **kw):
    """``make_pair`` as :class:`Image` objects, as read from 8-bit PNG files."""
    b, a, truth = make_pair(seed, model, **kw)
    return _image(b, name="before.png"), _image(a, name="after.png"), truth


# --------------------------------------------------------------------------------------
# Pure functions
# --------------------------------------------------------------------------------------


def test_kasa_circle_fit_exact():
    th = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    cx, cy, r = circle.kasa_circle_fit(10 + 7 * np.cos(th), -3 + 7 * np.sin(th))
    assert (cx, cy, r) == pytest.approx((10, -3, 7), abs=1e-9)


def test_fresnel_film_ratio_centre_and_rim():
    # n = 1.4: R1 = (0.4 / 2.4)^2, T = (1 - R1) / (1 + R1) per film, both polarisations
    r1 = (0.4 / 2.4) ** 2
    assert float(profile.fresnel_film_ratio(0.0, 1.4)) == pytest.approx(((1 - r1) / (1 + r1)) ** 2, rel=1e-9)
    assert float(profile.fresnel_film_ratio(1.0, 1.4)) == pytest.approx(0.0, abs=1e-6)
    s = profile.fresnel_shape(np.array([0.0, 0.5, 0.9]), 1.4)
    assert s[0] == 1.0 and 0.99 < s[1] < 1.0 and 0.75 < s[2] < 0.85


def test_n_from_t4_inverts():
    for n in (1.33, 1.4, 1.5):
        assert profile.n_from_t4(float(profile.fresnel_film_ratio(0.0, n))) == pytest.approx(n, abs=1e-7)
    assert np.isnan(profile.n_from_t4(1.01))


def test_robust_ratio_ignores_outliers():
    rng = np.random.default_rng(1)
    b = rng.uniform(0.3, 0.8, 2000)
    a = 0.9 * b + rng.normal(0, 0.005, b.size)
    a[:100] = 0.2  # dust
    k, w = ratio.robust_ratio(a, b)
    assert k == pytest.approx(0.9, abs=1e-3)
    assert np.all(w[:100] == 0)


def test_register_translation_recovers_subpixel_shift():
    b = _backdrop((0.0, 0.0)).sum(axis=2)
    a = _backdrop((1.7, -2.3)).sum(axis=2)
    (dx, dy), cc = registration.register_translation(a, b)
    assert dx == pytest.approx(1.7, abs=0.1) and dy == pytest.approx(-2.3, abs=0.1)
    assert cc > 0.95


# --------------------------------------------------------------------------------------
# Recovery
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("model", ["paper", "physical"])
def test_recovers_t_and_circle(model):
    before, after, truth = numpy_pair(3, model=model)
    res = cal.calibrate(before, after, n_boot=500)
    assert abs(res.t - truth["t"]) < 0.002
    assert res.t_ci95[0] <= res.t <= res.t_ci95[1]
    assert res.bubble["cx"] == pytest.approx(truth["cx"], abs=0.5)
    assert res.bubble["cy"] == pytest.approx(truth["cy"], abs=0.5)
    assert res.bubble["r"] == pytest.approx(truth["r"], abs=0.7)
    assert res.shift_px == pytest.approx(list(truth["shift"]), abs=0.15)
    assert res.t4 == pytest.approx(res.t**4)
    for v in res.t_rgb:
        assert abs(v - truth["t"]) < 0.003
    if model == "physical":
        assert res.radial["model"] == "fresnel"
        assert res.n_film == pytest.approx(truth["n"], abs=0.02)
    else:
        assert res.radial["model"] == "constant"
        assert res.n_film is None


def _two_films(rho, n):
    """after/before through both films of a bubble seen by an orthographic camera, written
    from Fresnel's equations (tests/helpers.py): the ray meets the front and the rear film
    at the same incidence, ``sin(theta) = rho``; each film is an incoherent slab with
    transmittance ``(1 - r) / (1 + r)`` per polarisation, and s and p (the same plane of
    incidence at both films) are averaged after both."""
    from helpers import incoherent_slab

    cos_i = np.sqrt(1.0 - np.clip(rho, 0.0, 1.0) ** 2)
    _, trans = incoherent_slab(cos_i, n)
    return np.mean(trans**2, axis=-1)


def test_forward_model_agrees_with_calibration_physics():
    """The renderer's physical background term (the light seen through the bubble in a dark
    box), and the fit's film ratio, are the Fresnel transmission through two films."""
    size, r = 64, 28.0
    ones = np.ones((size * SS, size * SS, 3))
    img = render_after(ones, "physical", 0.972, 1.4, (32.0, 32.0), r, size=size)
    # pixel centres well inside the disc: compare with the film model at the pixel centre
    # (averaged over the 3x3 sub-pixels the way render_after does)
    sub = (np.arange(SS) + 0.5) / SS
    ys, xs = np.mgrid[0:size, 0:size].astype(float)
    acc = np.zeros((size, size))
    for oy in sub:
        for ox in sub:
            acc += _two_films(np.minimum(np.hypot(xs + ox - 32, ys + oy - 32) / r, 1.0), 1.4)
    ref = acc / SS**2
    inner = np.hypot(xs + 0.5 - 32, ys + 0.5 - 32) < 0.9 * r
    assert np.max(np.abs(img[..., 1][inner] - ref[inner])) < 1e-5
    assert img[32, 32, 0] == pytest.approx(_two_films(0.0, 1.4), abs=1e-5)
    rho = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(profile.fresnel_film_ratio(rho, 1.4), _two_films(rho, 1.4), rtol=1e-12, atol=1e-15)


# --------------------------------------------------------------------------------------
# Coverage of the interval (seeded trials)
# --------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("model", ["paper", "physical"])
def test_t_within_0002_and_interval_coverage(model):
    trials = 20
    errors, covered = [], 0
    for k in range(trials):
        t_true = 0.972 if model == "paper" else None
        n_true = 1.4 if model == "paper" else [1.33, 1.36, 1.40, 1.45][k % 4]
        before, after, truth = numpy_pair(1000 + k, model=model, t=t_true or 0.972, n=n_true)
        res = cal.calibrate(before, after, n_boot=800, seed=k)
        errors.append(res.t - truth["t"])
        covered += res.t_ci95[0] <= truth["t"] <= res.t_ci95[1]
        if model == "physical":
            assert res.n_film is not None and abs(res.n_film - n_true) < 0.01, (k, res.n_film, n_true)
    errors = np.abs(errors)
    assert errors.max() < 0.002, errors
    assert covered >= 0.9 * trials, (covered, trials)


# --------------------------------------------------------------------------------------
# Other variations
# --------------------------------------------------------------------------------------


def test_exposure_change_is_corrected_and_reported():
    before, after, truth = numpy_pair(7, gain=0.95)
    res = cal.calibrate(before, after, n_boot=300)
    assert abs(res.t - truth["t"]) < 0.002
    assert res.exposure_ratio == pytest.approx(0.95, abs=0.003)
    assert any("exposure changed" in w for w in res.warnings)
    # without the correction t absorbs the exposure change
    raw = cal.calibrate(before, after, n_boot=300, exposure_correction=False)
    assert raw.t == pytest.approx(truth["t"] * 0.95**0.25, abs=0.002)


def test_given_circle_overrides_detection():
    before, after, truth = numpy_pair(8)
    circle = (truth["cx"] + 0.3, truth["cy"] - 0.2, truth["r"] - 0.5)
    res = cal.calibrate(before, after, circle=circle, n_boot=300)
    assert res.bubble_source == "given"
    assert [res.bubble["cx"], res.bubble["cy"], res.bubble["r"]] == pytest.approx(list(circle))
    assert abs(res.t - truth["t"]) < 0.002


def test_small_bubble_gives_t_but_no_index():
    before, after, truth = numpy_pair(11, model="physical", r=16.0)
    res = cal.calibrate(before, after, n_boot=300)
    assert abs(res.t - truth["t"]) < 0.002
    assert res.n_film is None
    assert any("n_film not reported" in w for w in res.warnings)


def test_result_does_not_depend_on_the_exposure_scale():
    before, after, truth = numpy_pair(13)
    res = cal.calibrate(before.pixels, after.pixels, n_boot=300)
    tiny = cal.calibrate(before.pixels * 1e-6, after.pixels * 1e-6, n_boot=300)
    assert tiny.t == pytest.approx(res.t, abs=1e-6)
    assert tiny.pixels_used == res.pixels_used


def test_no_shift_and_large_shift():
    before, after, truth = numpy_pair(10, shift=(0.0, 0.0))
    res = cal.calibrate(before, after, n_boot=300)
    assert res.shift_px == pytest.approx([0.0, 0.0], abs=0.1)
    before, after, truth = numpy_pair(11, shift=(6.4, -5.2))
    res = cal.calibrate(before, after, n_boot=300)
    assert res.shift_px == pytest.approx([6.4, -5.2], abs=0.15)
    assert abs(res.t - truth["t"]) < 0.002


def test_json_roundtrip_keys():
    before, after, truth = numpy_pair(12, model="physical")
    res = cal.calibrate(before, after, n_boot=300)
    d = json.loads(json.dumps(res.to_json()))
    for key in ("t", "t_rgb", "t4", "t_ci95", "bubble", "pixels_used", "warnings", "shift_px", "n_film", "n_film_stderr"):
        assert key in d
    assert set(d["bubble"]) == {"cx", "cy", "r"}
    assert len(d["t_rgb"]) == 3 and len(d["t_ci95"]) == 2
    assert d["t4"] == pytest.approx(d["t"] ** 4, rel=1e-5)


# --------------------------------------------------------------------------------------
# Files and command line
# --------------------------------------------------------------------------------------


def _write_codes(path, codes, bits=8):
    """Write integer codes exactly (8/16-bit PNG or TIFF) through OpenImageIO."""
    import OpenImageIO as oiio

    fmt = oiio.UINT8 if bits == 8 else oiio.UINT16
    dtype = np.uint8 if bits == 8 else np.uint16
    h, w, c = codes.shape
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(w, h, c, fmt))
    assert out.write_image(np.ascontiguousarray(codes.astype(dtype)))
    out.close()


def _write_pair(tmp_path, seed=20, ext="png", bits=8, **kw):
    b, a, truth = make_pair(seed, bits=bits if ext in ("png", "tif") else 8, **kw)
    pb, pa = tmp_path / f"before.{ext}", tmp_path / f"after.{ext}"
    if ext in ("png", "tif"):
        _write_codes(pb, b, bits)
        _write_codes(pa, a, bits)
    else:  # EXR (linear float) and JPEG go through the project's writer
        maxc = 255
        write_image(pb, srgb_decode(b / maxc), bit_depth=32 if ext == "exr" else None)
        write_image(pa, srgb_decode(a / maxc), bit_depth=32 if ext == "exr" else None)
    return pb, pa, truth


def run_cli(args, monkeypatch, capsys):
    """``bubblefit calibrate ...`` through the real ``main`` (only this sub-command registered)."""
    import bubblefit.cli as cli

    monkeypatch.setattr(cli, "COMMANDS", ("calibrate",))
    code = cli.main(["calibrate", *map(str, args)])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("ext,bits,tol", [("png", 8, 0.002), ("png", 16, 0.002), ("tif", 16, 0.002),
                                          ("exr", 32, 0.002), ("jpg", 8, 0.004)])
def test_cli_formats_json_and_debug_image(tmp_path, monkeypatch, capsys, ext, bits, tol):
    pb, pa, truth = _write_pair(tmp_path, ext=ext, bits=bits)
    js, dbg = tmp_path / "cal.json", tmp_path / "debug.png"
    code, out, err = run_cli([pb, pa, "--json", js, "--debug-image", dbg, "--bootstrap", 300], monkeypatch, capsys)
    assert code == 0, err
    d = json.loads(js.read_text())
    assert abs(d["t"] - truth["t"]) < tol
    printed = float(out.split("t = ")[1].split()[0])
    assert printed == pytest.approx(d["t"], abs=6e-5)
    assert d["bubble"]["cx"] == pytest.approx(truth["cx"], abs=0.6)
    img = read_image(dbg)
    assert img.shape[1] == 2 * img.shape[0]  # two panels
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries left


def test_cli_circle_option(tmp_path, monkeypatch, capsys):
    pb, pa, truth = _write_pair(tmp_path)
    circle = f"{truth['cx']:.2f},{truth['cy']:.2f},{truth['r']:.2f}"
    js = tmp_path / "c.json"
    code, out, err = run_cli([pb, pa, "--circle", circle, "--json", js, "-q"], monkeypatch, capsys)
    assert code == 0, err
    assert out == ""
    d = json.loads(js.read_text())
    assert d["bubble_source"] == "given" and d["bubble"]["r"] == pytest.approx(truth["r"], abs=0.01)
    code, out, err = run_cli([pb, pa, "--circle", "1,2"], monkeypatch, capsys)
    assert code == 2 and "--circle" in err and len(err.strip().splitlines()) == 1


def _assert_one_line_error(code, err, *words):
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("bubblefit: error:")
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], lines[0]


def test_cli_no_bubble(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(0)
    bg = _backdrop()
    _write_codes(tmp_path / "b.png", _quantise(bg, rng))
    _write_codes(tmp_path / "a.png", _quantise(bg, rng))
    js = tmp_path / "out.json"
    code, out, err = run_cli([tmp_path / "b.png", tmp_path / "a.png", "--json", js], monkeypatch, capsys)
    _assert_one_line_error(code, err, "no bubble found", "differ in fewer than")
    assert not js.exists()


def test_cli_two_different_scenes(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(1)
    _write_codes(tmp_path / "b.png", _quantise(_backdrop(), rng))
    other = _backdrop(square=23.0, phase=0.5)[::-1]  # another background, upside down
    _write_codes(tmp_path / "a.png", _quantise(other, rng))
    code, out, err = run_cli([tmp_path / "b.png", tmp_path / "a.png"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "do not show the same scene")


def test_cli_mismatched_sizes(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(2)
    _write_codes(tmp_path / "b.png", _quantise(_backdrop(), rng))
    _write_codes(tmp_path / "a.png", _quantise(_backdrop()[:120], rng))
    code, out, err = run_cli([tmp_path / "b.png", tmp_path / "a.png"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "160x160", "160x120")


def test_cli_mismatched_channels(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(3)
    codes = _quantise(_backdrop(), rng)
    _write_codes(tmp_path / "b.png", codes)
    _write_codes(tmp_path / "a.png", codes[..., :1])
    code, out, err = run_cli([tmp_path / "b.png", tmp_path / "a.png"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "channel")


def test_cli_saturated_pair(tmp_path, monkeypatch, capsys):
    b, a, truth = make_pair(21)
    # the same capture overexposed: three stops brighter, clipped at the top code
    over = lambda c: np.round(srgb_encode(np.clip(srgb_decode(c / 255) * 8, 0, 1)) * 255)
    _write_codes(tmp_path / "b.png", over(b))
    _write_codes(tmp_path / "a.png", over(a))
    code, out, err = run_cli([tmp_path / "b.png", tmp_path / "a.png"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "saturated")


def test_cli_too_few_pixels_inside_given_circle(tmp_path, monkeypatch, capsys):
    pb, pa, truth = _write_pair(tmp_path)
    # a circle over the black box (no checkerboard behind it)
    code, out, err = run_cli([pb, pa, "--circle", "6,150,5"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "too few usable pixels inside the bubble")


@pytest.mark.parametrize("kind", ["garbage", "truncated", "missing"])
def test_cli_corrupt_file(tmp_path, monkeypatch, capsys, kind):
    pb, pa, truth = _write_pair(tmp_path)
    if kind == "garbage":
        pa.write_bytes(b"this is not a PNG file at all" * 10)
    elif kind == "truncated":
        data = pa.read_bytes()
        pa.write_bytes(data[: len(data) // 3])
    else:
        pa.unlink()
    code, out, err = run_cli([pb, pa], monkeypatch, capsys)
    _assert_one_line_error(code, err, "after.png")


@pytest.mark.slow
def test_entry_point_end_to_end(tmp_path):
    """The installed command line, as users run it (needs every registered sub-command)."""
    import importlib.util

    import bubblefit.cli as cli

    missing = [c for c in cli.COMMANDS if importlib.util.find_spec(f"bubblefit.cli.{c}") is None]
    assert not missing, f"registered sub-commands without a module: {missing}"
    pb, pa, truth = _write_pair(tmp_path, seed=22)
    js = tmp_path / "cal.json"
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "calibrate", str(pb), str(pa), "--json", str(js)],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert abs(json.loads(js.read_text())["t"] - truth["t"]) < 0.002
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "calibrate", str(pb), str(tmp_path / "nope.png")],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1


# --------------------------------------------------------------------------------------
# Nothing wrong accepted, nothing lost (issue 16)
# --------------------------------------------------------------------------------------


def test_cli_swapped_files_are_refused(tmp_path, monkeypatch, capsys):
    """BEFORE and AFTER swapped: t above 1 is impossible, refused in one line."""
    pb, pa, _ = _write_pair(tmp_path, seed=21)
    code, _, err = run_cli([pa, pb, "--json", tmp_path / "out.json"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "swapped")
    assert not (tmp_path / "out.json").exists()


@pytest.mark.parametrize("size", [(1, 1), (3, 3), (12, 40)])
def test_cli_tiny_images_are_refused(tmp_path, monkeypatch, capsys, size):
    h, w = size
    codes = np.full((h, w, 3), 128, np.uint8)
    _write_codes(tmp_path / "b.png", codes)
    _write_codes(tmp_path / "a.png", codes)
    code, _, err = run_cli([tmp_path / "b.png", tmp_path / "a.png"], monkeypatch, capsys)
    _assert_one_line_error(code, err, "too small")


@pytest.mark.parametrize("option", ["--json", "--debug-image"])
@pytest.mark.parametrize("which", ["before", "after", "link"])
def test_cli_output_onto_an_input_is_refused(tmp_path, monkeypatch, capsys, option, which):
    pb, pa, _ = _write_pair(tmp_path, seed=22)
    target = {"before": pb, "after": pa, "link": tmp_path / "alias.png"}[which]
    if which == "link":
        target.symlink_to(pa)
    before_bytes, after_bytes = pb.read_bytes(), pa.read_bytes()
    code, _, err = run_cli([pb, pa, option, target], monkeypatch, capsys)
    _assert_one_line_error(code, err, "refusing to write")
    assert pb.read_bytes() == before_bytes and pa.read_bytes() == after_bytes


def test_json_has_the_frame_size_and_the_model_error():
    before, after, truth = numpy_pair(14)
    res = cal.calibrate(before, after, n_boot=300)
    d = res.to_json()
    h, w = before.shape
    assert d["image_size"] == [w, h]
    assert d["t4_model_stderr"] >= 0
    # the interval is at least as wide as the model error alone
    assert d["t4_ci95"][1] - d["t4_ci95"][0] >= 2 * 1.95 * d["t4_model_stderr"] - 1e-9


VALIDATION = Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data"
_PAIRS = sorted(p.parent.name for p in VALIDATION.glob("cal_*/truth.json"))  # shipped with the repository


@pytest.mark.slow
@pytest.mark.parametrize("case", _PAIRS[:1])
def test_interval_covers_the_truth_on_an_independent_pair(case):
    """A dark-box pair path traced by Mitsuba 3 (thin dielectric sphere, n = 1.4): the 95%
    interval, noise and model error, holds the true per-interface t."""
    folder = VALIDATION / case
    truth = json.loads((folder / "truth.json").read_text())
    res = cal.calibrate(folder / "before.png", folder / "after.png", n_boot=500)
    lo, hi = res.t_ci95
    assert lo <= truth["t"] <= hi, (res.t, res.t_ci95, truth["t"])
    assert hi - lo < 0.01  # still a measurement
    d = truth["disc"]
    assert abs(res.bubble["cx"] - d["cx"]) < 1.5 and abs(res.bubble["cy"] - d["cy"]) < 1.5
    assert abs(res.bubble["r"] - d["r"]) < 1.5
