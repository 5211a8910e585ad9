"""Fitting the forward model to a photograph of a bubble (``bubblefit fit``, docs/design.md).

:func:`fit_photo` recovers ``t``, the split of ``1 - t`` into ``r_d`` and ``r_s`` (eq. 14,
or both free), Ward's roughness ``a`` (eq. 1), the film thickness (one value, a drainage
profile, or a per-pixel map), a camera gain and optionally the environment's rotation
about +y, from a linear (H, W, 3) photo and its environment map. It runs the stages of
:mod:`bubblefit.inverse`, each in its own module:

1. Observation (:mod:`._observation`): the photo's noise, clipped pixels, the bubble's
   disc (found by :mod:`bubblefit.capture.disc`), and the photo
   at the fit's and the search's resolutions.
2. Parameters (:mod:`._parameters`): effects are decided once
   (:func:`bubblefit.model.effects.resolve`) from the starting values and the whole
   thickness search range; a parameter whose effect is skipped (``r_d`` without the
   diffuse term, roughness with a mirror lookup, thickness without interference; ``t``
   and ``r_s`` in the ``physical`` model, where Fresnel sets them) is held, with the
   reason, never fitted into noise.
3. Global thickness search (:mod:`.search`) on a downsampled image; the lowest minima are
   refined. Before it, :func:`~._programs.warm_up` starts the compiles of the programs
   the fit runs after it (:mod:`._programs` builds, stores and loads every program).
4. Local Levenberg-Marquardt (:mod:`._local`, :mod:`._lm`) on the whitened, robust residual
   ``(render - photo) / sigma`` inside the disc (``rho < rim``), not saturated, with
   ``sigma^2 = read^2 + shot * I + q^2``, through a pseudo-Huber loss of scale
   ``SolverSettings.robust_scale`` sigmas.
5. Uncertainty (:mod:`._uncertainty`): covariance by the delta method.
6. Thickness map (:mod:`._maps`), after a drainage fit.

Light, camera and film: the illuminant, camera response, white balance, the film's
dispersion law and the rays per pixel come from the options (the command line), else the
scene (:func:`._setup.colour_settings`), and are set once, in the render configurations
of :func:`._setup.setup` that every stage renders with (search candidates, local solves,
map, final image).

Transmission tint: with the ``paper`` model the fit turns on ``transmission_tint``
(:mod:`bubblefit.model.effects`) unless told otherwise: a real film transmits the complement of
the colour it reflects, which over a bright background is as strong as the reflection
itself, and eq. (11)'s grey ``t^4`` would then prefer another colour order.

:func:`fit_batch` fits several warm-started frames of a sequence in one solve vmapped
over frames (for devices that one small frame does not fill; on a 2-core CPU it is
slower than frame after frame).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from . import search
from ._local import DECREMENT_TOLERANCE, LocalSolution, remaining_step, solution_from, solve_local
from ._carried import CarriedMap, carried_map, carried_record, final_map_render, map_misfit
from ._maps import PROFILE_NAMES, fit_map
from ._observation import noise_sigma
from ..capture.circle import detect_disc
from ._programs import (FINAL_SOLVE, SEARCH_SOLVE, WARM_SOLVE, SolveSettings, batched_solver, final_params,
                        fitted_pixels, held_values, render_bubble, reporter, warm_up)
from ._options import FitOptions, ImageSizes, JudgeSettings, MapSettings, NoiseSettings, SolverSettings
from ._result import FitResult
from ._parameters import THICKNESSES, extrapolated, parameter_roles, refined_disc
from ._setup import Setup, defaults, setup
from ._uncertainty import Uncertainty, photo_misfit, uncertainty
from ._verdict import at_bounds, clamp_to_range, unresolved, verdict
from ._view import camera_record, fit_divergence, fit_view, lens_for
from .colour_check import judge_colours, microfacet_offsets
from .order_check import OrderCheck, neighbouring_orders, order_check, order_parameters
from .response_error import (pixel_thickness_stderr, response_cells, response_error, response_score_cells,
                             solve_response_gram)
from ..errors import InputError
from ..lighting.envmap import EnvMap
from ..model.modes import GREY
from ..model.thickness import drainage_gradient, drainage_profile
from ..progress import stage

__all__ = ["FitOptions", "FitResult", "NoiseSettings", "MapSettings", "JudgeSettings", "SolverSettings", "ImageSizes",
           "fit_photo", "fit_batch", "detect_disc", "noise_sigma", "explained"]

#: A warm-started fit whose noise-weighted reduced chi^2 exceeds this is checked against a
#: global thickness search (see :func:`fit_photo`).
WARM_START_CHI2 = 4.0


# ---------------------------------------------------------------------------------------
# Solving and finishing
# ---------------------------------------------------------------------------------------


def _warm_doubt(st: Setup, opts: FitOptions, sol: LocalSolution) -> str | None:
    """Why a warm-started solution is doubtful, or None: the solver failed, the thickness
    left the searched range, or the noise-weighted reduced chi^2 exceeds WARM_START_CHI2."""
    lo, hi = opts.thickness_range
    dof0 = max(int(np.count_nonzero(st.lev_fit.w)) - len(st.table.free), 1)
    chi2 = sol.cost / dof0
    thick = [sol.values[k] for k in THICKNESSES if k in st.table.free]
    if not (sol.successful and np.all(np.isfinite(sol.residual))):
        return "the solver failed"
    if any(not lo - 1 <= d <= hi + 1 for d in thick):
        return "the thickness left the searched range"
    if not chi2 <= WARM_START_CHI2:
        return f"reduced chi^2 = {chi2:.1f}"
    return None


def _searched_start(st: Setup, opts: FitOptions, env, misfit: list | None = None, order: list | None = None) -> dict:
    """The global search's best start: each of :func:`search.search_starts` refined with at
    most ``search_steps`` LM steps on the search image (the disc as found: it is refined
    in the final solve only); the lowest cost wins. ``misfit``, when given, receives the
    winner's noise-weighted reduced chi^2 on the search image (its cost over the fitted
    pixels less the free parameters), the measure :func:`_warm_doubt` reads; ``order``
    receives the refined candidates compared with the response's errors marginalised
    (:func:`~bubblefit.inverse.order_check.order_check`; None when the response states no
    errors)."""
    lev_s = st.level(st.k_search, opts)
    rank = _ranking_level(lev_s)
    starts = search.search_starts(rank, st.search_table, st.vals, env, opts.thickness_range,
                                  opts.solver.search_step_nm, opts.solver.candidates)
    best_v, best_c = None, np.inf
    refined = []
    model = st.search_table.thickness_model
    err = None if order is None else response_error(st.colour.response, st.colour.illuminant, float(st.vals["n_film"]))

    def refine(s):
        nonlocal best_v, best_c
        sol = solve_local(rank, st.search_table, opts.solver, s, env, max_steps=opts.solver.search_steps,
                          settings=SEARCH_SOLVE)
        refined.append(sol)
        if np.isfinite(sol.cost) and sol.cost < best_c:
            best_v, best_c = sol.values, sol.cost

    for s in starts:
        refine(s)
    if err is not None and model != "constant" and best_v is not None:
        # a profile's starts share one order: the neighbouring orders' from the best
        for s in neighbouring_orders(best_v, order_parameters(model), err.n_film, *opts.thickness_range):
            refine(s)
    if rank is not lev_s and best_v is not None:  # the winner refined on the search image as the fit renders it
        sol = solve_local(lev_s, st.search_table, opts.solver, best_v, env, max_steps=opts.solver.search_steps,
                          settings=SEARCH_SOLVE)
        if np.isfinite(sol.cost):
            best_v, best_c = sol.values, sol.cost
    if misfit is not None:
        misfit.append(_reduced_search_chi2(best_c, lev_s, st))
    if order is not None:
        order.append(order_check(err, rank, refined, float(opts.solver.robust_scale), len(st.search_table.free),
                                 model))
    return best_v if best_v is not None else starts[0]


def _ranking_level(lev_s):
    """The search image ``lev_s`` on which the global search ranks its candidates: one ray
    per pixel instead of the pixel footprint (:attr:`~bubblefit.model.render.RenderConfig.pixel_footprint`,
    ray differentials: Igehy, "Tracing ray differentials", SIGGRAPH 1999). The candidates
    are colour orders a fringe apart, which the footprint's blur of compact sources (a sun's
    glints) does not reorder; the winner is then refined with the footprint
    (:func:`_searched_start`), so the start, its reduced chi^2 and the solves that follow
    see the model the fit renders."""
    if not lev_s.cfg.pixel_footprint:
        return lev_s
    return replace(lev_s, cfg=replace(lev_s.cfg, pixel_footprint=False))


def _reduced_search_chi2(cost: float, lev_s, st: Setup) -> float:
    """A solve's noise-weighted reduced chi^2 on the search image ``lev_s``: its ``cost``
    over the fitted pixels less the search's free parameters (inf for a failed solve)."""
    dof = max(int(np.count_nonzero(lev_s.w)) - len(st.search_table.free), 1)
    return float(cost / dof) if np.isfinite(cost) else float("inf")


