"""Thin-film optics of a soap film in air: Snell, Fresnel, eq. (8)-(10) and the Airy sum.

A soap film is a lossless slab of index ``n`` (``n_g`` in the paper, 1.4 by default) and
thickness ``d`` between two half-spaces of air. The Fresnel coefficients and the Airy sum
also take the indices of the media above and below the film (``n_above``, ``n_below``:
a film on a substrate, an air or liquid gap between glass plates); without them both are
air. Every function here takes the cosine of
the angle of incidence in the medium above (air unless told), ``cos_i`` in [0, 1], and broadcasts over all its
arguments; wavelengths and thicknesses are in nanometres. ``n`` may be one index per
wavelength (shaped like ``wavelength``) for a dispersive film
(:mod:`bubblefit.optics.dispersion`). Functions that depend on the
polarisation return a trailing axis of size 2: ``[..., 0]`` is s (TE), ``[..., 1]`` is p
(TM).

Every function is written so that values and gradients stay finite over the whole
domain: normal to grazing incidence (``cos_i`` = 1 .. 0), ``d = 0`` and very thick films,
and ``n`` down to 1 (no film).

References:
    Born & Wolf, *Principles of Optics*, 7th ed., sec. 1.5 (Fresnel) and 7.6.1 (Airy
    summation for a plane-parallel plate). Glassner, "Soap Bubbles", IEEE CG&A 20(6),
    2000 (the two-beam form the paper uses as eq. 9).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

__all__ = [
    "cos_transmitted",
    "fresnel_amplitudes",
    "fresnel_reflectance",
    "phase",
    "paper_interference_factor",
    "paper_factor_at_phase",
    "paper_tinted_transmission",
    "airy_reflectance",
    "airy_at_phase",
    "two_beam_at_phase",
    "two_beam_reflectance",
    "incoherent_reflectance",
    "optical_path",
    "fringe_attenuation",
    "filtered_airy_reflectance",
    "box_airy_reflectance",
    "BOX_TERMS",
    "filtered_two_beam_reflectance",
    "filtered_paper_interference_factor",
]

_TINY = 1e-12


def _safe_sqrt(x):
    """sqrt(max(x, 0)) whose gradient is 0 (not inf/NaN) where x <= 0."""
    pos = x > _TINY
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def cos_transmitted(cos_i: ArrayLike, n: ArrayLike, n_outside: ArrayLike = 1.0) -> Array:
    """Cosine of the refraction angle inside the film, from Snell's law.

    ``sin t = (n_outside / n) sin i``. Beyond total internal reflection (only possible
    when ``n < n_outside``) the cosine is clamped to 0.
    """
    cos_i = jnp.asarray(cos_i)
    sin2_t = (n_outside / n) ** 2 * (1.0 - cos_i * cos_i)
    return _safe_sqrt(1.0 - sin2_t)


def fresnel_amplitudes(cos_i: ArrayLike, n: ArrayLike, n_outside: ArrayLike = 1.0) -> Float[Array, "... 2"]:
    """Fresnel amplitude reflection coefficients (r_s, r_p) from a medium ``n_outside`` into ``n``.

    Born & Wolf eq. 1.5(21a) with ``n_i = n_outside``, ``n_t = n``:
    ``r_s = (n_i cos_i - n cos_t)/(n_i cos_i + n cos_t)``,
    ``r_p = (n cos_i - n_i cos_t)/(n cos_i + n_i cos_t)``. The reverse interface has the
    opposite signs (Stokes relations). Equal indices give 0; beyond total internal
    reflection (``cos_t`` clamped to 0 by :func:`cos_transmitted`) both are 1.
    """
    cos_i = jnp.asarray(cos_i)
    cos_t = cos_transmitted(cos_i, n, n_outside)
    den_s = n_outside * cos_i + n * cos_t
    den_p = n * cos_i + n_outside * cos_t
    rs = (n_outside * cos_i - n * cos_t) / jnp.maximum(den_s, _TINY)
    rp = (n * cos_i - n_outside * cos_t) / jnp.maximum(den_p, _TINY)
    return jnp.stack([rs, rp], axis=-1)


def fresnel_reflectance(cos_i: ArrayLike, n: ArrayLike, n_outside: ArrayLike = 1.0) -> Float[Array, "... 2"]:
    """Power reflectance (R_s, R_p) of one interface (air/film unless ``n_outside``), ``|r|^2``."""
    return fresnel_amplitudes(cos_i, n, n_outside) ** 2


def phase(thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike,
          n_above: ArrayLike = 1.0) -> Array:
    """Eq. (8): the phase difference between the first and second reflected beams.

    ``delta = 2 pi / lambda * (2 d n cos t) + pi``; the ``+ pi`` is the half-wave shift of
    the reflection on the air-to-film interface, so a film much thinner than the
    wavelength reflects almost nothing (a black film). ``cos t`` follows from Snell's law
    with the light arriving from ``n_above`` (air by default). With other media the
    ``+ pi`` is kept as the convention of the argument; the signs of the two Fresnel
    coefficients carry the reflection shifts (:func:`airy_at_phase`).
    """
    cos_t = cos_transmitted(cos_i, n, n_above)
    return 2.0 * jnp.pi / wavelength * (2.0 * thickness * n * cos_t) + jnp.pi


def paper_interference_factor(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike, t: ArrayLike
) -> Array:
    """Eqs. (9)-(10) as the paper writes them: ``I' = 4 L' cos^2(delta/2) t^2``.

    Returns the factor ``4 cos^2(delta/2) t^2`` that multiplies the Ward-filtered radiance
    ``L'`` (which already carries ``r_s`` and ``r_d``). Its mean over a broad spectrum is
    ``2 t^2``, which is why the paper notes that interference brightens its bubbles.
    """
    return paper_factor_at_phase(phase(thickness, wavelength, n, cos_i), t)


def paper_factor_at_phase(delta: ArrayLike, t: ArrayLike) -> Array:
    """Eq. (10)'s factor ``4 t^2 cos^2(delta/2)`` at the phase ``delta`` of eq. (8)."""
    return 4.0 * jnp.cos(0.5 * delta) ** 2 * t * t


