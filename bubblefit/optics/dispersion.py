"""Refractive index of the film against wavelength: a constant, a Cauchy law or a preset.

A soap film's index is not one number: water and soap solutions disperse, from about
1.345 at 400 nm to 1.33 at 750 nm. At a few micrometres that moves an interference
spectrum by whole fringes, so everything that computes a phase (eq. 8) takes the index
*per wavelength*: the film functions of :mod:`bubblefit.optics.film` broadcast ``n``
like ``wavelength``, and :func:`refractive_index` turns a description of the film into
that array.

A description is one of

- a number (no dispersion, the paper's ``n_g``);
- :class:`Cauchy`: ``n = A + B / lambda^2 + C / lambda^4 (+ D / lambda^6 ...)``,
  lambda in nm (scene form ``{cauchy = [A, B]}`` or ``{cauchy = [A, B, C]}``);
- a preset name from :data:`PRESETS` (``"water"``, ``"soap"``).

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 2.3 (Cauchy's dispersion formula).
A. N. Bashkatov and E. A. Genina, "Water refractive index in dependence on temperature
and wavelength: a simple approximation", Proc. SPIE 5068, 393-395 (2003).
M. Daimon and A. Masumura, "Measurement of the refractive index of distilled water from
the near-infrared region to the ultraviolet region", Appl. Opt. 46, 3811-3820 (2007).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

import numpy as np

from ..errors import InputError

__all__ = ["Cauchy", "IndexSpec", "PRESETS", "refractive_index", "parse_index", "parse_cauchy", "describe",
           "index_offset", "N_MIN", "N_MAX", "REFERENCE_WAVELENGTH_NM"]

#: Where a dispersive film's single index is quoted (the sodium D line, ``n_D``): scenes
#: and fits carry ``n(589.3 nm)`` as the film's index and the law's shape around it.
REFERENCE_WAVELENGTH_NM = 589.3

#: Range of indices accepted anywhere (a film thinner than air or denser than most
#: glasses is a typing error).
N_MIN, N_MAX = 1.0, 3.0


@dataclass(frozen=True)
class Cauchy:
    """Cauchy's dispersion law ``n(lambda) = sum_k c_k / lambda^(2k)``, lambda in nm.

    ``coefficients = (A, B, C, ...)``: ``A`` dimensionless, ``B`` in nm^2, ``C`` in nm^4.

    References
    ----------
    Born & Wolf, *Principles of Optics*, 7th ed., sec. 2.3.4, eq. (39).
    """

    coefficients: tuple[float, ...]

    def __call__(self, wavelength_nm):
        """The index at ``wavelength_nm`` (any shape, nm); numpy float64."""
        lam2 = np.asarray(wavelength_nm, dtype=np.float64) ** -2
        n = np.zeros_like(lam2)
        for c in reversed(self.coefficients):  # Horner in 1/lambda^2
            n = n * lam2 + c
        return n


#: A description of the film's index: a number, a Cauchy law, or a preset name.
IndexSpec = Union[float, Cauchy, str]

#: Named indices and their sources (lambda in nm).
PRESETS: dict[str, Cauchy] = {
    # Distilled water at 20 C, four-term Cauchy fit of Bashkatov & Genina (2003) with the
    # coefficients corrected for the typesetting errors of their Table 2 (as tabulated by
    # refractiveindex.info); within 1.3e-3 of Daimon & Masumura's (2007) Sellmeier
    # formula over 380-1000 nm (tests/test_dispersion.py).
    "water": Cauchy((1.31984, 5190.553, -2.56169e8, 9.39388e12)),
    # A surfactant (soap) solution film: n = 1.324188 + 3102.06 / lambda^2, the law used
    # in the soap-film thickness literature (1.340 at 450 nm, 1.330 at 750 nm). Its primary
    # source was not available to us: treat it as an approximation to within ~2e-3.
    "soap": Cauchy((1.324188, 3102.06)),
}


def refractive_index(spec: IndexSpec, wavelength_nm) -> np.ndarray:
    """The film's index at each wavelength (nm): an array shaped like ``wavelength_nm``.

    ``spec`` is a number, a :class:`Cauchy` law or a preset name (:data:`PRESETS`).
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    if isinstance(spec, str):
        spec = parse_index(spec)
    if isinstance(spec, Cauchy):
        return spec(lam)
    return np.full_like(lam, float(spec))


