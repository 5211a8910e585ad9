"""Interference colour against film thickness (the soap-film colour sequence).

For each thickness the film's reflectance spectrum (Airy, two-beam, the paper's eq. 10 or
incoherent) is integrated to linear sRGB with the converged spectral quadrature of
:mod:`bubblefit.optics.spectral`. Thin films are black (the half-wave shift of eq. 8), then
white/silver, then the first-order yellow, red, blue and the repeating orders, which fade
to white beyond a few micrometres.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import dispersion, film, spectral

__all__ = ["interference_colours", "MODELS"]

MODELS = ("airy", "two_beam", "paper", "incoherent")


def interference_colours(thickness_nm, *, angle_deg: float = 0.0, model: str = "airy",
                         n_film: dispersion.IndexSpec = 1.4, t: float = 0.972,
                         basis: spectral.SpectralBasis | None = None, chunk: int = 256,
                         above: dispersion.IndexSpec | None = None, below: dispersion.IndexSpec | None = None,
                         na: float = 0.0) -> np.ndarray:
    """Linear RGB reflectance (N, 3) of a film at each thickness (nm).

    ``paper`` returns eq. (10)'s interference factor ``4 t^2 cos^2(delta/2)`` alone (it
    multiplies the Ward-filtered radiance, which carries ``r_s``). The others return the
    film's reflectance averaged over polarisations. ``n_film`` is a number, a Cauchy law
    or a preset (:mod:`bubblefit.optics.dispersion`), evaluated at each sample wavelength;
    ``basis`` carries the illuminant and the camera response (default: the converged
    ``reference`` quadrature, D65, sRGB). ``above`` and ``below`` are the media on either
    side of the film (air when not given; e.g. a glass|air|glass gap), with the exact
    three-media Airy sum (``airy`` only); the light comes from ``above``, which it entered
    from air at ``angle_deg`` through a face parallel to the film;
    ``na > 0`` averages over an objective's cone of illumination instead of one angle
    (:func:`bubblefit.optics.coaxial.coaxial_reflectance`).

    Examples
    --------
    A film of no thickness reflects nothing; a film too thick to interfere reflects the grey
    ``2R/(1+R)`` of its two faces, ``R`` one face's Fresnel reflectance:

    >>> import numpy as np
    >>> import bubblefit as bf
    >>> bf.interference_colours([0.0]).round(6).tolist()
    [[0.0, 0.0, 0.0]]
    >>> R = ((1.4 - 1.0) / (1.4 + 1.0)) ** 2
    >>> bool(np.allclose(bf.interference_colours([5000.0], model="incoherent"), 2 * R / (1 + R)))
    True
    """
    if model not in MODELS:
        raise ValueError(f"unknown chart model {model!r}; expected one of {MODELS}")
    basis = basis or spectral.spectral_basis("reference")
    lam = jnp.asarray(basis.wavelengths)
    film_spec = n_film
    n_film = jnp.asarray(dispersion.refractive_index(n_film, basis.wavelengths), dtype=lam.dtype)
    cos_i = float(np.cos(np.radians(angle_deg)))
    d = np.asarray(thickness_nm, dtype=np.float64).ravel()
    media = above is not None or below is not None or na > 0
    if media and model != "airy":
        raise ValueError("media around the film and an objective's aperture need the airy model")
    if media:
        from . import coaxial

        stack = coaxial.Stack(above if above is not None else "air", film_spec, below if below is not None else "air")
        n = stack.indices(basis.wavelengths)
        sin2_air = float(np.sin(np.radians(angle_deg)) ** 2)
        nodes = coaxial.cone_nodes_needed(float(d.max(initial=0.0)), na, float(np.min(n.film))) if na > 0 else 1

    @jax.jit
    def colours(dd):
        dd = dd[:, None]
        if media and na > 0:
            s = coaxial.coaxial_reflectance(dd, lam, n, na, nodes)
        elif media:
            s = coaxial.reflectance_at_angles(dd, lam, n, sin2_air)
        elif model == "airy":
            s = film.airy_reflectance(dd, lam, n_film, cos_i).mean(-1)
        elif model == "two_beam":
            s = film.two_beam_reflectance(dd, lam, n_film, cos_i).mean(-1)
        elif model == "paper":
            s = film.paper_interference_factor(dd, lam, n_film, cos_i, t)
        else:
            s = jnp.broadcast_to(film.incoherent_reflectance(cos_i, n_film).mean(-1), dd.shape[:1] + lam.shape)
        return spectral.integrate(s, basis)

    out = []
    for i in range(0, len(d), chunk):
        part = d[i:i + chunk]
        pad = chunk - len(part)
        out.append(np.asarray(colours(jnp.asarray(np.pad(part, (0, pad), mode="edge"))))[: len(part)])
    return np.concatenate(out) if out else np.zeros((0, 3))


def display_scale(model: str, *, angle_deg: float = 0.0, n_film: dispersion.IndexSpec = 1.4,
                  t: float = 0.972) -> float:
    """Factor that maps the film's mean (incoherent) reflectance to 0.5 for display."""
    cos_i = float(np.cos(np.radians(angle_deg)))
    if model == "paper":
        mean = 2 * t * t
    else:
        n = dispersion.refractive_index(n_film, np.linspace(spectral.LAMBDA_MIN, spectral.LAMBDA_MAX, 41))
        mean = float(np.asarray(film.incoherent_reflectance(cos_i, n)).mean())
    return 0.5 / max(mean, 1e-12)
