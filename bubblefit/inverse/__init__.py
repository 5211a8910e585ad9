"""Measuring a bubble: fitting the forward model to photographs and to sequences of them.

The fit of one photograph runs in stages, each in its own module:

- :mod:`._observation`: the photo's noise, clipped pixels, which disc the fit uses, and the
  photo at the resolution a stage runs at.
- :mod:`._parameters`: every fitted parameter described once (unit, bounds, transform,
  reference), and one fit's table of free and held parameters.
- :mod:`._setup`: starting values, the effects, the camera.
- :mod:`.search`: the global thickness search (tabulated interference, candidate images).
- :mod:`._programs`: the compiled programs (solves, renders of a level padded to a few
  sizes), prepared, stored and loaded.
- :mod:`._local`: the local Levenberg-Marquardt solve (:mod:`._lm`: the solver).
- :mod:`._uncertainty`: covariance and standard errors.
- :mod:`._maps`: per-pixel thickness maps.
- :mod:`._verdict`: whether a fit can be trusted (``ok``) and why not.
- :mod:`._options`: :class:`FitOptions`, what a fit is told.
- :mod:`._result`: :class:`FitResult`, what it returns.
- :mod:`.fit`: the orchestrators :func:`fit_photo` and :func:`fit_batch`.
- :mod:`.sequence`: a video of a draining bubble, frame by frame, locally or on Dask
  (its planning, executors, record store and tables in ``_plan``, ``_executors``,
  ``_records`` and ``_tables``).
- :mod:`.spectrum`: film thickness from a spectrometer reading (global profile likelihood).

The underscored modules are this subpackage's own; code outside it takes their names from
``bubblefit.inverse``.
"""

import importlib

