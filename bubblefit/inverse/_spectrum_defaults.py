"""What a set of readings is, read from the readings themselves: divided by the lamp or not,
one series or separate readings, in time order or not, and which reading of a draining
series read from its brightness is thinner than the film later was.

Each choice is made only when no option forces it, and is said in the result.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._spectrum_extrema import fringe_extrema
from ._spectrum_profile import local_noise

__all__ = ["looks_normalised", "series_normalised", "same_grid", "in_time_order", "ENVELOPE_WINDOWS",
           "FLAT_TOLERANCE", "SLOW_SLOPE", "DIVIDED_NOISE_RATIO", "TILTED_FLAT_TOLERANCE", "NOISE_WINDOWS", "noise_says_divided",
           "series_departures", "SeriesGroup", "series_groups"]

#: Most windows (equal in wavenumber) whose envelopes are compared (one per fringe at most).
ENVELOPE_WINDOWS = 6
#: Largest departure of a window's envelope from a straight line in wavenumber, as a
#: fraction of the mean envelope, of a reading divided by its lamp. A halogen lamp through
#: a spectrometer (3000 K Planck times the response) bends its envelope by 30 % or more
#: over 400-800 nm (the lamp of tests/test_spectrum.py: 45 %); the noise of a divided
#: reading's dim end moves its envelope by a few per cent.
FLAT_TOLERANCE = 0.12
#: Largest change of that line over the range, as a fraction of its mean: a slow slope
#: (a lamp that drifted between the reference and the reading; the divided readings of
#: tests/test_spectrum_normalised.py tilt by 40 %).
SLOW_SLOPE = 0.5
#: Windows (equal in wavenumber) in which the noise and the light are compared.
NOISE_WINDOWS = 8
#: A raw reading's noise is ``sqrt(a + b I + c I^2)`` (read, shot and flicker noise) of its
#: light ``I``, so the noise of its noisiest window is at most ``max(1, I_k / I_median)``
#: times the median window's: noise grows no faster than the light. A reading divided by its
#: lamp is noisiest where the lamp was dim, whatever its level there. The reading is marked
#: divided when its noisiest window's noise exceeds the median by more than this factor
#: times ``max(1, I_k / I_median)`` (twice the bound, for the scatter of a median over an
#: eighth of a reading). Measured: optifik's lamp-divided readings (``data/spectraVictor1``
#: and ``spectraVictor2``, 315 readings) 3.4-17; the synthetic raw readings of
#: tests/test_spectrum.py (noise of constant deviation) about 1.
DIVIDED_NOISE_RATIO = 2.0
#: Largest departure of the envelope from a line of a divided reading recognised by its
#: noise (a steep tilt is then allowed): twice :data:`FLAT_TOLERANCE`, still below the
#: 45 % hump of a halogen lamp through a spectrometer and the 57-68 % of optifik's raw
#: thick-film readings (``spectraLorene/sample2``; divided by a lamp too, by their noise,
#: but by one that was not the lamp that lit the film).
TILTED_FLAT_TOLERANCE = 2.0 * FLAT_TOLERANCE


def looks_normalised(wavelength_nm: np.ndarray, y: np.ndarray) -> tuple[bool | None, str]:
    """Whether a reading looks already divided by its lamp (None: it cannot tell), and why.

    A film's reflectance swings between its minima and maxima with an upper envelope
    (``4 R1 / (1 + R1)^2``, ~0.08 for soap water) that is flat over the visible; a reading
    divided by the lamp keeps that flat envelope, up to a slow slope, where a raw reading's
    envelope is the lamp's shape. The envelope is the swing (95th less 5th percentile, less
