"""The mode strings of the forward model, each defined once as a ``Literal`` type.

Scenes name these values in their ``[effects]``, ``[bubble.thickness]`` and ``[lighting]``
tables (``docs/design.md``, "Scene files"); the renderer, the effects decisions and the
fit compare against them. The ``*_VALUES`` tuples are the same sets for validation and
messages. The filtering and spectral methods live with their implementations
(:mod:`bubblefit.lighting.filtering`, :mod:`bubblefit.optics.spectral`) and are re-exported
here.
"""

from __future__ import annotations

from typing import Literal, get_args

from ..errors import InputError
from ..lighting.filtering import METHODS as FILTER_METHODS
from ..lighting.filtering import FilterMethod
from ..optics.spectral import SPECTRAL_METHODS, SpectralMethod

__all__ = ["Model", "ModelChoice", "Interference", "Background", "ThicknessKind", "Switch", "FilterMethod",
           "SpectralMethod", "MODELS", "MODEL_CHOICES", "INTERFERENCE_MODES", "BACKGROUNDS", "THICKNESS_KINDS",
           "FILTER_METHODS", "SPECTRAL_METHODS", "COLOURED", "GREY", "check_effects_table", "in_words"]

#: ``paper``: eqs. (1)-(14) as written; ``physical``: Fresnel films, Airy sum, internal bounces.
Model = Literal["paper", "physical"]
#: The forward model a fit is asked for: one of :data:`Model`, or ``auto`` (the paper model,
#: then the physical one when the paper model does not explain the photo;
#: :func:`~bubblefit.inverse.fit.fit_photo`).
ModelChoice = Literal["paper", "physical", "auto"]
#: How a film reflects: grey (``off``: no film factor; ``incoherent``: the spectral mean),
#: eq. (9)'s two beams, or the exact Airy sum (multi-beam).
Interference = Literal["off", "incoherent", "two_beam", "airy"]
#: What lies behind the bubble.
Background = Literal["envmap", "black", "photo"]
#: The film thickness model (:mod:`bubblefit.model.thickness`).
ThicknessKind = Literal["constant", "drainage", "map"]
#: A term's scene setting: on, off, or decided by its bound.
Switch = bool | Literal["auto"]

MODELS: tuple[str, ...] = get_args(Model)
MODEL_CHOICES: tuple[str, ...] = get_args(ModelChoice)
INTERFERENCE_MODES: tuple[str, ...] = get_args(Interference)
BACKGROUNDS: tuple[str, ...] = get_args(Background)
THICKNESS_KINDS: tuple[str, ...] = get_args(ThicknessKind)
#: Interference modes with a spectrum (colours), and the grey ones.
COLOURED: tuple[str, ...] = ("two_beam", "airy")
GREY: tuple[str, ...] = ("off", "incoherent")


def in_words(values: tuple[str, ...]) -> str:
    """``values`` as a sentence's list: ``"a, b or c"`` (for messages naming a mode's values)."""
    return values[0] if len(values) == 1 else ", ".join(values[:-1]) + " or " + values[-1]


def check_effects_table(e: dict) -> None:
    """Values of a scene's ``[effects]`` table (``docs/design.md``, "Scene files"), checked
    before anything is computed; raises :class:`~bubblefit.errors.InputError` naming the key."""

    def one_of(key, allowed):
        if key in e and e[key] not in allowed:
            raise InputError(f"effects.{key} must be one of {', '.join(map(str, allowed))}, got {e[key]!r}")

    one_of("interference", ("auto",) + INTERFERENCE_MODES)
    one_of("filtering", ("auto",) + FILTER_METHODS)
    for key in ("front_reflection", "rear_reflection", "transmission", "transmission_tint", "diffuse"):
        if key in e and not isinstance(e[key], bool) and e[key] != "auto":
            raise InputError(f"effects.{key} must be true, false or \"auto\", got {e[key]!r}")
    if "bounces" in e and e["bounces"] != "auto" and not (isinstance(e["bounces"], int) and 0 <= e["bounces"] <= 64):
        raise InputError(f"effects.bounces must be \"auto\" or an integer in [0, 64], got {e['bounces']!r}")
    for key, lo, hi in (("nodes", 1, 32), ("window", 0, 4096), ("level", 0, 32)):
        if key in e and not lo <= e[key] <= hi:
            raise InputError(f"scene value effects.{key} = {e[key]} is out of range [{lo}, {hi}]")
    if "tolerance" in e and not e["tolerance"] > 0:
        raise InputError(f"scene value effects.tolerance = {e['tolerance']} must be positive")
    spec = e.get("spectral", "auto")
    if isinstance(spec, str):
        if spec != "auto" and spec not in SPECTRAL_METHODS:
            raise InputError(f"effects.spectral must be \"auto\", one of {', '.join(SPECTRAL_METHODS)} "
                             f"or a table {{method, samples}}, got {spec!r}")
    else:
        unknown = set(spec) - {"method", "samples"}
        method, samples = spec.get("method", "uniform"), spec.get("samples", 30)
        if unknown or method not in SPECTRAL_METHODS or isinstance(samples, bool) \
                or not isinstance(samples, int) or not 1 <= samples <= 4000:
            raise InputError("effects.spectral table must be {method = uniform|reference|fourier, "
                             f"samples = 1..4000}}, got {spec!r}")
