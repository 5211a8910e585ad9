"""Spectral integration of film reflectance to linear sRGB (sec. 3.4 of the paper).

A reflectance spectrum ``S(lambda)`` seen under an illuminant ``I(lambda)`` has tristimulus
values ``XYZ = sum_k cmf(lambda_k) I(lambda_k) S(lambda_k) dlambda`` (CIE 1931 2-degree
observer, from colour-science), converted to linear sRGB with the Rec. 709 matrix of
IEC 61966-2-1 and normalised per channel so that a spectrally flat reflectance ``c``
gives ``(c, c, c)`` (DESIGN.md). The resulting RGB factor multiplies the RGB radiance of
the environment per channel.

A :class:`SpectralBasis` holds the K sample wavelengths and the (K, 3) weights of this
quadrature, so integration is one matrix product: ``rgb = S @ weights``.

Methods:
    ``uniform``: K samples at the midpoints of K equal bins over 380-780 nm (the
        paper used K = 10, 30, 100; few samples band on thick films).
    ``reference``: uniform with 0.5 nm bins (800 samples), the converged reference for
        films up to ~20 um.
"""

from __future__ import annotations

import functools

import colour
import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "LAMBDA_MIN",
    "LAMBDA_MAX",
    "SpectralBasis",
    "spectral_basis",
    "integrate",
    "REFERENCE_SAMPLES",
]

LAMBDA_MIN = 380.0
LAMBDA_MAX = 780.0
REFERENCE_SAMPLES = 800


@functools.lru_cache(maxsize=8)
def _tables(illuminant: str):
    """CMFs (1 nm, 360-830) and the illuminant on the same grid, as numpy arrays."""
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    lam = np.asarray(cmfs.wavelengths, dtype=np.float64)
    if illuminant.upper() in ("E", "EQUAL", "EQUAL_ENERGY"):
        ill = np.ones_like(lam)
    else:
        try:
            sd = colour.SDS_ILLUMINANTS[illuminant]
        except KeyError as exc:
            from .errors import InputError

            raise InputError(f"unknown illuminant {illuminant!r} (try D65, D50, A or E)") from exc
        ill = np.interp(lam, np.asarray(sd.wavelengths), np.asarray(sd.values))
    xyz_to_rgb = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=np.float64)
    return lam, np.asarray(cmfs.values, dtype=np.float64), ill, xyz_to_rgb


@functools.lru_cache(maxsize=64)
def _basis_arrays(method: str, samples: int, illuminant: str):
    lam_tab, cmf_tab, ill_tab, m = _tables(illuminant)
    if method == "reference":
        samples = REFERENCE_SAMPLES
    if method not in ("uniform", "reference"):
        raise ValueError(f"unknown spectral method {method!r}")
    if samples < 1:
        raise ValueError("spectral samples must be >= 1")
    width = (LAMBDA_MAX - LAMBDA_MIN) / samples
    lam = LAMBDA_MIN + (np.arange(samples) + 0.5) * width
    # Each sample stands for its bin: average the observer x illuminant over the bin on a
    # fine grid, so the weights integrate the whole visible range for any K.
    fine = np.linspace(LAMBDA_MIN, LAMBDA_MAX, 4001)
    cmf_f = np.stack([np.interp(fine, lam_tab, cmf_tab[:, c]) for c in range(3)], axis=1)
    ill_f = np.interp(fine, lam_tab, ill_tab)
    rgb_f = (cmf_f * ill_f[:, None]) @ m.T
    idx = np.minimum(((fine - LAMBDA_MIN) / width).astype(int), samples - 1)
    w = np.zeros((samples, 3))
    np.add.at(w, idx, rgb_f)
    w /= w.sum(axis=0, keepdims=True)  # flat spectrum -> (1, 1, 1)
    return lam, w, np.full(samples, width)


class SpectralBasis:
    """Sample wavelengths (K,) in nm, RGB weights (K, 3) and bin widths (K,) in nm.

    Hashable and compared by its definition, so it can be a static argument under jit.
    """

    def __init__(self, method: str = "uniform", samples: int = 30, illuminant: str = "D65"):
        lam, w, width = _basis_arrays(method, int(samples), illuminant)
        self.method = method
        self.samples = len(lam)
        self.illuminant = illuminant
        self.wavelengths = lam
        self.weights = w
        self.bin_width = width

    def _key(self):
        return (self.method, self.samples, self.illuminant)

    def __hash__(self):
        return hash(self._key())

    def __eq__(self, other):
        return isinstance(other, SpectralBasis) and self._key() == other._key()

    def __repr__(self):
        return f"SpectralBasis(method={self.method!r}, samples={self.samples}, illuminant={self.illuminant!r})"


def spectral_basis(method: str = "uniform", samples: int = 30, illuminant: str = "D65") -> SpectralBasis:
    """The quadrature for ``method`` (``uniform`` or ``reference``) with ``samples`` bins."""
    return SpectralBasis(method, samples, illuminant)


def integrate(spectrum: Float[Array, "... K"], basis: SpectralBasis) -> Float[Array, "... 3"]:
    """Linear sRGB of a reflectance spectrum sampled at ``basis.wavelengths``."""
    import jax.numpy as jnp

    return spectrum @ jnp.asarray(basis.weights, dtype=spectrum.dtype)
