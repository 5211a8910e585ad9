"""Is the fitted exposure possible for this map? (:func:`exposure_range`, :func:`exposure_doubt`)

The exposure is the camera's gain on the radiance the map sends: a pixel on the film shows
``exposure * rho * L`` of reflected light (eqs. 9-11), ``rho`` the film's reflectance and
``L`` the map's radiance in the reflected direction. For an orthographic view of a sphere
the reflected directions cover the sphere uniformly per unit of disc area
(``dOmega = 4 dA / r^2``), so the disc's mean reflected light is ``exposure`` times the
mean of ``rho L`` over the directions its fitted pixels see. Two bounds follow:

- the reflected light is at most the photo (the transmitted background only adds), and
  ``rho`` is at least :func:`least_reflectance` (the least luminance-weighted Airy
  reflectance of a film in the searched thickness range, any angle the fit uses): so
  ``exposure <= mean(Y_photo) / (rho_min * L_seen)``;
- with a background photo, the reflected light is at least ``photo - background`` (a film
  transmits at most all of it), and ``rho <= 1``: so
  ``exposure >= mean(max(Y_photo - Y_background, 0)) / L_seen_max``.

``L_seen``, the map's mean over the seen directions, is bounded from the map alone: the
fitted disc (``rho < rim``) sees all but a cone behind the bubble (8 % of the sphere at
``rim = 0.96``), so its mean is at least :data:`SEEN_MEDIAN_SHARE` of the map's
solid-angle median and at most the map's mean over the seen share. A fitted exposure
outside ``[lower, upper]`` is not a measurement: the map is not the one the photo was taken
in, or it is clipped (an 8-bit file whose sun and sky saturate).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ._pair import LUMINANCE
from ..lighting.envmap import texel_solid_angles

__all__ = ["least_reflectance", "map_levels", "exposure_range", "exposure_doubt", "SEEN_MEDIAN_SHARE"]

#: Least index of a soap film (water).
N_FILM_MIN = 1.33

#: The map's mean over the seen directions is at least this share of its solid-angle
#: median: half the sphere is at least as bright as the median, and at most 8 % of the
#: sphere (the cone behind the bubble that pixels with ``rho < 0.96`` do not see) is
#: missing from the seen part, so at least 42 % of the sphere's directions, of the seen
#: 92 %, are that bright.
SEEN_MEDIAN_SHARE = 0.42 / 0.92


@lru_cache(maxsize=8)
def least_reflectance(d_lo: float, d_hi: float, rim: float, n: float = N_FILM_MIN) -> float:
    """The least CIE Y-weighted reflectance (flat spectrum, D65) of one film of index ``n``
    in air, over thicknesses ``[d_lo, d_hi]`` nm and incidence angles with
    ``sin(theta) <= rim``: the Airy reflectance averaged over the polarisations and
    integrated against the observer (:func:`~bubblefit.optics.spectral.integrate`).

    References
    ----------
    Born & Wolf, *Principles of Optics*, eq. 7.6(13); CIE 1931 2 degree observer.
    """
    import jax
    import jax.numpy as jnp

    from ..optics.film import airy_reflectance
    from ..optics.spectral import integrate, spectral_basis

    basis = spectral_basis("uniform", 60)

    @jax.jit  # one program (stored by the compilation cache) instead of one per operation
    def grid(lo, hi, cos_lo):
        d = jnp.linspace(lo, hi, 400)[:, None, None]
        cos = jnp.linspace(cos_lo, 1.0, 24)[None, :, None]
        r = jnp.mean(airy_reflectance(d, jnp.asarray(basis.wavelengths), n, cos), axis=-1)  # (d, cos, lambda)
        return integrate(r, basis) @ jnp.asarray(LUMINANCE, r.dtype)

    lo = max(float(d_lo), 0.0)
    y = np.asarray(grid(lo, max(float(d_hi), lo), math.sqrt(max(0.0, 1.0 - rim**2))))
    return float(max(y.min(), 0.0))


def map_levels(pixels: np.ndarray) -> tuple[float, float]:
    """``(median, mean)`` of the map's luminance, weighted by each texel's solid angle
    (:func:`~bubblefit.lighting.envmap.texel_solid_angles`)."""
    px = np.asarray(pixels, np.float64)
    h, w = px.shape[:2]
    y = (px @ LUMINANCE).reshape(-1)
    sa = np.repeat(texel_solid_angles(h, w), w)
    order = np.argsort(y)
    cum = np.cumsum(sa[order])
    median = float(y[order][np.searchsorted(cum, 0.5 * cum[-1])])
    return median, float(np.sum(y * sa) / np.sum(sa))


def exposure_range(photo_y: float, excess_y: float | None, map_median: float, map_mean: float,
                   rho_min: float, seen_share: float = 0.92) -> tuple[float, float]:
    """``(lower, upper)`` of the exposure the module's bounds allow: ``photo_y`` the mean
    luminance of the fitted pixels, ``excess_y`` their mean excess over the background
    photo (None without one: no lower bound), the map's solid-angle median and mean
    luminance (:func:`map_levels`), ``rho_min`` (:func:`least_reflectance`)."""
    seen_lo = SEEN_MEDIAN_SHARE * map_median
    upper = photo_y / (rho_min * seen_lo) if rho_min > 0 and seen_lo > 0 else math.inf
    lower = 0.0
    if excess_y is not None and map_mean > 0:
        lower = excess_y * seen_share / map_mean
    return lower, upper


def exposure_doubt(exposure: float, lower: float, upper: float) -> str | None:
    """The warning for a fitted exposure outside ``[lower, upper]`` (None inside), naming
    the likely cause: a wrong map, or a clipped one."""
    if math.isfinite(exposure) and lower <= exposure <= upper:
        return None
    side = "below" if exposure < lower else "above"
    return (f"exposure = {exposure:.4g} is {side} what a film can show of this map ({lower:.3g} to {upper:.3g}, "
            "from the photo's and the map's brightness): the environment map is not the one the photo was taken "
            "in, or it is clipped (an 8-bit map saturates its sun and sky)")
