"""Measuring a bubble: fitting the forward model to photographs and to sequences of them.

The fit of one photograph runs in stages, each in its own module:

- :mod:`._observation`: the photo's noise, clipped pixels, the bubble's disc, and the photo
  at the resolution a stage runs at.
- :mod:`._parameters`: every fitted parameter described once (unit, bounds, transform,
  reference), and one fit's table of free and held parameters.
- :mod:`._setup`: starting values, the effects, the camera.
- :mod:`.search`: the global thickness search (tabulated interference, candidate images).
- :mod:`._local`: the local Levenberg-Marquardt solve.
- :mod:`._uncertainty`: covariance and standard errors.
- :mod:`._maps`: per-pixel thickness maps.
- :mod:`._verdict`: whether a fit can be trusted (``ok``) and why not.
- :mod:`._options`: :class:`FitOptions` and :class:`FitResult`.
- :mod:`.fit`: the orchestrators :func:`fit_photo` and :func:`fit_batch`.
- :mod:`.sequence`: a video of a draining bubble, frame by frame, locally or on Dask
  (its planning, executors, record store and tables in ``_plan``, ``_executors``,
  ``_records`` and ``_tables``).
- :mod:`.spectrum`: film thickness from a spectrometer reading (global profile likelihood).
"""

import importlib

# Names of the public namespace and the module each comes from; a submodule is imported
# when one of its names is first used (PEP 562), so that a fit does not import the
# spectrometer or sequence code and their libraries.
_EXPORTS = {
    "Disc": "_disc", "find_bubble": "_disc", "detect_disc": "_disc", "noise_sigma": "_observation",
    "FitOptions": "_options", "FitResult": "_options", "FitStatus": "_options", "ForwardModel": "_options",
    "ThicknessModel": "_options", "PARAMETERS": "_parameters", "Parameter": "_parameters",
    "ParameterTable": "_parameters", "fit_batch": "fit", "fit_photo": "fit", "SequenceOptions": "sequence",
    "SequenceResult": "sequence", "fit_sequence": "sequence", "SpectrumFit": "spectrum",
    "SpectrumOptions": "spectrum", "fit_spectrum": "spectrum", "fit_spectrum_series": "spectrum_series",
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
