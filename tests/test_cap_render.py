"""A bubble on a dish: the cap's render against an independent numpy ray trace of a few pixels.

The reference is written here from the sphere-plane geometry (the ray-sphere quadratic,
the plane ``y = plane_y``), a plane mirror's law, Fresnel's formulae for the liquid and
the Airy sum of a film in air (Born & Wolf 1.5.2 and 7.6.1), per polarisation, averaged
after the products. The map is two-toned, one radiance above the horizon and one below,
so every looked-up direction (kept away from the horizon) reads a known value; the
package's spectral weights are the data table that turns a spectrum into RGB.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import pinhole_ray

from bubblefit.lighting.envmap import EnvMap
from bubblefit.lighting.filtering import FilterConfig
from bubblefit.model.cap import Cap
from bubblefit.model.cap_render import CapConfig, render_cap
from bubblefit.model.effects import Effects
from bubblefit.model.geometry import PerspectiveCamera
from bubblefit.model.render import Params, RenderConfig
from bubblefit.optics import spectral

N_FILM, N_LIQ, D_NM = 1.38, 1.333, 420.0
UP, DOWN = np.array([1.0, 0.8, 0.6]), np.array([0.15, 0.3, 0.5])
W = H = 48


def _env():
    pix = np.zeros((64, 128, 3))
    pix[:32], pix[32:] = UP, DOWN
    return EnvMap.from_array(pix)


def _fresnel(cos_i, n1, n2):
    """Amplitude reflection (r_s, r_p) from n1 to n2."""
    sin_t = n1 / n2 * np.sqrt(1 - cos_i**2)
    cos_t = np.sqrt(1 - sin_t**2)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return np.array([rs, rp]), cos_t


def _film_r(cos_i, lam):
    """Airy reflectance of a film of N_FILM in air, (K, 2) per polarisation."""
    r01, cos_t = _fresnel(cos_i, 1.0, N_FILM)
    r12 = -r01
    phase = np.exp(1j * 4 * np.pi * N_FILM * D_NM * cos_t / lam)[:, None]
    r = (r01[None] + r12[None] * phase) / (1 + r01[None] * r12[None] * phase)
    return np.abs(r) ** 2


def _light(w):
    """Radiance along w: the map above the horizon; below, the liquid's Fresnel reflectance
    times the map along the mirrored direction (always above: UP). Directions within 6
    degrees of the horizon, where the map's bilinear lookup blends its two tones, are
    refused (NaN: the pixel is skipped)."""
    if abs(w[1]) < 0.1:
        return np.full(3, np.nan), 1.0
    if w[1] > 0:
        return UP, 1.0
    r, _ = _fresnel(abs(w[1]), 1.0, N_LIQ)
    return UP, float(np.mean(r**2))


def _sphere(o, d, c, rad):
    oc = o - c
    b = oc @ d
    disc = b * b - (oc @ oc - rad * rad)
    if disc <= 0:
        return None
    return -b - math.sqrt(disc), -b + math.sqrt(disc)


def _reference(cam, cap, i, j, basis, film_rgb="spectral"):
    o, d = pinhole_ray(cam, i, j)
    c = np.asarray(cap.center, float)
    weight, kind = 1.0, "direct"
    hit = _sphere(o, d, c, cap.radius)
    if hit is None or (o + hit[0] * d)[1] < cap.plane_y:   # not the cap: the liquid, then its mirror ray
        s = (cap.plane_y - o[1]) / d[1]
        if d[1] >= 0 or s <= 0:
            return None, "sky"
        weight = float(np.mean(_fresnel(abs(d[1]), 1.0, N_LIQ)[0] ** 2))
        o, d = o + s * d, d * np.array([1, -1, 1])
        hit = _sphere(o, d, c, cap.radius)
        if hit is None or hit[0] <= 0:
            return weight * UP, "liquid"
        kind = "mirror"
    p0, p1 = o + hit[0] * d, o + hit[1] * d
    n0 = (p0 - c) / cap.radius
    cos = abs(n0 @ d)
    lam = np.asarray(basis.wavelengths)
    R = _film_r(cos, lam)
    T = 1 - R
    rgb = lambda spec: spec.mean(-1) @ np.asarray(basis.weights)   # average polarisations, integrate
    if film_rgb == "clamped":   # each film's RGB reflectance clamped first, the series per channel
        Rc = np.clip(rgb(R), 0.0, 1.0)
        R, T = Rc[None, :, None], (1 - Rc)[None, :, None]
        rgb = lambda spec: spec[0, :, 0]
    front_dir = d - 2 * (d @ n0) * n0
    L, w = _light(front_dir)
    out = rgb(R) * L * w
    if p1[1] >= cap.plane_y:
        n1 = (p1 - c) / cap.radius
        rear_dir = d - 2 * (d @ n1) * n1
        L, w = _light(rear_dir)
        out = out + rgb(T * R * T) * L * w
        Lb, wb = _light(d)
    else:   # the liquid inside the foot reflects d upwards onto the cap's wall, which reflects it
        q = p0 + (cap.plane_y - p0[1]) / d[1] * d
        e = d * np.array([1, -1, 1])
        wall = q + _sphere(q, e, c, cap.radius)[1] * e
        nw = (wall - c) / cap.radius
        w_liq = float(np.mean(_fresnel(abs(d[1]), 1.0, N_LIQ)[0] ** 2))
        L, w = _light(e - 2 * (e @ nw) * nw)
        out = out + rgb(T * R * T) * L * w * w_liq
        Lb, wb = _light(d)
    out = out + rgb(T * T) * Lb * wb
    return weight * out, kind


@pytest.mark.parametrize("plane_y, origin, film_rgb", [(-0.35, (0.5, 1.5, 4.0), "spectral"),
                                                       (0.0, (-0.6, 2.2, 3.6), "clamped")])
def test_cap_pixels_match_an_independent_trace(plane_y, origin, film_rgb):
    """One rear reflection; the cap seen directly (its rear film above the plane, or the
    liquid inside the foot and the wall it reflects onto, at the front film's angle: the
    hemisphere is exact there), its mirror image, and the liquid reflecting the map."""
    cam = PerspectiveCamera(W, H, origin=origin, target=(0.0, 0.1, 0.0), fov_deg=42.0)
    cap = Cap((0.0, 0.0, 0.0), 1.0, plane_y, N_LIQ)
    basis = spectral.spectral_basis("uniform", 24, illuminant="E")
    fx = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                 spectral=basis, bounces=1, thickness="constant")
    cfg = CapConfig.of(RenderConfig(effects=fx, camera=cam, center=cap.center, radius=cap.radius), cap, film_rgb)
    img = np.asarray(render_cap(Params.make(thickness=D_NM, n_film=N_FILM, exposure=1.0, roughness=0.0), cfg,
                                _env()))
    seen = set()
    rng = np.random.default_rng(1)
    for i, j in rng.integers(4, W - 4, size=(400, 2)):
        ref, kind = _reference(cam, cap, i, j, basis, film_rgb)
        if ref is None or not np.all(np.isfinite(ref)):
            continue
        seen.add(kind)
        # float32 rays and film optics: a few 1e-5 relative
        np.testing.assert_allclose(img[i, j], ref, rtol=1e-3, atol=1e-5, err_msg=f"{kind} pixel {i},{j}")
    assert {"direct", "mirror", "liquid"} <= seen


TOP, BOTTOM, EXPONENT = 150.0, 1000.0, 1.6


def _drained(point, cap):
    """The cap's drainage profile at a film point: ``top + (bottom - top) u^exponent`` with
    ``u = (y_top - y) / H``, 0 at the cap's top and 1 at its foot."""
    y_top = cap.center[1] + cap.radius
    u = np.clip((y_top - point[1]) / (y_top - cap.plane_y), 0.0, 1.0)
    return TOP + (BOTTOM - TOP) * u**EXPONENT