def paper_tinted_transmission(factor: ArrayLike, t: ArrayLike, r_s: ArrayLike) -> Array:
    """One film's transmission with the paper model's transmission tint: ``t^2 - r_s (F - 2 t^2)``.

    A film that does not absorb transmits, wavelength by wavelength, what it does not
    reflect; the paper's film reflects ``r_s F`` (``F`` :func:`paper_interference_factor`,
    spectral mean ``2 t^2``), so its transmission is the grey ``t^2`` of eq. (11) minus
    the reflection's deviation from its mean, and ``T + r_s F`` is the same at every
    wavelength. ``r_s = 0`` gives eq. (11)'s ``t^2``.
    """
    return t * t - r_s * (factor - 2.0 * t * t)


def airy_reflectance(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike,
    n_above: ArrayLike | None = None, n_below: ArrayLike | None = None,
) -> Float[Array, "... 2"]:
    """Exact multi-beam (Airy) reflectance of a lossless film, per polarisation.

    The film (index ``n``, thickness ``d``) lies between a medium ``n_above``, from which
    the light arrives at ``cos_i``, and a medium ``n_below`` (both air when not given). Born
    & Wolf eq. 1.6(57) sums all the beams of a layer between two media:
    ``r = (r01 + r12 e^{2 i beta}) / (1 + r01 r12 e^{2 i beta})`` with the one-way phase
    ``beta = 2 pi n d cos t / lambda`` and the Fresnel coefficients ``r01`` (above to film)
    and ``r12`` (film to below) of :func:`fresnel_amplitudes`, so
    ``R = |r|^2 = ((r01 + r12)^2 - 4 r01 r12 s) / ((1 + r01 r12)^2 - 4 r01 r12 s)`` with
    ``s = sin^2(beta) = cos^2(delta/2)`` (eq. 8 gives ``delta = 2 beta + pi``). In air on
    both sides ``r12 = -r01`` and this is Born & Wolf eq. 7.6(13),
    ``4 R1 s / ((1 - R1)^2 + 4 R1 s)`` with ``R1 = r01^2``, finite at grazing incidence
    where ``R1 -> 1``. Transmittance is ``1 - R`` (lossless media).

    Indices may be arrays shaped like ``wavelength`` (dispersive media). The coefficients
    are real below total internal reflection, which never occurs for light that entered
    every medium from air (all indices >= 1); beyond it the film is taken to reflect
    fully (frustrated total reflection through a film thinner than a wavelength is not
    modelled).
    """
    above = 1.0 if n_above is None else n_above
    return airy_at_phase(phase(thickness, wavelength, n, cos_i, above), n, cos_i, n_above, n_below)


