"""How far a calibrated camera response's own errors move a fitted photo's colours.

A response CSV from ``bubblefit calibrate-camera`` states its errors as modes of each
channel's covariance between rows (:func:`bubblefit.optics.spectral.response_error_modes`;
a CSV with per-row errors only states independent rows). The colour check
(:mod:`bubblefit.inverse.colour_check`) asks whether the stated response can produce the
photo's hues; a response known only to within its errors can produce any hue those errors
reach, so the check's null hypothesis holds their covariance too. It is propagated
linearly (the first-order, "delta method" law of propagation of uncertainty: JCGM 100:2008,
GUM, section 5.1.2):

- the response of channel ``k`` is linear between the CSV's rows ``lambda_j``:
  ``rho_k(lambda) = sum_j x_kj H_j(lambda)`` with hat functions ``H_j``; the rows' errors
  have the covariance ``C_k = sum_m u_km u_km^T`` (the CSV's modes ``u_km``), and the
  channels are independent (each channel is fitted alone);
- a film of Airy reflectance ``R(lambda)`` (Born & Wolf eq. 7.6(13), the fit's own
  :func:`bubblefit.optics.film.airy_reflectance`, both polarisations averaged, at the
  pixel's fitted thickness and angle) seen through the white-balanced response reflects
  ``f_k = sum_l w_k R / sum_l w_k`` of the light, ``w_k = rho_k I`` with the lamp ``I``
  (the fit's white balance divides by the flat spectrum's ``sum_l w_k``), so
  ``d f_k / d x_kj = sum_l H_j I (R - f_k) / sum_l w_k``;
- the paper's model (eq. 11) renders a pixel as the light the film reflects plus the
  background it transmits, ``y_k = E_k f_k + B_k (1 - f_k)``: linear in ``f_k``, so
  ``d y_k / d f_k = E_k - B_k = (y_k - B_k) / f_k``, with ``y`` the fit's render and ``B``
  the background photo (zero without one, which overstates the response's share where
  the map's light is seen through the film: the check is then more lenient).

A pixel's render moves by ``d y_k / d x_k u_km`` per mode (:meth:`ResponseError.jacobian`);
a cell's mean render by the mean of that over its pixels, ``J_b`` (:meth:`ResponseError.cell_jacobian`).
It does not average down over pixels, and every cell shares the same mode coefficients: the
colour check's null holds one draw of them for the whole photo
(:func:`bubblefit.inverse.colour_check.colour_check`).

The same derivatives give the response's share of the fitted parameters' covariance
(:func:`response_gram`): a change ``dy`` of the render at fixed parameters moves the
least-squares optimum by ``dz = -(J^T J)^-1 J^T W dy`` (``J`` the Jacobian of the whitened
residual, ``W`` the whitening ``1 / sigma``), so the response's errors add
``(J^T J)^-1 [sum_m (J^T W dy_m)(J^T W dy_m)^T] (J^T J)^-1`` to the parameters' covariance
(the delta method for an input of known covariance, GUM sec. 5.1.2, with the fit's
solution as the measurement function). Unlike a pixel's noise it does not average down
over the film.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["ResponseError", "response_error", "response_cells", "response_perturbation", "response_score_cells", "tabulated_terms", "response_gram", "solve_response_gram", "marginal_chi2",
           "solve_marginal_chi2", "pixel_thickness_stderr", "pixel_thickness_shifts", "MAX_PIXELS"]

#: Pixels per cell the mean Jacobian is taken over (evenly strided): the Jacobian follows
#: the fitted thickness, smooth over a cell, so a subsample gives its mean (and bounds the
#: work on large photos).
MAX_PIXELS = 400


@dataclass(frozen=True)
class ResponseError:
    """A response's stated errors on its rows, ready to propagate (module docstring):
    ``hats`` (G, L) ``H_j(lambda) I(lambda)`` on the fine grid, ``density`` (G, 3)
    ``w_k = rho_k I``, ``modes`` (L, 3, M) the modes of each channel's covariance between
    rows, ``wavelengths`` (G,) nm and the film's index ``n_film``."""

    wavelengths: np.ndarray
    hats: np.ndarray
    density: np.ndarray
    modes: np.ndarray
    n_film: float

    def reflectance(self, thickness: np.ndarray, cos: np.ndarray) -> np.ndarray:
        """(n, G) the Airy reflectance of a film in air (Born & Wolf eq. 7.6(13), both
        polarisations averaged) of ``thickness`` (n,) nm seen at ``cos`` (n,), on the grid."""
        both = np.asarray(_airy()(np.asarray(thickness, np.float64)[:, None], self.wavelengths[None, :],
                                  self.n_film, np.asarray(cos, np.float64)[:, None]))
        return (both[..., 0] + both[..., 1]) / 2  # their mean (numpy's strided mean over the pair is slow)

    def shares(self, refl: np.ndarray) -> np.ndarray:
        """(n, 3) ``f_k = sum_l w_k R / sum_l w_k``: the reflected share per channel of a
        reflectance ``refl`` (n, G) on the grid (module docstring)."""
        return np.asarray(refl, np.float64) @ self.density / self.density.sum(axis=0)

    def moves(self) -> np.ndarray:
        """(G, 3, M) each mode's change of ``w_k = rho_k I`` on the grid (module docstring)."""
        return np.einsum("gl,lcm->gcm", self.hats, self.modes)

    def spectral_terms(self, refl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(f, fm)``: the linear functionals of a reflectance ``refl`` (n, G) that
        :meth:`jacobian` reads: the shares ``f`` (n, 3) of :meth:`shares` and
        ``fm = sum_l R move_kml`` (n, 3, M) over the grid, with ``move`` of :meth:`moves`."""
        refl = np.asarray(refl, np.float64)
        return self.shares(refl), np.einsum("ng,gcm->ncm", refl, self.moves())

    def share_slope(self, thickness: np.ndarray, reflectance) -> np.ndarray:
        """(n, 3) ``df / dd``: the shares of :meth:`shares` per nm of the film's thickness,
        their central difference over :data:`THICKNESS_STEP_NM` of the reflectance
        ``reflectance(d)`` (n, G) at thicknesses ``d`` (n,) nm."""
        d = np.asarray(thickness, np.float64)
        return (self.shares(reflectance(d + THICKNESS_STEP_NM)) - self.shares(reflectance(d - THICKNESS_STEP_NM))) / (
            2 * THICKNESS_STEP_NM)

    def jacobian(self, render: np.ndarray, background: np.ndarray | None, thickness: np.ndarray,
                 cos: np.ndarray, refl: np.ndarray | None = None, terms=None) -> np.ndarray:
        """(n, 3, M): each pixel's change of its render ``(n, 3)`` along each error mode of
        each channel's response (one standard deviation), at the pixel's film ``thickness``
        (n,) nm seen at ``cos`` (n,) (cosine of incidence); ``refl`` (n, G): the film's
        reflectance on the grid where it is not a film in air (:meth:`reflectance`), e.g. a
        film on a substrate; ``terms``: its :meth:`spectral_terms` where the caller holds
        them (then ``refl`` is not read)."""
        if terms is None:
            refl = self.reflectance(thickness, cos) if refl is None else refl
            terms = self.spectral_terms(refl)
        f, fm = terms                                            # (n, 3) the film's reflected share per channel
        total = self.density.sum(axis=0)                         # (3,)
        dfdx = (fm - f[:, :, None] * self.moves().sum(axis=0)[None]) / total[None, :, None]
        bg = 0.0 if background is None else np.asarray(background, np.float64)
        dydf = (np.asarray(render, np.float64) - bg) / np.maximum(f, 1e-9)
        return dydf[:, :, None] * dfdx

    def thickness_slope(self, render, background, thickness, cos, reflectance=None, at=None, terms=None) -> np.ndarray:
        """(n, 3) ``dy / dd``: each pixel's change of its render per nm of its film's
        thickness, ``(dy / df) (df / dd)`` (module docstring; ``df / dd`` of
        :meth:`share_slope`), at ``thickness`` (n,) nm seen at ``cos`` (n,);
        ``reflectance(d)``: the film's reflectance (n, G) at thicknesses ``d`` where it is
        not a film in air (default: :meth:`reflectance`); ``at``: that reflectance at
        ``thickness`` where the caller already holds it; ``terms``: ``(f, df / dd)`` where
        the caller holds them (then neither is read)."""
        if terms is None:
            d = np.asarray(thickness, np.float64)
            refl = (lambda x: self.reflectance(x, cos)) if reflectance is None else reflectance
            terms = self.shares(refl(d) if at is None else at), self.share_slope(d, refl)
        f, dfdd = terms
        bg = 0.0 if background is None else np.asarray(background, np.float64)
        return (np.asarray(render, np.float64) - bg) / np.maximum(f, 1e-9) * dfdd

    def cell_jacobian(self, render, background, thickness, cos) -> np.ndarray:
        """(3, 3 M): how a cell's mean render moves per unit of each channel's mode
        coefficients (channel ``k``'s modes in columns ``k M`` to ``(k + 1) M``; they move
        channel ``k`` only), over the cell's pixels (at most :data:`MAX_PIXELS` of them,
        evenly strided). Its outer product is the cell's covariance from the response."""
        good = np.nonzero(np.isfinite(np.asarray(thickness, np.float64)))[0]
        m = self.modes.shape[-1]
        out = np.zeros((3, 3 * m))
        if good.size == 0:
            return out
        take = good if good.size <= MAX_PIXELS else good[np.linspace(0, good.size - 1, MAX_PIXELS).astype(int)]
        bg = None if background is None else np.asarray(background)[take]
        jac = self.jacobian(np.asarray(render)[take], bg, np.asarray(thickness)[take], np.asarray(cos)[take]).mean(axis=0)
        for k in range(3):
            out[k, k * m:(k + 1) * m] = jac[k]
        return out