def index_offset(spec: IndexSpec, wavelength_nm) -> np.ndarray:
    """``n(lambda) - n(REFERENCE_WAVELENGTH_NM)``: the shape of the law around its quoted
    index (zeros for a constant), so that ``n_D + index_offset`` is the index per wavelength."""
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    return refractive_index(spec, lam) - float(refractive_index(spec, REFERENCE_WAVELENGTH_NM))


def _check_range(spec: IndexSpec, where: str) -> IndexSpec:
    """Reject a law whose index leaves [N_MIN, N_MAX] over 300-2000 nm."""
    n = refractive_index(spec, np.linspace(300.0, 2000.0, 200)) if isinstance(spec, Cauchy) else np.array([spec])
    if not np.all(np.isfinite(n)) or n.min() < N_MIN or n.max() > N_MAX:
        raise InputError(f"{where}: the index must stay within [{N_MIN:g}, {N_MAX:g}] "
                         f"(got {float(np.nanmin(n)):.4g} .. {float(np.nanmax(n)):.4g} over 300-2000 nm)")
    return spec


def parse_index(value, where: str = "n_film") -> IndexSpec:
    """A scene's or option's ``n_film``: a number, ``{cauchy = [A, B(, C)]}`` or a preset name.

    Raises :class:`~bubblefit.errors.InputError` (one line naming ``where``) otherwise.
    """
    if isinstance(value, Cauchy):
        return _check_range(value, where)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise InputError(f"{where} must be a finite number, got {value!r}")
        return _check_range(float(value), where)
    if isinstance(value, str):
        key = value.strip().lower()
        if key not in PRESETS:
            raise InputError(f"{where}: unknown index preset {value!r} (known: {', '.join(PRESETS)})")
        return PRESETS[key]
    if isinstance(value, dict):
        if set(value) != {"cauchy"}:
            raise InputError(f"{where} as a table must be {{cauchy = [A, B]}} or {{cauchy = [A, B, C]}}, got {value!r}")
        coef = value["cauchy"]
        ok = isinstance(coef, (list, tuple)) and 2 <= len(coef) <= 4 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in coef)
        if not ok:
            raise InputError(f"{where}.cauchy must be 2 or 3 finite numbers [A, B(, C)] (lambda in nm), got {coef!r}")
        return _check_range(Cauchy(tuple(float(c) for c in coef)), where)
    raise InputError(f"{where} must be a number, {{cauchy = [A, B(, C)]}} or one of {', '.join(PRESETS)}; got {value!r}")


def parse_cauchy(text: str, where: str = "--cauchy") -> Cauchy:
    """``"A,B"`` or ``"A,B,C"`` (lambda in nm) from the command line, as a :class:`Cauchy` law."""
    try:
        coef = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"{where} must be A,B or A,B,C (numbers, lambda in nm), got {text!r}") from None
    return parse_index({"cauchy": coef}, where)  # type: ignore[return-value]


def describe(spec: IndexSpec) -> str:
    """A short human-readable form, e.g. ``"1.4"`` or ``"cauchy(1.324188, 3102.06)"``."""
    if isinstance(spec, str):
        return spec
    if isinstance(spec, Cauchy):
        for name, law in PRESETS.items():
            if law == spec:
                return name
        return "cauchy(" + ", ".join(f"{c:.10g}" for c in spec.coefficients) + ")"
    return f"{float(spec):g}"
