"""The order test with a calibrated response's errors marginalised (bubblefit.inverse.order_check).

The photo is a constant film over a grey background written out with numpy (the Airy
reflectance of a film in air at normal incidence, Born & Wolf eq. 7.6(13), seen through
colour-science's Nikon D5100 sensitivities): independent of the package's renderer. Its two
candidates (the film's own order and the neighbouring one) are fitted here by Gauss-Newton
in (thickness, gain)."""

from types import SimpleNamespace

import numpy as np
import pytest

from bubblefit.inverse._local import LocalSolution
from bubblefit.inverse.order_check import neighbouring_orders, order_check, order_separation, order_threshold
from bubblefit.inverse.response_error import marginal_chi2, response_error
from test_response_error import LAM, _airy, _modes_csv

E_LIGHT, B_LIGHT, SIGMA = np.array([0.9, 1.0, 0.8]), np.array([0.2, 0.3, 0.25]), 0.002
H = W = 16
D_TRUE = 1500.0


def _pixel(d, rows, resp, gain=1.0):
    wl = np.stack([np.interp(LAM, rows, resp[:, c]) for c in range(3)], axis=1)
    f = _airy(d) @ wl / wl.sum(axis=0)
    return gain * E_LIGHT * f + B_LIGHT * (1 - f)


def _solve(photo_px, d, rows, resp):
    """Gauss-Newton in (thickness, gain) of the H x W pixels alike; the whitened residual
    and its Jacobian (central differences) at the end."""
    z = np.array([d, 1.0])

    def resid(z):
        return np.tile((_pixel(z[0], rows, resp, z[1]) - photo_px) / SIGMA, H * W)

    def jac(z):
        steps = np.array([0.05, 1e-4])
        return np.stack([(resid(z + s * e) - resid(z - s * e)) / (2 * s) for s, e in zip(steps, np.eye(2))], axis=1)

    for _ in range(12):
        j, r = jac(z), resid(z)
        z = z - np.linalg.lstsq(j, r, rcond=None)[0]
    return z, resid(z), jac(z)


def _level(render_px, photo_px):
    shape = (H, W, 3)
    return SimpleNamespace(w=np.full(shape, 1.0 / SIGMA), y=np.broadcast_to(photo_px, shape).copy(),
                           bg=np.broadcast_to(B_LIGHT, shape).copy(), cos=np.ones((H, W)), height=np.zeros((H, W)))


def _candidates(path, rows, resp):
    """The film's own order and the neighbouring order below (the plain cost's lowest
    local minimum more than a half fringe away), each solved; the noise-free photo."""
    photo = _pixel(D_TRUE, rows, resp)
    grid = np.arange(D_TRUE - 320.0, D_TRUE - order_separation(1.33), 2.0)
    cost = [np.sum((_pixel(d, rows, resp) - photo) ** 2) for d in grid]
    sols = []
    for d0 in (D_TRUE, float(grid[int(np.argmin(cost))])):
        z, r, j = _solve(photo, d0, rows, resp)
        sols.append(LocalSolution({"thickness_nm": float(z[0]), "exposure": float(z[1])}, z, True, False, 12, r, j, {}))
    return photo, sols


