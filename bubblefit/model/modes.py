"""The mode strings of the forward model, each defined once as a ``Literal`` type.

Scenes name these values in their ``[effects]``, ``[bubble.thickness]`` and ``[lighting]``
tables (``docs/design.md``, "Scene files"); the renderer, the effects decisions and the
fit compare against them. The upper-case tuples are the same sets for validation, messages and the
command line's ``choices``: this module imports neither JAX nor any other part of the
package, so ``bubblefit --help`` reads its choices here without loading the renderer. The
filtering and spectral methods live with their implementations
(:data:`bubblefit.lighting.filtering.METHODS`, :data:`bubblefit.optics.spectral.SPECTRAL_METHODS`).
"""

from __future__ import annotations

from typing import Literal, get_args


__all__ = ["Model", "ModelChoice", "Interference", "Background", "ThicknessKind", "Switch", "MODELS",
           "MODEL_CHOICES", "INTERFERENCE_MODES", "BACKGROUNDS", "THICKNESS_KINDS", "COLOURED", "GREY", "in_words"]

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
