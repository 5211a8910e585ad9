"""A calibrated response's stated errors in the colour check's null hypothesis.

References are independent of the package: colour-science's measured camera
sensitivities, the Airy reflectance of a film in air at normal incidence written out here
(Born & Wolf eq. 7.6(13)), and Monte Carlo draws of the response within its stated errors
against the package's linear propagation."""

import numpy as np
import pytest
from helpers import kept_per_pixels

from bubblefit.inverse.colour_check import colour_check
from bubblefit.inverse.response_error import response_cells, response_error
from bubblefit.optics.spectral import response_stderr

CAMERA = "Nikon 5100 (NPL)"
ROWS = np.arange(380.0, 781.0, 5.0)
LAM = np.arange(380.0, 781.0, 1.0)


def _nikon(rows, camera=CAMERA):
    """colour-science's measured sensitivities of ``camera`` (default the Nikon) at ``rows``, each channel's peak 1."""
    import colour

    ms = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    s = np.stack([np.interp(rows, ms.wavelengths, ms.values[:, c], left=0, right=0) for c in range(3)], axis=1)
    return s / s.max(axis=0)


def _airy(d, n=1.33):
    r = (1 - n) / (1 + n)
    f = 4 * r * r / (1 - r * r) ** 2
    s2 = np.sin(2 * np.pi * n * d / LAM) ** 2
    return f * s2 / (1 + f * s2)


def _csv(tmp_path, err_rel):
    resp = _nikon(ROWS)
    err = err_rel * np.ones_like(resp)
    path = tmp_path / "camera.csv"
    lines = ["# camera response fitted by bubblefit calibrate-camera from film; illuminant E",
             "wavelength_nm,r,g,b,r_err,g_err,b_err"]
    lines += [f"{w:g}," + ",".join(f"{v:.8g}" for v in (*r, *e)) for w, r, e in zip(ROWS, resp, err)]
    path.write_text("\n".join(lines) + "\n")
    return str(path), resp, err


def test_stated_errors_read_and_absent(tmp_path):
    path, _, err = _csv(tmp_path, 0.01)
    rows, read = response_stderr(path)
    assert np.allclose(rows, ROWS) and np.allclose(read, err)
    bare = tmp_path / "bare.csv"
    bare.write_text("wavelength_nm,r,g,b\n" + "\n".join(f"{w:g},1,1,1" for w in ROWS) + "\n")
    assert response_stderr(str(bare)) is None and response_error(str(bare), "E", 1.33) is None
    assert response_error(CAMERA, "E", 1.33) is None and response_error("srgb", "D65", 1.33) is None


@pytest.mark.parametrize("d", [300.0, 1000.0, 1500.0])
def test_propagation_against_monte_carlo(tmp_path, d):
    """The linear covariance of a pixel ``y = E f + B (1 - f)`` against 4000 responses
    drawn within their errors (2 % of the peak per row, independent). Monte Carlo's
    relative error on a variance is sqrt(2/4000) = 2.2 %; the draws' second-order terms
    add about the square of the colour's relative change (a few %): 12 % allowed."""
    path, resp, err = _csv(tmp_path, 0.02)
    e_light, b_light = np.array([0.9, 1.0, 0.8]), np.array([0.2, 0.3, 0.25])
    rng = np.random.default_rng(3)
    refl = _airy(d)

    def pixel(r_rows):
        w = np.stack([np.interp(LAM, ROWS, r_rows[:, c]) for c in range(3)], axis=1)
        f = refl @ w / w.sum(axis=0)
        return e_light * f + b_light * (1 - f)

    draws = np.array([pixel(resp + err * rng.normal(size=resp.shape)) for _ in range(4000)])
    y0 = pixel(resp)
    jac = response_error(path, "E", 1.33).jacobian(y0[None], b_light[None], np.array([d]), np.array([1.0]))[0]
    predicted = np.sum(jac**2, axis=-1)
    assert np.allclose(predicted, draws.var(axis=0), rtol=0.12)


