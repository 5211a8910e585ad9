"""Film thickness from a spectrometer reading: a global profile-likelihood search.

A film lit at normal incidence by a lamp of unknown spectrum ``L(nu)`` and read by a
spectrometer gives (after the dark reading is subtracted)

    I(nu) = L(nu) R(d, nu) + c + noise,

with ``R`` the exact Airy reflectance of the film in air (:func:`film_reflectance`, with
the index ``n(nu)`` of :mod:`bubblefit.optics.dispersion`), ``nu = 1/lambda`` the
wavenumber and ``c`` stray light. Without a reference reading the lamp is a smooth
function, a Legendre series of ``lamp_terms`` terms in ``nu``; with one (the lamp, or a
reflector, read the same way) it is the reference times such a series (one term, a
scale, by default). A reading already divided by the lamp (``normalised``) keeps only a
scale, tilt and curvature of it (3 terms). The stray light may have a smooth shape of
its own (``background_terms``, :func:`_background_basis`; one, a tilt, for a normalised
reading). For a given ``d`` the model is linear in the lamp's coefficients and the stray
light's, so they are solved exactly (variable projection), with the lamp kept
non-negative at every wavelength (a lamp cannot be negative, and one that dips below zero
is how a smooth series takes up a fringe; Lawson & Hanson's LSI), and the residual sum of
squares ``RSS(d)`` is the profile likelihood of ``d``. Its global minimum is found by a dense
search over the thickness range (step: a quarter radian of phase at the bluest
wavelength), the best few minima are refined locally together with the spectrometer's
resolution (a Gaussian of FWHM ``w`` nm that washes out fine fringes,
:func:`bubblefit.optics.film.filtered_airy_reflectance`), and the result says whether a
second minimum is within the noise (the interference order is then ambiguous), or whether
another split of the same smooth freedom between lamp and stray light puts the film in
another order within the noise (:func:`_lamp_split`).

Real readings are not equally good at every wavelength: a reading divided by the lamp is
noisiest where the lamp is dim, and a detector saturates or clips. Samples at the
detector's limits are left out (:func:`detector_limits`), and the residuals are weighted
by the local noise (:func:`~bubblefit.inverse._spectrum_profile.local_noise`) combined
with the model-error floor :data:`MODEL_ERROR_FLOOR` (weighted least squares, Press et al.,
*Numerical Recipes*, 3rd ed., sec. 15.1): a stretch of garbage counts as little as its
noise says, and the quietest stretch does not decide alone.

The standard error comes from the curvature of the profile: ``var(d) = 2 s^2 [H^-1]_dd``,
``H`` the Hessian of ``RSS`` in ``(d, w)`` and ``s^2 = RSS / (N - p)`` times the
correlation factor ``(1 + rho)/(1 - rho)`` of the residuals' lag-1 autocorrelation
``rho`` (a smoothed or over-sampled spectrum has fewer independent samples than
points), so that misfit widens it. See ``docs/design.md`` ("Spectra").

References
----------
Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1 (Airy reflectance of a plate).
G. H. Golub and V. Pereyra, "The differentiation of pseudo-inverses and nonlinear least
squares problems whose variables separate", SIAM J. Numer. Anal. 10, 413-432 (1973).
A. Scheludko, "Thin liquid films", Adv. Colloid Interface Sci. 1, 391-464 (1967) (the
fringe-intensity method this replaces).
C. L. Lawson and R. J. Hanson, *Solving Least Squares Problems* (Prentice-Hall, 1974),
ch. 23 (least squares with linear inequality constraints).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np
from numpy.polynomial import legendre

from ..errors import InputError
from ..io.spectra import Spectrum
from ..optics import dispersion, film
from ._spectrum_defaults import looks_normalised
from ._spectrum_drain import profile_candidates
from ._spectrum_extrema import RANDOM_PHASE, extrema_phase, fringe_extrema, fringe_minima, minima_phase
from ._spectrum_profile import (ProfileProblem, local_noise, profile_variance, refine_d, refine_dw, refine_near,
                                residual_correlation, rss_grids, second_difference_noise, second_minimum)

__all__ = ["SpectrumOptions", "SpectrumFit", "film_reflectance", "reflector", "fit_spectrum", "stray_basis",
           "resolve_normalised", "interference_order", "min_fringes"]

_FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))

#: Fewest fringes across the range for a thickness without a reference reading, with the
#: default 5-term lamp: a film with less than one fringe reflects a smooth spectrum of the
#: same kind as the lamp's smooth model, and the two cannot be separated.
#: :func:`min_fringes` scales it with the lamp's freedom.
MIN_FRINGES_WITHOUT_REFERENCE = 1.0


def min_fringes(lamp_terms: int) -> float:
    """Fewest fringes a film must show, without a reference, to be told apart from a lamp of
    ``lamp_terms`` Legendre terms: a quarter fringe per term beyond the scale
    (``(J - 1) / 4``: 1 for the default 5 terms, ``MIN_FRINGES_WITHOUT_REFERENCE``), and at
    least half a fringe (one extremum of ``R`` inside the range; with less, ``R`` is a
    monotonic ``sin^2`` ramp that a tilted lamp and offset reproduce).

    A degree ``J - 1`` polynomial has up to ``J - 1`` extrema; over a fraction of its range
    it bends like a quarter of a fringe per degree, so the lamp can imitate that much of the
    film's modulation (Golub & Pereyra's projection then takes it out of the profile)."""
    return max(0.5, MIN_FRINGES_WITHOUT_REFERENCE * (lamp_terms - 1) / 4.0)


#: Reflectances ``b`` of the lamp light that reaches the spectrometer without interfering,
#: ``I = L (R + b) + S``: a window or a wet frame in the beam, or a spot that spans films
#: of many orders (their fringes average to the mean reflectance ``2 R1 / (1 + R1)``,
#: ~0.04). It lifts the fringes' minima off the stray light in proportion to the lamp,
#: which a constant offset cannot do. A factor-2 ladder up to the film's peak ~0.08.
INCOHERENT_LEVELS = (0.0, 0.005, 0.01, 0.02, 0.04, 0.08)

#: A fit is trusted when its residual's rms is within ``MISFIT_RATIO`` times the reading's
#: noise (from its second differences) plus a model-error floor of ``MODEL_ERROR_FLOOR``
#: of the mean reading (the lamp's smooth model, the index law).
MISFIT_RATIO = 2.0
MODEL_ERROR_FLOOR = 0.005

#: A fit whose thickness leaves the reading's fringe extrema this far (rms of
#: ``4 n d / lambda`` from whole numbers, :mod:`._spectrum_extrema`) is not ok, when the
#: reading has at least ``EXTREMA_FOR_VERDICT`` clear extrema: two thirds of the way from
#: a thickness that fits them (0) to one unrelated to them (0.289). Correct fits of the
#: synthetic readings of tests/test_spectrum*.py score 0.015-0.15 (the smoothing and a
#: raw lamp's hump move the extrema; 0.145 for a raw 700 nm film with 5 extrema).
EXTREMA_PHASE_LIMIT = 0.2
EXTREMA_FOR_VERDICT = 4
#: A fit with fewer than ``EXTREMA_FOR_VERDICT`` extrema is not ok either when one clear fringe minimum lies further than this from an even
#: ``4 n d / lambda`` (:func:`~bubblefit.inverse._spectrum_extrema.minima_phase`): a minimum is a zero of
#: ``R``, which the lamp cannot move, so one minimum suffices. The same two thirds of the way as
#: ``EXTREMA_PHASE_LIMIT`` (from the synthetic readings of tests/test_spectrum*.py); on a film of order 1
#: (one minimum at ``x = 2``) it is 10 % of the thickness. The stray light's slope moves a
#: minimum by ``-S' / (L R'')``: under 0.01 in ``x`` on the order-1 readings of optifik's
#: spectraVictor2 (``S'`` of its void reading, ``L R''`` of the reading).
MINIMUM_PHASE_LIMIT = EXTREMA_PHASE_LIMIT


@dataclass(frozen=True)
class SpectrumOptions:
    """How :func:`fit_spectrum` reads a spectrum.

    Attributes
    ----------
    n_film : the film's index (number, :class:`~bubblefit.optics.dispersion.Cauchy` or
        preset name); default the soap-solution law.
    thickness_range : (min, max) nm searched.
    wavelength_range : (min, max) nm used, or None for the whole reading.
    lamp_terms : Legendre terms of the unknown lamp (None: 5 without a reference, 1 with,
        3 for a ``normalised`` reading).
    offset : fit a constant stray-light offset ``c``.
    normalised : the reading was already divided by the lamp (its envelope is flat up to a
        slow slope); None: decided from the reading (:func:`resolve_normalised`): the lamp left in it is a scale, tilt and curvature in wavenumber
        (3 terms; :func:`min_fringes` then asks for half a fringe), and the stray light
        gets a tilt (``background_terms`` 1), so that neither can take the shape of a fringe.
    background_terms : smooth stray-light terms added beyond the offset (None: 0, or 1 for
        a ``normalised`` reading); see :func:`_background_basis`.
    incoherent : fit lamp light that does not interfere, ``L (R + b)``, ``b`` one of
        ``INCOHERENT_LEVELS`` (profiled, the best over the whole search, kept only when it
        lowers ``chi^2`` by more than ``ambiguity_dchi2``). Off by default: on synthetic
        films of 150 nm without a reference (``b = 0``) the extra freedom let a 5-term lamp
        prefer a 330 nm alias, called ok.
    fit_resolution : fit the spectrometer's resolution (FWHM, nm) with the thickness.
    max_resolution_nm : its upper bound.
    ambiguity_dchi2 : a second minimum closer than this in ``chi^2`` makes the order
        ambiguous (10: the best minimum is ~150 times likelier, ``exp(10/2)``).
    """

    n_film: dispersion.IndexSpec = "soap"
    thickness_range: tuple[float, float] = (0.0, 15000.0)
    wavelength_range: tuple[float, float] | None = None
    lamp_terms: int | None = None
    offset: bool = True
    fit_resolution: bool = True
    max_resolution_nm: float = 10.0
    ambiguity_dchi2: float = 10.0
    normalised: bool | None = False
    background_terms: int | None = None
    incoherent: bool = False


@dataclass
class SpectrumFit:
    """The thickness read from one spectrum, with what a user needs to trust it."""

    thickness_nm: float
    thickness_nm_stderr: float
    stderr_statistical_nm: float
    stderr_lamp_nm: float
    ok: bool
    order: int
    fringes: float
    resolution_nm: float
    reduced_chi2: float
    residual_rms: float
    n_film: float
    second_minimum_nm: float
    delta_chi2: float
    reasons: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    wavelength_nm: np.ndarray | None = None
    measured: np.ndarray | None = None
    fitted: np.ndarray | None = None
    profile_nm: np.ndarray | None = None
    profile_chi2: np.ndarray | None = None
    #: Whether it was read as divided by its lamp, and why (detected or forced).
    normalised: bool = False
    normalised_why: str = ""
    #: The extrema phase test of the thickness (:mod:`._spectrum_extrema`; NaN with fewer
    #: than 3 clear extrema) and the number of extrema it used.
    extrema_phase: float = float("nan")
    extrema: int = 0
    #: The profile's distinct local minima within
    #: :data:`~bubblefit.inverse._spectrum_drain.CANDIDATE_DCHI2` of the best, as
    #: (thickness nm, ``chi^2`` above the best), best first: the sides of a maximum of ``R``
    #: a series in time order may choose between (:mod:`._spectrum_drain`).
    candidates: list = field(default_factory=list)
    #: Whether it was read with the lamp of its series (:mod:`._shared_lamp`), whose error
    #: (``stderr_lamp_nm``) is then common to the readings that lamp reads.
    shared_lamp: bool = False

    def summary(self) -> dict:
        """The scalar results as a JSON-ready dict (no arrays)."""
        keys = ("thickness_nm", "thickness_nm_stderr", "stderr_statistical_nm", "stderr_lamp_nm", "ok", "order", "fringes", "resolution_nm", "reduced_chi2",
                "residual_rms", "n_film", "second_minimum_nm", "delta_chi2", "reasons", "warnings", "normalised",
                "normalised_why", "extrema_phase", "extrema", "candidates", "shared_lamp")
        return {k: getattr(self, k) for k in keys}


@jax.jit
def _airy_kernel(d, lam, n):
    """Polarisation-averaged normal-incidence Airy reflectance (D, N)."""
    return film.airy_reflectance(d[:, None], lam[None, :], n[None, :], 1.0).mean(-1)


@jax.jit
def _filtered_kernel(d, lam, n, sigma):
    """The same seen through a Gaussian of deviation ``sigma`` (1/nm) in wavenumber."""
    return film.filtered_airy_reflectance(d[:, None], lam[None, :], n[None, :], 1.0, sigma[None, :]).mean(-1)


def film_reflectance(thickness_nm, wavelength_nm, n, resolution_nm: float = 0.0) -> np.ndarray:
    """Normal-incidence reflectance of a film in air, (D, N) for D thicknesses and N wavelengths.

    The exact Airy reflectance (:func:`bubblefit.optics.film.airy_reflectance`, float64),
    with ``n`` one index per wavelength; with ``resolution_nm > 0`` the spectrum seen by
    a spectrometer of that FWHM, a Gaussian of deviation
    ``sigma_nu = FWHM / (2.3548 lambda^2)`` in wavenumber
    (:func:`bubblefit.optics.film.filtered_airy_reflectance`).

    References
    ----------
    Born & Wolf, *Principles of Optics*, 7th ed., eq. 7.6(13).
    """
    return reflector(wavelength_nm, n)(thickness_nm, resolution_nm)


def reflector(wavelength_nm, n):
    """:func:`film_reflectance` at fixed wavelengths and index, as ``f(thickness_nm, resolution_nm)``.

    The arrays are converted once and thicknesses are evaluated in padded blocks of fixed
    size, so that the compiled kernels are reused across the many calls of a fit.
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    nn = np.broadcast_to(np.asarray(n, dtype=np.float64), lam.shape)
    with jax.enable_x64(True):
        lam_j, n_j = jnp.asarray(lam), jnp.asarray(nn)

    def reflect(thickness_nm, resolution_nm: float = 0.0) -> np.ndarray:
        d = np.atleast_1d(np.asarray(thickness_nm, dtype=np.float64))
        block = 1 if len(d) == 1 else 128
        out = np.empty((len(d), len(lam)))
        with jax.enable_x64(True):
            if resolution_nm > 0:
                sigma = jnp.asarray(float(resolution_nm) / (_FWHM_PER_SIGMA * lam**2))
                kernel, args = _filtered_kernel, (lam_j, n_j, sigma)
            else:
                kernel, args = _airy_kernel, (lam_j, n_j)
            for s in range(0, len(d), block):
                part = d[s:s + block]
                # (a numpy block goes to the kernel as it is: a fit makes thousands of
                # one-thickness calls, and np.pad and jnp.asarray cost more than the kernel)
                padded = part if len(part) == block else np.pad(part, (0, block - len(part)), mode="edge")
                out[s:s + len(part)] = np.asarray(kernel(padded, *args))[: len(part)]
        return out

    return reflect


