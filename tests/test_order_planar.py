"""The order test of flat films' few-parameter fits (bubblefit.inverse._planar_lm.fit_order):
a constant film, a drainage profile and Newton's rings, with a calibrated response's errors
marginalised.

The photos are noise-free renders of the package's own flat-film model (``PlanarForward``:
water on BK7, or Newton's air gap between BK7 glasses, under coaxial light, 16 x 16 pixels
of 2 um) seen through colour-science's
Nikon D5100 written as a CSV whose rows have correlated errors (tests/test_response_error.py),
known to 0.05 % or 5 % of the peak; the fits' whitening is a noise of 0.002. As for a
constant film (tests/test_order_check.py), a thick film's neighbouring order is admitted
by the looser response and excluded by the tighter one; a film whose colours run from the
black film (a contact point, a thin profile) tells its order whatever the response."""

import numpy as np
import pytest

from test_response_error import _modes_csv

SIGMA = 0.002
HI = 2000.0


def _forward(tmp_path, rel, layers=("air", "water", "bk7"), hi=HI):
    from bubblefit.inverse.planar import PlanarForward, view_of
    from bubblefit.model.planar_scene import parse_planar

    path, _, _ = _modes_csv(tmp_path, rel, 25.0)
    scene = parse_planar({"film": {"shape": "plane", "n": layers[1], "above": layers[0], "below": layers[2],
                                   "thickness": "constant", "range_nm": [0.0, hi]},
                          "light": {"type": "coaxial", "na": 0.25, "lamp": "E"},
                          "camera": {"width": 16, "height": 16, "pixel_um": 2.0, "response": str(path)}})
    return PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, hi), view_of(scene)


@pytest.mark.parametrize("rel, top, bottom, determined", [(0.0005, 1490.0, 1510.0, True),
                                                          (0.05, 1490.0, 1510.0, False),
                                                          (0.05, 300.0, 900.0, True)])
def test_planar_profile_order(tmp_path, rel, top, bottom, determined):
    """A flat film draining down the frame, fitted as a profile from its own (top,
    bottom, exponent 1): its neighbouring orders (the whole profile, its thin end) are
    fitted again and compared; an admitted one is named and the fit's warning says so."""
    from bubblefit.inverse._drainage_plane import fit_drainage
    from bubblefit.model.thickness import drainage_profile

    fwd, view = _forward(tmp_path, rel)
    m = view.mask
    h, s2, lum = view.height[m], view.sin2[m], view.radiance[m]
    d = np.asarray(drainage_profile(h, top, bottom, 1.0), np.float64)
    y = np.asarray(fwd.rgb(d, s2), np.float64) * lum[:, None]
    res = fit_drainage(fwd, y, lum, s2, h, (top, bottom, 1.0), 1.0, SIGMA, 0.0, HI, m.shape, np.flatnonzero(m.ravel()))
    check = res.order
    assert check.parameters == ("top_nm", "bottom_nm")
    assert check.thickness_nm == pytest.approx((top, bottom), abs=1.0)
    assert check.delta_chi2_plain > check.threshold  # the response taken as exact excludes it
    assert check.determined is determined
    assert (check.warning() is None) is determined