def _film_rd(cos_i, lam, d_nm):
    """Airy reflectance of a film of N_FILM and thickness ``d_nm`` in air, (K, 2)."""
    r01, cos_t = _fresnel(cos_i, 1.0, N_FILM)
    phase = np.exp(1j * 4 * np.pi * N_FILM * d_nm * cos_t / lam)[:, None]
    r = (r01[None] - r01[None] * phase) / (1 - r01[None] ** 2 * phase)
    return np.abs(r) ** 2


def _drainage_reference(cam, cap, i, j, basis):
    """A pixel seen directly of a hemisphere (``plane_y`` through the centre) whose film
    drains: each film the light crosses or leaves at its own thickness. One rear
    reflection, at the rear film (above the plane) or on the wall the liquid inside the foot
    reflects the ray onto; the reflected ray leaves through the film where its chord ends
    (None where that lies below the plane, or the pixel is not the cap seen directly)."""
    o, d = pinhole_ray(cam, i, j)
    c = np.asarray(cap.center, float)
    hit = _sphere(o, d, c, cap.radius)
    if hit is None or (o + hit[0] * d)[1] < cap.plane_y:
        return None
    p0, p1 = o + hit[0] * d, o + hit[1] * d
    cos = abs((p0 - c) / cap.radius @ d)   # every film of a chord, and of the mirrored chord, at this angle
    lam = np.asarray(basis.wavelengths)
    rgb = lambda spec: spec.mean(-1) @ np.asarray(basis.weights)
    R = lambda point: _film_rd(cos, lam, _drained(point, cap))
    chord_end = lambda q, e: q + _sphere(q, e, c, cap.radius)[1] * e
    front_dir = d - 2 * (d @ ((p0 - c) / cap.radius)) * ((p0 - c) / cap.radius)
    L, w = _light(front_dir)
    out = rgb(R(p0)) * L * w
    w_liq = 1.0
    if p1[1] >= cap.plane_y:
        mirror, e_in = p1, d
    else:   # the liquid inside the foot reflects d upwards onto the wall
        q = p0 + (cap.plane_y - p0[1]) / d[1] * d
        e_in = d * np.array([1, -1, 1])
        mirror = chord_end(q, e_in)
        w_liq = float(np.mean(_fresnel(abs(d[1]), 1.0, N_LIQ)[0] ** 2))
    nm = (mirror - c) / cap.radius
    e_out = e_in - 2 * (e_in @ nm) * nm
    exit_point = chord_end(mirror, e_out)
    if exit_point[1] < cap.plane_y:
        return None
    L, w = _light(e_out)
    T0, Rm, Tm, Tx = 1 - R(p0), R(mirror), 1 - R(mirror), 1 - R(exit_point)
    out = out + rgb(T0 * Rm * Tx) * L * w * w_liq
    Lb, wb = _light(e_in)
    return out + rgb(T0 * Tm) * Lb * wb * w_liq


