"""Per-pixel thickness maps, fitted after a drainage profile.

A pixel's colour depends on its own thickness only (the rear film and internal bounces
read the map at the same pixel, :func:`bubblefit.model.thickness.thickness_at`), so each
pixel is searched and refined separately, with a Gaussian prior of
``FitOptions.map_prior_nm`` around the fitted profile against the ambiguity of repeated
colours. With the ``paper`` model the search is exact and fast (eq. 11 is linear in eq.
10's factor) and the refinement is optimistix LM vmapped over pixels; other models use
renders of the profile plus offsets and a diagonal Gauss-Newton.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from . import search
from ._local import robust
from ._observation import Level
from ._parameters import ParameterTable, forward, inverse
from ..model.render import render
from ..model.thickness import drainage_profile
from ..optics import film

__all__ = ["fit_map", "profile_map"]


def profile_map(lev: Level, prof) -> np.ndarray:
    """(h, w) drainage profile ``prof = (top, bottom, exponent)`` at each pixel's film point (nm)."""
    return np.asarray(drainage_profile(jnp.asarray(lev.height), *prof), np.float64)


@functools.lru_cache(maxsize=16)
def _pixel_solver(basis, robust_scale: float, max_steps: int):
    """Vmapped optimistix LM for one thickness per pixel (paper model, eq. 11 linear in eq. 10)."""
    lam = jnp.asarray(basis.wavelengths, jnp.float32)
    wts = jnp.asarray(basis.weights, jnp.float32)
    sigma = None if getattr(basis, "sigma", None) is None else jnp.asarray(basis.sigma, jnp.float32)

    def model(d, a):
        m, c, cos_i, n, t, r_s = a  # r_s: 0 without the transmission tint
        if sigma is None:  # eq. (10)'s factor over 4 t^2: cos^2(delta/2) of eq. (8)
            factor = film.paper_interference_factor(d, lam, n, cos_i, 1.0)
        else:  # ``fourier`` lobes: the fringe averaged over each lobe
            factor = film.filtered_paper_interference_factor(d, lam, n, cos_i, 1.0, sigma)
        phi = (0.25 * factor) @ wts  # integrated over the spectrum
        refl, back = search.paper_candidates(phi, m, c, t, r_s)
        return refl + back

    def resid(u, a):
        m, c, cos_i, n, t, r_s, y, w, prior, sig = a
        d = forward("thickness_nm", u[0])
        r = robust((model(d, (m, c, cos_i, n, t, r_s)) - y) * w, robust_scale)
        return jnp.concatenate([r, ((d - prior) / sig)[None]])

    lm = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-5)

    def one(u0, a):
        sol = optx.least_squares(resid, lm, u0, a, max_steps=max_steps, throw=False)
        r = resid(sol.value, a)
        j = jax.jacfwd(resid)(sol.value, a)[:, 0]
        dd = jax.grad(lambda u: forward("thickness_nm", u))(sol.value[0])
        return sol.value[0], sol.result == optx.RESULTS.successful, r, j, dd

    return jax.jit(jax.vmap(one))


def _fit_map_paper(lev: Level, table: ParameterTable, vals: dict, pr, y, w, sig, opts, env):
    """The paper model's exact per-pixel search and vmapped LM: ``(d, err, all_ok)`` over the mask."""
    fx = lev.cfg.effects
    sel = lev.mask.reshape(-1)
    grid = search.thickness_grid(*opts.thickness_range, opts.search_step_nm)
    m, c = search.unlit_terms(lev, table, vals, env)
    n = float(vals["n_film"])
    cos_i = lev.cos.reshape(-1)[sel]
    xfac = 2 * n * np.asarray(film.cos_transmitted(cos_i, n), np.float64)
    t = float(vals["t"])
    p = table.render_params({k: jnp.asarray(v, jnp.float32) for k, v in dict(vals, thickness_nm=0.0).items()
                             if k != "map"}, "constant")
    r_s = float(p.r_s) if fx.tint and fx.transmission else 0.0
    phi_tab = jnp.asarray(search.phi_table(fx.spectral, 2 * n * float(grid.max())))
    best_d = np.empty(len(pr))
    chunk = 2048
    for s in range(0, len(pr), chunk):
        e = slice(s, s + chunk)
        refl, back = search.paper_pixel_candidates(grid, xfac[e], m[e], c[e], t, r_s, phi_tab)
        pri = jnp.asarray(((grid[:, None] - pr[e][None, :]) / sig) ** 2, jnp.float32)
        best, _, _ = search.score_pixels(refl, back, jnp.asarray(y[e]), jnp.asarray(w[e] ** 2), pri,
                                         per_pixel_gain=False)
        best_d[e] = grid[np.asarray(best)]
    solve = _pixel_solver(fx.spectral, float(opts.robust_scale), 40)
    u0 = np.asarray([[inverse("thickness_nm", d)] for d in best_d], np.float32)
    ones = np.ones(len(pr), np.float32)
    args = (jnp.asarray(m, jnp.float32), jnp.asarray(c, jnp.float32), jnp.asarray(cos_i, jnp.float32),
            jnp.asarray(n * ones), jnp.asarray(t * ones), jnp.asarray(r_s * ones), jnp.asarray(y), jnp.asarray(w),
            jnp.asarray(pr, jnp.float32), jnp.asarray(sig * ones))
    u, ok, r, j, dd = solve(jnp.asarray(u0), args)
    d = np.asarray(forward("thickness_nm", u), np.float64)
    r, j = np.asarray(r, np.float64), np.asarray(j, np.float64)
    s2 = float(np.sum(r[:, :3] ** 2) / max(3 * len(pr) - len(pr), 1))
    var_u = s2 / np.maximum(np.sum(j[:, :3] ** 2, axis=1) + np.sum(j[:, 3:] ** 2, axis=1) / max(s2, 1e-12), 1e-30)
    err = np.abs(np.asarray(dd, np.float64)) * np.sqrt(var_u)
    return d, err, bool(np.mean(np.asarray(ok)) > 0.99)


