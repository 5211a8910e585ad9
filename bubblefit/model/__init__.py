"""The soap bubble's forward model: geometry, thickness, effects, compositing and scenes.

- :mod:`.geometry`: cameras, front and rear films, internal bounces.
- :mod:`.thickness`: constant film, drainage profile, thickness map.
- :mod:`.modes`: the mode strings (``Literal`` types) of scenes and effects.
- :mod:`.effects`: the static set of terms a render computes, and decisions from scalar bounds.
- :mod:`.bounds`, :mod:`.footprint`, :mod:`.auto`: ``auto`` per pixel: the film's coefficient
  tables, what each pixel's films read, and the cheapest choice within each pixel's budget.
- :mod:`.render`: eq. (11) (``paper``), the ``physical`` variant, point lights eqs. (2)-(3).
- :mod:`.scene`: scene files (TOML) and rendering them.

The names below are loaded on first use (as :mod:`bubblefit`'s are).
"""

from __future__ import annotations

import importlib

_MODULES = ("effects", "geometry", "render", "scene", "thickness")
_EXPORTS = {"Effects": "effects", "SceneSummary": "bounds", "OrthographicCamera": "geometry", "PerspectiveCamera": "geometry",
            "Params": "render", "RenderConfig": "render", "render_terms": "render", "Scene": "scene",
            "load_scene": "scene", "render_scene": "scene",
            # a scene's value checks that the command line shares
            "samples_per_pixel": "_scene_checks", "white_balance": "_scene_checks"}

__all__ = list(_MODULES) + list(_EXPORTS)


def __getattr__(name: str):
    """The subpackage's names, loaded on first use, so that :mod:`.modes` (the command
    line's choices) is read without the renderer and JAX."""
    if name in _MODULES:
        value = importlib.import_module(f".{name}", __name__)
    elif name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
