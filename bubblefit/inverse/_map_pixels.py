"""A thickness map's per-pixel costs with the rays traced once.

A map pixel's colour depends on its own thickness only (the rear film and the internal
bounces read the map at the same pixel, changed by the drainage profile between the
heights of their film points, :func:`bubblefit.model.thickness.thickness_at`). The rays,
the environment map's filtered light at every film point and the background do not
depend on the thickness at all, so a level's pixels are traced once
(:func:`bubblefit.model.render.trace_pixels`) and only the film's optics (the Airy film
per wavelength and polarisation, or eq. 10's factor) are evaluated per candidate
thickness: the map's cost for ``G`` candidates is one trace plus ``G`` optics, not ``G``
renders of the whole image (:class:`bubblefit.inverse._maps.RenderCosts`).

The same separability makes the map's Jacobian diagonal: :func:`pixel_slopes` gives each
pixel's residual and its derivative in its own thickness with one forward-mode tangent
(all ones), for the per-pixel Gauss-Newton refinement of :mod:`._maps`.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

from ._observation import Level
from ._parameters import ParameterTable
from ._programs import fitted_pixels
from ..io.executables import stored
from ..model.geometry import compose_shift
from ..model.render import shade_pixels, trace_pixels
from ..model.thickness import thickness_at

__all__ = ["TracedCosts", "WindowCosts", "WindowPolynomials", "WINDOW_NODES", "window", "refine", "CHUNK", "REFINE_STEPS",
           "REFINE_TOL_NM", "REFINE_QUANTILE"]

#: Pixels per traced chunk (the renderer's chunks are of this order).
CHUNK = 512
#: Pixels per call of :meth:`TracedCosts.at` (the least
#: :func:`~bubblefit.inverse._programs.pixel_bucket`: one chunk's programs serve every count).
AT_CHUNK = 64


def _predict(cfg, traced, d):
    """(N, 3) pixels of a chunk whose front films have thicknesses ``d`` (N,): the mean over
    the chunk's sub-pixel rays of the model's terms (eq. 11 or the physical series)."""
    pix = jnp.arange(d.shape[0])

    def films(tr):
        thick = lambda local: thickness_at("map", d, local, pix, tr.p.profile, tr.hits.local0)
        return d, thick(tr.hits.local1), thick

    return shade_pixels(traced, cfg, films)[0]


def _trace(p, cfg, env, bg, r, c, i):
    """One chunk's rays (:func:`~bubblefit.model.render.trace_pixels`) at pixel rows ``r`` and
    columns ``c``, with the background photo's pixels ``i`` (flat indices) behind them."""
    return trace_pixels(p, cfg, env, None if bg is None else bg.reshape(-1, 3)[i], r, c)


def _at(traced, exposure, profile):
    """Traced rays (:func:`_chunk_trace`) with the exposure and the drainage profile
    ``exposure``, ``profile`` in place of those they were traced at: the rays and the light
    they read depend on neither (eq. (11) and the physical series scale the reflected terms
    by the exposure; the rear film reads the profile,
    :func:`bubblefit.model.thickness.thickness_at`)."""
    return [replace(t, p=replace(t.p, exposure=exposure, profile=profile)) for t in traced]


@functools.partial(jax.jit, static_argnames=("cfg",))
def _traced_costs(cfg, traced, cand, y, w2, exposure, profile):
    """(steps, G, chunk) data chi^2 of candidates ``cand`` (steps, G, chunk) from every
    chunk's rays traced once (:func:`_chunk_trace`), at the exposure and the drainage
    profile ``exposure``, ``profile`` (:func:`_at`): only the film's optics are evaluated
    per candidate."""

    def chunk(xs):
        tr, th, yy, ww = xs
        tr = _at(tr, exposure, profile)

        def at(d):
            res = _predict(cfg, tr, d) - yy
            return jnp.sum(ww * res * res, axis=-1)

        return jax.lax.map(at, th)

    return jax.lax.map(chunk, (traced, cand, y, w2))


def _slopes(predict, d, y, w):
    """A chunk's weighted residuals ``w (predict(d) - y)`` and their derivatives in each
    pixel's own thickness (one forward-mode tangent of ones: the Jacobian is diagonal)."""
    return jax.jvp(lambda x: w * (predict(x) - y), (d,), (jnp.ones_like(d),))


@functools.partial(jax.jit, static_argnames=("cfg",))
def _chunk_trace(p, cfg, env, bg, rows, cols, idx):
    """Every chunk's traced rays (:func:`~bubblefit.model.render.trace_pixels`), stacked
    over the chunks: what a level's pixels read that does not depend on the thickness."""

    return jax.lax.map(lambda xs: _trace(p, cfg, env, bg, *xs), (rows, cols, idx))


