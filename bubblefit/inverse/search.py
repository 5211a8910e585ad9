"""Global thickness search for the fit: dense grids of film thickness, vectorised.

The thickness objective has a local minimum every ~lambda / (4 n) of thickness (the
interference colours repeat), so :mod:`bubblefit.inverse.fit` first scores a dense grid of
thicknesses here and only refines the best candidates with a local solver.

Two evaluators:

``paper`` model (fast, exact for a constant film)
    Eq. (11) is linear in the interference factor of eq. (10), ``F = 4 t^2 Phi(x)`` with
    ``Phi(x) = integral of cos^2(pi x / lambda + pi / 2)`` over the spectrum and
    ``x = 2 n d cos th_t`` the optical path difference (eq. 8). Where the front and rear
    films have the same thickness (a constant film, or a per-pixel map, which the rear
    film reads at the same pixel) and, by the chord's symmetry, the same angle, a pixel is
    ``F(x) * M + C``: ``M`` the reflected radiance of both films rendered with
    interference off, ``C`` the transmitted background. ``Phi`` is tabulated once on a
    fine grid of ``x`` (:func:`phi_table`), so a candidate costs one interpolation per
    pixel and channel. The table integrates against the fit's spectral basis, so any
    illuminant, camera response and white balance is exact. A dispersive film (a Cauchy
    law, ``RenderConfig.dispersion``) has no single ``x``: each sample wavelength has its
    own ``x_k = 2 n_k d cos th_t(n_k)``, and ``Phi`` is then summed over the samples
    directly (:class:`PaperPhi`), as the renderer does. A pixel box-filtered over several
    rays (``samples_per_pixel`` > 1) mixes several optical paths, which ``F(x) M + C``
    cannot represent: such fits render their candidates (:func:`exact_paper_search`).

any model (generic)
    One render per candidate thickness (``lax.map`` over the grid), on the downsampled
    search image.

Both return per-pixel model images for every candidate through a callable, so the same
scoring code serves the constant fit (one global gain per candidate), the drainage
initialisation (a gain per pixel, i.e. hue matching) and the per-pixel map (fixed gain
and a prior).
"""

from __future__ import annotations

import functools
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

from ._censored import censored_residual
from ._parameters import ParameterTable
from ._programs import fitted_pixels, render_level
from ..model.geometry import compose_shift
from ..model.render import render_pixels_at, render_terms
from ..optics import spectral
from ..optics import film
from ..optics.dispersion import index_offset
from ..optics.film import paper_tinted_transmission

__all__ = ["phi_table", "phi_rgb", "paper_candidates", "thickness_grid", "local_minima", "score_global",
           "score_pixels", "pixel_costs", "best_profile", "PROFILE_EXPONENTS", "candidates", "search_starts",
           "unlit_terms", "paper_pixel_candidates", "render_candidates", "profile_from_pixels", "PaperPhi",
           "exact_paper_search", "grey_exposure"]

#: Step of the optical-path table, nm (the colour varies on scales of ~100 nm).
X_STEP = 0.5
#: Exponents of the drainage profile tried by the profile searches.
PROFILE_EXPONENTS = (0.5, 0.75, 1.0, 1.5, 2.0, 3.0)

# The film's functions as the search calls them on numpy arrays: one compiled program each
# (called eagerly, each of their operations compiles on its own, about 20 programs and
# 0.8 s of an empty cache's first fit).
_paper_factor = jax.jit(film.paper_interference_factor)
_filtered_paper_factor = jax.jit(film.filtered_paper_interference_factor)
_cos_transmitted = jax.jit(film.cos_transmitted)


def thickness_grid(lo: float, hi: float, step: float) -> np.ndarray:
    """Candidate thicknesses ``lo, lo + step, ..., hi`` (nm), shape (G,)."""
    n = max(2, int(np.floor((hi - lo) / step)) + 1)
    return np.linspace(lo, lo + (n - 1) * step, n)