def airy_at_phase(delta: ArrayLike, n: ArrayLike, cos_i: ArrayLike,
                  n_above: ArrayLike | None = None, n_below: ArrayLike | None = None) -> Float[Array, "... 2"]:
    """:func:`airy_reflectance` at the phase ``delta`` of eq. (8), per polarisation.

    The Airy sum depends on the wavelength and the thickness only through ``delta``; the
    ``harmonic`` spectral basis (:mod:`bubblefit.optics.spectral`) samples it there.
    ``n_above`` and ``n_below`` as in :func:`airy_reflectance` (air when not given).
    """
    if n_above is None and n_below is None:  # air on both sides: r12 = -r01 (Stokes)
        r01 = fresnel_amplitudes(cos_i, n)
        r12 = -r01
    else:
        above = 1.0 if n_above is None else n_above
        below = 1.0 if n_below is None else n_below
        r01 = fresnel_amplitudes(cos_i, n, above)
        r12 = fresnel_amplitudes(cos_transmitted(cos_i, n, above), below, n)
    s = (jnp.cos(0.5 * delta) ** 2)[..., None]
    p4s = 4.0 * (r01 * r12) * s
    num = (r01 + r12) ** 2 - p4s
    den = (1.0 + r01 * r12) ** 2 - p4s
    safe = den > _TINY
    return jnp.where(safe, num / jnp.where(safe, den, 1.0), r01 * r01)


def two_beam_reflectance(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike
) -> Float[Array, "... 2"]:
    """Two-beam reflectance with Fresnel coefficients (Glassner's eq. 9 made exact to O(R1)).

    Keeps the first reflection ``r`` and the beam reflected once at the rear face,
    ``-(1 - r^2) r e^{i 2 beta}``, dropping later beams:
    ``R = R1 (1 + (1 - R1)^2 + 2 (1 - R1) cos delta)``. It differs from the Airy sum by
    terms of order ``R1^2`` (about 0.1% at normal incidence for n = 1.4). Near grazing
    incidence, where ``R1 -> 1``, the truncated series overshoots 1; it is clipped to
    [0, 1] there (use :func:`airy_reflectance` when the rim matters).
    """
    return two_beam_at_phase(phase(thickness, wavelength, n, cos_i), n, cos_i)


def two_beam_at_phase(delta: ArrayLike, n: ArrayLike, cos_i: ArrayLike) -> Float[Array, "... 2"]:
    """:func:`two_beam_reflectance` at the phase ``delta`` of eq. (8), per polarisation."""
    r1 = fresnel_reflectance(cos_i, n)
    r = r1 * (1.0 + (1.0 - r1) ** 2 + 2.0 * (1.0 - r1) * jnp.cos(jnp.asarray(delta)[..., None]))
    return jnp.clip(r, 0.0, 1.0)


def incoherent_reflectance(cos_i: ArrayLike, n: ArrayLike) -> Float[Array, "... 2"]:
    """Reflectance of a film when the interference averages out: ``2 R1 / (1 + R1)``.

    The incoherent sum of all beams of a lossless plate (Born & Wolf 7.6); it is also the
    mean of :func:`airy_reflectance` over one period of the phase, so it is the limit of a
    finely integrated thick film.
    """
    r1 = fresnel_reflectance(cos_i, n)
    return 2.0 * r1 / (1.0 + r1)


# --- Spectrally prefiltered film functions (the ``fourier`` spectral basis) ---------------
#
# Every film function above depends on the wavelength only through fringes
# ``cos(2 pi m x / lambda)`` of the optical path ``x = 2 n d cos t``. A ``fourier`` sample
# stands for the spectrum averaged under a Gaussian lobe in wavenumber ``nu = 1/lambda``
# (mean ``1/lambda_k``, deviation ``sigma_k``); averaging a fringe under it multiplies it by
# ``exp(-2 pi^2 sigma^2 m^2 x^2)`` (the Gaussian's characteristic function; Belcour &
# Barla, ACM TOG 36(4), 2017, sec. 4). The functions below apply that factor to each
# Fourier term of the film's reflectance in the phase of eq. (8).


def optical_path(thickness: ArrayLike, n: ArrayLike, cos_i: ArrayLike) -> Array:
    """Optical path difference ``x = 2 n d cos t`` (nm) of eq. (8): ``delta = 2 pi x / lambda + pi``."""
    return 2.0 * thickness * n * cos_transmitted(cos_i, n)


