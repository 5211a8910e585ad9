"""The verdict on a fit: ``ok`` and the warnings that say why not.

A fit is ``ok`` only when (1) the local solver met its tolerances with finite errors,
(2) the bubble was found (or its disc given), (3) no fitted parameter sits at a bound
(its :data:`~bubblefit.inverse._parameters.PARAMETERS` ``plausible`` range, or the
searched thickness range) and (4) the photo is explained within its noise plus the
model-error floor: the reduced chi^2 with each pixel's variance
``sigma^2 + (JudgeSettings.model_error * photo)^2`` is at most ``JudgeSettings.ok_chi2``; after
:func:`verdict`, the fit adds (5): the stated camera response can produce the photo's hues
(:func:`bubblefit.inverse.colour_check.judge_colours`). When
it is not, the warning says whether the misfit is local: a few outlier pixels
(:data:`~bubblefit.inverse._uncertainty.OUTLIER_CHI2`) with the rest explained, as the
glints of the sun or of a lamp leave where the model renders them coarser than the camera
integrated them (one ray per pixel, or the pixel footprint's boxes). Such a fit
stays not ``ok``: on independent photos the share of outliers did not tell a glint from a
biased model apart (0.1-3.2 % on the development part's right fits with the sun, studio
lamps or a bright city map in view, but 20 % on the rough constant Cycles film
fitted within 0.4 nm; 10 % on the paper model's biased courtyard drainage profile;
experiments/validation/split.toml, docs/trust.md).

Zero roughness is not a bound but the mirror, eq. (1) as ``a -> 0``: a physical limit like
``r_d = 0``, which a smooth film reaches. A roughness within three standard errors of zero
is reported with a note that the photo bounds it only from above (:func:`unresolved`).
"""

from __future__ import annotations

import math

from ._parameters import PARAMETERS, ParameterTable
from ._uncertainty import OUTLIER_CHI2, Misfit

__all__ = ["at_bounds", "clamp_to_range", "unresolved", "verdict"]


def at_bounds(values: dict, table: ParameterTable, thickness_range: tuple, margin_nm: float) -> list[str]:
    """Warnings for free parameters at (or beyond) a bound of their plausible range."""
    out = []
    lo_t, hi_t = thickness_range
    for name in table.free:
        v = values[name]
        if PARAMETERS[name].unit == "nm":
            lo, hi, tol = lo_t, hi_t, margin_nm
        else:
            lo, hi = PARAMETERS[name].plausible
            tol = 0.0
        if v < lo or v > hi:
            out.append(f"{name} = {v:.4g} lies outside its plausible range [{lo:.4g}, {hi:.4g}]")
        elif v <= lo + tol or v >= hi - tol:
            out.append(f"{name} = {v:.4g} sits at a bound of its range [{lo:.4g}, {hi:.4g}]")
    return out


def clamp_to_range(reported: dict, table: ParameterTable, thickness_range: tuple,
                   keys: tuple) -> tuple[dict, list[str]]:
    """``(reported, warnings)``: every fitted thickness of ``keys`` that left the searched
    range ``thickness_range`` (nm) is reported at the bound it crossed, with a warning.

    The local solve works on unbounded coordinates, so a film the photo does not
    constrain can drift past the range it was searched over (a 4.4 nm thickness from a
    50-2000 nm search); the fit has no evidence for a value there, only that the best one
    lies at or beyond the bound. A warning makes the fit not ``ok`` (:func:`verdict`'s
    ``bound_warnings``).
    """
    out, warnings = dict(reported), []
    lo, hi = thickness_range
    for key in keys:
        v = out.get(key)
        if key not in table.free or v is None or lo <= v <= hi:
            continue
        bound = lo if v < lo else hi
        out[key] = float(bound)
        warnings.append(f"{key} left the searched range {lo:.4g}-{hi:.4g} nm (solved {v:.4g} nm): reported at "
                        f"the bound {bound:.4g} nm, which the photo does not confirm; widen --thickness-range "
                        "or check the disc, map and model")
    return out, warnings


def unresolved(values: dict, stderr: dict, table: ParameterTable) -> list[str]:
    """A note when the fitted roughness is within three standard errors of zero (or has no
    finite error): the photo then shows a mirror and bounds the roughness from above."""
    v, e = values.get("roughness"), stderr.get("roughness")
    if "roughness" not in table.free or v is None:
        return []
    known = e is not None and math.isfinite(e)
    if known and v > 3.0 * e:
        return []
    bound = f" (a < {v + 3.0 * e:.2g})" if known else ""
    return [f"roughness = {v:.2g} is within three standard errors of a mirror: read it as an upper limit{bound}"]


#: Largest share of outlier pixels a misfit may have to be called local: a misfit over most
#: of the film is not local, whatever the few remaining pixels say.
LOCAL_SHARE = 0.5


def verdict(*, converged: bool, disc_found: bool, bound_warnings: list, misfit: Misfit, ok_chi2: float,
            model_error: float, notes: list, swap_possible: bool = False) -> tuple[bool, list]:
    """``(ok, warnings)``: the conditions of the module docstring, each failed one in words
    (``notes``: cautions found on the way, kept first); ``misfit`` says whether the photo
    is explained, and whether a misfit is local: only when the outliers are a minority of
    the pixels (:data:`LOCAL_SHARE`) and the rest are explained. ``swap_possible``: a
    background photo was given and the pre-fit test (:mod:`._pair`) could not tell which of
    the two holds the bubble, so an unexplained photo may be a swapped pair."""
    chi2_floor, chi2_inliers, outliers = misfit.chi2_floor, misfit.chi2_inliers, misfit.outliers
    warnings = list(notes)
    if not converged:
        warnings.append("the solver did not converge")
    if not disc_found:
        warnings.append("the bubble was not found")
    warnings += bound_warnings
    explained = chi2_floor == chi2_floor and chi2_floor <= ok_chi2
    if not explained:
        text = (f"the model does not explain the photo: reduced chi^2 {chi2_floor:.3g} with a {model_error:.0%} "
                f"model-error floor (at most {ok_chi2:g} expected)")
        if 0 < outliers < LOCAL_SHARE and chi2_inliers <= ok_chi2:
            text += (f"; {outliers:.1%} of the pixels are outliers (chi^2 over {OUTLIER_CHI2:g} each) and the rest "
                     f"are at {chi2_inliers:.3g}: the misfit is local (glints of a compact light sharper than the "
                     "model renders them; specks), or a model wrong over that share of the film")
        else:
            text += ("; wrong environment map, rotation, disc or model, or the photo and the background photo "
                     "swapped?" if swap_possible else "; wrong environment map, rotation, disc or model?")
        warnings.append(text)
    ok = converged and disc_found and not bound_warnings and explained
    return ok, warnings