# Names of the public namespace and the module each comes from; a submodule is imported
# when one of its names is first used (PEP 562), so that a fit does not import the
# spectrometer or sequence code and their libraries. Besides the entry points, each
# stage's own functions and records are named here: the stages are the subpackage's API
# (its tests and benchmarks call them), the modules that hold them are not.
_EXPORTS = {
    # entry points and their records
    "FitOptions": "_options", "FitResult": "_result", "FitStatus": "_result", "ForwardModel": "_options",
    "NoiseSettings": "_options", "MapSettings": "_options", "JudgeSettings": "_options", "ImageSizes": "_options",
    "SolverSettings": "_options",
    "ThicknessModel": "_options", "fit_batch": "fit", "fit_photo": "fit", "SequenceOptions": "sequence",
    "SequenceResult": "sequence", "fit_sequence": "sequence", "SpectrumFit": "spectrum",
    "SpectrumOptions": "spectrum", "fit_spectrum": "spectrum", "fit_spectrum_series": "spectrum_series",
    # observe: noise, clipped pixels, the frame, the levels, which disc
    "Disc": "_observation", "find_bubble": "_observation", "detect_disc": "_observation",
    "noise_sigma": "_observation", "analysis_frame": "_observation", "Level": "_observation",
    "resolve_disc": "_observation", "saturation_mask": "_observation", "block_mean": "_observation",
    "censored_residual": "_censored",
    # the parameters: described once, one fit's table, their roles, a user's settings
    "PARAMETERS": "_parameters", "Parameter": "_parameters", "ParameterTable": "_parameters",
    "ParameterSetting": "_parameters", "parse_setting": "_parameters", "starts": "_parameters", "parameter_roles": "_parameters",
    "refined_disc": "_parameters", "disc_start": "_parameters", "extrapolated": "_parameters", "inverse": "_parameters", "plausible_box": "_parameters",
    # set up, and the camera's view
    "Setup": "_setup", "setup": "_setup", "defaults": "_setup", "colour_settings": "_setup",
    "calibrated_illuminant": "_setup", "compact_source": "_setup", "COMPACT_SOURCE_RATIO": "_setup",
    "fit_view": "_view", "widen_for_view": "_view", "fit_divergence": "_view", "divergence_profile": "_view",
    "fit_spectral_basis": "_spectral_rule", "quadrature_excess": "_spectral_rule",
    "FIT_SPECTRAL_CANDIDATES": "_spectral_rule", "QUADRATURE_EXCESS": "_spectral_rule",
    # compiled programs: the padded level, its fitted pixels, the renders of a level
    "padded": "_programs", "padded_size": "_programs", "fitted_pixels": "_programs",
    "pixel_bucket": "_programs", "render_level": "_programs", "render_bubble": "_programs",
    "bubble_list": "_programs", "solver": "_programs", "solve_pixels": "_programs", "rim_blocks": "_programs",
    # solve: Levenberg-Marquardt and the local solve
    "LevenbergMarquardt": "_lm_solver", "DenseDampedNewtonDescent": "_lm_solver", "column_jacobian": "_lm",
    "scaled_decrement": "_lm", "damped_step_length": "_lm", "gauss_newton_decrement": "_lm", "robust": "_lm",
    "LocalSolution": "_local", "remaining_step": "_local", "improves": "_local", "restart_moved": "_local",
    # judge: standard errors, the misfit, the verdict
    "Misfit": "_uncertainty", "misfit": "_uncertainty", "held_keys": "_uncertainty",
    "at_bounds": "_verdict", "clamp_to_range": "_verdict", "unresolved": "_verdict", "verdict": "_verdict",
    # thickness maps
    "COARSE_RADIUS": "_maps", "profile_map": "_maps", "RenderCosts": "_maps", "TracedCosts": "_map_pixels",
    # sequences: frames, executors, records, tables
    "FrameRef": "_plan", "load_frame": "_plan", "local_env": "_executors", "SchedulerAddress": "_executors",
    "local_cluster": "_executors", "start_client": "_executors", "base_record": "_records",
    "result_record": "_records", "flag_jumps": "_tables", "write_tables": "_tables", "row_ok": "_tables",
    # spectra: what the readings are, their noise, the extrema test
    "in_time_order": "_spectrum_defaults", "looks_normalised": "_spectrum_defaults",
    "same_grid": "_spectrum_defaults", "series_sides": "_spectrum_drain", "drain_path": "_spectrum_drain",
    "series_groups": "_spectrum_defaults", "SeriesGroup": "_spectrum_defaults",
    "FixedLampProblem": "_shared_lamp", "SharedLamp": "_shared_lamp", "alternative_lamps": "_shared_lamp", "MAX_ALTERNATIVE_LAMPS": "_shared_lamp",
    "shared_lamp": "_shared_lamp",
    "candidate_stderr": "_spectrum_drain", "isotonic_blocks": "_spectrum_drain",
    "noise_says_divided": "_spectrum_defaults", "series_departures": "_spectrum_defaults",
    "DIVIDED_NOISE_RATIO": "_spectrum_defaults", "local_noise": "_spectrum_profile",
    "positive_lamp_lstsq": "_spectrum_profile", "fringe_extrema": "_spectrum_extrema",
    "extrema_phase": "_spectrum_extrema", "RANDOM_PHASE": "_spectrum_extrema",
    "fringe_minima": "_spectrum_extrema", "minima_phase": "_spectrum_extrema",
    # is the pair a photo and its background, in that order; is the exposure possible
    "PairCheck": "_pair", "check_pair": "_pair", "check_disc_pair": "_plan", "judge_pair": "_pair",
    "frame_mismatch": "_pair", "outside_mismatch": "_pair", "transmission_floor": "_pair", "LUMINANCE": "_pair",
    "least_reflectance": "_exposure", "map_levels": "_exposure", "exposure_range": "_exposure",
    "exposure_doubt": "_exposure", "quiet_resource_tracker": "_executors", "close_local_cluster": "_executors",
    # flat films: a drainage profile along gravity
    "search_drainage": "_drainage_plane", "drainage_covariance": "_drainage_plane",
}
_SUBMODULES = ("fit", "search", "sequence", "spectrum")


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(__all__)


__all__ = [*_SUBMODULES, *_EXPORTS]
