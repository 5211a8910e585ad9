"""Per-pixel thickness maps that keep the film's interference order, fitted after a
drainage profile.

A pixel's colour depends on its own thickness only (the rear film and internal bounces
read the map at the same pixel, changed by the drainage profile between the heights of
their film points, :func:`bubblefit.model.thickness.thickness_at`), but the colours
repeat every ~lambda / (2 n) of thickness, so pixel by pixel a map hops between
interference orders wherever noise or model error makes a neighbouring order fit a
little better. A soap film is smooth apart from real features, so the map is built:

1. coarse to fine on a pyramid of the photo (blocks of 2^j pixels, the coarsest with a
   disc of about :data:`COARSE_RADIUS` pixels): the drainage profile, fitted globally
   first, has settled the interference order, so the coarsest level searches a window
   of +-:data:`WINDOW_NM` (less than half an order) around it, with a Gaussian prior of
   ``MapSettings.prior_nm`` towards it; each finer level searches the same window
   around the coarser map, so no pixel can take a neighbouring order (a sequence's frame
   that holds the global parameters scores first only the finest level's window of the
   profile extrapolated from the frames before, and the rest at the pixels whose choice
   reaches its edge: :func:`fit_map`'s ``narrow``). (Scoring every
   thickness of the range on the coarsest level let a model error between renderers pick
   the next order in whole regions: on independent photos 50% of the film was off by
   one order: development cases ref_drain_lin_courtyard, ref_drain_lin_city, ref_bump_sunrise, cyc_drain_lin_sunrise in experiments/validation/split.toml.)
2. with a smoothness prior on every level: the energy of pixel ``p`` at thickness ``d``
   is its data chi^2 plus ``sum over its 4 neighbours q of ((d - d_q) / s)^2``, ``s`` =
   ``MapSettings.smoothness_nm`` times the level's block size (neighbours are that
   far apart), minimised by iterated conditional modes (Besag 1986) in a red-black order;
   Given the previous frame of a sequence's map (``start``), the pyramid is skipped: the
   map starts from it, moved by the change of the fitted drainage profile
   (:func:`warm_centre`), and only the finest level is refined around it (a start a
   caller passes in ``init``; ``fit-sequence`` builds every frame's map coarse to fine,
   since a carried start passed its order hops on, ``docs/speed.md``);
3. refined below the grid by a parabola through the energy around each pixel's minimum;
   its curvature gives the pixel's standard error (of its posterior: data, prior and
   smoothness with the neighbours held), widened by ``sqrt(max(1, chi2_nu))`` of the
   map's own residual, as for the global parameters.

With the ``paper`` model and an orthographic camera a pixel's candidates are exact and
cheap (eq. 11 is linear in eq. 10's factor, :func:`bubblefit.inverse.search.paper_candidates`;
a dispersive film's factor per wavelength, :class:`bubblefit.inverse.search.PaperPhi`: the
rear film of a pixel then lies at the front's height and has its thickness); other models,
perspective views (whose rear film lies at another height) and pixels box-filtered over
several rays trace each level's rays once and evaluate the film's optics per candidate
(:class:`bubblefit.inverse._map_pixels.TracedCosts`; :class:`RenderCosts`, a whole render
per candidate, gives the same costs), and their finest level is refined by a per-pixel
Gauss-Newton solve instead of a grid (:func:`bubblefit.inverse._map_pixels.refine`,
:data:`FINE_SOLVE`): the map's Jacobian is diagonal, and the smoothness prior's sparse
Laplacian is solved by conjugate gradients; its trials read each pixel's colour from a
polynomial in its thickness over its window
(:class:`~bubblefit.inverse._map_pixels.WindowPolynomials`).

References
----------
J. Besag, "On the statistical analysis of dirty pictures", J. R. Stat. Soc. B 48(3), 1986
(iterated conditional modes).
"""

from __future__ import annotations

import math
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage as ndi

from . import search
from ._map_pixels import TracedCosts, WindowCosts, WindowPolynomials, refine, window
from ._observation import Level
from ._options import FitOptions
from ._parameters import ParameterTable
from ._programs import padded
from ._uncertainty import sandwich_block, widened
from ..model.geometry import OrthographicCamera
from ..model.thickness import drainage_profile

__all__ = ["fit_map", "profile_map", "profile_from_map", "PROFILE_NAMES", "warm_centre", "RenderCosts", "COARSE_RADIUS", "WINDOW_NM", "WARM_COVER"]