def _status_notes(sol: LocalSolution, finite: bool, chi2_nu: float, notes: list, free=()) -> tuple[str, bool]:
    """``(status, converged)`` of a solve, with the reasons prepended to ``notes``.

    A solve that met its tolerances has converged. When the Gauss-Newton step left from
    its end exceeds :data:`~bubblefit.inverse._local.DECREMENT_TOLERANCE` of the fit's
    own covariance (:func:`~bubblefit.inverse._local.remaining_step`) a note says how far
    (the solver stops on small steps, which a heavily damped step also is). ``free``: the
    solver's parameter names."""
    remaining = remaining_step(sol, chi2_nu, tuple(free))
    near = bool(remaining <= DECREMENT_TOLERANCE) or (not np.isfinite(remaining) and not finite)
    converged = sol.successful and bool(np.all(np.isfinite(sol.residual))) and finite
    status = "converged"
    if not sol.successful:
        status = "max_steps" if sol.max_steps_reached else "failed"
        notes.insert(0, "solver reached max_steps without meeting its tolerances" if sol.max_steps_reached
                     else "the solver failed (diverged or a non-finite residual)")
    elif not near:  # a caution: the restarts of solve_local did not close the gap
        notes.append(f"the solver stopped {math.sqrt(remaining):.2g} standard errors from the optimum its "
                     "Jacobian predicts")
    if not finite:
        status = "failed"
        notes.insert(0, "the Jacobian is singular at the optimum: some parameter is not constrained by the photo")
    return status, converged


@dataclass(frozen=True)
class Judgement:
    """What a solve's standard errors say (:func:`_judge`), before the map and the render.

    Attributes
    ----------
    uncertainty : Uncertainty
        Covariance, standard errors and misfit of the solve.
    reported, stderr : dict
        The reported values and their standard errors (the disc's refinement taken out).
    disc, disc_stderr : tuple, dict or None
        The disc in pixels, refined, and its standard errors (None when not refined).
    status : str
        ``converged``, ``max_steps`` or ``failed`` (:func:`_status_notes`).
    converged : bool
        The solver met its tolerances with finite errors.
    bounds : list
        Warnings for free parameters at a bound of their range.
    order : OrderCheck or None
        The global search's candidates compared with the response's errors marginalised
        (:mod:`bubblefit.inverse.order_check`; None without a search or without stated errors).
    """

    uncertainty: Uncertainty
    reported: dict
    stderr: dict
    disc: tuple | None
    disc_stderr: dict | None
    status: str
    converged: bool
    bounds: list
    order: OrderCheck | None = None


def _judge(st: Setup, opts: FitOptions, sol: LocalSolution, notes: list) -> Judgement:
    """Standard errors (:func:`~bubblefit.inverse._uncertainty.uncertainty`), the refined disc,
    the solver's status and the parameters at a bound or out of the searched range; the
    cautions are appended to ``notes``."""
    table = st.table
    gram = solve_response_gram(st.colour.response, st.colour.illuminant, float(st.vals["n_film"]), st.lev_fit, sol,
                               float(opts.solver.robust_scale), table.thickness_model)  # a calibrated response's own errors (None: exact)
    unc = uncertainty(sol, table, st.lev_fit, float(opts.solver.robust_scale), float(opts.judge.model_error),
                      float(opts.judge.thickness_model_error_nm), gram, float(opts.disc_model_error))
    reported, stderr = unc.reported, unc.stderr
    disc, disc_stderr = refined_disc(st.disc, reported, stderr)
    status, converged = _status_notes(sol, unc.finite, unc.misfit.chi2_nu, notes, table.free)
    solved = reported
    reported, outside = clamp_to_range(solved, table, opts.thickness_range, THICKNESSES)
    clamped = {k for k in THICKNESSES if reported.get(k) != solved.get(k)}  # said once, by clamp_to_range
    bounds = outside + [w for w in at_bounds(sol.values, table, opts.thickness_range, 0.5 * opts.solver.search_step_nm)
                        if w.split(" = ")[0] not in clamped]
    notes += unresolved(reported, stderr, table)
    return Judgement(unc, reported, stderr, disc, disc_stderr, status, converged, bounds)


