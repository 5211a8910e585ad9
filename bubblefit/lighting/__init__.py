"""Light arriving at the bubble: environment maps and their filtering by Ward's lobe.

- :mod:`.envmap`: equirectangular maps, texel directions and solid angles, mip levels.
- :mod:`.filtering`: eqs. (4)-(7), (12) and (13): mirror, window, mip-mapped and full sums.
"""

from . import envmap, filtering
from .envmap import EnvMap
from .filtering import FilterConfig

__all__ = ["envmap", "filtering", "EnvMap", "FilterConfig"]