@functools.cache
def _airy():
    """:func:`bubblefit.optics.film.airy_reflectance`, compiled (one program per cell size;
    eagerly each of its operations compiled on its own, again for every cell size)."""
    import jax

    from ..optics.film import airy_reflectance

    return jax.jit(airy_reflectance)


def response_error(response: str, illuminant: str, n_film: float) -> ResponseError | None:
    """The :class:`ResponseError` of ``response`` (a CSV with ``r_err,g_err,b_err``
    columns, and its covariance's modes where it holds them) under ``illuminant``, for a film of index ``n_film``; None when the response
    states no errors (a named camera, sRGB, a CSV without them: taken as exact). Kept per
    file name, as :func:`~bubblefit.optics.spectral.response_functions` keeps the response
    itself: a fit reads it for its error bars and again for its colour check."""
    return _response_error(str(response), str(illuminant), float(n_film))


@functools.lru_cache(maxsize=8)
def _response_error(response: str, illuminant: str, n_film: float) -> ResponseError | None:
    """:func:`response_error`, kept per file name, illuminant and index."""
    from ..optics.spectral import (LAMBDA_MAX, LAMBDA_MIN, TABLE_GRID, channel_density, illuminant_spectrum,
                                   response_error_modes)

    stated = response_error_modes(response)
    if stated is None:
        return None
    rows, modes = stated
    inside = (TABLE_GRID >= LAMBDA_MIN) & (TABLE_GRID <= LAMBDA_MAX)
    lam = TABLE_GRID[inside]
    lamp = illuminant_spectrum(illuminant)[inside]
    hats = np.stack([np.interp(lam, rows, np.eye(len(rows))[j], left=0.0, right=0.0) for j in range(len(rows))],
                    axis=1) * lamp[:, None]
    return ResponseError(lam, hats, channel_density(illuminant, response)[inside], np.asarray(modes, np.float64),
                         float(n_film))


