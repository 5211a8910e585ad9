"""Accuracy against time: the alias-free ``fourier`` spectral basis and the sweep script.

* Film colours (CIEDE2000 against the 800-sample reference): with K = 8 lobes the
  ``fourier`` basis keeps thick films (3000-6000 nm) free of the false colours uniform
  K = 10 and 30 show, and stays close to the reference on coloured films (100-1500 nm).
* Renders through a scene's ``[effects] spectral = {method = "fourier"}``, both models, of
  a thick film: closer to the reference render than uniform K = 30.
* ``experiments/accuracy_vs_time.py --quick`` writes ``results.csv`` with the documented
  columns, its plots, and every knob's error falls from its cheapest to its finest setting.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bubblefit.optics import film, spectral
from bubblefit.lighting.envmap import EnvMap
from bubblefit.model.render import render
from bubblefit.model.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
N = 1.4


def colours(basis, d, cos_i=1.0):
    """Linear sRGB (N, 3) of an Airy film, filtered per lobe when the basis has lobes.

    Compiled once per basis, as the renderer runs it (called eagerly, each operation
    compiles again for each basis' number of samples)."""
    lam = jnp.asarray(basis.wavelengths)

    @jax.jit
    def rgb(dd, c):
        if basis.sigma is None:
            s = film.airy_reflectance(dd, lam, N, c)
        else:
            s = film.filtered_airy_reflectance(dd, lam, N, c, jnp.asarray(basis.sigma))
        return spectral.integrate(s.mean(-1), basis)

    return np.asarray(rgb(jnp.asarray(d)[:, None], jnp.asarray(cos_i)), dtype=np.float64)


def delta_e(a, b, cos_i=1.0):
    """CIEDE2000 between film colours shown with the incoherent grey at 0.5."""
    k = 0.5 / float(np.asarray(film.incoherent_reflectance(cos_i, N)).mean())
    cs = colour.RGB_COLOURSPACES["sRGB"]
    lab = lambda rgb: colour.XYZ_to_Lab(colour.RGB_to_XYZ(np.clip(rgb * k, 0, None), cs, apply_cctf_decoding=False),
                                        cs.whitepoint)
    return np.asarray(colour.delta_E(lab(a), lab(b), method="CIE 2000"))


def test_fourier_basis_is_alias_free_on_thick_films_and_close_on_thin_ones():
    ref = spectral.spectral_basis("reference")
    f8 = spectral.spectral_basis("fourier", 8)
    assert f8.samples == 8 and f8.sigma.shape == (8,)
    np.testing.assert_allclose(f8.weights.sum(axis=0), 1.0, atol=1e-9)  # flat spectrum -> white
    rng = np.random.default_rng(0)
    thick = np.sort(rng.uniform(3000.0, 6000.0, 300))
    thin = np.sort(rng.uniform(100.0, 1500.0, 300))
    for cos_i in (1.0, 0.6):
        c_ref = colours(ref, thick, cos_i)
        e_f8 = delta_e(colours(f8, thick, cos_i), c_ref, cos_i)
        e_u10 = delta_e(colours(spectral.spectral_basis("uniform", 10), thick, cos_i), c_ref, cos_i)
        e_u30 = delta_e(colours(spectral.spectral_basis("uniform", 30), thick, cos_i), c_ref, cos_i)
        # Uniform sampling bands (false colours of several dE); the lobes fade to grey.
        assert e_f8.mean() < 0.1 * min(e_u10.mean(), e_u30.mean()), (e_f8.mean(), e_u10.mean(), e_u30.mean())
        assert e_f8.max() < 1.5, e_f8.max()
        e_thin = delta_e(colours(f8, thin, cos_i), colours(ref, thin, cos_i), cos_i)
        assert e_thin.mean() < 0.5 and e_thin.max() < 2.0, (e_thin.mean(), e_thin.max())


def test_filtered_film_functions_limits_and_gradients():
    airy = jax.jit(film.filtered_airy_reflectance)
    lam = jnp.linspace(400.0, 700.0, 7)
    cos = jnp.asarray([1.0, 0.5, 0.05])[:, None]
    d = 800.0
    # sigma = 0: the point-sampled functions exactly.
    np.testing.assert_allclose(airy(d, lam, N, cos, 0.0),
                               film.airy_reflectance(d, lam, N, cos), atol=1e-6)
    np.testing.assert_allclose(film.filtered_paper_interference_factor(d, lam, N, cos, 0.97, 0.0),
                               film.paper_interference_factor(d, lam, N, cos, 0.97), atol=1e-5)
    # Very thick films: the incoherent limit (Airy) and the mean 2 t^2 (eq. 10).
    inc = film.incoherent_reflectance(cos, N)
    # (float32 phases of ~5000 rad: the residue of the exact part cancels to ~1e-3.)
    np.testing.assert_allclose(airy(1e5, lam, N, cos, 1e-4), np.broadcast_to(inc, (3, 7, 2)),
                               atol=5e-3)
    np.testing.assert_allclose(film.filtered_paper_interference_factor(1e5, lam, N, cos, 0.97, 1e-4),
                               2 * 0.97**2, rtol=1e-5)
    g = jax.jit(jax.grad(lambda dd: film.filtered_airy_reflectance(dd, lam, N, cos, 1e-4).sum()))(jnp.asarray(0.0))
    assert np.isfinite(float(g))
    g = jax.jit(jax.grad(lambda c: film.filtered_airy_reflectance(3000.0, lam, N, c, 1e-4).sum()))(jnp.asarray(0.0))
    assert np.isfinite(float(g))


@pytest.mark.slow
@pytest.mark.parametrize("model", ["paper", "physical"])
def test_scene_renders_thick_film_with_fourier_basis(model):
    """A 3000-6000 nm film (front reflection): fourier/8 lands on the reference render;
    uniform/30 bands. (The physical model's rear and transmitted terms multiply the spectra
    of films of equal thickness, whose correlation per-sample filtering drops; see README.)"""
    env = EnvMap.constant(1.0, height=16)
    h = 20

    def img(method, samples):
        sc = Scene.from_dict({
            "camera": {"type": "orthographic", "width": h, "height": h},
            "bubble": {"thickness": {"profile": "drainage", "top_nm": 3000.0, "bottom_nm": 6000.0, "exponent": 1.0}},
            "lighting": {"envmap": "unused.exr", "background": "black"},
            "effects": {"model": model, "interference": "two_beam" if model == "paper" else "airy",
                        "filtering": "mirror", "transmission": False, "rear_reflection": False,
                        "spectral": {"method": method, "samples": samples}},
        })
        cfg, decisions = sc.config(env)
        assert cfg.effects.spectral.method == method
        return np.asarray(render(sc.params(), cfg, env), dtype=np.float64)

    ref = img("reference", 800)
    err = lambda x: np.sqrt(np.mean((x - ref) ** 2)) / np.sqrt(np.mean(ref**2))
    e_f8, e_u30 = err(img("fourier", 8)), err(img("uniform", 30))
    assert e_f8 < 0.25 * e_u30, (e_f8, e_u30)
    assert e_f8 < 0.03, e_f8


def test_unknown_fourier_sample_count_is_rejected():
    with pytest.raises(ValueError, match="fourier"):
        spectral.spectral_basis("fourier", 9)


@pytest.mark.slow
def test_quick_sweep_writes_results_and_error_falls(tmp_path):
    out = tmp_path / "acc"
    proc = subprocess.run([sys.executable, str(ROOT / "experiments" / "accuracy_vs_time.py"), "--quick",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    with open(out / "results.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames[:5] == ["knob", "setting", "error", "error_unit", "time_s"]
        rows = list(reader)
    knobs: dict[str, list] = {}
    for r in rows:
        assert float(r["time_s"]) > 0 and np.isfinite(float(r["error"])) and float(r["error"]) >= 0
        knobs.setdefault(r["knob"], []).append(float(r["error"]))
    families = {k.split("_")[0] for k in knobs}
    assert {"spectral", "filter", "envmap", "image", "precision"} <= families, families
    for knob, errs in knobs.items():
        if len(errs) < 2:
            continue
        # Settings run from cheapest to finest: the finest is better than the cheapest, and
        # no step makes things much worse (small noise allowed).
        assert errs[-1] < errs[0], (knob, errs)
        for a, b in zip(errs, errs[1:]):
            assert b <= 1.5 * a + 1e-6, (knob, errs)
    pngs = sorted(p.name for p in out.glob("pareto_*.png"))
    assert "pareto_spectral.png" in pngs and len(pngs) >= 5, pngs
    for name in ("pareto.png", "banding.png"):
        assert (out / name).stat().st_size > 1000