def _exposure_doubts(st: Setup, opts: FitOptions, env, full, reported: dict) -> list:
    """The warning of :func:`~._exposure.exposure_doubt` for a fitted exposure outside what the
    photo's and the map's brightness allow (:func:`~._exposure.exposure_range`), else none."""
    from ._exposure import exposure_doubt, exposure_range, least_reflectance, map_levels
    from ._pair import LUMINANCE

    if "exposure" not in st.table.free or not full.mask.any():
        return []
    y = np.asarray(st.photo, np.float64)[full.mask] @ LUMINANCE
    excess = None
    if st.background is not None and not st.base_cfg.point_lights:
        b = np.asarray(st.background, np.float64)[full.mask] @ LUMINANCE
        excess = float(np.mean(np.maximum(y - b, 0.0)))
    median, mean = map_levels(np.asarray(env.pixels))
    rho_min = least_reflectance(*(float(v) for v in opts.thickness_range), float(opts.rim))
    lower, upper = exposure_range(float(np.mean(y)), excess, median, mean, rho_min)
    doubt = exposure_doubt(float(reported["exposure"]), lower, upper)
    return [] if doubt is None else [doubt]


def _report(st: Setup, env, opts: FitOptions, sol: LocalSolution, judged: Judgement, notes: list,
            t_start: float, made: CarriedMap | None = None, carried: dict | None = None) -> FitResult:
    """The thickness map (``--thickness map``), the full-resolution render, the verdict and
    the :class:`FitResult` of a judged solve. ``made``: the sound map, its standard errors
    and the render a carried frame already made (:func:`_carried_map_fit`); ``carried``: the
    global parameters' record a warm-started map carries on (None: this solve's own,
    :func:`~._carried.carried_record`)."""
    table, unc = st.table, judged.uncertainty
    judge = opts.judge
    reported, stderr = dict(judged.reported), dict(judged.stderr)
    status, converged = judged.status, judged.converged
    new = sol.values
    final_vals, thickness_map, stderr_map = dict(new), None, None
    prof = None if opts.thickness == "constant" else (new["top_nm"], new["bottom_nm"], new["exponent"])
    full = st.level(1, opts, st.map_cfg if opts.thickness == "map" else st.base_cfg)
    kept = []  # the map's finest level's traced rays, which the final render shades its pixels from
    if opts.thickness == "map":
        dmap, emap, map_ok = (made.thickness_map, made.map_stderr, True) if made is not None else \
            fit_map(full, table, new, prof, opts, env, make_level=lambda k: st.level(k, opts, st.map_cfg),
                    start=st.map_start, kept=kept)
        final_vals["map"] = dmap
        thickness_map = np.where(full.inside, dmap, np.nan)
        stderr_map = np.where(full.mask, np.hypot(emap, float(judge.thickness_model_error_nm)), np.nan)
        reported["thickness_nm"] = float(np.median(dmap[full.mask])) if full.mask.any() else float("nan")
        stderr["thickness_nm"] = float(np.nanmedian(stderr_map[full.mask])) if full.mask.any() else float("nan")
        if not map_ok:
            converged, status = False, "failed"
            notes.append("the thickness map is not constrained at over 10% of the film's pixels")
    elif opts.thickness == "drainage":
        thickness_map = np.where(full.inside, np.asarray(drainage_profile(jnp.asarray(full.height), *prof)), np.nan)
    if made is not None:
        img = made.render
    elif opts.thickness == "map":
        img = final_map_render(full, kept, table, new, final_vals["map"], opts, env)
    else:
        img = np.asarray(render_bubble(final_params(table, final_vals, opts), full, env), np.float64)
    resid_img = st.photo - img
    # ``ok`` reads the photo as the camera took it: the final render against every pixel
    # (:func:`photo_misfit`); the solve's own level gave the standard errors' widening
    if opts.thickness == "map" and full.mask.any() and made is not None:
        seen = made.misfit  # the carried frame's map already judged its final render
    elif opts.thickness == "map" and full.mask.any():
        seen, map_dof = map_misfit(full, img, opts)
        carried = carried or carried_record(judged.disc_stderr, reported, stderr, seen, map_dof, st.disc, new)
    else:
        # its correlation area is not read: a fitted view's comes from the solve's level
        seen = photo_misfit(full, img, float(judge.model_error), len(unc.names), correlation=False)
    camera_stderr = unc.camera_stderr
    if opts.thickness == "map" and full.mask.any():  # each pixel's share of a calibrated response's errors
        camera_stderr, stderr_map = _map_camera_stderr(st, full, img, thickness_map, stderr_map, camera_stderr)
        if camera_stderr is not None:
            stderr["thickness_nm"] = float(np.nanmedian(stderr_map[full.mask]))
    rms = float(np.sqrt(np.mean(resid_img[full.mask] ** 2))) if full.mask.any() else float("nan")
    reported["n_film"] = float(st.vals["n_film"])
    bounds = judged.bounds + _exposure_doubts(st, opts, env, full, reported)
    ok, warnings = verdict(converged=bool(converged), disc_found=True, bound_warnings=bounds,
                           misfit=seen, ok_chi2=float(judge.ok_chi2), model_error=float(judge.model_error),
                           notes=st.warnings, swap_possible=st.pair is not None and st.pair.swap_possible)
    disc_stderr = judged.disc_stderr
    # can the stated camera response produce the photo's colours? (bubblefit.inverse.colour_check)
    share = opts.noise.photosite_share
    sigma = st.sigma if share is None else st.sigma / np.sqrt(np.asarray(share))
    explained = bool(seen.chi2_floor <= float(judge.ok_chi2))  # as the verdict judges it
    thick = thickness_map if thickness_map is not None else reported["thickness_nm"]
    response_jac = response_cells(st.colour.response, st.colour.illuminant, reported["n_film"], img, st.background,
                                  thick, full.cos)  # a calibrated response's own errors (None: exact)
    # the score test along smooth changes of the response, the film's thickness profiled out: a
    # constant film's (one number), a drainage profile's (its free parameters); maps are not tested
    # this way (a map's thickness is free per pixel, which the profile's columns do not hold)
    score_jac = None
    if opts.thickness != "map" and st.table.thickness_model in ("constant", "drainage"):
        free = [k for k, name in enumerate(PROFILE_NAMES) if name in st.table.free]
        nuisance = None if prof is None else np.asarray(drainage_gradient(full.height, *prof), np.float64)[..., free]
        score_jac = response_score_cells(st.colour.response, st.colour.illuminant, reported["n_film"], img,
                                         st.background, thick, full.cos, nuisance=nuisance)
    # the microfacet distribution, a nuisance the fit does not free: its Type B offsets, from
    # renders with GGX's facets and lobe at the fitted values (None for a mirror or the spectral film)
    offset = microfacet_offsets(final_params(table, final_vals, opts), full, env, img)
    ok, warnings, colour_record = judge_colours(ok, warnings, st.photo, img, full.mask, full.cos, sigma,
                                                float(judge.model_error), explained, judge.colour_check == "decide",
                                                response_jac, thick, reported["n_film"], score_jac, offset)
    order = judged.order  # does the photo tell the order, the response's errors allowed?
    names = order_parameters(st.table.thickness_model) or ()
    if order is not None and names and all(np.isfinite(reported.get(n, np.nan)) for n in names):
        own = tuple(float(reported[n]) for n in names)
        order = order.at(own[0] if len(own) == 1 else own, float(reported["n_film"]))
    if order is not None and order.warning() is not None:
        ok, warnings = False, warnings + [order.warning()]
    return FitResult(
        params=reported, stderr=stderr, held=list(table.held), converged=bool(converged),
        message="; ".join(notes) if notes else "converged", iterations=sol.steps, residual_rms=rms,
        time_s=time.perf_counter() - t_start, effects=st.decisions, render=img, residual=resid_img,
        thickness_map=thickness_map, thickness_stderr_map=stderr_map, disc=judged.disc, disc_stderr=disc_stderr,
        thickness_model=opts.thickness, model=opts.model, reduced_chi2=seen.chi2_nu,
        pixels_used=int(st.lev_fit.mask.sum()), status=status, names=unc.names, covariance=unc.covariance,
        ok=ok, warnings=warnings, chi2_floor=seen.chi2_floor, chi2_inliers=seen.chi2_inliers,
        outliers=seen.outliers, chi2_capped=seen.chi2_capped, solve_misfit=unc.misfit,
        correlation_area=unc.misfit.correlation_area, model_error=float(judge.model_error),
        thickness_model_error_nm=float(judge.thickness_model_error_nm),
        disc_model_error=float(opts.disc_model_error) if disc_stderr is not None else float("nan"),
        stderr_scale=unc.scale, roles=parameter_roles(table, st.fx.model, tuple(reported)),
        frame=None if st.frame.whole else (st.frame.x0, st.frame.y0, st.frame.k), colour=st.colour,
        camera=None if opts.view is None else camera_record(opts.view, st.base_cfg.camera),
        colour_check=colour_record, stderr_camera=camera_stderr,
        order_check=None if order is None else order.to_json(), carried=carried,
    )