def interference_order(thickness_nm: float, wavelength_nm: np.ndarray, n: np.ndarray) -> tuple[int, float]:
    """The order ``floor(2 n d / lambda)`` at the middle wavenumber of the range, and the
    number of fringes across it, ``2 d (n nu |_max - n nu |_min)`` (eq. 8 at normal incidence)."""
    nu = 1.0 / wavelength_nm
    mid = int(np.argmin(np.abs(nu - 0.5 * (nu.min() + nu.max()))))
    order = int(np.floor(2.0 * n[mid] * thickness_nm * nu[mid] + 1e-9))
    k = n * nu
    return order, float(2.0 * thickness_nm * (k.max() - k.min()))


def _order_spacing(wavelength_nm: np.ndarray, n: np.ndarray) -> float:
    """The thickness between interference orders at mid range, ``1 / (2 n nu)`` (eq. 8 at
    normal incidence, with the median ``n nu`` of the reading)."""
    return 1.0 / (2.0 * float(np.median(n / wavelength_nm)))


def _unit_wavenumber(wavelength_nm: np.ndarray, nu_range: tuple[float, float] | None = None) -> np.ndarray:
    """Wavenumber mapped linearly onto [-1, 1] over the range (the reading's own, or
    ``nu_range``, (min, max) 1/nm: a series' common one)."""
    nu = 1.0 / wavelength_nm
    lo, hi = (nu.min(), nu.max()) if nu_range is None else nu_range
    return 2.0 * (nu - lo) / max(hi - lo, 1e-30) - 1.0


