"""Refractive index against wavelength: a constant, a Cauchy or Sellmeier law, or a preset.

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
- :class:`Sellmeier`: ``n^2 = 1 + sum_k B_k lambda^2 / (lambda^2 - C_k)`` (glasses);
- a preset name from :data:`PRESETS` (``"water"``, ``"soap"``, ``"air"``, and for the
  media around a film or a gap ``"bk7"``, ``"soda-lime"``, ``"fused-silica"``).

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 2.3 (Cauchy's dispersion formula).
A. N. Bashkatov and E. A. Genina, "Water refractive index in dependence on temperature
and wavelength: a simple approximation", Proc. SPIE 5068, 393-395 (2003).
M. Daimon and A. Masumura, "Measurement of the refractive index of distilled water from
the near-infrared region to the ultraviolet region", Appl. Opt. 46, 3811-3820 (2007).
SCHOTT optical glass data sheet N-BK7 (Sellmeier coefficients).
I. H. Malitson, "Interspecimen comparison of the refractive index of fused silica",
J. Opt. Soc. Am. 55, 1205-1209 (1965).
M. Rubin, "Optical properties of soda lime silica glasses", Solar Energy Materials 12,
275-288 (1985).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

import numpy as np

from ..errors import InputError

__all__ = ["Cauchy", "Sellmeier", "IndexSpec", "PRESETS", "refractive_index", "parse_index", "parse_cauchy", "describe",
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
    #: Optional terms in positive powers, ``+ e_1 lambda^2 + e_2 lambda^4 ...`` (nm^-2, nm^-4):
    #: the infrared side of a glass's law as some fits write it (Rubin's soda-lime glass).
    rising: tuple[float, ...] = ()

    def __call__(self, wavelength_nm):
        """The index at ``wavelength_nm`` (any shape, nm); numpy float64."""
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        lam2 = lam ** -2
        n = np.zeros_like(lam2)
        for c in reversed(self.coefficients):  # Horner in 1/lambda^2
            n = n * lam2 + c
        for k, e in enumerate(self.rising, start=1):
            n = n + e * lam ** (2 * k)
        return n


@dataclass(frozen=True)
class Sellmeier:
    """Sellmeier's law ``n^2 = 1 + sum_k B_k lambda^2 / (lambda^2 - C_k)``, lambda in nm.

    ``b = (B_1, B_2, ...)`` dimensionless, ``c = (C_1, C_2, ...)`` in nm^2 (data sheets
    quote C in um^2: multiply by 1e6).

    References
    ----------
    Born & Wolf, *Principles of Optics*, 7th ed., sec. 2.3.4 (the dispersion formula of a
    medium with resonances); SCHOTT optical glass data sheets.
    """

    b: tuple[float, ...]
    c: tuple[float, ...]

    def __call__(self, wavelength_nm):
        """The index at ``wavelength_nm`` (any shape, nm); numpy float64."""
        lam2 = np.asarray(wavelength_nm, dtype=np.float64) ** 2
        n2 = np.ones_like(lam2)
        for b, c in zip(self.b, self.c):
            n2 = n2 + b * lam2 / (lam2 - c)
        return np.sqrt(n2)


#: A description of an index: a number, a Cauchy or Sellmeier law, or a preset name.
IndexSpec = Union[float, Cauchy, Sellmeier, str]

#: Named indices and their sources (lambda in nm).
PRESETS: dict[str, Cauchy | Sellmeier] = {
    # Distilled water at 20 C, four-term Cauchy fit of Bashkatov & Genina (2003) with the
    # coefficients corrected for the typesetting errors of their Table 2 (as tabulated by
    # refractiveindex.info); within 1.3e-3 of Daimon & Masumura's (2007) Sellmeier
    # formula over 380-1000 nm (tests/test_dispersion.py).
    "water": Cauchy((1.31984, 5190.553, -2.56169e8, 9.39388e12)),
    # A surfactant (soap) solution film: n = 1.324188 + 3102.06 / lambda^2, the law used
    # in the soap-film thickness literature (1.340 at 450 nm, 1.330 at 750 nm). Its primary
    # source was not available to us: treat it as an approximation to within ~2e-3.
    "soap": Cauchy((1.324188, 3102.06)),
    # Air as the package takes it everywhere else (the film functions' default outside
    # medium): 1 exactly; the true 1.00027-1.00029 changes a glass/air reflectance by < 0.1 %.
    "air": Cauchy((1.0,)),
    # SCHOTT N-BK7 data sheet: B = (1.03961212, 0.231792344, 1.01046945),
    # C = (0.00600069867, 0.0200179144, 103.560653) um^2 (n_d = 1.5168).
    "bk7": Sellmeier((1.03961212, 0.231792344, 1.01046945), (6000.69867, 20017.9144, 103560653.0)),
    # Clear soda-lime (window, microscope slide) glass, Rubin (1985):
    # n = 1.5130 - 0.003169 lambda^2 + 0.003962 / lambda^2, lambda in um (1.5234 at 587.6 nm).
    "soda-lime": Cauchy((1.5130, 3962.0), rising=(-3.169e-9,)),
    # Fused silica, Malitson (1965): B = (0.6961663, 0.4079426, 0.8974794),
    # sqrt(C) = (0.0684043, 0.1162414, 9.896161) um (n_D = 1.4585).
    "fused-silica": Sellmeier((0.6961663, 0.4079426, 0.8974794), (4679.148, 13512.06, 97934002.0)),
}


def refractive_index(spec: IndexSpec, wavelength_nm) -> np.ndarray:
    """The film's index at each wavelength (nm): an array shaped like ``wavelength_nm``.

    ``spec`` is a number, a :class:`Cauchy` law or a preset name (:data:`PRESETS`).
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    if isinstance(spec, str):
        spec = parse_index(spec)
    if isinstance(spec, (Cauchy, Sellmeier)):
        return spec(lam)
    return np.full_like(lam, float(spec))


