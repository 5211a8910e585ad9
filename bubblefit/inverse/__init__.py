"""Measuring a bubble: fitting the forward model to photographs and to sequences of them.

- :mod:`.fit`: one photograph (global thickness search, Levenberg-Marquardt, uncertainty).
- :mod:`.search`: tabulated interference for the global search over thickness.
- :mod:`.sequence`: a video of a draining bubble, frame by frame, locally or on Dask
  (its planning, executors, record store and tables in ``_plan``, ``_executors``,
  ``_records`` and ``_tables``).
"""

from . import fit, search, sequence
from .fit import FitOptions, FitResult, fit_batch, fit_photo
from .sequence import SequenceOptions, SequenceResult, fit_sequence

__all__ = ["fit", "search", "sequence", "FitOptions", "FitResult", "fit_batch", "fit_photo",
           "SequenceOptions", "SequenceResult", "fit_sequence"]
