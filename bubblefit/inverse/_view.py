"""Which view a photo fit renders with, and what an unknown view may change.

:func:`fit_view` chooses the view: a scene file's camera, else the options' (a field of
view from an option or the photo's EXIF), else an assumed orthographic one. An assumed
view is not silently trusted: :func:`widen_for_view` compares the orthographic fit with the
same fit through a plausible lens (:func:`~bubblefit.capture.view.assumed_lens`), keeps the
one that explains the photo better, and adds the difference to each standard error as a
Type B uncertainty. :func:`fit_divergence` first fits the view's divergence
``u = tan(fov/2)`` from the photo (a 1-D search over warm-started refits, bracketed by
the two views); only where the photo does not constrain it are the errors widened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..capture.view import MAX_FOV_DEG, View, assumed_lens, disc_angles, divergence, fov_of_divergence, scene_view
from ..errors import InputError
from ..model.geometry import DivergentCamera
from ._options import FitOptions
from ._result import FitResult

__all__ = ["fit_view", "camera_record", "widen_for_view", "lens_for", "fit_divergence", "divergence_profile",
           "Profile"]


def fit_view(options: FitOptions, scene) -> View:
    """The view a fit renders with: the scene's camera (:func:`~bubblefit.capture.view.scene_view`)
    over the photo's EXIF; an option that contradicts the scene's camera is refused; with
    neither, an orthographic view whose source is ``assumed``."""
    stated = scene_view(scene)
    given = options.view
    if stated is not None:
        if given is not None and given.source == "option" and (given.kind, given.fov_deg) != (stated.kind,
                                                                                               stated.fov_deg):
            raise InputError(f"the view is given twice: the scene file's {stated.kind} camera and {given.detail}; "
                             "give one")
        return stated
    return given or View("orthographic", None, "assumed", "no field of view given or in the photo's EXIF")


def camera_record(view: View, camera) -> dict:
    """The JSON's ``camera``: the view's record (:meth:`~bubblefit.capture.view.View.to_json`)
    and, for a pinhole, its distance to the sphere's centre in sphere radii: the pinhole's
    origin's, or for a :class:`~bubblefit.model.geometry.DivergentCamera` ``1 / sin(alpha)``
    of the half-angle its disc subtends in that view (:func:`~bubblefit.capture.view.disc_angles`,
    as :func:`~bubblefit.capture.view.perspective_from_disc` places the pinhole)."""
    out = view.to_json()
    origin = getattr(camera, "origin", None)
    if view.kind == "perspective" and origin is not None:
        out["distance_radii"] = float(np.linalg.norm(np.asarray(origin, float)))
    elif view.kind == "perspective" and isinstance(camera, DivergentCamera):
        cx, cy, r = camera.disc()
        rho = math.hypot(cx - camera.width / 2.0, camera.height / 2.0 - cy)
        _, alpha = disc_angles(rho, r, 2.0 * divergence(view.fov_deg) / camera.width)
        out["distance_radii"] = 1.0 / math.sin(float(alpha))
    return out


def widen_for_view(kept: FitResult, other: FitResult, lens: View) -> FitResult:
    """``kept`` (the fit through the view that explained the photo better, of the assumed
    orthographic one and the plausible ``lens``) with each standard error widened by the
    shift to ``other`` (the fit through the other view), and a warning saying so.

    The true view lies between parallel rays and, for most photos of a bubble, a normal
    lens; with nothing to tell where, the parameter's shift between the two fits,
    ``Delta = p_other - p_kept``, bounds a rectangular distribution about the reported
    value, of standard uncertainty ``|Delta| / sqrt(3)`` (GUM 4.3.7), added in quadrature to
    the standard error (and to the covariance's diagonal, and to a thickness map's errors
    by the thickness's). A lens wider than ``lens`` (a phone's 26 mm) can move the
    parameters further. When ``other`` did not converge, nothing is added and the warning
    says so.

    References
    ----------
    JCGM 100:2008 (GUM), sec. 4.3.7 (Type B evaluation from bounds).
    """
    out = replace(kept, stderr=dict(kept.stderr), warnings=list(kept.warnings))
    cam = dict(kept.camera or {})
    cam["compared_fov_deg"] = float(lens.fov_deg)
    which = (f"fitted as orthographic and through a {lens.detail.split(',')[0].removeprefix('a ')} "
             f"({lens.fov_deg:.1f} degrees across); kept the {cam.get('kind', 'orthographic')} view, which explains "
             "the photo better" if cam.get("kind") == "perspective" else "fitted as orthographic")
    if not other.converged:
        out.warnings.append(f"the view was not given (--fov, --focal-length or the photo's EXIF): {which}; the fit "
                            f"through the other view did not converge, so the standard errors do not include what "
                            "the view changes: give the view")
        out.camera = cam
        return out
    u = {}
    for k, e in kept.stderr.items():
        a, b = kept.params.get(k), other.params.get(k)
        if e is None or a is None or b is None or not (math.isfinite(e) and math.isfinite(a) and math.isfinite(b)):
            continue
        u[k] = abs(b - a) / math.sqrt(3.0)
        out.stderr[k] = math.hypot(e, u[k])
    if out.covariance is not None and len(out.names):
        cov = np.array(out.covariance, np.float64)
        for i, n in enumerate(out.names):
            cov[i, i] += u.get(n, 0.0) ** 2
        out.covariance = cov
    if out.thickness_stderr_map is not None and "thickness_nm" in u:
        out.thickness_stderr_map = np.hypot(out.thickness_stderr_map, u["thickness_nm"])
    cam["view_uncertainty"] = {k: float(v) for k, v in u.items()}
    out.camera = cam
    moved = ", ".join(f"{k} by {abs(other.params[k] - kept.params[k]):.3g}"
                      for k in ("thickness_nm", "top_nm", "bottom_nm", "t") if k in u)
    if cam.get("kind") != "perspective":
        which += (f"; a {lens.detail.split(',')[0].removeprefix('a ')} ({lens.fov_deg:.1f} degrees across) would "
                  "explain it no better")
    out.warnings.append(f"the view was not given (--fov, --focal-length or the photo's EXIF): {which}; the other "
                        f"view moves {moved}: the standard errors include |shift|/sqrt(3)")
    return out


def lens_for(photo) -> View:
    """:func:`~bubblefit.capture.view.assumed_lens` of ``photo``'s width and height."""
    return assumed_lens(int(photo.shape[1]), int(photo.shape[0]))