def response_cells(response: str, illuminant: str, n_film: float, render: np.ndarray, background: np.ndarray | None,
                   thickness: np.ndarray, cos: np.ndarray):
    """For the colour check (:func:`bubblefit.inverse.colour_check.colour_check`'s
    ``response_jac``): a function of a cell's pixel rows and columns giving the (3, 3 M)
    change of its mean render per unit of the response's mode coefficients
    (:meth:`ResponseError.cell_jacobian`; the coefficients are shared by every cell), over
    images ``render``, ``background`` (None: none given), ``thickness`` (nm) and ``cos``;
    None when the response states no errors."""
    err = response_error(response, illuminant, n_film)
    if err is None:
        return None
    thickness = np.broadcast_to(np.asarray(thickness, np.float64), np.shape(render)[:2])

    def jac(ys, xs):
        bg = None if background is None else np.asarray(background, np.float64)[ys, xs]
        return err.cell_jacobian(np.asarray(render)[ys, xs], bg, thickness[ys, xs], np.asarray(cos)[ys, xs])

    return jac


#: Highest degree of the Legendre polynomials in wavelength (over 380-780 nm) by which the
#: colour check's score test (:func:`response_score_cells`) lets each channel's response
#: change, relative to itself: degrees 1 to this (degree 0, the channel's scale, the white
#: balance takes back), three channels, so ``3 * SCORE_DEGREE`` directions.
SCORE_DEGREE = 4


def response_perturbation(response: str, illuminant: str, n_film: float, degree: int = SCORE_DEGREE) -> ResponseError:
    """A :class:`ResponseError` whose "modes" are smooth relative changes of ``response``:
    channel ``k``'s response ``rho_k(lambda)`` times the Legendre polynomial ``P_m(x)``,
    ``x = (2 lambda - 780 - 380) / (780 - 380)``, ``m = 1 .. degree`` (Abramowitz & Stegun
    22.2.10), on the fine grid (its rows are the grid's own samples, so its hat functions
    are the lamp alone); for :func:`response_score_cells`. Any response (a named camera,
    sRGB, a CSV with or without errors)."""
    from numpy.polynomial import legendre

    from ..optics.spectral import (LAMBDA_MAX, LAMBDA_MIN, TABLE_GRID, channel_density, illuminant_spectrum,
                                   response_functions)

    inside = (TABLE_GRID >= LAMBDA_MIN) & (TABLE_GRID <= LAMBDA_MAX)
    lam = TABLE_GRID[inside]
    x = (2.0 * lam - LAMBDA_MAX - LAMBDA_MIN) / (LAMBDA_MAX - LAMBDA_MIN)
    poly = np.stack([legendre.legval(x, np.eye(degree + 1)[m]) for m in range(1, degree + 1)], axis=-1)  # (G, K)
    rho = response_functions(response)[inside]                                                          # (G, 3)
    return ResponseError(lam, np.diag(illuminant_spectrum(illuminant)[inside]), channel_density(illuminant, response)[inside],
                         rho[:, :, None] * poly[:, None, :], float(n_film))