def _lamp_basis(wavelength_nm: np.ndarray, terms: int, reference: np.ndarray | None) -> np.ndarray:
    """(N, terms) Legendre polynomials in wavenumber over the range, times the reference."""
    p = legendre.legvander(_unit_wavenumber(wavelength_nm), terms - 1)
    return p * reference[:, None] if reference is not None else p


def _background_basis(wavelength_nm: np.ndarray, terms: int, reference: np.ndarray | None,
                      nu_range: tuple[float, float] | None = None) -> np.ndarray | None:
    """(N, terms) additive stray-light columns beyond the constant offset, or None for 0 terms.

    Light that reaches the spectrometer without passing through the film's interference
    (a reflection off a window or the frame, light scattered in the spectrometer) adds
    incoherently: ``I = L R + S``. Without a reference ``S`` is a smooth series
    (Legendre ``P_1 .. P_terms`` in wavenumber; ``P_0`` is the offset ``c``); with one it
    has the lamp's spectrum, the reference times ``P_0 .. P_{terms-1}``. The polynomials
    are on the reading's own wavenumber range, or on ``nu_range`` (a series' stray light
    shared by readings of several ranges).
    """
    if terms <= 0:
        return None
    u = _unit_wavenumber(wavelength_nm, nu_range)
    if reference is None:
        return legendre.legvander(u, terms)[:, 1:]
    return legendre.legvander(u, terms - 1) * reference[:, None]


