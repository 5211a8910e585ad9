"""Spectral integration of film reflectance to linear sRGB (sec. 3.4 of the paper).

A reflectance spectrum ``S(lambda)`` seen under an illuminant ``I(lambda)`` by a response
``rho_c(lambda)`` gives the channel values ``c = sum_k rho_c(lambda_k) I(lambda_k)
S(lambda_k) dlambda``. The response is

- ``"srgb"`` (default): the CIE 1931 2-degree observer followed by the XYZ to linear
  sRGB (Rec. 709) matrix of IEC 61966-2-1, so ``rho = M cmf``;
- a camera of ``colour.MSDS_CAMERA_SENSITIVITIES`` (measured raw sensitivities, e.g.
  ``"Nikon 5100 (NPL)"``), zero outside their measured range;
- a CSV file ``wavelength_nm,r,g,b``.

The illuminant is ``"D65"`` (default), ``"E"``, ``"A"`` (or any of colour-science's
``SDS_ILLUMINANTS``) or a CSV file ``wavelength_nm,power``. The observer, D65 and A are
read from tables shipped in ``bubblefit/data`` (written from colour-science's datasets by
``experiments/colour_tables.py``), so the default colour path does not import
colour-science (about a second per process); other names import it when asked for. White balance
``"illuminant"`` normalises each channel so that a spectrally flat reflectance ``c``
gives ``(c, c, c)`` (``docs/design.md``); explicit gains ``(g_r, g_g, g_b)`` multiply raw
channels normalised so that the green channel of a white reflector reads 1 (a camera's
as-shot multipliers). The resulting RGB factor multiplies the RGB radiance of the
environment per channel.

A :class:`SpectralBasis` holds the K sample wavelengths and the (K, 3) weights of this
quadrature, so integration is one matrix product: ``rgb = S @ weights``.

Methods:
    ``uniform``: K samples at the midpoints of K equal bins over 380-780 nm (the
        paper used K = 10, 30, 100; few samples band on thick films).
    ``reference``: uniform with 0.5 nm bins (800 samples), the converged reference for
        films up to ~20 um.
    ``fourier``: K Gaussian lobes in wavenumber (after Belcour & Barla, "A Practical
        Extension to Microfacet Theory for the Modeling of Varying Iridescence", ACM TOG
        36(4), 2017, sec. 4): the observer x illuminant of each sRGB channel is
        approximated by ``sum_k W_kc G_k(nu)``, ``G_k`` a unit-area Gaussian of mean
        ``1/lambda_k`` and standard deviation ``sigma_k`` (1/nm). Each sample then stands
        for the spectrum *filtered* by ``G_k``, and a fringe ``cos(2 pi m x nu)`` of optical
        path ``x`` filters in closed form to ``cos(2 pi m x / lambda_k)
        exp(-2 pi^2 sigma_k^2 m^2 x^2)`` (:func:`bubblefit.optics.film.fringe_attenuation`). Thick
        films therefore fade smoothly to the incoherent mean instead of aliasing, with
        K = 5-8 samples. The lobes' centres and widths were fitted once (least squares in
        wavenumber, D65, table :data:`FOURIER_LOBES`); the weights are solved for the
        illuminant when the basis is built.
    ``harmonic``: K samples in the *phase* of eq. (8), not in wavelength. A film of
        constant thickness and non-dispersive index depends on the wavelength only through
        ``theta = 2 pi x / lambda`` (``x`` the optical path, :func:`bubblefit.optics.film.optical_path`),
        and every term of the model (``R``, ``T T``, ``T R^k T``, eq. (10)'s factor) is an
        even ``2 pi``-periodic function ``g(theta) = sum_m c_m cos(m theta)``. So a channel
        is ``sum_m eps_m c_m A_c(m x)`` with ``A_c(xi) = sum_k W_kc cos(2 pi xi / lambda_k)``
        the cosine transform of the reference quadrature's weights: exact for any
        thickness, however many fringes the visible holds. The film functions are
        evaluated at ``theta_j = 2 pi (j + 1/2) / K``, whose discrete Fourier transform
        gives ``c_m`` for ``m < K/2``, and the weights of those samples depend on the
        pixel's ``x`` (:func:`harmonic_weights`, from a table of ``A`` up to
        :data:`HARMONIC_REACH_NM`, beyond which ``|A| < 3e-4``). Eq. (10)'s factor has two
        harmonics, so ``K = 4`` integrates the ``paper`` model exactly; the Airy sum's
        harmonics fall as ``R1^m``, so grazing pixels need more. Not for a thickness
        field (each film has its own ``x``) nor a dispersive index.
"""