def test_marginal_chi2_is_the_generalised_least_squares():
    """``marginal_chi2`` (Woodbury, joint Gauss-Newton decrement) against the dense
    generalised least squares ``min_dz (r + J dz)^T (I + G G^T)^-1 (r + J dz)`` with ``G``
    the whitened render change along each stated error mode, written out here."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path, resp, _ = _modes_csv(Path(tmp), 0.03, 25.0)
        err = response_error(path, "E", 1.33)
    rng = np.random.default_rng(4)
    render = np.broadcast_to(_pixel(900.0, np.arange(380.0, 781.0, 5.0), resp), (H, W, 3)).copy()
    render = render * (1 + 0.01 * rng.normal(size=render.shape))
    thick = np.full((H, W), 900.0) + rng.normal(size=(H, W))
    weight = np.full((H, W, 3), 1.0 / SIGMA)
    bg = np.broadcast_to(B_LIGHT, (H, W, 3)).copy()
    jac = rng.normal(size=(H * W * 3, 2))
    r = rng.normal(size=H * W * 3)
    chi2, marg = marginal_chi2(err, jac, r, weight, render, bg, thick, np.ones((H, W)))
    g = (err.jacobian(render.reshape(-1, 3), bg.reshape(-1, 3), thick.ravel(), np.ones(H * W))
         * weight.reshape(-1, 3)[:, :, None])                       # (n, 3, M) per channel
    m = g.shape[-1]
    gg = np.zeros((H * W * 3, 3 * m))
    for c in range(3):
        gg[c::3, c * m:(c + 1) * m] = g[:, c]
    sig_inv = np.linalg.inv(np.eye(H * W * 3) + gg @ gg.T)
    dz = -np.linalg.solve(jac.T @ sig_inv @ jac, jac.T @ sig_inv @ r)
    gls = float((r + jac @ dz) @ sig_inv @ (r + jac @ dz))
    assert chi2 == pytest.approx(float(r @ r), rel=1e-12)
    assert marg == pytest.approx(gls, rel=1e-8)
    assert marg < chi2


@pytest.mark.parametrize("rel, determined", [(0.0005, True), (0.05, False)])
def test_neighbouring_order_admitted_only_within_the_response_errors(tmp_path, rel, determined):
    """A noise-free 1500 nm film: its own order fits exactly, the neighbouring order's best
    leaves a colour error of several noise sigmas per pixel (a plain chi^2 difference far
    above the threshold). A response known to 0.05 % of its peak cannot absorb that and
    the order is determined; one known to 5 % (25 nm correlation) can: one draw of it moves
    the film's colour at the neighbouring order onto the photo's, and the neighbouring
    order is admitted."""
    path, resp, _ = _modes_csv(tmp_path, rel, 25.0)
    rows = np.arange(380.0, 781.0, 5.0)
    photo, sols = _candidates(path, rows, resp)
    assert abs(sols[1].values["thickness_nm"] - D_TRUE) > order_separation(1.33)
    err = response_error(path, "E", 1.33)
    lev = _level(None, photo)
    check = order_check(err, lev, sols, robust_scale=1e6, n_params=2)
    assert check.delta_chi2_plain > order_threshold()  # without the response's errors: excluded
    assert check.delta_chi2 <= check.delta_chi2_plain
    assert check.determined is determined
    assert check.alternative_nm == pytest.approx(sols[1].values["thickness_nm"])
    assert (check.warning() is None) is determined
    if not determined:
        assert f"admits the neighbouring order at {sols[1].values['thickness_nm']:.0f} nm" in check.warning()


def test_threshold_is_the_one_degree_of_freedom_quantile():
    """The chi^2 law with one degree of freedom: P(chi2_1 > 10.828) = 1e-3 (Abramowitz &
    Stegun, table 26.8)."""
    assert order_threshold(1e-3) == pytest.approx(10.828, abs=1e-3)
    assert order_separation(1.33) == pytest.approx(580.0 / (4 * 1.33))


def test_a_fit_in_another_order_than_the_best_is_not_determined(tmp_path):
    """Seen from the neighbouring order's candidate (a warm start that settled there), the
    test is not determined whatever the margin, and names the best's order, with the
    difference's sign turned (the best explains the photo better)."""
    path, resp, _ = _modes_csv(tmp_path, 0.0005, 25.0)
    rows = np.arange(380.0, 781.0, 5.0)
    photo, sols = _candidates(path, rows, resp)
    check = order_check(response_error(path, "E", 1.33), _level(None, photo), sols, robust_scale=1e6, n_params=2)
    assert check.determined and check.at(D_TRUE + 2.0, 1.33) is check
    other = check.at(sols[1].values["thickness_nm"], 1.33)
    assert not other.determined and other.alternative_nm == pytest.approx(check.thickness_nm)
    assert other.delta_chi2 == pytest.approx(-check.delta_chi2)
    assert "explains the photo better" in other.warning()


