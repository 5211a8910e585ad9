"""The profile likelihood of a film's thickness in a spectrum (variable projection).

For a thickness ``d`` (and resolution ``w``), the model
``y = sum_j a_j B_j R(d) + sum_k c_k S_k`` is linear in the lamp coefficients ``a`` and the
stray-light coefficients ``c`` (``S_0 = 1`` the constant offset, further ``S_k`` a smooth
background that does not pass through the film's fringes): they are solved by least
squares, and ``RSS(d)`` is what is left. :meth:`ProfileProblem.rss_grid` does this for
thousands of thicknesses at once through the normal equations; :meth:`ProfileProblem.rss`
solves one thickness with an orthogonal factorisation, for the local refinement.

References
----------
G. H. Golub and V. Pereyra, SIAM J. Numer. Anal. 10, 413-432 (1973).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import optimize

__all__ = ["ProfileProblem", "rss_grids", "local_minima", "residual_correlation", "second_difference_noise",
           "local_noise", "refine_d", "positive_lamp_lstsq",
           "second_minimum", "refine_near", "refine_dw", "profile_variance"]


@dataclass
class ProfileProblem:
    """A dark-subtracted reading ``y`` (N,), the lamp basis (N, J), whether to fit an
    offset, the film's reflectance at the reading's wavelengths, ``reflect(d, w) -> (D, N)``,
    and optionally more additive stray-light columns ``background`` (N, K). With
    ``positive`` the lamp ``basis @ a`` is kept >= 0 at every wavelength (:meth:`solve`).
    ``incoherent`` is a reflectance added to the film's, ``R + b``: light of the lamp that
    reaches the spectrometer without interfering (see :mod:`bubblefit.inverse.spectrum`).
    ``weight`` (N,) scales each wavelength's residual (weighted least squares: the
    reading's noise scale over the local noise, :func:`local_noise`); None weighs all alike.
    ``RSS`` and the solves are weighted; :meth:`model` is the unweighted spectrum."""

    y: np.ndarray
    basis: np.ndarray
    offset: bool
    reflect: Callable
    background: np.ndarray | None = None
    positive: bool = False
    incoherent: float = 0.0
    weight: np.ndarray | None = None

    def _weighted(self, a: np.ndarray) -> np.ndarray:
        """Rows (wavelengths) of ``a`` times their weight."""
        if self.weight is None:
            return a
        return a * (self.weight if a.ndim == 1 else self.weight[:, None])

    @property
    def additive(self) -> np.ndarray:
        """The (N, K) columns added to the film's light: 1 (the offset) and the background."""
        cols = [np.ones((len(self.y), 1))] if self.offset else []
        if self.background is not None:
            cols.append(np.asarray(self.background, dtype=np.float64).reshape(len(self.y), -1))
        return np.column_stack(cols) if cols else np.zeros((len(self.y), 0))

    @property
    def n_linear(self) -> int:
        """The number of linear parameters solved at every thickness."""
        return self.basis.shape[1] + self.additive.shape[1]

    def design(self, d: float, w: float) -> np.ndarray:
        """The (N, J + K) design matrix at thickness ``d``: lamp basis times ``R(d)``, and the additive columns."""
        r = self.reflect(np.array([d]), w)[0] + self.incoherent
        return np.column_stack([self.basis * r[:, None], self.additive])

    def solve(self, d: float, w: float) -> tuple[np.ndarray, np.ndarray]:
        """Linear coefficients and the model spectrum at ``(d, w)``.

        A lamp must shine: where the least-squares lamp would make the film's light
        ``sum_i L_i R_i`` negative (fringes turned upside down), the constrained optimum is
        on the boundary and is taken as no film light at all (the lamp's coefficients 0,
        the stray light alone), see :meth:`rss_grid`."""
        plain = self.design(d, w)
        a, y = self._weighted(plain), self._weighted(self.y)
        j = self.basis.shape[1]
        if self.positive:
            coef = positive_lamp_lstsq(a, y, self.basis)
            return coef, plain @ coef
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        if float(np.sum(a[:, :j] @ coef[:j])) <= 0.0:
            coef = np.zeros(a.shape[1])
            if a.shape[1] > j:
                coef[j:], *_ = np.linalg.lstsq(a[:, j:], y, rcond=None)
        return coef, plain @ coef

    def model(self, d: float, w: float) -> np.ndarray:
        return self.solve(d, w)[1]

    def rss(self, d: float, w: float) -> float:
        """(Weighted) residual sum of squares with the linear parameters solved (the profile)."""
        r = self._weighted(self.y - self.model(d, w))
        return float(r @ r)

    def rss_grid(self, thickness: np.ndarray, w: float, chunk: int = 256) -> np.ndarray:
        """``RSS(d)`` for every thickness of ``thickness`` (D,), by batched normal equations;
        thicknesses whose solved lamp makes the film's light negative get the RSS of the
        stray light alone (:meth:`solve`), unless the lamp is ``positive`` (the profile then
        stays a lower bound of the constrained one, for :func:`refine_d`)."""
        return rss_grids([self], thickness, w, (self.incoherent,), chunk)[0, 0]

    def _normal_equations(self):
        """What :meth:`_chunk_rss` needs that does not depend on the thickness."""
        y, b, e = self._weighted(self.y), self._weighted(self.basis), self._weighted(self.additive)
        npts, j = b.shape
        q = e.shape[1]
        no_film = float(y @ y) if q == 0 else float(np.sum((y - e @ np.linalg.lstsq(e, y, rcond=None)[0]) ** 2))
        bb = (b[:, :, None] * b[:, None, :]).reshape(npts, j * j)
        be = (b[:, :, None] * e[:, None, :]).reshape(npts, j * q)
        by = b * y[:, None]
        return dict(b=b, bb=bb, be=be, by=by, yy=float(y @ y), ee=e.T @ e, ey=e.T @ y, no_film=no_film,
                    sbb=bb.sum(0), sbe=be.sum(0), sby=by.sum(0), sb=b.sum(0))

    def _chunk_rss(self, r: np.ndarray, ne: dict, levels) -> np.ndarray:
        """``RSS`` (L, C) for the reflectance rows ``r`` (C, N) of a chunk of thicknesses, with
        ``R + b`` for each ``b`` of ``levels``: ``(R + b)^2 = R^2 + 2 b R + b^2`` expands the
        products, so that each level costs only its small solves."""
        b = ne["b"]
        j, q = b.shape[1], ne["ee"].shape[0]
        m, k = len(r), j + q
        rr, r1, rby, rb = (r * r) @ ne["bb"], r @ ne["bb"], r @ ne["by"], r @ b
        rbe = r @ ne["be"] if q else None
        out = np.empty((len(levels), m))
        for li, lev in enumerate(levels):
            g = np.zeros((m, k, k))
            rhs = np.zeros((m, k))
            g[:, :j, :j] = (rr + 2.0 * lev * r1 + lev**2 * ne["sbb"]).reshape(m, j, j)
            rhs[:, :j] = rby + lev * ne["sby"]
            if q:
                cross = (rbe + lev * ne["sbe"]).reshape(m, j, q)
                g[:, :j, j:] = cross
                g[:, j:, :j] = cross.transpose(0, 2, 1)
                g[:, j:, j:] = ne["ee"]
                rhs[:, j:] = ne["ey"]
            ridge = 1e-12 * np.trace(g, axis1=1, axis2=2)[:, None, None] + 1e-300
            coef = np.linalg.solve(g + ridge * np.eye(k), rhs[..., None])[..., 0]
            out[li] = np.maximum(ne["yy"] - np.einsum("mk,mk->m", coef, rhs), 0.0)
            if not self.positive:
                out[li, np.einsum("mj,mj->m", coef[:, :j], rb + lev * ne["sb"]) <= 0.0] = ne["no_film"]
        return out


