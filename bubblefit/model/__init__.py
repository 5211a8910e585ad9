"""The soap bubble's forward model: geometry, thickness, effects, compositing and scenes.

- :mod:`.geometry`: cameras, front and rear films, internal bounces.
- :mod:`.thickness`: constant film, drainage profile, thickness map.
- :mod:`.modes`: the mode strings (``Literal`` types) of scenes and effects.
- :mod:`.effects`: the static set of terms a render computes, and decisions from scalar bounds.
- :mod:`.bounds`, :mod:`.footprint`, :mod:`.auto`: ``auto`` per pixel: the film's coefficient
  tables, what each pixel's films read, and the cheapest choice within each pixel's budget.
- :mod:`.render`: eq. (11) (``paper``), the ``physical`` variant, point lights eqs. (2)-(3).
- :mod:`.scene`: scene files (TOML) and rendering them.
"""

from . import effects, geometry, render, scene, thickness
from .effects import Effects
from .geometry import OrthographicCamera, PerspectiveCamera
from .render import Params, RenderConfig, render_terms
from .scene import Scene, load_scene, render_scene

__all__ = ["effects", "geometry", "render", "scene", "thickness", "Effects", "OrthographicCamera",
           "PerspectiveCamera", "Params", "RenderConfig", "render_terms", "Scene", "load_scene",
           "render_scene"]