@functools.lru_cache(maxsize=8)
def phi_table(basis: spectral.SpectralBasis, x_max: float) -> np.ndarray:
    """``Phi(x)`` of the module docstring on ``x = 0, X_STEP, ...`` up to ``x_max``: (X, 3).

    ``cos^2(delta / 2)`` with ``delta = 2 pi x / lambda + pi`` (eq. 8,
    :func:`bubblefit.optics.film.phase`) integrated against ``basis`` (CIE 1931 to linear
    sRGB, white-normalised; :func:`spectral.integrate`).
    """
    x = np.arange(0.0, x_max + 2 * X_STEP, X_STEP)[:, None]
    lam = np.asarray(basis.wavelengths, dtype=np.float64)[None, :]
    # Eq. (10)'s factor over 4 t^2 at optical path x: at normal incidence in a film of
    # index 1, x = 2 d (film.optical_path), so the film functions give it exactly.
    if getattr(basis, "sigma", None) is not None:
        # ``fourier`` bases: each sample is a Gaussian lobe in wavenumber, under which the
        # fringe's cosine is attenuated (film.fringe_attenuation, Belcour & Barla 2017).
        sig = np.asarray(basis.sigma, dtype=np.float64)[None, :]
        factor = _filtered_paper_factor(x / 2.0, lam, 1.0, 1.0, 1.0, sig)
    else:
        factor = _paper_factor(x / 2.0, lam, 1.0, 1.0, 1.0)
    c2 = np.asarray(factor, np.float64) / 4.0
    return np.asarray(c2 @ np.asarray(basis.weights, dtype=np.float64), dtype=np.float32)


@jax.jit
def phi_rgb(table: jnp.ndarray, x: jnp.ndarray) -> jnp.ndarray:
    """Linear interpolation of :func:`phi_table` at optical paths ``x`` (...,) -> (..., 3)."""
    pos = jnp.clip(x / X_STEP, 0.0, table.shape[0] - 1.001)
    i = jnp.floor(pos).astype(jnp.int32)
    f = (pos - i)[..., None]
    return table[i] * (1 - f) + table[i + 1] * f


def exact_paper_search(cfg) -> bool:
    """Whether ``cfg``'s pixels are ``F(x) M + C`` of the module docstring, so the ``paper``
    candidates (:class:`PaperPhi`) are exact: the ``paper`` model with eq. (10)'s factor
    (``two_beam``) and one ray per pixel. Otherwise candidates are rendered."""
    fx = cfg.effects
    return fx.model == "paper" and fx.interference == "two_beam" and cfg.samples_per_pixel == 1


@jax.jit
def _phi_per_wavelength(d, cos_i, lam, n, sigma, weights):
    """``Phi`` (G, P, 3) of thicknesses ``d`` (G, P) from each sample wavelength's own index:
    eq. (10)'s factor over ``4 t^2`` (eqs. 8-10 with ``n = n_k``, Snell's law per sample;
    lobe-filtered for a ``fourier`` basis, :func:`bubblefit.optics.film.fringe_attenuation`)
    integrated against the basis weights (K, 3)."""
    dd, c = d[..., None], cos_i[:, None]
    if sigma is None:
        f = film.paper_interference_factor(dd, lam, n, c, 1.0)
    else:
        f = film.filtered_paper_interference_factor(dd, lam, n, c, 1.0, sigma)
    return (0.25 * f) @ weights