from __future__ import annotations

import functools
import os
from typing import Literal, get_args

import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "illuminant_spectrum",
    "response_functions",
    "response_stderr",
    "response_error_modes",
    "is_named_illuminant",
    "is_named_response",
    "LAMBDA_MIN",
    "LAMBDA_MAX",
    "TABLE_GRID",
    "channel_density",
    "SpectralBasis",
    "spectral_basis",
    "integrate",
    "REFERENCE_SAMPLES",
    "FOURIER_LOBES",
    "harmonic_weights",
    "HARMONIC_REACH_NM",
    "SpectralMethod",
    "SPECTRAL_METHODS",
]

#: The spectral integration methods (see the module docstring).
SpectralMethod = Literal["uniform", "reference", "fourier", "harmonic"]
SPECTRAL_METHODS: tuple[str, ...] = get_args(SpectralMethod)

LAMBDA_MIN = 380.0
LAMBDA_MAX = 780.0
REFERENCE_SAMPLES = 800


#: The colour-matching and response tables' grid: 1 nm over 360-830 nm.
TABLE_GRID = np.arange(360.0, 831.0, 1.0)

#: XYZ to linear sRGB, the matrix as IEC 61966-2-1:1999 prints it (colour-science's too).
XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986],
                        [-0.9689, 1.8758, 0.0415],
                        [0.0557, -0.2040, 1.0570]])

_DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")
#: The illuminants shipped in ``bubblefit/data/cie_illuminants.csv`` (besides ``E``).
_SHIPPED_ILLUMINANTS = ("D65", "A")


@functools.lru_cache(maxsize=2)
def _shipped_table(name: str) -> tuple[tuple[str, ...], np.ndarray]:
    """(column names, (rows, columns) values) of a CSV table in ``bubblefit/data``."""
    with open(os.path.join(_DATA, name), encoding="utf-8") as fh:
        header, *rows = [ln for ln in fh.read().splitlines() if ln and not ln.startswith("#")]
    return tuple(header.split(",")), np.array([[float(x) for x in r.split(",")] for r in rows])


def read_number_rows(path: str, columns: int, what: str) -> np.ndarray:
    """Rows of ``columns`` finite numbers from a text table (comma, semicolon or whitespace
    separated; ``#`` comments and header lines before the first row skipped), (rows, columns).

    Raises
    ------
    InputError
        The file cannot be read as text, or a row after the first has too few numbers.
    """
    from ..errors import InputError

    rows = []
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{what} {path}: cannot read it as text ({exc})") from None
    for no, line in enumerate(lines, start=1):
        parts = [x for x in line.replace(",", " ").replace(";", " ").split() if x]
        if not parts or parts[0].startswith("#"):
            continue
        try:
            vals = [float(x) for x in parts[:columns]]
        except ValueError:
            if rows:
                raise InputError(f"{what} {path}, line {no}: expected {columns} numbers") from None
            continue  # a header
        if len(vals) < columns or not np.all(np.isfinite(vals)):
            raise InputError(f"{what} {path}, line {no}: expected {columns} finite numbers")
        rows.append(vals)
    return np.asarray(rows, dtype=np.float64).reshape(-1, columns)


def _read_columns(path: str, columns: int, what: str, signed: tuple = ()) -> np.ndarray:
    """A CSV (comma or whitespace) of ``columns`` numbers per row, header lines skipped; the
    value columns ``signed`` (indices) may be negative, the others must be >= 0."""
    from ..errors import InputError

    data = read_number_rows(path, columns, what)
    if len(data) < 2 or np.any(np.diff(np.sort(data[:, 0])) <= 0):
        raise InputError(f"{what} {path}: need at least 2 rows with distinct wavelengths (nm) in the first column")
    unsigned = np.ones(columns, bool)
    unsigned[[0, *signed]] = False
    if data[:, 0].max() < LAMBDA_MIN or data[:, 0].min() > LAMBDA_MAX or np.any(data[:, unsigned] < 0):
        raise InputError(f"{what} {path}: wavelengths must overlap 380-780 nm and values must be >= 0")
    return data[np.argsort(data[:, 0])]


