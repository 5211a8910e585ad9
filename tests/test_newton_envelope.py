"""Newton's rings under a lamp whose irradiance falls off across the field.

The pixel's colour is ``g E(x, y) L rgb(R(h) + b)``: the two-beam intensity of Born and
Wolf, *Principles of Optics*, sec. 7.5, times the lamp's irradiance ``E`` where the pixel
sees the film, which multiplies the interfering and the stray light alike (one lamp).
``E`` is ``exp`` of a quadratic in the pixel's position (:func:`bubblefit.inverse._newton.lamp_envelope`):
a Gaussian spot of the lamp is one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_newton_stray import PITCH_UM, _box_rings, _scene_data

from bubblefit.errors import InputError


def _with_envelope(data: dict, envelope) -> dict:
    data["light"]["envelope"] = envelope
    return data


def test_envelope_scene_key(tmp_path):
    """``[light] envelope``: ``"auto"`` by default for Newton's rings, ``"fit"`` and ``"none"``
    as written; the other models take none (``"none"``) and refuse another value in one line."""
    from bubblefit.model.planar_scene import ENVELOPE_DEFAULT, parse_planar

    assert parse_planar(_scene_data(tmp_path), tmp_path).envelope == ENVELOPE_DEFAULT == "auto"
    for value in ("auto", "fit", "none"):
        assert parse_planar(_with_envelope(_scene_data(tmp_path), value), tmp_path).envelope == value
    assert parse_planar(_scene_data(tmp_path, kind="constant"), tmp_path).envelope == "none"
    for data in (_with_envelope(_scene_data(tmp_path, kind="map"), "fit"),
                 _with_envelope(_scene_data(tmp_path), "yes"), _with_envelope(_scene_data(tmp_path), 1.0)):
        with pytest.raises(InputError, match="light.envelope"):
            parse_planar(data, tmp_path)


def test_lamp_envelope_is_exp_of_its_quadratic():
    """``E = exp(c1 u + c2 v + c3 u^2 + c4 u v + c5 v^2)`` on coordinates about the photo's
    centre in half its larger side: 1 at the centre, and a Gaussian spot of width ``s``
    about ``(u0, v0)`` is ``c = (u0, v0, -1/2, 0, -1/2) / s^2`` times its value at the centre."""
    from bubblefit.inverse._newton import envelope_coordinates, lamp_envelope

    yy, xx = np.mgrid[0:48, 0:64] * PITCH_UM
    u, v = envelope_coordinates(xx.ravel(), yy.ravel())
    assert (u.min(), u.max(), np.ptp(v)) == (pytest.approx(-1.0), pytest.approx(1.0), pytest.approx(47 / 63 * 2))
    s, u0, v0 = 0.7, 0.3, -0.2
    spot = np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * s * s)) / np.exp(-(u0 ** 2 + v0 ** 2) / (2 * s * s))
    coef = np.array([u0, v0, -0.5, 0.0, -0.5]) / s ** 2
    np.testing.assert_allclose(np.asarray(lamp_envelope(u, v, coef)), spot, rtol=1e-5)  # float32 exp


@pytest.mark.slow
def test_rings_under_a_lamp_spot(tmp_path):
    """A 64x48 grey photo of Newton's rings under sodium light (lens R = 60 mm on BK7, six
    fringes, each pixel's mean over its box), a grey stray reflectance of 0.2, under a Gaussian lamp spot off the photo's
    centre (its irradiance falls by a factor of 5.1 across the film, the sodium photos of
    experiments/real_photos.py fall by more), Gaussian noise 0.01 and 8-bit steps. With the
    envelope (the scene's default, ``"auto"``: six fringes) the fit finds R, b and the
    envelope's fall-off within 3 of their standard errors (the noise's 99.7 %) and is ``ok``;
    without it (``envelope = "none"``) the rings under a uniform lamp do not explain the
    photo: not ``ok``, R off by more than 3 of the right model's standard errors, and its
    own error bar, widened by the cluster sandwich for a misfit smooth across the photo,
    still holds the truth within 3 of them (the Birge ratio alone put it 5.7 off)."""
    from bubblefit.inverse.planar import PlanarForward, fit_planar, view_of
    from bubblefit.model.planar_scene import parse_planar

    radius_um, h0, stray = 60000.0, 30.0, 0.2
    scene = parse_planar(_scene_data(tmp_path), tmp_path)
    view = view_of(scene)
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, 4000.0)
    w, h = scene.width * PITCH_UM, scene.height * PITCH_UM
    spot = np.exp(-((view.x_um - 0.25 * w) ** 2 + (view.y_um - 0.3 * h) ** 2) / (2 * (0.5 * w) ** 2))
    # each pixel the rings' mean over its box (the spot, smooth, at its centre)
    lin = _box_rings(fwd, view, 0.4 * w, 0.55 * h, radius_um, h0, stray) * spot[..., None]
    lin *= 0.8 / lin.max()
    noise = np.random.default_rng(0).normal(0.0, 0.01, lin.shape[:2])[..., None]  # one grey value per pixel
    photo = np.round(np.clip(lin + noise, 0.0, 1.0) * 255.0) / 255.0
    ratio = float(spot[view.mask].max() / spot[view.mask].min())

    res = fit_planar(photo, scene, clip_high=1.0)
    p, se = res.params, res.stderr
    assert res.ok, res.warnings
    assert abs(p["radius_mm"] - radius_um / 1000.0) < 3.0 * se["radius_mm"]
    assert abs(p["stray_reflectance"] - stray) < 3.0 * se["stray_reflectance"]
    assert abs(p["envelope_ratio"] - ratio) < 3.0 * se["envelope_ratio"]

    flat = fit_planar(photo, parse_planar(_with_envelope(_scene_data(tmp_path), "none"), tmp_path), clip_high=1.0)
    assert flat.params["envelope_ratio"] == 1.0
    assert not flat.ok
    assert abs(flat.params["radius_mm"] - radius_um / 1000.0) > 3.0 * se["radius_mm"]
    assert abs(flat.params["radius_mm"] - radius_um / 1000.0) < 3.0 * flat.stderr["radius_mm"]


def test_flat_field_turns_the_automatic_envelope_off(tmp_path, monkeypatch):
    """``fit --scene RINGS.toml --flat FLAT``: the photo divided by its flat field has the
    lamp's envelope divided out, so the scene's ``envelope = "auto"`` reaches the fit as
    ``"none"``; without ``--flat`` it stays ``"auto"``. (The fit itself is replaced by one
    that records the scene it is given.)"""
    import bubblefit.inverse.planar as planar
    from bubblefit.cli import build_parser
    from bubblefit.cli.fit_planar import run_planar
    from bubblefit.io.images import write_image

    gap_scene = (Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data"
                 / "film_newton_bk7_na010" / "scene.toml")
    write_image(tmp_path / "p.exr", np.full((128, 128, 3), 0.4), bit_depth=32)
    write_image(tmp_path / "f.exr", np.full((128, 128, 3), 0.8), bit_depth=32)
    seen = []

    class Stop(Exception):
        pass

    def record(photo, scene, **kwargs):
        seen.append(scene.envelope)
        raise Stop

    monkeypatch.setattr(planar, "fit_planar", record)
    for flags in ((), ("--flat", tmp_path / "f.exr")):
        args = build_parser().parse_args(["fit", str(tmp_path / "p.exr"), "--scene", str(gap_scene),
                                          *map(str, flags)])
        with pytest.raises(Stop):
            run_planar(args)
    assert seen == ["auto", "none"]
