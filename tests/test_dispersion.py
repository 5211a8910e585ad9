"""Dispersive films (bubblefit.optics.dispersion) in the film functions, charts and scenes.

References: the ``tmm`` package (transfer-matrix method, test-only) for the reflectance
of a film whose index differs per wavelength; Daimon & Masumura, Appl. Opt. 46, 3811
(2007), the Sellmeier formula of water at 20 C (coefficients as tabulated by
refractiveindex.info), written out below, for the ``water`` preset.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.optics import dispersion, film
from bubblefit.optics.chart import interference_colours

tmm = pytest.importorskip("tmm")


def daimon_water(lam_nm):
    a = (5.684027565e-1, 1.726177391e-1, 2.086189578e-2, 1.130748688e-1)
    b = (5.101829712e-3, 1.821153936e-2, 2.620722293e-2, 1.069792721e1)
    l2 = (np.asarray(lam_nm) / 1000.0) ** 2
    return np.sqrt(1.0 + sum(ai * l2 / (l2 - bi) for ai, bi in zip(a, b)))


def test_cauchy_law_and_presets():
    law = dispersion.Cauchy((1.5, 4000.0, 1e8))
    lam = np.array([400.0, 550.0, 800.0])
    np.testing.assert_allclose(law(lam), 1.5 + 4000.0 / lam**2 + 1e8 / lam**4, rtol=1e-14)
    soap = dispersion.refractive_index("soap", [450.0, 750.0])
    np.testing.assert_allclose(soap, 1.324188 + 3102.06 / np.array([450.0, 750.0]) ** 2, rtol=1e-14)
    assert 1.339 < soap[0] < 1.341 and 1.329 < soap[1] < 1.331
    grid = np.linspace(380.0, 1000.0, 300)
    assert np.abs(dispersion.refractive_index("water", grid) - daimon_water(grid)).max() < 1.5e-3
    assert abs(float(dispersion.refractive_index("water", 589.3)) - 1.3330) < 5e-4
    np.testing.assert_allclose(dispersion.refractive_index(1.4, lam), 1.4)
    np.testing.assert_allclose(dispersion.index_offset("soap", 589.3), 0.0, atol=1e-15)


@pytest.mark.parametrize("value,match", [
    ({"cauchy": [1.3]}, "2 or 3"), ({"cauchy": [1.3, "x"]}, "2 or 3"), ({"sellmeier": [1, 2]}, "cauchy"),
    ("honey", "preset"), (0.5, "within"), (float("nan"), "finite"), ({"cauchy": [1.3, -2e5]}, "within"), (True, "number"),
])
def test_bad_index_descriptions(value, match):
    with pytest.raises(InputError, match=match):
        dispersion.parse_index(value, "bubble.n_film")


def test_parse_forms():
    assert dispersion.parse_index({"cauchy": [1.33, 3000]}) == dispersion.Cauchy((1.33, 3000.0))
    assert dispersion.parse_cauchy("1.33,3000,1e7") == dispersion.Cauchy((1.33, 3000.0, 1e7))
    assert dispersion.parse_index("Water") == dispersion.PRESETS["water"]
    assert dispersion.describe(dispersion.PRESETS["soap"]) == "soap"


@pytest.mark.parametrize("angle_deg", [0.0, 35.0, 70.0])
def test_airy_with_index_per_wavelength_matches_transfer_matrix(x64, angle_deg):
    lam = np.array([380.0, 430.0, 500.0, 580.0, 660.0, 780.0])
    law = dispersion.Cauchy((1.30, 9000.0, 2e8))  # strongly dispersive: 1.37 .. 1.32
    n = law(lam)
    assert n[0] - n[-1] > 0.04
    d = np.array([0.0, 90.0, 640.0, 3100.0])
    cos_i = np.cos(np.radians(angle_deg))
    airy = jax.jit(film.airy_reflectance)  # compiled, as the renderer runs it
    got = np.asarray(airy(d[:, None], lam[None, :], n[None, :], cos_i))
    ref = np.array([[[tmm.coh_tmm(pol, [1.0, nk, 1.0], [np.inf, dd, np.inf], np.radians(angle_deg), wl)["R"]
                      for pol in "sp"] for wl, nk in zip(lam, n)] for dd in d])
    assert np.abs(got - ref).max() < 1e-9
    # The index per wavelength matters: a constant mean index is far off at 3.1 um.
    flat = np.asarray(airy(d[:, None], lam[None, :], float(n.mean()), cos_i))
    assert np.abs(flat - ref)[-1].max() > 0.02


def test_chart_uses_the_law():
    d = np.array([300.0, 1000.0, 2500.0])
    a = interference_colours(d, n_film="soap")
    b = interference_colours(d, n_film=float(dispersion.refractive_index("soap", 589.3)))
    assert np.abs(a - b).max() > 1e-3  # dispersion shifts thick films' colours
    assert np.abs(a - b)[0].max() < np.abs(a - b)[-1].max()


def test_scene_accepts_dispersive_films():
    from bubblefit.model.scene import Scene

    for value in (1.36, {"cauchy": [1.324188, 3102.06]}, "water"):
        sc = Scene.from_dict({"bubble": {"n_film": value}, "camera": {"width": 8, "height": 8}})
        p = sc.params()
        cfg, _ = sc.config()
        law = dispersion.parse_index(value)
        assert abs(float(p.n_film) - float(dispersion.refractive_index(law, 589.3))) < 1e-6
        assert (cfg.dispersion is None) == (not isinstance(law, dispersion.Cauchy))
    with pytest.raises(InputError, match="bubble.n_film"):
        Scene.from_dict({"bubble": {"n_film": {"cauchy": [1.3]}}})


def test_render_uses_the_index_per_wavelength():
    """A dispersive 3 um film renders other colours than a constant film of the same n_D,
    and a Cauchy law with B = C = 0 renders exactly like the constant."""
    from bubblefit.model.scene import Scene, render_scene

    def img(n_film):
        return render_scene(Scene.from_dict({
            "camera": {"width": 8, "height": 8},
            "bubble": {"thickness_nm": 3000.0, "n_film": n_film, "roughness": 0.4},
            "lighting": {"point_lights": [{"direction": [0.0, 0.0, 1.0], "radiance": [5.0, 5.0, 5.0]}],
                         "background": "black"},
            "effects": {"model": "physical", "interference": "airy", "filtering": "mirror",
                        "spectral": {"method": "uniform", "samples": 64}}}))

    n_d = float(dispersion.refractive_index("soap", 589.3))
    flat, soap, law0 = img(n_d), img("soap"), img({"cauchy": [n_d, 0.0]})
    np.testing.assert_allclose(law0, flat, atol=1e-6)
    assert np.abs(soap - flat).max() > 1e-3