def fringe_attenuation(opd: ArrayLike, sigma: ArrayLike, m: ArrayLike = 1) -> Array:
    """Mean of ``cos(2 pi m x nu)`` under a unit Gaussian in ``nu`` of deviation ``sigma`` (1/nm),
    relative to its value at the mean: ``exp(-2 pi^2 sigma^2 m^2 x^2)``. Broadcasts."""
    return jnp.exp(-2.0 * jnp.pi**2 * (sigma * m * opd) ** 2)


def filtered_airy_reflectance(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike, sigma: ArrayLike,
    terms: int = 8,
) -> Float[Array, "... 2"]:
    """:func:`airy_reflectance` averaged under a Gaussian lobe in wavenumber, per polarisation.

    The Airy transmittance of a plate with face reflectance ``R1`` is
    ``(1 - R1)^2 / (1 - 2 R1 cos(2 beta) + R1^2)`` (Born & Wolf 7.6(12)), whose Fourier series
    in ``2 beta = 2 pi x / lambda`` is ``(1 - R1)/(1 + R1) (1 + 2 sum_m R1^m cos(2 m beta))``;
    so ``R = 2 R1/(1 + R1) - 2 (1 - R1)/(1 + R1) sum_m R1^m cos(2 pi m x / lambda)``. The
    first ``terms`` harmonics are attenuated by :func:`fringe_attenuation`; the tail
    ``m > terms`` (in closed form, ``Re[z^(M+1) / (1 - z)]`` with ``z = R1 e^(i theta)``; it
    matters only near grazing incidence, where ``R1 -> 1``) by the factor of harmonic
    ``terms + 1``, an upper bound of the later ones. So ``sigma = 0`` gives
    :func:`airy_reflectance` exactly and ``sigma x -> inf`` gives
    :func:`incoherent_reflectance`. ``sigma`` broadcasts like ``wavelength``; the result
    has the shape of ``airy_reflectance``.
    """
    r1 = fresnel_reflectance(cos_i, n)
    exact = airy_reflectance(thickness, wavelength, n, cos_i)
    x = optical_path(thickness, n, cos_i)
    theta = (2.0 * jnp.pi * x / wavelength)[..., None]
    amp = -2.0 * (1.0 - r1) / (1.0 + r1)
    return _attenuated_airy(exact, r1, amp, theta, lambda m: fringe_attenuation(x, sigma, m)[..., None], terms)


def _attenuated_airy(exact, q, amp, theta, gain, terms: int):
    """``exact + sum_m amp q^m cos(m theta) (gain(m) - 1)``: the Airy reflectance whose
    Fourier series ``R = R_inf + amp sum_m q^m cos(m theta)`` (Born & Wolf 7.6(12); ``q``
    the product of the two faces' reflection amplitudes with its sign turned, ``theta =
    2 pi x / lambda``) has each harmonic ``m`` scaled by ``gain(m)``. The first ``terms``
    are summed; the tail ``m > terms`` (in closed form, ``Re[z^(M+1) / (1 - z)]`` with
    ``z = q e^(i theta)``; it matters only near grazing incidence, where ``q -> 1``) is
    scaled by the gain of harmonic ``terms + 1``."""
    corr = 0.0
    for m in range(1, terms + 1):
        g = gain(m)
        corr = corr + amp * q**m * jnp.cos(m * theta) * (g - 1.0)
    # Tail: amp * sum_{m > M} q^m cos(m theta) = amp q^(M+1) (cos((M+1) theta) - q cos(M theta))
    #       / (1 - 2 q cos theta + q^2), finite since amp carries (1 - q).
    den = (1.0 - q) ** 2 + 2.0 * q * (1.0 - jnp.cos(theta))
    safe = den > _TINY
    num = amp * q ** (terms + 1) * (jnp.cos((terms + 1) * theta) - q * jnp.cos(terms * theta))
    tail = jnp.where(safe, num / jnp.where(safe, den, 1.0), 0.0)
    g_tail = gain(terms + 1)
    return exact + corr + (g_tail - 1.0) * tail


#: Harmonics of the Airy series summed one by one in :func:`box_airy_reflectance`: the
#: ``m``-th is ``q^m`` of the first, ``q = r01 r12`` 0.042 for glass on air and 0.028 for
#: water on air at normal incidence, so the fifth is under 3e-6 of the fringe's amplitude.
BOX_TERMS = 4