def _wedge(tmp_path):
    """A 36 px wedge 300 -> 1000 nm seen by the Nikon over a grey background, and each
    pixel's render change per one standard error of each row of a response CSV stating
    30 % errors."""
    path, _, _ = _csv(tmp_path, 0.3)
    h = w = 36
    yy, xx = np.mgrid[:h, :w]
    thick = 300.0 + 20.0 * xx
    refl = np.stack([_airy(t) for t in thick.ravel()])
    w_rows = _nikon(LAM)
    f = (refl @ w_rows / w_rows.sum(axis=0)).reshape(h, w, 3)
    e_light, b_light = np.array([0.9, 1.0, 0.8]), np.array([0.2, 0.3, 0.25])
    render = e_light * f + b_light * (1 - f)
    bg = np.broadcast_to(b_light, render.shape).copy()
    cos = np.ones((h, w))
    jac = response_error(path, "E", 1.33).jacobian(render.reshape(-1, 3), bg.reshape(-1, 3), thick.ravel(), cos.ravel())
    return path, render, bg, thick, cos, jac.reshape(h, w, 3, -1)


def test_check_holds_the_response_error(tmp_path):
    """With the model-error floors off (they would hide the small shift), cells whose mean
    hue is moved by one coherent draw of the response's error (the same draw for every
    pixel, as a calibrated response moves them) plus pixel noise: the check without the
    response's errors flags them, with them it does not."""
    path, render, bg, thick, cos, jac = _wedge(tmp_path)
    rng = np.random.default_rng(8)
    shift = np.einsum("yxkl,kl->yxk", jac, rng.normal(size=(3, len(ROWS))))
    sigma = np.full(render.shape, 0.002)
    photo = render + shift + sigma * rng.normal(size=render.shape)
    mask = np.ones(render.shape[:2], bool)
    plain = colour_check(photo, render, mask, sigma, floor=0.0, chroma_floor=0.0)
    held = colour_check(photo, render, mask, sigma, floor=0.0, chroma_floor=0.0,
                        response_jac=response_cells(path, "E", 1.33, render, bg, thick, cos))
    assert not plain.consistent and held.consistent and held.response_errors


def test_check_shares_the_response_between_cells(tmp_path):
    """The same wedge, but each 6 x 6 cell's hue moved by its own draw of the response's
    error: every cell alone is within the response's errors, the film as a whole is not
    (one response cannot move each cell its own way), and the check, whose null holds one
    draw for the whole photo, flags it."""
    path, render, bg, thick, cos, jac = _wedge(tmp_path)
    rng = np.random.default_rng(9)
    shift = np.zeros_like(render)
    for by in range(0, 36, 6):
        for bx in range(0, 36, 6):
            draw = rng.normal(size=(3, len(ROWS)))
            shift[by:by + 6, bx:bx + 6] = np.einsum("yxkl,kl->yxk", jac[by:by + 6, bx:bx + 6], draw)
    sigma = np.full(render.shape, 0.002)
    photo = render + shift + sigma * rng.normal(size=render.shape)
    check = colour_check(photo, render, np.ones(render.shape[:2], bool), sigma, floor=0.0, chroma_floor=0.0,
                         response_jac=response_cells(path, "E", 1.33, render, bg, thick, cos))
    assert not check.consistent, check.chi2_per_dof


def _modes_csv(tmp_path, rel, corr_nm):
    """A response CSV whose rows' errors are correlated: ``rel`` of the peak, with a Gaussian
    correlation of ``corr_nm`` between rows, written as the covariance's modes."""
    resp = _nikon(ROWS)
    cov = rel**2 * np.exp(-0.5 * ((ROWS[:, None] - ROWS[None, :]) / corr_nm) ** 2)
    vals, vecs = np.linalg.eigh(cov)
    keep = vals > 1e-10 * vals.max()
    modes = vecs[:, keep] * np.sqrt(vals[keep])  # (L, M), the same for the three channels
    path = tmp_path / "modes.csv"
    head = "wavelength_nm,r,g,b,r_err,g_err,b_err" + "".join(f",m{m + 1}_r,m{m + 1}_g,m{m + 1}_b"
                                                        for m in range(modes.shape[1]))
    err = np.sqrt(np.diag(cov))
    lines = ["# camera response fitted by bubblefit calibrate-camera from chart; illuminant E", head]
    lines += [f"{w:g}," + ",".join(f"{v:.10g}" for v in (*r, e, e, e, *np.repeat(u, 3)))
              for w, r, e, u in zip(ROWS, resp, err, modes)]
    path.write_text("\n".join(lines) + "\n")
    return str(path), resp, modes