def test_a_draining_cap_reads_each_film_at_its_own_height():
    """A drainage film on a hemisphere: where the ray meets the liquid inside the foot, the
    wall it reflects onto (and the film it leaves by) is as thin as its height says, not
    the rear hit below the plane, which the light never reaches."""
    cam = PerspectiveCamera(W, H, origin=(0.7, 1.7, 4.8), target=(0.0, 0.25, 0.0), fov_deg=42.0)
    cap = Cap((0.0, 0.0, 0.0), 1.0, 0.0, N_LIQ)
    basis = spectral.spectral_basis("uniform", 24, illuminant="E")
    fx = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                 spectral=basis, bounces=1, thickness="drainage")
    cfg = CapConfig.of(RenderConfig(effects=fx, camera=cam, center=cap.center, radius=cap.radius), cap)
    img = np.asarray(render_cap(Params.make(thickness=np.array([TOP, BOTTOM, EXPONENT]), n_film=N_FILM,
                                            exposure=1.0, roughness=0.0), cfg, _env()))
    foot = 0
    for i, j in np.ndindex(W, H):
        ref = _drainage_reference(cam, cap, i, j, basis)
        if ref is None or not np.all(np.isfinite(ref)):
            continue
        o, d = pinhole_ray(cam, i, j)
        foot += bool((o + _sphere(o, d, np.zeros(3), 1.0)[1] * d)[1] < 0.0)
        # float32 rays and film optics: a few 1e-5 relative
        np.testing.assert_allclose(img[i, j], ref, rtol=1e-3, atol=1e-5, err_msg=f"pixel {i},{j}")
    assert foot >= 20, foot


