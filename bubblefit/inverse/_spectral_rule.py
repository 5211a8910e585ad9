"""The fit's spectral quadrature, chosen from the films it may meet before it solves.

The fit integrates each film's spectrum into RGB with a quadrature
(:mod:`bubblefit.optics.spectral`). The 8 ``fourier`` lobes average each film function
under a Gaussian in wavenumber, which is exact for one film's reflectance but not for the
products the physical model forms: the rear film is seen through the front film twice
(``T R T``, and ``T R^k T`` for the internal bounces), and the average of a product of
fringes is not the product of their averages once the lobes fade them (films of a few
hundred nm and more). Point samples (``uniform``, ``reference``) multiply the spectra
wavelength by wavelength and make no such error; their error is the quadrature's own,
which shrinks with the bin width.

The colour check (:mod:`bubblefit.inverse.colour_check`) allows a cell a model error of
:data:`~bubblefit.inverse.colour_check.CHROMA_FLOOR` of its brightness and
:data:`~bubblefit.inverse.colour_check.CHROMA_REL` of its chroma. So the rule,
:func:`fit_spectral_basis`, renders the film's colour under a uniform white light, front
film plus rear film and its internal bounces (the model's terms,
:func:`~bubblefit.model.bounds.film_coefficients`, on the grid of thicknesses and
incidences of :func:`~bubblefit.model.bounds.film_grids`), once with the 800-sample
reference and once with each candidate of :data:`FIT_SPECTRAL_CANDIDATES`, cheapest
first. The candidate's error ``e = c_cand - c_ref`` is projected on the plane orthogonal
to ``c_ref`` (the check's chromatic plane) and measured against the check's floor for
that colour:

``q = |P e|^2 / (CHROMA_FLOOR^2 |c_ref|^2 + CHROMA_REL^2 chroma(c_ref)^2)``

is what a noise-free cell of that film adds to the check's statistic per degree of
freedom. The first candidate whose largest ``q`` stays within :data:`QUADRATURE_EXCESS`
is the fit's. A transmitted background adds brightness and the same absolute error to a
cell, so leaving it out only raises ``q``; a map's own colours under the film are common
to both quadratures. Nothing in the rule reads a photo: it reads the thickness range the
fit searches, the film's index, the rim's incidence and the internal bounces.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..model.bounds import film_coefficients, film_grids, film_spectra
from ..model.effects import Decision
from ..optics.spectral import SpectralBasis, spectral_basis
from .colour_check import CHROMA_FLOOR, CHROMA_REL, _planes

__all__ = ["fit_spectral_basis", "quadrature_excess", "FIT_SPECTRAL_CANDIDATES", "QUADRATURE_EXCESS"]

#: The quadratures the rule tries, cheapest first, as ``(method, samples)``; the last is the
#: converged reference. A render costs about the same with 8 lobes and 80 or 100 uniform
#: samples where the environment's lookups dominate, 2x with the reference
#: (experiments/spectral_basis_cost.py on the development case ref_const1200_night_ortho_offc,
#: footprint on: 1.28, 1.33, 1.30 and 2.58 s of CPU).
FIT_SPECTRAL_CANDIDATES = (("fourier", 8), ("uniform", 80), ("uniform", 100), ("reference", 800))

#: Largest addition to the colour check's statistic per degree of freedom that the
#: quadrature may make on a noise-free cell. The statistic's null has mean 1 and, over the
#: 36 cells of a disc, a standard deviation of 1/6; the threshold is the chi-square 1e-3
#: point, 1.64 per degree of freedom. With 0.25 a right fit stays 2.3 standard deviations
#: below it where the quadrature errs most. Derived from the check's law, not from a photo.
QUADRATURE_EXCESS = 0.25


@functools.lru_cache(maxsize=32)
def _colours(basis: SpectralBasis, thickness_range: tuple, n_film: float, min_cos: float, bounces: int) -> np.ndarray:
    """The film's RGB (D, C, 3) under a uniform white light through ``basis``: front film
    plus the rear film and ``bounces`` internal bounces, on :func:`film_grids`' grid."""
    d, cos = film_grids(thickness_range, min_cos, n_film)
    spectra = film_spectra("physical", "airy", basis.wavelengths, d, cos, 1.0, n_film, basis.sigma)
    terms = film_coefficients("physical", "airy", basis.weights, spectra, cos, 1.0, n_film, max(int(bounces), 1))
    return np.asarray(terms["front"] + sum(terms["rear"]), np.float64)


def quadrature_excess(basis: SpectralBasis, thickness_range: tuple, n_film: float, min_cos: float,
                      bounces: int = 3) -> float:
    """The largest ``q`` of the module docstring over films of ``thickness_range`` (nm) of
    index ``n_film`` seen at incidence cosines ``min_cos``-1 with ``bounces`` internal
    bounces: what ``basis``' hue error adds, at most, to the colour check's statistic per
    degree of freedom. 0 for the reference.

    References
    ----------
    The film: Airy's sum per polarisation (Born & Wolf, *Principles of Optics*, 7th ed.,
    sec. 7.6) with the paper's eq. (8) phase; the lobes: Belcour & Barla, ACM TOG 36(4),
    2017, sec. 4; the floor: :mod:`bubblefit.inverse.colour_check`.
    """
    if basis.method == "reference":
        return 0.0
    key = (tuple(float(x) for x in thickness_range), float(n_film), float(min_cos), int(bounces))
    ref = _colours(SpectralBasis("reference", 800, basis.illuminant, basis.response, basis.white_balance), *key)
    err = np.einsum("...ij,...j->...i", _planes(ref), _colours(basis, *key) - ref)
    chroma = np.linalg.norm(ref - ref.mean(axis=-1, keepdims=True), axis=-1)
    allowed = (CHROMA_FLOOR * np.linalg.norm(ref, axis=-1)) ** 2 + (CHROMA_REL * chroma) ** 2
    return float(np.max(np.sum(err**2, axis=-1) / allowed))


def fit_spectral_basis(thickness_range: tuple, n_film: float, min_cos: float, bounces: int = 3,
                       illuminant: str = "D65", response: str = "srgb",
                       white_balance="illuminant") -> tuple[SpectralBasis, Decision]:
    """The cheapest quadrature of :data:`FIT_SPECTRAL_CANDIDATES` whose
    :func:`quadrature_excess` over films of ``thickness_range`` stays within
    :data:`QUADRATURE_EXCESS`, for the ``illuminant``, ``response`` and ``white_balance``
    (:mod:`bubblefit.optics.spectral`), and the
    :class:`~bubblefit.model.effects.Decision` that says why."""
    lo, hi = (float(x) for x in thickness_range)
    where = f"films {lo:.0f}-{hi:.0f} nm"
    for method, samples in FIT_SPECTRAL_CANDIDATES:
        basis = spectral_basis(method, samples, illuminant, response, white_balance)
        if method == "reference":
            return basis, Decision("spectral", True, f"{where}: no cheaper quadrature keeps its hue error within "
                                   f"{QUADRATURE_EXCESS:g} of the colour check's floor: reference",
                                   f"reference/{basis.samples}")
        q = quadrature_excess(basis, (lo, hi), n_film, min_cos, bounces)
        if q <= QUADRATURE_EXCESS and math.isfinite(q):
            return basis, Decision("spectral", True, f"{where}: {method}/{samples}'s hue error adds at most {q:.2f} "
                                   f"<= {QUADRATURE_EXCESS:g} to the colour check's statistic per degree of "
                                   "freedom", f"{method}/{samples}")
    raise AssertionError("the reference ends FIT_SPECTRAL_CANDIDATES")