def _carried_map_fit(started: Started, env, init: dict) -> tuple[FitResult | None, str | None]:
    """A sequence's warm-started thickness map with the global parameters carried
    (:func:`~._carried.carried_map`, block coordinate descent), the ``(result, None)``;
    ``(None, why)`` where the full solve must run. The held globals keep the standard
    errors of the solve that fitted them (they are its values); a stepped exposure has the
    larger of that and its step's; the map and the profile have their own. A frame whose
    verdict is not ok with the globals held (e.g. the colour check: held globals that
    moved tint the film) goes to the full solve too."""
    st, opts = started.setup, started.options
    carried = init.get("carried") if init else None
    if not (started.warm and opts.thickness == "map" and isinstance(carried, dict) and "exposure" in st.table.free):
        return None, None
    cm = carried_map(st, opts, env, carried)
    if isinstance(cm, str):
        return None, cm
    vals = cm.values
    reported = {k: float(init[k]) if init.get(k) is not None else float("nan") for k in carried["keys"]}
    reported.update({n: float(vals[n]) for n in PROFILE_NAMES if n in reported})
    reported["exposure"] = float(vals["exposure"])
    stderr = {k: carried["stderr"].get(k) for k in reported}
    stderr.update({n: e for n, e in cm.profile_stderr.items() if n in reported})
    stderr["exposure"] = cm.exposure_stderr
    disc_err = carried.get("disc_stderr")
    disc = tuple(float(v) for v in init["disc"]) if disc_err and init.get("disc") is not None else st.disc
    unc = Uncertainty(reported, stderr, (), np.zeros((0, 0)), cm.misfit, 1.0, True, None)
    judged = Judgement(unc, reported, stderr, disc, disc_err if disc is not st.disc else None, "converged", True, [])
    frames = int(carried.get("frames", 0)) + 1
    notes = [f"global parameters carried from the solve {frames} frame(s) before"
             + (f"; the exposure stepped by {cm.exposure_step:.3g} (score test z^2 = {cm.exposure_z2:.3g})"
                if cm.exposure_moved else f" (the exposure's score test z^2 = {cm.exposure_z2:.3g})")]
    sol = SimpleNamespace(values=vals, steps=0)
    res = _report(st, env, opts, sol, judged, notes, started.t_start,
                  made=cm, carried=dict(carried, frames=frames))
    if not res.ok:
        return None, "with the carried global parameters the fit is not ok: " + "; ".join(res.warnings)[:300]
    return res, None


def _map_camera_stderr(st: Setup, full, img, thickness_map, stderr_map, camera_stderr):
    """A thickness map's share of a calibrated response's errors: each pixel's standard
    error from the response alone (:func:`~bubblefit.inverse.response_error.pixel_thickness_stderr`)
    added in quadrature to ``stderr_map``, and ``camera_stderr`` with the map's median
    of it as ``thickness_nm``; both unchanged for a response taken as exact."""
    err = response_error(st.colour.response, st.colour.illuminant, float(st.vals["n_film"]))
    if err is None:
        return camera_stderr, stderr_map
    m = full.mask
    bg = None if st.background is None else np.asarray(st.background, np.float64)[m]
    cam = pixel_thickness_stderr(err, img[m], bg, thickness_map[m], np.asarray(full.cos)[m],
                                 np.asarray(full.w, np.float64)[m])
    out = np.array(stderr_map, np.float64)
    out[m] = np.hypot(out[m], cam)
    return dict(camera_stderr or {}, thickness_nm=float(np.nanmedian(cam))), out


def _warm_order(st: Setup, opts: FitOptions, env) -> OrderCheck | None:
    """The order test of a warm-started fit (a constant film or a profile), which has no candidates of its own:
    with a response that states its errors the global search supplies them, and the test
    then judges the warm start's order (:meth:`~bubblefit.inverse.order_check.OrderCheck.at`);
    None otherwise (no search is run)."""
    if not any(n in st.table.free for n in ("thickness_nm", "top_nm")) or \
            response_error(st.colour.response, st.colour.illuminant, float(st.vals["n_film"])) is None:
        return None
    found = []
    with stage("global thickness search for the order test"):
        _searched_start(st, opts, env, order=found)
    return found[0]