@functools.partial(jax.jit, static_argnames=("cfg", "table"))
def _map_jvp(base, dmap, cfg, env, bg, table):
    """Render with a thickness map and the per-pixel derivative (a map's Jacobian is diagonal)."""
    def f(m):
        return render(table.render_params(dict(base, map=m), "map"), cfg, env, bg)

    return jax.jvp(f, (dmap,), (jnp.ones_like(dmap),))


def _fit_map_generic(lev: Level, table: ParameterTable, base, prior, pr, y, w, sig, opts, env):
    """Any model: search offsets around the profile by rendering, then diagonal Gauss-Newton."""
    sel = lev.mask.reshape(-1)
    cfg = replace(lev.cfg, effects=replace(lev.cfg.effects, thickness="map"))
    bg = None if lev.bg is None else jnp.asarray(lev.bg)
    b = {k: jnp.asarray(v, jnp.float32) for k, v in base.items()}
    offsets = np.arange(-2 * sig, 2 * sig + 1e-9, opts.search_step_nm)
    maps = np.maximum(prior[None] + offsets[:, None, None], 0.0).astype(np.float32)
    refl, back = search.render_candidates(b, jnp.asarray(maps), cfg, env, bg, table)
    g = len(offsets)
    refl = np.asarray(refl).reshape(g, -1, 3)[:, sel] * float(base["exposure"])
    back = np.asarray(back).reshape(g, -1, 3)[:, sel]
    pri = ((maps.reshape(g, -1)[:, sel] - pr[None]) / sig) ** 2
    best, _, _ = search.score_pixels(jnp.asarray(refl), jnp.asarray(back), jnp.asarray(y), jnp.asarray(w**2),
                                     jnp.asarray(pri, jnp.float32), per_pixel_gain=False)
    d = maps.reshape(g, -1)[:, sel][np.asarray(best), np.arange(len(pr))].astype(np.float64)
    full = prior.copy()
    lam = 1e-3
    for _ in range(8):
        full.reshape(-1)[sel] = d
        img, dimg = _map_jvp(b, jnp.asarray(full, jnp.float32), cfg, env, bg, table)
        img = np.asarray(img).reshape(-1, 3)[sel]
        jd = np.asarray(dimg).reshape(-1, 3)[sel] * w
        res = (img - y) * w
        grad = np.sum(jd * res, axis=1) + (d - pr) / sig**2
        hess = np.sum(jd * jd, axis=1) + 1 / sig**2
        step = -grad / (hess * (1 + lam))
        d = np.maximum(d + np.clip(step, -30, 30), 0.0)
    s2 = float(np.sum(res**2) / max(2 * len(pr), 1))
    err = np.sqrt(s2 / hess)
    return d, err, bool(np.all(np.abs(step) < 1.0))


def fit_map(lev: Level, table: ParameterTable, vals: dict, prof, opts, env):
    """Per-pixel thickness (h, w), its standard error (h, w), and whether all pixels converged.

    ``prof`` is the fitted drainage profile the map starts from (and its prior's centre);
    ``opts`` a ``FitOptions``.
    """
    fx = lev.cfg.effects
    prior = profile_map(lev, prof)
    sel = lev.mask.reshape(-1)
    y = lev.y.reshape(-1, 3)[sel]
    w = lev.w.reshape(-1, 3)[sel]
    pr = prior.reshape(-1)[sel]
    sig = float(opts.map_prior_nm)
    base = {k: v for k, v in vals.items() if k != "map"}
    dmap = prior.copy()
    emap = np.full(prior.shape, np.nan)
    if fx.model == "paper" and fx.interference == "two_beam":
        d, err, all_ok = _fit_map_paper(lev, table, base, pr, y, w, sig, opts, env)
    else:
        d, err, all_ok = _fit_map_generic(lev, table, base, prior, pr, y, w, sig, opts, env)
    dmap.reshape(-1)[sel] = d
    emap.reshape(-1)[sel] = err
    return dmap, emap, all_ok