#: Disc radius (pixels) of the pyramid's coarsest level.
COARSE_RADIUS = 12.0
#: Half-width of the search window around the coarser level's map (nm): under half the
#: ~200 nm between interference orders of green light in a film of n = 1.4.
WINDOW_NM = 80.0
#: Half-width of the finest level's window around the coarser map, in steps of the
#: coarse grid (``SolverSettings.search_step_nm``).
FINE_HALF_STEPS = 6
#: Step of the finest level's grid (nm).
FINE_STEP_NM = 2.0
#: Sweeps of iterated conditional modes per level.
ICM_SWEEPS = 12
#: How the finest level of a rendered map (not the paper model's exact candidates) is
#: refined around the coarser map: ``"newton"``, per-pixel Gauss-Newton
#: (:func:`bubblefit.inverse._map_pixels.refine`), or ``"grid"``, the candidates of
#: :data:`FINE_STEP_NM` with iterated conditional modes.
FINE_SOLVE = "newton"


def profile_map(lev: Level, prof) -> np.ndarray:
    """(h, w) drainage profile ``prof = (top, bottom, exponent)`` at each pixel's film point (nm)."""
    return np.asarray(drainage_profile(jnp.asarray(lev.height), *prof), np.float64)


class _PaperCosts:
    """Exact per-pixel data chi^2 of the ``paper`` model at any thicknesses (module docstring)."""

    def __init__(self, lev: Level, table: ParameterTable, vals: dict, env, hi_nm: float):
        fx = lev.cfg.effects
        self.m, self.c = search.unlit_terms(lev, table, vals, env)
        sel = lev.mask.reshape(-1)
        self.phi = search.PaperPhi(lev, float(vals["n_film"]), hi_nm)
        self.t = float(vals["t"])
        p = table.render_params({k: jnp.asarray(v, jnp.float32) for k, v in dict(vals, thickness_nm=0.0).items()
                                 if k != "map"}, "constant")
        self.r_s = float(p.r_s) if fx.tint and fx.transmission else 0.0
        self.y = lev.y.reshape(-1, 3)[sel]
        self.w2 = lev.w.reshape(-1, 3)[sel] ** 2

    def __call__(self, d: np.ndarray) -> np.ndarray:
        """(G, P) chi^2 of candidate thicknesses ``d`` (G, P)."""
        out = np.empty(d.shape, np.float32)
        # a dispersive film's Phi is summed over the K samples: K numbers per candidate in flight
        per = 1 if self.phi.law is None else self.phi.samples
        chunk = max(1, 2_000_000 // max(d.shape[0] * per, 1))
        for s in range(0, d.shape[1], chunk):
            e = slice(s, s + chunk)
            out[:, e] = np.asarray(_paper_cost(self.phi(d[:, e], e), jnp.asarray(self.m[e]), jnp.asarray(self.c[e]),
                                               self.t, self.r_s, jnp.asarray(self.y[e]), jnp.asarray(self.w2[e])))
        return out


@jax.jit
def _paper_cost(phi, m, c, t, r_s, y, w2):
    refl, back = search.paper_candidates(phi, m[None], c[None], t, r_s)
    return search.pixel_costs(refl, back, y, w2)


class RenderCosts:
    """Data chi^2 of any model: the whole map rendered once per row of candidates."""

    def __init__(self, lev: Level, table: ParameterTable, vals: dict, env):
        self.lev, self.table, self.env = lev, table, env
        self.pad = padded(lev)
        self.cfg = replace(self.pad.cfg, effects=replace(lev.cfg.effects, thickness="map"))
        self.base = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k != "map"}
        self.gain = float(vals["exposure"])
        self.sel = lev.mask.reshape(-1)
        self.y = lev.y.reshape(-1, 3)[self.sel]
        self.w2 = lev.w.reshape(-1, 3)[self.sel] ** 2

    def __call__(self, d: np.ndarray) -> np.ndarray:
        h, w = self.lev.mask.shape
        hb, wb = self.cfg.shape
        g = d.shape[0]
        maps = np.zeros((g, h * w), np.float32)
        maps[:, self.sel] = np.maximum(d, 0.0)
        maps = np.pad(maps.reshape(g, h, w), ((0, 0), (0, hb - h), (0, wb - w)))
        refl, back = search.render_candidates(self.base, jnp.asarray(maps), self.cfg, self.env, self.pad.bg,
                                              self.table, self.pad.base)
        refl = np.asarray(refl)[:, :h, :w].reshape(g, -1, 3)[:, self.sel] * self.gain
        back = np.asarray(back)[:, :h, :w].reshape(g, -1, 3)[:, self.sel]
        return np.asarray(search.pixel_costs(jnp.asarray(refl), jnp.asarray(back), jnp.asarray(self.y),
                                             jnp.asarray(self.w2)))


