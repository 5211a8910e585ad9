"""Spectrometer readings: two-column text files ``wavelength_nm, intensity``.

What spectrometers and their software write: columns separated by commas, tabs, spaces
or semicolons, with decimal commas where tabs or semicolons separate the columns; a
header (column names, an instrument's preamble such as Ocean Optics'
``>>>>>Begin Spectral Data<<<<<``) before the numbers and possibly a footer after them;
``#`` or ``%`` comment lines anywhere. Extra columns are ignored. Rows are sorted by
wavelength; repeated wavelengths are averaged. Rows with a non-finite value (``nan``,
``inf``: spectrometer software writes them at the detector's dead ends) are skipped and
counted (:attr:`Spectrum.skipped`).

Wavelengths may be written in nm, Angstrom, um or m: the unit is read from their range
(:func:`wavelength_unit`, :data:`UNIT_RANGES`) and said in :attr:`Spectrum.unit`, or forced
by the caller. Anything else (text between numeric rows, fewer than :data:`MIN_SAMPLES`
finite samples, more than :data:`MAX_SAMPLES` rows, wavelengths in no unit's range, a
reading that is the same number everywhere, intensities beyond :data:`MAX_INTENSITY`)
raises :class:`~bubblefit.errors.InputError` with one line naming the file and, where
there is one, the line.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["Spectrum", "read_spectrum", "MIN_SAMPLES", "MAX_SAMPLES", "MAX_INTENSITY", "UNIT_RANGES",
           "wavelength_unit", "check_intensity"]

#: Fewest samples a spectrum may have.
MIN_SAMPLES = 16

#: Most rows a spectrum file may have. Spectrometers' line detectors have 512 to 16384
#: pixels; the fit's cost grows with the samples (a 10^6-row file took minutes and
#: gigabytes), and fringes resolved by 20000 samples are resolved by fewer: bin the
#: reading first.
MAX_SAMPLES = 20000

#: Largest intensity magnitude read (arbitrary units): a 32-bit float's range. Squares of
#: larger numbers overflow the fit's least squares; no detector counts that far.
MAX_INTENSITY = 1e30

#: The wavelength ranges each unit may cover, in that unit, and its factor to nm: a
#: spectrometer for thin films reads between the near ultraviolet and the near infrared,
#: 100-2500 nm. The ranges do not overlap except nm and Angstrom on 1000-2500, where nm
#: is taken (checked in this order).
UNIT_RANGES = {"nm": (100.0, 2500.0, 1.0), "um": (0.1, 2.5, 1e3), "m": (1e-7, 2.5e-6, 1e9),
               "Angstrom": (1000.0, 25000.0, 0.1)}

#: The range accepted in nm when the unit is forced to nm (infrared readings included).
FORCED_NM_RANGE = (100.0, 20000.0)

_SPLIT = re.compile(r"[,;\s]+")
_SPLIT_STRONG = re.compile(r"[;\t]+")
_DECIMAL_COMMA = re.compile(r"^([-+]?\d+),(\d+(?:[eE][-+]?\d+)?)$")


@dataclass(frozen=True)
class Spectrum:
    """A reading: wavelengths (N,) in nm, increasing, and intensities (N,), arbitrary units."""

    wavelength_nm: np.ndarray
    intensity: np.ndarray
    path: str = ""
    #: Rows of the file skipped because a value was not finite.
    skipped: int = 0
    #: The unit the file's wavelengths were written in (converted to nm here).
    unit: str = "nm"

    def on(self, wavelength_nm: np.ndarray, what: str = "spectrum") -> np.ndarray:
        """This reading linearly interpolated onto ``wavelength_nm`` (which it must cover)."""
        lo, hi = self.wavelength_nm[0], self.wavelength_nm[-1]
        tol = 1e-6 * hi
        if wavelength_nm.min() < lo - tol or wavelength_nm.max() > hi + tol:
            raise InputError(f"{what} {self.path} covers {lo:g}-{hi:g} nm, which does not cover the spectrum's "
                             f"{wavelength_nm.min():g}-{wavelength_nm.max():g} nm (use --wavelength-range)")
        return np.interp(wavelength_nm, self.wavelength_nm, self.intensity)


def _numbers(line: str):
    """The first two numbers of a data line, or None if it is not one.

    A line with tabs or semicolons is split on them alone, so that decimal commas (what
    spreadsheet and instrument software write in many locales: ``400,12;0,5`` or
    ``400,12<TAB>0,5``) are read as decimal points, not as separators."""
    s = line.strip()
    if "\t" in s or ";" in s:
        parts = [_DECIMAL_COMMA.sub(r"\1.\2", p.strip(" ,")) for p in _SPLIT_STRONG.split(s) if p.strip(" ,")]
    else:
        parts = [p for p in _SPLIT.split(s) if p]
    if len(parts) < 2:
        return None
    try:
        return float(parts[0]), float(parts[1])
    except ValueError:
        return None


def wavelength_unit(lo: float, hi: float, what: str = "spectrum") -> tuple[str, float]:
    """The unit of wavelengths spanning ``lo``-``hi`` and its factor to nm, from
    :data:`UNIT_RANGES` (nm first); :class:`InputError` when no unit's range holds them."""
    for unit, (a, b, factor) in UNIT_RANGES.items():
        if a <= lo and hi <= b:
            return unit, factor
    ranges = ", ".join(f"{u} {a:g}-{b:g}" for u, (a, b, _) in UNIT_RANGES.items())
    raise InputError(f"{what}: wavelengths {lo:g}-{hi:g} are in no unit's range ({ranges}); "
                     "give the unit with --wavelength-unit")