def box_airy_reflectance(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike, span_x: ArrayLike,
    span_y: ArrayLike, n_above: ArrayLike | None = None, n_below: ArrayLike | None = None, terms: int = BOX_TERMS,
) -> Float[Array, "... 2"]:
    """:func:`airy_reflectance` averaged over a pixel's box across which the thickness
    changes linearly, by ``span_x`` along one side and ``span_y`` along the other (nm;
    ``thickness`` at the box's centre), per polarisation.

    The Airy reflectance of a lossless layer is ``R = 1 - T`` with ``T = (1 - r01^2)(1 -
    r12^2) / (1 + q^2 - 2 q cos theta)``, ``q = -r01 r12``, ``theta = 2 pi x / lambda``
    (``x`` the optical path of :func:`optical_path`; Born & Wolf 1.6(57), 7.6(12)), whose
    Fourier series is ``T = (1 - r01^2)(1 - r12^2) / (1 - q^2) (1 + 2 sum_m q^m cos(m
    theta))``. Over the box ``theta`` is linear, and the box's mean of ``cos(m theta)`` is
    ``cos(m theta_c) sinc(m u_x) sinc(m u_y)`` with ``u = x'/lambda`` the fringes the path
    spans across the box along each side (``sinc t = sin(pi t)/(pi t)``: the box
    aperture's transfer function, J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed.,
    sec. 2.1, Table 2.1). The harmonics are so scaled by :func:`_attenuated_airy`, the
    first ``terms`` exactly; zero spans give :func:`airy_reflectance`. Indices and the
    reflection amplitudes as in :func:`airy_reflectance`; the spans broadcast like
    ``thickness``.
    """
    above = 1.0 if n_above is None else n_above
    below = 1.0 if n_below is None else n_below
    exact = airy_reflectance(thickness, wavelength, n, cos_i, n_above, n_below)
    r01 = fresnel_amplitudes(cos_i, n, above)
    r12 = fresnel_amplitudes(cos_transmitted(cos_i, n, above), below, n)
    q = -r01 * r12
    den = 1.0 - q * q  # 0 only at total reflection, where the layer's R is 1 and has no fringes
    safe = den > _TINY
    amp = jnp.where(safe, -2.0 * (1.0 - r01 * r01) * (1.0 - r12 * r12) / jnp.where(safe, den, 1.0), 0.0)
    path = 2.0 * n * cos_transmitted(cos_i, n, above) / wavelength  # fringes per nm of thickness (eq. 8)
    theta = (2.0 * jnp.pi * path * thickness)[..., None]
    ux, uy = path * span_x, path * span_y
    return _attenuated_airy(exact, q, amp, theta, lambda m: (jnp.sinc(m * ux) * jnp.sinc(m * uy))[..., None], terms)


def filtered_two_beam_reflectance(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike, sigma: ArrayLike
) -> Float[Array, "... 2"]:
    """:func:`two_beam_reflectance` averaged under a Gaussian lobe in wavenumber: its single
    fringe ``cos delta`` is attenuated by :func:`fringe_attenuation` (then clipped to [0, 1])."""
    r1 = fresnel_reflectance(cos_i, n)
    x = optical_path(thickness, n, cos_i)
    delta = phase(thickness, wavelength, n, cos_i)
    fringe = (jnp.cos(delta) * fringe_attenuation(x, sigma))[..., None]
    r = r1 * (1.0 + (1.0 - r1) ** 2 + 2.0 * (1.0 - r1) * fringe)
    return jnp.clip(r, 0.0, 1.0)


def filtered_paper_interference_factor(
    thickness: ArrayLike, wavelength: ArrayLike, n: ArrayLike, cos_i: ArrayLike, t: ArrayLike, sigma: ArrayLike
) -> Array:
    """Eq. (10)'s factor averaged under a Gaussian lobe in wavenumber:
    ``4 t^2 cos^2(delta/2) = 2 t^2 (1 + cos delta)`` with ``cos delta`` attenuated by
    :func:`fringe_attenuation`; it tends to the broadband mean ``2 t^2`` for thick films."""
    x = optical_path(thickness, n, cos_i)
    delta = phase(thickness, wavelength, n, cos_i)
    return 2.0 * t * t * (1.0 + jnp.cos(delta) * fringe_attenuation(x, sigma))
