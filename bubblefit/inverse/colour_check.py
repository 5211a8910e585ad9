"""Can the stated camera response produce the photo's colours? A test of the fit's hue.

A film's colour is set by its thickness *through* the camera's spectral response: fitted
with the wrong response (a Nikon's raw RGB read as sRGB/D65), the best thickness still
leaves hues the stated response cannot reach. Brightness errors (the light's strength,
the lobe's shape, the rim) are common to all channels, so this test looks only at the
residual's *chromatic* part and only at what is *coherent* over a patch of the film. A
grid of :data:`GRID` x :data:`GRID` cells is laid on the disc's inner part
(:data:`INNER_COS`; the rim is left to the chi^2), and each cell is split into parts whose
pixels' film has the same optical path ``2 n d cos t`` to within :data:`PATH_BIN` (the
hue error of a wrong response turns with the path, and a thick film's cell spans a fringe
of it: averaged over the whole cell, it cancels). In part ``b`` of ``n_b`` pixels (a
"cell" below), with ``P_b`` the (2, 3) orthonormal basis of the plane orthogonal to its
mean rendered colour, the statistic's terms are

``m_b = P_b mean_i(photo_i - render_i)``, the cell's mean chromatic residual;
``C_b = P_b diag(sum_i sigma_i^2) P_b^T / n_b^2``, its covariance under the fit's own noise
model (``sigma_i`` per pixel and channel: read, shot and quantisation noise,
:func:`~bubblefit.inverse._observation.noise_sigma`; channels independent), exact for any
per-channel noise (the chromatic plane of a pale film is far from isotropic);
``F_b``, a chromatic model-error floor that does not average down: :data:`CHROMA_FLOOR`
of the cell's brightness and :data:`CHROMA_REL` of its chroma, split over the plane's two
components, plus ``s_b s_b^T`` for each nuisance of the model that the fit does not free
and whose effect the model itself can compute at the fitted values (a Type B evaluation,
JCGM 100:2008 "Guide to the expression of uncertainty in measurement", sec. 4.3): ``s_b =
P_b mean_i(alt_i - render_i)``, the part's chromatic offset between the render with the
nuisance's other choice and the fit's render, an offset of unknown sign that the part's
pixels share, one such term per independent source. The one such nuisance is the rough
film's microfacet distribution (:func:`microfacet_offsets`: GGX's facets under the film and
GGX's lobe, each against Ward's): the paper's lobe is Ward's, and a real film's roughness
is neither Ward's nor GGX's.

Under the hypothesis that the colours are explained, each ``m_b`` is a centred normal
vector with covariance ``C_b`` (plus at most ``F_b``), so
``T = sum_b m_b^T (kappa C_b + F_b)^-1 m_b`` follows (at most) a chi^2 law with ``2 B``
degrees of freedom; the colours are inconsistent when ``T`` exceeds the law's
1 - :data:`FALSE_ALARM` quantile. The fit (:func:`judge_colours`) also pools each
optical-path bin over the whole film: a constant film's hue error from a wrong response
is a function of the path alone, the same in every cell, and one mean per bin holds it in
far fewer degrees of freedom (about 2 x 9 on a 1500 nm film's 48 px disc against 2 x 110
parts). For a constant film or a drainage profile it also runs a score test
(:func:`_score_verdict`): whether the stated response needs a smooth change (12 directions)
beyond its stated errors, the thickness (or the profile's parameters) profiled out, over
the cells' parts. The members are tested each at an equal
share of the false-alarm rate (Bonferroni), and the colours are inconsistent when any fails.
``kappa >= 1`` guards the noise model (:func:`noise_scale`): the ratio of the chromatic part of each pixel's residual minus the
mean of its four neighbours' to what the noise model predicts for it, pooled over the
film (hundreds of pixels, so it adds little tail). A hue error that follows the film's
thickness varies over several pixels and cancels in that difference; noise does not. (The
scatter about a plane fitted in each cell would also hold the part of a wrong response's
hue error that varies within a cell: on draining films read with a wrong response it
reads 3.6-4.1 and hides the error.) Where neighbours differ less than
independent pixels would (:data:`SHARED_BELOW`: they share noise), the means of 2 x 2 blocks
of pixels measure it instead (noise drawn once per block, which independent pixels would
average away). A camera noisier than the noise model (``FitOptions.noise``) raises
``kappa``, not the alarm. A wrong response
moves every pixel of a thickness the same way: ``m_b`` grows with it and ``C_b`` does not.

Pixels the fit calls outliers (chi^2 with its model-error floor over
:data:`~bubblefit.inverse._uncertainty.OUTLIER_CHI2`: glints, specks) are left out. A
photo demosaiced from a Bayer mosaic holds, in a mean over ``n`` pixels, the noise of
only ``share * n`` photosites per channel (1/4, 1/2, 1/4): the fit divides its ``sigma``
by ``sqrt(share)`` (``NoiseSettings.photosite_share``), an upper bound of that noise.

Why a cell's own scatter is not used as its noise: estimated from its ~25 pixels, it
makes ``2 |m_b|^2 / (tr S_b / n_b)`` an F-like law with a heavier tail than chi^2, and
its trace misweights an anisotropic plane. Drawn from those laws (``B = 32``,
``n_b = 25``), the sum per degree of freedom has mean 1.04 and 1e-3 quantile 1.75 for
isotropic noise, 1.07 and 2.11 when one chromatic component has ten times the other's
variance, against the 1.64 of chi^2: right-camera photos read 1.8-1.9 were within that
law's reach. And a RAW file's demosaic correlates neighbouring pixels: a right 48 px DNG
read 3.5 as independent pixels, 1.4 with the photosite shares.

References
----------
The chromatic/achromatic split of a residual: Finlayson, Drew & Funt, "Color constancy:
generalized diagonal transforms suffice", JOSA A 11(11), 1994 (colour as a direction in
RGB); the quadratic form of a normal vector in its inverse covariance is chi^2-distributed
(Mardia, Kent & Bibby, *Multivariate Analysis*, 1979, thm. 2.5.2); the Bayer mosaic:
B. E. Bayer, US patent 3,971,065 (1976); a noise level from each pixel less the mean of its
neighbours (a Laplacian, which a smooth signal cancels): J. Immerkaer, "Fast noise variance
estimation", Computer Vision and Image Understanding 64(2), 1996.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ._uncertainty import OUTLIER_CHI2
from ..optics.film import optical_path
from ..optics.spectral import LAMBDA_MIN

__all__ = ["ColourCheck", "colour_check", "judge_colours", "neighbour_scale", "noise_scale", "microfacet_offsets",
           "CHROMA_FLOOR", "CHROMA_REL", "FACET_MIRROR", "GGX_LOBE_WIDTHS", "FALSE_ALARM", "GRID", "INNER_COS",
           "MIN_PART_PIXELS", "PATH_BIN", "SHARED_BELOW"]

#: Chromatic model error allowed per cell, as a fraction of the cell's brightness ``|render|``.
#: From fits with the right camera only (experiments/colour_check_null.py: 48 px photos
#: rendered by bubblefit with the Nikon's sensitivities, 48 uniform spectral samples, fitted
#: with the fit's own quadrature): the quadratures differ in hue by about this much, the
#: largest at 1000 nm; with no floor the statistic reads 0.78-1.35 on the five thicknesses
#: 300-1500 nm, with this one 0.60-0.99.
CHROMA_FLOOR = 0.002

#: A second floor, as a fraction of the cell's *chroma* (the norm of its mean rendered
#: colour orthogonal to grey): independent renderers of the same film differ in the
#: interference term itself (polarisations averaged per hit or per path, a mesh sphere),
#: which colours saturated films most. Chosen on the validation set's development case
#: cyc_const500_courtyard_ortho (a Cycles render of a 500 nm film, fitted to 499.2 nm
#: under its own illuminant E), which left a coherent hue error of 0.9 % of its chroma; the
#: wrong cameras of experiments/wrong_camera.py leave 20-500 % of theirs, pale thick films
#: included.
CHROMA_REL = 0.01

#: The test's false-alarm probability on a correctly explained photo.
FALSE_ALARM = 1e-3

#: Cells per side of the grid laid on the disc's bounding square.
GRID = 6

#: Only pixels whose front film is seen at ``cos(theta_i) >`` this enter the test (within
#: 0.8 of the disc's radius for an orthographic camera). Towards the rim the models differ
#: most (Fresnel at grazing angles, bounces, each pixel's footprint): on the validation set's
#: reference render of a 300 nm film (experiments/validation, ref_const300_courtyard_ortho,
#: fitted with its own sRGB/D65 camera) the cells touching the rim held hue errors of 2-8 %
#: and the statistic was 4.6 over 0.95 of the radius, 1.06 over 0.8.
INNER_COS = 0.6

#: Fewest pixels a cell needs to enter the test (its scatter estimate needs a few).
MIN_PIXELS = 12

#: Width (nm) of the optical-path bins that split each cell (``colour_check``'s ``path``):
#: a quarter of the shortest wavelength's fringe, ``LAMBDA_MIN / 4``
#: (:data:`bubblefit.optics.spectral.LAMBDA_MIN`). A response's hue error at a pixel is a
#: function of the film's reflectance spectrum there, and so of its optical path
#: ``x = 2 n d cos t`` (eq. (8)'s phase, :func:`bubblefit.optics.film.optical_path`); its
#: part at wavelength ``lambda`` turns as ``cos(2 pi x / lambda)``, and a mean over a bin of
#: width ``w`` keeps ``sinc(w / lambda)`` of it: 0.90 at 380 nm for ``w = 95``, more at
#: longer wavelengths. A cell of a thick film's disc spans a fringe or more (a 1500 nm
#: film's path changes by about 110 nm per pixel at 0.8 of a 20 px radius, orthographic),
#: over which such an error averages to nearly nothing; split by path, each part keeps it.
PATH_BIN = LAMBDA_MIN / 4.0

#: Fewest pixels of one optical-path bin in a cell to enter the test as a part of its own:
#: a Bayer quad (2 x 2 pixels), the fewest whose mean holds a photosite of every colour, as
#: the photosite shares (1/4, 1/2, 1/4) of a demosaiced photo's noise assume.
MIN_PART_PIXELS = 4


@dataclass(frozen=True)
class ColourCheck:
    """The outcome of :func:`colour_check`."""

    consistent: bool
    chi2_per_dof: float      # the statistic divided by its degrees of freedom
    threshold_per_dof: float
    cells: int
    chroma_rms: float        # RMS over cells of |mean chromatic residual| / |mean render| (a fraction)
    noise_scale: float = 1.0  # kappa: the photo's scatter over the noise model's, at least 1
    response_errors: bool = False  # whether the response's own stated errors are in the null
    partition: str = "cells"  # the parts reported: "cells" (the grid's, split by path), "path" (the film's path
    # bins) or "response" (the score test along smooth changes of the response over the cells' parts)
    dof: int = 0              # the statistic's degrees of freedom
    #: RMS over the parts of |s_b| / |mean render|, the Type B offsets in F_b (module
    #: docstring; None: none given)
    offset_rms: float | None = None

    def warning(self, explained: bool = True) -> str | None:
        """One line for the fit's warnings when the colours are inconsistent, else None;
        when the model does not explain the photo's brightness either (``explained``
        False: the verdict's chi^2 test failed), the line says the camera is then only one
        suspect."""
        if self.consistent:
            return None
        if self.partition == "response":
            what = (f"a hue error of {self.chroma_rms:.1%} that a smooth change of the response beyond its stated errors "
                    f"explains (score chi^2/dof {self.chi2_per_dof:.3g} along {self.dof} changes of the response over "
                    f"{self.cells} patches, at most {self.threshold_per_dof:.3g} expected)")
        else:
            what = (f"a hue error of {self.chroma_rms:.1%} coherent over the film (chromatic chi^2/dof "
                    f"{self.chi2_per_dof:.3g} over {self.cells} "
                    f"{'patches' if self.partition == 'cells' else 'optical-path bins'}, "
                    f"at most {self.threshold_per_dof:.3g} expected)")
        if not explained:
            return (f"the hues are not explained either: {what}; with the model missing the photo as a whole, the "
                    "camera response (--camera-response, bubblefit calibrate-camera) and --encoding are suspects "
                    "among the map, disc and model (docs/cameras.md)")
        return (f"the stated camera response cannot produce the photo's colours: {what}: the camera response or the "
                "file's encoding is wrong (or the thickness is an interference order off); give the camera "
                "(--camera-response, a response from bubblefit calibrate-camera, with its --illuminant) and check "
                "--encoding (docs/cameras.md)")

    def to_json(self, decides: bool = True) -> dict:
        """The record of the fit's JSON; ``decides``: whether a failure makes the fit not
        ``ok`` (``JudgeSettings.colour_check``)."""
        out = {"consistent": self.consistent, "chi2_per_dof": self.chi2_per_dof,
               "threshold_per_dof": self.threshold_per_dof, "cells": self.cells, "chroma_rms": self.chroma_rms,
               "noise_scale": self.noise_scale, "response_errors": self.response_errors, "partition": self.partition,
               "dof": self.dof, "decides": bool(decides)}
        if self.offset_rms is not None:
            out["offset_rms"] = self.offset_rms
        return out


def _plane(c: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal rows spanning the plane orthogonal to the unit colour ``c``."""
    a = np.eye(3)[int(np.argmin(np.abs(c)))]
    u = np.cross(c, a)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(c, u)])