def stray_basis(p: "PreparedReading", nu_range: tuple[float, float]) -> np.ndarray:
    """(N, K) the stray-light columns of prepared reading ``p`` (its offset, then
    :func:`_background_basis`) on a series' common wavenumber range ``nu_range``: the same
    space as ``p.problem.additive``, the same coefficients for every reading of a series."""
    cols = [np.ones((len(p.y), 1))] if p.problem.offset else []
    bg = _background_basis(p.wavelength_nm, p.background_terms, p.reference, nu_range)
    if bg is not None:
        cols.append(bg)
    return np.column_stack(cols) if cols else np.zeros((len(p.y), 0))


def _prepare(spectrum: Spectrum, dark: Spectrum | None, reference: Spectrum | None, opts: SpectrumOptions):
    """Wavelengths, dark-subtracted intensities, the normalised reference (or None), the
    lamp's and the stray light's numbers of terms, the index per wavelength, and warnings."""
    lam, y = spectrum.wavelength_nm, spectrum.intensity.astype(np.float64)
    warnings: list[str] = []
    limited = detector_limits(y)
    if limited.any():
        if (~limited).sum() < 16:
            raise InputError(f"spectrum {spectrum.path}: only {int((~limited).sum())} samples below the detector's "
                             "ceiling and above its floor")
        top = int(np.count_nonzero(limited & (y == y.max())))
        warnings.append(f"{top} samples at the reading's ceiling (saturated) and {int(limited.sum()) - top} at its "
                        "floor (clipped) were left out")
        lam, y = lam[~limited], y[~limited]
    if opts.wavelength_range is not None:
        lo, hi = opts.wavelength_range
        keep = (lam >= lo) & (lam <= hi)
        if keep.sum() < 16:
            raise InputError(f"spectrum {spectrum.path}: only {int(keep.sum())} samples within {lo:g}-{hi:g} nm")
        lam, y = lam[keep], y[keep]
    dark_v = dark.on(lam, "dark") if dark is not None else 0.0
    y = y - dark_v
    ref = None
    if reference is not None:
        ref = reference.on(lam, "reference") - dark_v
        good = ref > 0.02 * np.max(ref)
        if good.sum() < 16:
            raise InputError(f"reference {reference.path}: fewer than 16 wavelengths with light after the dark")
        if not good.all():
            warnings.append(f"{int((~good).sum())} wavelengths where the reference is dark were left out")
        # a lamp read at full scale: the wavelengths its saturated samples touch
        saturated = np.interp(lam, reference.wavelength_nm, detector_limits(reference.intensity).astype(float)) > 0
        if saturated.any():
            good &= ~saturated
            if good.sum() < 16:
                raise InputError(f"reference {reference.path}: fewer than 16 wavelengths below its saturation")
            warnings.append(f"{int(saturated.sum())} wavelengths where the reference is saturated were left out")
        lam, y, ref = lam[good], y[good], ref[good]
        ref = ref / np.max(ref)
    terms = opts.lamp_terms if opts.lamp_terms is not None else (1 if ref is not None else 3 if opts.normalised else 5)
    if terms < 1 or terms > 20:
        raise InputError(f"lamp terms must be within 1..20, got {terms}")
    bg = opts.background_terms if opts.background_terms is not None else int(bool(opts.normalised))
    if bg < 0 or bg > 10:
        raise InputError(f"background terms must be within 0..10, got {bg}")
    n = dispersion.refractive_index(opts.n_film, lam)
    return lam, y, ref, terms, bg, n, warnings


