"""The fit's spectral quadrature, chosen from the film's optical paths before it solves.

The fit integrates each film's spectrum into RGB with a quadrature
(:mod:`bubblefit.optics.spectral`). A film of optical path ``x = 2 n d cos t`` (eq. 8)
shows fringes ``cos(2 pi m x / lambda)``, and a quadrature reads each fringe through its
:func:`~bubblefit.optics.spectral.fringe_response` ``A_c(m x)``; the 800-sample
reference reads it as the camera does. The 8 ``fourier`` lobes approximate the response
within about 0.5 % of a fringe's amplitude at every path, which is a small error on a
thin film's saturated colour and a large one on a thick film's pale colour: the colour
check (:mod:`bubblefit.inverse.colour_check`) allows a model error of
:data:`~bubblefit.inverse.colour_check.CHROMA_FLOOR` of a cell's brightness and
:data:`~bubblefit.inverse.colour_check.CHROMA_REL` of its chroma, and a film of 1200 nm
has little chroma left.

So the rule, :func:`fit_spectral_basis`, reads the colours an Airy film takes at every
optical path the fit may meet, relative to the film's mean reflectance (the Airy sum's
Fourier series, Born & Wolf 7.6(12), face reflectance ``R1`` at normal incidence,
:data:`HARMONICS` harmonics):

``c(x) = 1 - (1 - R1) sum_m R1^(m-1) Re A(m x)``,

once with the reference and once with each candidate of :data:`FIT_SPECTRAL_CANDIDATES`,
cheapest first. The candidate's error ``e = c_cand - c_ref`` is projected on the plane
orthogonal to ``c_ref`` (the colour check's chromatic plane) and measured against the
colour check's floor for that colour: ``q(x) = |P e|^2 / (CHROMA_FLOOR^2 |c|^2 +
CHROMA_REL^2 chroma^2)`` is what a cell of that film, noise-free, adds to the check's
statistic per degree of freedom. The first candidate whose largest ``q`` stays within
:data:`QUADRATURE_EXCESS` is the fit's. Only reflection is read: a transmitted
background adds brightness, and the same absolute error, to a cell, so it only lowers
``q``. Nothing in the rule reads a photo: the optical paths come from the thickness range
the fit will solve in and the rim's incidence.
"""

from __future__ import annotations

import numpy as np

from ..model.effects import Decision
from ..optics.spectral import SpectralBasis, fringe_response, spectral_basis
from .colour_check import CHROMA_FLOOR, CHROMA_REL, _planes

__all__ = ["fit_spectral_basis", "quadrature_excess", "optical_path_range", "FIT_SPECTRAL_CANDIDATES",
           "QUADRATURE_EXCESS"]

#: The quadratures the rule tries, cheapest first, as ``(method, samples)``; the last is the
#: converged reference. ``fourier`` 10-16 are not among them: their lobes were fitted to the
#: response's density, not to its fringes, and they stop short of the 8 lobes' reach by
#: less than uniform 80 (:func:`quadrature_excess` 0.35-0.47 against 0.21 beyond 2000 nm of
#: optical path; ``experiments/spectral_basis_cost.py``). Uniform 80 and 100 bins are 5 and
#: 4 nm, on the response tables' 1 nm grid; 64, 72, 90 and 120 bins read 0.41-0.58.
FIT_SPECTRAL_CANDIDATES = (("fourier", 8), ("uniform", 80), ("uniform", 100), ("reference", 800))

#: Largest addition to the colour check's statistic per degree of freedom that the
#: quadrature may make on a noise-free cell. The statistic's null has mean 1 and, over the
#: 36 cells of a disc, a standard deviation of 1/6; the threshold is the chi-square 1e-3
#: point, 1.64 per degree of freedom. With 0.25 a right fit stays 2.3 standard deviations
#: below it where the quadrature errs most, and a wrong camera's hue errors (20-500 % of
#: the chroma, experiments/wrong_camera.py) are not approached. Derived from the check's
#: law, not from any photo.
QUADRATURE_EXCESS = 0.25

#: Fringes the rule reads: the Airy sum's harmonic ``m`` weighs ``R1^(m-1)``, 8e-4 at the third.
HARMONICS = 3

