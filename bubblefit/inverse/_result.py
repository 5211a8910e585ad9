"""What a fit returns (:class:`FitResult`) and the colour settings it was evaluated with.

The JSON keys of :meth:`FitResult.to_json` are the command-line contract of
``bubblefit fit`` (``docs/design.md``, "Command line").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..model.modes import Model, ThicknessKind

if TYPE_CHECKING:
    from ._uncertainty import Misfit

__all__ = ["FitStatus", "FitResult", "ColourSettings"]

#: ``converged``: the local solver met its tolerances with finite errors;
#: ``max_steps``: it stopped at its step limit; ``failed``: it diverged, or the Jacobian
#: is singular at the optimum.
FitStatus = Literal["converged", "max_steps", "failed"]


@dataclass(frozen=True)
class ColourSettings:
    """How the fit's forward model turns a film into pixel values, beyond its parameters:
    the illuminant, the camera's response and white balance (:mod:`bubblefit.optics.spectral`),
    the film's index law (:mod:`bubblefit.optics.dispersion`; ``Params.n_film`` carries its
    value at 589.3 nm), the rays per pixel and how the physical model colours each film
    (:class:`~bubblefit.model.render.RenderConfig`, ``film_rgb``)."""

    illuminant: str = "D65"
    response: str = "srgb"
    white_balance: object = "illuminant"
    n_film: object = 1.4
    samples_per_pixel: int = 1
    film_rgb: str = "spectral"

    @property
    def default_colour(self) -> bool:
        """Whether illuminant, response and white balance are the defaults (D65, sRGB)."""
        return (self.illuminant, self.response, self.white_balance) == ("D65", "srgb", "illuminant")

    def to_json(self) -> dict:
        from ..optics.dispersion import Cauchy, describe

        wb = self.white_balance
        return {"illuminant": self.illuminant, "response": self.response,
                "white_balance": wb if isinstance(wb, str) else [float(g) for g in wb],
                "n_film": describe(self.n_film), "dispersive": isinstance(self.n_film, Cauchy),
                "samples_per_pixel": int(self.samples_per_pixel), "film_rgb": self.film_rgb}


def _clean(d: dict) -> dict:
    return {k: (None if v is None or not np.isfinite(v) else float(v)) for k, v in d.items()}


@dataclass
class FitResult:
    """What a fit found (see :meth:`to_json` for the command line's keys).

    Attributes
    ----------
    params : dict
        Reported values (t, r_d, r_s, f, roughness, thickness_nm, exposure, rotation_deg,
        n_film; top_nm, bottom_nm, exponent for a drainage profile).
    stderr : dict
        Standard errors of the same keys (None for held ones).
    held : list
        ``[(name, reason)]`` of parameters not fitted.
    roles : tuple
        The fit's parameter table (:class:`~bubblefit.inverse._parameters.ParameterRole`):
        for each reported parameter, whether it was fitted, derived (from what), held
        (why), given or unused by the model (JSON key ``parameters``; :meth:`report`).
    converged : bool
        True only when the solver met its tolerances and the errors are finite.
    message : str
        Why not, or notes.
    iterations : int
        Solver steps of the final refinement.
    residual_rms : float
        RMS of the linear residual over the fitted pixels (full resolution).
    time_s : float
        Wall time of the fit.
    effects : list
        The :class:`~bubblefit.model.effects.Decision` list.
    render, residual : np.ndarray
        (H, W, 3) fitted image and ``photo - render``.
    thickness_map, thickness_stderr_map : np.ndarray or None
        (H, W) front-film thickness (nm, NaN outside the bubble; None for a constant
        film) and the standard error of a fitted map.
    disc : tuple or None
        (cx, cy, r) used (orthographic camera) or None: refined by the fit when it was
        found (``FitOptions.fit_disc``).
    disc_stderr : dict or None
        Standard errors ``{cx, cy, r}`` in pixels of a refined disc (None: not fitted).
    thickness_model : ThicknessKind
        The thickness model fitted.
    status : FitStatus
        How the local solver ended.
    names : tuple
        The reported parameters the covariance is given for, in its order.
    covariance : np.ndarray or None
        Covariance of ``names`` (the fitted parameters in reported units).
    ok : bool
        True only when the solver converged, the bubble was found, no parameter sits at a
        bound and the photo is explained within its noise plus the model-error floor.
    warnings : list
        Each reason ``ok`` is False (and other cautions), in words.
    chi2_floor : float
        Reduced chi^2 with the model-error floor (``JudgeSettings.model_error``) of the
        final render against the photo's own pixels (full resolution; ``reduced_chi2``,
        the inliers, outliers and the capped figure likewise): what ``ok`` reads
        (:func:`~bubblefit.inverse._uncertainty.photo_misfit`).
    chi2_inliers : float
        The same over the pixels that are not outliers (JSON ``reduced_chi2_inliers``).
    outliers : float
        Fraction of the fitted pixels that are outliers (JSON ``outlier_fraction``;
        :data:`~bubblefit.inverse._uncertainty.OUTLIER_CHI2`).
    chi2_capped : float
        The reduced chi^2 with the floor, each pixel's share capped at an outlier's (JSON
        ``reduced_chi2_capped``): what ``model = "auto"`` compares (the two models' solves
        by their ``solve_misfit``'s, a model it keeps unsolved the other by this one).
    stderr_scale : float
        The largest factor a noise-only standard error was widened by for misfit (the
        Birge ratio or the cluster-robust sandwich, :mod:`bubblefit.inverse._uncertainty`).
    solve_misfit : Misfit or None
        The same figures on the level the solve ran (``pixels_used`` pixels, block-averaged
        where the photo is larger than the fit's size; JSON ``solve_misfit``): the standard
        errors' widening and a fitted view's chi^2 profile read them.
    correlation_area : float
        Data (pixels times channels) per independent datum of the fitted level's residual
        (:func:`~bubblefit.inverse._uncertainty.correlation_area`; 1: independent); a
        fitted view's standard error is widened by its square root.
    frame : tuple or None
        ``(x0, y0, k)``: the fit's images cover the photo from pixel ``(x0, y0)`` in blocks
        of ``k`` pixels (None: the whole photo at its own resolution).
    colour : ColourSettings or None
        The illuminant, camera response, white balance, index law and rays per pixel the
        forward model was evaluated with (JSON key ``colour``).
    camera : dict or None
        The view fitted (JSON key ``camera``): ``kind``, ``fov_deg``, ``source`` (``option``,
        ``EXIF``, ``scene``, ``fitted`` or ``assumed``), ``detail``; for a perspective camera its
        ``distance_radii`` (pinhole to the sphere's centre); for a fitted view
        ``fitted_fov_deg``, ``fov_stderr_deg``, the interval where the chi^2 profile lies
        within the Birge-widened ``Delta chi^2 = 1`` of its least (``fov_interval_deg``)
        and the views tried (``divergence_profile``); for an assumed view the lens it was compared with
        (``compared_fov_deg``); for both the standard uncertainty each parameter gained
        from the view (``view_uncertainty``).
    """

    params: dict
    stderr: dict
    held: list
    converged: bool
    message: str
    iterations: int
    residual_rms: float
    time_s: float
    effects: list
    render: np.ndarray
    residual: np.ndarray
    thickness_map: np.ndarray | None = None
    thickness_stderr_map: np.ndarray | None = None
    disc: tuple | None = None
    disc_stderr: dict | None = None
    thickness_model: ThicknessKind = "constant"
    model: Model = "paper"
    reduced_chi2: float = float("nan")
    pixels_used: int = 0
    status: FitStatus = "converged"
    names: tuple = ()
    covariance: np.ndarray | None = None
    ok: bool = False
    warnings: list = field(default_factory=list)
    chi2_floor: float = float("nan")
    chi2_inliers: float = float("nan")
    outliers: float = float("nan")
    chi2_capped: float = float("nan")
    model_error: float = float("nan")
    thickness_model_error_nm: float = 0.0
    disc_model_error: float = float("nan")
    roles: tuple = ()
    stderr_scale: float = 1.0
    solve_misfit: Misfit | None = None
    correlation_area: float = 1.0
    frame: tuple | None = None
    colour: ColourSettings | None = None
    camera: dict | None = None
    #: :meth:`bubblefit.inverse.colour_check.ColourCheck.to_json`, or None where not tested.
    colour_check: dict | None = None
    #: :meth:`bubblefit.inverse.self_calibration.SelfCalibration.to_json` with the stated
    #: response's fit, or None without ``FitOptions.calibrate_camera``.
    camera_calibration: dict | None = None
    #: A thickness map's global parameters as a sequence's next frame may carry them
    #: (``_carried.carried_record``: the map's reduced chi^2 with the floor and its
    #: degrees of freedom, the reported keys, their standard errors, the disc's, ``frames``
    #: since they were solved), or None.
    carried: dict | None = None
    #: The share of each standard error that is the calibrated camera response's: the
    #: standard error from the response's stated errors alone (included in ``stderr``;
    #: :mod:`bubblefit.inverse._uncertainty`), or None where the response is taken as exact.
    stderr_camera: dict | None = None
    #: :meth:`bubblefit.inverse.order_check.OrderCheck.to_json`: whether the photo tells the
    #: film's order (a constant film's, or a drainage profile's, which a map keeps) with the
    #: calibrated response's errors marginalised, or None where not tested (a response
    #: taken as exact, a fit without a thickness search).
    order_check: dict | None = None

    def to_json(self) -> dict:
        """The command line's result (``docs/design.md``): params, stderr, converged,
        iterations, residual_rms, time_s, and more."""
        cov = None
        if self.covariance is not None and len(self.names):
            m = np.asarray(self.covariance, np.float64)
            cov = {"names": list(self.names),
                   "matrix": [[None if not np.isfinite(v) else float(v) for v in row] for row in m]}
        return {
            "params": _clean(self.params),
            "stderr": _clean(self.stderr),
            "held": [{"name": n, "reason": r} for n, r in self.held],
            "parameters": [{"name": r.name, "role": r.role, "reason": r.reason} for r in self.roles],
            "converged": bool(self.converged),
            "ok": bool(self.ok),
            "warnings": list(self.warnings),
            "status": self.status,
            "message": self.message,
            "iterations": int(self.iterations),
            "residual_rms": float(self.residual_rms),
            "reduced_chi2": float(self.reduced_chi2),
            "reduced_chi2_floor": float(self.chi2_floor),
            "reduced_chi2_inliers": float(self.chi2_inliers),
            "outlier_fraction": float(self.outliers),
            "reduced_chi2_capped": float(self.chi2_capped),
            "model_error_floor": float(self.model_error),
            "thickness_model_error_nm": float(self.thickness_model_error_nm),
            "disc_model_error": None if not np.isfinite(self.disc_model_error) else float(self.disc_model_error),
            "stderr_scale": float(self.stderr_scale),
            "solve_misfit": None if self.solve_misfit is None else {
                "reduced_chi2": float(self.solve_misfit.chi2_nu),
                "reduced_chi2_floor": float(self.solve_misfit.chi2_floor),
                "reduced_chi2_inliers": float(self.solve_misfit.chi2_inliers),
                "outlier_fraction": float(self.solve_misfit.outliers),
                "reduced_chi2_capped": float(self.solve_misfit.chi2_capped)},
            "pixels_used": int(self.pixels_used),
            "time_s": float(self.time_s),
            "thickness": self.thickness_model,
            "model": self.model,
            "solver": "bubblefit.inverse._lm_solver.LevenbergMarquardt (optimistix trust region)",
            "disc": None if self.disc is None else {"cx": self.disc[0], "cy": self.disc[1], "r": self.disc[2]},
            "disc_stderr": None if self.disc_stderr is None else _clean(self.disc_stderr),
            "covariance": cov,
            "frame": None if self.frame is None else {"x0": int(self.frame[0]), "y0": int(self.frame[1]),
                                                      "block": int(self.frame[2])},
            "colour": None if self.colour is None else self.colour.to_json(),
            "camera": self.camera,
            "colour_check": self.colour_check,
            "camera_calibration": self.camera_calibration,
            "stderr_camera": None if self.stderr_camera is None else _clean(self.stderr_camera),
            "order_check": self.order_check,
            "effects": [{"effect": d.effect, "simulated": d.simulated, "setting": d.setting, "reason": d.reason}
                        for d in self.effects],
        }

    def report(self) -> str:
        """A readable summary: each parameter with its standard error and its row of the
        parameter table (:attr:`roles`: derived from what, held or unused and why), the
        solver's status, reduced chi^2 and the disc."""
        roles = {r.name: r for r in self.roles}
        held = dict(self.held)
        lines = []
        for k, v in self.params.items():
            err = self.stderr.get(k)
            known = err is not None and math.isfinite(err)
            row = roles.get(k)
            if row is not None and row.role == "derived":
                txt = (f"+- {err:.3g} " if known else "") + f"(derived: {row.reason})"
            elif row is not None and row.role in ("held", "unused"):
                txt = f"({'held' if row.role == 'held' else 'not used'}: {row.reason})"
            elif known:
                txt = f"+- {err:.3g}"
            elif k == "n_film":
                txt = "(given)"
            elif err is None:  # a result without its table: held, or set by held parameters
                why = held.get(k) or (held.get("split") if k in ("f", "r_d", "r_s") else None)
                txt = f"(held: {why})" if why else "(held)"
            else:
                txt = "(fitted; no standard error: the photo does not constrain it)"
            lines.append(f"{k:<13} {v:.6g} {txt}")
        lines.append(self.summary())
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def summary(self) -> str:
        """One line: the solver's status, steps, reduced chi^2, the disc and the time."""
        state = "converged" if self.converged else f"NOT CONVERGED ({self.status})"
        disc = "" if self.disc is None else " disc ({:.2f}, {:.2f}, r {:.2f}{}),".format(
            *self.disc, "" if self.disc_stderr is None else ", refined")
        outl = f", {self.chi2_inliers:.3g} without {self.outliers:.2%} outlier pixels" if self.outliers > 0 else ""
        return (f"ok {'yes' if self.ok else 'NO'}; {state}; {self.iterations} iterations, reduced chi^2 "
                f"{self.reduced_chi2:.3g} ({self.chi2_floor:.3g} with the model-error floor{outl}),{disc} "
                f"residual rms {self.residual_rms:.4g}, {self.time_s:.2f} s")