def _chi2(r: FitResult) -> float:
    """A fit's total capped chi^2 with the floor on the level its solve ran: its
    ``solve_misfit.chi2_capped`` times its degrees of freedom (three channels a pixel of
    ``pixels_used``, less the free parameters), infinite for a fit that did not converge."""
    capped = r.solve_misfit.chi2_capped if r.solve_misfit is not None else r.chi2_capped
    if not r.converged or r.status == "failed" or not math.isfinite(capped):
        return float("inf")
    return float(capped) * max(3 * int(r.pixels_used) - len(r.names), 1)


@dataclass(frozen=True)
class Profile:
    """The view's divergence a photo's chi^2 profile gives (:func:`divergence_profile`).

    Attributes
    ----------
    u, stderr : float
        The fitted divergence ``u = tan(fov/2)`` and its standard error: the half-width of
        the interval where the profile's chi^2 lies within ``Delta`` of its least.
    constrained : bool
        Whether the photo fixes it: the least point has a neighbour on either side in
        ``u`` (or lies at the orthographic boundary ``u = 0``), the parabola through them
        curves upward and the standard error is below half the span of the views tried.
    points : tuple
        The divergences of the three refits the parabola went through.
    above : bool
        Whether the least point is the largest divergence tried: the minimum may lie
        beyond the views tried.
    """

    u: float
    stderr: float
    constrained: bool
    points: tuple = ()
    above: bool = False


