"""The camera-times-lamp spectral response, fitted from what the camera saw.

A channel's value of a surface or film of spectral reflectance ``S(lambda)`` under the
lamp ``I(lambda)`` is ``y_c = g_c int rho_c(lambda) I(lambda) S(lambda) dlambda``
(:mod:`bubblefit.optics.spectral`). Given samples whose spectra are known, the unknown
``rho_c`` enters linearly, so each channel is a linear inverse problem:

- **samples**: the 24 patches of an X-Rite ColorChecker photographed under the lamp (their
  reflectances are colour-science's ``SDS_COLOURCHECKERS["ColorChecker N Ohta"]``), and/or
  a film of known thicknesses (a wedge, a draining film read against a spectrometer, the
  black film and its first orders): its Airy reflectance at normal incidence
  (:func:`bubblefit.optics.film.airy_reflectance`). A film's colour against thickness is the
  cosine transform of ``rho_c I`` at the optical paths ``2 n d`` (the ``harmonic``
  quadrature of :mod:`bubblefit.optics.spectral`): exactly what a thickness from colour
  depends on, so films spanning the thicknesses to be measured calibrate best. A chart's
  smooth reflectances fix the response's broad shape only.
- **basis**: ``rho_c I`` piecewise linear on knots every :data:`KNOT_STEP_NM` nm over
  380-780 nm, smoothed by a penalty on its second differences (a discrete smoothing
  spline: Eilers & Marx, "Flexible smoothing with B-splines and penalties", Statistical
  Science 11(2), 1996). The channel's scale
  (exposure times white balance, ``g_c``) is free: the response is normalised to a
  maximum of 1 per channel.
- **smoothing weight and uncertainty**: the penalty is a Gaussian prior on the second
  differences; its weight is weighed by the samples' restricted (marginal) likelihood
  (Wood, JRSS B 73(1), 2011) and the result averaged over it, and the stated covariance is
  the posterior's, ``s^2 (A^T A + lambda D^T D)^-1`` (Wahba, JRSS B 45(1), 1983) averaged
  the same way plus the scatter of the solutions between weights, which holds the
  smoothing's bias where the samples do not fix the response: a chart's 24 smooth
  reflectances leave the fine structure a film's colours depend on to the prior, and the
  posterior says so. (Generalised cross-validation picks the weight on a chart
  erratically, from nearly none to heavy, and the frequentist covariance
  ``s^2 M^-1 A^T A M^-1`` leaves the bias out: with both, the Nikon D5100's chart
  calibration reads its film colours 3.6-7.4 stated errors off (RMS), against 1.2-1.9
  this way; ``experiments/chart_calibration_error.py``.)
- The response may dip below zero where a steep filter edge makes the smooth fit ring; it
  is not clipped, since the negative ring and the overshoot beside it integrate to the
  edge's colours (:func:`bubblefit.optics.spectral.response_functions` reads signed values).

The result (the camera's own sensitivity when a lamp is named, since the design holds the
lamp; else the camera-times-lamp product, to be used with illuminant ``E``) is a CSV ``wavelength_nm,r,g,b,r_err,g_err,b_err,m1_r,m1_g,m1_b,...``
that ``--camera-response`` reads (:func:`bubblefit.optics.spectral.response_functions`
reads its first four columns; the errors and the covariance's modes are read by
:func:`bubblefit.optics.spectral.response_error_modes`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

__all__ = ["KNOT_STEP_NM", "CHART", "CameraCalibration", "chart_reflectances", "detect_chart", "film_reflectances",
           "fit_response", "patch_means"]

#: Spacing of the response's knots (nm). A film's fringes at 1.5 um (optical path 4.2 um)
#: have a period of 72 nm at 550 nm: knots every 5 nm sample it 14 times (on noise-free Nikon
#: film colours, 10 nm knots left 3-30 % errors in predicted colours, 5 nm knots 0.4 %).
KNOT_STEP_NM = 5.0

#: The chart whose reflectances are used (colour-science's name).
CHART = "ColorChecker N Ohta"

#: The integration grid (nm): 1 nm over the visible range.
_FINE = np.arange(380.0, 781.0, 1.0)


def _knots() -> np.ndarray:
    return np.arange(380.0, 780.0 + 0.5 * KNOT_STEP_NM, KNOT_STEP_NM)


def chart_reflectances() -> tuple[list[str], np.ndarray]:
    """The ColorChecker's 24 patch names in reading order (row by row from the brown
    "dark skin") and their reflectances (24, L) on the 1 nm grid (colour-science)."""
    import colour

    sds = colour.SDS_COLOURCHECKERS[CHART]
    names = list(sds)
    refl = np.stack([np.interp(_FINE, np.asarray(sd.wavelengths), np.asarray(sd.values)) for sd in sds.values()])
    return names, refl


def film_reflectances(thickness_nm, n_film=1.33, angle_deg: float = 0.0) -> np.ndarray:
    """Airy reflectance (N, L) of a free film at each thickness on the 1 nm grid, averaged over
    polarisations (:func:`bubblefit.optics.film.airy_reflectance`; ``n_film`` a number, a
    Cauchy law or a preset of :mod:`bubblefit.optics.dispersion`)."""
    import jax.numpy as jnp

    from ..optics import dispersion, film

    d = np.asarray(thickness_nm, np.float64).reshape(-1, 1)
    n = np.asarray(dispersion.refractive_index(n_film, _FINE), np.float64)
    cos_i = float(np.cos(np.radians(angle_deg)))
    r = film.airy_reflectance(jnp.asarray(d), jnp.asarray(_FINE), jnp.asarray(n), cos_i)
    return np.asarray(r, np.float64).mean(-1)


def patch_means(pixels: np.ndarray, patches: np.ndarray, saturated: np.ndarray | None = None) -> np.ndarray:
    """Mean linear RGB (P, 3) of square patches ``(x, y, half_size)`` in pixels of a photo.

    Raises
    ------
    InputError
        A patch outside the photo, smaller than one pixel, or with clipped pixels.
    """
    h, w = pixels.shape[:2]
    out = []
    for i, (x, y, s) in enumerate(np.asarray(patches, np.float64)):
        x0, x1, y0, y1 = int(round(x - s)), int(round(x + s)) + 1, int(round(y - s)), int(round(y + s)) + 1
        if s < 0.5 or x0 < 0 or y0 < 0 or x1 > w or y1 > h:
            raise InputError(f"patch {i + 1} at ({x:g}, {y:g}) half-size {s:g} does not lie inside the {w}x{h} photo")
        if saturated is not None and saturated[y0:y1, x0:x1].any():
            raise InputError(f"patch {i + 1} at ({x:g}, {y:g}) has clipped pixels: expose the chart darker")
        out.append(pixels[y0:y1, x0:x1].reshape(-1, 3).mean(axis=0))
    return np.asarray(out)


def detect_chart(pixels: np.ndarray) -> np.ndarray:
    """The 24 patches' mean linear RGB (24, 3), in the chart's reading order, of the one
    ColorChecker found in a linear photo by colour-science's ``colour-checker-detection``
    (its segmentation detector: the chart's quadrilateral found from the patches' contours,
    warped to a canonical chart and each patch sampled at its centre; the order is the
    chart's whatever its rotation).

    References
    ----------
    Mansencal et al., colour-checker-detection (https://github.com/colour-science/colour-checker-detection),
    ``detect_colour_checkers_segmentation``.

    Raises
    ------
    InputError
        The package is not installed, or no chart or several are found. Clipped patches are
        not detected here: give their centres (:func:`patch_means` refuses clipped ones).
    """
    try:
        import colour_checker_detection as ccd
    except ImportError:
        raise InputError("finding the chart in the photo needs colour-checker-detection (pip install "
                         "'bubblefit[chart]'), or give the patches' centres with --patches") from None
    img = np.clip(np.asarray(pixels, np.float32), 0.0, None)
    peak = float(np.percentile(img, 99.5)) if img.size else 0.0
    if not peak > 0:
        raise InputError("the chart photo is black: no chart to find")
    found = ccd.detect_colour_checkers_segmentation(img / peak, apply_cctf_decoding=False, additional_data=True)
    if len(found) != 1:
        raise InputError(f"found {len(found)} ColorChecker charts in the photo, not one: give the patches' "
                         "centres with --patches")
    values = np.asarray(found[0].swatch_colours, np.float64) * peak
    if values.shape != (24, 3) or not np.all(np.isfinite(values)):
        raise InputError("the chart found in the photo does not have 24 patches: give their centres with --patches")
    return values


@dataclass
class CameraCalibration:
    """A fitted response: ``response`` (L, 3) at ``wavelengths`` (L,) with ``stderr`` (L, 3),
    each channel's maximum 1, and ``modes`` (L, 3, M) of each channel's covariance between
    rows (``sum_m u_m u_m^T``; None: the rows' errors only, taken as independent); the fit's
    relative residual per channel, its smoothing weights and degrees of freedom."""

    wavelengths: np.ndarray
    response: np.ndarray
    stderr: np.ndarray
    residual_rel: np.ndarray
    smoothing: np.ndarray
    effective_dof: np.ndarray
    samples: int
    illuminant: str
    sources: list = field(default_factory=list)
    modes: np.ndarray | None = None

    def csv_text(self) -> str:
        """``wavelength_nm,r,g,b,r_err,g_err,b_err,m1_r,...`` (what ``--camera-response`` reads)."""
        from ..optics.spectral import _LAMP_INCLUDED, CALIBRATED_UNDER

        modes = np.zeros((len(self.wavelengths), 3, 0)) if self.modes is None else self.modes
        n_modes = modes.shape[-1]
        lines = [f"# camera response fitted by bubblefit calibrate-camera from {', '.join(self.sources)}"
                 f"{CALIBRATED_UNDER}{self.illuminant}" + (_LAMP_INCLUDED if self.illuminant == "E" else ""),
                 "wavelength_nm,r,g,b,r_err,g_err,b_err"
                 + "".join(f",m{m + 1}_r,m{m + 1}_g,m{m + 1}_b" for m in range(n_modes))]
        for lam, r, e, u in zip(self.wavelengths, self.response, self.stderr, modes):
            lines.append(f"{lam:g}," + ",".join(f"{v:.6g}" for v in (*r, *e, *u.T.ravel())))
        return "\n".join(lines) + "\n"

    def to_json(self) -> dict:
        return {"wavelength_nm": self.wavelengths.tolist(), "response": self.response.tolist(),
                "stderr": self.stderr.tolist(), "residual_rel": self.residual_rel.tolist(),
                "smoothing": self.smoothing.tolist(), "effective_dof": self.effective_dof.tolist(),
                "samples": self.samples, "illuminant": self.illuminant, "sources": list(self.sources),
                "knot_step_nm": KNOT_STEP_NM}


def _design(spectra: np.ndarray, lamp: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """``A_kj = sum_lambda H_j(lambda) I(lambda) S_k(lambda) dlambda`` for hat functions
    ``H_j`` on the knots (piecewise-linear interpolation's weights)."""
    hats = np.stack([np.interp(_FINE, knots, np.eye(len(knots))[j]) for j in range(len(knots))], axis=1)
    return spectra @ (hats * lamp[:, None])


def _smooth_fit(a: np.ndarray, y: np.ndarray, d: np.ndarray):
    """Penalised least squares ``min |y - A x|^2 + lambda |D x|^2``, averaged over the penalty
    weight by its restricted (marginal) likelihood, with the posterior covariance of ``x``:
    ``(x, cov, lambda, dof, rel)`` (module docstring; ``lambda`` and ``dof`` of the most
    likely weight).

    The penalty is a Gaussian prior on the response's second differences, of variance
    ``s^2 / lambda``; integrating ``x`` out, the restricted log likelihood of the samples is
    ``-1/2 [(n - m0) log s^2 + log|A^T A + lambda P| - log|lambda P|_+]`` with ``s^2`` at its
    maximum ``(|y - A x|^2 + lambda x^T P x) / (n - m0)``, ``P = D^T D`` and ``m0`` the
    dimension of ``P``'s null space (Wood, "Fast stable restricted maximum likelihood and
    marginal likelihood estimation of semiparametric generalized linear models", JRSS B
    73(1), 2011, eq. 4). For one weight the posterior covariance ``s^2 (A^T A + lambda P)^-1``
    holds the smoothing's bias as well as the noise (Wahba, "Bayesian 'confidence
    intervals' for the cross-validated smoothing spline", JRSS B 45(1), 1983): where the
    samples say nothing (a chart's smooth reflectances and a response's fine structure) it
    is the prior's width. The weight itself is uncertain, so the result is averaged over a
    grid of weights (uniform in ``log lambda``) with their likelihoods: the mean of the
    solutions, and the mean of their covariances plus the solutions' scatter (the law of
    total variance)."""
    ata, aty, pen = a.T @ a, a.T @ y, d.T @ d
    ev = np.linalg.eigvalsh(pen)
    kept = ev > 1e-10 * ev.max()
    log_det_pen, m0 = float(np.sum(np.log(ev[kept]))), int(np.count_nonzero(~kept))
    scale = np.trace(ata) / max(np.trace(pen), 1e-300)
    n = len(y)
    if n - m0 < 2:
        raise InputError("too few calibration samples for the response's smoothness (give more patches or thicknesses)")
    fits = []
    for lam in scale * np.logspace(-9, 3, 61):
        m = ata + lam * pen
        sign, log_det = np.linalg.slogdet(m)
        if sign <= 0:
            continue
        minv = np.linalg.inv(m)
        x = minv @ aty
        res = y - a @ x
        s2 = (float(res @ res) + lam * float(x @ pen @ x)) / (n - m0)
        if not s2 > 0:
            continue
        score = (n - m0) * np.log(s2) + log_det - (np.count_nonzero(kept) * np.log(lam) + log_det_pen)
        fits.append((score, lam, x, s2 * minv, minv))
    if not fits:
        raise InputError("too few calibration samples for the response's smoothness (give more patches or thicknesses)")
    scores = np.array([f[0] for f in fits])
    wts = np.exp(-0.5 * (scores - scores.min()))
    wts /= wts.sum()
    xs = np.stack([f[2] for f in fits])
    x = wts @ xs
    dev = xs - x
    cov = np.einsum("k,kij->ij", wts, np.stack([f[3] for f in fits])) + (dev * wts[:, None]).T @ dev
    _, lam, _, _, minv = fits[int(np.argmin(scores))]
    tr = float(np.trace(a @ minv @ a.T))
    res = y - a @ x
    rel = float(np.sqrt(np.mean(res**2)) / max(np.sqrt(np.mean(y**2)), 1e-300))
    return x, cov, lam, tr, rel


#: Modes of a covariance whose variance is below this share of the largest mode's are
#: dropped from the CSV (negligible: the smallest kept mode is 1e-4 of the largest in deviation).
_MODE_SHARE = 1e-8


def _covariance_modes(cov: np.ndarray) -> np.ndarray:
    """(L, M) modes ``u_m = sqrt(e_m) v_m`` of a symmetric covariance (``cov = sum_m u_m u_m^T``
    over its eigenpairs), largest first, those below :data:`_MODE_SHARE` of the largest dropped."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    order = np.argsort(vals)[::-1]
    vals, vecs = np.clip(vals[order], 0.0, None), vecs[:, order]
    keep = vals > _MODE_SHARE * max(float(vals[0]), 1e-300)
    return vecs[:, keep] * np.sqrt(vals[keep])


def fit_response(sources: list[tuple[str, np.ndarray, np.ndarray]], illuminant: str = "E") -> CameraCalibration:
    """Fit the response from ``sources``: ``(name, spectra (N, L) on the 1 nm grid, linear
    RGB (N, 3))``, all under the same lamp and exposure (module docstring).

    Raises
    ------
    InputError
        Fewer than 6 samples, non-finite or negative values, or a channel without signal.
    """
    from ..optics.spectral import TABLE_GRID, illuminant_spectrum

    spectra = np.concatenate([s for _, s, _ in sources])
    rgb = np.concatenate([np.asarray(v, np.float64) for _, _, v in sources])
    if len(rgb) < 6:
        raise InputError(f"calibration needs at least 6 samples (patches or thicknesses), got {len(rgb)}")
    if not np.all(np.isfinite(rgb)):
        raise InputError("calibration samples hold NaN or Inf values")
    if np.any(rgb.max(axis=0) <= 0):
        raise InputError("a colour channel has no signal in the calibration samples (wrong encoding or exposure?)")
    lamp = np.interp(_FINE, TABLE_GRID, illuminant_spectrum(illuminant))
    knots = _knots()
    a = _design(spectra, lamp, knots)
    a_scale = np.abs(a).max()
    d = np.diff(np.eye(len(knots)), n=2, axis=0)
    resp, err, modes, lams, dofs, rels = [], [], [], [], [], []
    for c in range(3):
        y = rgb[:, c] / rgb[:, c].max()
        x, cov, lam, tr, rel = _smooth_fit(a / a_scale, y, d)
        peak = float(np.max(x))
        if not peak > 0:
            raise InputError("the fitted response of a channel is not positive anywhere: check the samples")
        resp.append(x / peak)
        err.append(np.sqrt(np.clip(np.diag(cov), 0.0, None)) / peak)
        modes.append(_covariance_modes(cov) / peak)
        lams.append(lam)
        dofs.append(tr)
        rels.append(rel)
    response = np.stack(resp, axis=1)
    stderr = np.stack(err, axis=1)
    n_modes = max(u.shape[1] for u in modes)
    modes = np.stack([np.pad(u, ((0, 0), (0, n_modes - u.shape[1]))) for u in modes], axis=1)
    # the design holds the lamp (``_design``), so ``x`` is the camera's own sensitivity under a
    # named lamp and the camera-times-lamp product under ``E``
    return CameraCalibration(knots, response, stderr, np.asarray(rels), np.asarray(lams), np.asarray(dofs),
                             int(len(rgb)), illuminant, [name for name, _, _ in sources], modes)