class _Part(NamedTuple):
    """One part's terms of the statistic (:func:`_cell_terms`; module docstring)."""

    mean: np.ndarray         # m_b, the mean chromatic residual (2,)
    noise: np.ndarray        # C_b, its covariance under the noise model (2, 2)
    floor: np.ndarray        # F_b, the model-error floor with the Type B offsets' outer products (2, 2)
    bright: float            # the part's mean brightness |render|
    jac: np.ndarray | None   # P_b jac: the response's error coefficients' change (2, K), or None
    score: tuple | None      # (P_b D, P_b N): the score test's directions and nuisances, or None
    floors: np.ndarray       # F_b without the Type B offsets (2, 2)
    offset: float            # |s_b|, the root of the offsets' outer products' trace


def _cell_terms(e: np.ndarray, v: np.ndarray, rend: np.ndarray, floor: float, chroma_floor: float, jac, score=None,
                offset=None):
    """One cell's terms of :func:`colour_check` (module docstring) from its pixels' residuals
    ``e``, noise variances ``v`` and renders ``rend`` (n, 3), ``jac``, the (3, K) change of
    its mean render per unit of the response's error coefficients (None: none),
    ``score``, the pair ``(D, N)`` of the score test's directions and nuisances (None: none),
    and ``offset``, its pixels' Type B offsets (K, n, 3), one row per independent source
    (None: none): a :class:`_Part`, ``F_b`` with ``sum_k s_bk s_bk^T`` and ``floors``
    without it, ``|s_b|`` the root of that sum's trace."""
    n = e.shape[0]
    mean = rend.mean(axis=0)
    p = _plane(mean / np.linalg.norm(mean))
    noise = (p * v.sum(axis=0)) @ p.T / n**2       # covariance of the mean chromatic residual
    bright = float(np.linalg.norm(rend, axis=1).mean())
    chroma = float(np.linalg.norm(mean - mean.mean()))  # the part orthogonal to grey (1, 1, 1)
    floors = 0.5 * ((floor * bright) ** 2 + (chroma_floor * chroma) ** 2) * np.eye(2)
    s = np.zeros((1, 2)) if offset is None else offset.mean(axis=1) @ p.T  # (K, 2): each source's s_bk
    return _Part((e @ p.T).mean(axis=0), noise, floors + s.T @ s, bright, None if jac is None else p @ jac,
                 None if score is None else (p @ score[0], p @ score[1]), floors, float(np.linalg.norm(s)))


