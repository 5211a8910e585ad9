"""The soap bubble's forward model: geometry, thickness, effects, compositing and scenes.

- :mod:`.geometry`: cameras, front and rear films, internal bounces.
- :mod:`.thickness`: constant film, drainage profile, thickness map.
- :mod:`.effects`: which terms a scene needs, decided from bounds (``auto``).
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
