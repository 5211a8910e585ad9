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
- :mod:`._options`: :class:`FitOptions` and :class:`FitResult`.
- :mod:`.fit`: the orchestrators :func:`fit_photo` and :func:`fit_batch`.
- :mod:`.sequence`: a video of a draining bubble, frame by frame, locally or on Dask.
"""

from . import fit, search, sequence
from ._disc import Disc, find_bubble
from ._observation import detect_disc, noise_sigma
from ._options import FitOptions, FitResult, FitStatus, ForwardModel, ThicknessModel
from ._parameters import PARAMETERS, Parameter, ParameterTable
from .fit import fit_batch, fit_photo
from .sequence import SequenceResult, fit_sequence

__all__ = ["fit", "search", "sequence", "FitOptions", "FitResult", "FitStatus", "ForwardModel", "ThicknessModel",
           "fit_batch", "fit_photo", "Disc", "detect_disc", "find_bubble", "noise_sigma", "PARAMETERS", "Parameter",
           "ParameterTable", "SequenceResult", "fit_sequence"]