def _finish(st: Setup, env, opts: FitOptions, sol: LocalSolution, notes: list, t_start: float) -> FitResult:
    """Judge a solve (:func:`_judge`) and report it (:func:`_report`); a warm start's order
    test (:func:`_warm_order`) with it."""
    judged = _judge(st, opts, sol, notes)
    order = _warm_order(st, opts, env)
    return _report(st, env, opts, sol, judged if order is None else replace(judged, order=order), notes, t_start)


def fit_photo(photo: np.ndarray, env: EnvMap, *, options: FitOptions = FitOptions(), background=None,
              init: dict | None = None, scene=None, saturated: np.ndarray | None = None) -> FitResult:
    """Fit the forward model to a photo.

    The camera's view (:func:`~bubblefit.inverse._view.fit_view`) is the scene's, else
    ``options.view`` (a field of view: the pinhole is built from the disc); when neither
    states one, the photo is fitted as orthographic and again through a 50 mm (35 mm
    terms) lens warm-started from it, and the view's divergence ``u = tan(fov/2)`` is
    fitted from the photo by warm-started refits
    (:func:`~bubblefit.inverse._view.fit_divergence`: a bracket, then refits that minimise
    the chi^2 profile until its parabola reads the curvature near the minimum): the view at
    that minimum and the refit nearest it, its standard errors including the view's; where the photo does not fix the view, the
    view that explains it better (the lower capped reduced chi^2, :func:`_judged_chi2`)
    is kept and its standard errors are widened by the shift to the other
    (:func:`~bubblefit.inverse._view.widen_for_view`;
    ``docs/camera-view.md``). With ``options.calibrate_camera`` that fit, made with the
    stated camera response, is then refitted with the response freed
    (:func:`~bubblefit.inverse.self_calibration.self_calibrated`).

    Parameters
    ----------
    photo : np.ndarray
        (H, W, 3) linear photo of the bubble.
    env : EnvMap
        The environment map (aligned with the camera: it looks along -z of the map's
        frame; ``rotation`` about +y unless fitted or set by the scene).
    options : FitOptions
    background : np.ndarray, optional
        (H, W, 3) linear photo without the bubble: the transmitted background then comes
        from it (gain 1) instead of the map.
    init : dict, optional
        Warm start, a dict of the JSON's params (e.g. the previous frame's); the global
        thickness search is then skipped unless this fit fails.
    scene : Scene, optional
        Its camera (perspective or a disc), n_film (with its dispersion), illuminant,
        camera response, white balance, samples_per_pixel, effects settings, and every value its
        ``[bubble]`` table (and ``lighting.rotation_deg``) sets explicitly, which is then
        held fixed.
    saturated : np.ndarray, optional
        (H, W) bool of clipped pixels (e.g. :attr:`Image.saturated`), excluded in addition
        to values >= ``options.noise.saturation``.

    Returns
    -------
    FitResult

    Examples
    --------
    A photo rendered with a known 600 nm film over a black background through parallel rays,
    fitted back with its view stated (about a minute on a first call, which compiles; seconds
    with a warm cache):

    >>> import numpy as np
    >>> import bubblefit as bf
    >>> scene = bf.Scene.from_dict({
    ...     "camera": {"width": 48, "height": 48, "disc": [24, 24, 20]},
    ...     "bubble": {"thickness_nm": 600.0, "t": 0.972, "f": 0.3, "roughness": 0.02},
    ...     "lighting": {"envmap": "courtyard.exr", "background": "black"}})
    >>> photo = np.asarray(bf.render_scene(scene))
    >>> parallel = bf.resolve_view(fov_deg=0, width=48, height=48)  # rendered with parallel rays
    >>> result = bf.fit_photo(photo, scene.load_envmap(), background=np.zeros_like(photo),
    ...                       options=bf.FitOptions(disc=(24, 24, 20), view=parallel))
    >>> result.ok, round(float(result.params["thickness_nm"]))
    (True, 600)
    """
    if options.calibrate_camera and options.thickness == "map":
        raise InputError("--calibrate-camera fits the response with a constant film or a drainage profile, not a "
                         "thickness map: calibrate with --thickness drainage, then fit the map with the response")
    if options.calibrate_camera:
        options = _with_lobes(options, scene)
    stated = replace(options, calibrate_camera=False) if options.calibrate_camera else options
    fit = _fit_views(photo, env, stated, background, init, scene, saturated)
    if not options.calibrate_camera:
        return fit
    # the stated response's fit first, then the response freed
    from .self_calibration import self_calibrated

    return self_calibrated(fit, photo, env, options, background, scene, saturated)


def _with_lobes(options: FitOptions, scene) -> FitOptions:
    """``options`` with the 8-lobe ``fourier`` quadrature whose lobes a camera's
    self-calibration frees (:mod:`~bubblefit.inverse.self_calibration`), unless the options
    or the scene's ``[effects]`` set a quadrature (which the calibration then refuses
    unless it is ``fourier``)."""
    stated = dict(options.effects)
    if "spectral" in stated or (scene is not None and "spectral" in scene.table("effects")):
        return options
    return replace(options, effects=(*options.effects, ("spectral", {"method": "fourier", "samples": 8})))


def _fit_views(photo, env, options: FitOptions, background, init, scene, saturated) -> FitResult:
    """The fit through the camera's view (:func:`~bubblefit.inverse._view.fit_view`): the
    scene's or the options', else the orthographic view and a 50 mm lens compared
    (:func:`fit_photo`)."""
    view = fit_view(options, scene)
    options = replace(options, view=view)
    if view.source != "assumed":
        return _fit_model(photo, env, options, background, init, scene, saturated)
    t0 = time.perf_counter()
    ortho = _fit_model(photo, env, options, background, init, scene, saturated)
    lens = lens_for(photo)
    start = {k: v for k, v in ortho.params.items() if np.isfinite(v)} if ortho.converged else init
    with stage(f"the same fit through a {lens.fov_deg:.0f} degree lens (the view was not given)"):
        lens_fit = _fit_model(photo, env, replace(options, view=lens), background, start, scene, saturated)

    def refit(view, start):
        with stage(f"the same fit through a {view.fov_deg:.1f} degree view (fitting the view's divergence)"):
            return _fit_model(photo, env, replace(options, view=view), background, start, scene, saturated)

    # the photo may fix the view: fit its divergence; else keep the better view, errors widened
    out = fit_divergence(ortho, lens_fit, lens, refit)
    out.time_s = time.perf_counter() - t0
    return out