class PaperPhi:
    """``Phi`` of the module docstring at the fitted pixels of a level, for any thicknesses.

    ``n_film`` is the film's index at 589.3 nm (``Params.n_film``), ``d_max`` the largest
    thickness asked for (nm). Without dispersion ``Phi`` is a function of the optical path
    ``x = 2 n d cos th_t`` (eq. 8) alone, interpolated in :func:`phi_table`. With the
    level's ``cfg.dispersion`` the index per sample is ``n_k = n_film + index_offset_k``
    (as :func:`bubblefit.model.render.render` takes it) and ``Phi`` is evaluated per sample
    (:func:`_phi_per_wavelength`): exact, no approximation in ``x``, at K cosines per
    candidate and pixel instead of 3 interpolations.
    """

    def __init__(self, lev, n_film: float, d_max: float):
        basis = lev.cfg.effects.spectral
        cos = np.asarray(lev.cos.reshape(-1)[lev.mask.reshape(-1)], np.float64)
        self.law = lev.cfg.dispersion
        self.samples = int(basis.samples)
        if self.law is None:
            self.xfac = 2 * n_film * np.asarray(_cos_transmitted(cos, n_film), np.float64)
            self.table = jnp.asarray(phi_table(basis, 2 * n_film * float(d_max)))
        else:
            lam = np.asarray(basis.wavelengths, np.float64)
            self.args = (jnp.asarray(cos, jnp.float32), jnp.asarray(lam, jnp.float32),
                         jnp.asarray(n_film + index_offset(self.law, lam), jnp.float32),
                         None if basis.sigma is None else jnp.asarray(basis.sigma, jnp.float32),
                         jnp.asarray(basis.weights, jnp.float32))

    def __call__(self, d, cols=slice(None)):
        """(G, P', 3) ``Phi`` for thicknesses ``d`` (G, P') (or (G, 1)) at the pixels ``cols``."""
        if self.law is None:
            return phi_rgb(self.table, jnp.asarray(np.asarray(d) * self.xfac[cols], jnp.float32))
        cos, lam, n, sigma, w = self.args
        c = cos[cols]
        d = jnp.broadcast_to(jnp.asarray(d, jnp.float32), (np.shape(d)[0], c.shape[0]))
        return _phi_per_wavelength(d, c, lam, n, sigma, w)


@jax.jit
def paper_candidates(phi, m, c, t, r_s):
    """The ``paper`` model's pixel for interference integral ``Phi`` (..., 3): ``(refl, back)``.

    ``refl = 4 t^2 Phi M`` (eq. 10's factor times ``M``, the reflected radiance of both
    films rendered with interference off) and ``back = C (T / t^2)^2`` (``C`` the grey
    transmitted background of eq. 11, ``T`` :func:`bubblefit.optics.film.paper_tinted_transmission`
    of both films, ``r_s = 0`` without the tint). ``Phi`` is integrated per channel before
    the tint is squared: exact to ``O(r_s^2)`` of ``Phi``'s spread within a channel.
    """
    refl = 4.0 * t * t * phi * m
    tr = paper_tinted_transmission(4.0 * t * t * phi, t, r_s) / (t * t)
    return refl, c * tr * tr


def local_minima(cost: np.ndarray, grid: np.ndarray, k: int, separation: float) -> list[float]:
    """The ``k`` lowest local minima of ``cost`` over ``grid``, at least ``separation`` apart."""
    cost = np.asarray(cost, dtype=np.float64)
    cost = np.where(np.isfinite(cost), cost, np.inf)
    left = np.concatenate([[np.inf], cost[:-1]])
    right = np.concatenate([cost[1:], [np.inf]])
    idx = np.nonzero((cost <= left) & (cost <= right) & np.isfinite(cost))[0]
    idx = idx[np.argsort(cost[idx])]
    out: list[float] = []
    for i in idx:
        if all(abs(grid[i] - g) >= separation for g in out):
            out.append(float(grid[i]))
        if len(out) == k:
            break
    if not out:
        out.append(float(grid[int(np.argmin(cost))]))
    return out


@jax.jit
def score_global(refl, fixed, y, w2):
    """Score candidates with one least-squares gain each.

    Args:
        refl: (G, P, 3) the part of each candidate's image scaled by the camera gain.
        fixed: (P, 3) the part that is not (a background photo's transmission), or zeros.
        y: (P, 3) the photo; ``w2``: (P, 3) weights (1 / sigma^2, 0 where masked).

    Returns:
        ``(cost (G,), gain (G,))``: weighted sum of squares at the best gain >= 0.
    """
    target = y - fixed
    num = jnp.sum(w2 * refl * target, axis=(1, 2))
    den = jnp.sum(w2 * refl * refl, axis=(1, 2))
    gain = jnp.maximum(num / jnp.maximum(den, 1e-30), 0.0)
    res = -censored_residual(y, gain[:, None, None] * refl + fixed)  # the gain is the uncensored one
    return jnp.sum(w2 * res * res, axis=(1, 2)), gain


