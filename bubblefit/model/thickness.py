"""Film thickness fields over the bubble: constant, drainage profile, per-pixel map.

docs/design.md: the drainage profile is ``d = top + (bottom - top) ((1 - y) / 2)^exponent``
with ``y`` in [-1, 1] the height of the film point above the bubble's centre over its
radius: thin at the top (gravity drains the film), thick at the bottom. This realises the
paper's future-work item on drainage (sec. 5).

Parameters are one array whose shape depends on the kind: ``()`` for ``constant``,
``(3,)`` = (top_nm, bottom_nm, exponent) for ``drainage``, ``(H, W)`` for ``map`` (the
front film's thickness at each image pixel).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array

__all__ = ["KINDS", "thickness_at", "drainage_profile"]

KINDS = ("constant", "drainage", "map")


def drainage_profile(y: Array, top, bottom, exponent) -> Array:
    """``top + (bottom - top) ((1 - y)/2)^exponent``, with a finite gradient at the top (y = 1)."""
    x = jnp.clip((1.0 - y) * 0.5, 0.0, 1.0)
    pos = x > 0
    powed = jnp.where(pos, jnp.exp(exponent * jnp.log(jnp.where(pos, x, 1.0))), 0.0)
    return top + (bottom - top) * powed


def thickness_at(kind: str, values: Array, local: Array, pixel: Array) -> Array:
    """Thickness (nm) at film points.

    Args:
        kind: ``constant`` | ``drainage`` | ``map``.
        values: the field's parameters (see the module docstring).
        local: (N, 3) film points relative to the centre, over the radius.
        pixel: (N,) flat index of the image pixel the point belongs to (``map`` only:
            the rear film and the internal bounces read the map at the same pixel, which
            is exact for any field that depends on height only, as drainage does, and
            an approximation otherwise).
    """
    if kind == "constant":
        return jnp.broadcast_to(values, local.shape[:1])
    if kind == "drainage":
        return drainage_profile(local[:, 1], values[0], values[1], values[2])
    if kind == "map":
        return values.reshape(-1)[pixel]
    raise ValueError(f"unknown thickness kind {kind!r}")
