"""Thin-film optics (bubblefit.optics.film) against an independent transfer-matrix code and limits.

References: the ``tmm`` package (S. Byrnes, transfer-matrix method, a test-only
dependency) for the exact film reflectance; Born & Wolf 7.6 for the two-beam truncation
(error of order R1^2) and the incoherent limit ``2 R1 / (1 + R1)``.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

tmm = pytest.importorskip("tmm")

from bubblefit.optics import film
from bubblefit.optics import spectral  # noqa: E402


# Compiled, as the renderer runs them: called eagerly, JAX compiles each operation again
# for every array size and dtype.
airy_reflectance = jax.jit(film.airy_reflectance)
two_beam_reflectance = jax.jit(film.two_beam_reflectance)

THICKNESS = np.array([0.0, 1.0, 5.0, 10.0, 37.0, 100.0, 250.0, 512.0, 1000.0, 1999.0, 3500.0, 5000.0])
ANGLES_DEG = np.array([0.0, 10.0, 30.0, 45.0, 60.0, 70.0, 80.0, 85.0, 89.0])
WAVELENGTHS = np.array([380.0, 451.0, 550.0, 633.0, 780.0])


def _tmm_reflectance(d, angle_deg, lam, n):
    """(D, A, L, 2) reflectance of air | film (n, d) | air from the transfer-matrix method."""
    out = np.zeros((len(d), len(angle_deg), len(lam), 2))
    for i, dd in enumerate(d):
        for j, a in enumerate(angle_deg):
            for k, wl in enumerate(lam):
                for p, pol in enumerate("sp"):
                    out[i, j, k, p] = tmm.coh_tmm(pol, [1.0, n, 1.0], [np.inf, dd, np.inf], np.radians(a), wl)["R"]
    return out


@pytest.mark.parametrize("n", [1.33, 1.4])
def test_airy_matches_transfer_matrix(x64, n):
    ref = _tmm_reflectance(THICKNESS, ANGLES_DEG, WAVELENGTHS, n)
    cos_i = np.cos(np.radians(ANGLES_DEG))
    got = np.asarray(airy_reflectance(THICKNESS[:, None, None], WAVELENGTHS[None, None, :], n,
                                      cos_i[None, :, None]))
    assert got.shape == ref.shape
    err = np.abs(got - ref)
    assert err.max() < 1e-6, f"max |R - R_tmm| = {err.max():.3e} at {np.unravel_index(err.argmax(), err.shape)}"
    # The comparison is not vacuous: the reflectance spans a wide range, s and p differ.
    assert ref.max() > 0.5 and ref.min() < 1e-6
    assert np.abs(ref[..., 0] - ref[..., 1]).max() > 0.1


def test_fresnel_single_interface_matches_transfer_matrix(x64):
    """An infinitely thick film is one interface: compare (R_s, R_p) with tmm's air|glass."""
    cos_i = np.cos(np.radians(ANGLES_DEG))
    got = np.asarray(film.fresnel_reflectance(cos_i, 1.4))
    ref = np.array([[tmm.coh_tmm(pol, [1.0, 1.4], [np.inf, np.inf], np.radians(a), 550.0)["R"] for pol in "sp"]
                    for a in ANGLES_DEG])
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_phase_definition_eq8(x64):
    """Eq. (8): delta = 4 pi n d cos t / lambda + pi, with Snell's cos t."""
    d, lam, n, ang = 321.0, 555.0, 1.4, np.radians(40.0)
    cos_t = np.sqrt(1 - (np.sin(ang) / n) ** 2)
    assert float(film.phase(d, lam, n, np.cos(ang))) == pytest.approx(4 * np.pi * n * d * cos_t / lam + np.pi, rel=1e-12)
    assert float(film.cos_transmitted(np.cos(ang), n)) == pytest.approx(cos_t, rel=1e-12)


@pytest.mark.parametrize("n", [1.2, 1.4, 1.6])
def test_two_beam_differs_from_airy_by_order_r_squared(x64, n):
    lam = np.linspace(380.0, 780.0, 81)
    d = np.linspace(0.0, 3000.0, 301)[:, None, None]
    for angle in [0.0, 30.0, 60.0, 75.0]:
        cos_i = np.cos(np.radians(angle))
        airy = np.asarray(airy_reflectance(d, lam[None, :, None], n, cos_i))
        two = np.asarray(two_beam_reflectance(d, lam[None, :, None], n, cos_i))
        r1 = np.asarray(film.fresnel_reflectance(cos_i, n))
        ratio = np.abs(airy - two).max(axis=(0, 1, 2)) / r1**2
        # Leading term of the difference is 4 R1^2 cos(delta)... : bounded by ~4 R1^2, and
        # not much smaller than R1^2 either (the truncation is really second order).
        assert np.all(ratio < 4.5), (angle, ratio)
        assert np.all(ratio > 1.0), (angle, ratio)