def rss_grids(problems: list[ProfileProblem], thickness: np.ndarray, w: float, levels=(0.0,),
              chunk: int = 256) -> np.ndarray:
    """:meth:`ProfileProblem.rss_grid` of several problems on the same reading and film
    (the same ``reflect``), each with the film's reflectance ``R + b`` for every ``b`` of
    ``levels`` (their own ``incoherent`` is not used), (P, L, D): the film's reflectance is
    computed once per chunk."""
    eqs = [p._normal_equations() for p in problems]
    out = np.empty((len(problems), len(levels), len(thickness)))
    for s in range(0, len(thickness), chunk):
        r = problems[0].reflect(thickness[s:s + chunk], w)  # (C, N)
        for i, (p, ne) in enumerate(zip(problems, eqs)):
            out[i, :, s:s + len(r)] = p._chunk_rss(r, ne, levels)
    return out


def positive_lamp_lstsq(a: np.ndarray, y: np.ndarray, basis: np.ndarray, samples: int = 256) -> np.ndarray:
    """Least squares ``a @ coef ~ y`` with the lamp ``basis @ coef[:J]`` >= 0 at every
    wavelength (checked on at most ``samples`` of them, evenly spread: the lamp is a
    low-degree series) and the other coefficients (the additive stray light) free.

    The free columns are projected out (QR); the lamp's problem ``min |E x - f|`` subject
    to ``G x >= 0`` is solved as least distance programming by non-negative least squares
    (Lawson & Hanson, *Solving Least Squares Problems*, 1974, ch. 23, algorithms LSI and
    LDP); the free coefficients then follow by least squares on what is left.
    """
    j = basis.shape[1]
    lamp, extra = a[:, :j], a[:, j:]
    if extra.shape[1]:
        q, _ = np.linalg.qr(extra)
        e, f = lamp - q @ (q.T @ lamp), y - q @ (q.T @ y)
    else:
        e, f = lamp, y
    idx = np.unique(np.linspace(0, len(y) - 1, min(samples, len(y))).round().astype(int))
    g = basis[idx]
    qe, re = np.linalg.qr(e)
    x0 = np.linalg.lstsq(re, qe.T @ f, rcond=None)[0]
    if np.all(g @ x0 >= 0.0) or not np.all(np.isfinite(x0)):
        x = x0
    else:
        # x = R^-1 (z + Q^T f): min |z| subject to (G R^-1) z >= -G x0 (LDP), by NNLS.
        gt = np.linalg.solve(re.T, g.T).T          # G R^-1, (M, J)
        h = -(g @ x0)
        norm = max(float(np.max(np.abs(gt))), 1e-300)
        mat = np.vstack([gt.T / norm, h[None, :] / norm])  # (J + 1, M)
        rhs = np.zeros(j + 1)
        rhs[-1] = 1.0
        u, _ = optimize.nnls(mat, rhs, maxiter=50 * mat.shape[1])
        r = mat @ u - rhs
        if abs(r[-1]) < 1e-12:  # infeasible (cannot happen: the zero lamp is feasible)
            x = np.zeros(j)
        else:
            z = -r[:-1] / r[-1]
            x = np.linalg.solve(re, z + qe.T @ f)
    coef = np.zeros(a.shape[1])
    coef[:j] = x
    if extra.shape[1]:
        coef[j:], *_ = np.linalg.lstsq(extra, y - lamp @ x, rcond=None)
    return coef


