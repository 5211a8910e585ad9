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

from . import fit, search, sequence, spectrum
from ._disc import Disc, find_bubble
from ._observation import detect_disc, noise_sigma
from ._options import FitOptions, FitResult, FitStatus, ForwardModel, ThicknessModel
from ._parameters import PARAMETERS, Parameter, ParameterTable
from .fit import fit_batch, fit_photo
from .sequence import SequenceOptions, SequenceResult, fit_sequence
from .spectrum import SpectrumFit, SpectrumOptions, fit_spectrum

__all__ = ["fit", "search", "sequence", "spectrum", "FitOptions", "FitResult", "FitStatus", "ForwardModel",
           "ThicknessModel", "fit_batch", "fit_photo", "Disc", "detect_disc", "find_bubble", "noise_sigma",
           "PARAMETERS", "Parameter", "ParameterTable", "SequenceOptions", "SequenceResult", "fit_sequence",
           "SpectrumFit", "SpectrumOptions", "fit_spectrum"]
