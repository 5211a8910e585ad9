"""A draining film read in time order: which side of a maximum of ``R`` each reading lies
on, chosen by the series' thinning (a least-cost monotone path over the readings'
candidate thicknesses).

Near the first maximum of the reflectance (a quarter wave, ~100 nm for soap water in the
visible) a film and its twin on the far side of the maximum reflect nearly the same
spectrum: with the lamp known only as well as a few readings pin it, a reading alone may
not tell them apart. A draining film thins: gravity and capillary suction drive the
liquid out of the film, and its thickness does not grow with time (Mysels, Shinoda &
Frankel, *Soap Films*, 1959). Over a series in time order the readings' thicknesses are
then a non-increasing sequence, up to each reading's noise.

Each reading ``i`` offers candidates ``(d_ik, c_ik)``: the local minima of its profile
``chi^2`` within :data:`CANDIDATE_DCHI2` of its best, ``c_ik`` above the best, with its
standard error ``s_i``. A path picks one candidate per reading and costs

    C = sum_i c_{i,k_i} + sum_i max(0, d_{i+1,k_{i+1}} - d_{i,k_i})^2 / (s_i^2 + s_{i+1}^2).

The second sum is the ``chi^2`` of the thickenings the path shows if the film did not
thicken: the difference of two unbiased readings of a film that did not change has the
variance ``s_i^2 + s_{i+1}^2``, and a thinning costs nothing (the film may drain at any
rate). The least-cost path is found exactly by dynamic programming (Viterbi), and the
least cost with reading ``i`` held at candidate ``k`` (the forward and backward costs
added: a max-marginal) says how strongly the series and the reading together prefer one
side: ``Delta C`` of each other candidate. The whole is the likelihood of an isotonic
(monotone) regression over the discrete candidate sets (Barlow, Bartholomew, Bremner &
Brunk, *Statistical Inference under Order Restrictions*, 1972; G. D. Forney, "The Viterbi
algorithm", Proc. IEEE 61, 268-278 (1973)).

The path's thickening cost compares neighbours only; a slow rise over many readings, each
step within the noise, is found by the isotonic regression itself: the weighted
non-increasing least-squares fit of the path's thicknesses (weights ``1 / s_i^2``, the pool
adjacent violators algorithm) pools the readings that rise into blocks of one level. If
the film drained, the readings of a block scatter about its level as their errors say:
``chi^2 = sum (d_i - level)^2 / s_i^2`` is at most a chi-square of ``k - 1`` degrees of
freedom for ``k`` readings (equal when the film stood still, less when it thinned), so a
block with ``P(chi^2_{k-1} > chi^2)`` under :data:`BLOCK_P` did not drain as its readings
say: the film thickened, or some readings lie on the wrong side of a maximum of ``R``
that no candidate offers (a lamp that changed colour since the readings that pinned it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CANDIDATE_DCHI2", "BLOCK_P", "ORDER_REASON", "AMBIGUOUS_REASON", "DrainPath", "SideVerdict",
           "profile_candidates", "drain_path", "candidate_stderr", "isotonic_blocks", "series_sides"]

#: Candidates further than this in ``chi^2`` above a reading's best are left out: a side the
#: reading excludes by ``exp(-50)`` in likelihood (model error is in its ``s^2`` already)
#: is not one the series could choose.
CANDIDATE_DCHI2 = 100.0


#: A block of the isotonic fit whose scatter a draining film's readings reach with less than
#: this probability is not a draining film (see the module): one false alarm in a thousand
#: blocks, while a rise of ~3.3 standard errors between two readings is caught.
BLOCK_P = 1e-3


def isotonic_blocks(thickness: np.ndarray, stderr: np.ndarray) -> list[tuple[int, int, float, float]]:
    """The blocks of the weighted non-increasing least-squares fit of ``thickness`` (weights
    ``1 / stderr^2``; pool adjacent violators, Barlow et al. 1972, ch. 1, as
    :func:`scipy.optimize.isotonic_regression`), as (first index, end index, level,
    ``chi^2`` of the block's readings about its level)."""
    from scipy.optimize import isotonic_regression

    d = np.asarray(thickness, np.float64)
    w = 1.0 / np.maximum(np.asarray(stderr, np.float64), 1e-300) ** 2
    fit = isotonic_regression(d, weights=w, increasing=False)
    edges = list(fit.blocks)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        level = float(fit.x[a])
        out.append((int(a), int(b), level, float(np.sum(w[a:b] * (d[a:b] - level) ** 2))))
    return out


def profile_candidates(minima, step: float, s2: float) -> list[tuple[float, float]]:
    """The distinct minima (more than two grid ``step`` apart, as
    :func:`~bubblefit.inverse._spectrum_profile.second_minimum` separates them) of
    ``minima`` ((thickness, RSS), the best first) within :data:`CANDIDATE_DCHI2`, as
    (thickness, ``chi^2`` above the best in units of ``s2``): a reading's candidates."""
    best = min(r for _, r in minima)
    out: list[tuple[float, float]] = []
    for d, r in sorted(minima, key=lambda t: t[1]):
        dchi2 = float((r - best) / s2) if s2 > 0 else (0.0 if r == best else float("inf"))
        if dchi2 <= CANDIDATE_DCHI2 and all(abs(d - x) > 2.0 * step for x, _ in out):
            out.append((float(d), dchi2))
    return out


@dataclass(frozen=True)
class DrainPath:
    """The least-cost path: for each reading the chosen candidate's index, the least total
    cost with the reading held at each of its candidates (``through``, minus the path's
    cost: 0 at the chosen one), and the thickening cost of the step into each reading
    along the path (0 for the first)."""

    choice: list[int]
    through: list[np.ndarray]
    thickening: np.ndarray
    cost: float


def _step_cost(d_from: np.ndarray, s_from: float, d_to: np.ndarray, s_to: float) -> np.ndarray:
    """(K_from, K_to) ``chi^2`` of the thickening from each candidate to each candidate."""
    rise = np.maximum(d_to[None, :] - d_from[:, None], 0.0)
    return rise**2 / max(s_from**2 + s_to**2, 1e-300)


def drain_path(thickness: list[np.ndarray], chi2: list[np.ndarray], stderr: list[float]) -> DrainPath:
    """The least-cost non-increasing path (see the module) over readings in time order,
    reading ``i`` with candidate thicknesses ``thickness[i]`` (K_i,), their ``chi2[i]``
    above its best, and its standard error ``stderr[i]``."""
    n = len(thickness)
    d = [np.asarray(t, np.float64) for t in thickness]
    c = [np.asarray(x, np.float64) for x in chi2]
    steps = [_step_cost(d[i - 1], stderr[i - 1], d[i], stderr[i]) for i in range(1, n)]
    forward, back = [c[0]], [None]
    for i in range(1, n):
        tot = forward[-1][:, None] + steps[i - 1]
        back.append(np.argmin(tot, axis=0))
        forward.append(c[i] + tot.min(axis=0))
    backward = [np.zeros(len(x)) for x in d]
    for i in range(n - 2, -1, -1):
        backward[i] = np.min(steps[i] + (c[i + 1] + backward[i + 1])[None, :], axis=1)
    cost = float(forward[-1].min())
    choice = [int(np.argmin(forward[-1]))]
    for i in range(n - 1, 0, -1):
        choice.append(int(back[i][choice[-1]]))
    choice.reverse()
    through = [forward[i] + backward[i] - cost for i in range(n)]
    rise = np.zeros(n)
    for i in range(1, n):
        rise[i] = steps[i - 1][choice[i - 1], choice[i]]
    return DrainPath(choice=choice, through=through, thickening=rise, cost=cost)


def candidate_stderr(thickness: np.ndarray, through: np.ndarray, chosen: int, stderr: float) -> float:
    """The standard error of a reading about its chosen candidate, its other candidates
    counted by their weight ``exp(-Delta C / 2)`` (``Delta C`` = ``through``, the least
    path cost with the reading there, above the best): the root mean square of
    ``d - d_chosen`` over the mixture of the candidates, each a normal of deviation
    ``stderr``. A twin the data and the series do not exclude widens the error bar by
    its distance."""
    d = np.asarray(thickness, np.float64)
    w = np.exp(-0.5 * (np.asarray(through, np.float64) - np.min(through)))
    w /= w.sum()
    return float(np.sqrt(stderr**2 + np.sum(w * (d - d[chosen]) ** 2)))


#: The reasons of :mod:`bubblefit.inverse.spectrum` that only say the order (the side of a
#: maximum of ``R``) is open begin so: a reading with no other reason takes part in the path.
ORDER_REASON = "interference order"
#: Of those, the one the path settles (a second minimum within the noise: a candidate);
#: the other (the order depends on the lamp's model) stays.
AMBIGUOUS_REASON = "interference order ambiguous"


@dataclass(frozen=True)
class SideVerdict:
    """What the series' thinning says of one reading: its thickness and standard error
    (the twin's weight included), whether the series moved it from its own best, the
    reasons it is not ok (empty: ok as far as the series goes) and a warning (or "")."""

    index: int
    thickness_nm: float
    stderr_nm: float
    moved: bool
    reasons: list[str]
    warning: str


def series_sides(results, ambiguity_dchi2: float) -> list[SideVerdict]:
    """The side of a maximum of ``R`` of each reading of a draining series in time order
    (see the module), for the readings that take part: those with candidates and a finite
    thickness and error, ok or not ok only because their order is open (:data:`ORDER_REASON`).

    Along the least-cost path (:func:`drain_path`) a reading

    - takes the candidate the path chooses, said in a warning when it is not its own best;
    - is not ok when that candidate lies more than ``ambiguity_dchi2`` above its own best in
      ``chi^2`` (the reading and the series' thinning disagree: the film may have
      thickened, and neither is taken on trust);
    - is not ok when another candidate's least path cost is within ``ambiguity_dchi2`` of
      the path's (neither the reading nor the series tells the sides apart), its error bar
      then covering both (:func:`candidate_stderr`);
    - is not ok when it lies in a block of the path's isotonic fit that a draining film's
      readings would not scatter so (:func:`isotonic_blocks`, :data:`BLOCK_P`): the film
      did not drain as the readings say there, so its thinning cannot choose their sides.
    """
    take = [i for i, r in enumerate(results)
            if r.candidates and np.isfinite(r.thickness_nm) and np.isfinite(r.thickness_nm_stderr)
            and r.thickness_nm_stderr > 0 and all(x.startswith(ORDER_REASON) for x in r.reasons)]
    if len(take) < 2:
        return []
    d = [np.array([c[0] for c in results[i].candidates]) for i in take]
    c = [np.array([c[1] for c in results[i].candidates]) for i in take]
    s = [float(results[i].thickness_nm_stderr) for i in take]
    e = _own_errors([results[i] for i in take])
    # the candidate that is the reading's own result takes its refined thickness
    own = [int(np.argmin(np.abs(x - results[i].thickness_nm))) for x, i in zip(d, take)]
    for x, o, i in zip(d, own, take):
        x[o] = results[i].thickness_nm
    path = drain_path(d, c, e)
    rising = _rising(take, [float(x[k]) for x, k in zip(d, path.choice)], e)
    out = []
    for m, i in enumerate(take):
        r, k, through, o = results[i], path.choice[m], path.through[m], own[m]
        reasons: list[str] = []
        warning = ""
        chosen = float(d[m][k])
        if k != o:
            if c[m][k] - c[m][o] > ambiguity_dchi2:
                reasons.append(f"the reading puts the film at {d[m][o]:.1f} nm, the series' thinning at "
                               f"{chosen:.1f} nm "
                               f"(delta chi2 {c[m][k] - c[m][o]:.1f} for the reading): they disagree (did the film "
                               "thicken?)")
                chosen, k = float(d[m][o]), o
            else:
                warning = (f"read on the side of a maximum of R that the series' thinning says: {chosen:.1f} nm "
                           f"(the reading alone read {d[m][o]:.1f} nm; delta chi2 {c[m][k] - c[m][o]:.1f})")
        others = [j for j in range(len(d[m])) if j != k]
        if others:
            j = min(others, key=lambda t: through[t])
            if through[j] - through[k] < ambiguity_dchi2:
                reasons.append(f"neither the reading nor the series' thinning tells which side of a maximum of R it is "
                               f"on: {d[m][j]:.1f} nm costs delta chi2 {through[j] - through[k]:.1f} "
                               f"(< {ambiguity_dchi2:g}) more than {chosen:.1f} nm")
        if m in rising:
            reasons.append(rising[m])
        out.append(SideVerdict(index=i, thickness_nm=chosen, stderr_nm=candidate_stderr(d[m], through, k, s[m]),
                               moved=k != o, reasons=reasons, warning=warning))
    return out


#: Fewest readings read with the series' lamp whose scatter measures what of the lamp's
#: error is their own (a median of their second differences; five give three).
SCATTER_READINGS = 5


def _own_errors(results) -> list[float]:
    """The error of each reading that is its own, not shared with its neighbours: the
    differences between readings are what the path and the blocks judge.

    A reading read alone has its whole standard error. Readings read with the series'
    shared lamp (:attr:`~bubblefit.inverse.spectrum.SpectrumFit.shared_lamp`) share that
    lamp's error in part: the part that changes from reading to reading (a lamp flickering)
    shows as their scatter from one to the next, the part common to them (the lamp's shape,
    or a slow drift) does not. Their own error is their statistical error or their measured
    scatter, whichever is larger: the robust deviation of their second differences in time
    order, ``1.4826 MAD / sqrt(6)`` (the second difference of independent errors of
    deviation ``sigma`` has the variance ``6 sigma^2``; a curving trend only adds to it).
    With fewer than :data:`SCATTER_READINGS` of them the scatter is not measured and each
    keeps its whole standard error."""
    shared = [k for k, r in enumerate(results) if getattr(r, "shared_lamp", False)]
    out = [float(r.thickness_nm_stderr) for r in results]
    if len(shared) < SCATTER_READINGS:
        return out
    d = np.array([results[k].thickness_nm for k in shared])
    second = np.diff(d, 2)
    scatter = 1.4826 * float(np.median(np.abs(second - np.median(second)))) / np.sqrt(6.0)
    for k in shared:
        stat = float(results[k].stderr_statistical_nm)
        own = max(stat if np.isfinite(stat) else 0.0, scatter)
        if own > 0:
            out[k] = min(own, out[k])
    return out


def _rising(take: list[int], thickness: list[float], stderr: list[float]) -> dict[int, str]:
    """The reason of each path position (index into ``take``) in a block that did not drain
    (:func:`isotonic_blocks`, :data:`BLOCK_P`)."""
    from scipy import stats

    out = {}
    for a, b, level, chi2 in isotonic_blocks(np.array(thickness), np.array(stderr)):
        if b - a < 2:
            continue
        p = float(stats.chi2.sf(chi2, b - a - 1))
        if p < BLOCK_P:
            # the largest rise within the block: from a reading to the highest after it
            rises = [(max(thickness[k:b]) - thickness[k], k) for k in range(a, b)]
            k = max(rises)[1]
            low, top = thickness[k], max(thickness[k:b])
            why = (f"readings {take[a] + 1}-{take[b - 1] + 1} of the series in time order rise from "
                   f"{low:.1f} to {top:.1f} nm where a draining film thins (chi2 {chi2:.0f} "
                   f"for {b - a - 1} degree(s) of freedom about their common level {level:.1f} nm): the film "
                   "thickened, "
                   "or the series' lamp puts these readings on the wrong side of a maximum of R")
            out.update(dict.fromkeys(range(a, b), why))
    return out
