"""The physical model's film coloured as Blender Cycles colours it (``film_rgb = "clamped"``).

:func:`bubblefit.model.render.clamped_series` takes each film's reflectance to RGB and
clamps it to [0, 1] per channel before the series; the sphere's render and the dish's
(:mod:`bubblefit.model.cap_render`) both call it. Here the sphere's pixels are checked
against the series written in the test, with its own Airy reflectance (Born & Wolf eq.
7.6(13), Fresnel's amplitudes eq. 1.5(20)-(21)), in a uniform map where every film, every
bounce and the background read the same radiance.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bubblefit.lighting.envmap import EnvMap
from bubblefit.lighting.filtering import FilterConfig
from bubblefit.model.effects import Effects
from bubblefit.model.geometry import OrthographicCamera
from bubblefit.model.render import Params, RenderConfig, render
from bubblefit.optics.spectral import spectral_basis

pytestmark = pytest.mark.usefixtures("x64")

N_FILM, D_NM, BOUNCES, W = 1.4, 450.0, 2, 16
CAM = OrthographicCamera(W, W, W / 2, W / 2, W / 2 - 1)


def _airy_rgb(d_nm, cos_i, basis):
    """RGB (P, 3) of the film's reflectance, s and p averaged: ``4 R1 s / ((1 - R1)^2 + 4 R1 s)``
    with ``s = sin^2(2 pi n d cos t / lambda)`` and ``R1`` Fresnel's single-surface
    reflectance, integrated with the basis' weights."""
    lam = np.asarray(basis.wavelengths, np.float64)
    cos_t = np.sqrt(1.0 - (1.0 - cos_i**2) / N_FILM**2)[:, None]
    c = cos_i[:, None]
    s = np.sin(2.0 * np.pi * N_FILM * d_nm * cos_t / lam) ** 2
    total = 0.0
    for r in ((c - N_FILM * cos_t) / (c + N_FILM * cos_t), (N_FILM * c - cos_t) / (N_FILM * c + cos_t)):
        r1 = r * r
        total = total + 4.0 * r1 * s / ((1.0 - r1) ** 2 + 4.0 * r1 * s)
    return (0.5 * total) @ np.asarray(basis.weights, np.float64)


def _pixels():
    """Pixel centres inside the disc (rows, cols) and each front film's incidence cosine."""
    cx, cy, r = CAM.disc()
    ii, jj = np.mgrid[0:W, 0:W]
    x, y = (jj + 0.5 - cx) / r, (ii + 0.5 - cy) / r
    inside = x**2 + y**2 < 0.95
    return inside, np.sqrt(1.0 - x[inside] ** 2 - y[inside] ** 2)


def _render(film_rgb, **effects):
    basis = spectral_basis("uniform", 48)
    fx = Effects(**{"model": "physical", "interference": "airy", "diffuse": False, "filtering": FilterConfig("mirror"),
                    "spectral": basis, "bounces": BOUNCES, **effects})
    cfg = RenderConfig(effects=fx, camera=CAM, chunk=W * W, film_rgb=film_rgb)
    p = Params.make(thickness=D_NM, n_film=N_FILM, roughness=0.0, r_d=0.0, r_s=0.05, dtype=jnp.float64)
    return np.asarray(render(p, cfg, EnvMap.constant(1.0, height=8, dtype=jnp.float64))), basis


def test_clamped_sphere_is_the_rgb_series_of_clamped_films():
    """Every film reads the map's radiance 1, so a pixel is ``R + (1 - R)^2 (1 + R + ... + R^B)``
    with ``R`` the clamped RGB reflectance (front, background, B internal bounces); the
    spectral film's pixel differs wherever a channel was clamped (a 450 nm film's red
    is negative near normal incidence). Tolerance: float64 rounding of 48-term sums."""
    img, basis = _render("clamped")
    inside, cos = _pixels()
    rgb = _airy_rgb(D_NM, cos, basis)
    clipped = (rgb < 0.0) | (rgb > 1.0)
    assert clipped.any() and (~clipped).all(axis=-1).any()   # both kinds of pixel are tested
    r = np.clip(rgb, 0.0, 1.0)
    ref = r + (1.0 - r) ** 2 * sum(r**k for k in range(BOUNCES + 1))
    np.testing.assert_allclose(img[inside], ref, rtol=1e-9, atol=1e-12)
    spectral, _ = _render("spectral")
    # the reference tells the films apart: the spectral film's pixels miss it by far more
    # than the tolerance where a channel is clamped (in this white map R + T = 1 keeps both
    # near 1: measured 1.5e-4 to 3.2e-4)
    assert np.abs(spectral[inside] - ref)[clipped].max() > 1e4 * 1e-9


def test_clamped_equals_spectral_for_films_inside_the_gamut():
    """With the front film alone (no transmission, no bounces) the two films differ only where
    the film's RGB reflectance leaves [0, 1]: equal to float64 rounding elsewhere."""
    kw = dict(rear_reflection=False, transmission=False)
    clamped, basis = _render("clamped", **kw)
    spectral, _ = _render("spectral", **kw)
    inside, cos = _pixels()
    rgb = _airy_rgb(D_NM, cos, basis)
    ok = ((rgb >= 0.0) & (rgb <= 1.0)).all(axis=-1)
    np.testing.assert_allclose(clamped[inside][ok], spectral[inside][ok], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(clamped[inside][~ok], np.clip(rgb[~ok], 0.0, 1.0), rtol=1e-9, atol=1e-14)
    assert (np.abs(clamped - spectral)[inside][~ok] > 1e-3).any()


def test_film_rgb_is_part_of_the_programs_key():
    """Clamped and spectral configurations never share a compiled program or a stored one
    (the executable store keys on the pickled configuration); a bad value is refused."""
    from bubblefit.io.executables import _static_bytes

    fx = Effects(model="physical")
    a, b = RenderConfig(effects=fx), RenderConfig(effects=fx, film_rgb="clamped")
    assert a != b and hash(a) != hash(b) and _static_bytes(a) != _static_bytes(b)
    with pytest.raises(ValueError, match="film_rgb"):
        RenderConfig(effects=fx, film_rgb="srgb")
