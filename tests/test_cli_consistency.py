"""``fit-sequence`` on one frame fits it as ``fit`` does with the same options: the same
model, noise model, disc (the calibration's, checked, refined in the fit) and so the same
parameters. The photo is rendered with known parameters (as in ``test_fit``), 8-bit sRGB
with noise; the two commands read it in float32 (``fit``) and float64 (the sequence),
so they may differ by float32 rounding: far below one standard error."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

pytestmark = pytest.mark.slow


def test_one_frame_sequence_gives_what_fit_gives(small_courtyard, tmp_path, capsys):
    import test_fit as tf

    from bubblefit.cli import main
    from bubblefit.io.images import write_image

    env = tf._env(small_courtyard)
    rng = np.random.default_rng(5)
    bg = tf._background(rng)
    photo = tf._quantise(tf._render(env, bg, {"t": 0.97, "roughness": 0.08, "thickness_nm": 420.0}), rng)
    write_image(tmp_path / "photo.png", photo)
    write_image(tmp_path / "before.png", bg)
    write_image(tmp_path / "env.exr", small_courtyard, bit_depth=32)
    (tmp_path / "cal.json").write_text(json.dumps({"t": 0.968, "image_size": [tf.N, tf.N],
                                                   "bubble": dict(zip(("cx", "cy", "r"), tf.DISC))}))
    common = ["--envmap", tmp_path / "env.exr", "--background", tmp_path / "before.png",
              "--calibration", tmp_path / "cal.json", "--fov", "0"]
    assert main([str(a) for a in ["fit", tmp_path / "photo.png", *common, "--json", tmp_path / "fit.json"]]) == 0
    assert main([str(a) for a in ["fit-sequence", tmp_path / "photo.png", *common, "--workers", "0",
                                  "-o", tmp_path / "seq", "--no-progress"]]) == 0
    fit = json.loads((tmp_path / "fit.json").read_text())
    row = next(csv.DictReader(open(tmp_path / "seq" / "params.csv")))
    assert fit["ok"] and row["ok"] == "true"
    assert abs(fit["params"]["thickness_nm"] - 420.0) < 5.0
    for name in ("thickness_nm", "t", "roughness", "exposure", "f", "r_d", "r_s"):
        diff = abs(float(row[name]) - fit["params"][name])
        assert diff < 1e-3 * fit["stderr"][name], (name, row[name], fit["params"][name], fit["stderr"][name])
