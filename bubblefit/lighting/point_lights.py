"""Distant point lights: eqs. (2)-(3) of the paper.

A distant light delivers irradiance ``E`` (RGB) to a surface facing it from the unit
direction ``l``. Its contribution to the radiance a film reflects towards ``w_o`` is
eq. (1)'s BRDF times ``E cos th_i`` (eq. 3), added to the filtered environment (eq. 2).

References:
    N. Morris, "Capturing the Reflectance Model of Soap Bubbles", eqs. (2)-(3);
    ``docs/design.md``, "Lighting".
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..optics.brdf import ward_lobe

__all__ = ["PointLight", "lights_radiance", "MIN_ROUGHNESS"]

#: Smallest roughness of eq. (3)'s lobe (a = 0 would divide 0 by 0, and far smaller values
#: overflow the lobe's gradient in float32); a lobe this narrow is far below any pixel.
MIN_ROUGHNESS = 1e-4


@dataclass(frozen=True)
class PointLight:
    """A distant light: unit ``direction`` towards the light, ``irradiance`` (RGB) it
    delivers to a surface facing it."""

    direction: tuple
    irradiance: tuple


def lights_radiance(lights, n: Float[Array, "N 3"], wo: Float[Array, "N 3"], roughness, r_d, *,
                    diffuse: bool) -> tuple[Array, Array]:
    """Eq. (3): eq. (1)'s BRDF for each distant light, times its irradiance and cosine.

    Returns ``(specular, diffuse)``, each (N, 3): the Ward lobe with ``r_s = 1`` (the caller
    scales it by ``r_s``, or by ``R_film`` in the physical model, as it does for the
    filtered environment) and ``r_d / pi cos th_i E`` (0 unless ``diffuse``). A roughness
    below :data:`MIN_ROUGHNESS` is held there: the lobe of a perfect mirror (``a = 0``) is a
    delta that no pixel centre meets, and the held lobe keeps values and gradients finite.
    """
    roughness = jnp.maximum(roughness, MIN_ROUGHNESS)
    cos_r = jnp.sum(n * wo, axis=-1)
    spec = 0.0
    diff = 0.0
    for light in lights:
        l = jnp.asarray(light.direction, dtype=n.dtype)
        l = l / jnp.linalg.norm(l)
        e = jnp.asarray(light.irradiance, dtype=n.dtype)
        cos_i = n @ l
        h = wo + l
        h = h / jnp.linalg.norm(h, axis=-1, keepdims=True).clip(1e-12)
        cos_h = jnp.sum(n * h, axis=-1)
        lobe = ward_lobe(cos_i, cos_r, cos_h, roughness) * jnp.maximum(cos_i, 0.0)
        spec = spec + lobe[:, None] * e
        if diffuse:
            diff = diff + (r_d / jnp.pi * jnp.maximum(cos_i, 0.0) * (cos_r > 0))[:, None] * e
    return spec, diff