@functools.partial(jax.jit, static_argnames=("cfg",))
def _traced_slopes(cfg, traced, d, y, w, exposure, profile):
    """:func:`_slopes` of every chunk from its rays traced once (:func:`_chunk_trace`), at
    the exposure and the drainage profile ``exposure``, ``profile`` (:func:`_at`),
    (steps, chunk, 3) each: only the film's optics are evaluated."""

    def chunk(xs):
        tr, dd, yy, ww = xs
        return _slopes(lambda x: _predict(cfg, _at(tr, exposure, profile), x), dd, yy, ww)

    return jax.lax.map(chunk, (traced, d, y, w))


@functools.partial(jax.jit, static_argnames=("cfg",))
def _traced_pixels(cfg, traced, d, exposure, profile):
    """Every chunk's pixels (steps, chunk, 3) at front thicknesses ``d`` (steps, chunk) from
    its rays traced once (:func:`_chunk_trace`), with the exposure and the drainage profile
    ``exposure``, ``profile`` (:func:`_at`), and their derivative in the exposure (one
    forward-mode tangent)."""

    def chunk(xs):
        tr, dd = xs
        at = lambda e: _predict(cfg, _at(tr, e, profile), dd)
        return jax.jvp(at, (exposure,), (jnp.ones_like(exposure),))

    return jax.lax.map(chunk, (traced, d))


@functools.lru_cache(maxsize=16)
def _stored_programs(cfg):
    """``(costs, trace, slopes, pixels)``: :func:`_traced_costs`, :func:`_chunk_trace` (its
    output as the list of its leaves), :func:`_traced_slopes` and :func:`_traced_pixels`
    (the others taking that list) for ``cfg``
    through the executable store (:func:`bubblefit.io.executables.stored`): a new process
    loads the map's programs instead of tracing and lowering the film's optics again."""

    def structure(p, env, bg, rows, cols, idx):
        """The tree of :func:`_chunk_trace`'s output (only traced when a program is compiled)."""
        return jax.tree_util.tree_structure(jax.eval_shape(
            lambda *a: _chunk_trace(a[0], cfg, *a[1:]), p, env, bg, rows, cols, idx))

    def slopes(p, env, bg, rows, cols, idx, leaves, d, y, w):
        traced = jax.tree_util.tree_unflatten(structure(p, env, bg, rows, cols, idx), leaves)
        return _traced_slopes(cfg, traced, d, y, w, p.exposure, p.profile)

    def pixels(p, env, bg, rows, cols, idx, leaves, d, exposure, profile):
        traced = jax.tree_util.tree_unflatten(structure(p, env, bg, rows, cols, idx), leaves)
        return _traced_pixels(cfg, traced, d, exposure, profile)

    def costs(p, env, bg, rows, cols, idx, leaves, cand, y, w2):
        traced = jax.tree_util.tree_unflatten(structure(p, env, bg, rows, cols, idx), leaves)
        return _traced_costs(cfg, traced, cand, y, w2, p.exposure, p.profile)

    def trace(p, env, bg, rows, cols, idx):
        return jax.tree_util.tree_leaves(_chunk_trace(p, cfg, env, bg, rows, cols, idx))

    return (stored(jax.jit(costs), "inverse._map_pixels.costs", cfg),
            stored(jax.jit(trace), "inverse._map_pixels.trace", cfg),
            stored(jax.jit(slopes), "inverse._map_pixels.slopes", cfg),
            stored(jax.jit(pixels), "inverse._map_pixels.pixels", cfg))


#: How many levels' traced rays are kept (:func:`_kept_trace`), the last read first: a
#: sequence's frame that holds the global parameters reads every level of its pyramid from
#: the frame before it, which traced them at the same values.
KEPT_TRACES = 4
#: The kept traces, the last read first: ``(key, env, idx, leaves)``, ``key`` the values
#: traced at but the pixels (:func:`_values_key`), ``idx`` (steps, chunk) the padded level's
#: flat indices of the traced pixels (numpy), ``leaves`` :func:`_chunk_trace`'s leaves.
_TRACES: list = []


def _values_key(cfg, p, bg) -> tuple:
    """What a level's rays depend on but its pixels and the environment map: the
    configuration, every value but the exposure and the drainage profile (:func:`_at`)
    and the background photo, as bytes."""
    fields = tuple(f for f in p.__dataclass_fields__ if f not in ("exposure", "profile"))
    return (cfg, tuple(np.asarray(getattr(p, f)).tobytes() for f in fields), None if bg is None else np.asarray(bg).tobytes())


