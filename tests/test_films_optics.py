"""Films between two media (bubblefit.optics.film with ``n_above``/``n_below``) against ``tmm``.

The transfer-matrix code of the ``tmm`` package (S. Byrnes) is the independent reference:
it sums the layer's beams by 2x2 matrices, not by Airy's closed form. Cases: a film on
glass (air | film | glass), an air gap between glass plates (glass | air | glass), a
film in water (water | film | water), each at several angles and in both
polarisations, with dispersive media from :mod:`bubblefit.optics.dispersion`.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

tmm = pytest.importorskip("tmm")

from bubblefit.optics import dispersion, film  # noqa: E402


# Compiled, as the renderer runs them: called eagerly, JAX compiles each operation again
# for every array size and dtype.
airy_reflectance = jax.jit(film.airy_reflectance)

THICKNESS = np.array([0.0, 3.0, 40.0, 180.0, 420.0, 999.0, 2500.0])
WAVELENGTHS = np.array([400.0, 486.1, 550.0, 656.3, 760.0])


def _tmm(indices, d, angle_deg, lam):
    """(D, A, L, 2): tmm's R of the stack, ``indices`` (3, L), angle in the first medium."""
    out = np.zeros((len(d), len(angle_deg), len(lam), 2))
    for i, dd in enumerate(d):
        for j, a in enumerate(angle_deg):
            for k, wl in enumerate(lam):
                for p, pol in enumerate("sp"):
                    n = [indices[0][k], indices[1][k], indices[2][k]]
                    out[i, j, k, p] = tmm.coh_tmm(pol, n, [np.inf, dd, np.inf], np.radians(a), wl)["R"]
    return out


CASES = {
    # name: (above, film, below, angles in the medium above, degrees)
    "air|soap|bk7": ("air", "soap", "bk7", [0.0, 20.0, 45.0, 70.0, 85.0]),
    "bk7|air|bk7": ("bk7", "air", "bk7", [0.0, 10.0, 25.0, 38.0]),  # below the critical 41.2 deg
    "water|soap|water": ("water", 1.45, "water", [0.0, 30.0, 60.0, 80.0]),
    "soda-lime|water|fused-silica": ("soda-lime", "water", "fused-silica", [0.0, 30.0, 55.0]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_three_media_airy_matches_transfer_matrix(x64, case):
    above, mid, below, angles = CASES[case]
    idx = [dispersion.refractive_index(dispersion.parse_index(m) if isinstance(m, str) else m, WAVELENGTHS)
           for m in (above, mid, below)]
    angles = np.asarray(angles)
    ref = _tmm(idx, THICKNESS, angles, WAVELENGTHS)
    cos_i = np.cos(np.radians(angles))[None, :, None]
    got = np.asarray(airy_reflectance(THICKNESS[:, None, None], WAVELENGTHS, idx[1], cos_i,
                                           n_above=idx[0], n_below=idx[2]))
    err = np.abs(got - ref)
    assert err.max() < 1e-9, f"{case}: max |R - R_tmm| = {err.max():.2e}"
    assert ref.max() - ref.min() > 0.01  # the stack's fringes are there to be compared


def test_gap_is_not_a_rescaled_film(x64):
    """A glass|air|glass gap reflects unlike an air|glass|air film of the same optical
    thickness off normal incidence (the rescaling trick is exact only at 0 deg)."""
    lam = np.linspace(400.0, 700.0, 31)
    n = 1.517
    cos_i = np.cos(np.radians(30.0))
    gap = np.asarray(airy_reflectance(300.0, lam, 1.0, cos_i, n_above=n, n_below=n)).mean(-1)
    slab = np.asarray(airy_reflectance(300.0 / n, lam, n, cos_i)).mean(-1)
    assert np.abs(gap - slab).max() > 0.01
    ref0 = [tmm.coh_tmm("s", [n, 1.0, n], [np.inf, 300.0, np.inf], 0.0, wl)["R"] for wl in lam]
    at0 = np.asarray(airy_reflectance(300.0, lam, 1.0, 1.0, n_above=n, n_below=n))[:, 0]
    np.testing.assert_allclose(at0, ref0, atol=1e-12)


def test_air_on_both_sides_unchanged(x64):
    """Naming air above and below gives the in-air sum (the sphere renderer's path)."""
    lam = np.linspace(380.0, 780.0, 17)
    cos_i = np.linspace(0.05, 1.0, 7)[:, None]
    a = np.asarray(airy_reflectance(650.0, lam, 1.4, cos_i))
    b = np.asarray(airy_reflectance(650.0, lam, 1.4, cos_i, n_above=1.0, n_below=1.0))
    np.testing.assert_allclose(a, b, atol=1e-12)


@pytest.mark.parametrize("name,lam,expected,tol", [
    ("bk7", 587.56, 1.5168, 1e-4),        # SCHOTT n_d
    ("bk7", 486.13, 1.52238, 1e-4),       # SCHOTT n_F
    ("fused-silica", 587.56, 1.4585, 1e-4),  # Malitson n_d
    ("soda-lime", 589.3, 1.523, 2e-3),
])
def test_glass_presets(name, lam, expected, tol):
    n = float(dispersion.refractive_index(name, lam))
    assert abs(n - expected) < tol


def test_sellmeier_bk7_near_infrared():
    """Sellmeier written out by hand for N-BK7 at 1 um (data sheet n = 1.50731)."""
    assert abs(float(dispersion.refractive_index("bk7", 1014.0)) - 1.50731) < 5e-5


def test_gap_chart_colours_match_tmm_spectra(x64):
    """``chart``'s colours of a glass|air|glass gap are tmm's spectra integrated to RGB."""
    from bubblefit.optics import chart, spectral

    basis = spectral.spectral_basis("uniform", 60)
    d = np.array([0.0, 150.0, 420.0, 900.0])
    got = chart.interference_colours(d, n_film="air", above=1.52, below=1.52, basis=basis, angle_deg=20.0)
    t0 = np.arcsin(np.sin(np.radians(20.0)) / 1.52)
    spec = np.array([[np.mean([tmm.coh_tmm(p, [1.52, 1.0, 1.52], [np.inf, dd, np.inf], t0, wl)["R"] for p in "sp"])
                      for wl in basis.wavelengths] for dd in d])
    ref = spec @ basis.weights
    np.testing.assert_allclose(got, ref, atol=1e-6)
    assert np.abs(got[0]).max() < 1e-9  # no gap: glass meets glass, nothing reflects