@functools.partial(jax.jit, static_argnames=("per_pixel_gain",))
def score_pixels(refl, fixed, y, w2, prior, *, per_pixel_gain: bool):
    """Best candidate per pixel.

    Args:
        refl: (G, P, 3) candidate images (gain-scaled part); ``fixed`` (P, 3) or
            (G, P, 3) as in :func:`pixel_costs`; ``y``, ``w2``: (P, 3).
        prior: (G, P) extra cost per candidate and pixel (a prior on the thickness), or zeros.
        per_pixel_gain: fit a gain per pixel (hue matching; for an unknown exposure).

    Returns:
        ``(best index (P,), best cost (P,), gain (P,))``.
    """
    if per_pixel_gain:
        target = y - fixed
        num = jnp.sum(w2 * refl * target, axis=-1)
        den = jnp.sum(w2 * refl * refl, axis=-1)
        gain = jnp.maximum(num / jnp.maximum(den, 1e-30), 0.0)
    else:
        gain = jnp.ones(refl.shape[:2], refl.dtype)
    cost = pixel_costs(gain[..., None] * refl, fixed, y, w2) + prior
    best = jnp.argmin(cost, axis=0)
    take = lambda a: jnp.take_along_axis(a, best[None], axis=0)[0]
    return best, take(cost), take(gain)


@jax.jit
def pixel_costs(refl, fixed, y, w2):
    """(G, P) weighted squared residual of every candidate at every pixel (gain 1).

    ``refl`` (G, P, 3), ``fixed`` (P, 3) or (G, P, 3), ``y`` and ``w2`` (P, 3) as in
    :func:`score_global`. Unlike the whole-photo score and the solver's residual, a pixel's
    costs are not censored at black: in a dim photo every channel of a pixel can lie under
    :data:`~bubblefit.inverse._censored.BLACK_CLIP`, and then every candidate darker than
    the photo costs nothing there, so the tie goes to the grid's first (thinnest) candidate
    and the per-pixel search reads a black film (the 64 px demo photo of
    tests/test_demo.py, seed 3: top 0.4 nm for 250 nm).
    """
    res = refl - (y - fixed)
    return jnp.sum(w2 * res * res, axis=-1)


def best_profile(cost: np.ndarray, grid: np.ndarray, height: np.ndarray,
                 exponents=PROFILE_EXPONENTS, step: float | None = None) -> tuple:
    """Global search of a drainage profile (docs/design.md) through per-pixel candidate costs.

    Every ``(top, bottom, exponent)`` on a grid (``top`` and ``bottom`` over ``grid``'s
    range in steps of ``step``, default 5 grid steps) predicts each pixel's thickness,
    ``d = top + (bottom - top) ((1 - y) / 2)^exponent``; its score is the sum over pixels
    of the cost of the nearest grid thickness, each capped at 4x the median of the pixels'
    best costs (a robust loss: a bump on the film does not pull the profile). Summing
    along the profile uses every pixel of a height together, where matching each pixel's
    colour alone is at the mercy of its noise.

    Args:
        cost: (G, P) from :func:`pixel_costs`; grid: (G,) thicknesses (uniform steps).
        height: (P,) height of each pixel's film point over the radius, in [-1, 1].

    Returns:
        ``(top, bottom, exponent)`` of the best profile.
    """
    cost = np.asarray(cost, np.float32)
    cap = 4.0 * float(np.median(cost.min(axis=0)))
    cost = np.minimum(cost, cap)
    g0, dg = float(grid[0]), float(grid[1] - grid[0])
    stride = max(1, int(round((step or 5 * dg) / dg)))
    ends = np.arange(0, len(grid), stride)
    x = np.clip((1.0 - np.asarray(height, np.float64)) / 2.0, 0.0, 1.0)
    cols = np.arange(cost.shape[1])
    best = (np.inf, grid[0], grid[-1], 1.0)
    for e in exponents:
        xe = x**e
        for i in ends:
            # grid index of each pixel for every bottom, this top: (B, P)
            pos = i * (1.0 - xe)[None, :] + ends[:, None] * xe[None, :]
            idx = np.clip(np.rint(pos).astype(np.int64), 0, len(grid) - 1)
            total = cost[idx, cols[None, :]].sum(axis=1)
            j = int(np.argmin(total))
            if total[j] < best[0]:
                best = (float(total[j]), g0 + i * dg, g0 + ends[j] * dg, e)
    return best[1], best[2], best[3]