def test_correlated_modes_read(tmp_path):
    """The modes columns are read back as each channel's covariance ``sum_m u_m u_m^T``; the
    per-row errors are its diagonal."""
    from bubblefit.optics.spectral import response_error_modes

    path, _, modes = _modes_csv(tmp_path, 0.02, 30.0)
    rows, read = response_error_modes(path)
    assert read.shape == (len(ROWS), 3, modes.shape[1])
    for c in range(3):
        assert np.allclose(read[:, c] @ read[:, c].T, modes @ modes.T, atol=1e-12)
    assert np.allclose(response_stderr(path)[1][:, 0], np.sqrt(np.sum(modes**2, axis=1)))


@pytest.mark.parametrize("d0", [600.0, 1500.0])
def test_thickness_error_from_the_response_against_monte_carlo(tmp_path, d0):
    """A constant film over a grey background, fitted for its thickness alone by least
    squares (1-D Newton, numpy) with the stated response, in photos rendered with 600
    responses drawn within its correlated errors (3 % of the peak, 25 nm correlation): the
    spread of the fitted thickness against the sandwich ``(J^T J)^-1 G (J^T J)^-1`` with
    ``G`` from ``response_gram``. Monte Carlo's relative error on a standard deviation is
    1/sqrt(2 * 600) = 2.9 %; the linearisation adds a few %: 15 % allowed."""
    from bubblefit.inverse.response_error import response_gram

    path, resp, modes = _modes_csv(tmp_path, 0.03, 25.0)
    e_light, b_light, sigma = np.array([0.9, 1.0, 0.8]), np.array([0.2, 0.3, 0.25]), 0.002
    h, w = 4, 6

    def pixel(d, r_rows):
        wl = np.stack([np.interp(LAM, ROWS, r_rows[:, c]) for c in range(3)], axis=1)
        f = _airy(d) @ wl / wl.sum(axis=0)
        return e_light * f + b_light * (1 - f)

    def slope(d, r_rows, step=0.05):
        return (pixel(d + step, r_rows) - pixel(d - step, r_rows)) / (2 * step)

    def fit(photo_px):  # every pixel alike: the least squares of one pixel
        d = d0
        for _ in range(6):
            g = slope(d, resp)
            d -= g @ (pixel(d, resp) - photo_px) / (g @ g)
        return d

    rng = np.random.default_rng(11)
    fitted = [fit(pixel(d0, resp + modes @ rng.normal(size=(modes.shape[1], 3)))) for _ in range(600)]
    jac = np.tile(slope(d0, resp) / sigma, h * w)[:, None]  # (h w 3, 1): whitened
    weight = np.full((h, w, 3), 1.0 / sigma)
    render = np.broadcast_to(pixel(d0, resp), (h, w, 3))
    gram = response_gram(response_error(path, "E", 1.33), jac, weight, render,
                         np.broadcast_to(b_light, (h, w, 3)), np.full((h, w), d0), np.ones((h, w)))
    a_inv = 1.0 / float(jac[:, 0] @ jac[:, 0])
    predicted = np.sqrt(a_inv * gram[0, 0] * a_inv)
    assert predicted > 0.5  # a response known to 3 % moves a film by nanometres: the test is not of zeros
    assert np.std(fitted) == pytest.approx(predicted, rel=0.15), (np.std(fitted), predicted)