def local_minima(values: np.ndarray) -> np.ndarray:
    """Indices of the local minima of a 1-D profile (ends included), best first."""
    v = np.asarray(values)
    left = np.concatenate([[np.inf], v[:-1]])
    right = np.concatenate([v[1:], [np.inf]])
    idx = np.flatnonzero((v <= left) & (v <= right))
    return idx[np.argsort(v[idx], kind="stable")]


def residual_correlation(resid: np.ndarray) -> float:
    """Lag-1 autocorrelation of the residuals, clipped to [0, 0.95] (0: independent)."""
    r = resid - resid.mean()
    den = float(r @ r)
    if den <= 0:
        return 0.0
    return float(np.clip((r[1:] @ r[:-1]) / den, 0.0, 0.95))


def second_difference_noise(y: np.ndarray) -> float:
    """The reading's noise from its second differences, robustly (median absolute deviation):
    ``y[i+1] - 2 y[i] + y[i-1]`` of white noise has deviation ``sqrt(6) sigma``. Independent
    of any model, so ``RSS / (N - p)`` over its square measures misfit. A reading quantised
    more coarsely than its noise gets the rounding's noise, ``step / sqrt(12)``."""
    d2 = y[2:] - 2.0 * y[1:-1] + y[:-2]
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    if mad > 0:
        return 1.4826 * mad / np.sqrt(6.0)
    # Most second differences are exactly zero: a quantised reading whose noise is below its
    # step. Its noise is then the rounding's, step / sqrt(12) (0 when the reading is constant).
    steps = np.diff(np.unique(y))
    return float(steps.min() / np.sqrt(12.0)) if len(steps) else 0.0