# ---------------------------------------------------------------------------------------
# Candidate images of a level for the thickness grid, and the search's starting points
# ---------------------------------------------------------------------------------------


def unlit_terms(lev, table: ParameterTable, vals: dict, env, cfg=None):
    """``(M, C)`` (P, 3) over the fitted pixels of ``lev``: the reflected radiance of both
    films rendered with interference off at ``vals`` (gain included) and the transmitted
    background (the module docstring's ``F(x) M + C``); ``cfg``: a configuration to render
    them with instead (a grey film's own, :func:`grey_exposure`)."""
    fx = lev.cfg.effects
    off = cfg or replace(lev.cfg, effects=replace(fx, interference="off", spectral=None, thickness="constant"))
    v = {k: jnp.asarray(x, jnp.float32) for k, x in dict(vals, thickness_nm=0.0).items() if k != "map"}
    _, terms = render_level(table.render_params(v, "constant"), lev, env, cfg=off, terms=True)
    zero = np.zeros(lev.y.shape, np.float32)
    sel = lev.mask.reshape(-1)
    m = (terms.get("front", zero) + terms.get("rear", zero)).reshape(-1, 3)[sel]
    c = terms.get("background", zero).reshape(-1, 3)[sel]
    return m, c


def grey_exposure(lev, table: ParameterTable, vals: dict, env) -> float:
    """The exposure's weighted least-squares value on ``lev`` with every other parameter at
    ``vals``, for a film rendered without interference colours (``off`` or ``incoherent``,
    where no thickness search sets it): the render is affine in the camera gain (eq. 1's
    reflected terms scale with it, a background photo does not; the map's background
    does), so with the terms ``M``, ``C`` rendered at gain 1 it is
    ``sum w^2 M (y - C) / sum w^2 M^2`` (the linear parameter solved for the others held:
    variable projection, G. H. Golub and V. Pereyra, SIAM J. Numer. Anal. 10, 413, 1973).
    ``vals["exposure"]`` where the photo gives no positive value."""
    m, c = (np.asarray(a, np.float64) for a in unlit_terms(lev, table, dict(vals, exposure=1.0), env, cfg=lev.cfg))
    sel = lev.mask.reshape(-1)
    if lev.cfg.effects.background != "photo":
        m, c = m + c, np.zeros_like(c)
    y = np.asarray(lev.y, np.float64).reshape(-1, 3)[sel]
    w2 = np.asarray(lev.w, np.float64).reshape(-1, 3)[sel] ** 2
    num, den = float(np.sum(w2 * m * (y - c))), float(np.sum(w2 * m * m))
    return num / den if den > 0 and num > 0 else float(vals["exposure"])


def paper_pixel_candidates(grid, phi: PaperPhi, m, c, t: float, r_s: float):
    """``(refl, back)`` (G, P, 3) of :func:`paper_candidates` for thicknesses ``grid`` (G,)
    at every pixel of ``phi`` (:class:`PaperPhi`)."""
    return paper_candidates(phi(np.asarray(grid)[:, None]), jnp.asarray(m)[None], jnp.asarray(c)[None], t, r_s)


def _candidates_paper(lev, table: ParameterTable, vals: dict, grid: np.ndarray, env):
    """(G, P, 3) gain-scaled part and (P, 3) fixed part for constant films (paper model, exact)."""
    fx = lev.cfg.effects
    m, c = unlit_terms(lev, table, dict(vals, exposure=1.0), env)
    r_s = float(table.render_params({k: jnp.asarray(x, jnp.float32) for k, x in dict(vals, thickness_nm=0.0).items()
                                     if k != "map"}, "constant").r_s) if fx.tint and fx.transmission else 0.0
    phi = PaperPhi(lev, float(vals["n_film"]), float(grid.max()))
    refl, back = paper_pixel_candidates(grid, phi, m, c, float(vals["t"]), r_s)
    if fx.background == "photo":
        return refl, back
    return refl + back, jnp.zeros(back.shape[1:], back.dtype)