def test_neighbouring_orders_move_a_film_and_a_profile_by_one_fringe():
    """One fringe is ``2 order_separation`` (eq. (8)'s phase changes by ``2 pi``): a
    constant film moves up and down, a profile moves whole and at its thin end alone, and
    a start that would leave the searched range is not made."""
    fringe = 2 * order_separation(1.33)
    const = neighbouring_orders({"thickness_nm": 150.0, "exposure": 1.0}, ("thickness_nm",), 1.33, 0.0, 2000.0)
    assert [c["thickness_nm"] for c in const] == pytest.approx([150.0 + fringe])  # 150 - fringe < 0
    assert all(c["exposure"] == 1.0 for c in const)
    prof = neighbouring_orders({"top_nm": 900.0, "bottom_nm": 1300.0}, ("top_nm", "bottom_nm"), 1.33, 0.0, 2000.0)
    got = sorted((c["top_nm"], c["bottom_nm"]) for c in prof)
    want = sorted([(900 - fringe, 1300 - fringe), (900 - fringe, 1300.0), (900 + fringe, 1300 + fringe),
                   (900 + fringe, 1300.0)])
    assert np.array(got) == pytest.approx(np.array(want))


H_PROFILE = np.repeat(np.linspace(-1.0, 1.0, H), W).reshape(H, W)  # the film's height over its radius, by row


def _profile_photo(top, bottom, rows, resp, gain=1.0):
    """(H, W, 3) pixels of a drainage profile (docs/design.md, exponent 1) down the rows,
    each the Airy film of :func:`_pixel`."""
    d = top + (bottom - top) * (1.0 - H_PROFILE) / 2.0
    wl = np.stack([np.interp(LAM, rows, resp[:, c]) for c in range(3)], axis=1)
    f = np.stack([_airy(x) for x in d.ravel()]) @ wl / wl.sum(axis=0)
    return (gain * E_LIGHT * f + B_LIGHT * (1 - f)).reshape(H, W, 3)


def _profile_candidates(rows, resp, top, bottom):
    """A noise-free draining film and two solves of its profile by Gauss-Newton in (top,
    bottom, gain): from the truth and from the whole profile one fringe thinner
    (:func:`neighbouring_orders`)."""
    photo = _profile_photo(top, bottom, rows, resp)

    def resid(z):
        return ((_profile_photo(z[0], z[1], rows, resp, z[2]) - photo) / SIGMA).ravel()

    def jac(z):
        steps = np.array([0.05, 0.05, 1e-4])
        return np.stack([(resid(z + s * e) - resid(z - s * e)) / (2 * s) for s, e in zip(steps, np.eye(3))], axis=1)

    starts = [{"top_nm": top, "bottom_nm": bottom}]
    starts += [s for s in neighbouring_orders(starts[0], ("top_nm", "bottom_nm"), 1.33, 0.0, 4000.0)
               if s["top_nm"] < top and s["bottom_nm"] < bottom]
    sols = []
    for s in starts:
        z = np.array([s["top_nm"], s["bottom_nm"], 1.0])
        for _ in range(12):
            z = z - np.linalg.lstsq(jac(z), resid(z), rcond=None)[0]
        r = resid(z)
        sols.append(LocalSolution({"top_nm": float(z[0]), "bottom_nm": float(z[1]), "exponent": 1.0,
                                   "exposure": float(z[2]), "thickness_nm": 500.0}, z, True, False, 12, r, jac(z), {}))
    return photo, sols


