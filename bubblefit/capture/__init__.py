"""Capturing the data a fit needs: transmission, environment probes and capture checks.

- :mod:`.calibrate`: the transmission fraction t from a dark-box pair (sec. 3.3).
- :mod:`.probe`: mirror-ball probes to equirectangular maps, HDR merging.
- :mod:`.protocols`: machine-checkable capture protocols.
"""

from . import calibrate, probe, protocols
from .calibrate import CalibrationResult
from .calibrate import calibrate as calibrate_transmission
from .probe import find_ball, merge_exposures, unwrap_mirror_ball
from .protocols import check_capture

__all__ = ["calibrate", "probe", "protocols", "CalibrationResult", "calibrate_transmission",
           "find_ball", "merge_exposures", "unwrap_mirror_ball", "check_capture"]
