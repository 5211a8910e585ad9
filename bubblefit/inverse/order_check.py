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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .colour_check import FALSE_ALARM

__all__ = ["OrderCheck", "order_check", "order_threshold", "order_separation", "LEVEL"]

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


@dataclass(frozen=True)
class OrderCheck:
    """The outcome of :func:`order_check`: the best candidate's thickness and the
    neighbouring order's nearest in marginal chi^2, their chi^2 differences (plain and
    with the response marginalised, both over the Birge ratio ``scale``) and the threshold."""

    determined: bool
    thickness_nm: float
    alternative_nm: float | None
    delta_chi2: float | None          # marginal, over ``scale``
    delta_chi2_plain: float | None    # the response taken as exact, over ``scale``
    threshold: float
    scale: float
    candidates: int
    #: every candidate's ``(thickness, chi^2 taken as exact, marginal chi^2)``, unscaled
    scored: tuple = ()

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
        return (f"the response's uncertainty admits the neighbouring order at {self.alternative_nm:.0f} nm {how}: "
                "the thickness's order is not determined; calibrate the camera from a film of known thickness "
                "(docs/cameras.md)")

    def at(self, thickness_nm: float, n_film: float) -> "OrderCheck":
        """The test seen from the candidate in the order of ``thickness_nm`` (the fit's final
        thickness, which a warm start or the final solve may have left in another order
        than the search's best): unchanged when that is the best's order or no candidate's;
        otherwise not determined, the best's order the alternative (a negative difference)."""
        sep = order_separation(n_film)
        if abs(thickness_nm - self.thickness_nm) <= sep:
            return self
        near = [c for c in self.scored if abs(c[0] - thickness_nm) <= sep]
        best = [c for c in self.scored if abs(c[0] - self.thickness_nm) <= sep]
        if not near or not best:
            return self
        own, top = near[0], best[0]
        return OrderCheck(False, own[0], top[0], float((top[2] - own[2]) / self.scale),
                          float((top[1] - own[1]) / self.scale), self.threshold, self.scale, self.candidates,
                          self.scored)

    def to_json(self) -> dict:
        """The record of the fit's JSON (``order_check``)."""
        return {"determined": self.determined, "thickness_nm": self.thickness_nm,
                "alternative_nm": self.alternative_nm, "delta_chi2": self.delta_chi2,
                "delta_chi2_plain": self.delta_chi2_plain, "threshold": self.threshold, "level": LEVEL,
                "birge_scale": self.scale, "candidates": self.candidates}


def order_check(err, lev, solutions: list, robust_scale: float, n_params: int) -> OrderCheck | None:
    """Compare the refined candidates ``solutions`` (:class:`~bubblefit.inverse._local.LocalSolution`
    of a constant film on the search level ``lev``) by their chi^2 with the response's
    errors ``err`` (:class:`~bubblefit.inverse.response_error.ResponseError`) marginalised
    (module docstring), and taken as exact (the chi^2 less the Gauss-Newton decrement
    over the parameters alone: both to first order from where the search's short solves
    stopped). The best is the lowest chi^2 (the search's winner); a candidate is another
    order when its thickness is more than :func:`order_separation` from the best's.
    ``n_params``: the solve's free parameters (for the reduced chi^2). None when the response states no errors or no candidate has a constant thickness."""
    from .response_error import solve_marginal_chi2

    if err is None:
        return None
    scored = []
    for sol in solutions:
        d = sol.values.get("thickness_nm")
        if d is None or not np.isfinite(sol.cost):
            continue
        got = solve_marginal_chi2(err, lev, sol, robust_scale)
        plain = solve_marginal_chi2(None, lev, sol, robust_scale)
        if got is not None and all(np.isfinite(got)) and np.isfinite(plain[1]):
            scored.append((float(d), plain[1], got[1], got[0]))
    if not scored:
        return None
    best = min(scored, key=lambda s: s[3])
    dof = max(int(np.count_nonzero(lev.w)) - int(n_params), 1)
    scale = max(1.0, best[3] / dof)
    others = [s for s in scored if abs(s[0] - best[0]) > order_separation(err.n_film)]
    thr = order_threshold()
    kept = tuple((s[0], s[1], s[2]) for s in scored)
    if not others:
        return OrderCheck(True, best[0], None, None, None, thr, scale, len(scored), kept)
    alt = min(others, key=lambda s: s[2])
    delta = (alt[2] - best[2]) / scale
    return OrderCheck(bool(delta > thr), best[0], alt[0], float(delta), float((alt[1] - best[1]) / scale), thr, scale,
                      len(scored), kept)