def _fit_model(photo, env, options: FitOptions, background, init, scene, saturated) -> FitResult:
    """One view's fit: ``auto`` (:func:`_fit_either_model`) or one model (:func:`_fit_one`)."""
    if options.model == "auto":
        return _fit_either_model(photo, env, options, background, init, scene, saturated)
    return _fit_one(photo, env, options, background, init, scene, saturated)


@dataclass(frozen=True)
class Solved:
    """One model's fit up to its judgement (:func:`_solve_started`): what ``auto`` compares
    before the thickness map and the final render are made for the model it keeps.

    Its ``status``, ``converged``, ``chi2_floor``, ``chi2_capped`` and ``params`` read as a
    :class:`FitResult`'s do, from the solve's standard errors (:func:`_judge`); a map's
    failure is known only once :func:`_report` has made it.
    """

    setup: Setup
    options: FitOptions
    solution: LocalSolution
    judged: Judgement
    notes: list
    t_start: float

    @property
    def model(self) -> str:
        return self.options.model

    @property
    def status(self) -> str:
        return self.judged.status

    @property
    def converged(self) -> bool:
        return bool(self.judged.converged)

    @property
    def chi2_floor(self) -> float:
        return float(self.judged.uncertainty.misfit.chi2_floor)

    @property
    def chi2_capped(self) -> float:
        return float(self.judged.uncertainty.misfit.chi2_capped)

    @property
    def params(self) -> dict:
        """The reported values as :func:`_report` writes them (with ``n_film``), less a
        map's median thickness."""
        return {**self.judged.reported, "n_film": float(self.setup.vals["n_film"])}

    def report(self, env) -> FitResult:
        """The thickness map, the final render and the verdict (:func:`_report`)."""
        with stage("thickness map, final render" if self.options.thickness == "map" else "final render"):
            return _report(self.setup, env, self.options, self.solution, self.judged, list(self.notes),
                           self.t_start)


@dataclass(frozen=True)
class Started:
    """One model's fit up to its local solve (:func:`_start_one`): the set-up, the start the
    solve takes and, after a global search, the search winner's noise-weighted reduced
    chi^2 on the search image (None for a warm start) and its candidates' order test
    (:mod:`bubblefit.inverse.order_check`; None for a warm start or a response taken as
    exact)."""

    setup: Setup
    options: FitOptions
    start: dict
    settings: SolveSettings
    warm: bool
    searches: bool
    search_chi2: float | None
    t_start: float
    order: OrderCheck | None = None


def _start_one(photo, env, options: FitOptions, background, init, scene, saturated,
               settings: SolveSettings | None = None, compile_ahead: bool = True) -> Started:
    """Set-up and, for a fit that is not warm-started, the global search of one model's
    fit through ``options.view``; ``settings``: the local solve's (default: a warm start's
    when ``init`` is given, else a searched fit's); ``compile_ahead``: start the local
    solve's programs during the search (:func:`~._programs.warm_up`)."""
    t_start = time.perf_counter()
    opts = options
    with stage("finding the disc, choosing the effects"):
        st = setup(photo, env, opts, background, init, scene, saturated)
    searches = "thickness_nm" in st.table.free or "top_nm" in st.table.free
    warm = bool(init)
    settings = settings or (WARM_SOLVE if warm else FINAL_SOLVE)
    chi2, order = [], []
    if searches and not warm:
        if compile_ahead:
            warm_up(st, opts, env, settings)  # the final solve's programs compile during the search
        with stage("global thickness search"):
            start = _searched_start(st, opts, env, chi2, order)
    elif not warm and "exposure" in st.table.free and st.lev_fit.cfg.effects.interference in GREY:
        # a grey film: no thickness search sets the camera gain, its least-squares value does
        start = dict(st.vals, exposure=search.grey_exposure(st.level(st.k_search, opts), st.table, st.vals, env))
    else:
        start = st.vals
    return Started(st, opts, start, settings, warm, searches, chi2[0] if chi2 else None, t_start,
                   order[0] if order else None)


def _search_chi2(started: Started, env) -> tuple[float, dict]:
    """A short solve (``search_steps`` steps, as the global search refines its candidates)
    from ``started.start`` on the search image: its noise-weighted reduced chi^2 there and
    the values it reached (all finite, else ``started.start``)."""
    st, opts = started.setup, started.options
    lev_s = st.level(st.k_search, opts)
    sol = solve_local(lev_s, st.search_table, opts.solver, started.start, env, max_steps=opts.solver.search_steps,
                      settings=SEARCH_SOLVE)
    reached = sol.values if all(np.isfinite(v) for v in sol.values.values()) else started.start
    return _reduced_search_chi2(sol.cost, lev_s, st), reached


def _solve_started(started: Started, env) -> Solved:
    """The local solve and the standard errors of a :func:`_start_one`."""
    st, opts, settings = started.setup, started.options, started.settings
    with stage(f"local fit, {len(st.table.free)} parameters"):
        sol = solve_local(st.lev_fit, st.table, opts.solver, started.start, env, settings=settings)
    notes = []
    if started.warm and started.searches:
        sol = _checked_warm_start(st, opts, env, sol, settings, notes)
    with stage("standard errors"):
        judged = _judge(st, opts, sol, notes)
    order = started.order
    if order is None and started.warm and started.searches:
        order = _warm_order(st, opts, env)
    if order is not None:
        judged = replace(judged, order=order)
    return Solved(st, opts, sol, judged, notes, started.t_start)


def _fit_one(photo, env, options: FitOptions, background, init, scene, saturated) -> FitResult:
    """The stages of one model's fit through ``options.view`` (:func:`_start_one`, then
    :func:`_solve_started` and the report); a sequence's warm-started map whose start
    carries a solve's global parameters first tries them held (:func:`_carried_map_fit`)."""
    started = _start_one(photo, env, options, background, init, scene, saturated)
    quick, why = _carried_map_fit(started, env, init)
    if quick is not None:
        return quick
    res = _solve_started(started, env).report(env)
    if why:
        note = f"global parameters solved again: {why}"
        res = replace(res, message=note if res.message == "converged" else f"{res.message}; {note}")
    return res


