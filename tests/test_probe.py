"""Tests of bubblefit.capture.probe (mirror-ball unwrapping, HDR merge) and ``bubblefit envmap``.

The mirror balls are rendered here, independently of the unwrapping code, by an
orthographic camera looking along -z at a unit mirror sphere: each pixel's ray reflects
off the sphere (r = d - 2 (d.n) n) into the environment map, read with the bilinear
lookup of docs/design.md's convention written in tests/helpers.py (not the package's).
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from bubblefit.lighting import envmap as em
from bubblefit.capture import hdr, probe
from bubblefit.capture import ball as ballmod
from bubblefit.errors import BubblefitError, InputError
from bubblefit.io.images import read_image, srgb_decode, srgb_encode
from helpers import equirect_lookup, texel_band_solid_angles, texel_centres

DATA = Path(__file__).resolve().parents[1] / "bubblefit" / "data"
LUM = np.array([0.2126, 0.7152, 0.0722])


# ------------------------------------------------------------------------------ helpers


def render_ball(env: np.ndarray, size: int = 128, *, cx=None, cy=None, r=None, bg=0.05, ss: int = 2) -> np.ndarray:
    """Orthographic camera along -z, mirror sphere, ss x ss samples per pixel (box filter)."""
    cx = size / 2 if cx is None else cx
    cy = size / 2 if cy is None else cy
    r = size / 2 if r is None else r
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    acc = np.zeros((size, size, 3))
    for a in range(ss):
        for b in range(ss):
            x = (xx + (a + 0.5) / ss - cx) / r
            y = -(yy + (b + 0.5) / ss - cy) / r
            rho2 = x * x + y * y
            inside = rho2 < 1.0
            n = np.stack([x, y, np.sqrt(np.clip(1 - rho2, 0, 1))], axis=-1)
            d = np.array([0.0, 0.0, -1.0])
            refl = d - 2 * (n @ d)[..., None] * n
            refl /= np.linalg.norm(refl, axis=-1, keepdims=True)
            L = equirect_lookup(env, refl)
            acc += np.where(inside[..., None], L, bg)
    return acc / (ss * ss)


@pytest.fixture(scope="module")
def smooth_env() -> np.ndarray:
    """The shipped courtyard map, band-limited (16 x 32) and resampled to 64 x 128."""
    px = read_image(DATA / "courtyard.exr").pixels
    while px.shape[0] > 16:
        px = em.downsample(px)
    return equirect_lookup(px, texel_centres(64, 128))


def weighted_rel_error(got: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """Solid-angle weighted relative L1 error of luminance over ``mask``."""
    h, w = ref.shape[:2]
    sa = texel_band_solid_angles(h, w)[:, None] * np.ones((1, w))
    g, r = got @ LUM, ref @ LUM
    return float((np.abs(g - r) * sa)[mask].sum() / (r * sa)[mask].sum())


def angle_from(dirs: np.ndarray, axis) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(dirs @ np.asarray(axis, float), -1, 1)))


# ------------------------------------------------------------------------------ unwrapping


def test_unwrap_reproduces_environment(smooth_env):
    ball = render_ball(smooth_env, 128, r=56)
    pm = probe.unwrap_mirror_ball(ball, ballmod.Circle(64, 64, 56), height=64)
    dirs = texel_centres(64, 128)
    well = pm.valid & (angle_from(dirs, [0, 0, -1]) > 40)
    err_well = weighted_rel_error(pm.pixels, smooth_env, well)
    err_valid = weighted_rel_error(pm.pixels, smooth_env, pm.valid)
    rel = np.abs(pm.pixels @ LUM / (smooth_env @ LUM) - 1)
    print(f"unwrap error: {100 * err_well:.2f}% (>40 deg from -z), {100 * err_valid:.2f}% (all valid), "
          f"median {100 * np.median(rel[well]):.2f}%")
    assert well.mean() > 0.6
    assert err_well < 0.03
    assert err_valid < 0.04
    assert np.median(rel[well]) < 0.015


def test_unwrap_orientation_is_not_mirrored(smooth_env):
    """The same comparison against the map flipped left-right fails: the test can tell."""
    ball = render_ball(smooth_env, 128, r=56)
    pm = probe.unwrap_mirror_ball(ball, ballmod.Circle(64, 64, 56), height=64)
    flipped = np.concatenate([smooth_env[:, ::-1]], axis=0)
    assert weighted_rel_error(pm.pixels, flipped, pm.valid) > 3 * weighted_rel_error(pm.pixels, smooth_env, pm.valid)


def test_valid_mask_excludes_rim_and_camera():
    env = np.ones((32, 64, 3))
    ball = render_ball(env, 96, r=40, ss=1)
    pm = probe.unwrap_mirror_ball(ball, ballmod.Circle(48, 48, 40), height=32, rim_mask_deg=25, camera_mask_deg=10)
    dirs = texel_centres(32, 64)
    back, front = angle_from(dirs, [0, 0, -1]), angle_from(dirs, [0, 0, 1])
    assert not pm.valid[back <= 25].any()
    assert not pm.valid[front <= 10].any()
    assert pm.valid[(back > 25) & (front > 10)].all()
    # masked texels are filled from their neighbours (a uniform map stays uniform)
    assert np.allclose(pm.pixels, 1.0, rtol=5e-3)  # rim pixels mix a little background
    assert pm.info["valid_fraction"] == pytest.approx(pm.valid.mean())


@pytest.mark.parametrize("distance", [None, 6.0])
def test_unwrap_inverts_forward_reflection(distance):
    """Round trip: the photo position the unwrap samples for direction w reflects w."""
    size, circ = 160, ballmod.Circle(81.3, 78.6, 60.0)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    coords = np.stack([xx + 0.5, yy + 0.5, np.ones_like(xx)], axis=-1)  # each pixel stores its position
    pm = probe.unwrap_mirror_ball(coords, circ, height=32, distance=distance, fill=False, supersample=1,
                                  rim_mask_deg=30, camera_mask_deg=0)
    dirs_img, inside = probe.mirror_ball_directions((size, size), circ, distance=distance)
    tex = texel_centres(32, 64)[pm.valid]
    pos = pm.pixels[pm.valid]
    j = np.clip(np.floor(pos[:, 0]).astype(int), 0, size - 1)
    i = np.clip(np.floor(pos[:, 1]).astype(int), 0, size - 1)
    assert inside[i, j].all()
    cosang = np.sum(dirs_img[i, j] * tex, axis=-1)
    # within the angle one photo pixel spans near the rim mask
    assert np.degrees(np.arccos(np.clip(cosang, -1, 1))).max() < 8.0
    assert np.median(np.degrees(np.arccos(np.clip(cosang, -1, 1)))) < 1.5


def test_find_ball_subpixel():
    env = np.ones((16, 32, 3)) * [0.6, 0.7, 0.8]
    env[:8] *= 3.0  # a bright sky over a darker ground
    ball = render_ball(env, 128, cx=63.3, cy=64.6, r=50.0, bg=0.03, ss=4)
    c = ballmod.find_ball(ball)
    assert abs(c.cx - 63.3) < 0.15 and abs(c.cy - 64.6) < 0.15 and abs(c.r - 50.0) < 0.15


def test_find_ball_and_unwrap_end_to_end(smooth_env):
    ball = render_ball(smooth_env, 128, cx=63.3, cy=64.6, r=54.0, bg=0.05, ss=2)
    c = ballmod.find_ball(ball)
    assert math.hypot(c.cx - 63.3, c.cy - 64.6) < 0.7 and abs(c.r - 54.0) < 0.7
    pm = probe.unwrap_mirror_ball(ball, c, height=64)
    dirs = texel_centres(64, 128)
    well = pm.valid & (angle_from(dirs, [0, 0, -1]) > 40)
    assert weighted_rel_error(pm.pixels, smooth_env, well) < 0.06


def test_find_ball_fails_cleanly_without_ball():
    rng = np.random.default_rng(1)
    with pytest.raises(InputError):
        ballmod.find_ball(np.full((64, 64, 3), 0.3) + 0.001 * rng.random((64, 64, 3)))


# ------------------------------------------------------------------------------ HDR merge


def simulate_brackets(radiance, times, *, seed=0, encode="srgb"):
    """8-bit exposures of a known radiance: noise, clipping at 1, sRGB (or gamma) codes."""
    rng = np.random.default_rng(seed)
    codes = []
    for t in times:
        x = radiance * t * (1 + rng.normal(0, 0.002, radiance.shape)) + rng.normal(0, 5e-4, radiance.shape)
        x = np.clip(x, 0, 1)
        enc = srgb_encode(x) if encode == "srgb" else x ** (1 / 2.2)
        codes.append(np.round(enc * 255).astype(np.uint8))
    return codes


@pytest.fixture(scope="module")
def hdr_scene():
    vals = np.geomspace(0.1, 1500.0, 64 * 64).reshape(64, 64)
    rad = np.stack([vals, 0.8 * vals, 0.6 * vals], axis=-1)
    rad[:6, :6] = [2000.0, 1900.0, 1700.0]  # the sun
    times = [2.0 ** -k for k in range(0, 13, 2)]  # 7 exposures, 12 stops apart end to end
    return rad, times


@pytest.mark.parametrize("method, tol", [("robertson", 0.03), ("debevec", 0.04)])
def test_hdr_merge_recovers_radiance(hdr_scene, method, tol):
    rad, times = hdr_scene
    codes = simulate_brackets(rad, times)
    sun_sat = [bool((c[:6, :6] == 255).any()) for c in codes]
    assert sun_sat == [True] * 6 + [False]  # the sun clips in all but the darkest exposure
    lin = [srgb_decode(c / 255.0) for c in codes]
    hm = hdr.merge_exposures(lin, times, saturated=[(c == 255).any(-1) for c in codes], method=method)
    rel = np.abs(hm.radiance / rad - 1).max(axis=-1)
    stops = math.log2(rad.max() / rad.min())
    print(f"{method}: max error {100 * rel.max():.2f}% over {stops:.1f} stops (bracket {hdr.exposure_stops(times):.0f} stops), "
          f"sun {hm.radiance[0, 0]}")
    top = rad.max(axis=-1) >= 2000.0 / 2**12  # the brightest 12 stops, sun included
    print(f"  max error over the top 12 stops {100 * rel[top].max():.2f}%, median {100 * np.median(rel):.2f}%")
    assert stops >= 12 and hdr.exposure_stops(times) >= 12
    assert rel[top].max() < tol
    assert rel.max() < tol + 0.02  # the darkest values of the range (0.1 at 1 s) are coarser
    assert np.median(rel) < 0.01
    assert np.allclose(hm.radiance[:6, :6], rad[:6, :6], rtol=tol)
    assert not hm.clipped.any() and not hm.underexposed.any()


def test_hdr_merge_ignores_clipped_pixels_unlike_plain_average(hdr_scene):
    """Giving the clipped exposures any weight (a plain average of x/t) ruins the sun."""
    rad, times = hdr_scene
    codes = simulate_brackets(rad, times)
    lin = [srgb_decode(c / 255.0) for c in codes]
    naive = np.mean([x / t for x, t in zip(lin, times)], axis=0)
    assert abs(naive[0, 0, 0] / 2000.0 - 1) > 0.5
    hm = hdr.merge_exposures(lin, times)
    assert abs(hm.radiance[0, 0, 0] / 2000.0 - 1) < 0.02


def test_hdr_merge_fallback_when_clipped_everywhere(hdr_scene):
    rad, times = hdr_scene
    rad = rad.copy()
    rad[:6, :6] = 1e5  # brighter than the darkest exposure can hold
    codes = simulate_brackets(rad, times)
    lin = [srgb_decode(c / 255.0) for c in codes]
    hm = hdr.merge_exposures(lin, times)
    assert hm.clipped[:6, :6].all() and hm.clipped.sum() == 36
    # a lower bound: the darkest exposure's clipped value over its time
    assert np.allclose(hm.radiance[:6, :6], lin[-1][:6, :6] / times[-1])
    assert (hm.radiance[:6, :6] < 1e5).all()


def test_recovered_response_merge(hdr_scene):
    """A gamma-2.2 camera (not sRGB): OpenCV's Debevec calibration, then our merge."""
    rad, times = hdr_scene
    codes = simulate_brackets(rad, times, encode="gamma")
    resp = hdr.recover_response(codes, times, method="debevec")
    assert np.all(np.diff(resp, axis=0) >= 0)
    hm = hdr.merge_exposures([hdr.apply_response(c, resp) for c in codes], times,
                               saturated=[(c == 255).any(-1) for c in codes])
    ratio = hm.radiance / rad
    k = np.median(ratio)
    rel = np.abs(ratio / k - 1)
    print(f"recovered response: median error {100 * np.median(rel):.2f}%, p99 {100 * np.percentile(rel, 99):.2f}%")
    assert np.median(rel) < 0.03
    assert np.percentile(rel, 99) < 0.10