def _convert_wavelengths(lam: np.ndarray, unit: str | None, what: str) -> tuple[np.ndarray, str]:
    """``lam`` in nm and the unit it was in (read from the range, or ``unit`` forced)."""
    lo, hi = float(lam.min()), float(lam.max())
    if unit is None:
        unit, factor = wavelength_unit(lo, hi, what)
    else:
        if unit not in UNIT_RANGES:
            raise InputError(f"wavelength unit must be one of {', '.join(UNIT_RANGES)}, got {unit!r}")
        factor = UNIT_RANGES[unit][2]
        a, b = FORCED_NM_RANGE
        if not (a <= lo * factor and hi * factor <= b):
            raise InputError(f"{what}: wavelengths {lo:g}-{hi:g} {unit} are {lo * factor:g}-{hi * factor:g} nm, "
                             f"outside {a:g}-{b:g} nm")
    return lam * factor, unit


def check_intensity(y: np.ndarray, what: str, constant_ok: bool = False) -> None:
    """:class:`InputError` for intensities no reading has: beyond :data:`MAX_INTENSITY` in
    magnitude, or (unless ``constant_ok``, as for a dark reading) the same value everywhere
    (no light read, or a constant fill)."""
    top = float(np.max(np.abs(y))) if y.size else 0.0
    if top > MAX_INTENSITY:
        raise InputError(f"{what}: intensities up to {top:.3g} are beyond any detector's range (at most "
                         f"{MAX_INTENSITY:g} in magnitude); rescale the reading")
    if not constant_ok and y.size and float(np.min(y)) == float(np.max(y)):
        raise InputError(f"{what}: every intensity is {float(y.flat[0]):g}: the reading holds no spectrum")


def read_spectrum(path: str | os.PathLike, unit: str | None = None, *, dark: bool = False) -> Spectrum:
    """Read a two-column spectrum file (see the module's description of what is accepted);
    ``unit`` forces the wavelengths' unit (a key of :data:`UNIT_RANGES`), else it is read
    from their range; a ``dark`` reading may be constant.

    Examples
    --------
    >>> import os, tempfile
    >>> import bubblefit as bf
    >>> path = os.path.join(tempfile.mkdtemp(), "film.csv")
    >>> rows = [f"{400 + 10 * k},5;0,{k:02d}" for k in range(20)]   # decimal commas
    >>> with open(path, "w") as f:
    ...     _ = f.write("wavelength_nm;intensity\\n" + "\\n".join(rows))
    >>> reading = bf.read_spectrum(path)
    >>> reading.wavelength_nm[:3].tolist(), reading.intensity[:3].tolist()
    ([400.5, 410.5, 420.5], [0.0, 0.01, 0.02])
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"spectrum {p}: no such file")
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise InputError(f"spectrum {p}: not a text file (expected two columns wavelength_nm,intensity)") from None
    except OSError as exc:
        raise InputError(f"spectrum {p}: cannot read it ({exc.strerror or exc})") from None
    rows, first, gap = [], None, None
    for no, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s[0] in "#%":
            continue
        vals = _numbers(s)
        if vals is None:
            if first is not None and gap is None:
                gap = no  # text after numbers: a footer, unless numbers follow
            continue
        if gap is not None:
            raise InputError(f"spectrum {p}, line {gap}: not two numbers ({text.splitlines()[gap - 1].strip()[:40]!r})")
        first = first or no
        rows.append(vals)
        if len(rows) > MAX_SAMPLES:
            raise InputError(f"spectrum {p}: more than {MAX_SAMPLES} rows; bin the reading to at most "
                             f"{MAX_SAMPLES} samples first (fringes are resolved by far fewer)")
    if len(rows) < MIN_SAMPLES:
        raise InputError(f"spectrum {p}: found {len(rows)} rows of two numbers; need at least {MIN_SAMPLES} "
                         "(columns wavelength_nm,intensity)")
    data = np.asarray(rows, dtype=np.float64)
    finite = np.all(np.isfinite(data), axis=1)
    skipped = int(np.count_nonzero(~finite))
    data = data[finite]
    if len(data) < MIN_SAMPLES:
        raise InputError(f"spectrum {p}: only {len(data)} of its {len(rows)} rows are finite numbers; need at "
                         f"least {MIN_SAMPLES}")
    lam, val = data[:, 0], data[:, 1]
    lam, unit = _convert_wavelengths(lam, unit, f"spectrum {p}")
    check_intensity(val, f"spectrum {p}", constant_ok=dark)
    order = np.argsort(lam, kind="stable")
    lam, val = lam[order], val[order]
    uniq, inv = np.unique(lam, return_inverse=True)
    if len(uniq) < len(lam):
        val = np.bincount(inv, weights=val) / np.bincount(inv)
        lam = uniq
    if len(lam) < MIN_SAMPLES:
        raise InputError(f"spectrum {p}: only {len(lam)} distinct wavelengths; need at least {MIN_SAMPLES}")
    return Spectrum(lam, val, str(p), skipped, unit)