def divergence_profile(us, chi2s, birge: float = 1.0, area: float = 1.0) -> Profile:
    """The divergence where the parabola through the least of ``(us, chi2s)`` (total chi^2
    of refits through each view) and its two neighbours in ``u`` is least, and its
    standard error: the half-width ``sqrt(Delta / a)`` of the interval where the parabola
    ``a (u - u*)^2 + chi2_min`` rises by ``Delta = birge^2 area`` (``Delta chi^2 = 1`` on a
    profile, times the reduced chi^2 at the minimum when above 1: the Birge ratio squared;
    times the residual's correlation area when above 1: the chi^2 counts each pixel's
    channels as independent, and ``n`` data correlated over ``area`` of them carry the
    information of ``n / area`` independent ones, Bayley and Hammersley 1946,
    :func:`~bubblefit.inverse._uncertainty.correlation_area`).

    The least point and its neighbours on either side bracket the profile's minimum
    (golden-section bracketing, Numerical Recipes sec. 10.1). When the least point is the
    largest ``u`` tried, the parabola goes through it and its two lower neighbours and the
    minimum is not bracketed: not constrained (``above``; :func:`fit_divergence` then
    extends the bracket). When it is ``u = 0``, the orthographic boundary closes the
    bracket: the parabola goes through it and its two upper neighbours, and a minimum
    below 0 is the orthographic view. The parabola's curvature is the profile's near its
    minimum only when the three points lie within a few standard errors of it:
    :func:`fit_divergence` refits until they lie within three before it reads the interval.

    References
    ----------
    W. H. Press et al., *Numerical Recipes*, 3rd ed., 2007, sec. 10.1 (bracketing a
    minimum), sec. 10.3 (parabolic interpolation) and sec. 15.6.5 (confidence limits from
    Delta chi^2 = 1 on a profile); D. J. Venzon and S. H. Moolgavkar, Appl. Statist. 37,
    87 (1988) (profile-likelihood intervals); R. T. Birge, Phys. Rev. 40, 207 (1932);
    G. V. Bayley and J. M. Hammersley, J. R. Statist. Soc. Suppl. 8(2), 184 (1946)
    (the effective number of independent observations).
    """
    pts = sorted((u, c) for u, c in zip(us, chi2s) if math.isfinite(c))
    if len(pts) < 3:
        return Profile(float("nan"), float("inf"), False)
    i = min(range(len(pts)), key=lambda k: (pts[k][1], pts[k][0]))
    j = min(max(i - 1, 0), len(pts) - 3)  # the least point and its neighbours; at an end, the end's three
    (u0, c0), (u1, c1), (u2, c2) = pts[j:j + 3]
    above = i == len(pts) - 1 and pts[i][0] > 0
    a, b, _ = np.polyfit([u0, u1, u2], [c0, c1, c2], 2)
    span = max(u for u, _ in pts)
    if not a > 0:
        return Profile(float(pts[i][0]), float("inf"), False, (u0, u1, u2), above)
    u_min = min(max(-b / (2 * a), 0.0), span)
    se = math.sqrt(max(area, 1.0) / a) * max(birge, 1.0)
    return Profile(float(u_min), float(se), bool(not above and se < 0.5 * span), (u0, u1, u2), above)


#: Refits :func:`fit_divergence` makes after the bracket before it stops, converged or not.
MAX_REFINE = 13
#: The golden section's smaller fraction, (3 - sqrt 5) / 2 (Numerical Recipes eq. 10.2.2).
GOLDEN = 0.3819660112501051