def response_score_cells(response: str, illuminant: str, n_film: float, render: np.ndarray,
                         background: np.ndarray | None, thickness: np.ndarray, cos: np.ndarray,
                         degree: int = SCORE_DEGREE, nuisance: np.ndarray | None = None):
    """For the colour check's score test (:func:`bubblefit.inverse.colour_check.colour_check`'s
    ``score_jac``): a function of pixel rows and columns (n,) giving ``(D, N)``: ``D``
    (n, 3, 3 ``degree``) each pixel's change of its render per unit of each smooth relative
    change of the response (:func:`response_perturbation`, through
    :meth:`ResponseError.jacobian`; channel ``k``'s changes in columns ``k degree`` to
    ``(k + 1) degree``, moving channel ``k`` only), and ``N`` (n, 3, P) per unit of the
    nuisances the fit adjusts in the hue, through the film's thickness: the thickness slope
    (:meth:`ResponseError.thickness_slope`) times the thickness's change per unit of each.
    ``nuisance`` (h, w, P): that change at each pixel, e.g. a drainage profile's per unit of
    its free parameters (:func:`bubblefit.model.thickness.drainage_gradient` at the pixel's
    height); None: 1, ``v`` and ``v^2`` with ``v`` the pixel's row from the image's middle
    over half its height (a constant film, and to second order a profile in height). Over
    images ``render``, ``background`` (None: none), ``thickness`` (nm) and ``cos``; the
    film's spectral terms interpolated from :func:`tabulated_terms`."""
    err = response_perturbation(response, illuminant, n_film, degree)
    h = np.shape(render)[0]
    nuisance = None if nuisance is None else np.asarray(nuisance, np.float64)
    thickness = np.broadcast_to(np.asarray(thickness, np.float64), np.shape(render)[:2])
    render = np.asarray(render, np.float64)
    cos = np.asarray(cos, np.float64)

    def jac(ys, xs):
        bg = None if background is None else np.asarray(background, np.float64)[ys, xs]
        d, c, r = thickness[ys, xs], cos[ys, xs], render[ys, xs]
        f, fm, dfdd = tabulated_terms(err, d, c)
        move = err.jacobian(r, bg, d, c, terms=(f, fm))                      # (n, 3, degree)
        dirs = np.zeros((np.size(ys), 3, 3 * degree))
        for k in range(3):
            dirs[:, k, k * degree:(k + 1) * degree] = move[:, k]
        v = ((ys - 0.5 * (h - 1)) / (0.5 * h))[:, None, None] ** np.arange(3) if nuisance is None else \
            nuisance[ys, xs][:, None, :]
        nuis = err.thickness_slope(r, bg, d, c, terms=(f, dfdd))[:, :, None] * v
        return np.nan_to_num(dirs), np.nan_to_num(nuis)

    return jac


#: Steps of :func:`tabulated_terms`' table: in the optical path ``x = 2 n d cos t`` (nm)
#: and in the cosine of incidence. A film's reflectance depends on ``x`` through the phase
#: ``2 pi x / lambda`` (eq. 8) and on the cosine, at a fixed path, only through the Fresnel
#: reflectances ``R1`` (Born & Wolf eq. 1.5(21a)). Cubic (four-point Lagrange)
#: interpolation errs by at most ``max|omega| h^4 / 4! max|F^(4)|`` (Abramowitz & Stegun
#: 25.2.2; ``max|omega|`` = 9/16 on a middle interval, 1.0 on an end one). Along the path
#: ``|F^(4)| <= (2 pi / lambda_min)^4 a_4 A``, ``A`` the fringes' amplitude and ``a_4 =
#: sum_j j^4 q^(j-1)`` over the Airy sum's harmonics, whose ratio ``q = (sqrt(1 + F') - 1) /
#: (sqrt(1 + F') + 1)`` with ``F' = 4 R1 / (1 - R1)^2`` is 0.09 at ``R1 = 0.1`` (the larger
#: Fresnel reflectance at a cosine of 0.6, the colour check's inner limit), so ``a_4 <=
#: 3.4``: at 6 nm, ``h 2 pi / 380 nm = 0.099``, the error is at most 3.4 x 0.099^4 / 24 =
#: 1.4e-5 of ``A``. Along the cosine, over ``[0.6, 1]`` and indices 1.33-1.5, ``|d^4 R1 /
#: d cos^4| <= 39`` (both polarisations, differenced on a 1e-3 grid) and ``dR / dR1 <= 4 (1 +
#: R1) / (1 - R1)^3 <= 5.5``, so ``|F^(4)| <~ 210`` and at 0.025 the error is at most 210 x
#: 0.025^4 / 24 = 3.4e-6 of the reflectance: below float32's rounding of the direct
#: evaluation's thickness slope (its central difference over 1 nm loses four digits).
#: tests/test_response_error.py checks the table against the direct evaluation.
TABLE_PATH_STEP_NM = 6.0
TABLE_COS_STEP = 0.025