@pytest.mark.parametrize("d0", [600.0, 1500.0])
def test_pixel_thickness_error_against_monte_carlo(tmp_path, d0):
    """One pixel's thickness fitted from its own three channels (a thickness map's pixel,
    the gain known; 1-D Newton, numpy), in renders through 600 responses drawn within the
    CSV's correlated errors (3 % of the peak, 25 nm correlation): the spread against
    ``pixel_thickness_stderr``. Monte Carlo's relative error on a standard deviation is
    1/sqrt(2 * 600) = 2.9 %; the linearisation adds a few %: 15 % allowed."""
    from bubblefit.inverse.response_error import pixel_thickness_stderr

    path, resp, modes = _modes_csv(tmp_path, 0.03, 25.0)
    e_light, b_light, sigma = np.array([0.9, 1.0, 0.8]), np.array([0.2, 0.3, 0.25]), 0.002

    def pixel(d, r_rows):
        wl = np.stack([np.interp(LAM, ROWS, r_rows[:, c]) for c in range(3)], axis=1)
        f = _airy(d) @ wl / wl.sum(axis=0)
        return e_light * f + b_light * (1 - f)

    def fit(photo_px):
        d = d0
        for _ in range(6):
            g = (pixel(d + 0.05, resp) - pixel(d - 0.05, resp)) / 0.1
            d -= g @ (pixel(d, resp) - photo_px) / (g @ g)
        return d

    rng = np.random.default_rng(12)
    fitted = [fit(pixel(d0, resp + modes @ rng.normal(size=(modes.shape[1], 3)))) for _ in range(600)]
    got = pixel_thickness_stderr(response_error(path, "E", 1.33), pixel(d0, resp)[None], b_light[None],
                                 np.array([d0]), np.ones(1), np.full((1, 3), 1.0 / sigma))
    assert got[0] > 0.5  # nanometres: the test is not of zeros
    assert np.std(fitted) == pytest.approx(got[0], rel=0.15), (np.std(fitted), got[0])


#: The lamp's and the background's light of the score tests' films (``y = E f + B (1 - f)``).
E_LIGHT, B_LIGHT = np.array([0.9, 1.0, 0.8]), np.array([0.2, 0.3, 0.25])


def _film(resp, thick):
    """The paper model's pixel ``E f + B (1 - f)`` of films of ``thick`` (h, w) nm at normal
    incidence through the response ``resp`` (on :data:`LAM`), white-balanced."""
    f = (np.stack([_airy(v) for v in np.ravel(thick)]) @ resp / resp.sum(axis=0)).reshape(*np.shape(thick), 3)
    return E_LIGHT * f + B_LIGHT * (1 - f)


def _score_member(photo, render, thick, sigma, jac):
    """The score test's member of the colour check's union (floors off, no stated errors)
    on ``photo`` against ``render``, parts split by the optical path ``2 n d``."""
    from bubblefit.inverse.colour_check import GRID, _tests

    got = _tests(photo, render, np.ones(render.shape[:2], bool), sigma, model_error=None, floor=0.0,
                 chroma_floor=0.0, grid=GRID, false_alarm=1e-3, response_jac=None, path=2 * 1.33 * thick,
                 path_bin=None, pooled=True, score_jac=jac)
    return next(c for c in got if c.partition == "response")


def test_score_test_of_the_response():
    """The colour check's score test along smooth changes of the response
    (``response_score_cells``: Legendre degrees 1-4 of each channel's response, the
    thickness profiled out) on a 32 px wedge of pale thick film (1300 -> 1700 nm) seen by
    the Nikon over a grey background, 0.1 % noise per channel, the floors off (and with them
    their shared draw along the directions). With the
    right render each part's mean chromatic residual is exactly normal with the covariance
    the check gives it, so the statistic follows chi^2 with 12 degrees of freedom: over 30
    draws its mean lies within 4 of its deviations (sqrt(2 * 12 / 30) = 0.89) of 12, and
    no draw exceeds its share of the threshold (1e-3 / 3: 0.01 alarms expected; one
    allowed). A film read 3 nm off (a few of a fit's standard errors) moves the hues along
    the thickness, which the test profiles out: the same law, where without that nuisance
    the test fires (its noise-free statistic about 130, ten times the 12 it adds to).
    A response changed smoothly by 60 % of itself at the ends of the range (red tilted up,
    green curved, blue tilted down) moves the hue by about 0.3 noise sigmas per pixel,
    which the directions hold (a non-centrality of about 100 against a threshold of 36:
    its deviation ~21), and the test fires on every draw."""
    from bubblefit.inverse.response_error import response_score_cells

    h = w = 32
    thick = 1300.0 + 400.0 * np.mgrid[:h, :w][1] / w
    nik = _nikon(LAM)
    x = (LAM - 580.0) / 200.0
    truth = _film(nik, thick)
    wrong = _film(nik * (1 + 0.6 * np.stack([x, 1.5 * x**2 - 0.5, -x], axis=1)), thick)
    off = _film(nik, thick + 3.0)
    bg = np.broadcast_to(B_LIGHT, truth.shape).copy()
    sigma = np.full(truth.shape, 0.001)
    score = kept_per_pixels(response_score_cells(CAMERA, "E", 1.33, truth, bg, thick, np.ones((h, w))))

    def bare(ys, xs):  # the same directions, no nuisance
        return score(ys, xs)[0], np.zeros((ys.size, 3, 1))

    def test(photo, jac=score):
        return _score_member(photo, truth, thick, sigma, jac)

    rng = np.random.default_rng(4)
    for centre in (truth, off):
        got = [test(centre + sigma * rng.normal(size=truth.shape)) for _ in range(30)]
        stat = np.array([c.chi2_per_dof * c.dof for c in got])
        assert got[0].dof == 12 and abs(stat.mean() - 12) < 4 * np.sqrt(2 * 12 / 30), stat.mean()
        assert sum(not c.consistent for c in got) <= 1, stat.max()
    assert not test(off, bare).consistent
    for _ in range(3):
        c = test(wrong + sigma * rng.normal(size=truth.shape))
        assert not c.consistent and c.dof == 12, c


