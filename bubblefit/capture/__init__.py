"""Capturing the data a fit needs: transmission, environment probes and capture checks.

- :mod:`.calibrate`: the transmission fraction t from a dark-box pair (sec. 3.3).
- :mod:`.ball`: finding the mirror ball in a photograph.
- :mod:`.hdr`: merging a bracket of exposures to HDR, camera responses.
- :mod:`.probe`: unwrapping a mirror ball to an equirectangular map.
- :mod:`.protocols`: machine-checkable capture protocols (specs; the checks in
  :mod:`.checks`, their measurements in :mod:`.measure`, the report in :mod:`.report`).
"""

from . import ball, calibrate, hdr, probe, protocols
from .ball import find_ball
from .calibrate import CalibrationResult
from .calibrate import calibrate as calibrate_transmission
from .hdr import merge_exposures
from .probe import unwrap_mirror_ball
from .protocols import check_capture

__all__ = ["calibrate", "ball", "hdr", "probe", "protocols", "CalibrationResult", "calibrate_transmission",
           "find_ball", "merge_exposures", "unwrap_mirror_ball", "check_capture"]
