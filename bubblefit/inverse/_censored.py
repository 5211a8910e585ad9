"""Censored observations: channels the sensor clipped at black or at white.

A channel at a clip records only that the true value lies beyond it, so it carries a
residual only when the model lies on the wrong side of the clip (a censored observation,
in the sense of a Tobit model; J. Tobin, *Econometrica* 26, 24-36, 1958).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = ["BLACK_CLIP", "censored_residual"]

#: Linear value at or below which a channel is taken as clipped at black: 8-bit sRGB code
#: 6 (0.0018). A sensor's read noise scatters a clipped channel over the first few codes
#: (3 e- RMS at 4000 e- full well is 0.00075, code 2.5), so a colour outside the gamut
#: reads as a small positive value, not as the negative one the model gives.
BLACK_CLIP = 0.002


def censored_residual(y, m, high=np.inf, xp=jnp):
    """``y - m`` where the sensor recorded the value; for a channel clipped at black (``y <= BLACK_CLIP``)
    or at white (``y >= high``, 1 for 8/16-bit files) only a model on the wrong side of
    the clip leaves a residual (a censored observation). Colours of thin films lie
    outside the sRGB gamut (a negative channel), so real and rendered 8-bit photos clip
    at black."""
    r = y - m
    return xp.where(y <= BLACK_CLIP, xp.minimum(r, 0.0), xp.where(y >= high, xp.maximum(r, 0.0), r))