def test_newton_rings_order(tmp_path):
    """Newton's rings (an air gap between BK7 glasses) of a lens touching the plate (a black contact point: fitted by
    ``fit_newton`` from its per-pixel start) tell their order with a response known to
    5 %: the contact offset one fringe up leaves a coloured centre no draw of the response
    darkens. A flatter lens lifted to a 2000 nm gap (pale high-order rings growing by 30 nm
    over 16 um, no contact: about the optical path of the constant 1500 nm water film of
    tests/test_order_check.py) in a noisier photo (0.005) is fitted from its truth: its
    rings one fringe lower or higher are admitted by a response known to 20 % (not by one
    known to 5 % or 10 %: a draw of the response must move every ring's colour at once), though
    the response taken as exact excludes them."""
    import jax.numpy as jnp

    from bubblefit.inverse._newton import fit_newton, newton_gap
    from bubblefit.inverse._planar_lm import fit_colours, fit_order

    hi = 3000.0  # above the lifted lens's widest gap
    for h0, growth, sigma, rel, determined in ((0.0, 300.0, SIGMA, 0.05, True), (2000.0, 30.0, 0.005, 0.2, False)):
        radius = 1000.0 * 16.0**2 / (2 * growth)  # um: the gap grows by ``growth`` nm over 16 um
        (tmp_path / f"{h0:g}").mkdir()
        fwd, view = _forward(tmp_path / f"{h0:g}", rel, ("bk7", "air", "bk7"), hi)
        m = view.mask
        x, yy, s2, lum = view.x_um[m], view.y_um[m], view.sin2[m], view.radiance[m]
        gap = np.asarray(newton_gap(jnp.asarray(np.hypot(x - 1.0, yy - 1.0)), radius, h0), np.float64)
        y = np.asarray(fwd.rgb(gap, s2), np.float64) * lum[:, None]
        if h0 == 0.0:
            check = fit_newton(fwd, y, lum, s2, view, m, gap, 1.0, sigma, 0.0, hi).order
        else:
            xj, yj, lj, sj = (jnp.asarray(a) for a in (x, yy, lum, s2))

            def gap_of(t):
                return jnp.clip(newton_gap(jnp.sqrt((xj - t[1]) ** 2 + (yj - t[2]) ** 2), jnp.exp(t[0]), t[3]), 0.0, hi)

            def model(t):
                return jnp.exp(t[4]) * lj[:, None] * fwd.rgb(gap_of(t), sj)

            theta = jnp.asarray([np.log(radius), 1.0, 1.0, h0, 0.0])
            fitted = fit_colours(model, jnp.asarray(y), sigma, np.inf, theta)
            check = fit_order(fwd, model, gap_of, jnp.asarray(y), sigma, np.inf, fitted, {"contact_offset_nm": 3},
                              s2, 0.0, hi)
        assert check.parameters == ("contact_offset_nm",)
        assert check.thickness_nm == pytest.approx(h0, abs=1.0)
        assert abs(check.alternative_nm - h0) > 0.5 * fwd.fringe_nm
        assert check.delta_chi2_plain > check.threshold
        assert check.determined is determined, (h0, check.scored, check.delta_chi2_plain)


@pytest.mark.parametrize("rel, determined", [(0.0005, True), (0.05, False)])
def test_constant_flat_film_order(tmp_path, rel, determined):
    """A constant 1500 nm water film on BK7 (16 x 16 pixels, its brightest channel at 0.5,
    Gaussian noise 0.002 drawn with a fixed seed) through ``fit_planar``: the film at one
    thickness and exposure refitted one fringe thinner and thicker, the candidates compared
    with the response's errors marginalised, as for a bubble's constant film
    (tests/test_order_check.py). The response taken as exact excludes the neighbouring
    order; known to 0.05 % of its peak it still does (the fit is ok, ``order_check``
    determined), known to 5 % it admits it: ``ok`` false with the order test's line as its
    only warning (the colour-only "nearly as well" warning is the response taken as
    exact's)."""
    from bubblefit.inverse.order_check import order_separation
    from bubblefit.inverse.planar import fit_planar
    from bubblefit.model.planar_scene import parse_planar

    d_true = 1500.0
    path, _, _ = _modes_csv(tmp_path, rel, 25.0)
    scene = parse_planar({"film": {"shape": "plane", "n": "water", "above": "air", "below": "bk7",
                                   "thickness": "constant", "range_nm": [0.0, HI]},
                          "light": {"type": "coaxial", "na": 0.25, "lamp": "E"},
                          "camera": {"width": 16, "height": 16, "pixel_um": 2.0, "response": path}})
    fwd, view = _forward(tmp_path, rel)
    colours = np.asarray(fwd.rgb(np.full(int(view.mask.sum()), d_true), view.sin2[view.mask]), np.float64)
    noise = np.random.default_rng(0).normal(scale=SIGMA, size=colours.shape)
    photo = (0.5 * colours / colours.max() + noise).reshape(16, 16, 3)
    res = fit_planar(photo, scene)
    check = res.to_json()["order_check"]
    assert check is not None and check["parameters"] == ["thickness_nm"]
    assert abs(res.params["thickness_nm"] - d_true) < 3 * res.stderr["thickness_nm"], res.params
    # the neighbouring order: one fringe (2 order_separation) away, past half a fringe
    assert abs(check["alternative_nm"] - d_true) > order_separation(1.33)
    assert check["delta_chi2_plain"] > check["threshold"]  # the response taken as exact excludes it
    assert check["determined"] is determined, check
    assert res.ok is determined, res.warnings
    if determined:
        assert res.warnings == []
    else:
        assert len(res.warnings) == 1 and "admits the neighbouring order" in res.warnings[0], res.warnings



