"""The thickness map's per-pixel solve (:mod:`bubblefit.inverse._map_pixels`).

A physical-model photo (Airy film, internal bounces) of a known thickness map is rendered
in the shipped courtyard map, with noise and 8-bit sRGB quantisation; the per-pixel
costs with the rays traced once must equal those of whole renders, the diagonal
Jacobian must match central differences of the costs, and the map fit (coarse levels on
candidates, the finest by per-pixel Gauss-Newton) must recover the map.
"""

from __future__ import annotations

import numpy as np
import pytest

from test_fit import _env, _quantise

# 64 px: the map's pyramid then has two levels (disc radius 27 px over the coarsest
# level's 12), so the finest level is solved per pixel
N = 64
DISC = (N / 2, N / 2, 0.42 * N)


def _opts(**kw):
    from bubblefit.inverse.fit import FitOptions
    from bubblefit.inverse import starts

    # 48 uniform spectral samples resolve films up to ~1500 nm (Nyquist)
    return FitOptions(**dict(dict(disc=DISC, parameters=starts(roughness=0.04),
                                  effects=(("spectral", {"method": "uniform", "samples": 48}),)), **kw))


def _background(rng):
    from scipy import ndimage as ndi

    return ndi.gaussian_filter(rng.uniform(0.15, 0.6, (N, N, 3)), (2.5, 2.5, 0))


def _render(env, bg, bubble, model):
    from bubblefit.model.scene import Scene, render_scene

    scene = Scene.from_dict({"camera": {"width": N, "height": N, "disc": list(DISC)}, "bubble": bubble,
                             "lighting": {"envmap": "unused.exr"}, "effects": {"model": model}}, base_dir=".")
    return render_scene(scene, bg, env=env)


@pytest.fixture(scope="module")
def env(small_courtyard):
    return _env(small_courtyard)


def _truth(tmp_path_factory):
    from bubblefit.io.images import write_image
    from bubblefit.model.thickness import drainage_profile

    ii, jj = np.mgrid[0:N, 0:N] + 0.5
    y = -(ii - DISC[1]) / DISC[2]
    x = (jj - DISC[0]) / DISC[2]
    true = np.asarray(drainage_profile(y, 300.0, 900.0, 1.0)) + 30.0 * np.exp(-((x + 0.2) ** 2 + y**2) / 0.1)
    path = tmp_path_factory.mktemp("pixmap") / "truth.exr"
    write_image(path, np.repeat(true[..., None], 3, axis=2), bit_depth=32)
    return true, path


@pytest.fixture(scope="module")
def photo(env, tmp_path_factory):
    rng = np.random.default_rng(11)
    true, path = _truth(tmp_path_factory)
    bg = 0.5 * _background(rng)
    img = _quantise(_render(env, bg, {"roughness": 0.05, "thickness": {"profile": "map", "path": str(path)}},
                            model="physical"), rng)
    return img, _quantise(bg, rng), true


@pytest.fixture(scope="module")
def level(env, photo):
    from bubblefit.inverse import setup

    img, bg, true = photo
    opts = _opts(thickness="map", model="physical")
    st = setup(img, env, opts, bg, None, None, None)
    lev = st.level(2, opts, st.map_cfg)
    vals = dict(st.vals, top_nm=300.0, bottom_nm=900.0, exponent=1.0, roughness=0.05)
    return st, lev, vals


def test_traced_costs_equal_whole_renders(env, level):
    """One trace plus the film's optics per candidate gives the whole render's chi^2 (float32 rounding)."""
    from bubblefit.inverse import RenderCosts, TracedCosts, profile_map

    st, lev, vals = level
    sel = lev.mask.reshape(-1)
    prof = profile_map(lev, (300.0, 900.0, 1.0)).reshape(-1)[sel]
    d = prof[None] + np.array([-60.0, -20.0, 0.0, 35.0])[:, None]
    whole = RenderCosts(lev, st.table, vals, env)(d)
    traced = TracedCosts(lev, st.table, vals, env)(d)
    # float32 renders of ~1e3 chi^2 units: agree to 1e-3 relative
    np.testing.assert_allclose(traced, whole, rtol=1e-3, atol=1e-2)


