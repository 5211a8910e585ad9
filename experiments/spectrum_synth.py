"""Synthetic spectra for the spectrum experiments, written independently of bubblefit.

The Airy reflectance of a film in air at normal incidence (Born & Wolf, *Principles of
Optics*, 7th ed., 7.6(13)): ``R = F sin^2(beta) / (1 + F sin^2(beta))``,
``F = 4 R1 / (1 - R1)^2``, ``beta = 2 pi n d / lambda``; the soap solution's Cauchy law;
a Planck lamp, and a halogen lamp seen through a spectrometer (Planck times a Gaussian
response).
"""

from __future__ import annotations

import numpy as np


def soap_index(lam):
    """The soap solution's index, ``1.324188 + 3102.060378 / lambda^2`` (lambda in nm)."""
    return 1.324188 + 3102.060378 / lam**2


def airy(d, lam, n):
    """Normal-incidence Airy reflectance of a film of ``d`` nm and index ``n`` in air."""
    r1 = ((n - 1.0) / (n + 1.0)) ** 2
    f = 4.0 * r1 / (1.0 - r1) ** 2
    s = np.sin(2.0 * np.pi * n * d / lam) ** 2
    return f * s / (1.0 + f * s)


def planck(lam, temperature=3000.0):
    """Planck's law at ``lam`` nm, scaled to its largest value there."""
    h, c, k = 6.62607e-34, 2.99792e8, 1.380649e-23
    m = lam * 1e-9
    v = 1.0 / (m**5 * (np.exp(h * c / (m * k * temperature)) - 1.0))
    return v / v.max()


def lamp(lam, temperature=3000.0):
    """A halogen lamp through a spectrometer: Planck times a Gaussian response (600 nm, 150 nm)."""
    v = planck(lam, temperature) * np.exp(-0.5 * ((lam - 600.0) / 150.0) ** 2)
    return v / v.max()