#: Fewest samples at exactly the reading's largest value that mark a saturated detector,
#: and at exactly its smallest that mark a clipped floor (a reading at 0 where the
#: instrument subtracted its dark and clipped what fell below, or a divided reading where
#: the lamp gave no light).
SATURATED_SAMPLES = 2
CLIPPED_SAMPLES = 3


def detector_limits(y: np.ndarray) -> np.ndarray:
    """Samples (N,) at the detector's limits, which carry no measurement: every sample at
    exactly the reading's maximum when at least :data:`SATURATED_SAMPLES` of them are (a
    saturated pixel reads the full scale; noise makes two equal maxima of a real signal
    unlikely unless the reading is quantised to a few levels), and every sample at exactly
    its minimum when at least :data:`CLIPPED_SAMPLES` are."""
    y = np.asarray(y)
    top, bottom = y == y.max(), y == y.min()
    out = np.zeros(len(y), dtype=bool)
    if top.sum() >= SATURATED_SAMPLES and not bottom.all():
        out |= top
    if bottom.sum() >= CLIPPED_SAMPLES and not top.all():
        out |= bottom
    return out


def _search_grid(lam: np.ndarray, n: np.ndarray, opts: SpectrumOptions) -> np.ndarray:
    """Thicknesses of the global search: a quarter radian of phase (eq. 8) at the bluest sample."""
    dmin, dmax = opts.thickness_range
    if not (0.0 <= dmin < dmax):
        raise InputError(f"thickness range must be 0 <= MIN < MAX, got {dmin:g},{dmax:g}")
    step = 0.25 / (4.0 * np.pi * float(np.max(n / lam)))
    count = int(np.ceil((dmax - dmin) / step)) + 1
    if count > 400_000:
        raise InputError(f"thickness range {dmin:g}-{dmax:g} nm needs {count} search steps; narrow it (at most 400000)")
    return np.linspace(dmin, dmax, count)


@dataclass
class PreparedReading:
    """A reading ready to fit: its wavelengths (N,), dark-subtracted intensities, the
    normalised reference (or None), the index per wavelength, the weighted profile problem
    with the unknown lamp, the thickness search grid, the number of smooth stray-light
    terms, and the warnings so far."""

    wavelength_nm: np.ndarray
    y: np.ndarray
    reference: np.ndarray | None
    n: np.ndarray
    problem: ProfileProblem
    grid: np.ndarray
    background_terms: int
    warnings: list[str]

    @property
    def order_spacing(self) -> float:
        """The thickness between interference orders at mid range (:func:`_order_spacing`)."""
        return _order_spacing(self.wavelength_nm, self.n)


def prepared_problem(spectrum: Spectrum, dark: Spectrum | None, reference: Spectrum | None,
                     options: SpectrumOptions) -> PreparedReading:
    """The reading as :func:`fit_spectrum` fits it (:class:`PreparedReading`)."""
    lam, y, ref, terms, bg_terms, n, warnings = _prepare(spectrum, dark, reference, options)
    # Weighted least squares: each wavelength's variance is its measured noise plus the
    # model-error floor (the noise alone would let the quietest stretch, often a dim end
    # of the lamp, decide; the floor alone would let garbage where the lamp is dark count).
    sigma = np.hypot(local_noise(y), MODEL_ERROR_FLOOR * float(np.mean(np.abs(y))))
    weight = float(np.median(sigma)) / sigma
    prob = ProfileProblem(y, _lamp_basis(lam, terms, ref), options.offset, reflector(lam, n),
                          _background_basis(lam, bg_terms, ref), positive=True, weight=weight)
    return PreparedReading(lam, y, ref, n, prob, _search_grid(lam, n, options), bg_terms, warnings)


