"""Does the photo tell the film's interference order, the camera response's errors allowed?

A film's colours repeat every fringe (about ``lambda / (2 n)`` of thickness), so the
global thickness search (:mod:`bubblefit.inverse.search`) refines several local minima and
keeps the lowest. With a calibrated response that states its errors
(:mod:`bubblefit.inverse.response_error`) the lowest is not the whole answer: a draw of the
response within its errors may explain the photo at the neighbouring order about as well.
This test compares the refined candidates by their chi^2 with the response's errors
marginalised (:func:`~bubblefit.inverse.response_error.marginal_chi2`: one draw of the
response for the whole photo, integrated out under its stated covariance, the parameters
re-solved with it to first order).

The order is *determined* when every neighbouring order's marginal chi^2 exceeds the
best's by more than the chi^2 law's ``1 - alpha`` quantile with one degree of freedom
(``alpha`` = :data:`LEVEL`): the profile likelihood's confidence region for the thickness
at level ``1 - alpha`` is ``{d : chi2(d) - chi2_min <= chi2_1^-1(1 - alpha)}`` (Wilks'
theorem; Press et al., *Numerical Recipes*, 3rd ed., sec. 15.6.5), and a neighbouring
order inside it is a thickness the photo does not exclude. The chi^2 differences are
divided by the best solve's reduced chi^2 where it exceeds 1 (the Birge ratio, as
:mod:`bubblefit.inverse._uncertainty` widens the errors of a fit that does not explain
its photo within its noise).

One test for every fit kind: a candidate's order is set by the parameters
:data:`ORDER_PARAMETERS` name for its thickness model (a constant film's thickness; a
drainage profile's two ends; the contact offset of Newton's rings, whose every ring moves
with it), and two candidates are different orders when any of them differs by more than
:func:`order_separation`. Where the search has no candidate in a neighbouring order (a
profile's searches find one order), :func:`neighbouring_orders` gives the starts one fringe
away: the whole profile shifted, or its thin end alone. A thickness map is fitted after the
profile (bubble fits) or the reference (flat films) that sets its order, and carries that
fit's test. :func:`compare_orders` makes the decision from the candidates' chi^2 values,
however each fit computed them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .colour_check import FALSE_ALARM

__all__ = ["OrderCheck", "order_check", "compare_orders", "neighbouring_orders", "order_parameters",
           "order_threshold", "order_separation", "ORDER_PARAMETERS", "LEVEL"]

#: ``alpha``: the chance that the neighbouring order of a film whose order the photo does
#: determine is called admitted (the colour check's false-alarm rate,
#: :data:`~bubblefit.inverse.colour_check.FALSE_ALARM`).
LEVEL = FALSE_ALARM


def order_threshold(level: float = LEVEL) -> float:
    """The chi^2 difference below which a neighbouring order is admitted: the chi^2 law's
    upper ``level`` quantile with one degree of freedom (10.83 for 1e-3; module docstring)."""
    from scipy.special import chdtri

    return float(chdtri(1, level))


def order_separation(n_film: float) -> float:
    """Thickness (nm) beyond which two refined candidates are different orders: half a
    fringe, ``lambda_c / (4 n)`` at the centre ``lambda_c`` of the spectral band
    (:data:`~bubblefit.optics.spectral.LAMBDA_MIN` to ``LAMBDA_MAX``), where eq. (8)'s
    phase ``4 pi n d / lambda`` changes by ``pi``; two minima of the search's cost a fringe
    apart are about twice this apart."""
    from ..optics.spectral import LAMBDA_MAX, LAMBDA_MIN

    return 0.5 * (LAMBDA_MIN + LAMBDA_MAX) / (4.0 * float(n_film))


#: The parameters that set a candidate's interference order, per thickness model: a constant
#: film's thickness, a drainage profile's ends (:func:`bubblefit.model.thickness.drainage_profile`;
#: a bubble's map is fitted after its profile), the contact offset of Newton's rings
#: (:func:`bubblefit.inverse._newton.newton_gap`).
ORDER_PARAMETERS = {"constant": ("thickness_nm",), "drainage": ("top_nm", "bottom_nm"), "map": ("top_nm", "bottom_nm"),
                    "newton": ("contact_offset_nm",)}


def order_parameters(thickness_model: str) -> tuple[str, ...] | None:
    """The names of :data:`ORDER_PARAMETERS` for a thickness model, or None."""
    return ORDER_PARAMETERS.get(thickness_model)


def neighbouring_orders(values: dict, names: tuple, n_film: float, lo: float, hi: float) -> list[dict]:
    """Starts one fringe (``2 order_separation(n_film)``: eq. (8)'s phase changes by
    ``2 pi``) from ``values`` in each direction, within the searched range ``[lo, hi]``
    (nm): a constant film's thickness or a Newton lens's contact offset moved; a drainage
    profile moved whole (both ends) and at its thin end alone (the order the colours of
    the thin end set; the thick end's colours are paler). Each a copy of ``values``."""
    if not names or not all(n in values for n in names):
        return []
    fringe = 2.0 * order_separation(n_film)
    moves = [names]
    if len(names) == 2:
        moves.append((min(names, key=lambda n: values[n]),))
    out = []
    for step in (-fringe, fringe):
        for moved in moves:
            new = dict(values, **{n: float(values[n]) + step for n in moved})
            if all(lo <= new[n] <= hi for n in moved):
                out.append(new)
    return out


def _distance(a, b) -> float:
    """The largest difference (nm) between two candidates' order parameters."""
    return float(np.max(np.abs(np.atleast_1d(np.asarray(a, np.float64)) - np.atleast_1d(np.asarray(b, np.float64)))))


def _nm(x) -> str:
    """A candidate's order parameters in words."""
    x = np.atleast_1d(np.asarray(x, np.float64))
    if x.size == 2:
        return f"the profile from {x[0]:.0f} nm (top) to {x[1]:.0f} nm (bottom)"
    return f"{x[0]:.0f} nm"


@dataclass(frozen=True)
class OrderCheck:
    """The outcome of :func:`compare_orders`: the best candidate's order parameters
    (:data:`ORDER_PARAMETERS`: a float for one, a tuple for a profile's two ends) and the
    neighbouring order's nearest in marginal chi^2, their chi^2 differences (plain and
    with the response marginalised, both over the Birge ratio ``scale``) and the threshold."""

    determined: bool
    thickness_nm: float | tuple
    alternative_nm: float | tuple | None
    delta_chi2: float | None          # marginal, over ``scale``
    delta_chi2_plain: float | None    # the response taken as exact, over ``scale``
    threshold: float
    scale: float
    candidates: int
    #: every candidate's ``(order parameters, chi^2 taken as exact, marginal chi^2)``, unscaled
    scored: tuple = ()
    #: the names of the order parameters (:data:`ORDER_PARAMETERS`)
    parameters: tuple = ("thickness_nm",)

    def warning(self) -> str | None:
        """One line for the fit's warnings when the neighbouring order is admitted."""
        if self.determined or self.alternative_nm is None:
            return None
        if self.delta_chi2 < 0:
            how = (f"which explains the photo better (its chi^2 with the response's errors marginalised is "
                   f"{-self.delta_chi2:.3g} below this order's; without them {self.delta_chi2_plain:+.3g})")
        else:
            how = (f"(its chi^2 with the response's errors marginalised is {self.delta_chi2:.3g} above the best's, "
                   f"under the {self.threshold:.3g} that excludes it at level {LEVEL:g}; without them "
                   f"{self.delta_chi2_plain:.3g})")
        return (f"the response's uncertainty admits the neighbouring order at {_nm(self.alternative_nm)} {how}: "
                "the thickness's order is not determined; calibrate the camera from a film of known thickness "
                "(docs/cameras.md)")

    def at(self, thickness_nm, n_film: float) -> "OrderCheck":
        """The test seen from the candidate in the order of ``thickness_nm`` (the fit's final
        order parameters, which a warm start or the final solve may have left in another
        order than the search's best): unchanged when that is the best's order or no
        candidate's; otherwise not determined, the best's order the alternative (a
        negative difference)."""
        sep = order_separation(n_film)
        if _distance(thickness_nm, self.thickness_nm) <= sep:
            return self
        near = [c for c in self.scored if _distance(c[0], thickness_nm) <= sep]
        best = [c for c in self.scored if _distance(c[0], self.thickness_nm) <= sep]
        if not near or not best:
            return self
        own, top = near[0], best[0]
        return replace(self, determined=False, thickness_nm=own[0], alternative_nm=top[0],
                       delta_chi2=float((top[2] - own[2]) / self.scale),
                       delta_chi2_plain=float((top[1] - own[1]) / self.scale))

    def to_json(self) -> dict:
        """The record of the fit's JSON (``order_check``)."""
        listed = lambda x: list(x) if isinstance(x, tuple) else x  # noqa: E731
        return {"determined": self.determined, "parameters": list(self.parameters),
                "thickness_nm": listed(self.thickness_nm), "alternative_nm": listed(self.alternative_nm),
                "delta_chi2": self.delta_chi2, "delta_chi2_plain": self.delta_chi2_plain, "threshold": self.threshold,
                "level": LEVEL, "birge_scale": self.scale, "candidates": self.candidates}


def compare_orders(scored: list, n_film: float, n_values: int, n_params: int,
                   parameters: tuple = ("thickness_nm",)) -> OrderCheck | None:
    """The decision of the module docstring from the candidates ``scored``, each
    ``(order parameters, chi^2 taken as exact, marginal chi^2, chi^2)`` (the last the
    solve's own cost, which picks the best): the neighbouring order with the least
    marginal chi^2 against the best, the differences over the best's Birge ratio
    (``n_values`` fitted values less ``n_params`` parameters). None without candidates."""
    if not scored:
        return None
    shaped = [((float(s[0]) if np.ndim(s[0]) == 0 else tuple(float(x) for x in s[0])), *s[1:]) for s in scored]
    best = min(shaped, key=lambda s: s[3])
    dof = max(int(n_values) - int(n_params), 1)
    scale = max(1.0, best[3] / dof)
    others = [s for s in shaped if _distance(s[0], best[0]) > order_separation(n_film)]
    thr = order_threshold()
    kept = tuple((s[0], s[1], s[2]) for s in shaped)
    if not others:
        return OrderCheck(True, best[0], None, None, None, thr, scale, len(shaped), kept, tuple(parameters))
    alt = min(others, key=lambda s: s[2])
    delta = (alt[2] - best[2]) / scale
    return OrderCheck(bool(delta > thr), best[0], alt[0], float(delta), float((alt[1] - best[1]) / scale), thr, scale,
                      len(shaped), kept, tuple(parameters))


def order_check(err, lev, solutions: list, robust_scale: float, n_params: int,
                thickness_model: str = "constant") -> OrderCheck | None:
    """Compare the refined candidates ``solutions`` (:class:`~bubblefit.inverse._local.LocalSolution`
    of a constant film or a drainage profile on the search level ``lev``) by their chi^2
    with the response's errors ``err`` (:class:`~bubblefit.inverse.response_error.ResponseError`)
    marginalised (module docstring), and taken as exact (the chi^2 less the Gauss-Newton
    decrement over the parameters alone: both to first order from where the search's short
    solves stopped), by :func:`compare_orders`. The best is the lowest chi^2 (the search's
    winner). ``n_params``: the solve's free parameters (for the reduced chi^2);
    ``thickness_model``: the solves' (:data:`ORDER_PARAMETERS`). None when the response
    states no errors or no candidate has order parameters."""
    from .response_error import solve_marginal_chi2

    if err is None:
        return None
    names = order_parameters(thickness_model)
    scored = []
    for sol in solutions:
        if names is None or not all(n in sol.values for n in names) or not np.isfinite(sol.cost):
            continue
        got = solve_marginal_chi2(err, lev, sol, robust_scale, thickness_model)
        plain = solve_marginal_chi2(None, lev, sol, robust_scale, thickness_model)
        if got is not None and all(np.isfinite(got)) and np.isfinite(plain[1]):
            key = tuple(float(sol.values[n]) for n in names)
            scored.append((key[0] if len(key) == 1 else key, plain[1], got[1], got[0]))
    if not scored:
        return None
    return compare_orders(scored, err.n_film, int(np.count_nonzero(lev.w)), n_params, names)
