"""Which view a photo fit renders with, and what an unknown view may change.

:func:`fit_view` chooses the view: a scene file's camera, else the options' (a field of
view from an option or the photo's EXIF), else an assumed orthographic one. An assumed
view is not silently trusted: :func:`widen_for_view` compares the orthographic fit with the
same fit through a plausible lens (:func:`~bubblefit.capture.view.assumed_lens`), keeps the
one that explains the photo better, and adds the difference to each standard error as a
Type B uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..capture.view import View, assumed_lens, scene_view
from ..errors import InputError
from ._options import FitOptions, FitResult

__all__ = ["fit_view", "camera_record", "widen_for_view", "lens_for"]


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
    and, for a pinhole, its distance to the sphere's centre in sphere radii."""
    out = view.to_json()
    origin = getattr(camera, "origin", None)
    if view.kind == "perspective" and origin is not None:
        out["distance_radii"] = float(np.linalg.norm(np.asarray(origin, float)))
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