def test_score_test_of_a_drainage_profile():
    """The score test on a draining film, its nuisances the drainage profile's three
    parameters (``response_score_cells``' ``nuisance``: ``drainage_gradient`` at each
    pixel's height): a 32 px film ``200 + 1000 ((1 - y) / 2)^2.5`` nm seen by the Nikon,
    0.1 % noise per channel, the floors off. The fit's profile is taken off the photo's by
    (5 nm, 5 nm, 0.05) in (top, bottom, exponent), -2.4 to +5.0 nm over the film: the
    photo is the render moved along that change (its central difference, so that what is
    left beyond first order is third order, about 1e-4 of the move), which the profile's
    nuisance profiles out: the statistic follows chi^2 with 12 degrees of freedom, its mean
    over 20 draws within 4 deviations (sqrt(2 * 12 / 20) = 1.1) of 12, at most one alarm
    (1e-3 / 3 each: 0.007 expected). A constant film's nuisance (1, v, v^2 of the row)
    cannot follow the exponent's ``x^2.5 ln x``, and its noise-free statistic (about 70)
    exceeds the threshold of 36. The same film seen by the Sigma and tested with the
    Nikon's response is flagged on every draw (a hue error of several % of the colour,
    hundreds of noise sigmas per part)."""
    from bubblefit.inverse.response_error import response_score_cells
    from bubblefit.model.thickness import drainage_gradient, drainage_profile

    h = w = 32
    height = np.broadcast_to((1 - 2 * (np.arange(h) + 0.5) / h)[:, None], (h, w))
    prof = (200.0, 1200.0, 2.5)
    thick = np.asarray(drainage_profile(height, *prof), np.float64)
    grad = np.asarray(drainage_gradient(height, *prof), np.float64)
    nik = _nikon(LAM)
    truth = _film(nik, thick)
    move = grad @ np.array([5.0, 5.0, 0.05])
    off = truth + 0.5 * (_film(nik, thick + move) - _film(nik, thick - move))
    other = _film(_nikon(LAM, "Sigma SDMerill (NPL)"), thick)
    bg = np.broadcast_to(B_LIGHT, truth.shape).copy()
    sigma = np.full(truth.shape, 0.001)
    profile = kept_per_pixels(response_score_cells(CAMERA, "E", 1.33, truth, bg, thick, np.ones((h, w)), nuisance=grad))
    constant = response_score_cells(CAMERA, "E", 1.33, truth, bg, thick, np.ones((h, w)))

    rng = np.random.default_rng(5)
    got = [_score_member(off + sigma * rng.normal(size=truth.shape), truth, thick, sigma, profile) for _ in range(20)]
    stat = np.array([c.chi2_per_dof * c.dof for c in got])
    assert got[0].dof == 12 and abs(stat.mean() - 12) < 4 * np.sqrt(2 * 12 / 20), stat.mean()
    assert sum(not c.consistent for c in got) <= 1, stat.max()
    assert not _score_member(off, truth, thick, sigma, constant).consistent
    for _ in range(2):
        c = _score_member(other + sigma * rng.normal(size=truth.shape), truth, thick, sigma, profile)
        assert not c.consistent and c.dof == 12, c


