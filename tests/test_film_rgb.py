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


def _facet_mean_rgb(d_nm, cos_i, basis, a, nodes=48):
    """The clamped RGB reflectance averaged over the visible facets of Ward's lobe of width
    ``a``, by a dense product Gauss-Hermite rule over both slopes ``(p, q)`` (each normal
    with variance ``a^2 / 2``), each facet's incidence ``(cos_i + p sin_i) / sqrt(1 + p^2 + q^2)``
    and visible area ``max(cos_i + p sin_i, 0)`` written out here (Heitz 2014)."""
    z, w = np.polynomial.hermite_e.hermegauss(nodes)
    w = w / w.sum()
    sig = a / np.sqrt(2.0)
    p, q = np.meshgrid(sig * z, sig * z, indexing="ij")
    wpq = np.outer(w, w)
    c = cos_i[:, None, None]
    s = np.sqrt(1.0 - c**2)
    area = np.maximum(c + p * s, 0.0)
    cos_h = np.clip((c + p * s) / np.sqrt(1.0 + p**2 + q**2), 1e-6, 1.0)
    rgb = np.clip(_airy_rgb(d_nm, cos_h.reshape(-1), basis).reshape(cos_h.shape + (3,)), 0.0, 1.0)
    weight = (wpq * area)[..., None]
    return (weight * rgb).sum(axis=(1, 2)) / weight.sum(axis=(1, 2)), rgb.reshape(len(cos_i), -1, 3)


def test_rough_clamped_film_is_the_mean_over_visible_facets():
    """On a rough film the clamped colour is the mean over the lobe's visible facets of the
    film at each facet's angle, as Cycles samples it: the front film's render (three Gauss-Hermite
    nodes in the in-plane slope, brdf.facet_cosines) against a 48 x 48 product rule over
    both slopes written here. Where no facet of a pixel crosses a clamp the integrand is
    smooth, and the three-node rule's error on the film's first harmonic of phase slope
    ``k`` is ``|exp(-x^2/2) - 2/3 - cos(sqrt(3) x) / 3|`` at ``x = k a / sqrt(2)``
    (A&S 25.4.46), the second harmonic's at ``2x``; the cross slope's mean square adds
    ``O(a^4)`` to the cosine. The mean over facets must also differ from the film at the
    mean surface's angle by far more than that bound (a = 0.04: the filled-in minima)."""
    a = 0.04
    basis = spectral_basis("uniform", 48)
    front = dict(rear_reflection=False, transmission=False)           # the pixel is the front film's R
    fx = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                 spectral=basis, bounces=BOUNCES, **front)
    cfg = RenderConfig(effects=fx, camera=CAM, chunk=W * W, film_rgb="clamped")
    p = Params.make(thickness=D_NM, n_film=N_FILM, roughness=a, r_d=0.0, r_s=0.05, dtype=jnp.float64)
    img = np.asarray(render(p, cfg, EnvMap.constant(1.0, height=8, dtype=jnp.float64)))
    mirror, _ = _render("clamped", **front)
    inside, cos = _pixels()
    ref, facets = _facet_mean_rgb(D_NM, cos, basis, a)
    smooth = (((facets > 0.0) & (facets < 1.0)).all(axis=1) | (facets <= 0.0).all(axis=1)).all(axis=-1)
    assert smooth.sum() > 20 and (~smooth).any()
    lam_min = float(np.min(basis.wavelengths))
    cos_t = np.sqrt(1.0 - (1.0 - cos**2) / N_FILM**2)
    k = 4.0 * np.pi * N_FILM * D_NM / lam_min * cos * np.sqrt(1.0 - cos**2) / (N_FILM**2 * cos_t)
    x = k * a / np.sqrt(2.0)
    e3 = lambda v: np.abs(np.exp(-v**2 / 2) - 2.0 / 3.0 - np.cos(np.sqrt(3.0) * v) / 3.0)
    amp = facets.max(axis=(1, 2))[:, None]           # the harmonics' amplitude is at most the film's RGB
    bound = 2.0 * amp * (e3(x) + e3(2 * x) + 4.0 * np.pi * N_FILM * D_NM / lam_min * (a * a / 2) ** 2)[:, None]
    err = np.abs(img[inside] - ref)
    off = np.abs(mirror[inside] - ref)                # the film at the mean surface's angle
    assert (err[smooth] <= bound[smooth]).all(), float((err - bound)[smooth].max())
    assert (off[smooth] > 10 * bound[smooth]).any()
    # across a clamp the integrand has a kink, which three nodes follow only roughly (4 % of
    # the mirror film's error here): the facets' mean must still take most of that error away
    assert err[~smooth].max() < 0.25 * off[~smooth].max()