def colour_temperature(name: str) -> float | None:
    """The temperature in kelvin of an illuminant named ``"3200K"`` (a black body), else None."""
    text = name.strip()
    if len(text) < 2 or text[-1] not in "kK":
        return None
    try:
        kelvin = float(text[:-1])
    except ValueError:
        return None
    if not 500.0 <= kelvin <= 50000.0:
        from ..errors import InputError

        raise InputError(f"colour temperature {name!r} must lie within 500-50000 K")
    return kelvin


def planck_spectrum(wavelength_nm, kelvin: float) -> np.ndarray:
    """Planck's law, the spectral radiance of a black body at ``kelvin``, relative (its value at 560 nm is 1).

    ``L(lambda) ~ lambda^-5 / (exp(c2 / (lambda T)) - 1)`` with the second radiation
    constant ``c2 = h c / k = 1.438777e7 nm K`` (CODATA 2018). A tungsten-halogen lamp is
    close to a black body at its colour temperature (about 2800-3400 K).

    References
    ----------
    CIE 015:2018 *Colorimetry*, sec. 11 (Planckian radiator); CODATA 2018 for ``c2``.
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    c2 = 1.438777e7

    def radiance(x):
        return x ** -5.0 / np.expm1(c2 / (x * kelvin))

    return radiance(lam) / radiance(560.0)


@functools.lru_cache(maxsize=16)
def illuminant_spectrum(illuminant: str) -> np.ndarray:
    """Relative spectral power of an illuminant on the 1 nm grid 360-830 nm (``TABLE_GRID``).

    ``"E"`` is equal energy; ``"3200K"`` a black body (:func:`planck_spectrum`); other names are colour-science's ``SDS_ILLUMINANTS`` (CIE D65,
    A, ...); anything else is read as a CSV ``wavelength_nm,power`` (zero outside it).
    """
    from ..errors import InputError

    if illuminant.upper() in ("E", "EQUAL", "EQUAL_ENERGY"):
        return np.ones_like(TABLE_GRID)
    kelvin = colour_temperature(illuminant)
    if kelvin is not None:
        return planck_spectrum(TABLE_GRID, kelvin)
    if illuminant in _SHIPPED_ILLUMINANTS:
        names, table = _shipped_table("cie_illuminants.csv")
        return np.interp(TABLE_GRID, table[:, 0], table[:, names.index(illuminant)])
    if not os.path.isfile(illuminant) and _colour_has("SDS_ILLUMINANTS", illuminant):
        import colour

        sd = colour.SDS_ILLUMINANTS[illuminant]
        return np.interp(TABLE_GRID, np.asarray(sd.wavelengths), np.asarray(sd.values))
    if not os.path.isfile(illuminant):
        raise InputError(f"unknown illuminant {illuminant!r} (D65, E, A, another CIE name, or a CSV "
                         "wavelength_nm,power)")
    data = _read_columns(illuminant, 2, "illuminant")
    return _cell_means(data[:, 0], data[:, 1], TABLE_GRID)


def _cell_means(x: np.ndarray, y: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The mean over each cell ``[g - h/2, g + h/2]`` of the uniform ``grid`` (step ``h``) of
    the piecewise-linear curve through ``(x, y)`` (zero outside ``[x[0], x[-1]]``), integrated
    exactly (the trapezoid rule is exact on a piecewise-linear curve whose knots include the
    cells' edges).

    A lamp's spectrum is weighted by ``integral rho(lambda) I(lambda) dlambda``; on a 1 nm
    grid each sample must carry the power of its nanometre. A spectrometer's CSV sampled
    finer than the grid (a sodium or mercury line 0.1 nm wide) keeps each line's power this
    way; sampled at the grid's points it would keep only what falls on them (a line between
    two of them is lost). On a CSV sampled at the grid's points or more coarsely the mean
    differs from the point value only by the curve's bend within a cell.
    """
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    grid = np.asarray(grid, np.float64)
    h = float(grid[1] - grid[0])
    edges = np.append(grid - 0.5 * h, grid[-1] + 0.5 * h)
    pts = np.union1d(x, edges)
    vals = np.interp(pts, x, y, left=0.0, right=0.0)
    inside = (pts[:-1] >= x[0]) & (pts[1:] <= x[-1])
    area = np.concatenate([[0.0], np.cumsum(np.where(inside, 0.5 * (vals[1:] + vals[:-1]) * np.diff(pts), 0.0))])
    return np.diff(area[np.searchsorted(pts, edges)]) / h