def _next_divergence(pts: list, prof: Profile, xs: list) -> float | None:
    """The next divergence to refit at in :func:`fit_divergence`'s minimisation of the
    profile ``pts`` (sorted ``(u, chi2)``, finite), whose parabola ``prof`` reads the
    minimum ``u*`` and standard error ``s``; None when it has converged: a refit lies
    within ``s / 4`` of ``u*`` and the parabola's three points within ``3 s`` of it.

    A safeguarded parabolic step (Brent's method, Numerical Recipes sec. 10.3) in the
    bracket ``(a, b)`` of the least point ``x`` (its neighbours; ``u = 0`` closes it at
    the orthographic boundary): while no refit lies within ``s / 4`` of ``u*``, a refit at
    ``u*``; once one does, at ``u* -+ 2 s`` (``-+ s`` when a refit lies within ``s / 4``
    of that, else the golden section of that side, eq. 10.2.2) on the side whose parabola
    point lies beyond ``3 s``. A step toward the long side of a lopsided bracket (one side
    over twice the other and over ``3 s``), where a parabola through it creeps in from
    that side, goes at least as far as the short side (a mirror of it) and ``2 s`` and,
    while ``u*`` has no refit and the least point keeps moving that way, 1.618 times its
    last move (the golden ratio's growth, sec. 10.1), never past the golden section of
    the long side. ``xs`` holds the least point of each call (appended to here)."""
    m, s = prof.u, prof.stderr
    us = [u for u, _ in pts]
    near = min(abs(u - m) for u in us)
    lo = [p for p in prof.points if p < m - 3.0 * s]
    hi = [p for p in prof.points if p > m + 3.0 * s]
    if near <= 0.25 * s and not lo and not hi:
        return None
    i = min(range(len(pts)), key=lambda k: (pts[k][1], pts[k][0]))
    x = us[i]
    below = x - us[i - 1] if i > 0 else 0.0
    above = us[i + 1] - x if i + 1 < len(us) else 0.0
    xs.append(x)
    moved = xs[-1] - xs[-2] if len(xs) >= 2 else 0.0
    if near > 0.25 * s:
        u = m
    else:
        side = -1.0 if lo and (not hi or m - min(lo) >= max(hi) - m) else 1.0
        u = next((m + side * k * s for k in (2.0, 1.0)
                  if m + side * k * s > 0 and min(abs(v - m - side * k * s) for v in us) > 0.25 * s), None)
        if u is None:
            return x + side * GOLDEN * (below if side < 0 else above)
    sign = 1.0 if u >= x else -1.0
    short, long_ = (below, above) if sign > 0 else (above, below)
    if long_ > 3.0 * s and long_ > 2.0 * short:
        d = max(abs(u - x), short, 2.0 * s, 1.618 * abs(moved) if moved * sign > 0 and near > 0.25 * s else 0.0)
        u = x + sign * min(d, GOLDEN * long_) if d > abs(u - x) else u
    return u