def colour_check(photo: np.ndarray, render: np.ndarray, mask: np.ndarray, sigma: np.ndarray, *,
                 model_error: float | None = None, floor: float = CHROMA_FLOOR, chroma_floor: float = CHROMA_REL, grid: int = GRID,
                 false_alarm: float = FALSE_ALARM, response_jac=None, path: np.ndarray | None = None,
                 path_bin: float | None = None, pooled: bool = False, score_jac=None,
                 offset: np.ndarray | None = None) -> ColourCheck | None:
    """Test whether ``render`` explains the hues of ``photo`` over the pixels of ``mask``,
    each pixel's channels having the noise standard deviation ``sigma`` (the fit's noise
    model, :func:`~bubblefit.inverse._observation.noise_sigma`); module docstring. Pixels
    that are outliers of the fit (chi^2 over their channels, with the fit's ``model_error``
    floor, above :data:`~bubblefit.inverse._uncertainty.OUTLIER_CHI2`: glints, specks) are
    left out, as the verdict's split leaves them out of the explained pixels (none with
    ``model_error`` None). ``response_jac``, where the camera response states its own
    errors (:func:`bubblefit.inverse.response_error.response_cells`): a function of a cell's
    pixel rows and columns giving the (3, K) change of its mean render per unit of the
    response's K error coefficients (independent, unit variance), which every cell shares:
    the null's covariance over all cells is then ``blockdiag(C_b) + G G^T`` (``C_b`` each
    cell's noise and floor, ``G`` the cells' projected Jacobians stacked), and the
    statistic ``m^T (blockdiag(C_b) + G G^T)^-1 m`` is computed by the Woodbury identity,
    ``sum_b m_b^T C_b^-1 m_b - u^T (I + sum_b G_b^T C_b^-1 G_b)^-1 u`` with
    ``u = sum_b G_b^T C_b^-1 m_b`` (Woodbury, 1950; Press et al., *Numerical Recipes*, 3rd
    ed., sec. 2.7.3): one draw of the response explains one pattern of hue errors over the
    film, not a different one in each cell. ``pooled`` (with ``path``): the test is the
    union of two partitions of the same pixels, the grid's cells split by the path and the
    path's bins over the whole film (a constant film's hue error is a function of the path
    alone, so pooling each bin over the film keeps it and averages the noise over every
    pixel of that path), each at ``false_alarm / 2`` (Bonferroni: the union's false-alarm
    rate is at most the sum), and the partition with the larger statistic over its
    threshold is returned (``partition``). ``score_jac`` (:func:`bubblefit.inverse.response_error.response_score_cells`):
    a function of a part's pixel rows and columns giving ``(D, N)``, the change of its mean
    render per unit of each of a few smooth changes of the response and of each nuisance the
    fit adjusts in the hue; the score test along them (:func:`_score_verdict`) is then one
    more member of the union, every member at ``false_alarm`` over their number.
    ``offset`` (H, W, 3), or (K, H, W, 3) for K independent sources: Type B offsets per
    pixel (module docstring; :func:`microfacet_offsets`), whose part means' outer products
    join each part's floor ``F_b`` in every member.
    ``None`` when fewer than two cells have :data:`MIN_PIXELS` pixels."""
    tests = _tests(photo, render, mask, sigma, model_error=model_error, floor=floor, chroma_floor=chroma_floor,
                   grid=grid, false_alarm=false_alarm, response_jac=response_jac, path=path, path_bin=path_bin,
                   pooled=pooled, score_jac=score_jac, offset=offset)
    if not tests:
        return None
    worse = max(tests, key=lambda c: c.chi2_per_dof / c.threshold_per_dof)
    return replace(worse, consistent=all(c.consistent for c in tests))