def fit_spectrum(spectrum: Spectrum, *, dark: Spectrum | None = None, reference: Spectrum | None = None,
                 options: SpectrumOptions = SpectrumOptions()) -> SpectrumFit:
    """Film thickness (nm) and its standard error from one spectrometer reading.

    See the module's description for the model; ``dark`` is subtracted from the reading
    (and from ``reference``) first. Never raises for a spectrum it cannot read a thickness
    from: the result then has ``ok = False`` and the reasons.

    References
    ----------
    Golub & Pereyra (1973), variable projection; Born & Wolf, sec. 7.6.1.

    Examples
    --------
    A reading made from the closed-form reflectance of a 1200 nm film of index 1.33 in air
    (normal incidence) under a smooth lamp:

    >>> import numpy as np
    >>> import bubblefit as bf
    >>> from bubblefit.inverse.spectrum import SpectrumOptions
    >>> from bubblefit.io.spectra import Spectrum
    >>> wl = np.linspace(450.0, 800.0, 700)
    >>> r2 = ((1.33 - 1.0) / (1.33 + 1.0)) ** 2
    >>> cos = np.cos(4 * np.pi * 1.33 * 1200.0 / wl)
    >>> film = 2 * r2 * (1 - cos) / (1 + r2 ** 2 - 2 * r2 * cos)
    >>> lamp = np.exp(-(((wl - 600.0) / 250.0) ** 2))
    >>> fit = bf.fit_spectrum(Spectrum(wl, lamp * film), options=SpectrumOptions(n_film=1.33))
    >>> fit.ok, round(fit.thickness_nm, 1)
    (True, 1200.0)
    """
    options, why = resolve_normalised(spectrum, dark, reference, options)
    p = prepared_problem(spectrum, dark, reference, options)
    lam, y, ref, n, prob, grid, warnings = p.wavelength_nm, p.y, p.reference, p.n, p.problem, p.grid, p.warnings
    terms = prob.basis.shape[1]
    weight = prob.weight
    alt = _split_problem(prob, lam, ref, terms, p.background_terms)
    step = grid[1] - grid[0]
    prob, alt, rss, alt_rss, minima, d_best, rss_best, w, fit_w = _search(prob, alt, grid, lam, n, options, warnings)
    dof = max(len(y) - (prob.n_linear + 1 + int(fit_w)), 1)
    fitted = prob.model(d_best, w)
    resid = y - fitted
    rho = residual_correlation(resid * weight)
    s2 = rss_best / dof * (1.0 + rho) / (1.0 - rho)
    var = profile_variance(prob, d_best, w, step, fit_w=fit_w)
    stat = float(np.sqrt(2.0 * s2 * var)) if np.isfinite(var) and var > 0 else float("inf")
    # The lamp's model is a choice: the thickness's largest change when it gets one or two
    # more terms (one, a tilt such as a lamp's drift, over a measured reference) is a
    # systematic error, added in quadrature.
    extra = (1,) if ref is not None else (1, 2)
    order, fringes = interference_order(d_best, lam, n)
    lamp_sys = max(abs(refine_near(replace(prob, basis=_lamp_basis(lam, terms + k, ref)),
                                    d_best, w, 3.0 * step, grid) - d_best) for k in extra)
    stderr = float(np.hypot(stat, lamp_sys))
    second, dchi2 = second_minimum(minima, d_best, step, s2)
    candidates = profile_candidates([(d_best, rss_best), *minima], step, s2)
    noise = second_difference_noise(y)
    red = float(rss_best / dof / noise**2) if noise > 0 else float("nan")
    reasons = _verdict(d_best, stderr, second, dchi2, grid, lam, n, reference is not None, options)
    if reference is None and fringes < min_fringes(terms):
        reasons.append(f"only {fringes:.2f} fringe across the range (fewer than {min_fringes(terms):.2g} with a "
                       f"{terms}-term lamp): without --reference the film cannot be told apart from the unknown "
                       "lamp's smooth spectrum")
    split = _lamp_split(alt, alt_rss, lam, n, ref, options, grid, w, d_best, rss_best, s2)
    if split is not None:
        reasons.append(split)
    _misfit(rss_best / dof, noise, float(np.mean(np.abs(y))), reasons, warnings)
    if fit_w and w >= 0.999 * options.max_resolution_nm:
        # The fringes are washed out more than a spectrometer of that resolution washes them:
        # something the model lacks does it (a thickness varying over the spot washes them as
        # 1 / lambda, a resolution as 1 / lambda^2), and the fit trades the phase for the contrast.
        reasons.append(f"the fringes are washed out beyond what a resolution of {options.max_resolution_nm:g} nm "
                       "explains (the thickness varies over the spot?): their contrast is not the model's, and "
                       "neither may their phase be")
    if rho > 0.5:
        warnings.append(f"residuals are correlated (lag-1 {rho:.2f}): the error bar counts "
                        f"{(1 - rho) / (1 + rho):.2f} independent samples per point")
    profile = (rss - rss_best) / s2
    scale = float(np.mean(np.abs(y))) or 1.0
    phase, count = extrema_verdict(lam, y, d_best, options.n_film, reasons)
    return SpectrumFit(
        thickness_nm=float(d_best), thickness_nm_stderr=stderr, stderr_statistical_nm=stat,
        stderr_lamp_nm=float(lamp_sys), ok=not reasons, order=order, fringes=fringes,
        resolution_nm=float(w), reduced_chi2=red, residual_rms=float(np.sqrt(np.mean(resid**2)) / scale),
        n_film=float(np.interp(0.5 * (lam.min() + lam.max()), lam, n)), second_minimum_nm=second,
        delta_chi2=dchi2, reasons=reasons, warnings=warnings, wavelength_nm=lam, measured=y, fitted=fitted,
        profile_nm=grid, profile_chi2=profile, normalised=bool(options.normalised), normalised_why=why,
        extrema_phase=phase, extrema=count, candidates=candidates)