def _ggx_visible_mean(f, cos_v, alpha):
    """The mean of ``f(w_i . h)`` over GGX's visible normals (Heitz, JCGT 3(2), 2014, eq. 2:
    ``max(w_i . h, 0) D(h) / ((1 + Lambda(w_i)) cos_v)``, ``D`` Walter et al. 2007's eq. 33,
    ``Lambda`` Smith's for GGX, Heitz 2014 eq. 72) by scipy's adaptive ``dblquad`` over
    the normal's polar and azimuthal angles (the half ``phi`` in [0, pi], doubled), split at
    ``5 alpha`` where the lobe's peak ends."""
    from scipy.integrate import dblquad

    sin_v = np.sqrt(1.0 - cos_v**2)

    def g(phi, th):
        vh = sin_v * np.sin(th) * np.cos(phi) + cos_v * np.cos(th)
        if vh <= 0.0:
            return 0.0
        d = 1.0 / (np.pi * alpha**2 * np.cos(th) ** 4 * (1.0 + np.tan(th) ** 2 / alpha**2) ** 2)
        return f(vh) * vh * d * np.sin(th)

    lam = 0.5 * (np.sqrt(1.0 + alpha**2 * (sin_v / cos_v) ** 2) - 1.0)
    edge = 5.0 * alpha
    total = sum(dblquad(g, a, b, 0.0, np.pi, epsabs=0.0, epsrel=1e-6)[0] for a, b in ((0.0, edge), (edge, np.pi / 2)))
    return 2.0 * total / ((1.0 + lam) * cos_v)


def test_ggx_visible_facets_against_an_independent_quadrature():
    """``brdf.ggx_facet_cosines`` (Heitz 2018's map of the unit square, Gauss-Legendre in
    ``sqrt(1 - u1)`` x midpoints in the angle) against scipy's adaptive quadrature of GGX's
    visible-normal density over the hemisphere, at the rough Cycles case's width (alpha =
    0.0225) and two cosines. The density's normalisation is checked by ``f = 1`` (the
    quadrature's own tolerance, 1e-6 relative, times ten); a smooth ``f = (w_i . h)^4`` to
    1e-4 (the rule converges geometrically on an analytic integrand: 1.4e-5 at worst
    measured); and a 700 nm film's first harmonic clipped at 0 (the clamped film's kink),
    which the rule must hold to a quarter of what separates GGX's visible facets from
    Ward's (``brdf.facet_cosines``), the difference a fit's Type B term is built from
    (measured: 0.07 and 0.01 of it). At ``alpha = 0`` every node is the ray's own cosine."""
    from bubblefit.optics import brdf

    alpha = 0.0225
    film = lambda x: max(0.0, np.cos(2.0 * np.pi * 2.0 * 1.33 * 700.0 * x / 620.0))
    for cos_v in (0.9, 0.5):
        nodes, w = (np.asarray(a, np.float64) for a in brdf.ggx_facet_cosines(np.array([cos_v]), alpha))
        ward_c, ward_w = brdf.facet_cosines(np.array([cos_v]), alpha)
        rule = lambda f: float(np.vectorize(f)(nodes[:, 0]) @ w)
        if cos_v == 0.5:
            assert abs(_ggx_visible_mean(lambda x: 1.0, cos_v, alpha) - 1.0) < 1e-5
        assert abs(rule(lambda x: x**4) - _ggx_visible_mean(lambda x: x**4, cos_v, alpha)) < 1e-4
        ref = _ggx_visible_mean(film, cos_v, alpha)
        ward = sum(float(b[0]) * film(float(a[0])) for a, b in zip(ward_c, ward_w))
        assert abs(rule(film) - ref) < 0.25 * abs(ward - ref), (rule(film), ref, ward)
    c0, _ = brdf.ggx_facet_cosines(np.array([0.3, 0.8]), 0.0)
    assert np.allclose(np.asarray(c0), [0.3, 0.8], atol=1e-6)


