"""A sequence's warm frame with the global parameters carried (block coordinate descent).

A drainage video's frames share their light, reflectances, roughness and disc; what changes
frame to frame is the film. A warm-started thickness map therefore holds the global
parameters at the last full solve's values and solves the map, the main unknown, alone
(variable projection, Golub and Pereyra 1973): :func:`carried_map` builds the map coarse
to fine (:func:`~bubblefit.inverse._maps.fit_map`), steps the exposure in closed form where
its score test says it moved (:func:`exposure_step`) and fits the drainage profile to the
map (:func:`~bubblefit.inverse._maps.profile_from_map`). The fit assembles its result from
the :class:`CarriedMap`, or runs the full solve where :func:`carried_map` says why not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._map_pixels import TracedCosts
from ._maps import PROFILE_NAMES, fit_map, profile_from_map
from ._options import FitOptions
from ._parameters import DISC_PARAMETERS
from ._programs import final_params, render_bubble
from ._uncertainty import Misfit, photo_misfit
from ..progress import stage

__all__ = ["EXPOSURE_TEST_ALPHA", "CarriedMap", "carried_map", "carried_record", "exposure_step", "final_map_render", "held_disc",
           "map_misfit"]

#: Per-frame false-alarm probability of the score test that a sequence's exposure has not
#: moved (:func:`exposure_step`): the share of frames whose exposure did not move that
#: still take its closed-form step and a second map.
EXPOSURE_TEST_ALPHA = 0.01


def map_misfit(full, img: np.ndarray, opts: FitOptions) -> tuple[Misfit, int]:
    """The :func:`~bubblefit.inverse._uncertainty.photo_misfit` of a thickness map's
    full-resolution render ``img`` (one thickness fitted per pixel, so ``2 N`` degrees of
    freedom over ``N`` pixels of 3 channels) and its degrees of freedom."""
    n_free = int(full.mask.sum())
    return photo_misfit(full, img, float(opts.judge.model_error), n_free), max(int((full.w > 0).sum()) - n_free, 1)


def carried_record(disc_stderr, reported: dict, stderr: dict, fit: Misfit, dof: int, disc=None, values=None) -> dict:
    """What a solve of the global parameters passes on to the next frames of a sequence
    (JSON): its map's reduced chi^2 with the floor and degrees of freedom, its reported
    keys, their standard errors (the profile's and the map's excepted: each frame fits its
    own) and the disc's; ``frames``: frames since. Where the solve refined the disc
    (``disc_stderr``), ``disc_refinement``: the disc found (``disc``, pixels) and the
    refinement ``disc_x``, ``disc_y``, ``disc_r`` of the solve's ``values`` as its map traced
    them, which the held frames render with (:func:`held_disc`)."""
    own = set(PROFILE_NAMES) | {"thickness_nm"}
    out = {"chi2_floor": float(fit.chi2_floor), "dof": int(dof), "keys": list(reported),
           "stderr": {k: (None if v is None else float(v)) for k, v in stderr.items() if k not in own},
           "disc_stderr": disc_stderr, "frames": 0}
    if disc_stderr and disc is not None and values is not None and all(n in values for n in DISC_PARAMETERS):
        out["disc_refinement"] = {"found": [float(v) for v in disc], **{n: float(values[n]) for n in DISC_PARAMETERS}}
    return out


def held_disc(disc, carried: dict) -> dict:
    """The disc's refinement (``disc_x``, ``disc_y``, ``disc_r``) a frame that holds the
    global parameters renders with: the solve's own values (``carried["disc_refinement"]``,
    :func:`carried_record`) where this frame found the same disc ``disc`` (pixels), so that
    its map reads the rays the solve's map traced, the same numbers bit for bit
    (:func:`~bubblefit.inverse._map_pixels._kept_trace`). Empty elsewhere: the warm start's
    disc stands (:func:`~bubblefit.inverse._parameters.disc_start`, from the refined disc
    the solve reported, rounded to 0.001 px, 1e-5 of a 48 px radius, which moves every
    ray and so traced them all again)."""
    held = (carried or {}).get("disc_refinement")
    if not isinstance(held, dict) or disc is None:
        return {}
    try:
        same = [float(v) for v in held["found"]] == [float(v) for v in disc]
        return {n: float(held[n]) for n in DISC_PARAMETERS} if same else {}
    except (KeyError, TypeError, ValueError):
        return {}


def exposure_step(full, photo, img, column, opts: FitOptions, fit: Misfit) -> tuple[float, float, float]:
    """The exposure's closed-form Gauss-Newton step with the map held, its score statistic
    and its standard error: ``(step, z2, stderr)``.

    The render is affine in the exposure (eq. 1's reflected terms scale with it; the
    transmitted background photo does not, a map's background does), so its derivative in
    the exposure, ``column`` ``a`` (h, w, 3), is its exact column. With residual
    ``r`` and column ``a`` whitened by each pixel's noise and model-error floor, the step
    is ``a.r / a.a`` (variable projection: the linear parameter solved for the others
    held, Golub and Pereyra 1973) and ``z2 = (a.r)^2 / (a.a chi2_floor)`` is Rao's score
    statistic, chi^2 with one degree of freedom when the exposure has not moved (the
    misfit's Birge ratio scales the variance, as for the standard errors); its standard
    error ``sqrt(chi2_floor / a.a)``."""
    used = full.w > 0
    var = 1.0 / np.where(used, full.w, 1.0) ** 2 + (float(opts.judge.model_error) * np.clip(full.y, 0, None)) ** 2
    wf = np.where(used, 1.0 / np.sqrt(var), 0.0)
    a = column * wf
    r = (photo - img) * wf
    aa, ar = float(np.sum(a * a)), float(np.sum(a * r))
    s2 = max(float(fit.chi2_floor), 1.0)
    if not aa > 0:
        return 0.0, 0.0, float("nan")
    return ar / aa, ar * ar / (aa * s2), math.sqrt(s2 / aa)


def _from_traced_rays(kept: list, table, vals: dict, dmap: np.ndarray):
    """``(flat, values, column)`` of the map ``dmap``'s fitted pixels shaded at ``vals`` from
    the rays its finest level traced (``kept``'s last, :func:`fit_map`;
    :meth:`~bubblefit.inverse._map_pixels.TracedCosts.pixels`: the pixels' flat indices,
    their values and their derivative in the exposure), or None without such rays (the
    paper model's exact candidates)."""
    if not (kept and isinstance(kept[-1], TracedCosts)):
        return None
    costs = kept[-1]
    flat = costs.pix.flat
    return (flat, *costs.pixels(np.asarray(dmap, np.float64).reshape(-1)[flat], table, vals))


def _shaded(full, kept: list, table, vals: dict, dmap: np.ndarray, opts: FitOptions, env) -> tuple[np.ndarray, np.ndarray]:
    """``(img, column)`` (h, w, 3): the map ``dmap``'s render at ``vals`` and its derivative
    in the exposure (eq. 11 and the physical series scale the reflected terms by it), over
    the fitted pixels (0 elsewhere, where :func:`map_misfit` and :func:`exposure_step` read
    nothing). From the map's finest level's traced rays (``kept``, :func:`fit_map`): only
    the film's optics are evaluated, with one forward-mode tangent in the exposure
    (:meth:`~bubblefit.inverse._map_pixels.TracedCosts.pixels`); without them (the paper
    model's exact candidates), two renders, the column their difference from half the
    exposure (the render is affine in it)."""
    traced = _from_traced_rays(kept, table, vals, dmap)
    if traced is not None:
        flat, vals_p, col_p = traced
        img, column = np.zeros(full.y.shape), np.zeros(full.y.shape)
        img.reshape(-1, 3)[flat], column.reshape(-1, 3)[flat] = vals_p, col_p
        return img, column
    render = lambda v: np.asarray(render_bubble(final_params(table, dict(v, map=dmap), opts), full, env), np.float64)
    e = float(vals["exposure"])
    img = render(vals)
    return img, (img - render(dict(vals, exposure=0.5 * e))) / (0.5 * e)


def final_map_render(full, kept: list, table, vals: dict, dmap: np.ndarray, opts: FitOptions, env) -> np.ndarray:
    """The map ``dmap``'s full-resolution render at ``vals`` (eq. 11 or the physical series,
    :func:`~bubblefit.inverse._programs.render_bubble`), its fitted pixels shaded from the
    rays the map's finest level traced (``kept``, :func:`fit_map`; the exposure and the
    drainage profile of ``vals`` replace those they were traced at,
    :meth:`~bubblefit.inverse._map_pixels.TracedCosts.pixels`) and only the rest of the
    bubble rendered; without them (the paper model's exact candidates) a whole render."""
    traced = _from_traced_rays(kept, table, vals, dmap)
    known = None if traced is None else traced[:2]
    return np.asarray(render_bubble(final_params(table, dict(vals, map=dmap), opts), full, env, known), np.float64)


@dataclass(frozen=True)
class CarriedMap:
    """A warm frame's map with the global parameters carried: the values (globals held,
    exposure possibly stepped, profile fitted to the map), the map and its per-pixel
    standard errors, its full-resolution render and misfit, the profile's and the
    exposure's standard errors, and the exposure's score test."""

    values: dict
    thickness_map: np.ndarray
    map_stderr: np.ndarray
    render: np.ndarray
    misfit: Misfit
    profile_stderr: dict
    exposure_stderr: float | None
    exposure_step: float
    exposure_z2: float
    exposure_moved: bool


def carried_map(st, opts: FitOptions, env, carried: dict) -> CarriedMap | str:
    """The warm frame's map with the globals held at the last full solve's values
    (``carried``, :func:`carried_record`), or why the full solve must run instead.

    The map is built coarse to fine as a solved frame's (from the warm start's
    extrapolated profile, whose coarsest level scores first only the candidates near it:
    :func:`fit_map`'s ``narrow``); the exposure then gets its closed-form step when its score test
    says it moved (:func:`exposure_step`, :data:`EXPOSURE_TEST_ALPHA`; the map's pixels and
    the exposure's column are shaded from the rays its finest level traced, :func:`_shaded`),
    and the map is refined once more at the new exposure, at full resolution from itself. The drainage profile is fitted to the map (the rear
    film reads it, and a profile held with the globals tinted the film beyond the colour
    check). The frame goes to the full solve when the map is not sound, or the kept model
    does not explain the frame with the map (its reduced chi^2 with the floor above
    ``judge.ok_chi2``, the rule by which a fit is explained)."""
    table = st.table
    vals = dict(st.vals)
    if all(n in table.free for n in DISC_PARAMETERS):
        vals.update(held_disc(st.disc, carried))  # the solve's disc, as its map's rays were traced
    prof = tuple(float(vals[n]) for n in PROFILE_NAMES)
    make = lambda k: st.level(k, opts, st.map_cfg)
    exposure_err = (carried.get("stderr") or {}).get("exposure")
    with stage("thickness map, the global parameters carried"):
        full = st.level(1, opts, st.map_cfg)
        if not full.mask.any():
            return "no film pixels"
        kept = []
        dmap, emap, map_ok = fit_map(full, table, vals, prof, opts, env, make_level=make, start=st.map_start, kept=kept,
                                     narrow=True)
        img, column = _shaded(full, kept, table, vals, dmap, opts, env)
        fit, _ = map_misfit(full, img, opts)
        e = float(vals["exposure"])
        step, z2, step_err = exposure_step(full, st.photo, img, column, opts, fit)
        # the chi-square law's upper quantile with one degree of freedom, from scipy.special,
        # as the colour and order checks read theirs: scipy.stats would be imported (with the
        # optimize, spatial and interpolate modules it pulls in) by every fit's process
        from scipy.special import chdtri

        moved = bool(z2 > float(chdtri(1, EXPOSURE_TEST_ALPHA)))
        if moved and np.isfinite(step) and e + step > 0:
            vals["exposure"] = e + step
            exposure_err = max(float(exposure_err or 0.0), step_err)
            # the exposure moved the colours, not the interference order the coarse levels
            # settled: the map is refined at full resolution from itself (:func:`fit_map`'s start)
            # from the polynomials of each pixel's colour the first map was refined on, at the
            # new exposure (the colours are affine in it: no shading of the film again)
            dmap, emap, map_ok = fit_map(full, table, vals, prof, opts, env, make_level=make, start=(dmap, prof),
                                         fine=getattr(kept[-1], "polynomials", None) if kept else None)
        new_prof, prof_err = profile_from_map(full, dmap, emap, prof, tuple(n for n in PROFILE_NAMES if n in table.free))
        vals.update(zip(PROFILE_NAMES, new_prof))
        img = final_map_render(full, kept, table, vals, dmap, opts, env)
        fit, _ = map_misfit(full, img, opts)
    if not map_ok:
        return "its map with the carried global parameters is not sound"
    if not fit.chi2_floor <= float(opts.judge.ok_chi2):
        return (f"its map with the carried global parameters leaves a reduced chi^2 with the floor of "
                f"{fit.chi2_floor:.3g} > {float(opts.judge.ok_chi2):g}")
    return CarriedMap(vals, dmap, emap, img, fit, dict(prof_err), exposure_err, float(step), float(z2), moved)