@pytest.mark.slow
@pytest.mark.parametrize("top, bottom, rel, determined", [(300.0, 900.0, 0.05, True), (1490.0, 1510.0, 0.2, False)])
def test_planar_drainage_order_through_the_command(tmp_path, top, bottom, rel, determined):
    """``bubblefit fit PHOTO --scene FILM.toml --thickness drainage`` on a flat water film
    draining from ``top`` to ``bottom`` down the frame (16 x 16 pixels, a 32-bit EXR of the
    film's own reflectance, brightest channel about 0.025, with Gaussian noise 0.002 drawn
    with a fixed seed: the signal-to-noise of the fits above), the scene's response the
    Nikon CSV with correlated errors (25 nm) of ``rel`` of its peak. The global search finds
    the profile; the JSON's ``order_check`` compares it with its neighbouring orders.

    The error sizes from the arithmetic. A film draining from 300 to 900 nm spans 2.8
    fringes (218 nm of water each): the profile one fringe thinner or thicker, whole or at
    its thin end, changes the sequence of colours along the film, which one draw of the
    response (the same for every pixel) cannot undo, so even a response known to 5 % leaves
    it determined. A film from 1490 to 1510 nm has one pale colour: the neighbouring
    order's best colours miss the photo's by ``delta = sigma sqrt(B dchi2_plain / n)`` rms
    per value (``n`` values, ``B`` the Birge ratio), a fraction ``delta / peak`` of the
    brightest channel, and a draw of the response moves every pixel's colour by about
    ``rel`` of the peak (its errors are fractions of the peak, correlated over a channel's
    width) at a prior cost of about ``(delta / rel)^2``, under 1 when ``rel > delta / peak``:
    a response known to 20 % admits the neighbouring order (``ok`` false, the order test's
    line in the warnings). The test checks that ``delta / peak`` is under ``rel`` before it
    checks the decision."""
    import json

    from bubblefit.cli import main
    from bubblefit.io.images import write_image
    from bubblefit.model.thickness import drainage_profile

    size = 16
    fwd, view = _forward(tmp_path, rel)
    m = view.mask
    d = np.asarray(drainage_profile(view.height[m], top, bottom, 1.0), np.float64)
    colours = np.asarray(fwd.rgb(d, view.sin2[m]), np.float64)
    noise = np.random.default_rng(0).normal(scale=SIGMA, size=colours.shape)
    write_image(tmp_path / "photo.exr", (colours + noise).reshape(size, size, 3), bit_depth=32)
    (tmp_path / "film.toml").write_text(
        '[film]\nshape = "plane"\nn = "water"\nabove = "air"\nbelow = "bk7"\nthickness = "drainage"\n'
        f'range_nm = [0.0, {HI}]\n[light]\ntype = "coaxial"\nna = 0.25\nlamp = "E"\n'
        f'[camera]\nwidth = {size}\nheight = {size}\npixel_um = 2.0\nresponse = "{fwd.response}"\n')
    out = tmp_path / "r.json"
    assert main(["fit", str(tmp_path / "photo.exr"), "--scene", str(tmp_path / "film.toml"), "--thickness",
                 "drainage", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    check = res["order_check"]
    assert check is not None and check["parameters"] == ["top_nm", "bottom_nm"], res
    for name, truth in (("top_nm", top), ("bottom_nm", bottom)):
        assert abs(res["params"][name] - truth) < 3 * res["stderr"][name], res["params"]
    assert check["delta_chi2_plain"] > check["threshold"]  # the response taken as exact excludes it
    assert check["determined"] is determined, check
    said = [w for w in res["warnings"] if "admits the neighbouring order" in w]
    if determined:
        assert res["ok"] and not said, res["warnings"]
    else:
        delta = res["noise_sigma"] * np.sqrt(check["delta_chi2_plain"] * check["birge_scale"] / (3 * size * size))
        assert delta / float(colours.max()) < rel, delta
        assert not res["ok"] and len(said) == 1 and "calibrate the camera" in said[0], res["warnings"]