@functools.partial(jax.jit, static_argnames=("cfg", "table"))
def render_candidates(base: dict, thick, cfg, env, bg, table: ParameterTable, shift):
    """Render each candidate thickness field ``thick`` (G, ...) with exposure 1: (G, H, W, 3) x2,
    the disc moved by ``shift`` before the refinement ``base`` holds (a padded level's
    ``base``, :func:`~bubblefit.inverse._programs.padded`). The thickness maps' candidates
    (:mod:`bubblefit.inverse._maps`); constant films trace their light once instead
    (:func:`_candidates_generic`)."""

    def one(th):
        p = table.render_params(dict(base, exposure=jnp.float32(1.0), thickness_nm=th, map=th),
                                cfg.effects.thickness)
        p = replace(p, disc=compose_shift(shift, p.disc))
        _, terms = render_terms(p, cfg, env, bg)
        zero = jnp.zeros(cfg.shape + (3,), jnp.float32)
        refl = terms.get("front", zero) + terms.get("rear", zero)
        back = terms.get("background", zero)
        if cfg.effects.background == "photo":
            return refl, back
        return refl + back, zero

    return jax.lax.map(one, thick)


#: Pixels and thicknesses per call of the generic candidates' program: every level and
#: thickness grid is served by the one program of these sizes.
CANDIDATE_PIXELS = 256
CANDIDATE_THICKNESSES = 64