@pytest.mark.parametrize("rel, determined", [(0.0005, True), (0.05, False)])
def test_a_profile_order_admitted_only_within_the_response_errors(tmp_path, rel, determined):
    """A noise-free film draining from 1490 nm at the top to 1510 nm at the bottom (little
    range: its colours tell its order no better than a constant film's) and the same
    profile solved from one fringe thinner: as for a constant film, a response known to
    0.05 % excludes the neighbouring order and one known to 5 % admits it. The test
    reads the profile, not the held ``thickness_nm`` the solves' values also carry, and
    names the alternative by its two ends."""
    path, resp, _ = _modes_csv(tmp_path, rel, 25.0)
    rows = np.arange(380.0, 781.0, 5.0)
    photo, sols = _profile_candidates(rows, resp, 1490.0, 1510.0)
    alt = (sols[1].values["top_nm"], sols[1].values["bottom_nm"])
    assert abs(alt[0] - 1490.0) > order_separation(1.33)
    lev = SimpleNamespace(**{**vars(_level(None, photo[0, 0])), "y": photo, "height": H_PROFILE})
    check = order_check(response_error(path, "E", 1.33), lev, sols, robust_scale=1e6, n_params=3,
                        thickness_model="drainage")
    assert check.parameters == ("top_nm", "bottom_nm")
    assert check.thickness_nm == pytest.approx((1490.0, 1510.0), abs=0.5)
    assert check.alternative_nm == pytest.approx(alt)
    assert check.delta_chi2_plain > order_threshold()
    assert check.determined is determined
    if not determined:
        assert f"the profile from {alt[0]:.0f} nm (top) to {alt[1]:.0f} nm (bottom)" in check.warning()
    # seen from the alternative's order (a map or a warm start left there): never determined
    assert not check.at(alt, 1.33).determined
    assert check.to_json()["thickness_nm"] == list(check.thickness_nm)


@pytest.mark.slow
def test_bubble_drainage_order_through_the_fit(small_courtyard, tmp_path):
    """A bubble draining from 300 nm at the top to 900 nm at the bottom (exponent 1; the
    48 px photo of tests/helpers.py's ``film_photo``: bubblefit's renderer, 8-bit codes
    with read and shot noise) rendered through the Nikon CSV's response and fitted by
    ``bubblefit.fit_photo`` with the drainage profile and that CSV stating correlated
    errors of 5 % of its peak. The profile spans 2.8 fringes (``580 / (2 n)`` = 218 nm of
    thickness each): the search's profile moved one fringe, whole or at its thin end,
    changes the sequence of colours from the top to the bottom of the bubble, which one
    draw of the response (the same for every pixel) cannot undo. So the JSON's
    ``order_check`` is determined though the response is known to 5 % only (where a
    constant 1500 nm film's neighbouring order is admitted, above), and the fit is ok
    within 3 standard errors of each end."""
    from bubblefit import FitOptions, fit_photo
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.lighting.envmap import EnvMap
    from helpers import FILM_PHOTO_DISC, film_photo

    path, _, _ = _modes_csv(tmp_path, 0.05, 25.0)
    env = EnvMap.from_array(small_courtyard)
    photo, bg = film_photo(env, (300.0, 900.0, 1.0), 7, path, "E")
    r = fit_photo(photo, env, background=bg, options=FitOptions(
        disc=FILM_PHOTO_DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=path,
        illuminant="E", view=ORTHOGRAPHIC, thickness="drainage"))
    check = r.to_json()["order_check"]
    assert check is not None and check["parameters"] == ["top_nm", "bottom_nm"], check
    assert check["delta_chi2_plain"] > check["threshold"]  # the response taken as exact excludes it
    assert check["determined"], check
    assert check["delta_chi2"] > check["threshold"]
    assert r.ok, r.warnings
    for name, truth in (("top_nm", 300.0), ("bottom_nm", 900.0)):
        assert abs(r.params[name] - truth) < 3 * r.stderr[name], (r.params, r.stderr)