def test_merge_rejects_bad_input():
    a = np.zeros((4, 4, 3))
    with pytest.raises(InputError, match="differ in size"):
        hdr.merge_exposures([a, np.zeros((4, 5, 3))], [1, 2])
    with pytest.raises(InputError, match="positive"):
        hdr.merge_exposures([a, a], [1, 0])
    with pytest.raises(InputError, match="exposure times"):
        hdr.merge_exposures([a, a], [1])


# ------------------------------------------------------------------------------ CLI


def cli(argv) -> int:
    """Run a sub-command through its own parser (independent of other commands)."""
    from bubblefit.cli import check_capture, envmap

    parser = argparse.ArgumentParser(prog="bubblefit")
    sub = parser.add_subparsers(dest="command")
    envmap.register(sub)
    check_capture.register(sub)
    args = parser.parse_args([str(a) for a in argv])
    try:
        return int(args.func(args) or 0)
    except BubblefitError as exc:
        print(f"bubblefit: error: {exc}")
        return exc.exit_code


def write_exposure(path, codes, exposure_time=None):
    spec = oiio.ImageSpec(codes.shape[1], codes.shape[0], 3, oiio.UINT8)
    if exposure_time is not None:
        spec.attribute("ExposureTime", float(exposure_time))
        spec.attribute("FNumber", 8.0)
        spec.attribute("Exif:WhiteBalance", 1)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(codes))
    out.close()