def _candidates_generic(lev, table: ParameterTable, vals: dict, grid: np.ndarray, env):
    """(G, P, 3) gain-scaled and fixed parts for constant films of any model, rendered at
    the fitted pixels: the rays and the map's light traced once, the film's optics per
    thickness (:func:`~bubblefit.model.render.render_pixels_at`), in blocks of
    :data:`CANDIDATE_PIXELS` pixels and :data:`CANDIDATE_THICKNESSES` thicknesses."""
    pix = fitted_pixels(lev, CANDIDATE_PIXELS, layout="whole")
    cfg = replace(pix.padded.cfg, effects=replace(lev.cfg.effects, thickness="constant"))
    base = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k != "map"}
    p = table.render_params(dict(base, exposure=jnp.float32(1.0), thickness_nm=jnp.float32(0.0)), "constant")
    p = replace(p, disc=compose_shift(pix.padded.base, p.disc))
    g, n = len(grid), pix.flat.size
    steps = -(-g // CANDIDATE_THICKNESSES)
    thick = np.asarray(grid, np.float32)[np.minimum(np.arange(steps * CANDIDATE_THICKNESSES), g - 1)]
    thick = thick.reshape(steps, CANDIDATE_THICKNESSES)
    blocks = [[render_pixels_at(p, cfg, env, pix.padded.bg, pix.rows[i:i + 1], pix.cols[i:i + 1], pix.idx[i:i + 1],
                                th) for i in range(pix.rows.shape[0])] for th in thick]
    names = blocks[0][0].keys()
    joined = {k: np.concatenate([np.concatenate([np.asarray(b[k]) for b in row], axis=1) for row in blocks])[:g, :n]
              for k in names}
    part = lambda *ks: sum((joined[k] for k in ks if k in joined), np.zeros((g, n, 3), np.float32))
    if lev.cfg.effects.background == "photo":
        return part("front", "rear"), part("background")
    return part("front", "rear", "background"), np.zeros((g, n, 3), np.float32)


def candidates(lev, table: ParameterTable, vals: dict, grid: np.ndarray, env):
    """Candidate images for the thickness grid: ``(refl, fixed)``, see :func:`score_global`."""
    if exact_paper_search(lev.cfg):
        return _candidates_paper(lev, table, vals, grid, env)
    return _candidates_generic(lev, table, vals, grid, env)


def profile_from_pixels(height, d, w):
    """Robust least-squares drainage profile (top, bottom, exponent) through per-pixel thicknesses.

    Iteratively reweighted least squares of ``d = top (1 - x^e) + bottom x^e``,
    ``x = (1 - y) / 2`` (the drainage profile of docs/design.md), for each exponent of
    :data:`PROFILE_EXPONENTS`; the exponent of the smallest median absolute residual wins.
    """
    best = None
    x = np.clip((1 - height) / 2, 0, 1)
    for e in PROFILE_EXPONENTS:
        basis = np.stack([1 - x**e, x**e], axis=1)
        wt = w.copy()
        for _ in range(6):
            sw = np.sqrt(wt)
            coef, *_ = np.linalg.lstsq(basis * sw[:, None], d * sw, rcond=None)
            res = d - basis @ coef
            s = 1.4826 * np.median(np.abs(res)) + 1.0
            wt = w / np.maximum(1.0, np.abs(res) / (2.0 * s))
        score = np.median(np.abs(res))
        if best is None or score < best[0]:
            best = (score, coef[0], coef[1], e)
    _, top, bottom, e = best
    return max(top, 1.0), max(bottom, 1.0), e


def _profile_starts(lev_s, table, v, grid, refl, fixedpart, y, w2, tint: bool):
    """Starting drainage profiles: a robust line through each pixel's best thickness, and
    :func:`best_profile` over every pixel's candidate costs at one camera gain."""
    zero = jnp.zeros(refl.shape[:2])
    best, _, gain = score_pixels(refl, fixedpart, y, w2, zero, per_pixel_gain=True)
    gain = np.asarray(gain)
    g = float(np.median(gain[gain > 0])) if np.any(gain > 0) else v["exposure"]
    if tint:
        # A gain per pixel can cancel the reflected colour against the tint's
        # complementary one; scan one gain for all pixels around the hue-matched median.
        scan = []
        for gg in g * np.geomspace(1 / 3, 3, 17):
            _, c, _ = score_pixels(gg * refl, fixedpart, y, w2, zero, per_pixel_gain=False)
            c = np.asarray(c)
            scan.append((float(np.sum(np.minimum(c, 4 * np.median(c)))), gg))
        g = min(scan)[1]
    hgt = lev_s.height.reshape(-1)[lev_s.mask.reshape(-1)]
    d_pix = grid[np.asarray(best)]
    profiles = [profile_from_pixels(hgt, d_pix, np.ones_like(d_pix))]
    cost = np.asarray(pixel_costs(g * refl, fixedpart, y, w2))
    profiles.append(best_profile(cost, grid, hgt))
    starts = []
    for top, bottom, e in profiles:
        nv = dict(v, exposure=g if "exposure" in table.free else v["exposure"])
        for n, val in (("top_nm", top), ("bottom_nm", bottom), ("exponent", e)):
            if n in table.free:
                nv[n] = val
        starts.append(nv)
    return starts


def search_starts(lev_s, table: ParameterTable, vals: dict, env, thickness_range, step_nm: float,
                  n_candidates: int) -> list[dict]:
    """Starting values from the global thickness search on ``lev_s``: the ``n_candidates``
    lowest local minima of a constant film (each with its best gain), or the starting
    drainage profiles (:func:`_profile_starts`)."""
    lo, hi = thickness_range
    grid = thickness_grid(lo, hi, step_nm)
    refl, fixedpart = candidates(lev_s, table, vals, grid, env)
    y = jnp.asarray(lev_s.y.reshape(-1, 3)[lev_s.mask.reshape(-1)])
    w2 = jnp.asarray(lev_s.w.reshape(-1, 3)[lev_s.mask.reshape(-1)] ** 2)
    if table.thickness_model != "constant":
        return _profile_starts(lev_s, table, vals, grid, refl, fixedpart, y, w2, lev_s.cfg.effects.tint)
    cost, gain = score_global(refl, fixedpart, y, w2)
    cost, gain = np.asarray(cost), np.asarray(gain)
    starts = []
    for d in local_minima(cost, grid, n_candidates, separation=20.0):
        g = float(gain[int(np.argmin(np.abs(grid - d)))])
        starts.append(dict(vals, thickness_nm=d, exposure=max(g, 1e-6) if "exposure" in table.free
                           else vals["exposure"]))
    return starts