def _checked_warm_start(st: Setup, opts: FitOptions, env, sol: LocalSolution, settings: SolveSettings,
                        notes: list) -> LocalSolution:
    """A warm start can settle in a neighbouring colour order: when its solution is
    doubtful (:func:`_warm_doubt`), search globally, solve again (stopping on rejections,
    :class:`~bubblefit.inverse._programs.SolveSettings`) and keep whichever fit explains
    the photo better; ``notes`` says what was done."""
    why = _warm_doubt(st, opts, sol)
    if not why:
        return sol
    with stage(f"warm start doubtful ({why}): global search and local fit"):
        second = solve_local(st.lev_fit, st.table, opts.solver, _searched_start(st, opts, env), env,
                             settings=settings)
    if np.isfinite(second.cost) and (not np.isfinite(sol.cost) or second.cost < sol.cost):
        notes.append(f"warm start rejected ({why}); searched globally")
        return second
    notes.append(f"warm start doubtful ({why}); a global search did not do better")
    return sol


def _judged_chi2(r: FitResult) -> float:
    """The misfit ``auto`` compares: the reduced chi^2 with the model-error floor, each
    pixel's share capped at an outlier's (:func:`bubblefit.inverse._uncertainty.misfit`),
    so that glints both models point-sample do not decide between them. A failed fit
    (diverged, a non-finite residual, a singular Jacobian) scores infinity, whatever its
    residual says."""
    if r.status == "failed" or not np.isfinite(r.chi2_capped):
        return float("inf")
    return float(r.chi2_capped)


def _judged_text(r: FitResult) -> str:
    """:func:`_judged_chi2` as ``auto``'s message writes it ("failed" for a failed fit)."""
    return "failed" if r.status == "failed" else f"{_judged_chi2(r):.3g}"


def explained(r: FitResult, judge: JudgeSettings) -> bool:
    """Whether a fit explains its photo: converged, with the reduced chi^2 with the
    model-error floor within ``judge.ok_chi2``."""
    return bool(r.converged) and r.chi2_floor <= float(judge.ok_chi2)


def _fit_either_model(photo, env, options: FitOptions, background, init, scene, saturated) -> FitResult:
    """``model = "auto"``: the paper model (eq. 11); when it does not explain the photo,
    the physical model (Fresnel per polarisation, internal bounces) warm-started from the
    paper fit's values, and whichever explains the photo better (the lower reduced chi^2
    with the model-error floor, each pixel's share capped at an outlier's,
    :func:`_judged_chi2`; a converged fit before one that is not). Uncapped, the glints
    of a sun that both models point-sample decided: on a Blender Cycles photo (development case cyc_drain_lin_sunrise_persp, experiments/validation/split.toml) the
    physical model's right profile (top 148 nm for 150) scored 70.5 against the paper
    model's 18.5 (top 105 nm), capped 1.83 against 4.65.

    The paper model's two-beam film and grey ``t`` bias a real film's drainage ends and
    leave a misfit that hides a wrong map; a photo from a physical film (another renderer,
    a camera) is explained by the physical model, within its floor.

    Only the kept model's thickness map and final render are made: the models are
    compared by their solves' standard errors (:class:`Solved`), which the map does not
    change, so a model's map is never made to be discarded.

    Which model is solved first (:func:`_auto_order`): the paper model's global search is
    cheap (eq. 11 is linear in a tabulated interference factor, :mod:`.search`). When its
    winner leaves a noise-weighted reduced chi^2 above :data:`WARM_START_CHI2` on the
    search image (the bound a warm start is doubted by) and the physical model's short
    solve there from that winner (:func:`_search_chi2`) leaves a lower one, the physical
    model is solved first, from the search's start (the paper model's local solve only
    refines that start within its colour order, which the physical solve does as well):
    a photo of a real film costs one model's fit and a search. Otherwise (a photo the
    paper model explains, as its own renders) and for warm starts, the paper model is
    solved first. The first model's fit is kept when it explains the photo (its map, when
    one is made, included), the physical model solved first also when it explains it up to
    a local misfit (:func:`_keeps_first`: the capped measure the final comparison reads);
    else the other model is solved and the two compared."""
    t0 = time.perf_counter()

    def begin(model: str, start=init, settings: SolveSettings | None = None) -> Started:
        """One model's set-up and, unless warm-started, global search (:func:`_start_one`)."""
        return _start_one(photo, env, replace(options, model=model), background, start, scene, saturated, settings)

    with stage("paper model"):
        started = {"paper": begin("paper")}
    order, labels, why = _auto_order(started, begin, env)
    solved, made = {}, {}  # made: the first model's report, when made
    for model in order:
        paper = solved.get("paper")
        with stage(labels.get(model) or f"physical model (the paper model's reduced chi^2 {_judged_text(paper)} "
                                        "with the floor, capped)"):
            if model not in started:  # the physical model after the paper model's solve, from its values
                start = {k: v for k, v in paper.params.items() if np.isfinite(v)} if paper.converged else init
                started[model] = begin(model, start, WARM_SOLVE if start else None)
            solved[model] = _solve_started(started[model], env)
        if model == order[0] and _keeps_first(solved[model], model, options.judge):
            made[model] = early = solved[model].report(env)
            if _keeps_first(early, model, options.judge):  # its map, when one is made, is sound
                early.message += f"; model auto: {why}" + _local_text(early, options.judge)
                early.time_s = time.perf_counter() - t0
                return early
    paper, physical = solved["paper"], solved["physical"]
    c1, c2 = _judged_chi2(paper), _judged_chi2(physical)
    kept = "physical" if (not physical.converged, c2) < (not paper.converged, c1) else "paper"
    best = made.get(kept) or solved[kept].report(env)
    best.message += (f"; model auto: paper reduced chi^2 {_judged_text(paper)}, physical {_judged_text(physical)} "
                     f"(with the floor, each pixel capped at an outlier's share): kept the {best.model} model")
    best.time_s = time.perf_counter() - t0
    return best


def _keeps_first(r, model: str, judge: JudgeSettings) -> bool:
    """Whether ``auto`` keeps the model it solved first (``model``) without solving the
    other (:func:`_fit_either_model`): when it explains the photo (:func:`explained`), or,
    for the physical model solved first because it explained the search image better than
    the paper model's global search (:func:`_auto_order`: the two models already
    compared once), when converged with the measure the final comparison reads within
    ``judge.ok_chi2``: the reduced chi^2 with the floor, each pixel's share capped at an
    outlier's (:func:`_judged_chi2`). A misfit left in a few pixels (the glints of a sun
    that both models point-sample) then decides neither which model is kept nor whether
    the other is solved. The paper model solved first keeps the uncapped rule: it comes
    first by default, not by a comparison, and a capped misfit within the limit does not
    mean the physical model would not explain the photo better (a development case,
    ref_drain_lin_courtyard_ortho in experiments/validation/split.toml: capped 1.79 for
    the paper model, 0.61 for the physical model it kept)."""
    if explained(r, judge):
        return True
    return model == "physical" and bool(r.converged) and _judged_chi2(r) <= float(judge.ok_chi2)


