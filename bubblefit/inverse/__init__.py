"""Measuring a bubble: fitting the forward model to photographs and to sequences of them.

- :mod:`.fit`: one photograph (global thickness search, Levenberg-Marquardt, uncertainty).
- :mod:`.search`: tabulated interference for the global search over thickness.
- :mod:`.sequence`: a video of a draining bubble, frame by frame, locally or on Dask
  (its planning, executors, record store and tables in ``_plan``, ``_executors``,
  ``_records`` and ``_tables``).
- :mod:`.spectrum`: film thickness from a spectrometer reading (global profile likelihood).
"""

from . import fit, search, sequence, spectrum
from .fit import FitOptions, FitResult, fit_batch, fit_photo
from .sequence import SequenceOptions, SequenceResult, fit_sequence
from .spectrum import SpectrumFit, SpectrumOptions, fit_spectrum

__all__ = ["fit", "search", "sequence", "spectrum", "FitOptions", "FitResult", "fit_batch", "fit_photo",
           "SequenceOptions", "SequenceResult", "fit_sequence", "SpectrumFit", "SpectrumOptions", "fit_spectrum"]