def _cubic_stencil(x: np.ndarray, lo: float, step: float, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``(first, weights)``: the first of the four nodes ``lo + i step`` (``i < count``) whose
    cubic Lagrange polynomial interpolates at ``x`` (n,) (the interval's own two and one on
    each side; at the ends the four end nodes), and their (n, 4) weights (Abramowitz &
    Stegun 25.2.13). One node: weight 1."""
    if count == 1:
        return np.zeros(x.shape, np.int64), np.ones(x.shape + (1,))
    first = np.clip(np.floor((x - lo) / step).astype(np.int64) - 1, 0, count - 4)
    t = (x - lo) / step - first                            # in [0, 3]: the nodes at 0, 1, 2, 3
    return first, np.stack([-(t - 1) * (t - 2) * (t - 3) / 6, t * (t - 2) * (t - 3) / 2,
                            -t * (t - 1) * (t - 3) / 2, t * (t - 1) * (t - 2) / 6], axis=-1)


def _axis(x: np.ndarray, step: float) -> tuple[float, float, int]:
    """``(lo, step, count)``: evenly spaced nodes over ``x``'s range at most ``step`` apart,
    at least four of them (one where the range is a point)."""
    lo, hi = float(x.min()), float(x.max())
    if hi <= lo:
        return lo, 1.0, 1
    count = max(4, int(np.ceil((hi - lo) / step)) + 1)
    return lo, (hi - lo) / (count - 1), count


@functools.cache
def _path_program():
    """:func:`bubblefit.optics.film.optical_path`, compiled (one program for every block)."""
    import jax

    from ..optics.film import optical_path

    return jax.jit(optical_path)


def _optical_path(thickness: np.ndarray, n_film: float, cos: np.ndarray) -> np.ndarray:
    """(n,) :func:`bubblefit.optics.film.optical_path` of films ``thickness`` (n,) nm seen at
    ``cos`` (n,), in blocks of :data:`_GRAM_BLOCK` (the last one padded: one compiled shape
    for every photo, where the eager operations would each compile for every length)."""
    out = np.empty(np.size(thickness))
    for rows, i, keep in _padded_blocks(out.size):
        out[rows] = np.asarray(_path_program()(thickness[i], n_film, cos[i]))[keep]
    return out


def _padded_blocks(n: int):
    """Yields ``(rows, index, keep)`` over ``n`` items in blocks of :data:`_GRAM_BLOCK`:
    the block's slice of the output, its item indices with the last block padded by its
    last item (one compiled shape for every length), and the slice of a block's result
    that holds real items."""
    for lo in range(0, n, _GRAM_BLOCK):
        yield (slice(lo, lo + _GRAM_BLOCK), np.arange(lo, lo + _GRAM_BLOCK).clip(max=n - 1),
               slice(0, min(_GRAM_BLOCK, n - lo)))


def tabulated_terms(err: ResponseError, thickness: np.ndarray, cos: np.ndarray):
    """``(f, fm, df / dd)`` at pixels of film ``thickness`` (n,) nm seen at ``cos`` (n,): the
    film-in-air reflectance's (:meth:`ResponseError.reflectance`) linear functionals of
    :meth:`ResponseError.spectral_terms` and :meth:`ResponseError.share_slope`, evaluated
    on the nodes of a table in the optical path (:func:`bubblefit.optics.film.optical_path`)
    and the cosine (:data:`TABLE_PATH_STEP_NM`, :data:`TABLE_COS_STEP`; only the nodes
    some pixel's stencil reads) and interpolated to each pixel (:func:`_cubic_stencil`;
    linear in the reflectance, so each term's interpolation is that of its reflectance).
    Where the table would hold as many nodes as there are pixels, they are evaluated at the
    pixels. In float64 (a node's rounding, unlike a pixel's, does not average out over a
    cell), in blocks of :data:`_GRAM_BLOCK`, the last one padded (one compiled shape for
    every photo). NaN where the thickness is not finite."""
    import jax

    d = np.asarray(thickness, np.float64)
    c = np.asarray(cos, np.float64)
    n = d.size
    good = np.isfinite(d) & np.isfinite(c)
    m = err.modes.shape[-1]
    out = np.full((n, 3 + 3 * m + 3), np.nan)
    if not good.any():
        return out[:, :3], out[:, 3:3 + 3 * m].reshape(n, 3, m), out[:, 3 + 3 * m:]
    with jax.enable_x64(True):  # in float64: a node's rounding is shared by every pixel it serves
        x = _optical_path(d[good], err.n_film, c[good])
        px, pc = _axis(x, TABLE_PATH_STEP_NM), _axis(c[good], TABLE_COS_STEP)
        fx, wx = _cubic_stencil(x, *px)
        fc, wc = _cubic_stencil(c[good], *pc)
        kx, kc = wx.shape[1], wc.shape[1]
        node = (fx[:, None, None] + np.arange(kx)[None, :, None]) * pc[2] + fc[:, None, None] + np.arange(kc)
        mark = np.zeros(px[2] * pc[2], bool)
        mark[node.reshape(-1)] = True
        used = np.flatnonzero(mark)
        tabled = used.size < good.sum()
        if tabled:
            nc = pc[0] + pc[1] * (used % pc[2])
            nd = (px[0] + px[1] * (used // pc[2])) / _optical_path(np.ones_like(nc), err.n_film, nc)  # path per nm
        else:
            nc, nd = c[good], d[good]
        values = np.empty((nd.size, out.shape[1]))
        for rows, i, keep in _padded_blocks(nd.size):  # the last block padded with its last node
            refl = lambda t: err.reflectance(t, nc[i])  # noqa: E731
            f, fm = err.spectral_terms(refl(nd[i]))
            values[rows] = np.concatenate([f, fm.reshape(-1, 3 * m), err.share_slope(nd[i], refl)],
                                           axis=1)[keep]
    if tabled:
        table = np.zeros((mark.size, out.shape[1]))
        table[used] = values
        values = np.zeros((node.shape[0], out.shape[1]))
        for j in range(kx):
            for k in range(kc):
                values += (wx[:, j] * wc[:, k])[:, None] * table[node[:, j, k]]
    out[good] = values
    return out[:, :3], out[:, 3:3 + 3 * m].reshape(n, 3, m), out[:, 3 + 3 * m:]


#: Pixels per block of :func:`response_gram` (bounds its memory: a block holds its pixels'
#: derivatives along every mode, 3 M floats each).
_GRAM_BLOCK = 2048


#: Half step (nm) of the central difference of a film's channel shares in its thickness
#: (:func:`pixel_thickness_stderr`): the shares change on the scale of a fringe's tenth
#: (about 20 nm), so the difference's truncation error is under 1e-3 of the slope.
THICKNESS_STEP_NM = 0.5


def pixel_thickness_stderr(err: ResponseError | None, render: np.ndarray, background: np.ndarray | None,
                           thickness: np.ndarray, cos: np.ndarray, weight: np.ndarray,
                           reflectance=None) -> np.ndarray | None:
    """(n,) each pixel's thickness standard error from the response's errors alone, the
    pixel's thickness fitted from its own three channels (a per-pixel thickness map): the
    root sum of squares of :func:`pixel_thickness_shifts` over the response's error
    coefficients (arguments as there); None when the response states no errors."""
    shifts = pixel_thickness_shifts(err, render, background, thickness, cos, weight, reflectance)
    return None if shifts is None else np.sqrt(np.sum(shifts[0] ** 2, axis=(1, 2)))


def pixel_thickness_shifts(err: ResponseError | None, render: np.ndarray, background: np.ndarray | None,
                           thickness: np.ndarray, cos: np.ndarray, weight: np.ndarray,
                           reflectance=None) -> tuple[np.ndarray, np.ndarray] | None:
    """``(shifts, jj)``: (n, 3, M) how far each pixel's thickness, fitted from its own three
    channels, moves per unit of each channel's error coefficients, and (n,) ``j^T j``:
    :func:`response_gram`'s sandwich with one parameter per pixel, ``-(j_k W_k dy_km) /
    (j^T j)`` with ``j = W dy / dd`` the whitened render's slope in the thickness
    (``dy / dd = (dy / df) (df / dd)``, the shares ``f`` of :meth:`ResponseError.shares`
    differenced over :data:`THICKNESS_STEP_NM`) and ``dy_km`` channel ``k``'s render change
    along its mode ``m`` (:meth:`ResponseError.jacobian`). A smoothness prior between
    pixels does not narrow it: one draw of the response moves neighbouring pixels alike.
    ``render``, ``background`` (None: none) and ``weight`` (``1 / sigma``) are (n, 3),
    ``thickness`` and ``cos`` (n,); ``reflectance(d)`` gives the film's reflectance (n, G)
    on the response's grid at thicknesses ``d`` (n,) where it is not a film in air (default:
    :meth:`ResponseError.reflectance` at ``cos``). None when the response states no errors.
    A film whose pixels share one thickness moves by their ``j^T j``-weighted mean."""
    if err is None:
        return None
    d = np.asarray(thickness, np.float64)
    cs = np.asarray(cos, np.float64)
    refl = (lambda x: err.reflectance(x, cs)) if reflectance is None else reflectance
    y = np.asarray(render, np.float64)
    wt = np.asarray(weight, np.float64)
    j = wt * err.thickness_slope(y, background, d, cs, refl)                            # (n, 3)
    g = err.jacobian(y, background, d, cs, refl=refl(d)) * wt[:, :, None]              # (n, 3, M)
    jj = np.sum(j * j, axis=1)
    return -j[:, :, None] * g / np.maximum(jj, 1e-300)[:, None, None], jj


def _whitened_modes(err: ResponseError, weight: np.ndarray, render: np.ndarray, background: np.ndarray | None,
                    thickness: np.ndarray, cos: np.ndarray, reflectance=None):
    """Blocks of :data:`_GRAM_BLOCK` fitted pixels (``weight > 0`` in a channel): yields
    ``(index, W dy)``, the flat pixel indices and their whitened render change ``(n, 3, M)``
    along each error mode (:meth:`ResponseError.jacobian` times the whitening ``W = 1 / sigma``),
    over (h, w, 3) ``weight``, ``render``, ``background`` (None: none) and (h, w) ``thickness``
    (nm) and ``cos``: the columns ``G`` that :func:`response_gram` and :func:`marginal_chi2` read.
    ``reflectance(i)``: the film's reflectance (n, G) on the response's grid at the flat
    pixels ``i`` where it is not a film in air (default: :meth:`ResponseError.reflectance`)."""
    h, w = weight.shape[:2]
    pix = np.nonzero(np.any(np.asarray(weight) > 0, axis=-1).ravel())[0]
    flat = lambda a, n: np.asarray(a, np.float64).reshape(h * w, n)  # noqa: E731
    wt, y = flat(weight, 3), flat(render, 3)
    bg = None if background is None else flat(background, 3)
    th = np.broadcast_to(np.asarray(thickness, np.float64), (h, w)).reshape(-1)
    cs = np.broadcast_to(np.asarray(cos, np.float64), (h, w)).reshape(-1)
    for lo in range(0, pix.size, _GRAM_BLOCK):
        i = pix[lo:lo + _GRAM_BLOCK]
        refl = None if reflectance is None else reflectance(i)
        dy = err.jacobian(y[i], None if bg is None else bg[i], th[i], cs[i], refl=refl) * wt[i][:, :, None]
        yield i, np.nan_to_num(dy)


def response_gram(err: ResponseError | None, jac: np.ndarray, weight: np.ndarray, render: np.ndarray,
                  background: np.ndarray | None, thickness: np.ndarray, cos: np.ndarray,
                  reflectance=None) -> np.ndarray | None:
    """(p, p) ``sum_m (J^T W dy_m)(J^T W dy_m)^T`` over the response's error modes ``dy_m``
    (:meth:`ResponseError.jacobian`; module docstring): what the response's errors add to
    the fitted parameters' covariance between two ``(J^T J)^-1``.

    Parameters
    ----------
    err : ResponseError or None
        The response's stated errors (None: exact, and so is the result).
    jac : np.ndarray
        (h w 3, p) the Jacobian of the whitened residual over the level's pixels.
    weight : np.ndarray
        (h, w, 3) the whitening ``1 / sigma`` (0 where not fitted).
    render, background : np.ndarray
        (h, w, 3) the fit's render and the background photo (None: none).
    thickness, cos : np.ndarray
        (h, w) each pixel's film thickness (nm) and cosine of incidence.
    reflectance : callable, optional
        The film's reflectance at flat pixel indices where it is not a film in air
        (:func:`_whitened_modes`).
    """
    if err is None:
        return None
    h, w = weight.shape[:2]
    p = jac.shape[1]
    jr = np.asarray(jac, np.float64).reshape(h * w, 3, p)
    total = np.zeros((p, 3, err.modes.shape[-1]))
    for i, dy in _whitened_modes(err, weight, render, background, thickness, cos, reflectance):
        total += np.einsum("ncp,ncm->pcm", jr[i], dy)
    return np.einsum("pcm,qcm->pq", total, total)


def marginal_chi2(err: ResponseError | None, jac: np.ndarray, resid: np.ndarray, weight: np.ndarray,
                  render: np.ndarray, background: np.ndarray | None, thickness: np.ndarray,
                  cos: np.ndarray, reflectance=None) -> tuple[float, float]:
    """``(chi2, marginal)``: a solve's chi^2 ``r^T r`` and its chi^2 with the response's
    errors marginalised and the fitted parameters re-solved to first order.

    The response's error coefficients ``c`` (unit normal, one draw for the whole photo)
    move the whitened residual by ``G c`` (``G = W dy``, :func:`_whitened_modes`), the
    parameters by ``J dz``; the least ``|r + J dz + G c|^2 + |c|^2`` over both (the
    Gaussian prior on ``c`` integrated out, which for a linear model is its minimum) is
    ``r^T r - b^T A^-1 b`` with ``A = [[J^T J, J^T G], [G^T J, G^T G + I]]`` and
    ``b = [J^T r; G^T r]``: the Gauss-Newton decrement of the joint problem, the same
    normal equations whose response block :func:`response_gram` sandwiches (the
    generalised least squares of ``r`` under the covariance ``I + G G^T``, by the
    Woodbury identity; Press et al., *Numerical Recipes*, 3rd ed., sec. 2.7.3 and 15.4).
    ``jac`` (h w 3, p) and ``resid`` (h w 3,) are the whitened residual's Jacobian and
    plain residual; the other arguments (``reflectance`` too) as :func:`response_gram`'s.
    Without stated errors (``err`` None) the marginal is the decrement over the parameters
    alone."""
    h, w = weight.shape[:2]
    r = np.nan_to_num(np.asarray(resid, np.float64).reshape(h * w, 3))
    jr = np.nan_to_num(np.asarray(jac, np.float64).reshape(h * w, 3, -1))
    p = jr.shape[-1]
    k = 0 if err is None else 3 * err.modes.shape[-1]
    a = np.zeros((p + k, p + k))
    b = np.zeros(p + k)
    a[:p, :p] = np.einsum("ncp,ncq->pq", jr, jr)
    b[:p] = np.einsum("ncp,nc->p", jr, r)
    if err is not None:
        m = err.modes.shape[-1]
        a[p:, p:] = np.eye(k)
        for i, dy in _whitened_modes(err, weight, render, background, thickness, cos, reflectance):
            for c in range(3):  # channel c's modes move channel c only
                cols = slice(p + c * m, p + (c + 1) * m)
                a[:p, cols] += jr[i, c].T @ dy[:, c]
                a[cols, cols] += dy[:, c].T @ dy[:, c]
                b[cols] += dy[:, c].T @ r[i, c]
        a[p:, :p] = a[:p, p:].T
    chi2 = float(np.sum(r * r))
    return chi2, chi2 - float(b @ np.linalg.lstsq(a, b, rcond=None)[0])


def _solve_images(lev, sol, robust_scale: float, thickness_model: str | None = None):
    """``(weight, render, thickness, resid)`` of a solve ``sol`` (a
    :class:`~bubblefit.inverse._local.LocalSolution`) on its level ``lev``: the whitening,
    the render (the photo plus the plain residual), each pixel's thickness (the solve's
    constant film or drainage profile, :func:`bubblefit.model.thickness.drainage_profile`,
    at the pixel's height) and the plain whitened residual (flat); None for a solve with
    neither. ``thickness_model`` (``constant``, ``drainage``, ``map``): which of the two
    the solve fitted (its values hold the other's held start too); None: the constant
    film where the values have one."""
    import jax.numpy as jnp

    from ..model.thickness import drainage_profile
    from ._uncertainty import plain_residual

    v = sol.values
    if "thickness_nm" in v and thickness_model in (None, "constant"):
        thickness = np.full(lev.y.shape[:2], float(v["thickness_nm"]))
    elif all(k in v for k in ("top_nm", "bottom_nm", "exponent")):
        thickness = np.asarray(drainage_profile(jnp.asarray(lev.height), v["top_nm"], v["bottom_nm"], v["exponent"]),
                               np.float64)
    else:
        return None
    weight = np.asarray(lev.w, np.float64)
    resid = plain_residual(sol.residual, robust_scale)
    shaped = resid.reshape(lev.y.shape)
    render = np.asarray(lev.y, np.float64) + np.where(weight > 0, shaped / np.where(weight > 0, weight, 1.0), 0.0)
    return weight, render, thickness, resid


def solve_response_gram(response: str, illuminant: str, n_film: float, lev, sol, robust_scale: float,
                        thickness_model: str | None = None):
    """:func:`response_gram` of a solve ``sol`` (a :class:`~bubblefit.inverse._local.LocalSolution`)
    on its level ``lev`` (:func:`_solve_images`, with its ``thickness_model``); None when
    the response states no errors."""
    err = response_error(response, illuminant, n_film)
    if err is None or sol.jacobian is None or not sol.jacobian.size:
        return None
    images = _solve_images(lev, sol, robust_scale, thickness_model)
    if images is None:
        return None
    weight, render, thickness, _ = images
    return response_gram(err, sol.jacobian, weight, render, lev.bg, thickness, lev.cos)


def solve_marginal_chi2(err: ResponseError | None, lev, sol, robust_scale: float,
                        thickness_model: str | None = None) -> tuple[float, float] | None:
    """:func:`marginal_chi2` of a solve ``sol`` on its level ``lev`` (:func:`_solve_images`,
    with its ``thickness_model``); None for a solve without a Jacobian or a thickness."""
    if sol.jacobian is None or not sol.jacobian.size:
        return None
    images = _solve_images(lev, sol, robust_scale, thickness_model)
    if images is None:
        return None
    weight, render, thickness, resid = images
    return marginal_chi2(err, sol.jacobian, resid, weight, render, lev.bg, thickness, lev.cos)