the noise's own span in quadrature, the noise from
:func:`~bubblefit.inverse._spectrum_profile.local_noise`) of each of
    :data:`ENVELOPE_WINDOWS` windows equal in wavenumber; the reading is divided when the
    envelope departs from a line by at most :data:`FLAT_TOLERANCE` of its mean and the
    line changes by at most :data:`SLOW_SLOPE` of it. A divided reading may also tilt more
    (a lamp that drifted further, or a reference that was not the lamp alone): it is then
    told by its noise, which is largest where the lamp it was divided by was dim, so it
    does not follow its light (:func:`noise_says_divided`), with the envelope within
    :data:`TILTED_FLAT_TOLERANCE` of a line. A reading with fewer than one fringe per window
    has no envelope to see: it is read as divided when its noise says so (a film of under
    three fringes cannot be told from a raw lamp's shape by its envelope, and the raw
    model's five lamp terms cannot read it anyway), else None."""
    lam = np.asarray(wavelength_nm, np.float64)
    y = np.asarray(y, np.float64)
    nu = 1.0 / lam
    if len(y) < 8 * ENVELOPE_WINDOWS:
        return None, "too few samples to see an envelope"
    extrema = len(fringe_extrema(lam, y))
    windows = min(ENVELOPE_WINDOWS, extrema // 2)  # one fringe a window at least
    noise = local_noise(y)
    if windows < 3:
        few = f"fewer than 3 clear fringes ({extrema} extrema): no envelope to judge"
        divided, ratio = noise_says_divided(lam, y, noise)
        if divided:
            return True, (f"{few}, and its noise is {ratio:.1f} times what its light allows a raw reading "
                          f"(divided: over {DIVIDED_NOISE_RATIO:g}; the noise is largest where the lamp was dim)")
        return None, few
    edges = np.linspace(nu.min(), nu.max(), windows + 1)
    env, mid = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (nu >= a) & (nu <= b)
        if sel.sum() < 8:
            return None, "too few samples per window to see an envelope"
        top, bottom = np.percentile(y[sel], [95, 5])
        # the noise widens the percentiles' span by about its own 5-95 % span, 3.29 sigma
        spread = 3.29 * float(np.median(noise[sel]))
        env.append(np.sqrt(max((top - bottom) ** 2 - spread**2, 0.0)))
        mid.append(0.5 * (a + b))
    env, u = np.array(env), np.array(mid)
    mean = float(np.mean(env))
    if not mean > 0:
        return None, "its envelope is not positive"
    coef = np.polyfit(u, env, 1)
    line = np.polyval(coef, u)
    bend = float(np.max(np.abs(env - line)) / mean)
    slope = float(abs(line[-1] - line[0]) / mean)
    flat = bend <= FLAT_TOLERANCE and slope <= SLOW_SLOPE
    why = (f"its upper envelope departs {bend:.0%} from a line that changes {slope:.0%} over the range "
           f"(divided: within {FLAT_TOLERANCE:.0%} and {SLOW_SLOPE:.0%})")
    if flat or bend > TILTED_FLAT_TOLERANCE or np.min(env) <= 0:
        return flat, why
    divided, ratio = noise_says_divided(lam, y, noise)
    if divided:
        return True, (f"its upper envelope departs {bend:.0%} from a line that changes {slope:.0%} over the range, "
                      f"and its noise is {ratio:.1f} times what its light allows a raw reading (divided: within "
                      f"{TILTED_FLAT_TOLERANCE:.0%} and over {DIVIDED_NOISE_RATIO:g})")
    return False, why + f"; its noise follows its light ({ratio:.1f} times a raw reading's bound)"


def noise_says_divided(wavelength_nm: np.ndarray, y: np.ndarray, noise: np.ndarray | None = None) -> tuple[bool, float]:
    """Whether a reading's noise says it was divided by a lamp, and the ratio measured.

    A raw reading's noise variance is ``a + b I + c I^2`` of its light ``I`` (read noise,
    shot noise, the lamp's flicker), so between two parts of the reading the noise changes
    by at most ``max(1, I_1 / I_0)``. Of :data:`NOISE_WINDOWS` windows equal in wavenumber,
    the noisiest's median noise over the median window's, divided by ``max(1, level ratio)``,
    is that ratio (at most 1 for a raw reading); divided when it exceeds
    :data:`DIVIDED_NOISE_RATIO`. ``noise`` is the local noise
    (:func:`~bubblefit.inverse._spectrum_profile.local_noise`) when already computed."""
    lam = np.asarray(wavelength_nm, np.float64)
    y = np.asarray(y, np.float64)
    noise = local_noise(y) if noise is None else noise
    nu = 1.0 / lam
    edges = np.linspace(nu.min(), nu.max(), NOISE_WINDOWS + 1)
    level, sigma = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (nu >= a) & (nu <= b)
        if sel.sum() < 8:
            return False, float("nan")
        level.append(abs(float(np.mean(y[sel]))))
        sigma.append(float(np.median(noise[sel])))
    level, sigma = np.array(level), np.array(sigma)
    k = int(np.argmax(sigma))
    mid_sigma, mid_level = float(np.median(sigma)), float(np.median(level))
    if not (mid_sigma > 0 and mid_level > 0):
        return False, float("nan")
    ratio = float(sigma[k] / mid_sigma / max(1.0, level[k] / mid_level))
    return ratio > DIVIDED_NOISE_RATIO, ratio


def series_normalised(spectra, dark=None) -> tuple[bool, str]:
    """Whether a series' readings are divided by their lamp, by the majority of those that
    can be judged (:func:`looks_normalised`: by their envelope or their noise): one lamp, one
    treatment for all."""
    votes = []
    for s in spectra:
        y = s.intensity - (dark.on(s.wavelength_nm, "dark") if dark is not None else 0.0)
        votes.append(looks_normalised(s.wavelength_nm, y)[0])
    decided = [v for v in votes if v is not None]
    if not decided:
        return False, ("read as not divided: no reading of the series shows fringes enough to judge its envelope, "
                       "nor noise that says it was divided")
    flat = sum(decided)
    verdict = flat * 2 > len(decided)
    return verdict, (f"read as {'divided by their lamp' if verdict else 'not divided'}: {flat} of the "
                     f"{len(decided)} readings that can be judged look divided (a flat envelope, or noise that "
                     "does not follow the light)")


def same_grid(spectra) -> bool:
    """Whether the readings share their wavelengths (one spectrometer, one setting)."""
    first = spectra[0].wavelength_nm
    return all(len(s.wavelength_nm) == len(first) and np.allclose(s.wavelength_nm, first, rtol=1e-7, atol=1e-6)
               for s in spectra[1:])


def _natural(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def in_time_order(paths: list[str]) -> tuple[bool, str]:
    """Whether the files are given in time order: their names in natural order (frame
    numbers, time stamps), or else their modification times increasing."""
    names = [Path(p).name for p in paths]
    if names == sorted(names, key=_natural) and any(ch.isdigit() for ch in "".join(names)):
        return True, "names in order"
    try:
        times = [Path(p).stat().st_mtime for p in paths]
    except OSError:
        return False, "no order"
    if all(b > a for a, b in zip(times, times[1:])):
        return True, "modification times in order"
    return False, "neither names nor times in order"


@dataclass(frozen=True)
class SeriesGroup:
    """One series of a set of readings: the indices of its files (in the order given), what
    set it apart (``"folder"``, ``"name"`` or ``"given"``), its key (the folder or the
    name's stem), and whether it is in time order and why (:func:`in_time_order`)."""

    indices: tuple[int, ...]
    by: str
    key: str
    ordered: bool
    order_why: str

    def summary(self, paths) -> dict:
        return {"by": self.by, "key": self.key, "files": [paths[i] for i in self.indices],
                "time_ordered": self.ordered, "time_order": self.order_why}


def _stem_key(path: str) -> str:
    """A file name's stem less its trailing number (``run2_0013.xy`` -> ``run2_``)."""
    return re.sub(r"\d+$", "", Path(path).stem)


def series_groups(paths: list[str], by: str = "auto", ordered: bool | None = None) -> list[SeriesGroup]:
    """The series a set of readings forms, each with its own time order.

    Files taken on one instrument may come from several films (several draining runs, one
    a folder, or one a name stem such as ``runA_0001``, ``runB_0001``). They share the lamp
    but not a time order: a reading of one run says nothing about whether a reading of
    another thinned. ``by`` is ``"folder"`` (a series per parent folder), ``"name"`` (per
    name stem, the name less its trailing number), ``"one"`` (the files as given, one
    series) or ``"auto"`` (by folder when the files lie in several, else by name stem when
    the names have several stems, else one). ``ordered`` forces every series' time order
    (None: each is in time order when its names, or else its modification times, are:
    :func:`in_time_order`).

    Folders of which one ends on the frame the other begins with (a file of the same name
    stem and frame number, as ``T9503.xy`` and ``T09503.xy``) are one film filed in parts (``spectraVictor2`` of optifik's data: one draining film in
    six folders by interference order, 5543 to 25492): they are one series, its files in
    frame order, and its key names its folders (``parent/{order5,order4}``)."""
    keys: dict[str, list[int]] = {}
    if by == "auto":
        folders = {str(Path(p).resolve().parent) for p in paths}
        by = "folder" if len(folders) > 1 else "name" if len({_stem_key(p) for p in paths}) > 1 else "one"
    for i, p in enumerate(paths):
        key = (str(Path(p).resolve().parent) if by == "folder" else _stem_key(p) if by == "name" else "")
        keys.setdefault(key, []).append(i)
    if by == "folder":
        keys = _join_continued(keys, paths)
    out = []
    for key, idx in keys.items():
        if ordered is None:
            flag, why = in_time_order([paths[i] for i in idx])
        else:
            flag, why = ordered, "as forced"
        out.append(SeriesGroup(tuple(idx), "given" if by == "one" else by, key, flag, why))
    return out


def _frame(path: str) -> tuple[str, int] | None:
    """A file's name stem and trailing frame number (None without one)."""
    m = re.match(r"^(.*?)(\d+)$", Path(path).stem)
    return (m.group(1), int(m.group(2))) if m else None


def _join_continued(keys: dict[str, list[int]], paths: list[str]) -> dict[str, list[int]]:
    """Folders (``key -> indices``) joined into one, in frame order, where one ends on the frame
    the other begins with (two runs each numbered from 0 overlap instead, and stay apart)."""
    names = list(keys)
    frames = {k: {_frame(paths[i]) for i in keys[k]} - {None} for k in names}
    parent = {k: k for k in names}

    def root(k):
        while parent[k] != k:
            k = parent[k]
        return k

    def ends(k):  # the first and last frame of a folder (stem, number)
        f = sorted(frames[k], key=lambda t: t[1])
        return (f[0], f[-1]) if f else (None, None)

    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            (a0, a1), (b0, b1) = ends(names[a]), ends(names[b])
            if a0 is not None and b0 is not None and (a1 == b0 or b1 == a0):
                parent[root(names[b])] = root(names[a])
    joined: dict[str, list[str]] = {}
    for k in names:
        joined.setdefault(root(k), []).append(k)
    out = {}
    for members in joined.values():
        idx = [i for k in members for i in keys[k]]
        if len(members) > 1:
            idx.sort(key=lambda i: (_frame(paths[i]) or ("", -1))[1])
        if len(members) > 1:
            top = os.path.commonpath(members)
            out[f"{top}/{{{','.join(os.path.relpath(m, top) for m in members)}}}"] = idx
        else:
            out[members[0]] = idx
    return out


def series_departures(results, order_spacing: list[float], alone: set[int]) -> list[tuple[int, float, str]]:
    """Readings of a draining series in time order, not read by their own fringes, that are
    thinner than a later reading that is.

    A reading without fringes enough to be read alone is read from its brightness under the
    series' lamp; a film of one to a few micrometres whose fringes are washed out (a spread
    of thickness over the spot, the spectrometer's resolution) reflects the mean
    reflectance of its fringes, as bright as a film of ~100 nm, so its brightness reads it
    thin. A draining film does not thicken: a reading not in ``alone`` (the indices read by
    their own fringes) thinner, by more than a quarter of an order and three standard
    errors, than a later ``ok`` reading in ``alone`` is flagged.
    Returns (index, that later reading's thickness, the reason)."""
    d = np.array([r.thickness_nm for r in results])
    pins = [j for j in sorted(alone) if results[j].ok and np.isfinite(d[j])]
    out = []
    for i, r in enumerate(results):
        later = [j for j in pins if j > i]
        if i in alone or not later or not np.isfinite(d[i]):
            continue
        j = max(later, key=lambda k: d[k])
        gap = float(d[j] - d[i])
        if gap > 0.25 * order_spacing[i] and gap > 3.0 * r.thickness_nm_stderr:
            out.append((i, float(d[j]), f"a later reading of the series in time order, read by its own fringes, is "
                                        f"{d[j]:.0f} nm, {gap:.0f} nm thicker: a draining film does not thicken, and a "
                                        "thick film whose fringes are washed out is as bright as a thin one"))
    return out
