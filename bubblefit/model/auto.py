"""``auto`` pixel by pixel: the cheapest choice of each effect that meets each pixel's budget.

A scene's ``[effects] tolerance`` (default :data:`DEFAULT_TOLERANCE`, 1%) is relative to
what each pixel shows: a skipped or cheapened effect may change a pixel by ``tolerance``
times its own radiance plus ``tolerance x`` :data:`~bubblefit.model.footprint.FLOOR_FRACTION`
times the bubble's bright level (:func:`~bubblefit.model.footprint.pixel_budget`). The
budget is shared between the decisions (:data:`SHARES`), so that their errors together stay
within it.

Every error here is per pixel: the film coefficients of a candidate and of the converged
reference (:class:`~bubblefit.model.bounds.FilmTable`, on the scene's thickness x
incidence grid, taken at the grid cells around each pixel's thickness and cosine) times
the radiance each film of that pixel reflects (:class:`~bubblefit.model.footprint.Footprint`),
with a margin :data:`MARGIN` for the estimate of that radiance. So a sun costs accuracy
only in the pixels whose reflection or lobe reaches it.

Regions: where the mirror lookup is within budget except in a few pixels (a sun's glint),
those pixels form a second region rendered with the filtered lookup, and every other
decision is then taken per region (:class:`Plan`). Each choice is the cheapest, by
:func:`spectral_cost`, among every method whose error meets the budget in its region.

References:
    ``docs/design.md``, "Effects and auto".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..lighting.filtering import FilterConfig
from ..optics.spectral import FOURIER_LOBES, REFERENCE_SAMPLES, SpectralBasis, spectral_basis
from .bounds import MAX_BOUNCES, FilmTable, SceneBounds
from .effects import (ALL_ON_NODES, SPECTRAL_CANDIDATES, Decision, Effects, as_switch, decide_spectral,
                      decide_tint, model_settings, source_decisions)
from .footprint import FILTER_CANDIDATES, FLOOR_FRACTION, REFERENCE_FILTER, Footprint, filter_key, pixel_budget
from .modes import COLOURED, GREY, INTERFERENCE_MODES, Model, ThicknessKind

__all__ = ["Plan", "decide_pixels", "spectral_cost", "DEFAULT_TOLERANCE", "SHARES", "MARGIN", "HOT_FRACTION",
           "TAIL_FRACTION"]

#: Default ``[effects] tolerance``: 1% of each pixel's radiance (plus the floor).
DEFAULT_TOLERANCE = 0.01
#: Share of each pixel's budget given to each decision (they sum to 1).
SHARES = {"film": 0.5, "filtering": 0.25, "bounces": 0.15, "terms": 0.1}
#: Factor on the per-pixel errors (the film coefficients are already the largest over the
#: grid cells around each pixel, and the radiances are the all-on filter's own).
MARGIN = 1.0
#: Largest fraction of the bubble's pixels rendered as a second, filtered region.
HOT_FRACTION = 0.25
#: Largest fraction (and at least :data:`TAIL_MIN_PIXELS` pixels) of the bubble rendered as a
#: third region, the pixels of the second that need costlier choices still.
TAIL_FRACTION = 0.005
TAIL_MIN_PIXELS = 16
#: Cost of one ``fourier`` sample relative to one point sample (the filtered film
#: functions carry their harmonics): paper's eq. (10) factor, and the Airy sum.
FOURIER_COST = {"paper": 1.5, "physical": 4.0}
#: Cost of one ``harmonic`` sample relative to one point sample (its per-pixel weights).
HARMONIC_COST = 1.25
#: Phase sample counts of the ``harmonic`` basis ``auto`` tries.
HARMONIC_CANDIDATES = (4, 6, 8, 12, 16, 24, 32, 48, 64)


def spectral_cost(basis: SpectralBasis, model: Model) -> float:
    """Relative cost of a spectral basis: its samples, times :data:`FOURIER_COST` for
    ``fourier`` and :data:`HARMONIC_COST` for ``harmonic``."""
    if basis.phases is not None:
        return basis.samples * HARMONIC_COST
    return basis.samples * (FOURIER_COST[model] if basis.sigma is not None else 1.0)


def spectral_candidates(model: Model, harmonic: bool = False) -> list[SpectralBasis]:
    """Every spectral method ``auto`` may take, cheapest first: uniform, fourier and, where
    the film has one thickness and a non-dispersive index (``harmonic``), the phase samples."""
    cands = [spectral_basis("uniform", k) for k in SPECTRAL_CANDIDATES]
    cands += [spectral_basis("fourier", k) for k in sorted(FOURIER_LOBES)]
    if harmonic:
        cands += [spectral_basis("harmonic", k) for k in HARMONIC_CANDIDATES]
    return sorted(cands, key=lambda b: spectral_cost(b, model))


@dataclass(frozen=True)
class Plan:
    """The static effects of each region of the image: ``parts`` pairs an :class:`Effects`
    with the flat pixel indices it renders (None: every pixel not in another part)."""

    parts: tuple


class _Cells:
    """Grid cells around each pixel's (thickness, cosine), per film: the front (0), the
    rear (1) and, for ``physical``, each internal bounce (k >= 1)."""

    def __init__(self, b: SceneBounds, fp: Footprint):
        n = b.n_film
        cos_t = lambda c: np.sqrt(np.maximum(0.0, 1.0 - (1.0 - np.asarray(c) ** 2) / n**2))
        xg = b.d_grid[:, 0] * 2 * n * cos_t(b.c_grid[0])
        self.jc = np.searchsorted(b.c_grid, fp.cos)  # cells jc - 1 and jc, those that exist
        self.varies = bool(np.ptp(np.concatenate([fp.d0, fp.d1])) > 0) if fp.count else False
        path = lambda d: 2 * n * d * cos_t(fp.cos)  # eq. (8)'s optical path x
        self.ix = [np.searchsorted(xg, path(d)) for d in (fp.d0, fp.d1)]
        # With a thickness field, the term of film k >= 1 reads the film at every point its
        # light met (d0, d1, then dq[:k] for the bounces), and a product of films of
        # different thickness oscillates with the sums of their paths: its rows run from
        # the smallest path to the sum of the two largest (a grid that reaches that far,
        # :func:`~bubblefit.model.bounds.film_grids`).
        # Flat positions in the (D + 1) x (C + 1) cells of _pair_max: one take per read.
        self.flat = [ix * (b.c_grid.size + 1) + self.jc for ix in self.ix]
        xs = [path(fp.d0), path(fp.d1)]
        self.rows = [(self.ix[0], self.ix[0])]
        for k in range(len(fp.dq) + 1 if self.varies else 1):
            if k:
                xs.append(path(fp.dq[k - 1]))
            top2 = np.sort(np.stack(xs), axis=0)[-2:].sum(axis=0) if b.model == "physical" else np.max(xs, axis=0)
            self.rows.append((np.searchsorted(xg, np.min(xs, axis=0)), np.searchsorted(xg, top2)))

    def at(self, arr, film: int) -> np.ndarray:
        """Largest value (N, 3) of a (D, C, 3) grid array over the cells around each pixel's
        film ``film`` (with a thickness field, over every row its light's path crosses)."""
        arr = np.asarray(arr)
        if film == 0 or not self.varies:
            q = _pair_max(arr)
            return np.take(q.reshape((-1,) + q.shape[2:]), self.flat[min(film, 1)], axis=0)
        lo, hi = self.rows[min(film + 1, len(self.rows) - 1)]  # bounce k: d0, d1 and dq[:k]
        return _range_max(_pair_max(arr), lo, hi, self.jc)


def _range_max(q: np.ndarray, lo: np.ndarray, hi: np.ndarray, col: np.ndarray) -> np.ndarray:
    """``max(q[lo:hi + 1, col])`` per pixel, (N, ...), from a sparse table over the rows of
    ``q`` (R, C, ...): ``log2 R`` levels of maxima over ``2^l`` rows, two reads per pixel."""
    levels = [q]
    while 2 ** len(levels) <= q.shape[0]:
        prev, w = levels[-1], 2 ** (len(levels) - 1)
        levels.append(np.maximum(prev[:-w], prev[w:]))
    span = hi - lo + 1
    lev = np.floor(np.log2(np.maximum(span, 1))).astype(int)
    out = np.full((lo.size,) + q.shape[2:], -np.inf)
    for l in np.unique(lev):
        m = lev == l
        t, w = levels[l], 2 ** l
        out[m] = np.maximum(t[lo[m], col[m]], t[hi[m] - w + 1, col[m]])
    return out


def _pair_max(arr: np.ndarray) -> np.ndarray:
    """``q[u, v]``: the largest of ``arr`` (D, C, ...) over rows ``u - 1, u`` and columns
    ``v - 1, v`` that exist, shape (D + 1, C + 1, ...). Indexed by ``searchsorted``
    positions it is the largest over the cells around each pixel in one gather."""
    pad = np.full((arr.shape[0] + 2, arr.shape[1] + 2) + arr.shape[2:], -np.inf)
    pad[1:-1, 1:-1] = arr
    rows = np.maximum(pad[:-1], pad[1:])
    return np.maximum(rows[:, :-1], rows[:, 1:])


class _Pixels:
    """Per-pixel errors of film coefficient sets, for one scene (see the module docstring)."""

    def __init__(self, b: SceneBounds, fp: Footprint, table: FilmTable, tolerance: float):
        self.b, self.fp, self.table, self.cells = b, fp, table, _Cells(b, fp)
        rs, rd = max(b.r_s, 0.0), max(b.r_d, 0.0)
        spec_scale = rs if b.model == "paper" else 1.0
        ref_spec = fp.spec[filter_key(REFERENCE_FILTER)]
        w = spec_scale * ref_spec
        w[: min(2, len(fp.films))] += rd * fp.irr[: min(2, len(fp.films))] / math.pi
        self.w = w  # (F, N, 3): radiance the film coefficients multiply (the all-on filter's own)
        self.spec_scale = spec_scale
        ref = table("airy" if b.model == "physical" else "two_beam", spectral_basis("reference"))
        self.estimate = self.image(ref)
        self.budget = pixel_budget(self.estimate, tolerance)
        self.bright = float(np.percentile(np.max(self.estimate, axis=-1), 99.0)) if fp.count else 0.0

    def terms(self, c: dict, grid_abs=False) -> list[np.ndarray]:
        """Per-term contributions (N, 3) of a coefficient set: front, each rear bounce, background."""
        fix = np.abs if grid_abs else (lambda x: x)
        out = [self.cells.at(fix(c["front"]), 0) * self.w[0]]
        for k, ck in enumerate(c["rear"][: len(self.fp.films) - 1]):
            out.append(self.cells.at(fix(ck), k + 1) * self.w[k + 1])
        bg = np.maximum(self.cells.at(fix(c["background"]), 0), self.cells.at(fix(c["background"]), 1))
        out.append(bg * self.fp.bg)
        return out

    def image(self, c: dict) -> np.ndarray:
        return sum(self.terms(c))

    def error(self, c: dict, ref: dict) -> np.ndarray:
        """Bound (N,) of the change from ``ref`` to ``c``: ``MARGIN`` x largest channel of
        ``sum_terms |C_c - C_ref| W``."""
        diff = {"front": np.abs(c["front"] - ref["front"]),
                "background": np.abs(c["background"] - ref["background"]),
                "rear": [np.abs((c["rear"][k] if k < len(c["rear"]) else 0.0) - ref["rear"][k])
                         for k in range(len(ref["rear"]))]}
        return MARGIN * np.max(sum(self.terms(diff)), axis=-1)

    def used(self, err: np.ndarray, share: str, mask=None) -> float:
        """Largest ``err / (share x budget)`` over the pixels of ``mask``: <= 1 meets the budget."""
        ratio = err / np.maximum(SHARES[share] * self.budget, 1e-30)
        if mask is not None:
            ratio = ratio[mask]
        return float(ratio.max()) if ratio.size else 0.0


def _memo(fn):
    """``fn`` of one hashable argument, computed once per argument (each candidate's
    per-pixel errors are read by the split, the tail and every region's choice)."""
    cache = {}

    def call(arg):
        if arg not in cache:
            cache[arg] = fn(arg)
        return cache[arg]

    return call


def _lookups(conf: FilterConfig) -> int:
    return 1 if conf.method == "mirror" else conf.nodes * conf.nodes


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%"


def _interference(px: _Pixels, setting, tol: float):
    b = px.b
    on_mode = "airy" if b.model == "physical" else "two_beam"
    if setting not in ("auto",) + INTERFERENCE_MODES:
        raise InputError(f"effects.interference must be auto, off, two_beam, airy or incoherent, got {setting!r}")
    if setting != "auto":
        return setting, Decision("interference", setting not in GREY, "set by the scene", setting)
    ref = px.table(on_mode, spectral_basis("reference"))
    used = px.used(px.error(px.table("incoherent"), ref), "film")
    dmin, dmax = b.thickness_range
    if used <= 1.0:
        return "incoherent", Decision("interference", False, f"film {dmin:.0f}-{dmax:.0f} nm: the grey film is within "
                                      f"{_pct(used)} of its budget in every pixel (skips the spectral loop)",
                                      "incoherent")
    return on_mode, Decision("interference", True, f"film {dmin:.0f}-{dmax:.0f} nm keeps colours: grey would use "
                             f"{used:.3g}x its budget", on_mode)


def _filter_error(px: _Pixels, coeffs: dict, conf: FilterConfig) -> np.ndarray:
    """Per-pixel change (N,) from the all-on filter to ``conf``: each film's specular
    coefficient times the difference of the two filtered radiances, both measured in the
    footprint (:data:`~bubblefit.model.footprint.FILTER_CANDIDATES`)."""
    fp = px.fp
    specs = [px.cells.at(coeffs["front"], 0)] + [px.cells.at(c, k + 1)
                                                  for k, c in enumerate(coeffs["rear"][: len(fp.films) - 1])]
    diff = np.abs(fp.spec[filter_key(conf)] - fp.spec[filter_key(REFERENCE_FILTER)])
    return MARGIN * np.max(sum(px.spec_scale * c * diff[f] for f, c in enumerate(specs)), axis=-1)


def _split(px: _Pixels, candidates, errors, share: str, hot: np.ndarray):
    """The cheapest candidate that meets the budget everywhere but in a region of at most
    :data:`HOT_FRACTION` of the bubble's pixels (with those already ``hot``), and that region.
    The last candidate (the reference) always qualifies."""
    last = None
    for cand in candidates:
        over = hot | (errors(cand) > SHARES[share] * px.budget)
        last = cand
        if over.mean() <= HOT_FRACTION if over.size else True:
            return cand, over
    return last, hot


def _tail(px: _Pixels, candidates, errors, share: str, hot: np.ndarray, tail: np.ndarray) -> np.ndarray:
    """``tail`` widened by the pixels of ``hot`` that the cheapest of ``candidates`` meeting
    the budget in all but :data:`TAIL_FRACTION` of the bubble's pixels leaves out: a third
    region, so that a few pixels (the rim, where the film's harmonics grow) do not make the
    whole bright region take the converged choices."""
    limit = max(TAIL_MIN_PIXELS, TAIL_FRACTION * hot.size)
    for cand in candidates:
        over = hot & (errors(cand) > SHARES[share] * px.budget)
        if over.sum() <= limit:
            return tail | over
    return tail


def _first(px: _Pixels, candidates, errors, share: str, mask):
    """The cheapest candidate that meets the budget in every pixel of ``mask``, and the share it uses."""
    cands = list(candidates)
    for cand in cands[:-1]:
        used = px.used(errors(cand), share, mask)
        if used <= 1.0:
            return cand, used
    return cands[-1], px.used(errors(cands[-1]), share, mask)


def _term_skips(px: _Pixels, coeffs: dict, settings: dict, b: SceneBounds) -> tuple[dict, list[Decision]]:
    """Front, rear, transmission and diffuse: ``auto`` skips a term whose whole contribution
    (with the skipped ones before it) stays within the terms' share of every pixel's budget."""
    terms = px.terms(coeffs)
    parts = {"front_reflection": terms[0], "rear_reflection": sum(terms[1:-1], np.zeros_like(terms[0])),
             "transmission": terms[-1]}
    fp = px.fp
    dif = [max(b.r_d, 0.0) * fp.irr[f] / math.pi * px.cells.at(coeffs["front"] if f == 0 else coeffs["rear"][0], f)
           if b.model == "paper" else max(b.r_d, 0.0) * fp.irr[f] / math.pi for f in range(min(2, len(fp.films)))]
    parts["diffuse"] = sum(dif, np.zeros_like(terms[0]))
    spent = np.zeros(fp.count)
    on, out = {}, []
    for name, part in parts.items():
        s = as_switch(settings.get(name, "auto"), name)
        if s != "auto":
            on[name] = bool(s)
            out.append(Decision(name, bool(s), "set by the scene"))
            continue
        if name == "transmission" and b.background == "black":
            on[name] = False
            out.append(Decision(name, False, "black background: nothing to transmit"))
            continue
        if name == "diffuse" and b.r_d <= 0:
            on[name] = False
            out.append(Decision(name, False, "r_d = 0: no irradiance needed"))
            continue
        err = MARGIN * np.max(part, axis=-1)
        used = px.used(spent + err, "terms")
        if used <= 1.0:
            spent = spent + err
            on[name] = False
            out.append(Decision(name, False, f"adds at most {_pct(used)} of the terms' share of any pixel's budget",
                                budget_used=used))
        else:
            on[name] = True
            share = float(np.mean(err > SHARES["terms"] * px.budget)) if fp.count else 0.0
            out.append(Decision(name, True, f"visible in {_pct(share)} of the bubble's pixels (up to {used:.3g}x "
                                f"the terms' share of the budget)"))
    return on, out


def _filter_decision(px: _Pixels, b: SceneBounds, filt, knobs: dict, f_err, masks, where):
    """The filter of each region: ``auto`` takes the cheapest measured within the filtering share."""
    if not b.has_env:
        return [FilterConfig("mirror")], Decision("roughness_filtering", False, "no environment map: nothing to filter")
    if b.roughness <= 0:
        return [FilterConfig("mirror")], Decision("roughness_filtering", False, "roughness = 0: a perfect mirror, "
                                                  "the mirror lookup is exact", "mirror")
    if filt != "auto":
        try:
            conf = FilterConfig(str(filt), **knobs)
        except ValueError as exc:
            raise InputError(f"effects.filtering: {exc}") from None
        return [conf], Decision("roughness_filtering", filt != "mirror", "set by the scene", conf.method)
    picks = [_first(px, FILTER_CANDIDATES, f_err, "filtering", m) for m in masks]
    text = "; ".join(f"{filter_key(c)}{where[i]} uses {_pct(u)} of the filtering share "
                     f"({_lookups(c)} lookups per film instead of {_lookups(REFERENCE_FILTER)})"
                     for i, (c, u) in enumerate(picks))
    return [c for c, _ in picks], Decision("roughness_filtering", any(c.method != "mirror" for c, _ in picks),
                                           f"a = {b.roughness:.2e}: {text}", "+".join(filter_key(c) for c, _ in picks),
                                           budget_used=max(u for _, u in picks))


def _spectral_decision(px: _Pixels, b: SceneBounds, s_err, masks, where, cands):
    """The spectral basis of each region: the cheapest of ``cands`` (every method, the
    reference last) within the film share."""
    picks = [_first(px, cands, s_err, "film", m) for m in masks]
    text = "; ".join(f"{c.method}/{c.samples}{where[i]} uses {_pct(u)} of the film share "
                     f"(cost {spectral_cost(c, b.model):.0f} against {REFERENCE_SAMPLES} for the reference)"
                     for i, (c, u) in enumerate(picks))
    return [c for c, _ in picks], Decision("spectral", True, text, "+".join(f"{c.method}/{c.samples}" for c, _ in picks),
                                           budget_used=max(u for _, u in picks))


def _bounce_decision(px: _Pixels, b: SceneBounds, bset, rear: bool, b_err, masks, where, budget_text: str):
    """Internal bounces of each region: the fewest whose tail stays within the bounces' share."""
    if b.model != "physical":
        return [1] * len(masks), Decision("internal_bounces", False, "paper model: eq. (11) keeps one rear reflection")
    if bset != "auto":
        n = int(bset)
        return [n] * len(masks), Decision("internal_bounces", rear and n > 1, "set by the scene", str(n))
    res = [_first(px, range(1, MAX_BOUNCES + 1), b_err, "bounces", m) for m in masks]
    text = "; ".join((f"{n}{where[i]}: bounces {n + 1}-{MAX_BOUNCES} add {_pct(u)} of their share"
                      if n < MAX_BOUNCES else f"{n}{where[i]}, the all-on count: fewer would miss the budget")
                     for i, (n, u) in enumerate(res))
    return [n for n, _ in res], Decision("internal_bounces", rear and max(n for n, _ in res) > 1,
                                         f"{text} ({budget_text})", "+".join(str(n) for n, _ in res),
                                         budget_used=max(u for _, u in res))


def decide_pixels(b: SceneBounds, fp: Footprint, settings: dict, *, thickness_kind: ThicknessKind,
                  tolerance: float = DEFAULT_TOLERANCE, nodes: int = ALL_ON_NODES,
                  dispersive: bool = False) -> tuple[Plan, list[Decision]]:
    """Every effect of a scene, decided against each pixel's budget (module docstring).

    The ``harmonic`` spectral basis is a candidate for a film of one thickness whose index
    does not disperse (``dispersive`` False), where it is exact.

    The bright region is the union of the pixels that the cheapest filter, spectral basis
    and bounce count meeting the budget in all but :data:`HOT_FRACTION` of the bubble
    leave out (:func:`_split`); each region then takes its own cheapest choices.
    Returns the :class:`Plan` (one or two regions) and one :class:`Decision` per effect.
    """
    tol = float(tolerance)
    fresnel, tint_set, tint_rs, bset = model_settings(b, settings)
    out = [fresnel]
    cands = spectral_candidates(b.model, harmonic=thickness_kind == "constant" and not dispersive)
    table = FilmTable(b, MAX_BOUNCES, tint_rs, [spectral_basis("reference")] + cands)
    px = _Pixels(b, fp, table, tol)
    interference, d = _interference(px, settings.get("interference", "auto"), tol)
    out.append(d)
    if b.model == "physical" and interference == "off":
        interference = "incoherent"
    coloured = interference in COLOURED
    ref_coeffs = table(interference, spectral_basis("reference") if coloured else None)

    filt, spectral_setting = settings.get("filtering", "auto"), settings.get("spectral", "auto")
    f_err = _memo(lambda conf: _filter_error(px, ref_coeffs, conf))
    s_err = _memo(lambda basis: px.error(table(interference, basis), ref_coeffs))
    tails = np.cumsum([np.max(t, axis=-1) for t in px.terms(ref_coeffs)[1:-1]][::-1], axis=0)[::-1]
    b_err = lambda n: MARGIN * tails[n] if n < len(tails) else np.zeros(fp.count)
    hot = np.zeros(fp.count, dtype=bool)
    if b.has_env and b.roughness > 0 and filt == "auto":
        _, hot = _split(px, FILTER_CANDIDATES, f_err, "filtering", hot)
    if coloured and spectral_setting == "auto":
        _, hot = _split(px, cands + [spectral_basis("reference")], s_err, "film", hot)
    if b.model == "physical" and bset == "auto":
        _, hot = _split(px, range(1, MAX_BOUNCES + 1), b_err, "bounces", hot)
    tail = np.zeros(fp.count, dtype=bool)
    if hot.any():
        if b.has_env and b.roughness > 0 and filt == "auto":
            tail = _tail(px, FILTER_CANDIDATES, f_err, "filtering", hot, tail)
        if coloured and spectral_setting == "auto":
            tail = _tail(px, cands, s_err, "film", hot, tail)
        if b.model == "physical" and bset == "auto":
            tail = _tail(px, range(1, MAX_BOUNCES), b_err, "bounces", hot, tail)
    regions = [(~hot, ""), (hot & ~tail, f" in the {int((hot & ~tail).sum())} pixels whose light comes from a "
                                          "bright source"),
               (tail, f" in the {int(tail.sum())} pixels that need more (the rim, the brightest glints)")]
    regions = regions[:1] + [r for r in regions[1:] if r[0].any()]
    masks, where = [m for m, _ in regions], [w for _, w in regions]

    knobs = {k: settings[k] for k in ("nodes", "window", "level") if k in settings}
    fconf, d = _filter_decision(px, b, filt, knobs, f_err, masks, where)
    out.append(d)
    if coloured and spectral_setting == "auto":
        bases, d = _spectral_decision(px, b, s_err, masks, where, cands + [spectral_basis("reference")])
    else:
        basis, d = decide_spectral(b, table, spectral_setting, interference, tol)
        bases = [basis] * len(masks)
    out.append(d)
    on, ds = _term_skips(px, table(interference, bases[0]), settings, b)
    out.extend(ds[:3])
    tint, d = decide_tint(b, tint_set, on["transmission"], interference)
    out.extend([d, ds[3]])
    front, rear, transmission = on["front_reflection"], on["rear_reflection"], on["transmission"]
    out.extend(source_decisions(b, front, rear, transmission, thickness_kind))
    budget_text = f"budget {tol:g} x (pixel + {FLOOR_FRACTION:g} x bright level {px.bright:.3g})"
    bounces, d = _bounce_decision(px, b, bset, rear, b_err, masks, where, budget_text)
    out.append(d)

    parts = []
    for i, mask in enumerate(masks):
        fx = Effects(model=b.model, front_reflection=front, rear_reflection=rear, transmission=transmission,
                     interference=interference, diffuse=on["diffuse"] and (front or rear),
                     environment=b.has_env and (front or rear or b.background == "envmap"),
                     point_lights=b.n_point_lights > 0 and (front or rear), filtering=fconf[min(i, len(fconf) - 1)],
                     spectral=bases[i], bounces=bounces[i], thickness=thickness_kind, background=b.background,
                     tint=tint)
        parts.append((fx, None if i == 0 else fp.pixels[mask]))
    return Plan(tuple(parts)), out
