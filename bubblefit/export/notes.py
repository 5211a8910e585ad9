"""The sentences an export's log shares across formats: what a target renderer drops from a fit.

Each exporter lists its own format's limits and adds these where they apply, so one fact
about the fit (its roughness, its diffuse term, the paper model's constants) is worded once.
"""

from __future__ import annotations

import math

from .record import FittedBubble

__all__ = ["roughness_note", "diffuse_note", "paper_model_note"]


def roughness_note(bubble: FittedBubble, parameter: str) -> str:
    """Ward's a exported as a microfacet width alpha = a, i.e. the renderer's ``parameter = sqrt(a)``.

    Both Ward's lobe (paper eq. 8) and the GGX/Trowbridge-Reitz lobe of the target renderers
    have an angular width of about alpha for small alpha; renderers take a perceptual
    roughness whose square is alpha.
    """
    a = bubble.roughness
    return (f"roughness: Ward's a = {a:.4g} exported as the microfacet width alpha = a "
            f"({parameter} = sqrt(a) = {math.sqrt(max(a, 0.0)):.4g})")


def diffuse_note(bubble: FittedBubble, why: str | None = None) -> str | None:
    """The diffuse term r_d (paper eq. 14) the target material has no place for, or None when it is 0."""
    if bubble.r_d <= 0:
        return None
    return f"the diffuse term r_d = {bubble.r_d:.3g} is left out" + (f" ({why})" if why else "")


def paper_model_note(bubble: FittedBubble, how: str, *, with_r_s: bool = False) -> str | None:
    """The paper model's constant t (and r_s) that a Fresnel-driven material cannot carry, or None."""
    if bubble.model != "paper":
        return None
    what = f"t = {bubble.t:.4g}" + (f" and r_s = {bubble.r_s:.3g}" if with_r_s else "")
    return f"the paper model's {what} is not expressed: {how}"