def _neighbours(mask: np.ndarray):
    """(P, 4) indices of each mask pixel's 4-neighbours among the mask pixels (-1: none)."""
    h, w = mask.shape
    idx = np.full((h, w), -1, np.int64)
    idx[mask] = np.arange(int(mask.sum()))
    pad = np.pad(idx, 1, constant_values=-1)
    ii, jj = np.nonzero(mask)
    return np.stack([pad[ii, jj + 1], pad[ii + 2, jj + 1], pad[ii + 1, jj], pad[ii + 1, jj + 2]], axis=1), ii + jj


def _icm(d: np.ndarray, cost: np.ndarray, nb: np.ndarray, parity: np.ndarray, s: float, start: np.ndarray):
    """Iterated conditional modes over candidates ``d`` (G, P) with data ``cost`` (G, P):
    the index (P,) minimising cost + sum over neighbours ((d - d_q) / s)^2, from ``start``."""
    pick = start.copy()
    cols = np.arange(d.shape[1])
    has = nb >= 0
    for _ in range(ICM_SWEEPS):
        changed = 0
        for colour in (0, 1):
            cur = d[pick, cols]
            nd = np.where(has, cur[np.where(has, nb, 0)], 0.0)
            cnt = has.sum(axis=1)
            mean = np.where(cnt > 0, nd.sum(axis=1) / np.maximum(cnt, 1), cur)
            energy = cost + cnt[None, :] * ((d - mean[None, :]) / s) ** 2
            new = np.argmin(energy, axis=0)
            upd = (parity % 2) == colour
            changed += int(np.sum(new[upd] != pick[upd]))
            pick = np.where(upd, new, pick)
        if changed == 0:
            break
    return pick


def _upsample(coarse: Level, cmap: np.ndarray, fine: Level) -> np.ndarray:
    """The coarse map (NaN off its mask, filled from the nearest mask pixel) at the fine level's pixels."""
    filled = cmap.copy()
    bad = ~np.isfinite(filled)
    if bad.any():
        _, (ii, jj) = ndi.distance_transform_edt(bad, return_indices=True)
        filled = filled[ii, jj]
    ratio = coarse.k / fine.k
    h, w = fine.mask.shape
    ii, jj = np.mgrid[0:h, 0:w]
    coords = np.stack([(ii + 0.5) / ratio - 0.5, (jj + 0.5) / ratio - 0.5])
    return ndi.map_coordinates(filled, coords, order=1, mode="nearest")


