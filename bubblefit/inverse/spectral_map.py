"""Thickness maps from spectral images: a spectrum per pixel (a hyperspectral cube) or per
row (a line scan), one lamp shared by every pixel.

Each pixel ``p`` reads ``y_p(nu) = a_p L(nu) R(d_p, nu) + c_p + noise``: the lamp ``L``
(times the camera's response) is the same for the whole image, ``a_p`` its brightness at
the pixel (the illumination is not uniform) and ``c_p`` the pixel's stray light; ``R`` is
the exact Airy reflectance at normal incidence with the film's dispersion
(:func:`bubblefit.inverse.spectrum.film_reflectance`, Born & Wolf 7.6(13)). For a given
``d`` the model is linear in ``(a_p, c_p)``; projecting out the offset centres both sides,
and the profile residual is ``RSS_p(d) = |y_c|^2 - C_p(d)^2`` with
``C_p(d) = y_c . f_c(d) / |f_c(d)|``, ``f = L R(d)``, ``_c`` the mean removed, and
``a_p >= 0`` (a lamp shines: ``C_p < 0`` is the no-film fit). The global thickness search is
therefore a matched filter: one matrix product of the centred pixels with the centred,
normalised model spectra on the thickness grid (a quarter radian of phase at the bluest
band, as :func:`bubblefit.inverse.spectrum.fit_spectrum` searches), and its largest
local maxima are each pixel's candidate thicknesses (variable projection, Golub &
Pereyra 1973).

The lamp, when no reference reading gives it, is a Legendre series in wavenumber
(:func:`bubblefit.inverse.spectrum._lamp_basis`) fitted to a sample of pixels by
alternation: their thicknesses, brightnesses and offsets with the lamp held, then the lamp's
coefficients by linear least squares with those held (block coordinate descent; the pixels'
films differ, so their fringes do not add up to a shape the lamp could take).

The interference order is made coherent between neighbours as in the photographs' maps: a
pixel whose candidates are within ``ambiguity_dchi2`` of its best takes the one nearest the
median of its neighbourhood; a pixel still more than half an order from that median is an
order hop and not ok; so is a pixel the model does not explain (its residual over twice its
noise and the model-error floor, as for one reading). The chosen thickness is refined by two successive parabolas through
``C_p`` at three points (a quarter, then a sixteenth of a grid step apart; one compiled
kernel for a whole block of pixels, no loop over pixels), and its standard error is
``sqrt(s^2 / (-C C''))`` (from ``RSS'' = -2 C C''`` at the maximum, ``var = 2 s^2 / RSS''``,
``s^2 = RSS / (N - 3)``).

The image is read and fitted a block of pixels at a time (the matched filter's block is
``(pixels, thicknesses)``), so memory is bounded by the block size and the maps; the blocks
can run on a Dask cluster.

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1 (Airy reflectance of a plate).
G. H. Golub and V. Pereyra, SIAM J. Numer. Anal. 10, 413-432 (1973) (variable projection).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..io.cubes import SpectralCube
from ..io.spectra import Spectrum
from ..optics import dispersion, film
from .spectrum import (MISFIT_RATIO, MODEL_ERROR_FLOOR, SpectrumOptions, _lamp_basis, _order_spacing, _search_grid,
                       reflector)

__all__ = ["MapOptions", "ThicknessMap", "fit_cube", "count_order_hops"]

_FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))


@dataclass(frozen=True)
class MapOptions:
    """How :func:`fit_cube` reads a spectral image.

    Attributes
    ----------
    n_film : the film's index (number, Cauchy law or preset; default the soap law).
    thickness_range : (min, max) nm searched.
    wavelength_range : (min, max) nm of the bands used, or None for all.
    resolution_nm : the bands' FWHM (nm), 0 for point samples: fringes finer than a band
        are washed out (:func:`bubblefit.optics.film.filtered_airy_reflectance`).
    lamp_terms : Legendre terms of the shared lamp when no reference gives it (8: a
        smooth lamp times a camera's response over the visible).
    lamp_rounds : alternations of the lamp's fit.
    lamp_pixels : about how many pixels (evenly spread) fit the lamp.
    candidates : local maxima kept per pixel for the order's coherence.
    ambiguity_dchi2 : a candidate within this ``chi^2`` of the best is a possible order.
    window : side (pixels) of the neighbourhood whose median decides between them.
    block_pixels : pixels per block of the matched filter (memory: about
        ``block_pixels x thicknesses x 4`` bytes, a few times over).
    """

    n_film: dispersion.IndexSpec = "soap"
    thickness_range: tuple[float, float] = (0.0, 15000.0)
    wavelength_range: tuple[float, float] | None = None
    resolution_nm: float = 0.0
    lamp_terms: int = 8
    lamp_rounds: int = 3
    lamp_pixels: int = 4096
    candidates: int = 3
    ambiguity_dchi2: float = 10.0
    window: int = 5
    block_pixels: int = 2048


@dataclass
class ThicknessMap:
    """A thickness map (nm, (H, W); W 1 for a line scan) with its standard error, which
    pixels can be trusted (``ok``), the ``chi^2`` gap to the best other order, the lamp used
    at the image's wavelengths, the thickness between orders, and notes for the user."""

    thickness_nm: np.ndarray
    stderr_nm: np.ndarray
    ok: np.ndarray
    delta_chi2: np.ndarray
    wavelength_nm: np.ndarray
    lamp: np.ndarray
    order_spacing_nm: float
    from_neighbours: int = 0
    order_hops: int = 0
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """Scalar results as a JSON-ready dict."""
        t, e, ok = self.thickness_nm, self.stderr_nm, self.ok
        good = ok & np.isfinite(t)
        return {"shape": list(t.shape), "pixels_ok": int(good.sum()), "fraction_ok": float(good.mean()),
                "median_thickness_nm": float(np.nanmedian(t)) if np.isfinite(t).any() else float("nan"),
                "median_stderr_nm": float(np.median(e[good])) if good.any() else float("nan"),
                "order_spacing_nm": self.order_spacing_nm, "orders_from_neighbours": self.from_neighbours,
                "order_hops": self.order_hops, "notes": list(self.notes)}


# ------------------------------------------------------------------------------- kernels
@partial(jax.jit, static_argnums=2)
def _matched_filter(y, fn, k: int):
    """Centred pixels ``y`` (P, N) against centred, normalised model spectra ``fn`` (D, N):
    ``C = y fn^T`` (P, D); the ``k`` largest local maxima of each row with ``C > 0`` (the
    no-film fit, ``C <= 0``, excluded), each refined by the parabola through its three grid
    values. Returns their fractional grid positions and values (P, k) (``-inf`` where a
    pixel has fewer maxima)."""
    c = y @ fn.T
    edge = jnp.full((c.shape[0], 1), -jnp.inf, c.dtype)
    left = jnp.concatenate([edge, c[:, :-1]], axis=1)
    right = jnp.concatenate([c[:, 1:], edge], axis=1)
    peak = (c >= left) & (c > right) & (c > 0)
    val, idx = jax.lax.top_k(jnp.where(peak, c, -jnp.inf), k)
    lo = jnp.take_along_axis(c, jnp.maximum(idx - 1, 0), axis=1)
    hi = jnp.take_along_axis(c, jnp.minimum(idx + 1, c.shape[1] - 1), axis=1)
    curv = lo - 2.0 * val + hi
    shift = jnp.clip(jnp.where(curv < 0, 0.5 * (lo - hi) / jnp.where(curv < 0, curv, -1.0), 0.0), -0.5, 0.5)
    top = jnp.maximum(val - 0.25 * (lo - hi) * shift, val)
    found = jnp.isfinite(val)
    return jnp.where(found, idx + shift, jnp.nan), jnp.where(found, top, -jnp.inf)


def _top_candidates(y: np.ndarray, fn: np.ndarray, k: int):
    """:func:`_matched_filter` on numpy arrays (float32): (P, k) grid positions and ``C``."""
    pos, val = _matched_filter(jnp.asarray(y, jnp.float32), jnp.asarray(fn, jnp.float32), k)
    return np.asarray(pos, np.float64), np.asarray(val, np.float64)


def _model_spectra(lamp: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``f = L R`` (D, N) centred and normalised per thickness (rows of zero norm stay 0)."""
    f = r * lamp[None, :]
    f = f - f.mean(axis=1, keepdims=True)
    norm = np.linalg.norm(f, axis=1, keepdims=True)
    return f / np.where(norm > 0, norm, 1.0)


def _centre(y: np.ndarray):
    """Pixels (P, N) with their means removed, their centred sums of squares, and which are
    usable (finite and not constant)."""
    good = np.all(np.isfinite(y), axis=1)
    y = np.where(good[:, None], y, 0.0)
    yc = y - y.mean(axis=1, keepdims=True)
    syy = np.einsum("pn,pn->p", yc, yc)
    return yc, syy, good & (syy > 0)


@partial(jax.jit, static_argnums=5)
def _correlation(d, yc, lam, n, lamp, filtered: bool, sigma):
    """``C_p(d_p + o)`` (P, O) for thicknesses ``d`` (P, O) and centred pixels ``yc`` (P, N):
    the pixel against the centred, normalised model ``L R(d)``."""
    args = (d[..., None], lam, n, 1.0)
    # at normal incidence the two polarisations coincide: one is enough
    r = (film.filtered_airy_reflectance(*args, sigma) if filtered else film.airy_reflectance(*args))[..., 0]
    f = lamp * r
    f = f - f.mean(axis=-1, keepdims=True)
    return jnp.einsum("pon,pn->po", f, yc) / jnp.sqrt(jnp.sum(f * f, axis=-1))


def _refine(s: "_Setup", lamp: np.ndarray, d0: np.ndarray, yc: np.ndarray, step: float, rounds: int = 2):
    """The maximum of ``C_p(d)`` near ``d0`` (P,) by successive parabolas through three
    points ``h`` apart (``h`` a quarter step, then a sixteenth, ...), each move clipped to
    ``2 h``; returns ``d``, ``C`` at the last parabola's vertex, and ``C''`` (from it)."""
    lam, n, lp = (jnp.asarray(v, jnp.float32) for v in (s.lam, s.n, lamp))
    sigma = jnp.asarray(s.sigma if s.sigma is not None else np.zeros_like(s.lam), jnp.float32)
    y = jnp.asarray(yc, jnp.float32)
    d = np.asarray(d0, np.float64)
    h = 0.25 * step
    for _ in range(rounds):
        pts = d[:, None] + h * np.array([-1.0, 0.0, 1.0])[None, :]
        c = np.asarray(_correlation(jnp.asarray(pts, jnp.float32), y, lam, n, lp, s.sigma is not None, sigma),
                       np.float64)
        curv = c[:, 0] - 2.0 * c[:, 1] + c[:, 2]
        down = curv < 0
        x = np.where(down, 0.5 * (c[:, 0] - c[:, 2]) / np.where(down, curv, -1.0), 0.0)  # vertex, in units of h
        x = np.where(down, np.clip(x, -2.0, 2.0), np.where(c[:, 2] > c[:, 0], 1.0, -1.0))
        top = np.where(down, c[:, 1] + 0.5 * (c[:, 2] - c[:, 0]) * x + 0.5 * curv * x**2, c.max(axis=1))
        d = d + h * x
        last = (h, curv, top, c[:, 1])
        h *= 0.25
    h, curv, top, mid = last
    return d, np.maximum(top, mid), curv / h**2


# ---------------------------------------------------------------------------- the image
@dataclass
class _Setup:
    lam: np.ndarray
    n: np.ndarray
    keep: np.ndarray
    grid: np.ndarray
    r: np.ndarray
    sigma: np.ndarray | None
    dark: np.ndarray | float
    order_spacing: float


def _setup(cube: SpectralCube, opts: MapOptions, dark: Spectrum | None) -> _Setup:
    lam = cube.wavelength_nm
    keep = np.ones(len(lam), bool)
    if opts.wavelength_range is not None:
        lo, hi = opts.wavelength_range
        keep = (lam >= lo) & (lam <= hi)
        if keep.sum() < 16:
            raise InputError(f"cube {cube.path}: only {int(keep.sum())} bands within {lo:g}-{hi:g} nm")
    lam = lam[keep]
    n = dispersion.refractive_index(opts.n_film, lam)
    grid = _search_grid(lam, n, SpectrumOptions(thickness_range=opts.thickness_range))
    r = reflector(lam, n)(grid, opts.resolution_nm)
    sigma = None
    if opts.resolution_nm > 0:
        sigma = jnp.asarray(opts.resolution_nm / (_FWHM_PER_SIGMA * lam**2))
    dk = dark.on(lam, "dark") if dark is not None else 0.0
    return _Setup(lam, n, keep, grid, r, sigma, dk, _order_spacing(lam, n))


def _pixels(cube: SpectralCube, s: _Setup, r0: int, r1: int) -> np.ndarray:
    """Rows ``r0:r1`` of the image as (pixels, bands), the dark subtracted."""
    block = cube.rows(r0, r1)[..., s.keep]
    return block.reshape(-1, block.shape[-1]) - s.dark


def _fit_lamp(cube: SpectralCube, s: _Setup, opts: MapOptions) -> tuple[np.ndarray, list[str]]:
    """The shared lamp (N,) from a sample of pixels, by alternation (see the module)."""
    h, w = cube.shape
    stride = max(1, int(np.sqrt(h * w / max(opts.lamp_pixels, 1))))
    rows = range(0, h, stride) if w > 1 else range(0, h, max(1, h // max(opts.lamp_pixels, 1)))
    y = np.concatenate([_pixels(cube, s, r, r + 1)[::stride if w > 1 else 1] for r in rows])
    yc, syy, good = _centre(y)
    y, yc = y[good], yc[good]
    if len(y) < 8:
        raise InputError(f"cube {cube.path}: fewer than 8 pixels with a spectrum to fit the lamp from")
    basis = _lamp_basis(s.lam, opts.lamp_terms, None)
    mean = y.mean(axis=0)
    lamp = basis @ np.linalg.lstsq(basis, mean, rcond=None)[0]
    notes = []
    step = s.grid[1] - s.grid[0]
    for _ in range(opts.lamp_rounds):
        lamp = np.maximum(lamp, 1e-6 * np.max(np.abs(lamp)))
        pos, _ = _top_candidates(yc, _model_spectra(lamp, s.r), 1)
        d = s.grid[0] + step * np.nan_to_num(pos[:, 0])
        rr = reflector(s.lam, s.n)(d, opts.resolution_nm)          # (P, N)
        f = rr * lamp[None, :]
        fc = f - f.mean(axis=1, keepdims=True)
        a = np.einsum("pn,pn->p", yc, fc) / np.maximum(np.einsum("pn,pn->p", fc, fc), 1e-300)
        a = np.maximum(a, 0.0)
        c = y.mean(axis=1) - a * f.mean(axis=1)
        # lamp coefficients b: y - c = a R (B b), normal equations over pixels and bands
        wgt = np.sum((a[:, None] * rr) ** 2, axis=0)
        rhs = np.sum(a[:, None] * rr * (y - c[:, None]), axis=0)
        coef = np.linalg.lstsq(basis * np.sqrt(wgt)[:, None], rhs / np.sqrt(np.maximum(wgt, 1e-300)),
                               rcond=None)[0]
        new = basis @ coef
        if not np.all(np.isfinite(new)) or np.max(new) <= 0:
            notes.append("the lamp's fit did not converge; the pixels' mean spectrum is used as the lamp")
            break
        lamp = new / np.max(new)
    if np.ptp(d) < s.order_spacing:
        notes.append(f"the pixels sampled for the lamp span only {np.ptp(d):.0f} nm of thickness (less than an "
                     "order): the lamp may take up part of the film's spectrum; give --reference")
    return np.maximum(lamp, 1e-6), notes


def _search_block(cube: SpectralCube, s: _Setup, fn: np.ndarray, k: int, r0: int, r1: int):
    """Candidates of rows ``r0:r1``: thicknesses (P, k) nm, ``C`` (P, k), ``|y_c|^2`` (P,)."""
    yc, syy, good = _centre(_pixels(cube, s, r0, r1))
    pos, val = _top_candidates(yc, fn, k)
    step = s.grid[1] - s.grid[0]
    d = s.grid[0] + step * pos
    d[~good] = np.nan
    return d.astype(np.float32), val.astype(np.float32), syy


def _search_block_at(source: tuple, s: _Setup, fn: np.ndarray, k: int, r0: int, r1: int):
    """:func:`_search_block` on a Dask worker: the image opened there from its file."""
    from ..io.cubes import read_cube

    path, wavelengths, unit = source
    return _search_block(read_cube(path, wavelengths=wavelengths, unit=unit), s, fn, k, r0, r1)


def _blocks(cube: SpectralCube, opts: MapOptions):
    h, w = cube.shape
    rows = max(1, opts.block_pixels // w)
    return [(r, min(h, r + rows)) for r in range(0, h, rows)]


def _median_map(d: np.ndarray, window: int) -> np.ndarray:
    from scipy import ndimage

    size = (window, window) if d.shape[1] > 1 else (window, 1)
    filled = np.where(np.isfinite(d), d, np.nanmedian(d) if np.isfinite(d).any() else 0.0)
    return ndimage.median_filter(filled, size=size, mode="nearest")


def _coherent(cand: np.ndarray, dchi2: np.ndarray, opts: MapOptions, spacing: float):
    """The candidate index per pixel (H, W) nearest its neighbourhood's median among those
    within ``ambiguity_dchi2`` of the best, the median map, and how many pixels changed."""
    pick = np.zeros(cand.shape[:2], int)
    allowed = (dchi2 < opts.ambiguity_dchi2) & np.isfinite(cand)
    allowed[..., 0] = np.isfinite(cand[..., 0])
    for _ in range(3):
        chosen = np.take_along_axis(cand, pick[..., None], 2)[..., 0]
        med = _median_map(chosen, opts.window)
        dist = np.where(allowed, np.abs(cand - med[..., None]), np.inf)
        new = np.argmin(dist, axis=2)
        new[~np.isfinite(dist).any(axis=2)] = 0
        if np.array_equal(new, pick):
            break
        pick = new
    chosen = np.take_along_axis(cand, pick[..., None], 2)[..., 0]
    return pick, _median_map(chosen, opts.window)


def _misfit(y: np.ndarray, mean_square: np.ndarray) -> np.ndarray:
    """Pixels (P,) whose residual's mean square exceeds ``MISFIT_RATIO^2`` times their noise
    (from second differences, robustly: :func:`~._spectrum_profile.second_difference_noise`,
    here for every pixel at once) plus the model-error floor, as for one reading."""
    d2 = y[:, 2:] - 2.0 * y[:, 1:-1] + y[:, :-2]
    mad = np.median(np.abs(d2 - np.median(d2, axis=1, keepdims=True)), axis=1)
    noise = 1.4826 * mad / np.sqrt(6.0)
    level = MODEL_ERROR_FLOOR * np.mean(np.abs(y), axis=1)
    return mean_square > MISFIT_RATIO**2 * (noise**2 + level**2)


def count_order_hops(thickness_nm: np.ndarray, truth_nm: np.ndarray, spacing_nm: float) -> int:
    """Pixels whose thickness is off the truth by more than half an order (``spacing_nm``)."""
    return int(np.count_nonzero(np.abs(thickness_nm - truth_nm) > 0.5 * spacing_nm))


def fit_cube(cube: SpectralCube, *, options: MapOptions = MapOptions(), dark: Spectrum | None = None,
             reference: Spectrum | None = None, scheduler: str | None = None, progress=None) -> ThicknessMap:
    """The thickness map of a spectral image (see the module for the model and the steps).

    ``dark`` (one spectrum) is subtracted from every pixel; ``reference`` (the lamp read
    the same way, dark subtracted) is the shared lamp instead of the fitted one;
    ``scheduler`` is a Dask scheduler's address (the blocks then run on its workers, which
    must read the image's file at the same path); ``progress(stage, k, n)`` is called per
    block.

    References
    ----------
    Born & Wolf, sec. 7.6.1; Golub & Pereyra (1973).
    """
    s = _setup(cube, options, dark)
    notes: list[str] = []
    if reference is not None:
        lamp = reference.on(s.lam, "reference") - (s.dark if dark is not None else 0.0)
        if not np.all(lamp > 0):
            raise InputError(f"reference {reference.path}: not above its dark at every band used")
        lamp = lamp / lamp.max()
        notes.append("lamp: the reference reading")
    else:
        lamp, extra = _fit_lamp(cube, s, options)
        notes += [f"lamp: fitted to the image ({options.lamp_terms} Legendre terms in wavenumber), shared by every "
                  "pixel"] + extra
    fn = _model_spectra(lamp, s.r)
    h, w = cube.shape
    k = max(1, min(options.candidates, len(s.grid)))
    blocks = _blocks(cube, options)
    results = _run_blocks(cube, s, fn, k, blocks, scheduler, progress)
    cand = np.full((h * w, k), np.nan, np.float32)
    val = np.full((h * w, k), -np.inf, np.float32)
    syy = np.zeros(h * w)
    for (r0, r1), (d, v, q) in zip(blocks, results):
        cand[r0 * w:r1 * w], val[r0 * w:r1 * w], syy[r0 * w:r1 * w] = d, v, q
    nbands = len(s.lam)
    best = np.maximum(val[:, 0].astype(np.float64), 0.0)
    s2 = np.maximum(syy - best**2, 1e-300) / max(nbands - 3, 1)
    dchi2 = (best[:, None] ** 2 - np.maximum(val.astype(np.float64), 0.0) ** 2) / s2[:, None]
    cand, dchi2 = cand.reshape(h, w, k), dchi2.reshape(h, w, k)
    pick, med = _coherent(cand, dchi2, options, s.order_spacing)
    moved = int(np.count_nonzero(pick > 0))
    d0 = np.take_along_axis(cand, pick[..., None], 2)[..., 0].astype(np.float64).reshape(-1)
    # refine the chosen order's maximum (a second pass over the image, block by block)
    step = float(s.grid[1] - s.grid[0])
    thick = np.full(h * w, np.nan)
    stderr = np.full(h * w, np.inf)
    misfit = np.zeros(h * w, bool)
    size = max(b[1] - b[0] for b in blocks) * w
    lo, hi = options.thickness_range
    for i, (r0, r1) in enumerate(blocks):
        if progress is not None:
            progress("refining", i, len(blocks))
        raw = _pixels(cube, s, r0, r1)
        yc, q, good = _centre(raw)
        start = d0[r0 * w:r1 * w]
        good &= np.isfinite(start)
        m = len(yc)
        pad = size - m  # one block shape: one compiled kernel
        dd, cc, hh = _refine(s, lamp, np.pad(np.where(good, start, s.grid[0] + step), (0, pad)),
                             np.pad(yc, ((0, pad), (0, 0))), step)
        dd, cc, hh = np.clip(dd[:m], lo, hi), cc[:m], hh[:m]
        curv = np.where((hh < 0) & (cc > 0), -cc * hh, np.nan)
        var = np.maximum(q - cc**2, 1e-300) / max(nbands - 3, 1) / curv
        thick[r0 * w:r1 * w] = np.where(good, dd, np.nan)
        stderr[r0 * w:r1 * w] = np.where(good & np.isfinite(var), np.sqrt(np.abs(var)), np.inf)
        misfit[r0 * w:r1 * w] = _misfit(raw, np.maximum(q - cc**2, 0.0) / max(nbands - 3, 1))
    thick, stderr, misfit = thick.reshape(h, w), stderr.reshape(h, w), misfit.reshape(h, w)
    hop = np.abs(thick - med) > 0.5 * s.order_spacing
    others = np.where(np.arange(k)[None, None, :] == pick[..., None], np.inf, dchi2)
    gap = np.min(others, axis=2) if k > 1 else np.full((h, w), np.inf)
    ok = np.isfinite(thick) & np.isfinite(stderr) & (stderr < 0.25 * s.order_spacing) & ~hop & ~misfit
    if misfit.any():
        notes.append(f"{int(misfit.sum())} pixels are not explained by the model (residual over {MISFIT_RATIO:g} "
                     "times their noise and the model-error floor): not ok")
    if moved:
        notes.append(f"{moved} pixels took the order of their neighbours (their own best was within "
                     f"delta chi2 {options.ambiguity_dchi2:g} of it)")
    hops = int(np.count_nonzero(hop & np.isfinite(thick)))
    if hops:
        notes.append(f"{hops} pixels stay more than half an order from their neighbours' median: not ok")
    return ThicknessMap(thickness_nm=thick.astype(np.float32), stderr_nm=stderr.astype(np.float32), ok=ok,
                        delta_chi2=np.minimum(gap, 1e30).astype(np.float32), wavelength_nm=s.lam, lamp=lamp,
                        order_spacing_nm=float(s.order_spacing), from_neighbours=moved, order_hops=hops, notes=notes)


def _run_blocks(cube, s, fn, k, blocks, scheduler, progress):
    """The matched filter of every block, here or on a Dask cluster (``scheduler``)."""
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise InputError("--scheduler needs dask.distributed (pip install distributed)") from None
        try:
            client = Client(scheduler, timeout=30)
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from None
        with client:
            fn_f = client.scatter(fn, broadcast=True)
            futures = [client.submit(_search_block_at, cube.source, s, fn_f, k, r0, r1, pure=False)
                       for r0, r1 in blocks]
            return client.gather(futures)
    out = []
    for i, (r0, r1) in enumerate(blocks):
        if progress is not None:
            progress("searching", i, len(blocks))
        out.append(_search_block(cube, s, fn, k, r0, r1))
    return out