def extrema_verdict(lam: np.ndarray, y: np.ndarray, d: float, n_film, reasons: list[str]) -> tuple[float, int]:
    """The extrema phase of thickness ``d`` on the reading ``y`` and its number of clear
    extrema (:mod:`._spectrum_extrema`), appending to ``reasons`` when the thickness
    misplaces them: the rms phase above :data:`EXTREMA_PHASE_LIMIT` with at least
    :data:`EXTREMA_FOR_VERDICT` extrema, or, with fewer (a film of order 0 to 2, whose
    extrema the rms cannot judge), one clear minimum (a zero of ``R``, which no lamp moves)
    further than :data:`MINIMUM_PHASE_LIMIT` from an even ``4 n d / lambda``. The limit is
    in ``x``, where a minimum's error in wavelength counts ``x`` times over: a test of each
    minimum is tight for the few fringes of a thin film and would not hold for a thick one's
    many (the smoothing's shift of a minimum of a 10 um film's fine fringes is itself ~0.2).

    References
    ----------
    Born & Wolf, *Principles of Optics*, 7th ed., sec. 7.6.1 (extrema of the Airy reflectance).
    """
    def n_at(x):
        return dispersion.refractive_index(n_film, x)

    ext = fringe_extrema(lam, y)
    phase = extrema_phase(d, ext, n_at)
    if len(ext) >= EXTREMA_FOR_VERDICT:
        if phase > EXTREMA_PHASE_LIMIT:
            reasons.append(f"the thickness does not put the reading's {len(ext)} fringe extrema where they are "
                           f"(4 n d / lambda is {phase:.2f} rms from whole numbers there; {RANDOM_PHASE:.2f} for a "
                           "thickness unrelated to them)")
        return phase, int(len(ext))
    minima = fringe_minima(lam, y)
    off = minima_phase(d, minima, n_at)
    if np.isfinite(off) and off > MINIMUM_PHASE_LIMIT:
        reasons.append(f"the thickness does not put the reading's fringe minimum where it is: a film in air reflects "
                       f"nothing where 4 n d / lambda is even, whatever the lamp, and at the reading's minimum "
                       f"it is {off:.2f} from an even number (limit {MINIMUM_PHASE_LIMIT:g})")
    return phase, int(len(ext))


def resolve_normalised(spectrum: Spectrum, dark: Spectrum | None, reference: Spectrum | None,
                       options: SpectrumOptions) -> tuple[SpectrumOptions, str]:
    """``options`` with ``normalised`` decided, and the reason: as given when it is True or
    False; else False with a reference (a reading one divides by a reference is not divided
    yet), and otherwise from the reading's envelope
    (:func:`bubblefit.inverse._spectrum_defaults.looks_normalised`)."""
    if options.normalised is not None:
        return options, "as asked" if options.normalised else ""
    if reference is not None:
        return replace(options, normalised=False), "not divided: a reference reading was given"
    y = spectrum.intensity - (dark.on(spectrum.wavelength_nm, "dark") if dark is not None else 0.0)
    flat, why = looks_normalised(spectrum.wavelength_nm, y)
    return replace(options, normalised=bool(flat)), ("read as divided by its lamp: " if flat else
                                                     "read as not divided: ") + why


def _split_problem(prob: ProfileProblem, lam, ref, terms: int, bg_terms: int) -> ProfileProblem | None:
    """The model of :func:`_lamp_split`: ``prob`` with the same number of smooth terms,
    ``max(1, J - 2)`` of them in the lamp and the rest in the stray light; None when that is
    the model itself."""
    alt_terms = max(1, terms - 2)
    if alt_terms == terms:
        return None
    return replace(prob, basis=_lamp_basis(lam, alt_terms, ref),
                   background=_background_basis(lam, bg_terms + terms - alt_terms, ref))


def _lamp_split(alt: ProfileProblem | None, alt_rss, lam, n, ref, options: SpectrumOptions, grid, w: float,
                d_best: float, rss_best: float, s2: float) -> str | None:
    """The reason the order is not established when it depends on how the model's smooth
    freedom is split between the lamp (multiplying ``R``) and the stray light (added), or None.

    The reading only fixes ``L R + S``; a smooth ``L`` of many terms can take up part of a
    fringe of a thinner film, which a stiffer lamp with a freer stray light cannot. The
    global search is repeated (``alt_rss``, the grid profile of ``alt``) with the same
    number of smooth terms split otherwise (:func:`_split_problem`), so that the two
    ``chi^2 = RSS / s^2`` compare without a penalty for parameters; when its best thickness
    lies a quarter of an order or more away and its ``chi^2`` is within ``ambiguity_dchi2``
    of the best (or below it), the data do not choose between the two readings.
    """
    if alt is None:
        return None
    d_alt, rss_alt = refine_d(alt, grid, alt_rss, w, keep=2)[0]
    dchi2 = (rss_alt - rss_best) / s2
    if abs(d_alt - d_best) < 0.25 * _order_spacing(lam, n) or dchi2 >= options.ambiguity_dchi2:
        return None
    hint = "" if options.normalised or ref is not None else "; if the reading was divided by the lamp, use --normalised"
    return (f"interference order depends on the lamp model: a {alt.basis.shape[1]}-term lamp with "
            f"{alt.additive.shape[1] - int(alt.offset)} more stray-light term(s) puts the film at {d_alt:.1f} nm "
            f"(delta chi2 {dchi2:.2f} < {options.ambiguity_dchi2:g}){hint}")