def index_offset(spec: IndexSpec, wavelength_nm) -> np.ndarray:
    """``n(lambda) - n(REFERENCE_WAVELENGTH_NM)``: the shape of the law around its quoted
    index (zeros for a constant), so that ``n_D + index_offset`` is the index per wavelength."""
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    return refractive_index(spec, lam) - float(refractive_index(spec, REFERENCE_WAVELENGTH_NM))


def _check_range(spec: IndexSpec, where: str) -> IndexSpec:
    """Reject a law whose index leaves [N_MIN, N_MAX] over 300-2000 nm."""
    n = (refractive_index(spec, np.linspace(300.0, 2000.0, 200)) if isinstance(spec, (Cauchy, Sellmeier))
         else np.array([spec]))
    if not np.all(np.isfinite(n)) or n.min() < N_MIN or n.max() > N_MAX:
        raise InputError(f"{where}: the index must stay within [{N_MIN:g}, {N_MAX:g}] "
                         f"(got {float(np.nanmin(n)):.4g} .. {float(np.nanmax(n)):.4g} over 300-2000 nm)")
    return spec


def parse_index(value, where: str = "n_film") -> IndexSpec:
    """A scene's or option's ``n_film``: a number, ``{cauchy = [A, B(, C)]}`` or a preset name.

    Raises :class:`~bubblefit.errors.InputError` (one line naming ``where``) otherwise.
    """
    if isinstance(value, (Cauchy, Sellmeier)):
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
    if isinstance(spec, (Cauchy, Sellmeier)):
        for name, law in PRESETS.items():
            if law == spec:
                return name
        if isinstance(spec, Sellmeier):
            return "sellmeier(b=" + ", ".join(f"{b:.10g}" for b in spec.b) + "; c=" + ", ".join(
                f"{c:.10g}" for c in spec.c) + ")"
        return "cauchy(" + ", ".join(f"{c:.10g}" for c in spec.coefficients) + ")"
    return f"{float(spec):g}"
