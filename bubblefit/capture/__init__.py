"""Capturing the data a fit needs: transmission, environment probes and capture checks.

- :mod:`.calibrate`: the transmission fraction t from a dark-box pair (sec. 3.3), a
  pipeline of the steps below.
- :mod:`.pair`: reading and checking a before/after pair.
- :mod:`.registration`: phase-correlation and ECC registration, image shifts.
- :mod:`.circle`: the algebraic (Kasa) circle fit and the bubble of a dark-box pair.
- :mod:`.profile`: the radial (Fresnel) profile of the ratio across the disc.
- :mod:`.ratio`: usable pixels, the robust ratio and its block bootstrap.
- :mod:`.result`: :class:`CalibrationResult`, its JSON and debug image.
- :mod:`.disc`: the bubble's disc in a photo, with or without a background photo.
- :mod:`.rim`: a circle's rim along rays: support, sub-pixel rim, roundness.
- :mod:`.ball`: finding the mirror ball in a photograph.
- :mod:`.hdr`: merging a bracket of exposures to HDR, camera responses.
- :mod:`.probe`: unwrapping a mirror ball to an equirectangular map.
- :mod:`.protocols`: machine-checkable capture protocols (specs; the checks in
  :mod:`.checks`, their measurements in :mod:`.measure`, the report in :mod:`.report`).
"""

from . import ball, calibrate, circle, disc, hdr, pair, probe, profile, protocols, ratio, registration, result, rim
from .ball import find_ball
from .calibrate import calibrate as calibrate_transmission
from .circle import kasa_circle_fit
from .disc import Disc, find_disc
from .hdr import merge_exposures
from .probe import unwrap_mirror_ball
from .protocols import check_capture
from .registration import phase_correlate, register_translation, shift_image
from .result import CalibrationResult

__all__ = ["ball", "calibrate", "circle", "disc", "hdr", "pair", "probe", "profile", "protocols", "ratio",
           "registration", "result", "rim", "CalibrationResult", "calibrate_transmission", "Disc", "find_disc",
           "kasa_circle_fit", "phase_correlate", "register_translation", "shift_image", "find_ball",
           "merge_exposures", "unwrap_mirror_ball", "check_capture"]
