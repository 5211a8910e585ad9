"""bubblefit: differentiable rendering and fitting of soap bubbles from photographs.

Implements, in JAX, Morris, "Capturing the Reflectance Model of Soap Bubbles": an
environment map filtered by Ward's BRDF, tinted by thin-film interference, composited
over two films and the background, and fits it to photographs with optimistix.

The public namespace is small; each concept lives in its own module:

- :mod:`bubblefit.film`: Snell, Fresnel, eq. (8)-(10) and the Airy film.
- :mod:`bubblefit.spectral`: spectra to linear sRGB (CIE 1931, D65).
- :mod:`bubblefit.brdf`: Ward's BRDF, eq. (1).
- :mod:`bubblefit.envmap`, :mod:`bubblefit.filtering`: maps and eqs. (4)-(7), (12)-(13).
- :mod:`bubblefit.geometry`: cameras, front/rear films, internal bounces.
- :mod:`bubblefit.render`: compositing, eqs. (2), (3), (11) and the physical variant.
- :mod:`bubblefit.effects`, :mod:`bubblefit.scene`: which effects a scene needs; scene files.
- :mod:`bubblefit.imageio`: image files through OpenImageIO.
"""

from .effects import Effects, resolve as resolve_effects
from .envmap import EnvMap
from .errors import BubblefitError, InputError
from .filtering import FilterConfig
from .render import Params, RenderConfig, render, render_terms
from .scene import Scene, load_scene, render_scene
from .spectral import spectral_basis

__version__ = "0.1.0"

__all__ = [
    "BubblefitError",
    "Effects",
    "EnvMap",
    "FilterConfig",
    "InputError",
    "Params",
    "RenderConfig",
    "Scene",
    "load_scene",
    "render",
    "render_scene",
    "render_terms",
    "resolve_effects",
    "spectral_basis",
]