def _level_map(lev, costs_of, centre, s, step, half, prior=None, prior_nm=None, first=None):
    """One pyramid level: candidates ``centre +- half`` in ``step`` around each pixel's
    ``centre`` (P,), a Gaussian prior of width ``prior_nm`` around ``prior`` (P,) if given,
    ICM, and the sub-grid parabola.

    ``first``: score first only the candidates within ``+-first`` of the centre (``costs_of``
    then has :meth:`~bubblefit.inverse._map_pixels.TracedCosts.at`); a pixel whose start
    (its best candidate with the prior) or whose ICM choice lies next to a candidate not
    scored has all its candidates scored, and the choice is made again, until none does:
    a choice inside the window then has its neighbouring candidates and those of its start
    scored, as the full grid would (a minimum the window holds, not necessarily the
    global one of a pixel whose energy has another minimum outside it).
    Returns ``(map over the mask, stderr, data chi^2 at the optimum)``."""
    nb, parity = _neighbours(lev.mask)
    offs = np.arange(-half, half + 1e-9, step)
    d = np.maximum(centre[None, :] + offs[:, None], 0.0)
    extra = 0.0 if prior is None else ((d - prior[None, :]) / prior_nm) ** 2
    inner = np.ones(offs.size, bool) if first is None else np.abs(offs) <= first + 1e-9
    cost = np.full(d.shape, np.inf)
    cost[inner] = costs_of(d[inner])
    while True:
        energy0 = cost + extra
        # start from each pixel's best candidate with the prior, or from the coarser map (offset 0)
        start = np.argmin(energy0, axis=0) if prior is not None else np.full(d.shape[1], d.shape[0] // 2)
        pick = _icm(d, energy0, nb, parity, s, start)
        if inner.all():
            break
        # the pixels whose start or choice lies next to a candidate not scored
        unscored = np.pad(~np.isfinite(cost), ((1, 1), (0, 0)))
        cols = np.arange(d.shape[1])
        edge = np.zeros(d.shape[1], bool)
        for k in (start, pick):
            edge |= unscored[k, cols] | unscored[k + 2, cols]
        more = np.flatnonzero(edge)
        if more.size == 0:
            break
        cost[np.ix_(~inner, more)] = costs_of.at(d[~inner][:, more], more)
    # the parabola through the full energy (data + smoothness, neighbours fixed) at pick -1, 0, +1
    cols = np.arange(d.shape[1])
    cur = d[pick, cols]
    has = nb >= 0
    cnt = has.sum(axis=1)
    nd = np.where(has, cur[np.where(has, nb, 0)], 0.0)
    mean = np.where(cnt > 0, nd.sum(axis=1) / np.maximum(cnt, 1), cur)
    energy = energy0 + cnt[None, :] * ((d - mean[None, :]) / s) ** 2
    j = np.clip(pick, 1, d.shape[0] - 2)
    em, e0, ep = energy[j - 1, cols], energy[j, cols], energy[j + 1, cols]
    curv = em - 2 * e0 + ep
    shift = np.where(curv > 0, 0.5 * (em - ep) / np.where(curv > 0, curv, 1.0), 0.0)
    h_ = d[j + 1, cols] - d[j, cols]
    best = d[j, cols] + np.clip(shift, -1, 1) * h_
    # standard error from the curvature of the pixel's energy (data, prior and smoothness
    # with its neighbours held): E'' = 2 / sigma^2 of the pixel's posterior
    err = np.where(curv > 0, np.sqrt(2.0 / np.where(curv > 0, curv, 1.0)) * np.maximum(h_, 1e-9), np.nan)
    return best, err, cost[pick, cols]


def _pyramid(lev: Level) -> list[int]:
    """Block sizes of the pyramid, coarse to fine, ending at 1 (the level itself)."""
    r = float(lev.cfg.camera.disc()[2]) if hasattr(lev.cfg.camera, "disc") else min(lev.mask.shape) / 2.0
    n = max(0, int(math.floor(math.log2(max(r / COARSE_RADIUS, 1.0)))))
    return [2**j for j in range(n, -1, -1)]


#: Least share of the film's pixels a warm start's map must cover to start the next
#: frame's map (below it, the map is built coarse to fine): the share of constrained
#: pixels a sound map has (:func:`fit_map`).
WARM_COVER = 0.9


def warm_centre(lev: Level, prof, start) -> np.ndarray | None:
    """The previous frame's map moved by the change of the fitted drainage profile, (h, w) nm:
    ``map_prev + profile(prof) - profile(prof_prev)`` at each pixel's film point, the
    profile itself where the previous map has no value; None when that map covers less
    than :data:`WARM_COVER` of the film's pixels.

    ``start = (map_prev, prof_prev)`` (:func:`bubblefit.inverse._setup.map_start`). The
    profile (eq. of :func:`bubblefit.model.thickness.drainage_profile`) carries the film's
    drainage between the frames; the map's own features (the map less its profile) are
    carried from the previous frame, where a film's thickness changes by far less than the
    ~lambda / (2 n) between interference orders, so the previous map has settled each
    pixel's order."""
    tmap, prof0 = start
    now = profile_map(lev, prof)
    if tmap.shape != now.shape:
        return None
    moved = tmap + now - profile_map(lev, prof0)
    good = np.isfinite(moved)
    if not lev.mask.any() or float(np.mean(good[lev.mask])) < WARM_COVER:
        return None
    return np.where(good, moved, now)


def fit_map(lev: Level, table: ParameterTable, vals: dict, prof, opts: FitOptions, env, make_level=None,
            start=None, kept: list | None = None, narrow: bool = False, fine: WindowPolynomials | None = None):
    """Per-pixel thickness (h, w), its standard error (h, w), and whether the map is sound.

    ``lev`` is the full-resolution level, ``prof`` the fitted drainage profile the map
    starts from, ``opts`` a ``FitOptions``, ``make_level(k)`` the level ``k`` times
    coarser than ``lev`` (None: no pyramid). ``start``: a warm start's map and its
    profile (a sequence's previous frame, :func:`warm_centre`); the pyramid is then
    skipped and only the finest level is refined around it (the same window and solve
    as after a coarser level). ``kept``: a list the finest level's costs
    (:class:`~bubblefit.inverse._map_pixels.TracedCosts`, its rays traced) are appended to,
    for the caller to shade the map's pixels without tracing them again. ``narrow``: the
    profile ``prof`` is already close to the map (a sequence's frame that holds the global
    parameters, its profile extrapolated from the frames before): the coarsest level of a
    traced map scores first only the candidates within the finest level's window of it
    (:data:`FINE_HALF_STEPS` grid steps), and the rest at the pixels whose choice reaches
    the window's edge (:func:`_level_map`'s ``first``). ``fine``: the polynomials an earlier
    map of this level was refined on (its finest costs' ``polynomials``, kept by that call's
    ``kept``), at the same values but the exposure: the finest level reads them at this
    exposure (:meth:`~bubblefit.inverse._map_pixels.WindowPolynomials.at`; the colours are
    affine in it) instead of shading its window's nodes again, and its pixels stay within
    that earlier window too (the one the coarser levels set around the order they settled).
    """
    exact = search.exact_paper_search(lev.cfg) and isinstance(lev.cfg.camera, OrthographicCamera)
    hi = opts.thickness_range[1]
    base = {k: v for k, v in vals.items() if k != "map"}
    warm = None if start is None else warm_centre(lev, prof, start)
    blocks = _pyramid(lev) if make_level is not None and warm is None else [1]
    prev, prev_map = None, None
    for k in blocks:
        L = lev if k == 1 else make_level(k)
        sel = L.mask.reshape(-1)
        if sel.sum() == 0:
            continue
        costs_of = _PaperCosts(L, table, base, env, hi + WINDOW_NM) if exact else TracedCosts(L, table, base, env)
        s = float(opts.map.smoothness_nm) * k
        prior = profile_map(L, prof).reshape(-1)[sel]
        if prev is None and warm is None:
            # the drainage profile has settled the interference order: the coarsest level
            # searches within less than half an order of it, with the profile's prior
            grid = opts.solver.search_step_nm
            first = FINE_HALF_STEPS * grid if narrow and not exact else None
            # the candidates within the window first scored read from its polynomials
            scored = costs_of if first is None else WindowCosts(costs_of, *window(prior, first))
            best, err, c = _level_map(L, scored, prior, s, grid, WINDOW_NM, prior=prior,
                                      prior_nm=float(opts.map.prior_nm), first=first)
        else:
            centre = (warm if warm is not None else _upsample(prev, prev_map, L)).reshape(-1)[sel]
            # the finest level refines within a few coarse steps; the order is settled by then
            grid = opts.solver.search_step_nm
            step, half = (FINE_STEP_NM, FINE_HALF_STEPS * grid) if k == 1 else (grid, WINDOW_NM)
            if k == 1 and not exact and FINE_SOLVE == "newton":
                # each pixel's thickness moves its own pixel only: Gauss-Newton with a diagonal
                # Jacobian and the smoothness prior's sparse Laplacian, not a grid of renders
                # from the polynomials of each pixel's colour over its window (a few shadings
                # of the film's optics) rather than a forward-mode pass each trial
                lo, hi = window(centre, half)
                same = fine is not None and fine.lo.shape == lo.shape and np.array_equal(
                    fine.profile, np.asarray(costs_of.p.profile))
                if same:
                    poly = fine.at(float(costs_of.p.exposure))
                    lo, hi = np.maximum(lo, poly.lo), np.minimum(hi, poly.hi)
                else:
                    poly = costs_of.window_polynomials(lo, hi)
                costs_of.polynomials = poly
                best, err, c = refine(poly, centre, _neighbours(L.mask)[0], s, half, bounds=(lo, hi))
            else:
                best, err, c = _level_map(L, costs_of, centre, s, step, half)
        if k == 1 and kept is not None:
            kept.append(costs_of)
        m = np.full(L.mask.shape, np.nan)
        m.reshape(-1)[sel] = best
        prev, prev_map = L, m
        e_map = np.full(L.mask.shape, np.nan)
        e_map.reshape(-1)[sel] = err
        chi = c
    dmap = profile_map(lev, prof)
    sel = lev.mask.reshape(-1)
    dmap.reshape(-1)[sel] = prev_map.reshape(-1)[sel]
    chi2 = float(np.sum(chi)) / max(2 * int(sel.sum()), 1)  # 3 channels, 1 thickness per pixel
    emap = e_map * math.sqrt(max(1.0, chi2))
    emap = np.where(lev.mask, emap, np.nan)
    sound = bool(np.mean(np.isfinite(emap[lev.mask])) > 0.9) if lev.mask.any() else False
    return dmap, emap, sound


#: The drainage profile's parameters, in the order of :func:`profile_map`'s ``prof``.
PROFILE_NAMES = ("top_nm", "bottom_nm", "exponent")


def profile_from_map(lev: Level, dmap: np.ndarray, emap: np.ndarray, prof, free=PROFILE_NAMES):
    """The drainage profile that fits a thickness map best, and its standard errors:
    ``((top, bottom, exponent), {name: stderr})``.

    The profile ``d(y) = top + (bottom - top) x^e``, ``x = (1 - y) / 2``
    (:func:`bubblefit.model.thickness.drainage_profile`) is linear in ``top`` and ``bottom``
    for a fixed exponent, so it is fitted by variable projection (G. H. Golub and V.
    Pereyra, "The differentiation of pseudo-inverses and nonlinear least squares problems
    whose variables separate", SIAM J. Numer. Anal. 10(2), 1973): the two linear values by
    weighted least squares for each exponent, the exponent by a bounded 1-D search of the
    projected residual, weights ``1 / emap^2`` over the pixels the map constrains. The
    standard errors are the delta method's from the full Jacobian at the optimum, each
    variance the larger of the Birge ratio's and the cluster sandwich's over blocks of
    pixels, as the global parameters' are (:func:`~._uncertainty.widened`: a map's
    neighbouring pixels share their errors). Names not in
    ``free`` are held at ``prof`` (no standard error)."""
    from scipy.optimize import minimize_scalar

    top0, bottom0, e0 = (float(v) for v in prof)
    ok = lev.mask & np.isfinite(dmap) & np.isfinite(emap) & (emap > 0)
    x = np.clip((1.0 - np.asarray(lev.height, np.float64)[ok]) * 0.5, 0.0, 1.0)
    d, w = np.asarray(dmap, np.float64)[ok], 1.0 / np.asarray(emap, np.float64)[ok]
    lin = [n for n in PROFILE_NAMES[:2] if n in free]
    if x.size <= len(lin) + 1 or not lin:
        return (top0, bottom0, e0), {}

    def linear(e):
        xe = np.where(x > 0, x ** e, 0.0)
        cols = {"top_nm": 1.0 - xe, "bottom_nm": xe}
        held = d - sum(v * cols[n] for n, v in zip(PROFILE_NAMES[:2], (top0, bottom0)) if n not in lin)
        a = np.stack([cols[n] for n in lin], axis=1) * w[:, None]
        coef, *_ = np.linalg.lstsq(a, held * w, rcond=None)
        vals = dict(zip(PROFILE_NAMES[:2], (top0, bottom0)), **dict(zip(lin, coef)))
        r = (held - (a / w[:, None]) @ coef) * w
        return vals, float(r @ r)

    e = e0
    if "exponent" in free:
        e = float(minimize_scalar(lambda s: linear(s)[1], bounds=(0.1 * e0, 10.0 * e0), method="bounded",
                                  options={"xatol": 1e-4}).x)
    vals, cost = linear(e)
    top, bottom = vals["top_nm"], vals["bottom_nm"]
    xe = np.where(x > 0, x ** e, 0.0)
    cols = {"top_nm": 1.0 - xe, "bottom_nm": xe,
            "exponent": (bottom - top) * np.where(x > 0, xe * np.log(np.where(x > 0, x, 1.0)), 0.0)}
    names = [n for n in PROFILE_NAMES if n in free]
    jac = np.stack([cols[n] for n in names], axis=1) * w[:, None]
    resid = (d - (top + (bottom - top) * xe)) * w
    chi2_nu = cost / max(x.size - len(names), 1)
    try:
        a_inv = np.linalg.inv(jac.T @ jac)
        # neighbouring pixels of a map share their errors (the smoothness prior, the model
        # error): each variance is the larger of the Birge ratio's and the cluster sandwich's
        full_jac, full_r = np.zeros((ok.size, len(names))), np.zeros(ok.size)
        full_jac[ok.reshape(-1)], full_r[ok.reshape(-1)] = jac, resid
        cov, _ = widened(a_inv * max(1.0, chi2_nu), a_inv, full_jac, full_r, ok.shape + (1,), sandwich_block(lev))
        err = {n: float(math.sqrt(cov[k, k])) if cov[k, k] >= 0 else float("nan") for k, n in enumerate(names)}
    except np.linalg.LinAlgError:
        err = {n: float("nan") for n in names}
    return (top, bottom, e), err
