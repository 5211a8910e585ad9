"""Spectrometer readings: two-column text files ``wavelength_nm, intensity``.

What spectrometers and their software write: columns separated by commas, tabs, spaces
or semicolons, with decimal commas where tabs or semicolons separate the columns; a
header (column names, an instrument's preamble such as Ocean Optics'
``>>>>>Begin Spectral Data<<<<<``) before the numbers and possibly a footer after them;
``#`` or ``%`` comment lines anywhere. Extra columns are ignored. Rows are sorted by
wavelength; repeated wavelengths are averaged. Rows with a non-finite value (``nan``,
``inf``: spectrometer software writes them at the detector's dead ends) are skipped and
counted (:attr:`Spectrum.skipped`). Anything else (text between numeric rows, fewer than
:data:`MIN_SAMPLES` finite samples, wavelengths outside 100-20000 nm) raises
:class:`~bubblefit.errors.InputError` with one line naming the file and, where there is
one, the line.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["Spectrum", "read_spectrum", "MIN_SAMPLES"]

#: Fewest samples a spectrum may have.
MIN_SAMPLES = 16

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


def read_spectrum(path: str | os.PathLike) -> Spectrum:
    """Read a two-column spectrum file (see the module's description of what is accepted).

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
    if lam.min() < 100.0 or lam.max() > 20000.0:
        raise InputError(f"spectrum {p}: wavelengths {lam.min():g}-{lam.max():g} are not in nm "
                         "(expected 100-20000 nm in the first column)")
    order = np.argsort(lam, kind="stable")
    lam, val = lam[order], val[order]
    uniq, inv = np.unique(lam, return_inverse=True)
    if len(uniq) < len(lam):
        val = np.bincount(inv, weights=val) / np.bincount(inv)
        lam = uniq
    if len(lam) < MIN_SAMPLES:
        raise InputError(f"spectrum {p}: only {len(lam)} distinct wavelengths; need at least {MIN_SAMPLES}")
    return Spectrum(lam, val, str(p), skipped)