@pytest.mark.parametrize("n_film", [1.33, 1.5])
def test_tabulated_terms_against_direct(n_film):
    """The score test's spectral terms interpolated from the table in (optical path,
    cosine) (``tabulated_terms``) against the same terms evaluated at each pixel, both in
    float64, over 6000 pixels of films 300-700 nm thick seen at cosines 0.6-1 (a draining
    film's range; its table holds fewer nodes, at most 3,800, than there are pixels) and of
    one 380 nm film: each term's largest error, relative to its
    largest size over the pixels, stays within the bound its steps were chosen for
    (``TABLE_PATH_STEP_NM``: 1.4e-5 of the fringes' amplitude along the path, plus
    ``TABLE_COS_STEP``: 3.4e-6 of the reflectance along the cosine), taken as 2e-5."""
    import jax

    from bubblefit.inverse.response_error import response_perturbation, tabulated_terms

    err = response_perturbation(CAMERA, "E", n_film)
    rng = np.random.default_rng(7)
    cos = rng.uniform(0.6, 1.0, 6000)
    with jax.enable_x64(True):
        for d in (rng.uniform(300.0, 700.0, 6000), np.full(6000, 380.0)):
            direct = (*err.spectral_terms(err.reflectance(d, cos)), err.share_slope(d, lambda t: err.reflectance(t, cos)))
            table = tabulated_terms(err, d, cos)
            for got, want in zip(table, direct):
                got, want = got.reshape(d.size, -1), want.reshape(d.size, -1)
                rel = np.max(np.abs(got - want), axis=0) / np.max(np.abs(want), axis=0)
                assert rel.max() < 2e-5, rel.max()


def test_score_floor_draw_does_not_depend_on_the_directions_units():
    """The score test's statistic is the part of the whitened residual that the directions'
    span explains, so it does not depend on their units; its null must not either. The
    floors' shared draw along the directions (``_score_verdict``) is spread evenly over
    them, each scaled by its own reach: scaling one direction by 1e6 and another by 1e-6 in
    every part (as an sRGB film's red share crossing zero scales the red channel's
    directions) leaves the statistic the same to rounding (float64's 2.2e-16 times the
    covariance's condition number, times 100 for the Cholesky and SVD steps). With one
    ``tau^2`` for all directions the draw would go to the scaled-up one alone, and the
    statistic on this residual, which follows every direction, grows tenfold (13 to 138 per
    degree of freedom)."""
    from bubblefit.inverse.colour_check import _Part, _score_verdict

    rng = np.random.default_rng(11)
    parts, k = 40, 6
    dirs = rng.normal(size=(parts, 2, k)) * np.linspace(1.0, 2.0, parts)[:, None, None]
    nuis = rng.normal(size=(parts, 2, 1))
    noise = np.eye(2) * 1e-6
    floor = np.eye(2) * 4e-6       # the floors larger than the noise: the shared draw matters
    coef = rng.normal(size=k) * 2e-3
    mean = np.einsum("bij,j->bi", dirs, coef) + rng.normal(size=(parts, 2)) * 1e-3

    def cells(d):  # colour_check._cell_terms' parts, no Type B offset (F_b = floors, |s_b| = 0)
        return [_Part(mean[b], noise, floor, 1.0, None, (d[b], nuis[b]), floor, 0.0) for b in range(parts)]

    base = _score_verdict(cells(dirs), 1.0, 1e-3, False)
    scaled = dirs * np.array([1e6, 1e-6, 1, 1, 1, 1])
    got = _score_verdict(cells(scaled), 1.0, 1e-3, False)
    sigma = np.kron(np.eye(parts), noise + floor) + np.concatenate(dirs) @ np.concatenate(dirs).T * 4e-6 / k
    tol = 100 * 2.2e-16 * np.linalg.cond(sigma)
    assert got.dof == base.dof == k
    assert abs(got.chi2_per_dof - base.chi2_per_dof) <= tol * base.chi2_per_dof, (got.chi2_per_dof, base.chi2_per_dof)