def _local_text(r, judge: JudgeSettings) -> str:
    """What ``auto``'s message adds when its first model is kept by the capped misfit
    alone (:func:`_keeps_first`): that measure, beside the uncapped one."""
    if explained(r, judge):
        return ""
    return (f" up to a local misfit (reduced chi^2 with the floor {r.chi2_floor:.3g}, each pixel capped at an "
            f"outlier's share {_judged_chi2(r):.3g}): the paper model's local fit was not run")


def _auto_order(started: dict, begin, env) -> tuple[tuple, dict, str]:
    """``auto``'s order of solves (:func:`_fit_either_model`: the paper model, eq. 11, and
    the physical model) from the paper model's global search in ``started``: when its winner leaves the search image unexplained
    (reduced chi^2 above :data:`WARM_START_CHI2`), the physical model's set-up and short
    solve there from that winner (``begin(model, start, settings)`` sets a model up; its
    :class:`Started` joins ``started``), which comes first when its reduced chi^2 there is
    the lower. Returns the models in order, the stage labels known before solving, and
    what the message says when the first model explains the photo."""
    begun = started["paper"]
    if begun.search_chi2 is not None and not begun.search_chi2 <= WARM_START_CHI2:
        # both models on the search image from the paper search's start; the physical
        # model's short solve there (its exposure differs from the paper model's) says
        # whether it explains the photo better than the paper model can
        start = {k: float(v) for k, v in begun.start.items() if np.isfinite(v)}
        with stage("physical model on the search image"):
            started["physical"] = begin("physical", start, WARM_SOLVE)
            raced, reached = _search_chi2(started["physical"], env)
        if raced < begun.search_chi2:
            # the fit image's solve starts where the search image's stopped: a coarser
            # pyramid level's solution, as the paper search's winner is the paper model's
            started["physical"] = replace(started["physical"], start=reached)
            return (("physical", "paper"),
                    {"physical": f"physical model first (search image reduced chi^2 {raced:.3g} against the paper "
                                 f"model's {begun.search_chi2:.3g})", "paper": "paper model's local fit"},
                    f"on the search image the physical model's reduced chi^2 {raced:.3g} (noise-weighted) against "
                    f"the paper model's {begun.search_chi2:.3g}: fitted the physical model first, which explains "
                    "the photo")
        started.pop("physical")  # the paper model first; the physical model from its values
    return ("paper", "physical"), {"paper": "paper model's local fit"}, "the paper model explains the photo"


def _batch_starts(first: Setup, n: int, prev_vals: dict | None) -> list:
    """Frame ``k``'s start: the free thicknesses extrapolated linearly,
    ``init + (k + 1) (init - previous)`` (:func:`~bubblefit.inverse._parameters.extrapolated`)."""
    prev = None if prev_vals is None else {k: v for k, v in prev_vals.items() if k in first.table.free}
    return [np.asarray(first.table.unconstrained(extrapolated(first.vals, prev, k + 1))) for k in range(n)]


def fit_batch(photos, env: EnvMap, *, options: FitOptions = FitOptions(), background=None, init: dict,
              previous: dict | None = None, scene=None) -> list[FitResult]:
    """Fit consecutive frames of a sequence together, warm-started, in one vmapped solve.

    Frame ``k`` of the batch starts from ``init`` (the last fitted frame's params) with
    its thicknesses extrapolated from ``previous`` (:func:`_batch_starts`). One
    Levenberg-Marquardt solve runs for all frames at once (:func:`jax.vmap` over frames;
    the loop runs until the slowest frame has converged). Each solution then gets
    :func:`fit_photo`'s warm-start check; a doubtful one is refitted alone by
    :func:`fit_photo` (global search included). Whether this is faster than fitting frame
    after frame depends on the machine (``experiments/bench_sequence.py``: on a 2-core
    CPU it is slower). Frames must share their size, the disc (give ``options.disc``)
    and ``background``; otherwise, or for a single frame, each is fitted alone.

    Returns
    -------
    list of FitResult
        One per photo, in order.
    """
    photos = [np.asarray(p, np.float64) for p in photos]
    t_start = time.perf_counter()
    alone = lambda photo, start: fit_photo(photo, env, options=options, background=background, init=start,
                                           scene=scene)
    if len(photos) < 2 or options.disc is None or len({p.shape for p in photos}) != 1:
        return [alone(p, init) for p in photos]
    first = setup(photos[0], env, options, background, init, scene, None)
    table = first.table
    if not any(n in table.free for n in THICKNESSES):
        return [alone(p, init) for p in photos]
    setups = [first] + [setup(p, env, options, background, init, scene, None, decided=(first.fx, first.decisions))
                        for p in photos[1:]]
    prev_vals = defaults(scene, previous, options)[0] if previous else None
    z0 = _batch_starts(first, len(photos), prev_vals)
    fixed = held_values(table, first.vals)
    union = np.logical_or.reduce([s.lev_fit.mask for s in setups])  # a frame's other pixels: weight 0
    pxs = [fitted_pixels(s.lev_fit, s.lev_fit.cfg.chunk, union) for s in setups]
    pad = pxs[0].padded
    lm = options.solver
    solve = batched_solver(pad.cfg, table, float(lm.robust_scale), int(lm.max_steps), float(lm.rtol), float(lm.atol),
                           None)
    out = solve(jnp.asarray(np.stack(z0), jnp.float32),
                (fixed, env, pad.bg, pad.bg_sigma, jnp.stack([x.y for x in pxs]), jnp.stack([x.w for x in pxs]), pad.base,
                 (pxs[0].rows, pxs[0].cols, pxs[0].idx)))
    outs = [np.asarray(x) for x in out]
    share = (time.perf_counter() - t_start) / len(photos)  # each frame's part of the batch
    results = []
    for k, st in enumerate(setups):
        t0 = time.perf_counter() - share
        sol = solution_from(table, st.vals, *(x[k] for x in outs), fixed, st.lev_fit, pxs[k])
        why = _warm_doubt(st, options, sol)
        if why:
            start = {key: float(x) for key, x in reporter(table)[0](jnp.asarray(outs[0][k]), fixed).items()}
            ok_start = all(np.isfinite(x) for x in start.values())
            results.append(alone(photos[k], dict(init, **start) if ok_start else init))
            results[-1].message = f"batched warm start doubtful ({why}); refitted alone: {results[-1].message}"
            continue
        results.append(_finish(st, env, options, sol, ["batched warm start"], t0))
    return results