def test_cli_envmap_hdr_brackets(smooth_env, tmp_path):
    env = smooth_env / (smooth_env @ LUM).max() * 400.0  # brightest sky 400, darkest parts ~10 stops lower
    ball = render_ball(env, 128, cx=63.3, cy=64.6, r=54.0, bg=0.05)
    times = [1 / 4, 1 / 16, 1 / 64, 1 / 256, 1 / 1024]
    paths = []
    for k, c in enumerate(simulate_brackets(ball, times, seed=3)):
        p = tmp_path / f"probe_{k}.png"
        write_exposure(p, c, times[k])
        paths.append(p)
    out = tmp_path / "env.exr"
    js = tmp_path / "env.json"
    assert cli(["envmap", *paths, "-o", out, "--height", 64, "--json", js, "--mask", tmp_path / "mask.png"]) == 0
    got = read_image(out).pixels
    assert got.shape == (64, 128, 3)
    assert (tmp_path / "env.png").exists() and (tmp_path / "mask.png").exists()
    summary = json.loads(js.read_text())
    assert summary["bracket_stops"] == pytest.approx(8.0)
    assert abs(summary["ball"]["r"] - 54.0) < 0.7
    dirs = texel_centres(64, 128)
    valid = read_image(tmp_path / "mask.png").pixels[..., 0] > 0.5
    well = valid & (angle_from(dirs, [0, 0, -1]) > 40)
    err = weighted_rel_error(got, env, well)
    print(f"CLI envmap error {100 * err:.2f}%")
    assert err < 0.06


