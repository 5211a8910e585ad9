"""Lamps for flat films: the objective's cone, Planck lamps, the area light's mirror geometry.

References written independently of the code under test: ``tmm`` (transfer matrices)
averaged over the cone by a dense midpoint rule in solid angle, CIE illuminant A (a
black body at 2856 K by definition), and mirror reflection worked out by hand.
"""

from __future__ import annotations

import numpy as np
import pytest

from bubblefit.lighting import area
from bubblefit.optics import coaxial
from bubblefit.optics import spectral

tmm = pytest.importorskip("tmm")


def _tmm_cone(d, lam, n0, n1, n2, na, k=300):
    """Cone average with the weight cos(theta) sin(theta) dtheta (midpoint rule in theta, air)."""
    th = (np.arange(k) + 0.5) / k * np.arcsin(na)
    wt = np.cos(th) * np.sin(th)
    out = 0.0
    for t, wk in zip(th, wt):
        t0 = np.arcsin(np.sin(t) / n0)
        out += wk * np.mean([tmm.coh_tmm(p, [n0, n1, n2], [np.inf, d, np.inf], t0, lam)["R"] for p in "sp"])
    return out / wt.sum()


@pytest.mark.parametrize("d,na", [(300.0, 0.3), (1500.0, 0.5), (2500.0, 0.6)])
def test_cone_average_matches_dense_tmm(x64, d, na):
    """The few-node Gauss-Legendre cone average of a glass|air|glass gap equals tmm averaged
    densely over the cone (midpoint rule in theta, 300 nodes, error ~1e-5)."""
    lam = np.array([420.0, 550.0, 680.0])
    stack = coaxial.Stack(1.52, 1.0, 1.52)
    n = stack.indices(lam)
    nodes = coaxial.cone_nodes_needed(d, na, 1.0)
    got = np.asarray(coaxial.coaxial_reflectance(d, lam, n, na, nodes))
    ref = np.array([_tmm_cone(d, wl, 1.52, 1.0, 1.52, na) for wl in lam])
    np.testing.assert_allclose(got, ref, atol=2e-4)


def test_cone_quadrature_converges(x64):
    """The chosen node count agrees with 400 nodes within 1e-4 over 0-3000 nm, NA <= 0.6."""
    lam = np.linspace(380.0, 780.0, 21)
    n = coaxial.Stack(1.52, 1.0, 1.52).indices(lam)
    d = np.linspace(0.0, 3000.0, 61)[:, None]
    for na in (0.1, 0.3, 0.6):
        few = np.asarray(coaxial.coaxial_reflectance(d, lam, n, na, coaxial.cone_nodes_needed(3000.0, na, 1.0)))
        dense = np.asarray(coaxial.coaxial_reflectance(d, lam, n, na, 400))
        assert np.abs(few - dense).max() < 1e-4, na


def test_aperture_fades_thick_fringes(x64):
    """A wide cone washes out a thick gap's fringes; a thin gap's stay (the module's claim)."""
    lam = np.linspace(380.0, 780.0, 801)
    n = coaxial.Stack(1.52, 1.0, 1.52).indices(lam)

    def contrast(d, na):
        r = np.asarray(coaxial.coaxial_reflectance(d, lam, n, na, 64))
        return r.max() - r.min()

    # 5 um of air: the optical path changes by d NA^2 = 1.8 um across an NA 0.6 cone,
    # several fringes; 300 nm: by 0.1 um, a fifth of one.
    assert contrast(5000.0, 0.6) < 0.3 * contrast(5000.0, 0.05)
    assert contrast(300.0, 0.6) > 0.8 * contrast(300.0, 0.05)


def test_planck_lamp_is_cie_a():
    """CIE illuminant A is a black body at 2856 K: '2856K' matches the shipped A over 380-780 nm."""
    grid = spectral.TABLE_GRID
    inside = (grid >= 380) & (grid <= 780)
    a = spectral.illuminant_spectrum("A")
    b = spectral.illuminant_spectrum("2856K")
    a, b = a / a[grid == 560], b / b[grid == 560]
    assert np.abs(a[inside] / b[inside] - 1).max() < 2e-3


def test_mirror_view_of_a_panel():
    """A camera at z = 1 looking at a film in z = 0 sees, along a ray tilted by theta, the
    panel at z = 2 at the offset 3 tan(theta) (to the film, then twice as far back)."""
    film = area.Patch(center=(0, 0, 0), normal=(0, 0, 1), size=(2.0, 2.0))
    light = area.Patch(center=(0.9, 0, 2.0), normal=(0, 0, -1), size=(0.2, 0.2), radiance=3.0)
    theta = np.arctan(np.array([0.0, 0.3, 0.6]))
    dirs = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], -1)[None]
    orig = np.broadcast_to(np.array([0.0, 0.0, 1.0]), dirs.shape)
    v = area.view_plane(orig, dirs, film, light)
    # offsets on the panel: 3 tan(theta) = 0, 0.9, 1.8: only the middle ray hits it
    np.testing.assert_array_equal(v.radiance[0], [0.0, 3.0, 0.0])
    np.testing.assert_allclose(v.sin2_air[0], np.sin(theta) ** 2)


def test_edge_on_film_is_refused():
    from bubblefit.errors import InputError

    film = area.Patch(center=(0, 0, 0), normal=(1, 0, 0), size=(1.0, 1.0))
    light = area.Patch(center=(0, 0, 2), normal=(0, 0, -1), size=(1, 1))
    dirs = np.array([[[0.0, 0.001, -1.0]]]) / np.linalg.norm([0.0, 0.001, -1.0])
    with pytest.raises(InputError, match="edge-on|does not appear"):
        area.view_plane(np.array([[[0.0, 0.0, 1.0]]]), dirs, film, light)
