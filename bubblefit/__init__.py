"""bubblefit: differentiable rendering and fitting of soap bubbles from photographs.

Implements, in JAX, Morris, "Capturing the Reflectance Model of Soap Bubbles": an
environment map filtered by Ward's BRDF, tinted by thin-film interference, composited
over two films and the background, and fits it to photographs with optimistix.

The package follows the paper's structure, each dependency pointing down the list:

- :mod:`bubblefit.optics`: one film (eqs. 1, 8-10, Airy, Fresnel) and colour.
- :mod:`bubblefit.lighting`: environment maps and their filtering (eqs. 4-7, 12-13).
- :mod:`bubblefit.model`: geometry, thickness, effects, compositing (eq. 11), scenes.
- :mod:`bubblefit.inverse`: fitting photographs and sequences.
- :mod:`bubblefit.capture`: calibration of t (sec. 3.3), probes, capture protocols.
- :mod:`bubblefit.io`: image files.
- :mod:`bubblefit.cli`: the ``bubblefit`` command.

The names below are the public API. They are loaded on first use, so that
``import bubblefit`` (and the command line's ``--help``) stays fast.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_EXPORTS = {
    # forward model
    "Scene": "model.scene", "load_scene": "model.scene", "render_scene": "model.scene",
    "Params": "model.render", "RenderConfig": "model.render", "render": "model.render",
    "render_terms": "model.render", "Effects": "model.effects", "SceneSummary": "model.bounds",
    "OrthographicCamera": "model.geometry", "PerspectiveCamera": "model.geometry",
    "EnvMap": "lighting.envmap", "FilterConfig": "lighting.filtering",
    "spectral_basis": "optics.spectral", "interference_colours": "optics.chart",
    # fitting
    "FitOptions": "inverse.fit", "FitResult": "inverse.fit", "fit_photo": "inverse.fit",
    "NoiseSettings": "inverse.fit", "MapSettings": "inverse.fit", "JudgeSettings": "inverse.fit", "ImageSizes": "inverse.fit",
    "SolverSettings": "inverse.fit",
    "fit_sequence": "inverse.sequence", "fit_spectrum": "inverse.spectrum",
    "fit_spectrum_series": "inverse.spectrum_series", "read_spectrum": "io.spectra",
    # calibration and capture
    "CalibrationResult": "capture.calibrate", "calibrate": "capture.calibrate",
    "unwrap_mirror_ball": "capture.probe", "check_capture": "capture.protocols",
    "View": "capture.view", "resolve_view": "capture.view",
    # files and errors
    "read_image": "io.images", "write_image": "io.images",
    "BubblefitError": "errors", "InputError": "errors",
}
_ALIASES = {"resolve_effects": ("model.effects", "resolve")}

__all__ = sorted(_EXPORTS) + sorted(_ALIASES)


def __getattr__(name: str):
    if name in _EXPORTS:
        module, attr = _EXPORTS[name], name
    elif name in _ALIASES:
        module, attr = _ALIASES[name]
    else:
        raise AttributeError(f"module 'bubblefit' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