def _tests(photo, render, mask, sigma, *, model_error, floor, chroma_floor, grid, false_alarm, response_jac, path,
           path_bin, pooled, score_jac, offset=None) -> list:
    """The members of :func:`colour_check`'s union (its arguments), each a
    :class:`ColourCheck` at its share of ``false_alarm``: the grid's cells (split by
    ``path``), with ``pooled`` the path's bins over the film, with ``score_jac`` the score
    test over the cells' parts; empty when fewer than two cells have :data:`MIN_PIXELS`
    pixels."""
    photo = np.asarray(photo, np.float64)
    render = np.asarray(render, np.float64)
    var = np.asarray(sigma, np.float64) ** 2 * np.ones_like(photo)
    norm = np.linalg.norm(render, axis=-1)
    use = (np.asarray(mask, bool) & (norm > 0) & np.all(np.isfinite(photo), axis=-1)
           & np.all(np.isfinite(var) & (var > 0), axis=-1))
    if model_error is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            chi = np.sum((photo - render) ** 2 / (var + (model_error * np.clip(photo, 0, None)) ** 2), axis=-1)
        use &= ~(chi > OUTLIER_CHI2)
    ys, xs = np.nonzero(use)
    if ys.size < 2 * MIN_PIXELS:
        return []
    e, v, rend = photo[ys, xs] - render[ys, xs], var[ys, xs], render[ys, xs]
    shift = None if offset is None else np.asarray(offset, np.float64).reshape((-1,) + photo.shape)[:, ys, xs]
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    cy = np.minimum((ys - y0) * grid // max(y1 - y0, 1), grid - 1)
    cx = np.minimum((xs - x0) * grid // max(x1 - x0, 1), grid - 1)
    cell = cy * grid + cx
    path_bin = PATH_BIN if path_bin is None else float(path_bin)
    if path is None:
        part = np.zeros(ys.size, np.int64)
    else:  # the optical-path bin of each pixel (PATH_BIN); pixels without a path form their own
        x = np.broadcast_to(np.asarray(path, np.float64), photo.shape[:2])[ys, xs]
        part = np.where(np.isfinite(x), np.floor(np.where(np.isfinite(x), x, 0.0) / path_bin), -1).astype(np.int64)
    subs = []  # the cells' parts: indices of their pixels
    white = np.full(photo.shape[:2] + (2,), np.nan)  # detrended chromatic residual / its predicted sigma
    for b in np.unique(cell):
        sel = np.nonzero(cell == b)[0]
        n = sel.size
        if n < MIN_PIXELS:
            continue
        mean = rend[sel].mean(axis=0)
        p = _plane(mean / np.linalg.norm(mean))
        ep = e[sel] @ p.T                                   # (n, 2) chromatic residuals
        # the scatter about a plane in (x, y), whitened: for the 2 x 2 block means (_block_scale)
        x = np.stack([np.ones(n), ys[sel] - ys[sel].mean(), xs[sel] - xs[sel].mean()], axis=1)
        fitted = x @ np.linalg.lstsq(x, ep, rcond=None)[0]
        per = np.sqrt(0.5 * np.einsum("ij,nj,ij->n", p, v[sel], p) * (n - 3) / n)
        white[ys[sel], xs[sel]] = (ep - fitted) / per[:, None]
        for q in np.unique(part[sel]):  # the cell's pixels of one optical-path bin
            sub = sel[part[sel] == q]
            if sub.size >= MIN_PART_PIXELS:
                subs.append(sub)
    if len(subs) < 2:
        return []
    scores = [None] * len(subs) if score_jac is None else _part_means(score_jac, ys, xs, subs)
    cells = [_cell_terms(e[sub], v[sub], rend[sub], floor, chroma_floor,
                         None if response_jac is None else response_jac(ys[sub], xs[sub]), score,
                         None if shift is None else shift[:, sub])
             for sub, score in zip(subs, scores)]
    kappa = noise_scale(photo, render, var, use, white)
    bins = []  # the path's bins over the whole film
    for q in np.unique(part) if pooled and path is not None else ():
        sub = np.nonzero(part == q)[0]
        if sub.size >= MIN_PART_PIXELS:
            bins.append(_cell_terms(e[sub], v[sub], rend[sub], floor, chroma_floor,
                                    None if response_jac is None else response_jac(ys[sub], xs[sub]), None,
                                    None if shift is None else shift[:, sub]))
    members = 1 + (pooled and path is not None) + (score_jac is not None)
    shared = response_jac is not None
    out = [_verdict(cells, kappa, false_alarm / members, shared)]
    if len(bins) >= 2:
        out.append(_verdict(bins, kappa, false_alarm / members, shared, "path"))
    if score_jac is not None:
        score = _score_verdict(cells, kappa, false_alarm / members, shared)
        out += [] if score is None else [score]
    if offset is not None:  # the Type B offsets' size beside the residual's (ColourCheck.offset_rms)
        out = [replace(c, offset_rms=_offset_rms(cells if c.partition != "path" else bins)) for c in out]
    return out


def _offset_rms(parts: list) -> float:
    """RMS over ``parts`` (:func:`_cell_terms`' tuples) of ``|s_b| / brightness``."""
    return float(np.sqrt(np.mean([(c.offset / c.bright) ** 2 for c in parts])))


def _part_means(score_jac, ys, xs, subs: list) -> list:
    """``[(D_b, N_b)]``: the means over each part's pixels (``subs``, indices into ``ys``,
    ``xs``; at most :data:`bubblefit.inverse.response_error.MAX_PIXELS` of each, evenly
    strided) of ``score_jac``'s per-pixel directions and nuisances, from one call over all
    of them."""
    from .response_error import MAX_PIXELS

    take = [sub if sub.size <= MAX_PIXELS else sub[np.linspace(0, sub.size - 1, MAX_PIXELS).astype(int)]
            for sub in subs]
    every = np.concatenate(take)
    d, n = score_jac(ys[every], xs[every])
    ends = np.cumsum([t.size for t in take])[:-1]
    return [(a.mean(axis=0), b.mean(axis=0)) for a, b in zip(np.split(d, ends), np.split(n, ends))]


def _verdict(cells: list, kappa: float, false_alarm: float, shared: bool, partition: str = "cells") -> ColourCheck:
    """:func:`colour_check`'s statistic over the parts ``cells`` (:func:`_cell_terms`' tuples)
    at noise scale ``kappa``, against the chi^2 law's ``1 - false_alarm`` quantile with two
    degrees of freedom per part; ``shared``: the parts carry the response's Jacobian, whose one
    draw enters the null by the Woodbury identity (Woodbury, 1950; Press et al., *Numerical
    Recipes*, 3rd ed., sec. 2.7.3)."""
    # the chi-square upper quantile, chi2.isf(p, dof) of scipy.stats, from scipy.special:
    # the same function without scipy.stats' import (0.4 s of CPU in every fit's process)
    from scipy.special import chdtri

    stat = sum(float(c.mean @ np.linalg.solve(kappa * c.noise + c.floor, c.mean)) for c in cells)
    if shared:  # the shared response's draw, by the Woodbury identity
        k = cells[0].jac.shape[1]
        u, inner = np.zeros(k), np.eye(k)
        for m, c, f, _, g, *_ in cells:
            cg = np.linalg.solve(kappa * c + f, g)  # C_b^-1 G_b
            u += cg.T @ m
            inner += g.T @ cg
        stat -= float(u @ np.linalg.solve(inner, u))
    dof = 2 * len(cells)
    thr = float(chdtri(dof, false_alarm)) / dof
    value = stat / dof
    rel = [float(np.linalg.norm(c.mean)) / c.bright for c in cells]
    return ColourCheck(bool(value <= thr), value, thr, len(cells), float(np.sqrt(np.mean(np.square(rel)))), kappa,
                       shared, partition, dof)


#: Size under which a singular value of the score test's whitened directions counts as none
#: (:func:`_score_verdict`): their columns are scaled to unit norm first (before the
#: nuisances are projected out), so this bounds their conditioning, far above float64's
#: rounding (1e-16).
SCORE_RCOND = 1e-6


def _score_verdict(cells: list, kappa: float, false_alarm: float, shared: bool) -> ColourCheck | None:
    """The score (Lagrange multiplier) test that the camera response needs a change along
    the directions ``D`` that :func:`_cell_terms` carries in each part (a few smooth changes
    of the response, :func:`bubblefit.inverse.response_error.response_score_cells`), with
    the fit's nuisances ``N`` profiled out (Rao, "Large sample tests of statistical
    hypotheses concerning several parameters", Proc. Cambridge Phil. Soc. 44, 1948;
    Breusch & Pagan, Econometrica 47, 1979): the parts' mean chromatic residuals ``m``
    have, under the stated response, the covariance ``Sigma = blockdiag(kappa C_b + F_b) +
    G G^T + tau^2 D D^T`` (the response's stated errors ``G`` with ``shared``: their one
    draw is the prior, and only a change beyond it is tested). The last term is the
    model-error floors' share: a floor does not average down over the pixels of a part,
    nor over the parts (another renderer's hue error is coherent over the film, and a smooth
    change of the response can mimic it), so besides each part's own floor ``F_b`` the
    null holds one shared draw along the directions, of the size that moves the mean part's
    hue by its floor, spread evenly over the ``K`` directions that move it:
    ``tau_k^2 = mean_b tr F_b / (K mean_b |D_bk|^2)`` (the constant floors only: a Type B
    offset ``s_b s_b^T`` is the model's own computed pattern, held in ``F_b`` of the first
    term) for direction ``k`` (``D_bk`` its
    column of ``D_b``, projected on the chromatic plane; zero without floors), so that
    ``sum_k tau_k^2 mean_b |D_bk|^2 = mean_b tr F_b`` and each direction alone moves the
    mean part by its floor over ``sqrt(K)``, whatever the directions' units (the statistic
    does not depend on them, and neither does its null: one ``tau^2`` for all would hand
    the floors' draw to the directions of the largest reach, as on an sRGB film whose red
    share crosses zero, where the red channel's directions are 10^7 times the others' in size):
    the test asks for a change of the response beyond its stated errors and beyond what
    the floors allow. With ``L L^T = Sigma``, ``z = L^-1 m``
    and ``X = L^-1 [N, D]``, the statistic is the part of ``|z|^2`` that the columns of
    ``D`` explain beyond those of ``N``, ``|Q_D^T z|^2`` with ``Q_D`` an orthonormal basis
    of ``L^-1 D``'s part orthogonal to ``L^-1 N``: the score ``D'^T Sigma^-1 m`` in the
    inverse of its information, a chi^2 law with as many degrees of freedom as ``Q_D``
    has columns (Mardia, Kent & Bibby, 1979, thm. 2.5.2). None without directions."""
    from scipy.linalg import block_diag, cholesky, solve_triangular
    from scipy.special import chdtri

    if any(c.score is None for c in cells):
        return None
    m = np.concatenate([c.mean for c in cells])
    sigma = block_diag(*[kappa * c.noise + c.floor for c in cells])
    if shared:
        g = np.concatenate([c.jac for c in cells])
        sigma = sigma + g @ g.T
    dirs = np.concatenate([c.score[0] for c in cells])
    reach = np.mean([np.sum(c.score[0] ** 2, axis=0) for c in cells], axis=0)  # mean_b |D_bk|^2 per direction
    moved = reach > 0
    if moved.any():  # the floors' shared draw along the directions, evenly over those that move the hue
        tau2 = np.where(moved, np.mean([np.trace(c.floors) for c in cells]) / (moved.sum() * np.where(moved, reach, 1.0)),
                        0.0)
        sigma = sigma + (dirs * tau2) @ dirs.T
    low = cholesky(sigma, lower=True)
    z = solve_triangular(low, m, lower=True)
    nuis = solve_triangular(low, np.concatenate([c.score[1] for c in cells]), lower=True)
    dirs = solve_triangular(low, dirs, lower=True)

    def unit(a):  # the columns scaled to unit norm, empty ones left out
        norm = np.linalg.norm(a, axis=0)
        return a[:, norm > 0] / norm[norm > 0]

    def basis(a):  # orthonormal columns spanning a's (unit columns: SCORE_RCOND bounds their conditioning)
        if a.shape[1] == 0:
            return a
        u, sv, _ = np.linalg.svd(a, full_matrices=False)
        return u[:, sv > SCORE_RCOND]

    qn = basis(unit(nuis))
    dirs = unit(dirs)
    qd = basis(dirs - qn @ (qn.T @ dirs))
    dof = qd.shape[1]
    if dof == 0:
        return None
    stat = float(np.sum((qd.T @ z) ** 2))
    thr = float(chdtri(dof, false_alarm)) / dof
    rel = [float(np.linalg.norm(c.mean)) / c.bright for c in cells]
    return ColourCheck(bool(stat / dof <= thr), stat / dof, thr, len(cells), float(np.sqrt(np.mean(np.square(rel)))),
                       kappa, shared, "response", dof)


def _planes(c: np.ndarray) -> np.ndarray:
    """(N, 2, 3): :func:`_plane` of each row of ``c`` (N, 3), not necessarily unit."""
    c = c / np.linalg.norm(c, axis=-1, keepdims=True)
    a = np.eye(3)[np.argmin(np.abs(c), axis=-1)]
    u = np.cross(c, a)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return np.stack([u, np.cross(c, u)], axis=-2)


def neighbour_scale(photo: np.ndarray, render: np.ndarray, var: np.ndarray, use: np.ndarray) -> float:
    """The photo's chromatic noise over the noise model's, from differences between
    neighbouring pixels: at every tested pixel whose four neighbours are tested too,
    ``d = e - mean(e of the 4 neighbours)`` (``e = photo - render``), projected on the
    plane orthogonal to the pixel's rendered colour; the sum of ``|P d|^2`` over the sum
    of its variance under the model, ``tr P (v + sum_4 v_j / 16) P^T``. A hue error that
    varies smoothly over a few pixels (a wrong response's, which follows the film's
    thickness) cancels in ``d`` to first order, noise does not: 1 when the noise is the
    model's and independent between pixels, more for a noisier photo, less for noise that
    neighbours share (which ``d`` partly cancels: 0.3 when each 2 x 2 block shares one
    draw) or a pessimistic model. 0 with fewer than 20 such pixels."""
    inner = np.zeros_like(use)
    inner[1:-1, 1:-1] = use[1:-1, 1:-1] & use[:-2, 1:-1] & use[2:, 1:-1] & use[1:-1, :-2] & use[1:-1, 2:]
    ys, xs = np.nonzero(inner)
    if ys.size < 20:
        return 0.0
    e = photo - render
    d = e[ys, xs] - 0.25 * (e[ys - 1, xs] + e[ys + 1, xs] + e[ys, xs - 1] + e[ys, xs + 1])
    vd = var[ys, xs] + (var[ys - 1, xs] + var[ys + 1, xs] + var[ys, xs - 1] + var[ys, xs + 1]) / 16.0
    p = _planes(render[ys, xs])
    return float(np.sum(np.einsum("nij,nj->ni", p, d) ** 2) / np.sum(np.einsum("nij,nj,nij->n", p, vd, p)))


#: Below this :func:`neighbour_scale`, neighbouring pixels are taken to share noise and the
#: noise scale is measured on 2 x 2 block means (:func:`_block_scale`): noise drawn once per
#: 2 x 2 block reads 0.3 (``(1/4 + 1/8) / (1 + 1/4)``, closed form), independent noise 1,
#: and the right-camera 48 px films of experiments/colour_check_null.py, whose noise model
#: (``NoiseSettings``) is more pessimistic than their noise, 0.82-1.07. A hue error that
#: varies over a few pixels raises both measures, so the block means, which a wrong
#: response's error on a draining film inflates (noise scale 3.6-4.1), are not read for a
#: photo whose neighbours differ as independent pixels do.
SHARED_BELOW = 0.6


def noise_scale(photo, render, var, use, white) -> float:
    """``kappa``: the factor, at least 1, on the noise model's variance of a cell's mean:
    :func:`neighbour_scale`, or :func:`_block_scale` of the whitened residual ``white``
    where the neighbour scale is under :data:`SHARED_BELOW` (neighbours share noise)."""
    near = neighbour_scale(photo, render, var, use)
    return max(1.0, near, _block_scale(white) if near < SHARED_BELOW else 0.0)


def _block_scale(white: np.ndarray, k: int = 2) -> float:
    """``k^2`` times the mean square of the means of ``k x k`` blocks of ``white`` (the
    chromatic residual about each cell's plane, over its noise model's sigma, NaN off the
    tested pixels), pooled over every whole block: 1 when the noise is the model's and
    independent between pixels, more when neighbours share it (JPEG's 4:2:0 chroma
    subsampling keeps one chroma sample per 2 x 2 pixels); 0 with fewer than 20 whole
    blocks."""
    h, w = (white.shape[0] // k) * k, (white.shape[1] // k) * k
    blocks = white[:h, :w].reshape(h // k, k, w // k, k, 2)
    whole = np.all(np.isfinite(blocks), axis=(1, 3, 4))
    if whole.sum() < 20:
        return 0.0
    return k * k * float(np.mean(blocks.mean(axis=(1, 3))[whole] ** 2))


#: Roughness below which the film counts as a mirror for :func:`microfacet_offsets`: Ward's
#: and GGX's visible facets (the same density ``1 / (pi a^2)`` at the mirror direction) differ
#: in ``w_i . h`` at second order in ``a``, and ``a^2`` here is 2^-24, the float32 render's
#: rounding, so the two renders could not differ: no extra render, no term.
FACET_MIRROR = 2.0**-12

#: Ward widths of the GGX lobe's scale mixture in :func:`microfacet_offsets`
#: (:func:`~bubblefit.optics.brdf.ggx_ward_widths`).
GGX_LOBE_WIDTHS = 6


def microfacet_offsets(params, lev, env, base: np.ndarray) -> np.ndarray | None:
    """The Type B offsets of the microfacet distribution (module docstring) per pixel of the
    level ``lev`` (:class:`~bubblefit.inverse._observation.Level`) at the fitted render
    parameters ``params``, two sources (2, H, W, 3), each less ``base``, the fit's render
    there (Ward's lobe of width ``a`` = the fitted roughness, the clamped film averaged over
    its visible facets):

    * the facets: the render with the clamped film averaged over GGX's visible facets
      (:attr:`~bubblefit.model.render.RenderConfig.facets` ``"ggx"``) of width ``alpha =
      a``, the width at which the two slope laws have the same density at the mirror
      direction (one render);
    * the lobe: GGX's lobe of width ``a`` as the mean of the model's renders at the Ward
      widths of its Gaussian scale mixture (:func:`~bubblefit.optics.brdf.ggx_ward_widths`,
      :data:`GGX_LOBE_WIDTHS` renders, one program: the render is linear in the lobe; each
      width's film over its own facets).

    A nuisance the fit does not free: Blender Cycles draws GGX's lobe and facets, the
    paper's lobe is Ward's (eq. 1), a real film's roughness is neither. None where the
    model does not average the film over facets (the spectral film, the paper model) or
    the film is a mirror (roughness under :data:`FACET_MIRROR`): no render is made. The
    term has no constant of its own; it was built because the development case
    cyc_const700_sunset_ortho_rough (a Cycles render of a rough 700 nm film, fitted right)
    failed the check without it (experiments/validation/split.toml;
    docs/validation-split.md)."""
    from dataclasses import replace as swap

    from ..optics.brdf import ggx_ward_widths
    from ._programs import render_bubble

    cfg = lev.cfg
    if cfg.film_rgb != "clamped" or cfg.effects.model != "physical":
        return None
    a = float(np.asarray(params.roughness))
    if not a > FACET_MIRROR:
        return None
    base = np.asarray(base, np.float64)
    facets = np.asarray(render_bubble(params, swap(lev, cfg=swap(cfg, facets="ggx")), env), np.float64)
    lobe = np.mean([np.asarray(render_bubble(swap(params, roughness=np.asarray(w, np.float32)), lev, env), np.float64)
                    for w in ggx_ward_widths(a, GGX_LOBE_WIDTHS)], axis=0)
    return np.stack([facets - base, lobe - base])


def judge_colours(ok: bool, warnings: list, photo, render, mask, cos, sigma, model_error: float = 0.0,
                  explained: bool = True, decide: bool = True, response_jac=None,
                  thickness=None, n_film: float | None = None, score_jac=None,
                  offset: np.ndarray | None = None) -> tuple[bool, list, dict | None]:
    """The fit's verdict with the colour test added: ``(ok, warnings, record)``. The test
    (:func:`colour_check`) runs over the fitted pixels ``mask`` whose front film's ``cos``
    (cosine of incidence) exceeds :data:`INNER_COS`, with the fit's noise ``sigma`` and
    model-error floor ``model_error`` (for its outliers); colours it finds inconsistent
    add the warning of :meth:`ColourCheck.warning` (worded for a photo the model does not
    ``explained`` as a whole, as the verdict found) and, with ``decide`` true
    (``JudgeSettings.colour_check == "decide"``), make the fit not ``ok``. ``response_jac``:
    the calibrated response's own errors (:func:`colour_check`); ``thickness`` (nm, a value
    or a per-pixel map) and ``n_film``: the fitted film, whose optical path ``2 n d cos t``
    (:func:`~bubblefit.optics.film.optical_path`) at each pixel's ``cos`` splits the cells
    (:data:`PATH_BIN`; None: not split). ``score_jac``: the score test's directions and
    nuisances (:func:`bubblefit.inverse.response_error.response_score_cells`; None: no score
    test), one more member of :func:`colour_check`'s union. ``offset``: the Type B offsets
    per pixel (:func:`microfacet_offsets`; None: none)."""
    path = None
    if thickness is not None and n_film is not None:
        path = np.asarray(optical_path(np.asarray(thickness, np.float64), float(n_film),
                                       np.clip(np.asarray(cos, np.float64), 0.0, 1.0)))
    check = colour_check(photo, render, np.asarray(mask, bool) & (np.asarray(cos) > INNER_COS), sigma,
                         model_error=model_error, response_jac=response_jac, path=path, pooled=True, score_jac=score_jac,
                         offset=offset)
    if check is None:
        return ok, warnings, None
    why = check.warning(explained)
    if why is None:
        return ok, warnings, check.to_json(decide)
    if not decide:
        return ok, warnings + [why + " [warning only: --colour-check warn]"], check.to_json(decide)
    return False, warnings + [why], check.to_json(decide)