def _search(prob: ProfileProblem, alt: ProfileProblem | None, grid, lam, n, options: SpectrumOptions,
            warnings: list[str]):
    """Global search and local refinement: the grid profile (and that of ``alt``, computed
    with it, or None), its refined minima (best first), the best thickness and RSS, the
    resolution, and whether it was fitted."""
    step = grid[1] - grid[0]
    levels = INCOHERENT_LEVELS if options.incoherent else (0.0,)
    profiles = rss_grids([prob] if alt is None else [prob, alt], grid, 0.0, levels)
    k = _incoherent_level(prob, profiles[0], grid, levels, options.ambiguity_dchi2)
    prob, rss = replace(prob, incoherent=levels[k]), profiles[0, k]
    alt_rss = None
    if alt is not None:  # the same non-interfering light: it belongs to the optics, not to the lamp's model
        alt, alt_rss = replace(alt, incoherent=levels[k]), profiles[1, k]
    d0 = refine_d(prob, grid, rss, 0.0)[0][0]
    w = 0.0
    fit_w = options.fit_resolution and _resolution_matters(d0, lam, n, options.max_resolution_nm)
    if fit_w:
        d0, w = refine_dw(prob, d0, step, options.max_resolution_nm)
    # The resolution changes the fringes' contrast, not their phase: the grid's basins
    # (searched at w = 0) stand, and their minima are refined at the fitted w.
    minima = refine_d(prob, grid, rss, w)
    d_best, rss_best = minima[0]
    if fit_w and w > 0:
        d_best, w = refine_dw(prob, d_best, step, options.max_resolution_nm, w)
        rss_best = prob.rss(d_best, w)
    return prob, alt, rss, alt_rss, minima, d_best, rss_best, w, fit_w and w > 0


def _incoherent_level(prob: ProfileProblem, profiles: np.ndarray, grid, levels, dchi2: float) -> int:
    """The index of the non-interfering reflectance ``b`` of ``levels`` whose profile (the
    rows of ``profiles``, refined at their best minima, the lamp's sign free) reaches the lowest RSS, kept only
    when it lowers ``chi^2`` by more than ``dchi2`` below ``b = 0`` (``s^2 = RSS / dof`` of
    ``b = 0``): one more parameter is taken only when the reading asks for it (a
    likelihood-ratio test; the grid alone is too coarse to compare the levels)."""
    best = np.array([refine_d(replace(prob, incoherent=lev, positive=False), grid, row, 0.0, keep=1)[0][1]
                     for lev, row in zip(levels, profiles)])
    k = int(np.argmin(best))
    s2 = best[0] / max(len(prob.y) - prob.n_linear, 1)
    return k if s2 > 0 and (best[0] - best[k]) / s2 > dchi2 else 0


def _resolution_matters(d: float, lam: np.ndarray, n: np.ndarray, w_max: float) -> bool:
    """Whether a resolution of ``w_max`` nm would wash out more than a fifth of the film's
    bluest fringe (:func:`bubblefit.optics.film.fringe_attenuation`); if not, it cannot be
    measured from the spectrum and is left at 0."""
    i = int(np.argmin(lam))
    sigma = w_max / (_FWHM_PER_SIGMA * lam[i] ** 2)
    x = 2.0 * float(np.max(n)) * d
    return float(film.fringe_attenuation(x, sigma)) < 0.8


def _misfit(mean_square: float, noise: float, level: float, reasons: list[str], warnings: list[str],
            what: str = "the reading's noise") -> None:
    """Not ok when the residual exceeds ``MISFIT_RATIO`` times the noise plus the model-error
    floor; a warning when it exceeds twice the noise alone. ``what`` names ``noise`` in the
    messages (a reading read with its series' lamp is judged by its noise and that lamp's spread)."""
    red = mean_square / noise**2 if noise > 0 else float("nan")
    if mean_square > MISFIT_RATIO**2 * (noise**2 + (MODEL_ERROR_FLOOR * level) ** 2):
        reasons.append(f"the model does not explain the spectrum: the residual is {np.sqrt(red):.1f} times "
                       f"{what} (check the index, the range, the reference, or --lamp-terms)")
    elif np.isfinite(red) and red > 4.0:
        warnings.append(f"the residual is {np.sqrt(red):.1f} times {what}: the model leaves "
                        "structure (lamp, reference or index?); the error bar is widened for it")


def _verdict(d, stderr, second, dchi2, grid, lam, n, has_reference: bool, opts: SpectrumOptions) -> list[str]:
    """Reasons the thickness cannot be trusted (empty when it can)."""
    reasons = []
    step = grid[1] - grid[0]
    if not np.isfinite(stderr) or stderr > 0.25 * _order_spacing(lam, n) or stderr > 0.3 * max(d, 1e-9):
        hint = "" if has_reference else " (a film without fringes needs --reference to fix its brightness)"
        reasons.append(f"the spectrum does not constrain the thickness (stderr {stderr:.3g} nm){hint}")
    if dchi2 < opts.ambiguity_dchi2:
        reasons.append(f"interference order ambiguous: a second minimum at {second:.1f} nm is within the noise "
                       f"(delta chi2 {dchi2:.2f} < {opts.ambiguity_dchi2:g})")
    lo, hi = opts.thickness_range
    if (lo > 0 and d - lo < 1.5 * step) or hi - d < 1.5 * step:
        reasons.append(f"thickness {d:.1f} nm is at the edge of the searched range {lo:g}-{hi:g} nm")
    return reasons