def fit_divergence(ortho: FitResult, lens_fit: FitResult, lens: View, refit) -> FitResult:
    """The fit through the view's divergence fitted from the photo, when nothing stated the
    view: ``u = tan(fov/2)`` (:func:`~bubblefit.capture.view.divergence`) profiled by
    warm-started refits (``refit(view, start)``: the fit through ``view``, started from the
    refit nearest it), the profile's minimum found by Brent's method.

    1. Bracket: the orthographic fit (``u = 0``), the ``lens`` fit and a refit halfway, a
       fourth at twice the lens's ``u`` when the lens's fit is the least; the least point
       and its neighbours in ``u`` bracket the minimum (:func:`divergence_profile`).
    2. Minimise: the parabola through the least point and its two neighbours reads a
       minimum ``u*`` and standard error ``s``; the photo is refitted one view at a time
       (:func:`_next_divergence`, Brent's safeguarded parabolic steps): at ``u*`` while no
       refit lies within ``s / 4`` of it, then at ``u* -+ 2 s`` on the side whose parabola
       point lies beyond ``3 s``, a step toward the long side of a lopsided bracket going
       further (at least the short side's length and ``2 s``, growing by the golden ratio
       while the least point keeps moving that way, at most the long side's golden
       section), until a refit lies within ``s / 4`` of ``u*`` and the parabola's three
       points within ``3 s`` of it: its curvature (and ``s``) is then the profile's near
       its minimum, not across the bracket. After :data:`MAX_REFINE` refits it stops; a
       warning says the view's profile did not converge, and ``s`` is widened in
       quadrature by the distance from ``u*`` to the kept refit.
    3. The view reported is the last ``u*``, with standard error ``s``; the fit kept is the
       refit nearest it (within ``s / 4`` when converged: the parameters at the minimum
       differ from its by at most a quarter of what the view's error adds to theirs).

    The kept fit's parameters ``p`` are conditional on the view; freeing it adds
    ``(dp/du)^2 var(u)`` to each variance and ``dp/du var(u)`` as the covariance with the
    view (the slope of a line through the refits the parabola went through), per pixel
    for a thickness map, and the view's ``fov_deg`` joins ``names``, with its standard
    error from ``var(u)`` by ``dfov/du = 2/(1+u^2)``. The standard error of ``u`` counts
    the residual's spatial correlation (the least refit's ``correlation_area``,
    :func:`divergence_profile`); the parameters' own errors already do (the cluster-robust
    sandwich, :mod:`bubblefit.inverse._uncertainty`). Where the profile is flat or its
    minimum is not bracketed, this is :func:`widen_for_view` of the better of the two
    first fits, and its warning says that the photo does not fix the view.

    References
    ----------
    Numerical Recipes, 3rd ed., 2007, sec. 10.2 (golden section), sec. 10.3 (Brent's
    parabolic interpolation, safeguarded) and sec. 15.6 (profile confidence regions);
    Venzon and Moolgavkar, Appl. Statist. 37, 87 (1988) (profile-likelihood intervals);
    JCGM 100:2008 (GUM) eq. 13 (propagation with correlated inputs).
    """
    width_fits = [(0.0, ortho), (divergence(lens.fov_deg), lens_fit)]
    u_lens = width_fits[1][0]
    best = min(width_fits, key=lambda p: _chi2(p[1]))[1]
    first = {k: v for k, v in best.params.items() if math.isfinite(v)}

    def through(u: float) -> FitResult:
        fov = fov_of_divergence(u)
        view = View("perspective", fov, "fitted", f"the view's divergence tried at {fov:.1f} degrees across")
        near = [p for p in fits if math.isfinite(_chi2(p[1]))]
        start = ({k: v for k, v in min(near, key=lambda p: abs(p[0] - u))[1].params.items() if math.isfinite(v)}
                 if near else first)
        return refit(view, start)

    def profile_now() -> Profile:
        ok = [f for _, f in fits if math.isfinite(_chi2(f))]
        least = min(ok, key=_chi2) if ok else None
        birge = math.sqrt(max(1.0, least.chi2_capped if least is not None else 1.0))
        area = float(least.correlation_area) if least is not None and math.isfinite(least.correlation_area) else 1.0
        return divergence_profile([u for u, _ in fits], [_chi2(f) for _, f in fits], birge, area)

    fits = list(width_fits)
    fits.append((u_lens / 2.0, through(u_lens / 2.0)))
    prof = profile_now()
    u_far = min(2.0 * u_lens, divergence(MAX_FOV_DEG) * 0.5)
    if prof.above:
        fits.append((u_far, through(u_far)))
        prof = profile_now()
    good, converged, steps, refits = None, False, [], 0
    while prof.constrained:
        good = prof
        pts = sorted((u, _chi2(f)) for u, f in fits if math.isfinite(_chi2(f)))
        u = _next_divergence(pts, prof, steps)
        converged = u is None
        if converged or refits == MAX_REFINE:
            break
        fits.append((u, through(u)))
        refits += 1
        prof = profile_now()
    lens_better = lens_fit.converged and _chi2(lens_fit) < _chi2(ortho)
    kept, other = (lens_fit, ortho) if lens_better else (ortho, lens_fit)
    if good is None:
        out = widen_for_view(kept, other, lens)
        out.camera = {**(out.camera or {}), "divergence_profile": _profile_record(fits)}
        out.warnings = [w + "; the photo does not fix the view (its chi^2 over the field of view is flat or "
                        "least outside the views tried)" if w.startswith("the view was not given") else w
                        for w in out.warnings]
        return out
    u_fit, fit = min(((u, f) for u, f in fits if math.isfinite(_chi2(f))), key=lambda p: abs(p[0] - good.u))
    se = good.stderr if converged else math.hypot(good.stderr, u_fit - good.u)
    used = [p for p in fits if any(p[0] == v for v in good.points) and math.isfinite(_chi2(p[1]))]
    out = _with_fitted_view(fit, good.u, se, used, _profile_record(fits), u_fit)
    if not converged:
        out.warnings.append(f"the view's chi^2 profile did not converge in {MAX_REFINE} refits (the refits nearest "
                            f"its minimum lie more than a quarter or three of its standard errors from it): the "
                            f"view's standard error is widened by the distance to the kept refit, "
                            f"{fov_of_divergence(u_fit):.2f} degrees across")
    return out