def _covering_trace(cfg, p, env, bg, idx: np.ndarray):
    """The kept trace (:data:`_TRACES`' entry) at the values of ``(cfg, p, env, bg)`` whose
    pixels hold every pixel of the layout ``idx`` (steps, chunk; the padded level's flat
    indices) in a layout of the same shape: the same pixels, or a mask that lost a few
    (a frame's clipped pixels) and whose own layout would be as long
    (:func:`~bubblefit.inverse._programs._even_chunks`: the same programs, at the same
    cost). The same pixels are preferred; None where no kept trace holds them."""
    key, best = _values_key(cfg, p, bg), None
    want = np.unique(idx)
    for i, (k, e, kidx, leaves) in enumerate(_TRACES):
        if e is not env or k != key or kidx.shape != idx.shape:
            continue
        if np.array_equal(kidx, idx):
            best = i
            break
        if best is None and np.all(np.isin(want, kidx)):
            best = i
    if best is None:
        return None
    _TRACES.insert(0, _TRACES.pop(best))
    return _TRACES[0]


def _kept_trace(cfg, args: tuple):
    """The leaves of :func:`_chunk_trace` at the render arguments ``args = (p, env, bg, rows,
    cols, idx)``, traced once and kept (the last :data:`KEPT_TRACES`): the rays and the light
    they read depend on every value but the exposure and the drainage profile (:func:`_at`,
    which the programs that read the rays put in place), so a level traced at the same
    values otherwise (a sequence's frames that hold the global parameters, a frame's map
    refined again after its exposure's step) reads the kept rays."""
    p, env, bg, idx = args[0], args[1], args[2], np.asarray(args[5])
    kept = _covering_trace(cfg, p, env, bg, idx)
    if kept is not None and np.array_equal(kept[2], idx):
        return kept[3]
    leaves = _stored_programs(cfg)[1](*args)
    _TRACES.insert(0, (_values_key(cfg, p, bg), env, idx, leaves))
    del _TRACES[KEPT_TRACES:]
    return leaves