@pytest.mark.slow
def test_fit_of_a_cap_recovers_its_thickness_from_a_noisy_8bit_render(tmp_path):
    """Known film -> render (4 rays per pixel) -> Poisson-Gaussian noise and 8-bit sRGB ->
    the ``fit`` command -> the thickness within its standard errors' reach."""
    from bubblefit.inverse.cap_fit import cap_config
    from bubblefit.model.cap_scene import parse_cap_scene

    size, truth_nm, expo = 56, 540.0, 0.6
    pix = np.zeros((64, 128, 3))
    v = (np.arange(64) + 0.5) / 64
    u = (np.arange(128) + 0.5) / 128
    # a sky brighter towards the zenith with a warm band, a dim ground: colours in every direction
    pix[:] = (0.4 + 0.6 * np.cos(np.pi * v)[:, None, None].clip(0) * np.array([0.6, 0.8, 1.0])
              + 0.5 * np.exp(-((u - 0.3) / 0.08) ** 2)[None, :, None] * np.array([1.0, 0.7, 0.3]))
    pix[32:] *= 0.2
    from bubblefit.io.images import write_image

    write_image(str(tmp_path / "env.exr"), pix.astype(np.float32))
    text = (f'[film]\nshape = "cap"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nplane_y = -0.25\nliquid = "water"\n'
            f'n = 1.4\nthickness = "constant"\nrange_nm = [0.0, 1200.0]\n\n[environment]\npath = "env.exr"\n\n'
            f'[camera]\ntype = "perspective"\nwidth = {size}\nheight = {size}\norigin = [0.3, 1.5, 4.5]\n'
            f'target = [0.0, 0.0, 0.0]\nfov_deg = 36.0\n')
    (tmp_path / "scene.toml").write_text(text)
    import tomllib

    scene = parse_cap_scene(tomllib.loads(text), tmp_path)
    from bubblefit.model.scene import read_envmap

    img = np.asarray(render_cap(Params.make(thickness=truth_nm, n_film=1.4, exposure=expo, roughness=0.0),
                                cap_config(scene, "constant", samples_per_pixel=4), read_envmap(scene.envmap)))
    from helpers import fit_scene_photo

    res = fit_scene_photo(img, tmp_path, seed=7, timeout=600)
    d, se = res["params"]["thickness_nm"], res["stderr"]["thickness_nm"]
    # the standard error holds the 0.6 nm model error; the photo's own error is ~0.1 nm,
    # the 8-bit quantisation of dark pixels a bias of the same order: 3 standard errors
    assert abs(d - truth_nm) <= 3 * se, (d, se)
    assert abs(res["params"]["exposure"] / expo - 1) < 0.01
    assert res["ok"], res["warnings"]
    assert res["skipped_light_paths"]
    # the model's own photo: an outlier (chi^2 over 30 in 3 channels) has a chance of 1.4e-6
    # per pixel, so among a few thousand pixels none is expected; 1 % would be a misfit
    assert res["outlier_fraction"] < 0.01, res["outlier_fraction"]


@pytest.mark.parametrize("film, camera_origin, words", [
    ("plane_y = -2.5", "[0.0, 1.0, 5.0]", "taller than its sphere"),
    ("plane_y = 1.2", "[0.0, 2.0, 5.0]", "above the sphere"),
    ("plane_y = -0.3", "[0.0, -1.0, 5.0]", "below the liquid"),
    ("plane_y = -0.3\nthickness = \"map\"", "[0.0, 1.0, 5.0]", "film.thickness of a cap"),
])
def test_a_bad_cap_scene_is_one_line(tmp_path, film, camera_origin, words):
    import tomllib

    from bubblefit.errors import InputError
    from bubblefit.io.images import write_image
    from bubblefit.model.cap_scene import parse_cap_scene

    write_image(str(tmp_path / "env.exr"), np.ones((8, 16, 3), np.float32))
    text = (f'[film]\nshape = "cap"\nradius = 1.0\n{film}\n[environment]\npath = "env.exr"\n'
            f'[camera]\ntype = "perspective"\nwidth = 32\nheight = 32\norigin = {camera_origin}\n'
            'target = [0.0, 0.0, 0.0]\n')
    with pytest.raises(InputError, match=words) as err:
        parse_cap_scene(tomllib.loads(text), tmp_path)
    assert "\n" not in str(err.value)