def _profile_record(fits: list) -> list:
    """The JSON's ``divergence_profile``: ``[fov_deg, capped reduced chi^2]`` of each view
    tried, in order of the field of view."""
    return [[fov_of_divergence(u), float(f.chi2_capped)] for u, f in sorted(fits, key=lambda p: p[0])]


def _with_fitted_view(fit: FitResult, u: float, se_u: float, fits: list, profile: list,
                      u_fit: float | None = None) -> FitResult:
    """``fit`` (the refit through ``u_fit``, nearest the profile's minimum ``u``; ``u`` when
    not given) reported at the divergence ``u`` with the view's variance ``se_u^2`` propagated
    into its parameters, and per pixel into its thickness map's errors, by the slopes
    ``dp/du`` of lines through ``fits`` (the refits near the minimum, :func:`fit_divergence`),
    ``fov_deg`` added to its covariance, and its camera record's source ``fitted``."""
    out = replace(fit, stderr=dict(fit.stderr), warnings=list(fit.warnings))
    us = np.array([p[0] for p in fits], float)
    var_u = se_u**2
    dfov = math.degrees(2.0 / (1.0 + u * u))  # d fov / d u, degrees
    slopes = {}
    for k, e in fit.stderr.items():
        vals = np.array([p[1].params.get(k, np.nan) for p in fits], float)
        if e is None or not math.isfinite(e) or not np.all(np.isfinite(vals)) or len(set(us)) < 2:
            continue
        slopes[k] = float(np.polyfit(us, vals, 1)[0])
        out.stderr[k] = math.sqrt(e * e + slopes[k] ** 2 * var_u)
    fov = fov_of_divergence(u)
    fov_se = dfov * se_u
    names = tuple(fit.names)
    if fit.covariance is not None and len(names):
        n = len(names)
        cov = np.zeros((n + 1, n + 1))
        cov[:n, :n] = np.asarray(fit.covariance, np.float64)
        s = np.array([slopes.get(nm, 0.0) for nm in names])
        cov[:n, :n] += np.outer(s, s) * var_u
        cov[:n, n] = cov[n, :n] = s * var_u * dfov
        cov[n, n] = fov_se**2
        out.covariance, out.names = cov, (*names, "fov_deg")
    if out.thickness_stderr_map is not None:
        maps = [p[1].thickness_map for p in fits]
        if len(set(us)) >= 2 and all(m is not None and np.shape(m) == np.shape(out.thickness_stderr_map)
                                     for m in maps):
            # per pixel: the slope of the least-squares line through the refits' maps
            du = us - us.mean()
            slope_map = np.tensordot(du / np.sum(du * du), np.stack([np.asarray(m, np.float64) for m in maps]), 1)
            slope_map = np.where(np.isfinite(slope_map), slope_map, slopes.get("thickness_nm", 0.0))
            out.thickness_stderr_map = np.hypot(out.thickness_stderr_map, slope_map * se_u)
        elif "thickness_nm" in slopes:
            out.thickness_stderr_map = np.hypot(out.thickness_stderr_map, slopes["thickness_nm"] * se_u)
    lo, hi = max(u - se_u, 0.0), u + se_u
    detail = f"the view's divergence fitted from the photo: {fov:.1f} +- {fov_se:.1f} degrees across"
    cam = {**(fit.camera or {}), "kind": "perspective" if u > 0 else "orthographic", "fov_deg": fov if u > 0 else None,
           "source": "fitted", "detail": detail, "fov_stderr_deg": fov_se, "fitted_fov_deg": fov,
           "fov_interval_deg": [fov_of_divergence(lo), fov_of_divergence(hi)],
           "refit_fov_deg": fov_of_divergence(u if u_fit is None else u_fit),
           "divergence_profile": profile, "correlation_area": float(fit.correlation_area),
           "view_uncertainty": {k: abs(v) * se_u for k, v in slopes.items()}}
    out.camera = cam
    out.warnings = [w for w in out.warnings if not w.startswith("the view was not given")]
    out.warnings.append(f"the view was not given (--fov, --focal-length or the photo's EXIF): {detail} (the "
                        "standard errors include what it changes); give the view if it is known")
    return out
