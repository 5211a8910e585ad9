"""Film thickness fields over the bubble: constant, drainage profile, per-pixel map.

docs/design.md: the drainage profile is ``d = top + (bottom - top) ((1 - y) / 2)^exponent``
with ``y`` in [-1, 1] the height of the film point above the bubble's centre over its
radius: thin at the top (gravity drains the film), thick at the bottom. This realises the
paper's future-work item on drainage (sec. 5).

Parameters are one array whose shape depends on the kind: ``()`` for ``constant``,
``(3,)`` = (top_nm, bottom_nm, exponent) for ``drainage``, ``(H, W)`` for ``map`` (the
front film's thickness at each image pixel, with the drainage profile under it,
:attr:`bubblefit.model.render.Params.profile`, for the films the photo does not show).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .modes import ThicknessKind

__all__ = ["thickness_at", "drainage_profile", "drainage_gradient"]


def drainage_profile(y: Array, top, bottom, exponent) -> Array:
    """``top + (bottom - top) ((1 - y)/2)^exponent``, with a finite gradient at the top (y = 1)."""
    x = jnp.clip((1.0 - y) * 0.5, 0.0, 1.0)
    pos = x > 0
    powed = jnp.where(pos, jnp.exp(exponent * jnp.log(jnp.where(pos, x, 1.0))), 0.0)
    return top + (bottom - top) * powed


def drainage_gradient(y: Array, top, bottom, exponent) -> Array:
    """``(..., 3)``: the change of the drainage profile (docs/design.md,
    :func:`drainage_profile`) at heights ``y`` per unit of ``top``, ``bottom`` and
    ``exponent`` (``1 - x^e``, ``x^e`` and ``(bottom - top) x^e ln x`` with
    ``x = (1 - y) / 2``), by forward-mode differentiation of that function itself."""
    import jax

    y = jnp.asarray(y, jnp.float32)
    args = tuple(jnp.asarray(v, jnp.float32) for v in (top, bottom, exponent))
    return jax.jacfwd(lambda p: drainage_profile(y, *p))(jnp.stack(args))


def thickness_at(kind: ThicknessKind, values: Array, local: Array, pixel: Array, profile: Array | None = None,
                 front: Array | None = None) -> Array:
    """Thickness (nm) at film points.

    Args:
        kind: ``constant`` | ``drainage`` | ``map``.
        values: the field's parameters (see the module docstring).
        local: (N, 3) film points relative to the centre, over the radius.
        pixel: (N,) flat index of the image pixel the point belongs to (``map`` only).
        profile: (3,) ``(top, bottom, exponent)`` of the drainage profile under a map
            (``map`` only; NaN: none).
        front: (N, 3) the front film point of the same pixel (``map`` with a profile).

    A map holds the front film's thickness at each pixel. The photo does not show the rear
    film or the film points of internal bounces; such a point takes the map's value at its
    pixel changed by the profile between the front point's height and its own. That is
    exact for a field of height alone in any camera (in a perspective view the rear point
    of a pixel lies higher or lower than the front one, and a bounce's points anywhere),
    and only the difference of the profile enters, so its own fitting error mostly
    cancels; a local feature of the front film (a bump) is carried to the films behind.
    (Taking the profile alone behind the front kept the bump in front but put the
    profile's error on the rear film: on a Blender Cycles photo (development case cyc_bump_city_ortho_offc, experiments/validation/split.toml) the map's coverage within
    15 nm fell from 96 % to 80 %.) Without a profile (None, or NaN) the point takes the
    map's value at its pixel.
    """
    if kind == "constant":
        return jnp.broadcast_to(values, local.shape[:1])
    if kind == "drainage":
        return drainage_profile(local[:, 1], values[0], values[1], values[2])
    if kind == "map":
        d = values.reshape(-1)[pixel]
        if profile is None or front is None:
            return d
        has = jnp.isfinite(profile[0])
        top, bottom, expo = (jnp.where(has, profile[i], v) for i, v in enumerate((0.0, 0.0, 1.0)))
        shift = drainage_profile(local[:, 1], top, bottom, expo) - drainage_profile(front[:, 1], top, bottom, expo)
        return d + jnp.where(has, shift, 0.0)
    raise ValueError(f"unknown thickness kind {kind!r}")