def test_cli_envmap_bad_input(tmp_path, capsys):
    c = np.full((32, 32, 3), 100, np.uint8)
    write_exposure(tmp_path / "a.png", c)
    write_exposure(tmp_path / "b.png", np.full((32, 40, 3), 100, np.uint8))
    assert cli(["envmap", tmp_path / "missing.png", "-o", tmp_path / "e.exr"]) == 2
    assert "not found" in capsys.readouterr().out
    assert cli(["envmap", tmp_path / "a.png", tmp_path / "b.png", "-o", tmp_path / "e.exr"]) == 2
    assert "differ in size" in capsys.readouterr().out
    write_exposure(tmp_path / "c.png", c)
    assert cli(["envmap", tmp_path / "a.png", tmp_path / "c.png", "-o", tmp_path / "e.exr"]) == 2
    assert "ExposureTime" in capsys.readouterr().out
    assert cli(["envmap", tmp_path / "a.png", "-o", tmp_path / "e.png"]) == 2
    assert cli(["envmap", tmp_path / "a.png", "-o", tmp_path / "e.exr", "--ball", "1,2"]) == 2
    assert not (tmp_path / "e.exr").exists()


# ------------------------------------------------------------------------------ ball detection
#
# An independent mirror-ball generator: numpy only (its own equirectangular lookup in
# Mitsuba's convention, its own sphere intersection), nothing from bubblefit. A chrome ball
# of reflectance 0.85 reflects an environment map over a plain, dark or busy backdrop,
# seen by an orthographic camera or by a pinhole camera at a few ball radii; 4 x 4 samples
# per pixel give the rim its soft, partial-coverage edge; photon and read noise, then 8-bit
# sRGB codes, make it a photograph.

