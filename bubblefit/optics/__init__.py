"""Optics of one soap film: interference, Fresnel, Ward's BRDF and colour.

- :mod:`.film`: Snell, Fresnel, the phase of eq. (8), eqs. (9)-(10) and the exact Airy film.
- :mod:`.brdf`: Ward's isotropic BRDF, eq. (1).
- :mod:`.spectral`: spectra to linear sRGB (CIE 1931 2 degree observer, an illuminant).
- :mod:`.chart`: interference colour against thickness.
- :mod:`.dispersion`: the film's index against wavelength (Cauchy laws, presets).
- :mod:`.coaxial`: a flat film between media, and its reflectance averaged over an
  objective's cone of coaxial light.
"""

from . import brdf, chart, dispersion, film, spectral
from .chart import interference_colours
from .spectral import SpectralBasis, spectral_basis

__all__ = ["brdf", "chart", "dispersion", "film", "spectral", "interference_colours", "SpectralBasis", "spectral_basis"]
