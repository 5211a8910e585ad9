"""`bubblefit report`: the page's content, its error band, a real browser's rendering, bad inputs.

The fit result is written by hand (a drainage film on a small orthographic photo, with a
covariance and a warning), so the page is made in seconds. The error band is checked
against the closed-form linear propagation for an exponent of 1; the browser check
(headless Chromium, skipped where it is not installed) screenshots the page and looks at
the pixels.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

W, H = 64, 48
DISC = {"cx": 30.5, "cy": 25.0, "r": 17.0}
WARNING = "the roughness sits at its upper bound (a test warning)"


def _fit(tmp_path, ok=False):
    from bubblefit.io.images import write_image

    rng = np.random.default_rng(1)
    photo = rng.uniform(0.1, 0.6, (H, W, 3))
    render = photo + rng.normal(0, 0.01, photo.shape)
    write_image(tmp_path / "photo.png", photo)
    write_image(tmp_path / "fit_render.exr", render.astype(np.float32))
    write_image(tmp_path / "fit_residual.exr", (photo - render).astype(np.float32))
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x, y = (jj - DISC["cx"]) / DISC["r"], -(ii - DISC["cy"]) / DISC["r"]
    tmap = np.where(x * x + y * y < 1, 200 + 300 * (1 - y), np.nan).astype(np.float32)
    write_image(tmp_path / "fit_thickness.exr", tmap, bit_depth=32)
    params = {"exposure": 0.8, "f": 0.03, "r_d": 0.001, "r_s": 0.029, "rotation_deg": 0.0, "roughness": 0.02,
              "t": 0.968, "top_nm": 200.0, "bottom_nm": 800.0, "exponent": 1.0, "n_film": 1.4}
    stderr = {"exposure": 0.002, "f": None, "r_d": 0.0002, "r_s": None, "rotation_deg": None,
              "roughness": 0.001, "t": None, "top_nm": 3.0, "bottom_nm": 5.0, "exponent": 0.02}
    cov = np.diag([0.002, 0.0002, 0.001, 3.0, 5.0, 0.02]) ** 2
    cov[3, 4] = cov[4, 3] = -0.5 * 3.0 * 5.0  # top and bottom anti-correlated
    fit = {"params": params, "stderr": stderr, "converged": True, "ok": ok, "thickness": "drainage",
           "model": "physical", "status": "converged", "message": "converged", "iterations": 7,
           "held": [{"name": "t", "reason": "physical model: Fresnel sets t"},
                    {"name": "rotation_deg", "reason": "not fitted"}],
           "warnings": [] if ok else [WARNING], "reduced_chi2": 4.2, "reduced_chi2_floor": 2.1,
           "reduced_chi2_inliers": 1.9, "outlier_fraction": 0.01, "model_error_floor": 0.03,
           "thickness_model_error_nm": 0.6, "stderr_scale": 2.0, "residual_rms": 0.01, "pixels_used": 900,
           "time_s": 3.0, "disc": DISC, "colour": {"illuminant": "D65", "response": "srgb"},
           "covariance": {"names": ["exposure", "r_d", "roughness", "top_nm", "bottom_nm", "exponent"],
                          "matrix": cov.tolist()},
           "photo": str(tmp_path / "photo.png"),
           "outputs": {"render": str(tmp_path / "fit_render.exr"), "residual": str(tmp_path / "fit_residual.exr"),
                       "thickness": str(tmp_path / "fit_thickness.exr")}}
    path = tmp_path / "fit.json"
    path.write_text(json.dumps(fit))
    return path


def test_page_content_says_everything_in_words(tmp_path):
    from bubblefit.report import load_report_inputs, write_fit_page

    page = write_fit_page(load_report_inputs(_fit(tmp_path)), tmp_path / "page")
    text = page.read_text()
    assert "Fit ok: NO." in text and WARNING in text
    assert "Reduced chi^2 4.2 from the noise alone; 2.1 with the model-error floor of 3%" in text
    for name in ("top_nm", "bottom_nm", "exponent", "roughness", "exposure"):
        assert f"<code>{name}</code>" in text
    assert "held: physical model: Fresnel sets t" in text and "held: not fitted" in text
    assert "<dt>f</dt>" in text and "<dt>model-error floor</dt>" in text
    for fig in ("photo_render.png", "residual.png", "thickness.png", "profile.png"):
        assert f"src='{fig}'" in text
        assert (page.parent / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((page.parent / "fit.json").read_text())["warnings"] == [WARNING]


def test_drainage_band_is_the_linear_propagation():
    """exponent 1: d = top + (bottom - top) w, w = (1 - y)/2; dd/dexponent = (bottom - top) w ln w."""
    from bubblefit.report.figures import drainage_band

    top, bottom = 200.0, 800.0
    cov = np.array([[9.0, -7.5, 0.01], [-7.5, 25.0, 0.02], [0.01, 0.02, 4e-4]])
    y = np.linspace(-0.95, 0.95, 9)
    d, s = drainage_band(y, (top, bottom, 1.0), cov, 0.6)
    w = (1 - y) / 2
    jac = np.stack([1 - w, w, (bottom - top) * w * np.log(w)], axis=-1)
    want = np.sqrt(np.einsum("ni,ij,nj->n", jac, cov, jac) + 0.6 ** 2)
    assert d == pytest.approx(top + (bottom - top) * w, rel=1e-6)
    assert s == pytest.approx(want, rel=1e-4)


def test_report_bad_inputs_exit_2_and_write_nothing(tmp_path, capsys):
    from bubblefit.cli import main

    fit = _fit(tmp_path)
    out = tmp_path / "page"
    (tmp_path / "fit_residual.exr").unlink()
    assert main(["report", str(fit), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "fit_residual.exr" in err and len(err.strip().splitlines()) == 1 and not out.exists()
    notfit = tmp_path / "other.json"
    notfit.write_text("[1, 2]")
    assert main(["report", str(notfit), "-o", str(out)]) == 2 and not out.exists()
    before = fit.read_text()
    assert main(["report", str(fit), "-o", str(fit)]) == 2 and fit.read_text() == before


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


@pytest.mark.slow
@pytest.mark.skipif(_chromium() is None, reason="no Chromium to render the page (apt-get install chromium)")
def test_page_renders_in_a_browser(tmp_path):
    """Headless Chromium draws the page: the screenshot holds the figures (many colours) and
    the verdict's red box, not a blank or broken page."""
    from bubblefit.io.images import read_image
    from bubblefit.report import load_report_inputs, write_fit_page

    page = write_fit_page(load_report_inputs(_fit(tmp_path)), tmp_path / "page")
    shot = tmp_path / "shot.png"
    subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--screenshot={shot}", "--window-size=1280,2000", page.as_uri()],
                   check=True, capture_output=True, timeout=120)
    img = read_image(shot, linear=True).pixels[..., :3]  # the codes as stored
    assert img.shape[:2] == (2000, 1280)
    codes = np.round(img * 255).astype(int)
    colours = len(np.unique(codes[..., 0] * 65536 + codes[..., 1] * 256 + codes[..., 2]))
    assert colours > 2000  # figures drawn (a text-only or blank page has a few hundred)
    # the verdict box's pale red (#fdecea) is on screen
    assert np.any(np.all(np.abs(codes - [253, 236, 234]) <= 2, axis=-1))