PROBES = Path(__file__).parent / "data" / "probes"


def gen_lookup(env: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear equirectangular lookup: u = atan2(x, -z) / 2 pi, v = acos(y) / pi, texel
    column u W - 1/2 (wrapping), row v (H - 1)."""
    h, w = env.shape[:2]
    u = (np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    x, y = u * w - 0.5, v * (h - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = (x - x0)[..., None], np.clip(y - y0, 0, 1)[..., None]
    x0, x1 = x0 % w, (x0 + 1) % w
    return (1 - fy) * ((1 - fx) * env[y0, x0] + fx * env[y0, x1]) + fy * ((1 - fx) * env[y0 + 1, x0] + fx * env[y0 + 1, x1])


def gen_env(kind: str) -> np.ndarray:
    if kind == "courtyard":  # a real CC0 map, read without bubblefit
        buf = oiio.ImageBuf(str(DATA / "courtyard.exr"))
        return np.asarray(buf.get_pixels(oiio.FLOAT))[..., :3].astype(np.float64)
    h, w = 64, 128
    th = np.pi * (np.arange(h) / (h - 1))[:, None] * np.ones((1, w))
    ph = 2 * np.pi * ((np.arange(w) + 0.5) / w)[None, :] * np.ones((h, 1))
    sky = np.stack([0.5 + 0 * th, 0.7 + 0 * th, 1.2 + 0 * th], -1) * (1 + np.cos(th))[..., None]
    ground = (0.15 + 0.1 * (np.sin(6 * ph) > 0))[..., None] * np.array([0.9, 0.7, 0.5])
    env = np.where((th < np.pi / 2)[..., None], sky, ground)
    env[(np.abs(th - 0.6) < 0.08) & (np.abs(ph - 2.0) < 0.12)] = [50.0, 45.0, 40.0]  # a sun
    return env


def gen_backdrop(kind: str, h: int, w: int, seed: int = 0) -> np.ndarray:
    if kind == "plain":
        return np.ones((h, w, 3)) * [0.35, 0.33, 0.30]
    if kind == "dark":
        return np.ones((h, w, 3)) * [0.012, 0.011, 0.013]
    cells = np.random.default_rng(seed).random((h // 10 + 2, w // 10 + 2, 3))
    yy, xx = np.mgrid[0:h, 0:w]
    stripes = 0.5 + 0.5 * np.sin(0.3 * xx + 0.17 * yy)
    return (0.6 * cells[yy // 10, xx // 10] + 0.4 * stripes[..., None] * [1.0, 0.6, 0.3]) ** 2.2


def gen_ball(env, shape, cx, cy, r, *, distance=None, backdrop="plain", reflectance=0.85, ss=4):
    """Linear radiance of a mirror ball whose outline is the circle (cx, cy, r) in pixels."""
    h, w = shape
    back = gen_backdrop(backdrop, h, w)
    acc = np.zeros((h, w, 3))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    for a in range(ss):
        for b in range(ss):
            px, py = xx + (a + 0.5) / ss, yy + (b + 0.5) / ss
            if distance is None:
                x, y = (px - cx) / r, -(py - cy) / r
                hit = x * x + y * y < 1
                n = np.stack([x, y, np.sqrt(np.clip(1 - x * x - y * y, 0, 1))], -1)
                d = np.broadcast_to([0.0, 0.0, -1.0], n.shape)
            else:  # pinhole at (0, 0, distance) looking along -z; the outline's radius is r px
                f = r / math.tan(math.asin(1.0 / distance))
                d = np.stack([(px - cx) / f, -(py - cy) / f, -np.ones_like(px)], -1)
                d = d / np.linalg.norm(d, axis=-1, keepdims=True)
                bq = d[..., 2] * distance
                disc = bq * bq - (distance ** 2 - 1)
                hit = disc > 0
                t = -bq - np.sqrt(np.maximum(disc, 0))
                n = np.array([0.0, 0.0, distance]) + t[..., None] * d
                n = n / np.linalg.norm(n, axis=-1, keepdims=True)
            refl = d - 2 * np.sum(d * n, -1, keepdims=True) * n
            acc += np.where(hit[..., None], reflectance * gen_lookup(env, refl), back)
    return acc / (ss * ss)


def gen_photo(radiance: np.ndarray, seed: int = 0) -> np.ndarray:
    """Exposed so the 99th percentile sits at 0.9, photon (4000 e- full well) and read noise,
    8-bit sRGB codes, decoded back to linear."""
    rng = np.random.default_rng(seed)
    x = radiance * 0.9 / np.percentile(radiance, 99)
    x = np.clip(x + rng.normal(0, 1, x.shape) * np.sqrt(np.clip(x, 0, None) / 4000 + (2 / 4000) ** 2), 0, 1)
    codes = np.round(np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055) * 255) / 255
    return np.where(codes <= 0.04045, codes / 12.92, ((codes + 0.055) / 1.055) ** 2.4)


@pytest.fixture(scope="module")
def gen_envs():
    return {k: gen_env(k) for k in ("courtyard", "procedural")}


@pytest.mark.parametrize("env_name, backdrop, distance", [
    ("courtyard", "plain", None), ("courtyard", "dark", None), ("courtyard", "busy", None),
    ("courtyard", "plain", 5.0), ("courtyard", "dark", 5.0), ("courtyard", "busy", 5.0),
    ("procedural", "busy", None), ("procedural", "dark", 5.0),
])
def test_find_ball_on_plain_dark_and_busy_backdrops(gen_envs, env_name, backdrop, distance):
    cx, cy, r = 101.3, 90.6, 58.2
    photo = gen_photo(gen_ball(gen_envs[env_name], (192, 208), cx, cy, r, distance=distance, backdrop=backdrop))
    c = ballmod.find_ball(photo)
    print(f"{env_name} {backdrop} {distance}: error ({c.cx - cx:+.2f}, {c.cy - cy:+.2f}, {c.r - r:+.2f}) px")
    assert math.hypot(c.cx - cx, c.cy - cy) < 0.6 and abs(c.r - r) < 0.6


def test_find_ball_in_noise_free_float_render(gen_envs):
    """A linear float render (no noise at all, a sun far above 1) is found like a photograph."""
    cx, cy, r = 101.3, 90.6, 58.2
    rad = gen_ball(gen_envs["procedural"], (192, 208), cx, cy, r, backdrop="dark")
    assert rad.max() > 10
    c = ballmod.find_ball(rad)
    assert math.hypot(c.cx - cx, c.cy - cy) < 0.5 and abs(c.r - r) < 0.5


@pytest.mark.parametrize("seed", [1, 2])
def test_find_ball_refuses_busy_backdrop_without_ball(seed):
    with pytest.raises(InputError, match="no clear mirror-ball outline|no mirror ball found"):
        ballmod.find_ball(gen_photo(gen_backdrop("busy", 192, 208, seed)))


def test_find_ball_refuses_uniform_noise():
    codes = np.random.default_rng(3).integers(0, 256, size=(192, 192, 3))
    with pytest.raises(InputError, match="no mirror ball"):
        ballmod.find_ball(srgb_decode(codes / 255.0))


def mitsuba_probes():
    truth = json.loads((PROBES / "probes_truth.json").read_text())["probes"]
    return [(f, v["ball"]) for k, v in truth.items() for f in v.get("files", [k + ".png"])]


@pytest.mark.parametrize("name, truth", mitsuba_probes())
def test_find_ball_on_mitsuba_probes(name, truth):
    """Mirror balls path traced by Mitsuba 3 (tests/data/probes, with their true outlines):
    never a wrong ball. Over the busy backdrop the outline is found; uniform noise is
    refused. Over the plain dark backdrop (a diffuse plane that also fills the outer ring of
    the reflection, r 51-60 px) a perfect mirror's outline is not in the image at all (the
    ring matches the backdrop to one 8-bit code): there the edge of the backdrop's
    reflection, 10 px inside, must not be taken for the ball."""
    px = read_image(PROBES / name).pixels
    try:
        c = ballmod.find_ball(px)
    except InputError as exc:
        print(f"{name}: refused: {exc}")
        assert truth is None or "dark" in name, f"{name}: the ball was missed: {exc}"
        return
    assert truth is not None, f"{name}: a ball found in noise: {c}"
    err = (c.cx - truth["cx"], c.cy - truth["cy"], c.r - truth["r"])
    print(f"{name}: error ({err[0]:+.2f}, {err[1]:+.2f}, {err[2]:+.2f}) px")
    assert math.hypot(err[0], err[1]) < 0.7 and abs(err[2]) < 0.7


def test_merge_float_exposure_is_not_clipped():
    """A float exposure holds radiance above 1: with its clip level at infinity nothing
    counts as clipped; with an 8-bit clip level the same values would be."""
    x = np.full((4, 4, 3), 0.5)
    x[0, 0] = [40.0, 30.0, 20.0]
    hm = hdr.merge_exposures([x], [1.0], clip_level=[hdr.file_clip_level(32)])
    assert not hm.clipped.any() and np.allclose(hm.radiance, x)
    assert hdr.merge_exposures([x], [1.0], clip_level=hdr.file_clip_level(8)).clipped[0, 0]


def test_cli_envmap_float_probe_is_not_warned_as_clipped(tmp_path, capsys):
    from bubblefit.cli import main

    out, js = tmp_path / "env.exr", tmp_path / "env.json"
    rc = main(["envmap", str(PROBES / "ball_dark_ortho.exr"), "-o", str(out), "--ball", "104,88,60",
               "--height", "32", "--json", str(js)])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "clipped" not in err
    assert json.loads(js.read_text())["clipped_pixels_in_ball"] == 0


def test_cli_envmap_distance_inside_the_ball_is_one_line(tmp_path, capsys):
    from bubblefit.cli import main

    out = tmp_path / "env.exr"
    for d in ("0.5", "1", "-3", "inf", "nan"):
        rc = main(["envmap", str(PROBES / "ball_busy_persp.png"), "-o", str(out), "--distance", d])
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert rc == 2 and len(err) == 1 and "--distance" in err[0] and "ball radii" in err[0], err
    assert not out.exists()
    with pytest.raises(InputError, match="must exceed 1"):
        probe.unwrap_mirror_ball(np.zeros((32, 32, 3)), ballmod.Circle(16, 16, 12), height=8, distance=0.5)


@pytest.mark.parametrize("how", ["preview", "json", "mask", "hardlink"])
def test_cli_envmap_refuses_to_overwrite_the_probe(tmp_path, capsys, how):
    from bubblefit.cli import main

    src = tmp_path / "probe.png"
    src.write_bytes((PROBES / "ball_busy_ortho.png").read_bytes())
    before = src.read_bytes()
    argv = ["envmap", str(src), "--height", "16", "-o", str(tmp_path / "probe.exr" if how == "preview" else tmp_path / "m.exr")]
    if how == "json":
        argv += ["--json", str(src)]
    elif how == "mask":
        argv += ["--mask", str(tmp_path / ".." / tmp_path.name / "probe.png")]
    elif how == "hardlink":
        link = tmp_path / "link.png"
        os.link(src, link)
        argv += ["--mask", str(link)]
    rc = main(argv)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc != 0 and len(err) == 1 and "refusing to write" in err[0], err
    assert src.read_bytes() == before
    assert not (tmp_path / "m.exr").exists() and not (tmp_path / "probe.exr").exists()