def test_thin_films_are_black():
    basis = spectral.spectral_basis("uniform", 100)
    lam = basis.wavelengths
    for angle in [0.0, 45.0, 70.0]:
        cos_i = np.cos(np.radians(angle))
        grey = float(np.mean(film.incoherent_reflectance(cos_i, 1.4)))
        rgb0 = np.asarray(spectral.integrate(airy_reflectance(0.0, lam, 1.4, cos_i).mean(-1), basis))
        assert np.abs(rgb0).max() < 1e-6
        for d in [2.0, 5.0, 9.9]:
            rgb = np.asarray(spectral.integrate(airy_reflectance(d, lam, 1.4, cos_i).mean(-1), basis))
            # A 10 nm film reflects under a tenth of the incoherent grey; it grows like d^2.
            assert np.all(rgb < 0.1 * grey), (angle, d, rgb / grey)
            assert np.all(rgb >= 0)
        r5 = np.asarray(spectral.integrate(airy_reflectance(5.0, lam, 1.4, cos_i).mean(-1), basis))
        r2 = np.asarray(spectral.integrate(airy_reflectance(2.5, lam, 1.4, cos_i).mean(-1), basis))
        np.testing.assert_allclose(r5 / r2, 4.0, rtol=0.05)
    # The paper's eq. (10) factor has the same black-film limit (the + pi of eq. 8).
    assert float(np.max(film.paper_interference_factor(0.0, lam, 1.4, 1.0, 0.97))) < 1e-10


@pytest.mark.parametrize("angle", [0.0, 50.0, 75.0])
def test_thick_films_tend_to_incoherent_limit(x64, angle):
    cos_i = np.cos(np.radians(angle))
    grey = float(np.mean(film.incoherent_reflectance(cos_i, 1.4)))
    fine = spectral.spectral_basis("reference")
    coarse = spectral.spectral_basis("uniform", 10)
    fine_dev, coarse_dev = [], []
    for d in [8000.0, 12345.0, 20000.0]:
        f = np.asarray(spectral.integrate(airy_reflectance(d, fine.wavelengths, 1.4, cos_i).mean(-1), fine))
        c = np.asarray(spectral.integrate(airy_reflectance(d, coarse.wavelengths, 1.4, cos_i).mean(-1), coarse))
        fine_dev.append(np.abs(f / grey - 1).max())
        coarse_dev.append(np.abs(c / grey - 1).max())
    assert max(fine_dev) < 5e-3, fine_dev
    # ... and it needs the fine integration: 10 samples alias the fringes.
    assert max(coarse_dev) > 10 * max(fine_dev), (coarse_dev, fine_dev)


def test_incoherent_is_phase_average_of_airy(x64):
    """2 R1 / (1 + R1) is the mean of the Airy reflectance over one period of the phase."""
    lam = 500.0
    n = 1.4
    for angle in [0.0, 40.0, 80.0]:
        cos_i = np.cos(np.radians(angle))
        cos_t = float(film.cos_transmitted(cos_i, n))
        period = lam / (2 * n * cos_t)  # thickness step that advances the phase by 2 pi
        d = np.linspace(0.0, period, 4001)[:-1]
        mean = np.asarray(airy_reflectance(d, lam, n, cos_i)).mean(axis=0)
        np.testing.assert_allclose(mean, np.asarray(film.incoherent_reflectance(cos_i, n)), rtol=1e-9)


def test_energy_and_grazing_limits(x64):
    lam = np.linspace(380, 780, 41)
    d = np.linspace(0, 5000, 101)[:, None]
    for cos_i in [1.0, 0.5, 1e-3, 0.0]:
        r = np.asarray(airy_reflectance(d, lam, 1.4, cos_i))
        assert np.all((r >= 0) & (r <= 1))
    # At grazing incidence every film (except the black d -> 0 limit) reflects everything.
    r = np.asarray(airy_reflectance(500.0, lam, 1.4, 0.0))
    np.testing.assert_allclose(r, 1.0, atol=1e-9)
    # n = 1 is no film at all.
    assert np.abs(np.asarray(airy_reflectance(d, lam, 1.0, 0.7))).max() < 1e-12


def test_gradients_are_finite_everywhere():
    import jax
    import jax.numpy as jnp

    def f(d, n, c):
        return jnp.sum(airy_reflectance(d, 550.0, n, c)) + jnp.sum(two_beam_reflectance(d, 550.0, n, c))

    g = jax.jit(jax.grad(f, argnums=(0, 1, 2)))
    for d in [0.0, 1e-3, 500.0]:
        for c in [0.0, 1e-6, 0.5, 1.0]:
            for n in [1.0, 1.4]:
                vals = [float(v) for v in g(jnp.float32(d), jnp.float32(n), jnp.float32(c))]
                assert np.all(np.isfinite(vals)), (d, c, n, vals)