def test_diagonal_jacobian_matches_differences(env, level):
    """d chi^2_p / d d_p = 2 r_p . j_p, against central differences of 0.25 nm (the Airy
    film's colours vary over ~100 nm: the difference's error is ~1e-5 relative)."""
    from bubblefit.inverse import RenderCosts, TracedCosts, profile_map

    st, lev, vals = level
    sel = lev.mask.reshape(-1)
    d = profile_map(lev, (300.0, 900.0, 1.0)).reshape(-1)[sel] + 10.0
    costs = TracedCosts(lev, st.table, vals, env)
    r, j = costs.slopes(d)
    h = 0.25
    # one batch of four candidates, as in the test above: its compiled program is reused
    at_d, plus, minus, _ = costs(np.stack([d, d + h, d - h, d]))
    np.testing.assert_allclose(np.sum(r * r, axis=1), at_d, rtol=1e-3, atol=1e-2)
    fd = (plus - minus) / (2 * h)
    an = 2.0 * np.sum(r * j, axis=1)
    big = np.abs(an) > 0.05 * np.max(np.abs(an))
    # float32 costs of ~1e2 differenced over 0.5 nm: a few percent of the largest slope
    assert np.median(np.abs(fd - an)[big] / np.abs(an[big])) < 0.03
    # a further call reads the rays its first call traced: a fresh trace's values, to the
    # same program's rounding
    r2, j2 = costs.slopes(d + 7.0)
    r3, j3 = TracedCosts(lev, st.table, vals, env).slopes(d + 7.0)
    np.testing.assert_allclose(r2, r3, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(j2, j3, rtol=1e-6, atol=1e-6)
    assert not np.allclose(r2, r)  # the thickness changed the residuals


def test_costs_at_a_few_pixels_equal_the_levels(env, level):
    """The costs of a few of a level's pixels, their rays traced on their own
    (:meth:`TracedCosts.at`, AT_CHUNK at a time: 70 pixels take two calls), equal the whole
    level's at those pixels: a pixel's rays do not depend on the others' (the same
    programs' float32 rounding on other chunk lengths)."""
    from bubblefit.inverse import TracedCosts, profile_map
    from bubblefit.inverse._map_pixels import AT_CHUNK

    st, lev, vals = level
    sel = lev.mask.reshape(-1)
    d = profile_map(lev, (300.0, 900.0, 1.0)).reshape(-1)[sel]
    cand = d[None] + np.array([-60.0, -20.0, 0.0, 35.0])[:, None]  # the batch of the tests above
    costs = TracedCosts(lev, st.table, vals, env)
    cols = np.sort(np.random.default_rng(3).choice(d.size, AT_CHUNK + 6, replace=False))
    np.testing.assert_allclose(costs.at(cand[:, cols], cols), costs(cand)[:, cols], rtol=1e-5, atol=1e-4)


def test_kept_rays_read_at_another_exposure_and_profile(env, level):
    """A level traced before at the same values but the exposure and the drainage profile
    reads the kept rays (no second trace), and its slopes and costs equal those of a fresh
    trace at its own values: the rays and the light they read depend on neither, so both
    run the same program on the same numbers (float32 rounding of ~1e-6 at most)."""
    import bubblefit.inverse._map_pixels as MP
    from bubblefit.inverse import TracedCosts, profile_map

    st, lev, vals = level
    sel = lev.mask.reshape(-1)
    d = profile_map(lev, (300.0, 900.0, 1.0)).reshape(-1)[sel] + 10.0
    first = TracedCosts(lev, st.table, vals, env)
    r0, _ = first.slopes(d)
    other = dict(vals, exposure=0.8 * float(vals["exposure"]), top_nm=280.0, bottom_nm=950.0)
    kept = TracedCosts(lev, st.table, other, env)
    r_kept, j_kept = kept.slopes(d)
    c_kept = kept(d[None])
    assert kept._traced is first._traced
    MP._TRACES.clear()
    fresh = TracedCosts(lev, st.table, other, env)
    r, j = fresh.slopes(d)
    assert fresh._traced is not first._traced
    np.testing.assert_allclose(r_kept, r, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(j_kept, j, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(c_kept, fresh(d[None]), rtol=1e-6, atol=1e-5)
    assert not np.allclose(r, r0, rtol=1e-3)  # the exposure and the profile moved the residuals


def test_mask_that_lost_pixels_reads_the_kept_rays(env, level):
    """A level whose mask lost a few pixels since its rays were traced (a frame's clipped
    pixels) reads the kept rays at its pixels' entries, the others weighted 0, and its
    costs, slopes and shadings equal a fresh trace of its own mask (a pixel's rays do not
    depend on the others'; the same program on the same numbers, float32 rounding of ~1e-6
    at most). A mask with a pixel the kept rays lack is traced on its own."""
    from dataclasses import replace

    import bubblefit.inverse._map_pixels as MP
    from bubblefit.inverse import TracedCosts, profile_map

    st, lev, vals = level
    MP._TRACES.clear()
    first = TracedCosts(lev, st.table, vals, env)
    first.slopes(np.zeros(first.n))  # traced and kept
    flat = np.flatnonzero(lev.mask.reshape(-1))
    lost = lev.mask.copy().reshape(-1)
    lost[flat[[0, 57, 58, flat.size - 1]]] = False  # the first, two neighbours and the last
    lev_lost = replace(lev, mask=lost.reshape(lev.mask.shape))
    covered = TracedCosts(lev_lost, st.table, vals, env)
    assert covered._traced is first._traced and covered.shape == first.shape and covered.n == first.n - 4
    d = profile_map(lev_lost, (300.0, 900.0, 1.0)).reshape(-1)[lost] + 10.0
    r, j = covered.slopes(d)
    c = covered(np.stack([d, d + 20.0]))
    img, col = covered._shaded(d, covered.p.exposure, covered.p.profile)
    MP._TRACES.clear()
    fresh = TracedCosts(lev_lost, st.table, vals, env)
    r1, j1 = fresh.slopes(d)
    assert fresh._traced is not first._traced and np.array_equal(fresh.slot, np.arange(fresh.n))
    np.testing.assert_allclose(r, r1, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(j, j1, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(c, fresh(np.stack([d, d + 20.0])), rtol=1e-6, atol=1e-5)
    img1, col1 = fresh._shaded(d, fresh.p.exposure, fresh.p.profile)
    np.testing.assert_allclose(img, img1, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(col, col1, rtol=1e-6, atol=1e-7)
    grown = lost.copy()
    grown[np.flatnonzero(~lev.mask.reshape(-1))[0]] = True  # a pixel the first mask did not trace
    assert TracedCosts(replace(lev, mask=grown.reshape(lev.mask.shape)), st.table, vals, env)._traced is None
    MP._TRACES.clear()


def test_held_frame_reads_the_rays_its_solve_traced(env, level):
    """A frame that holds the global parameters renders with the disc refinement its solve's
    map traced its rays at, carried through the record (JSON) bit for bit, so its levels
    read those rays; the refined disc the solve reported (rounded to 0.001 px) moves the
    refinement by up to 5e-4 px and would trace every ray again. Another disc found holds
    nothing."""
    import json
    from types import SimpleNamespace

    import bubblefit.inverse._map_pixels as MP
    from bubblefit.inverse import TracedCosts, disc_start, refined_disc
    from bubblefit.inverse._carried import carried_record, held_disc
    from bubblefit.inverse._parameters import DISC_PARAMETERS

    st, lev, vals = level
    moves = dict(zip(DISC_PARAMETERS, np.float32([0.0123457, -0.0071234, 0.0032109])))
    solved = dict(vals, **moves)  # a solve's values, float32 as its solver leaves them
    MP._TRACES.clear()
    first = TracedCosts(lev, st.table, solved, env)
    first.slopes(np.zeros(first.n))  # the solve's map traced its rays
    stderr = {"cx": 0.01, "cy": 0.01, "r": 0.01}
    record = json.loads(json.dumps(carried_record(stderr, {}, {}, SimpleNamespace(chi2_floor=1.0), 10, DISC, solved)))
    held = held_disc(DISC, record)
    assert held == {n: float(v) for n, v in moves.items()}
    assert TracedCosts(lev, st.table, dict(vals, **held), env)._traced is first._traced
    reported, _ = refined_disc(DISC, {n: float(v) for n, v in moves.items()}, {})
    start = disc_start(DISC, reported)  # the warm start's disc, from the reported one
    assert start != held
    assert TracedCosts(lev, st.table, dict(vals, **start), env)._traced is None  # not the rays traced
    assert held_disc((DISC[0] + 0.01, DISC[1], DISC[2]), record) == {}
    assert held_disc(DISC, carried_record(None, {}, {}, SimpleNamespace(chi2_floor=1.0), 10, DISC, solved)) == {}
    MP._TRACES.clear()


def test_window_polynomials_equal_the_slopes(env, level):
    """Each pixel's colour as a polynomial over its window of +-24 nm (WINDOW_NODES
    Chebyshev nodes, :class:`WindowPolynomials`) gives the residuals and the diagonal
    Jacobian of the forward-mode pass at any thicknesses of the window: the fringes of a
    300-900 nm film (at least 136 nm of thickness each at 380 nm) are interpolated to
    ~1e-5 of their amplitude (WINDOW_NODES' comment), under 3e-3 of a pixel's noise here
    (the residuals are weighted by it; 3e-4 measured, where float32's rounding of residuals
    up to ~70 is ~1e-5); and at another exposure (read from the exposure column, the
    colours being affine in it) those of a level traced there."""
    from bubblefit.inverse import TracedCosts, profile_map
    from bubblefit.inverse._map_pixels import window

    st, lev, vals = level
    sel = lev.mask.reshape(-1)
    centre = profile_map(lev, (300.0, 900.0, 1.0)).reshape(-1)[sel] + 10.0
    lo, hi = window(centre, 24.0)
    costs = TracedCosts(lev, st.table, vals, env)
    poly = costs.window_polynomials(lo, hi)
    d = lo + np.random.default_rng(5).uniform(0.0, 1.0, centre.size) * (hi - lo)
    r, j = costs.slopes(d)
    r_p, j_p = poly.slopes(d)
    np.testing.assert_allclose(r_p, r, atol=3e-3)
    # the derivative's error is the interpolant's times at most the degree squared over
    # the window's half width (Markov's inequality, 36 / 24 per nm); 2e-4 measured
    np.testing.assert_allclose(j_p, j, atol=3e-3)
    assert np.max(np.abs(j)) > 1.0  # the colours do move over the window
    other = dict(vals, exposure=0.8 * float(vals["exposure"]))
    r2, j2 = TracedCosts(lev, st.table, other, env).slopes(d)
    r2_p, j2_p = poly.at(0.8 * float(vals["exposure"])).slopes(d)
    np.testing.assert_allclose(r2_p, r2, atol=3e-3)
    np.testing.assert_allclose(j2_p, j2, atol=3e-3)
    assert not np.allclose(r2, r, atol=1e-1)  # the exposure moved the residuals


class _UphillSlopes:
    """Per-pixel residuals ``r_p = d_p - 500`` (nm) with the sign of their slope reversed, so
    that every Gauss-Newton step goes uphill and is rejected: the number of passes counted."""

    def __init__(self):
        self.calls = 0

    def slopes(self, d):
        self.calls += 1
        r = np.repeat((np.asarray(d, np.float64) - 500.0)[:, None], 3, axis=1)
        return r, -np.ones_like(r)


def test_refine_stops_where_the_next_trial_would_repeat_a_rejected_one():
    """A rejected step at small damping (1e-3 of the curvature) is repeated by a fourfold
    damping to within 3e-3 of itself: below REFINE_TOL_NM for steps under ~70 nm, so the
    solve stops after one trial instead of spending REFINE_STEPS passes on the same step,
    and keeps its start."""
    from bubblefit.inverse._map_pixels import REFINE_STEPS, refine
    from bubblefit.inverse._maps import _neighbours

    mask = np.ones((4, 4), bool)
    nb = _neighbours(mask)[0]
    centre = np.full(16, 510.0)  # 10 nm from the minimum: the uphill step is ~10 nm
    costs = _UphillSlopes()
    d, err, chi = refine(costs, centre, nb, 8.0, 24.0)
    assert costs.calls == 2 < REFINE_STEPS + 1
    np.testing.assert_array_equal(d, centre)
    np.testing.assert_allclose(chi, 3 * 10.0**2)


class _CurvedSlopes:
    """Per-pixel residuals ``(x, x^2 / 20 - 2, 0)``, ``x = d_p - t_p`` (nm): chi^2 =
    ``x^2 + (x^2 / 20 - 2)^2`` has its minimum at ``x = 0`` with curvature 1.6, where
    Gauss-Newton's ``2 J^T J`` is 2, so Gauss-Newton alone contracts the error by only
    ``1 - 1.6 / 2 = 0.2`` a step."""

    def __init__(self, t):
        self.t, self.calls = t, 0

    def slopes(self, d):
        self.calls += 1
        x = np.asarray(d, np.float64) - self.t
        return np.stack([x, x * x / 20.0 - 2.0, 0.0 * x], 1), np.stack([np.ones_like(x), x / 10.0, 0.0 * x], 1)


def test_refine_takes_each_pixels_secant_curvature():
    """Started 8 nm off, the per-pixel solve stops (its quantile step under REFINE_TOL_NM)
    with every pixel within 0.01 nm of its minimum: with Gauss-Newton's curvature alone the
    error left after a last step of up to 0.2 nm is 0.2 / (1 - 0.2) of it, up to 0.05 nm;
    the secant of each pixel's gradient converges superlinearly. No pass is spent on a
    rejected step (one pass per accepted step and one at the start)."""
    from bubblefit.inverse._map_pixels import REFINE_STEPS, refine
    from bubblefit.inverse._maps import _neighbours

    nb = _neighbours(np.ones((6, 6), bool))[0]
    t = 500.0 + np.random.default_rng(1).uniform(-3.0, 3.0, 36)
    costs = _CurvedSlopes(t)
    d, err, chi = refine(costs, t + 8.0, nb, 1e3, 24.0)  # a smoothness scale far above the steps
    assert np.abs(d - t).max() < 0.01
    assert costs.calls <= REFINE_STEPS


class _WellCosts:
    """Per-pixel data chi^2 ``3 ((d - t_p) / 4)^2`` (one minimum per pixel, at ``t_p``),
    with :meth:`~bubblefit.inverse._map_pixels.TracedCosts.at`'s call for a few pixels;
    the pixels each call scores are kept."""

    def __init__(self, t):
        self.t, self.scored = t, []

    def __call__(self, d):
        self.scored.append(np.arange(d.shape[1]))
        return 3.0 * ((d - self.t) / 4.0) ** 2

    def at(self, d, cols):
        self.scored.append(cols)
        return 3.0 * ((d - self.t[cols]) / 4.0) ** 2


def test_narrow_coarse_level_chooses_as_the_full_grid():
    """The coarse level scored first within +-24 nm of the prior (a held frame's
    ``narrow``): where each pixel's energy has one minimum, the map, its standard errors and
    costs equal the full grid's exactly (the same candidates and costs), a feature 50 nm
    off the prior has its pixels (and those ICM drew to the window's edge) scored over the
    whole grid, and the rest only within the window."""
    from bubblefit.inverse._maps import _level_map

    h = w = 12
    mask = np.ones((h, w), bool)
    ii, jj = np.mgrid[0:h, 0:w]
    t = 500.0 + 0.8 * (ii - jj) + np.where((ii - 4) ** 2 + (jj - 6) ** 2 <= 4, 50.0, 0.0)
    t = t.reshape(-1)
    prior = np.full(t.size, 500.0)
    lev = type("L", (), {"mask": mask})
    full = _level_map(lev, _WellCosts(t), prior, 8.0, 4.0, 80.0, prior=prior, prior_nm=150.0)
    costs = _WellCosts(t)
    narrow = _level_map(lev, costs, prior, 8.0, 4.0, 80.0, prior=prior, prior_nm=150.0, first=24.0)
    for a, b in zip(narrow, full):
        np.testing.assert_array_equal(a, b)
    whole = np.concatenate(costs.scored[1:])
    feature = np.flatnonzero(t > 530.0)
    assert np.isin(feature, whole).all()  # every feature pixel scored over the whole grid
    assert whole.size < 0.5 * t.size  # the rest within the window only
    assert np.all(full[0][feature] - prior[feature] > 24.0)  # the feature's map lies beyond the window


def test_map_levels_chunked_evenly():
    """A map level's pixel list (:class:`TracedCosts`' chunks): the fewest chunks of at most
    CHUNK pixels, each the bucket of its share (at most a quarter over it, or 64), so a level
    of 1030 pixels renders 3 x 384 instead of 3 x 512; the list holds the mask's pixels in
    order, the padding repeating the last with weight 0; and one (steps, size) serves every
    count within a chunk count and a bucket (at most four sizes per chunk count)."""
    from bubblefit.inverse import Level, fitted_pixels
    from bubblefit.inverse._map_pixels import CHUNK
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.model.effects import Effects
    from bubblefit.model.render import RenderConfig

    h = w = 80
    cfg = RenderConfig(effects=Effects(model="paper"), camera=OrthographicCamera(w, h, w / 2, h / 2, 30.0))
    shapes = {}
    for n in (1, 63, 64, 65, 511, 512, 513, 1030, 1200, 2974, 4152, 4160, 6399):
        mask = np.zeros(h * w, bool)
        mask[np.random.default_rng(n).choice(h * w, n, replace=False)] = True
        mask = mask.reshape(h, w)
        one = np.ones((h, w, 3), np.float32)
        lev = Level(1, cfg, one, one * mask[..., None], None, mask, mask, np.ones((h, w)), np.zeros((h, w)))
        px = fitted_pixels(lev, CHUNK, layout="even")
        steps, size = px.rows.shape
        share = -(-n // steps)
        assert size <= CHUNK and steps == -(-n // CHUNK)  # the fewest chunks of at most CHUNK
        assert share <= size <= max(1.25 * share, 64)
        rows, cols = np.asarray(px.rows).reshape(-1), np.asarray(px.cols).reshape(-1)
        np.testing.assert_array_equal(rows[:n] * w + cols[:n], np.flatnonzero(mask))
        wt = np.asarray(px.w).reshape(-1, 3)
        assert np.all(wt[:n] == 1.0) and np.all(wt[n:] == 0.0)
        shapes.setdefault(steps, set()).add(size)
    assert shapes[3] == {384, 448}  # 1030 and 1200: shares 344 and 400, buckets of 64 up to 512
    assert all(len(v) <= 4 for v in shapes.values())


def test_final_render_of_a_map_on_an_unpadded_level(env):
    """A map's final render on a level whose size is not a padded size (37 x 45, padded to
    48 x 48) reads each pixel's own thickness: the bubble's pixels alone and the whole
    padded render both equal the level's own render (float32 rounding of ~1e-6)."""
    from dataclasses import replace

    import jax.numpy as jnp

    from bubblefit.inverse import Level, render_bubble, render_level
    from bubblefit.lighting.filtering import FilterConfig
    from bubblefit.model.effects import Effects
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.model.render import Params, RenderConfig, render
    from bubblefit.optics.spectral import spectral_basis

    rng = np.random.default_rng(5)
    fx = Effects(model="paper", interference="airy", filtering=FilterConfig("mipmap", nodes=2),
                 spectral=spectral_basis("uniform", 16), thickness="map", background="photo")
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(45, 37, 20.3, 17.9, 15.2))
    bg = rng.uniform(0.1, 0.5, (37, 45, 3)).astype(np.float32)
    lev = Level(1, cfg, np.zeros((37, 45, 3), np.float32), np.ones((37, 45, 3), np.float32), bg,
                np.ones((37, 45), bool), np.ones((37, 45), bool), np.ones((37, 45)), np.zeros((37, 45)))
    tmap = rng.uniform(400.0, 700.0, (37, 45)).astype(np.float32)  # every pixel its own colour
    p = replace(Params.make(roughness=0.05), thickness=jnp.asarray(tmap))
    want = np.asarray(render(p, cfg, env, jnp.asarray(bg)))
    for draw in (render_level, render_bubble):
        np.testing.assert_allclose(np.asarray(draw(p, lev, env)), want, atol=2e-5)


@pytest.mark.slow
def test_physical_map_recovered(env, photo):
    """The default map fit of a physical photo, its finest level by per-pixel Gauss-Newton:
    the validation set's targets over the inner disc (0.8 r, as validate.py scores maps:
    median <= 15 nm, >= 90 % within 15 nm) and a standard error at every fitted pixel."""
    from bubblefit.inverse import COARSE_RADIUS
    from bubblefit.inverse.fit import fit_photo

    assert DISC[2] >= 2 * COARSE_RADIUS  # a pyramid of two levels at least: the per-pixel solve runs
    img, bg, true = photo
    res = fit_photo(img, env, options=_opts(thickness="map", model="physical"), background=bg)
    used = np.isfinite(res.thickness_stderr_map)
    assert used.sum() > 0.5 * np.pi * DISC[2] ** 2
    ii, jj = np.mgrid[0:N, 0:N] + 0.5
    inner = (jj - DISC[0]) ** 2 + (ii - DISC[1]) ** 2 <= (0.8 * DISC[2]) ** 2
    err = np.abs(res.thickness_map - true)[used & inner]
    assert np.median(err) <= 15.0
    assert np.mean(err <= 15.0) >= 0.9
    assert np.all(res.thickness_stderr_map[used] > 0)


def test_map_programs_through_the_store(env, level, tmp_path, monkeypatch):
    """The map's programs through the executable store (a command's process loads them
    instead of tracing the film's optics again): compiled and saved by a first
    :class:`TracedCosts`, read back from the files by a second, with the plain programs'
    values (one program, compiled afresh: float32 rounding at most)."""
    from bubblefit.io import executables
    from bubblefit.io.jaxcache import private_folder
    from bubblefit.inverse import TracedCosts, profile_map
    from bubblefit.inverse import _map_pixels

    st, lev, vals = level
    sel = lev.mask.reshape(-1)
    d = profile_map(lev, (300.0, 900.0, 1.0)).reshape(-1)[sel] + 10.0
    cand = np.stack([d, d + 20.0])
    plain = TracedCosts(lev, st.table, vals, env)
    want_c, (want_r, want_j) = plain(cand), plain.slopes(d)
    folder = tmp_path / "cache" / "executables"
    assert private_folder(folder) is None
    monkeypatch.setattr(executables, "ENABLED", True)
    monkeypatch.setattr(executables, "_folder", lambda: folder)
    loads, load = [], executables._load
    monkeypatch.setattr(executables, "_load", lambda path, args: (loads.append(path.name), load(path, args))[1])
    for run in ("saved", "loaded"):
        _map_pixels._stored_programs.cache_clear()  # a new process's programs and no kept rays
        _map_pixels._TRACES.clear()
        costs = TracedCosts(lev, st.table, vals, env)
        got_c, (got_r, got_j) = costs(cand), costs.slopes(d)
        np.testing.assert_allclose(got_c, want_c, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(got_r, want_r, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(got_j, want_j, rtol=1e-5, atol=1e-5)
        assert len(list(folder.glob("*.bin"))) == 3, run  # the costs, the trace and the slopes
    assert len(loads) == 3, loads  # the second read all three from their files
    _map_pixels._stored_programs.cache_clear()
    _map_pixels._TRACES.clear()


def test_traced_pixels_equal_the_render_and_its_exposure_column(env, level):
    """The map's pixels from its traced rays, at another exposure and drainage profile than
    traced (neither changes the rays), equal the whole render's at the fitted pixels, and
    their exposure derivative the render's exact column (the render is affine in the
    exposure: eq. 11's reflected terms scale with it, the transmitted background photo does
    not), float32 rounding apart; and the render that takes them as known and renders only
    the rest of the bubble equals the whole render everywhere."""
    from bubblefit.inverse import TracedCosts, profile_map
    from bubblefit.inverse._programs import final_params, render_bubble

    st, lev, vals = level
    opts = _opts(thickness="map", model="physical")
    sel = lev.mask.reshape(-1)
    costs = TracedCosts(lev, st.table, vals, env)
    moved = dict(vals, exposure=1.3 * float(vals["exposure"]), top_nm=320.0, bottom_nm=880.0, exponent=1.1)
    dmap = profile_map(lev, (320.0, 880.0, 1.1)) + 12.0
    img, col = costs.pixels(dmap.reshape(-1)[sel], st.table, moved)
    render = lambda v: np.asarray(render_bubble(final_params(st.table, dict(v, map=dmap), opts), lev, env), np.float64)
    full = render(moved)
    whole = full.reshape(-1, 3)[sel]
    e = float(moved["exposure"])
    column = (whole - render(dict(moved, exposure=0.5 * e)).reshape(-1, 3)[sel]) / (0.5 * e)
    # float32 pixels of order 1 through two programs (a few ulps of their ~1e2 summed terms)
    np.testing.assert_allclose(img, whole, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(col, column, rtol=1e-3, atol=1e-4)
    assert not np.allclose(img, render(vals).reshape(-1, 3)[sel], atol=1e-3)  # the values changed the pixels
    rest = render_bubble(final_params(st.table, dict(moved, map=dmap), opts), lev, env, (np.flatnonzero(sel), img))
    np.testing.assert_allclose(np.asarray(rest, np.float64), full, rtol=1e-4, atol=1e-5)