#: Step of the optical paths the rule reads (nm): a third harmonic's shortest period is 127 nm.
PATH_STEP_NM = 5.0


def optical_path_range(lo_nm: float, hi_nm: float, n_film: float, min_cos: float) -> tuple[float, float]:
    """The optical paths ``2 n d cos t`` (eq. 8, :func:`~bubblefit.optics.film.optical_path`)
    of films ``lo_nm``-``hi_nm`` thick seen at incidence cosines ``min_cos``-1 (nm)."""
    from ..optics.film import optical_path

    lo = float(optical_path(float(lo_nm), float(n_film), float(min_cos)))
    hi = float(optical_path(float(hi_nm), float(n_film), 1.0))
    return lo, hi


def _film_colours(basis: SpectralBasis, x: np.ndarray, r1: float) -> np.ndarray:
    """The module docstring's ``c(x)``, (N, 3), read through ``basis``."""
    c = np.ones(x.shape + (3,))
    for m in range(1, HARMONICS + 1):
        c -= (1.0 - r1) * r1 ** (m - 1) * np.real(fringe_response(basis, m * x))
    return c


def quadrature_excess(basis: SpectralBasis, x_lo: float, x_hi: float, n_film: float) -> float:
    """The largest ``q(x)`` of the module docstring over optical paths ``x_lo``-``x_hi`` (nm):
    what ``basis``' hue error on an Airy film of index ``n_film`` adds, at most, to the
    colour check's statistic per degree of freedom. 0 for the reference itself."""
    from ..optics.film import fresnel_reflectance

    r1 = float(np.mean(np.asarray(fresnel_reflectance(1.0, float(n_film)))))
    x = np.arange(max(x_lo, 0.0), max(x_hi, x_lo) + PATH_STEP_NM, PATH_STEP_NM)
    if basis.method == "reference":
        return 0.0
    ref = _film_colours(SpectralBasis("reference", 800, basis.illuminant, basis.response, basis.white_balance), x, r1)
    err = np.einsum("nij,nj->ni", _planes(ref), _film_colours(basis, x, r1) - ref)
    chroma = np.linalg.norm(ref - ref.mean(axis=-1, keepdims=True), axis=-1)
    allowed = (CHROMA_FLOOR * np.linalg.norm(ref, axis=-1)) ** 2 + (CHROMA_REL * chroma) ** 2
    return float(np.max(np.sum(err**2, axis=-1) / allowed))


def fit_spectral_basis(lo_nm: float, hi_nm: float, n_film: float, min_cos: float, illuminant: str = "D65",
                       response: str = "srgb", white_balance="illuminant") -> tuple[SpectralBasis, Decision]:
    """The cheapest quadrature of :data:`FIT_SPECTRAL_CANDIDATES` whose
    :func:`quadrature_excess` over the optical paths of films ``lo_nm``-``hi_nm`` thick
    (:func:`optical_path_range`, incidence down to ``min_cos``) stays within
    :data:`QUADRATURE_EXCESS`, for the ``illuminant``, ``response`` and ``white_balance``
    (:mod:`bubblefit.optics.spectral`), and the :class:`~bubblefit.model.effects.Decision` that says why."""
    x_lo, x_hi = optical_path_range(lo_nm, hi_nm, n_film, min_cos)
    where = f"films {lo_nm:.0f}-{hi_nm:.0f} nm (optical paths {x_lo:.0f}-{x_hi:.0f} nm)"
    for method, samples in FIT_SPECTRAL_CANDIDATES:
        basis = spectral_basis(method, samples, illuminant, response, white_balance)
        if method == "reference":
            return basis, Decision("spectral", True, f"{where}: no cheaper quadrature keeps the colour check's "
                                   f"statistic within {QUADRATURE_EXCESS:g} of its floor: reference",
                                   f"reference/{basis.samples}")
        q = quadrature_excess(basis, x_lo, x_hi, n_film)
        if q <= QUADRATURE_EXCESS:
            return basis, Decision("spectral", True, f"{where}: {method}/{samples} adds at most {q:.2f} <= "
                                   f"{QUADRATURE_EXCESS:g} to the colour check's statistic per degree of freedom",
                                   f"{method}/{samples}")
    raise AssertionError("the reference ends FIT_SPECTRAL_CANDIDATES")