class TracedCosts:
    """Per-pixel data chi^2 of a level's map at any thicknesses, its rays traced once (and
    kept, :func:`_kept_trace`).

    ``vals`` the fitted values (exposure, profile under the map, ...); the photo's
    background (``lev.bg``) enters as the renderer takes it. Calling with ``d`` (G, P)
    (``P`` the level's mask pixels, in the order of ``lev.mask.reshape(-1)``) gives (G, P).
    ``mask``: the pixels compared, if not the level's (:meth:`at`).
    """

    def __init__(self, lev: Level, table: ParameterTable, vals: dict, env, mask: np.ndarray | None = None):
        self._args = (lev, table, vals, env)
        self._keep = mask is None  # a level's rays are kept (:func:`_kept_trace`), a few pixels' are not
        self.pix = fitted_pixels(lev, CHUNK, mask, layout="even")
        pad = self.pix.padded
        self.cfg = replace(pad.cfg, effects=replace(lev.cfg.effects, thickness="map"))
        base = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k != "map"}
        h, w = pad.cfg.shape
        p = table.render_params(dict(base, map=jnp.zeros((h, w), jnp.float32)), "map")
        self.p = replace(p, disc=compose_shift(pad.base, p.disc))
        self.env, self.bg = env, pad.bg
        self.n = self.pix.flat.size
        steps, size = self.pix.rows.shape
        self.shape = (steps, size)
        #: each of the ``P`` pixels' entry in the chunks (steps chunk,), and each entry's pixel
        #: among the ``P`` (the padding repeating the last pixel, with weight 0)
        self.slot, self._take = np.arange(self.n), np.minimum(np.arange(steps * size), self.n - 1)
        self._traced = None  # the level's traced rays, once a call has traced them
        if self._keep:
            self._cover(lev)
        self.y = self.pix.y.reshape(steps, size, 3)
        self.w = self.pix.w.reshape(steps, size, 3)
        #: the :class:`WindowPolynomials` the finest level's map was refined on (set by
        #: :func:`~bubblefit.inverse._maps.fit_map`), for a second refinement at another exposure
        self.polynomials = None

    def _cover(self, lev: Level) -> None:
        """Read a kept trace whose pixels hold this level's in a layout of the same shape
        (:func:`_covering_trace`): a pixel's rays do not depend on the others', so a mask
        that lost a few pixels since (a frame's clipped pixels) reads the kept rays at its
        pixels' entries, the other entries weighted 0 (the costs, slopes and shadings of its
        pixels are those of a fresh trace, the same programs on the same numbers)."""
        pix = self.pix
        kept = _covering_trace(self.cfg, self.p, self.env, self.bg, np.asarray(pix.idx))
        if kept is None:
            return
        kidx, self._traced = kept[2], kept[3]
        if np.array_equal(kidx, np.asarray(pix.idx)):
            return
        steps, size = self.shape
        entries = kidx.reshape(-1)
        own = np.asarray(pix.idx).reshape(-1)[:self.n]  # the P pixels, ascending as the kept list is
        self.slot = np.searchsorted(entries, own)  # each pixel's first entry
        self._take = np.clip(np.searchsorted(self.slot, np.arange(steps * size), side="right") - 1, 0, self.n - 1)
        y, w = np.zeros((steps * size, 3), np.float32), np.zeros((steps * size, 3), np.float32)
        y[self.slot], w[self.slot] = np.asarray(pix.y).reshape(-1, 3)[:self.n], np.asarray(pix.w).reshape(-1, 3)[:self.n]
        wb = pix.padded.cfg.shape[1]
        rows, cols = np.divmod(kidx, wb)
        i32 = lambda a: jnp.asarray(a, jnp.int32)
        self.pix = replace(pix, rows=i32(rows), cols=i32(cols), idx=i32(kidx), y=jnp.asarray(y), w=jnp.asarray(w))

    def _spread(self, d: np.ndarray) -> np.ndarray:
        """(..., P) -> (..., steps, chunk): each entry its pixel's (:attr:`slot`)."""
        steps, size = self.shape
        return np.asarray(d, np.float32)[..., self._take].reshape(d.shape[:-1] + (steps, size))

    def __call__(self, d: np.ndarray) -> np.ndarray:
        """(G, P) chi^2 of candidate thicknesses ``d`` (G, P)."""
        cand = np.moveaxis(self._spread(np.maximum(d, 0.0)), 0, 1)  # (steps, G, chunk)
        out = _stored_programs(self.cfg)[0](*self._traced_args(), jnp.asarray(cand), self.y, self.w * self.w)
        return np.moveaxis(np.asarray(out), 1, 0).reshape(d.shape[0], -1)[:, self.slot]

    def at(self, d: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(G, len(cols)) chi^2 of candidate thicknesses ``d`` (G, len(cols)) at the level's
        pixels ``cols`` alone (indices into its ``P``, ascending): those pixels' rays traced
        on their own (not kept), :data:`AT_CHUNK` at a time, so that one program of each
        ``G`` serves every count."""
        lev = self._args[0]
        flat = np.flatnonzero(lev.mask.reshape(-1))[np.asarray(cols)]
        out = np.empty(d.shape, np.float32)
        for s in range(0, flat.size, AT_CHUNK):
            mask = np.zeros(lev.mask.size, bool)
            mask[flat[s:s + AT_CHUNK]] = True
            out[:, s:s + AT_CHUNK] = TracedCosts(*self._args, mask=mask.reshape(lev.mask.shape))(d[:, s:s + AT_CHUNK])
        return out

    def slopes(self, d: np.ndarray):
        """``(r, j)``, (P, 3) each: the weighted residual of each pixel at thickness ``d`` (P,)
        and its derivative in that pixel's thickness (the map's diagonal Jacobian). The
        level's rays are traced at the first call and kept (the light the films read does
        not depend on the thickness), so each further call evaluates the film's optics only."""
        r, j = _stored_programs(self.cfg)[2](*self._traced_args(), jnp.asarray(self._spread(np.maximum(d, 0.0))), self.y, self.w)
        return np.asarray(r).reshape(-1, 3)[self.slot], np.asarray(j).reshape(-1, 3)[self.slot]

    def _traced_args(self) -> tuple:
        """The level's render arguments and its rays, traced at the first call and kept
        (:func:`_kept_trace`: a level traced before at the same values but the exposure and
        the drainage profile reads its rays from there)."""
        pix = self.pix
        args = (self.p, self.env, self.bg, pix.rows, pix.cols, pix.idx)
        if self._traced is None:
            self._traced = _kept_trace(self.cfg, args) if self._keep else _stored_programs(self.cfg)[1](*args)
        return (*args, self._traced)

    def pixels(self, d: np.ndarray, table: ParameterTable, vals: dict) -> tuple[np.ndarray, np.ndarray]:
        """``(img, column)``, (P, 3) each: the level's pixels at thicknesses ``d`` (P,) with
        the exposure and the drainage profile of ``vals`` (the other values as traced), and
        their derivative in the exposure, from the rays :meth:`slopes` traced (traced here
        if not yet): a render of the fitted pixels without tracing them again. Read from
        the :attr:`polynomials` the level's map was refined on where they hold ``d`` and
        were made at the drainage profile of ``vals`` (the exposure is read from their
        column: :meth:`WindowPolynomials.pixels`)."""
        h, w = self.pix.padded.cfg.shape
        base = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k != "map"}
        q = table.render_params(dict(base, map=jnp.zeros((h, w), jnp.float32)), "map")
        poly = self.polynomials
        if poly is not None and poly.holds(d, q.profile):
            return poly.at(float(q.exposure)).pixels(d)
        return self._shaded(d, q.exposure, q.profile)

    def _shaded(self, d: np.ndarray, exposure, profile) -> tuple[np.ndarray, np.ndarray]:
        """``(img, column)`` of :meth:`pixels` at the render's own ``exposure`` and ``profile``."""
        img, col = _stored_programs(self.cfg)[3](*self._traced_args(), jnp.asarray(self._spread(np.maximum(d, 0.0))),
                                                 exposure, profile)
        return (np.asarray(img, np.float64).reshape(-1, 3)[self.slot], np.asarray(col, np.float64).reshape(-1, 3)[self.slot])

    def window_polynomials(self, lo: np.ndarray, hi: np.ndarray) -> "WindowPolynomials":
        """Each pixel's colour over its thicknesses ``[lo, hi]`` (P,) as a polynomial
        (:class:`WindowPolynomials`), at this level's values."""
        return WindowPolynomials(self, lo, hi)