@functools.lru_cache(maxsize=16)
def response_functions(response: str) -> np.ndarray:
    """(L, 3) channel responses on ``TABLE_GRID``: ``srgb``, a colour-science camera, or a CSV.

    References
    ----------
    CIE 015:2018 (1931 2-degree observer); IEC 61966-2-1:1999 (sRGB primaries);
    colour-science's ``MSDS_CAMERA_SENSITIVITIES`` (measured camera sensitivities).
    """
    from ..errors import InputError

    if response.lower() == "srgb":
        _, table = _shipped_table("cie_1931_2deg.csv")
        cmf = np.stack([np.interp(TABLE_GRID, table[:, 0], table[:, c]) for c in (1, 2, 3)], axis=1)
        return cmf @ XYZ_TO_SRGB.T
    if not os.path.isfile(response) and _colour_has("MSDS_CAMERA_SENSITIVITIES", response):
        import colour

        msds = colour.MSDS_CAMERA_SENSITIVITIES[response]
        lam, vals = np.asarray(msds.wavelengths), np.asarray(msds.values)
        return np.stack([np.interp(TABLE_GRID, lam, vals[:, c], left=0.0, right=0.0) for c in range(3)], axis=1)
    if not os.path.isfile(response):
        import colour

        raise InputError(f"unknown camera response {response!r} (srgb, one of "
                         f"{', '.join(colour.MSDS_CAMERA_SENSITIVITIES)}, or a CSV wavelength_nm,r,g,b)")
    data = _read_columns(response, 4, "camera response", signed=_RESPONSE_COLUMNS)
    return np.stack([np.interp(TABLE_GRID, data[:, 0], data[:, c], left=0.0, right=0.0) for c in (1, 2, 3)], axis=1)


#: A response CSV's value columns that may be negative: a response may have negative lobes
#: (sRGB's own have; a calibrated response may ring about a steep filter edge, and clipping
#: the ring would bias every colour it integrates and leave the stated errors behind).
_RESPONSE_COLUMNS = (1, 2, 3)