#: The fewest samples of :func:`local_noise`'s sliding window, and the range its estimate
#: may span around the reading's median noise.
LOCAL_NOISE_WINDOW = 41
LOCAL_NOISE_RANGE = (1.0 / 3.0, 30.0)


def local_noise(y: np.ndarray, window: int = LOCAL_NOISE_WINDOW) -> np.ndarray:
    """The reading's noise at each sample (N,): the root mean square of its fourth
    differences over a sliding window of ``max(window, N / 20)`` samples, over ``sqrt(70)``.

    A spectrometer's noise is not the same at every wavelength: shot noise follows the
    light, and a reading divided by the lamp is noisiest where the lamp is weak (the blue
    end of a halogen lamp, where a divided reading can jump between 0 and its ceiling).
    Fourth differences of white noise have deviation ``sqrt(70) sigma``; those of a fringe
    of ``P`` samples per period are ``(2 sin(pi / P))^4`` of its amplitude, so fringes of
    more than ~12 samples barely count (second differences would see the square root of
    that). A mean square, not a median, so that a short burst of garbage raises the noise
    of its neighbourhood instead of being voted out. The estimate is kept within
    :data:`LOCAL_NOISE_RANGE` of its median; all ones when the median is zero (a reading
    with no measurable noise)."""
    y = np.asarray(y, dtype=np.float64)
    n = len(y)
    if n < 16:
        return np.ones(n)
    d4 = y[4:] - 4.0 * y[3:-1] + 6.0 * y[2:-2] - 4.0 * y[1:-3] + y[:-4]
    box = np.ones(min(max(window, n // 20), len(d4)))
    mean_square = np.convolve(d4**2, box, mode="same") / np.convolve(np.ones(len(d4)), box, mode="same")
    sigma = np.sqrt(np.pad(mean_square, (2, 2), mode="edge") / 70.0)
    mid = float(np.median(sigma))
    if not mid > 0:
        return np.ones(n)
    lo, hi = LOCAL_NOISE_RANGE
    return np.clip(sigma, lo * mid, hi * mid)


def refine_d(prob: ProfileProblem, grid, rss, w: float, keep: int = 6, slack: float = 0.05,
             limit: int = 60) -> list[tuple[float, float]]:
    """The ``keep`` best local minima of the grid profile, each refined by a bounded 1-D
    search over one grid step either side; best first, as (thickness, RSS).

    With a positive lamp the grid profile ``rss`` (unconstrained, batched) is a lower
    bound of the constrained one, so its minima are refined in increasing order until the
    next one's bound exceeds the best refined RSS by the fraction ``slack`` (branch and
    bound; at most ``limit`` minima): the best constrained minima are all visited."""
    step = grid[1] - grid[0]
    out = []
    order = local_minima(rss)
    for count, i in enumerate(order[:limit] if prob.positive else order[:keep]):
        if prob.positive and len(out) >= keep and rss[i] > min(r for _, r in out) * (1.0 + slack):
            break
        lo, hi = max(grid[0], grid[i] - step), min(grid[-1], grid[i] + step)
        res = optimize.minimize_scalar(lambda d: prob.rss(d, w), bounds=(lo, hi), method="bounded",
                                       options={"xatol": 1e-4 * step})
        if prob.positive:
            at = prob.rss(float(grid[i]), w)
            out.append((float(res.x), float(res.fun)) if res.fun <= at else (float(grid[i]), at))
        else:
            out.append((float(res.x), float(res.fun)) if res.fun <= rss[i] else (float(grid[i]), float(rss[i])))
    return sorted(out, key=lambda t: t[1])


def second_minimum(minima, d_best: float, step: float, s2: float) -> tuple[float, float]:
    """The best other minimum of :func:`refine_d`'s ``minima`` (more than two grid steps
    from ``d_best``) and its ``chi^2`` above the best, in units of ``s2``; ``(nan, inf)``
    when there is none."""
    rss_best = min(r for _, r in minima)
    others = [(d, r) for d, r in minima if abs(d - d_best) > 2.0 * step]
    if not others:
        return float("nan"), float("inf")
    d2, r2 = min(others, key=lambda t: t[1])
    return float(d2), float((r2 - rss_best) / s2)


def refine_near(prob: ProfileProblem, d: float, w: float, half_width: float, grid) -> float:
    """The profile's minimum within ``half_width`` of ``d`` (bounded 1-D search)."""
    lo, hi = max(grid[0], d - half_width), min(grid[-1], d + half_width)
    res = optimize.minimize_scalar(lambda x: prob.rss(x, w), bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-5 * half_width})
    return float(res.x)


def refine_dw(prob: ProfileProblem, d0: float, step: float, w_max: float, w0: float = 0.5):
    """Joint local minimum of the profile in thickness (within a step of ``d0``) and
    resolution FWHM ``w`` in [0, w_max] nm (L-BFGS-B on a scaled problem)."""
    ref = max(prob.rss(d0, 0.0), 1e-300)

    def f(x):
        return prob.rss(d0 + x[0] * step, x[1]) / ref

    res = optimize.minimize(f, np.array([0.0, min(max(w0, 0.05), w_max)]), method="L-BFGS-B",
                            bounds=[(-1.0, 1.0), (0.0, w_max)], options={"ftol": 1e-12, "gtol": 1e-10})
    if res.fun > 1.0:  # no better than the start: keep it
        return d0, 0.0
    w = float(res.x[1])
    return d0 + float(res.x[0]) * step, (w if w > 1e-3 else 0.0)


def profile_variance(prob: ProfileProblem, d: float, w: float, step: float, fit_w: bool) -> float:
    """``[H^-1]_dd`` of the profile ``RSS`` (the thickness's inverse curvature, with the
    resolution profiled out when it is fitted), by central differences."""
    h = 0.02 * step
    f0 = prob.rss(d, w)
    hdd = (prob.rss(d + h, w) - 2 * f0 + prob.rss(d - h, w)) / h**2
    if not fit_w:
        return 1.0 / hdd if hdd > 0 else float("inf")
    k = max(0.02 * w, 1e-3)
    k = min(k, 0.5 * w)
    hww = (prob.rss(d, w + k) - 2 * f0 + prob.rss(d, w - k)) / k**2
    hdw = (prob.rss(d + h, w + k) - prob.rss(d + h, w - k) - prob.rss(d - h, w + k) + prob.rss(d - h, w - k)) / (4 * h * k)
    det = hdd * hww - hdw**2
    if hww <= 0 or det <= 0:
        return 1.0 / hdd if hdd > 0 else float("inf")
    return hww / det