#: Chebyshev nodes of each pixel's window in :class:`WindowPolynomials` (a polynomial of
#: degree one less). The film's colours vary with the phase ``4 pi n d cos(theta_t) /
#: lambda``: at 380 nm and n = 1.4 a fringe spans at least 136 nm of thickness, so over a
#: window of +-24 nm (``_maps.FINE_HALF_STEPS`` coarse steps) a fringe ``cos(omega d)`` has
#: ``omega h <= 1.11`` and its interpolant's error is about ``2 J_7(1.11) ~ 6e-6`` of its
#: amplitude (Trefethen 2013, ch. 8); the Airy sum's second harmonic and the bounces'
#: products (fringes of 68 nm, ``omega h = 2.2``) have under 0.03 of the amplitude and
#: ``2 J_7(2.2) ~ 8e-4`` of it. On held frames of the 96 px sequence of
#: ``experiments/bench_sequence_maps.py`` (4152 pixels, 30 thicknesses each across the
#: window) the weighted residual's error was at most 2.2e-3 of the noise (99th percentile
#: 1.2e-4) with 7 nodes, 0.074 with 5 and 6e-4 (float32 rounding) with 9 or more.
WINDOW_NODES = 7


def window(centre: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)``: the thicknesses within ``half`` of ``centre`` (P,), none below 0 (nm)."""
    return np.maximum(centre - half, 0.0), centre + half


class WindowPolynomials:
    """Each pixel's colour as a polynomial in its own thickness over its window ``[lo, hi]``
    (P,): the colours at the window's :data:`WINDOW_NODES` Chebyshev points (of the first
    kind) and their Chebyshev series through them (Trefethen, Approximation Theory and
    Approximation Practice, 2013, ch. 3-4), from the level's rays traced once
    (:meth:`TracedCosts.pixels`).

    A map pixel's colour depends on its own thickness only, smoothly (the module
    docstring; :data:`WINDOW_NODES` bounds the interpolant's error), so the per-pixel
    solve's residuals and diagonal Jacobian at any thicknesses of the window are read from
    the series (:meth:`slopes`) instead of a forward-mode pass of the film's optics each
    trial: :data:`WINDOW_NODES` shadings of the film's optics without a thickness tangent
    in all. The colours are affine in the exposure (eq. 11 and the physical series scale
    the reflected terms by it, the transmitted background photo is not), so the series of
    their exposure derivative gives the colours at any exposure exactly (:meth:`at`).
    """

    def __init__(self, costs: TracedCosts, lo: np.ndarray, hi: np.ndarray, nodes: int = WINDOW_NODES):
        self.lo, self.hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self._mid, self._half = 0.5 * (self.lo + self.hi), np.maximum(0.5 * (self.hi - self.lo), 1e-9)
        self.exposure = float(costs.p.exposure)
        self.profile = np.asarray(costs.p.profile)
        j = np.arange(nodes) + 0.5
        x = np.cos(np.pi * j / nodes)  # the nodes on [-1, 1]
        shaded = [costs._shaded(self._mid + self._half * xk, costs.p.exposure, costs.p.profile) for xk in x]
        img, col = (np.stack([s[i] for s in shaded]) for i in (0, 1))  # (nodes, P, 3)
        # the discrete cosine transform of the values gives the series' coefficients
        m = (2.0 / nodes) * np.cos(np.pi * np.outer(np.arange(nodes), j) / nodes)
        m[0] *= 0.5
        self._c, self._a = np.einsum("kj,jpc->kpc", m, img), np.einsum("kj,jpc->kpc", m, col)
        self.y = np.asarray(costs.y, np.float64).reshape(-1, 3)[costs.slot]
        self.w = np.asarray(costs.w, np.float64).reshape(-1, 3)[costs.slot]

    def at(self, exposure: float) -> "WindowPolynomials":
        """The same pixels' polynomials at another ``exposure`` (the colours are affine in it)."""
        out = object.__new__(WindowPolynomials)
        out.__dict__.update(self.__dict__)
        out._c, out.exposure = self._c + (float(exposure) - self.exposure) * self._a, float(exposure)
        return out

    def holds(self, d: np.ndarray, profile) -> bool:
        """Whether the polynomials give the pixels at thicknesses ``d`` (P,) with the
        drainage profile ``profile`` (the rear film reads it): made at that profile, and
        every ``d`` within its pixel's window."""
        d = np.asarray(d, np.float64)
        return (d.shape == self.lo.shape and np.array_equal(self.profile, np.asarray(profile))
                and bool(np.all((d >= self.lo) & (d <= self.hi))))

    def _chebyshev(self, d: np.ndarray):
        """``(T, U)``: lists of the Chebyshev polynomials ``T_k`` and ``U_(k-1)`` (P, 1) at
        ``d`` (P,) mapped onto [-1, 1] from each pixel's window, ``k`` up to the degree
        (``U_(-1) = 0``; ``T_k' = k U_(k-1)``)."""
        t = np.clip((np.asarray(d, np.float64) - self._mid) / self._half, -1.0, 1.0)[:, None]
        T, U = [np.ones_like(t), t], [np.zeros_like(t), np.ones_like(t)]
        for _ in range(2, self._c.shape[0]):
            T.append(2.0 * t * T[-1] - T[-2])
            U.append(2.0 * t * U[-1] - U[-2])
        return T, U

    def colours(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(colour, derivative)`` (P, 3) each: the pixels' colours at thicknesses ``d`` (P,)
        within their windows and their derivatives in the thickness (per nm)."""
        T, U = self._chebyshev(d)
        f = sum(c * tk for c, tk in zip(self._c, T))
        g = sum(k * c * uk for k, (c, uk) in enumerate(zip(self._c, U)))
        return f, g / self._half[:, None]

    def pixels(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(img, column)`` of :meth:`TracedCosts.pixels` at thicknesses ``d`` (P,) within the
        windows: the pixels and their derivative in the exposure."""
        T, _ = self._chebyshev(d)
        return sum(c * tk for c, tk in zip(self._c, T)), sum(a * tk for a, tk in zip(self._a, T))

    def slopes(self, d: np.ndarray):
        """:meth:`TracedCosts.slopes` from the polynomials: ``(r, j)``, (P, 3) each, the
        weighted residual at thicknesses ``d`` (P,) within the windows and its derivative in
        each pixel's own thickness."""
        f, g = self.colours(d)
        return self.w * (f - self.y), self.w * g


class WindowCosts:
    """:class:`TracedCosts`' per-pixel data chi^2, the candidates within each pixel's window
    ``[lo, hi]`` (P,) read from the window's polynomials (:class:`WindowPolynomials`:
    :data:`WINDOW_NODES` shadings of the film's optics, however many candidates the window
    holds), the others shaded (candidates outside a window, and :meth:`at`)."""

    def __init__(self, costs: TracedCosts, lo: np.ndarray, hi: np.ndarray):
        self.costs, self.polynomials = costs, costs.window_polynomials(lo, hi)

    def __call__(self, d: np.ndarray) -> np.ndarray:
        """(G, P) chi^2 of candidate thicknesses ``d`` (G, P)."""
        d = np.maximum(np.asarray(d, np.float64), 0.0)
        poly = self.polynomials
        if not np.all((d >= poly.lo) & (d <= poly.hi)):
            return self.costs(d)
        return np.stack([np.sum(poly.slopes(row)[0] ** 2, axis=1) for row in d])

    def at(self, d: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """:meth:`TracedCosts.at`."""
        return self.costs.at(d, cols)


#: Most Gauss-Newton steps of :func:`refine` (each one forward-mode pass over the level).
REFINE_STEPS = 8
#: Stop when the pixels' step, at the quantile :data:`REFINE_QUANTILE` of its size, is
#: below this (nm): a tenth of the map's finest grid step.
REFINE_TOL_NM = 0.2
#: The quantile of the pixels' step sizes that :data:`REFINE_TOL_NM` bounds. A held frame of
#: ``experiments/bench_sequence_maps.py`` (96 px, 4160 pixels) has 99 % of its pixels within
#: 0.2 nm after 2-5 steps, while 1-15 pixels whose Gauss-Newton curvature overstates their
#: energy's creep on by 0.5-2.4 nm a step, a few per cent less each step (up to 1.8 nm at
#: the 30th): a stop on the largest step spent every frame's step limit on them
#: (``docs/speed.md``).
REFINE_QUANTILE = 0.99


def _step_size(delta: np.ndarray) -> float:
    """The size of a step of :func:`refine` (nm): the quantile :data:`REFINE_QUANTILE` of the
    pixels' ``|delta|`` (0 with no pixels)."""
    return float(np.quantile(np.abs(delta), REFINE_QUANTILE)) if delta.size else 0.0


def _laplacian(x, nb, has):
    """``(L x)_p = sum over p's neighbours q of (x_p - x_q)`` (the 4-neighbour graph Laplacian)."""
    return jnp.sum(jnp.where(has, x[:, None] - x[jnp.where(has, nb, 0)], 0.0), axis=1)


@jax.jit
def _damped_step(g, hdiag, nb, lam, inv_s2):
    """The step ``delta`` of ``(D + 2 L / s^2 + lam diag) delta = -g`` by preconditioned
    conjugate gradients: ``D`` the data's diagonal Gauss-Newton curvature, ``L`` the
    smoothness prior's sparse Laplacian (a matrix-free operator: never a dense matrix)."""
    has = nb >= 0
    diag = hdiag + 2.0 * inv_s2 * jnp.sum(has, axis=1)
    op = lambda x: hdiag * x + 2.0 * inv_s2 * _laplacian(x, nb, has) + lam * diag * x
    delta, _ = jax.scipy.sparse.linalg.cg(op, -g, M=lambda x: x / ((1.0 + lam) * diag), tol=1e-4, maxiter=200)
    return delta


def _secant_curvature(d, d2, g, g2, hgn):
    """Each pixel's curvature of its data chi^2 along its last accepted step, ``(g2 - g) /
    (d2 - d)`` (the secant in one variable, Dennis and Schnabel 1983, 2.6: each pixel's
    chi^2 depends on its own thickness only, so the secant of its gradient ``g = 2 r.j`` is
    that pixel's own curvature), where the step moved the pixel by at least
    :data:`SECANT_MIN_NM` and the secant is positive; at least a quarter of the Gauss-Newton
    curvature ``hgn`` (``2 J^T J``); NaN elsewhere (Gauss-Newton's is taken there)."""
    s = d2 - d
    ok = np.abs(s) >= SECANT_MIN_NM
    c = np.where(ok, (g2 - g) / np.where(ok, s, 1.0), np.nan)
    return np.where(ok & (c > 0), np.maximum(c, 0.25 * hgn), np.nan)


#: Least step of a pixel (nm) whose secant gives its curvature (:func:`_secant_curvature`):
#: the float32 gradient's rounding (~1e-6 of chi^2 ~ 1e1 per pixel) over 0.01 nm is ~1e-3 of
#: a pixel's curvature (~0.1 per nm^2).
SECANT_MIN_NM = 0.01


def refine(costs, centre: np.ndarray, nb: np.ndarray, s: float, half: float, *,
           steps: int = REFINE_STEPS, stop: bool = True, observe=None, bounds: tuple | None = None):
    """Per-pixel Newton (Levenberg-Marquardt damped) on the map's energy from ``centre`` (P,).

    The energy is the data chi^2 of every pixel plus ``sum over neighbour pairs ((d_p -
    d_q) / s)^2`` (the smoothness prior of :mod:`._maps`' iterated conditional modes,
    summed once per pair). Its Hessian is the data's diagonal (each pixel's thickness moves
    its own pixel only: :meth:`TracedCosts.slopes`) plus the prior's sparse Laplacian,
    solved by conjugate gradients; thicknesses stay within ``half`` of ``centre``, so that
    the interference order the coarser levels settled is kept. The data's diagonal is
    Gauss-Newton's ``2 J^T J`` on the first step; after an accepted step it is each pixel's
    secant curvature along that step (:func:`_secant_curvature`, which includes the
    residual's own curvature that Gauss-Newton leaves out, so the pixels whose ``2 J^T J``
    overstates their energy's curvature take their full step), Gauss-Newton's where the
    secant is not defined. A rejected step taken with secant curvatures is tried again with
    Gauss-Newton's. It stops at an accepted step that moves the pixels, at the quantile
    :data:`REFINE_QUANTILE` of their step sizes, by less than :data:`REFINE_TOL_NM`, and at a
    rejected Gauss-Newton one whose next damping would change their steps (at that quantile)
    by less than that (the next trial would repeat it).

    ``costs`` gives the residuals and their diagonal Jacobian at any thicknesses of the
    window (``slopes(d)``): a :class:`TracedCosts` (a forward-mode pass of the film's optics
    a call) or its :class:`WindowPolynomials` over the window (:func:`window`; what
    :func:`~bubblefit.inverse._maps.fit_map` passes).
    ``steps``: most trial steps; ``stop=False`` runs them all (no stopping test);
    ``observe(d, trial, hdiag, lam, e, e2)``, if given, sees every trial (the point, the
    trial point, the curvature's diagonal, the damping, the energies at both), as
    ``experiments/refine_steps.py`` records them. ``bounds``: ``(lo, hi)`` (P,) the
    thicknesses stay within instead of ``half`` of ``centre``.

    Returns ``(map (P,), stderr (P,), data chi^2 (P,))``; the standard error from the
    Gauss-Newton curvature of each pixel's energy with its neighbours held, ``E'' = 2 /
    sigma^2``, as the grid's parabola gives it.

    References
    ----------
    K. Levenberg, Q. Appl. Math. 2, 164 (1944); D. Marquardt, J. SIAM 11, 431 (1963);
    M. Hestenes and E. Stiefel, J. Res. NBS 49, 409 (1952) (conjugate gradients);
    J. E. Dennis and R. B. Schnabel, Numerical Methods for Unconstrained Optimization and
    Nonlinear Equations (1983), 2.6 (the secant method).
    """
    inv_s2 = 1.0 / float(s) ** 2
    nbj = jnp.asarray(nb, jnp.int32)
    has = nb >= 0

    def energy(d, r):
        dn = np.where(has, d[np.where(has, nb, 0)], d[:, None])
        return float(np.sum(r * r) + 0.5 * inv_s2 * np.sum((d[:, None] - dn) ** 2))

    lo, hi = window(centre, half) if bounds is None else bounds
    d = centre.astype(np.float64)
    r, j = costs.slopes(d)
    e = energy(d, r)
    # each pixel's data gradient 2 r.j and Gauss-Newton curvature 2 j.j
    data_terms = lambda r, j: (2.0 * np.sum(r * j, axis=1), 2.0 * np.sum(j * j, axis=1))
    gdata, hgn = data_terms(r, j)
    secant = None  # each pixel's curvature along the last accepted step (NaN: Gauss-Newton's)
    lam = 1e-3
    for _ in range(steps):
        g = gdata + 2.0 * inv_s2 * np.asarray(_laplacian(jnp.asarray(d), nbj, jnp.asarray(has)))
        hdiag = hgn if secant is None else np.where(np.isfinite(secant), secant, hgn)
        delta = np.asarray(_damped_step(jnp.asarray(g, jnp.float32), jnp.asarray(hdiag, jnp.float32), nbj,
                                        jnp.float32(lam), jnp.float32(inv_s2)), np.float64)
        trial = np.clip(d + delta, lo, hi)
        r2, j2 = costs.slopes(trial)
        e2 = energy(trial, r2)
        if observe is not None:
            observe(d, trial, hdiag, lam, e, e2)
        if e2 <= e:
            moved = _step_size(trial - d)
            g2, h2 = data_terms(r2, j2)
            secant = _secant_curvature(d, trial, gdata, g2, h2)
            d, r, j, e, gdata, hgn, lam = trial, r2, j2, e2, g2, h2, max(lam / 3.0, 1e-6)
            if stop and moved < REFINE_TOL_NM:
                break
        elif secant is not None:
            secant = None  # the secant's step is tried again with Gauss-Newton's curvature
        else:
            # Raised fourfold, the damping scales each pixel's step by about
            # (1 + lam) / (1 + 4 lam) (its curvature's diagonal dominating): while that changes
            # the steps by less than REFINE_TOL_NM, the next trial repeats the rejected one
            # and is rejected again, so the solve stops at its last accepted point
            if stop and _step_size(delta) * 3.0 * lam / (1.0 + 4.0 * lam) < REFINE_TOL_NM:
                break
            lam *= 4.0
    cnt = has.sum(axis=1)
    curv = 0.5 * hgn + cnt * inv_s2  # E''/2 of each pixel, neighbours held
    err = np.where(curv > 0, 1.0 / np.sqrt(np.where(curv > 0, curv, 1.0)), np.nan)
    return d, err, np.sum(r * r, axis=1)