def response_stderr(response: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(wavelengths (L,), standard errors (L, 3))`` of a response CSV that states them
    (``wavelength_nm,r,g,b,r_err,g_err,b_err``, as ``bubblefit calibrate-camera`` writes:
    :meth:`bubblefit.capture.camera_calibration.CameraCalibration.csv_text`), on the CSV's
    own rows, which :func:`response_functions` interpolates linearly between; None for a
    named response or a CSV without the error columns (the response is then taken as
    exact)."""
    modes = response_error_modes(response)
    if modes is None:
        return None
    rows, factor = modes
    return rows, np.sqrt(np.sum(factor**2, axis=-1))


def response_error_modes(response: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(wavelengths (L,), modes (L, 3, M))`` of a response CSV's stated errors: each
    channel's covariance between the rows is ``sum_m u_m u_m^T`` over its modes ``u_m``.

    A CSV of ``bubblefit calibrate-camera`` holds the modes after the row errors, in
    columns ``m1_r,m1_g,m1_b,m2_r,...`` (the eigenvectors of each channel's posterior
    covariance scaled by the square roots of their eigenvalues); a CSV with the error
    columns only states independent rows (``M = L``, one mode per row). None for a named
    response or a CSV without errors."""
    if not os.path.isfile(response):
        return None
    with open(response, encoding="utf-8", errors="replace") as fh:
        head = [line for line in (fh.readline() for _ in range(3)) if line.strip()]
    header = next((line for line in head if "r_err" in line), None)
    if header is None:
        return None
    names = [x for x in header.replace(",", " ").replace(";", " ").split() if x]
    n_modes = sum(1 for x in names if x.startswith("m") and x.endswith("_r"))
    columns = 7 + 3 * n_modes
    data = _read_columns(response, columns, "camera response", signed=_RESPONSE_COLUMNS + tuple(range(7, columns)))
    if n_modes == 0:
        err = data[:, 4:7]
        return data[:, 0], np.stack([np.diag(err[:, c]) for c in range(3)], axis=1)
    return data[:, 0], data[:, 7:].reshape(len(data), n_modes, 3).transpose(0, 2, 1)


#: The comment a response CSV of ``bubblefit calibrate-camera`` opens with names the lamp it
#: was fitted under after this (:meth:`bubblefit.capture.camera_calibration.CameraCalibration.csv_text`).
CALIBRATED_UNDER = "; illuminant "
_LAMP_INCLUDED = " (the response includes the lamp)"


def response_illuminant(response: str) -> str | None:
    """The illuminant a calibrated response CSV was fitted under, from its first comment
    line (``E``: the CSV is the camera-times-lamp product), else None (a named camera, or
    a CSV that does not say)."""
    if not os.path.isfile(response):
        return None
    with open(response, encoding="utf-8", errors="replace") as fh:
        first = fh.readline().strip()
    if not first.startswith("#") or "calibrate-camera" not in first or CALIBRATED_UNDER not in first:
        return None
    name = first.rsplit(CALIBRATED_UNDER, 1)[1]
    name = name[:-len(_LAMP_INCLUDED)] if name.endswith(_LAMP_INCLUDED) else name
    return name.strip() or None


def _colour_has(dataset: str, name: str) -> bool:
    """Whether colour-science's ``dataset`` (e.g. ``SDS_ILLUMINANTS``) holds ``name``; imports
    colour-science, so it is asked only for names bubblefit does not ship."""
    import colour

    return name in getattr(colour, dataset)


def is_named_illuminant(name: str) -> bool:
    """Whether ``name`` is a built-in illuminant (``E`` or colour-science's), not a file."""
    return (name.upper() in ("E", "EQUAL", "EQUAL_ENERGY") or name in _SHIPPED_ILLUMINANTS
            or colour_temperature(name) is not None or _colour_has("SDS_ILLUMINANTS", name))


def is_named_response(name: str) -> bool:
    """Whether ``name`` is a built-in response (``srgb`` or a colour-science camera), not a file."""
    return name.lower() == "srgb" or _colour_has("MSDS_CAMERA_SENSITIVITIES", name)


def channel_density(illuminant: str, response: str) -> np.ndarray:
    """(L, 3) ``rho_c(lambda) I(lambda)`` on ``TABLE_GRID``, zero outside 380-780 nm."""
    inside = ((TABLE_GRID >= LAMBDA_MIN) & (TABLE_GRID <= LAMBDA_MAX))[:, None]
    dens = response_functions(response) * illuminant_spectrum(illuminant)[:, None] * inside
    dark = [name for name, total in zip(("red", "green", "blue"), dens.sum(axis=0)) if total <= 0]
    if dark:
        from ..errors import InputError

        raise InputError(f"camera response {response!r} under illuminant {illuminant!r} leaves the "
                         f"{' and '.join(dark)} channel{'s' if len(dark) > 1 else ''} without light: interference "
                         "colours need a lamp that every channel sees (a narrow-band lamp such as sodium or a laser "
                         "does not; docs/films.md)")
    return dens


def _balance(raw_white: np.ndarray, white_balance) -> np.ndarray:
    """Per-channel factors applied to weights whose flat-spectrum sum is ``raw_white`` (3,)."""
    if isinstance(white_balance, str):
        if white_balance != "illuminant":
            raise ValueError(f"white_balance must be 'illuminant' or three gains, got {white_balance!r}")
        return 1.0 / raw_white
    return np.asarray(white_balance, dtype=np.float64) / raw_white[1]


#: ``fourier`` lobes per sample count K: (centre wavelengths in nm, standard deviations in
#: wavenumber, 1/um), from a least-squares fit of K shared Gaussians in wavenumber to the
#: three sRGB weight densities under D65 (the script that made them is in
#: ``experiments/accuracy_vs_time.py --fit-lobes``).
FOURIER_LOBES: dict = {
    3: ((598.161, 553.392, 453.353),
        (0.09174, 0.1414, 0.10651)),
    5: ((652.043, 607.004, 550.692, 549.625, 452.752),
        (0.06308, 0.10527, 0.19089, 0.11237, 0.10395)),
    6: ((652.724, 606.97, 550.026, 536.493, 452.471, 452.379),
        (0.06416, 0.1071, 0.11829, 0.23356, 0.10559, 0.1061)),
    7: ((707.149, 603.028, 577.197, 550.492, 446.779, 427.019, 426.746),
        (0.07495, 0.10388, 0.16481, 0.12047, 0.11618, 0.09231, 0.09164)),
    8: ((611.779, 578.367, 577.361, 521.856, 485.572, 467.462, 463.037, 415.358),
        (0.05999, 0.10556, 0.10625, 0.06325, 0.07527, 0.1443, 0.14133, 0.07374)),
    10: ((659.362, 612.152, 603.063, 555.974, 522.397, 477.304, 460.575, 439.574, 434.821, 423.598),
        (0.05217, 0.02735, 0.08466, 0.09968, 0.06606, 0.12243, 0.06686, 0.05624, 0.08929, 0.02244)),
    12: ((641.324, 631.771, 611.634, 594.063, 562.123, 525.734, 479.539, 464.063, 443.673, 420.59, 419.634, 419.381),
        (0.05752, 0.03911, 0.03377, 0.06056, 0.09178, 0.07284, 0.10348, 0.05919, 0.0934, 0.03991, 0.03058, 0.02849)),
    16: ((662.057, 641.78, 605.949, 601.421, 596.308, 575.56, 547.331, 522.971, 486.184, 479.577, 462.785, 442.511, 417.514, 417.46, 410.854, 407.859),
        (0.02002, 0.02001, 0.07758, 0.05011, 0.03548, 0.06732, 0.07389, 0.07321, 0.07113, 0.02639, 0.05317, 0.05918, 0.05171, 0.05178, 0.02625, 0.04523)),
}


def _fourier_arrays(samples: int, illuminant: str, response: str):
    """Centres (K,) nm, weights (K, 3) (flat spectrum -> 1) and wavenumber deviations (K,) 1/nm."""
    if samples not in FOURIER_LOBES:
        raise ValueError(f"fourier spectral samples must be one of {sorted(FOURIER_LOBES)}, got {samples}")
    lam_k = np.asarray(FOURIER_LOBES[samples][0], dtype=np.float64)
    sig_k = np.asarray(FOURIER_LOBES[samples][1], dtype=np.float64) * 1e-3
    nu, dens = _wavenumber_density(illuminant, response)
    mu = 1.0 / lam_k
    g = np.exp(-0.5 * ((nu[:, None] - mu) / sig_k) ** 2) / (np.sqrt(2 * np.pi) * sig_k)
    w, *_ = np.linalg.lstsq(g, dens, rcond=None)
    w /= w.sum(axis=0, keepdims=True)  # flat spectrum -> (1, 1, 1)
    return lam_k, w, sig_k


def _wavenumber_density(illuminant: str, response: str = "srgb", points: int = 600):
    """The three channels' weight densities per unit wavenumber (each of unit integral), (P, 3),
    on a grid ``nu`` (P,) in 1/nm spanning the visible range with a margin of zeros."""
    dens_tab = channel_density(illuminant, response)
    lo, hi = 1.0 / LAMBDA_MAX, 1.0 / LAMBDA_MIN
    nu = np.linspace(lo - 2e-4, hi + 2e-4, points)
    lam = 1.0 / nu
    dens = np.stack([np.interp(lam, TABLE_GRID, dens_tab[:, c], left=0.0, right=0.0) for c in range(3)], axis=1)
    dens = dens * lam[:, None] ** 2
    return nu, dens / (dens.sum(axis=0, keepdims=True) * (nu[1] - nu[0]))


#: Largest ``xi`` (nm) of the ``harmonic`` basis' table of ``A_c(xi)``, and its step: the
#: envelope of ``A`` varies over ``1 / (1/380 - 1/780) / 2 ~ 1500 nm``, so linear
#: interpolation at 10 nm is within 2e-4 of it.
HARMONIC_REACH_NM = 64000.0
_HARMONIC_STEP_NM = 10.0


@functools.lru_cache(maxsize=16)
def _harmonic_table(illuminant: str, response: str, white_balance) -> tuple[float, np.ndarray]:
    """``(nu_c, E)``: the reference quadrature's characteristic function
    ``sum_k W_kc exp(2 pi i xi / lambda_k) = exp(2 pi i xi nu_c) E_c(xi)`` as a slowly varying
    envelope ``E`` (G, 6: real parts, then imaginary parts of the 3 channels) on
    ``xi = 0, step, ..., HARMONIC_REACH_NM``, about the band's central wavenumber ``nu_c``."""
    lam, w, _, _ = _basis_arrays("reference", REFERENCE_SAMPLES, illuminant, response, white_balance)
    nu = 1.0 / lam
    nu_c = 0.5 * (nu.min() + nu.max())
    rows = int(round(HARMONIC_REACH_NM / _HARMONIC_STEP_NM)) + 1
    # xi = (64 q + r) step: exp(2 pi i xi dnu) = exp(2 pi i 64 q step dnu) exp(2 pi i r step dnu),
    # so the (rows, K) exponentials become two small tables and one matrix product.
    q, r = np.arange(-(-rows // 64)), np.arange(64)
    coarse = np.exp(2j * np.pi * np.outer(64 * q * _HARMONIC_STEP_NM, nu - nu_c))  # (Q, K)
    fine = np.exp(2j * np.pi * np.outer(r * _HARMONIC_STEP_NM, nu - nu_c))  # (64, K)
    env = np.einsum("qk,rk,kc->qrc", coarse, fine, w, optimize=True).reshape(-1, 3)[:rows]
    return float(nu_c), np.concatenate([env.real, env.imag], axis=1)


def _harmonic_phases(samples: int) -> np.ndarray:
    """The phases ``delta_j = theta_j + pi`` of eq. (8) at ``theta_j = 2 pi (j + 1/2) / K``."""
    return 2.0 * np.pi * (np.arange(samples) + 0.5) / samples + np.pi


def harmonic_weights(opd, basis: "SpectralBasis"):
    """Per-pixel RGB weights (..., K, 3) of a ``harmonic`` basis' phase samples for optical
    paths ``opd`` (..., nm): ``K_j(x) = (1/K) (A(0) + 2 sum_{m=1}^{L} A(m x) cos(m theta_j))``,
    ``L = ceil(K/2) - 1`` (module docstring). ``sum_j g(theta_j) K_j(x)`` is then the channel
    value of any film function ``g`` whose harmonics above ``L`` vanish. Differentiable in
    ``opd`` and float32-safe (the carrier's phase is at most ``2 pi 170`` rad); numpy in,
    numpy out (``auto``'s grids), else jnp (the renderer)."""
    import jax.numpy as jnp

    xp = np if isinstance(opd, np.ndarray) else jnp
    nu_c, env = _harmonic_table(basis.illuminant, basis.response, basis.white_balance)
    k = basis.samples
    harm = np.arange(-(-k // 2))  # m = 0 .. L
    theta = 2.0 * np.pi * (np.arange(k) + 0.5) / k
    cmat = np.where(harm[:, None] == 0, 1.0, 2.0) * np.cos(harm[:, None] * theta[None, :]) / k  # (L + 1, K)
    x = xp.asarray(opd)
    dtype = x.dtype if xp.issubdtype(x.dtype, xp.floating) else xp.float32
    xi = x[..., None] * xp.asarray(harm, dtype=dtype)  # (..., L + 1)
    pos = xi / _HARMONIC_STEP_NM
    i0 = xp.clip(xp.floor(pos), 0, env.shape[0] - 2)
    frac = (pos - i0)[..., None]
    tab = xp.asarray(env, dtype=dtype)
    i0 = i0.astype(xp.int32)
    e = tab[i0] * (1.0 - frac) + tab[i0 + 1] * frac  # (..., L + 1, 6)
    e = xp.where((pos <= env.shape[0] - 1)[..., None], e, 0.0)
    arg = 2.0 * np.pi * nu_c * xi
    a = xp.cos(arg)[..., None] * e[..., :3] - xp.sin(arg)[..., None] * e[..., 3:]  # (..., L + 1, 3)
    return xp.einsum("...lc,lj->...jc", a, xp.asarray(cmat, dtype=dtype))


@functools.lru_cache(maxsize=64)
def _basis_arrays(method: str, samples: int, illuminant: str, response: str = "srgb",
                  white_balance="illuminant"):
    if method == "harmonic":
        if samples < 2:
            raise ValueError("harmonic spectral samples must be >= 2")
        return None, None, None, None
    fine = np.linspace(LAMBDA_MIN, LAMBDA_MAX, 4001)
    dens_tab = channel_density(illuminant, response)
    rgb_f = np.stack([np.interp(fine, TABLE_GRID, dens_tab[:, c]) for c in range(3)], axis=1)
    raw_white = rgb_f.sum(axis=0)
    gains = _balance(raw_white, white_balance) * raw_white  # 1 for "illuminant"
    if method == "fourier":
        lam_k, w, sig_k = _fourier_arrays(samples, illuminant, response)
        fwhm_nm = 2.3548 * sig_k * lam_k**2  # the lobe's width in wavelength, for display
        return lam_k, w * gains, fwhm_nm, sig_k
    if method == "reference":
        samples = REFERENCE_SAMPLES
    if method not in ("uniform", "reference"):
        raise ValueError(f"unknown spectral method {method!r} (uniform, reference, fourier or harmonic)")
    if samples < 1:
        raise ValueError("spectral samples must be >= 1")
    width = (LAMBDA_MAX - LAMBDA_MIN) / samples
    lam = LAMBDA_MIN + (np.arange(samples) + 0.5) * width
    # Each sample stands for its bin: the response x illuminant integrated over the bin
    # [lam - width/2, lam + width/2] exactly (:func:`_cell_means` of the table's
    # piecewise-linear curve), so the weights integrate the whole visible range for any K
    # and each weight is centred on its sample (the midpoint rule; a weight taken from
    # points of the bin's left side only stands for a wavelength short of the sample and
    # shifts every fringe's phase: 0.05 nm with 0.1 nm points, 1e-4 of a gap's scale)
    cells = np.append(lam, lam[-1] + width)  # one cell more: the step of a single bin
    w = np.stack([_cell_means(TABLE_GRID, dens_tab[:, c], cells)[:samples] for c in range(3)], axis=1)
    w /= w.sum(axis=0, keepdims=True)  # flat spectrum -> (1, 1, 1)
    return lam, w * gains, np.full(samples, width), None


class SpectralBasis:
    """Sample wavelengths (K,) in nm, RGB weights (K, 3) and bin widths (K,) in nm.

    ``sigma`` is None for point-sampled methods (``uniform``, ``reference``) and, for
    ``fourier``, the (K,) wavenumber standard deviations (1/nm) of the lobes each sample
    stands for: film functions must then return the lobe-filtered spectrum. A
    ``harmonic`` basis has no wavelengths, weights nor widths (None): its samples are the
    ``phases`` and its weights depend on each pixel's optical path (:func:`harmonic_weights`). ``illuminant``,
    ``response`` and ``white_balance`` are as in the module's description.

    Hashable and compared by its definition, so it can be a static argument under jit.
    """

    def __init__(self, method: SpectralMethod = "uniform", samples: int = 30, illuminant: str = "D65",
                 response: str = "srgb", white_balance="illuminant"):
        if not isinstance(white_balance, str):
            white_balance = tuple(float(g) for g in white_balance)
        lam, w, width, sigma = _basis_arrays(method, int(samples), illuminant, response, white_balance)
        self.method = method
        self.samples = int(samples) if lam is None else len(lam)
        #: ``harmonic``: the (K,) phases of eq. (8) its film functions are sampled at (else None).
        self.phases = _harmonic_phases(self.samples) if method == "harmonic" else None
        self.illuminant = illuminant
        self.response = response
        self.white_balance = white_balance
        self.wavelengths = lam
        self.weights = w
        self.bin_width = width
        self.sigma = sigma

    def _key(self):
        return (self.method, self.samples, self.illuminant, self.response, self.white_balance)

    def __hash__(self):
        return hash(self._key())

    def __eq__(self, other):
        return isinstance(other, SpectralBasis) and self._key() == other._key()

    def __repr__(self):
        return (f"SpectralBasis(method={self.method!r}, samples={self.samples}, illuminant={self.illuminant!r}, "
                f"response={self.response!r}, white_balance={self.white_balance!r})")

    def with_colour(self, illuminant: str, response: str = "srgb", white_balance="illuminant") -> "SpectralBasis":
        """The same quadrature (method, samples) for another illuminant, response or white balance."""
        samples = self.samples if self.method != "reference" else REFERENCE_SAMPLES
        return SpectralBasis(self.method, samples, illuminant, response, white_balance)


def spectral_basis(method: SpectralMethod = "uniform", samples: int = 30, illuminant: str = "D65", response: str = "srgb",
                   white_balance="illuminant") -> SpectralBasis:
    """The quadrature for ``method`` (``uniform``, ``reference``, ``fourier`` or ``harmonic``) with ``samples`` bins.

    Examples
    --------
    >>> import bubblefit as bf
    >>> basis = bf.spectral_basis("fourier", 8)     # the alias-free lobes fits use
    >>> basis.method, basis.wavelengths.shape
    ('fourier', (8,))
    """
    return SpectralBasis(method, samples, illuminant, response, white_balance)


def integrate(spectrum: Float[Array, "... K"], basis: SpectralBasis) -> Float[Array, "... 3"]:
    """Linear sRGB of a reflectance spectrum sampled at ``basis.wavelengths`` (``basis``: a
    :class:`SpectralBasis`, or anything whose ``weights`` (K, 3) are the RGB weights of the
    spectrum's K samples)."""
    import jax.numpy as jnp

    spectrum = jnp.asarray(spectrum)
    return spectrum @ jnp.asarray(basis.weights, dtype=spectrum.dtype)