def test_ggx_facets_are_part_of_the_programs_key():
    """The render with GGX's facets is another program (and stored one); at a mirror it is
    the model's render; a bad value is refused."""
    from bubblefit.io.executables import _static_bytes

    fx = Effects(model="physical")
    a, b = RenderConfig(effects=fx, film_rgb="clamped"), RenderConfig(effects=fx, film_rgb="clamped", facets="ggx")
    assert a != b and _static_bytes(a) != _static_bytes(b)
    with pytest.raises(ValueError, match="facets"):
        RenderConfig(effects=fx, facets="beckmann")
    basis = spectral_basis("uniform", 48)
    fx = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                 spectral=basis, bounces=BOUNCES)
    p = Params.make(thickness=700.0, n_film=N_FILM, roughness=0.0, r_d=0.0, r_s=0.05, dtype=jnp.float64)
    env = EnvMap.constant(1.0, height=8, dtype=jnp.float64)
    imgs = [np.asarray(render(p, RenderConfig(effects=fx, camera=CAM, chunk=W * W, film_rgb="clamped", facets=f),
                              env)) for f in ("ward", "ggx")]
    assert np.abs(imgs[0] - imgs[1]).max() < 1e-12


def test_microfacet_offsets_only_for_a_rough_clamped_film(monkeypatch):
    """The colour check's Type B offsets of the microfacet distribution
    (``colour_check.microfacet_offsets``) are rendered only where the model averages the
    film over facets (the clamped film) and the film is rougher than ``FACET_MIRROR``; else
    they are None and nothing is rendered. Two sources: one render with GGX's facets at the
    fitted width, and GGX's lobe as the mean of renders at its Ward scale mixture's widths
    (``brdf.ggx_ward_widths``), each less the fit's render."""
    import dataclasses
    from types import SimpleNamespace

    from bubblefit.inverse import _programs
    from bubblefit.inverse.colour_check import FACET_MIRROR, GGX_LOBE_WIDTHS, microfacet_offsets
    from bubblefit.optics.brdf import ggx_ward_widths

    calls = []

    def fake(p, lev, env):  # a render whose value is its lobe width (0.5 with GGX's facets)
        calls.append((lev.cfg.facets, float(p.roughness)))
        return np.full((2, 2, 3), 0.5 if lev.cfg.facets == "ggx" else float(p.roughness))

    monkeypatch.setattr(_programs, "render_bubble", fake)
    fx = Effects(model="physical")
    rough = Params.make(thickness=700.0, roughness=0.03)
    mirror = dataclasses.replace(rough, roughness=np.float32(0.5 * FACET_MIRROR))

    @dataclasses.dataclass
    class Lev:  # the one field of a fit's Level that microfacet_offsets reads
        cfg: RenderConfig

    spectral = Lev(RenderConfig(effects=fx))
    clamped = Lev(RenderConfig(effects=fx, film_rgb="clamped"))
    paper = Lev(RenderConfig(effects=Effects(model="paper"), film_rgb="clamped"))
    assert microfacet_offsets(rough, spectral, None, None) is None
    assert microfacet_offsets(rough, paper, None, None) is None
    assert microfacet_offsets(mirror, clamped, None, None) is None
    assert calls == []
    base = np.full((2, 2, 3), 0.25)
    out = microfacet_offsets(rough, clamped, None, base)
    widths = ggx_ward_widths(0.03, GGX_LOBE_WIDTHS)
    assert out.shape == (2, 2, 2, 3) and [c[0] for c in calls] == ["ggx"] + ["ward"] * GGX_LOBE_WIDTHS
    assert np.allclose([c[1] for c in calls[1:]], widths, rtol=1e-6)
    assert np.allclose(out[0], 0.25) and np.allclose(out[1], np.mean(widths.astype(np.float32)) - 0.25)


def test_ggx_ward_widths_are_ggx_slopes():
    """The equal-weight mixture of Ward's slope Gaussians at ``brdf.ggx_ward_widths`` is
    GGX's slope law (a Student t with 2 degrees of freedom): the share of slopes beyond
    ``r`` is ``alpha^2 / (alpha^2 + r^2)`` for GGX (closed form) and ``mean_k
    exp(-r^2 / a_k^2)`` for the mixture; with 200 mid-quantile widths they agree within
    1 / (2 * 200) (the quantile rule's step in ``w``'s probability) out to 5 alpha."""
    from bubblefit.optics.brdf import ggx_ward_widths

    alpha, k = 0.03, 200
    a = ggx_ward_widths(alpha, k)
    r = alpha * np.linspace(0.0, 5.0, 51)
    mix = np.exp(-(r[:, None] / a) ** 2).mean(axis=1)
    assert np.abs(mix - alpha**2 / (alpha**2 + r**2)).max() < 1.0 / (2 * k)
    assert np.isclose(ggx_ward_widths(alpha, 6).max(), alpha / np.sqrt(-np.log(11 / 12)))
