"""The camera's response fitted together with the film (``bubblefit fit --calibrate-camera``).

The fit integrates a film's spectrum into RGB with the ``fourier`` quadrature
(:mod:`bubblefit.optics.spectral`): ``K`` Gaussian lobes ``G_k`` in wavenumber, and
weights ``W`` (K, 3) that make ``sum_k W_kc G_k(nu)`` the channel's response times the
lamp. Every response the fit is told is projected onto these lobes
(:func:`~bubblefit.optics.spectral._fourier_arrays`), so ``W`` is the response as the
fit sees it: here its columns are freed. Lobes that a photo cannot tell apart share one
weight (:data:`TIED_OVERLAP`: two pairs of the fit's 8), and with the white balance that
makes a flat reflector grey (``"illuminant"``) each column sums to 1, which leaves 5 free
coefficients per channel, 15 in all (:func:`lobe_groups`).

Every channel of the forward model is linear in its own column of ``W``: the film's
reflectance and transmittance are integrated sample by sample before they meet the
map's and the background's RGB (eqs. 10-14 of the paper are sums over the spectral
samples). So with ``B_kc(theta)`` the image rendered with the one-hot weights ``e_k``
(probe renders, :class:`ProbeBasis`),

``render_c(theta, W) = sum_k W_kc B_kc(theta)``,

and the joint problem ``min_{theta, W} |(render(theta, W) - photo) / sigma|^2`` has an
exact, cheap Jacobian in ``W`` (the probe images themselves) and one in the film's
parameters ``theta`` (thicknesses and exposure) by finite differences of the probe
images. It is solved by Levenberg-Marquardt (Marquardt, SIAM J. Appl. Math. 11(2), 1963)
from the ordinary fit's film and the stated response's ``W``.

When does a photo determine the response? A film's colours depend on the response only
through its cosine transform at the film's optical paths (``harmonic`` quadrature of
:mod:`bubblefit.optics.spectral`): a constant film fixes three numbers per path, not 15
coefficients, while a draining film whose paths span several orders fixes the transform
over a range. The test (:func:`degeneracy`) is on the whitened joint Jacobian with its
columns scaled to unit norm (parameters in any unit): its numerical rank at the
tolerance ``s_max max(M, N) eps`` (Golub & Van Loan, *Matrix Computations*, 4th ed., sec.
5.4.1; numpy's ``matrix_rank``), ``eps`` the renders' resolution (float32), and the least
singular value of the response's columns projected off the film's (what the film's
parameters cannot mimic), which must exceed the fit's model-error floor
(``JudgeSettings.model_error``). A bubble's constant film is seen over a spread of
refraction angles, so its Jacobian has full numerical rank, but the response's distinct
part is a few parts in ten thousand of its coefficients' effects: far under what the
model is trusted to render. A photo that fails either test leaves some combination of
response and thickness free: the fit is not ``ok``, with the reason, rather than
reporting a thickness that a wrong response explains as well.

One direction is close to degenerate for every photo: stretching all thicknesses by
``s`` and the response in wavenumber by ``1/s`` leaves a non-dispersive film's colours
unchanged (they depend on ``n d nu`` only); only the lobes' fixed positions and the
film's dispersion break it. Its size is in the covariance: the thickness's standard
error of a self-calibrated fit includes it.

References
----------
Marquardt, "An algorithm for least-squares estimation of nonlinear parameters", SIAM J.
Appl. Math. 11(2), 1963; Golub & Van Loan, *Matrix Computations*, 4th ed., 2013,
sec. 5.4.1 (numerical rank); the lobes: Belcour & Barla, ACM TOG 36(4), 2017, sec. 4.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..optics.spectral import SpectralBasis

__all__ = ["ProbeBasis", "Degeneracy", "degeneracy", "SelfCalibration", "calibrate_in_fit", "self_calibrated", "summary",
           "response_csv",
           "lobe_groups", "RENDER_EPS", "TIED_OVERLAP"]

#: Resolution of a rendered value: the renders are float32.
RENDER_EPS = float(np.finfo(np.float32).eps)

#: Relative step of the finite differences in the film's parameters (thicknesses in nm,
#: exposure): float32 renders resolve ~1e-7, a step of 1e-3 leaves ~1e-4 rounding in a
#: derivative and a truncation error of the same order on fringes of 100 nm period.
_STEP = {"thickness_nm": 0.5, "top_nm": 0.5, "bottom_nm": 0.5, "exponent": 2e-3, "exposure": 1e-3}


class ProbeBasis(SpectralBasis):
    """The fit's ``fourier`` quadrature with one-hot weights: channel ``c`` integrates lobe
    ``(shift + c) mod K`` alone, so one render gives three probe images ``B_kc``."""

    def __init__(self, base: SpectralBasis, shift: int):
        super().__init__(base.method, base.samples, base.illuminant, base.response, base.white_balance)
        k = self.samples
        w = np.zeros((k, 3))
        for c in range(3):
            w[(shift + c) % k, c] = 1.0
        self.weights = w
        self.shift = int(shift)

    def _key(self):
        return super()._key() + ("probe", self.shift)

    def __repr__(self):
        return f"ProbeBasis({super().__repr__()}, shift={self.shift})"


@dataclass(frozen=True)
class Degeneracy:
    """The rank test of a joint Jacobian (:func:`degeneracy`)."""

    rank: int
    parameters: int
    condition: float          # s_max / s_min of the column-scaled Jacobian
    tolerance: float          # the numerical rank's tolerance relative to s_max
    response_floor: float     # the least distinct response combination's share (see degeneracy)
    floor: float              # what it must exceed: the model-error floor
    weakest: dict             # that combination, by coefficient (largest entries)
    singular: tuple = ()      # the column-scaled Jacobian's singular values, largest first
    response_singular: tuple = ()  # the film-projected response block's, largest first

    @property
    def determined(self) -> bool:
        return self.rank == self.parameters and self.response_floor > self.floor

    def reason(self) -> str:
        names = ", ".join(f"{k} {v:+.2f}" for k, v in self.weakest.items())
        return (f"the photo does not determine the camera response: a combination of its coefficients ({names}) "
                f"changes the image by {self.response_floor:.2g} of their own effect beyond what the film's "
                f"parameters can mimic, under the {self.floor:.0%} model-error floor (rank {self.rank} of "
                f"{self.parameters}); a film that spans several interference orders (a drainage profile) "
                "calibrates the camera, a constant film does not: give the camera (--camera-response, bubblefit "
                "calibrate-camera)")

    def to_json(self) -> dict:
        return {"rank": self.rank, "parameters": self.parameters, "condition": self.condition,
                "tolerance": self.tolerance, "response_floor": self.response_floor, "floor": self.floor,
                "determined": self.determined, "weakest": self.weakest, "singular": list(self.singular),
                "response_singular": list(self.response_singular)}


def degeneracy(jacobian: np.ndarray, names, film: int, floor: float, eps: float = RENDER_EPS) -> Degeneracy:
    """Whether a whitened joint Jacobian (M, N), its first ``film`` columns the film's
    parameters and the rest the response's coefficients, determines the response.

    Two tests, on the columns scaled to unit norm (parameters in any unit):

    - numerical rank: singular values above ``s_max max(M, N) eps`` count (Golub & Van
      Loan, sec. 5.4.1), ``eps`` the renders' resolution;
    - the response's distinct part: the response columns projected off the span of the
      film's columns (what the film cannot mimic); its least singular value ``s`` is the
      image change of the least distinct unit combination of coefficients, as a share of
      the coefficients' own effects. It must exceed ``floor``, the fit's model-error floor
      (a fraction of each pixel's value that the renders are not trusted to): a change
      smaller than that is as well explained by the model's own errors, and the fit would
      trade thickness for response along it (on a constant film, a synthetic 600 nm film
      seen by the Nikon D5100 read 525 nm, ``ok``, without this test).
    """
    j = np.asarray(jacobian, np.float64)
    norms = np.linalg.norm(j, axis=0)
    scaled = j / np.where(norms > 0, norms, 1.0)
    s = np.linalg.svd(scaled, compute_uv=False)
    tol = max(j.shape) * eps
    rank = int(np.sum(s > s[0] * tol)) - int(np.sum(norms == 0))
    q, _ = np.linalg.qr(scaled[:, :film]) if film else (np.zeros((j.shape[0], 0)), None)
    resp = scaled[:, film:]
    proj = resp - q @ (q.T @ resp)
    _, sr, vt = np.linalg.svd(proj, full_matrices=False)
    v = vt[-1]
    order = np.argsort(-np.abs(v))[:4]
    rnames = list(names)[film:]
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return Degeneracy(max(rank, 0), j.shape[1], cond, tol, float(sr[-1]), float(floor),
                      {str(rnames[i]): float(v[i]) for i in order}, tuple(float(x) for x in s),
                      tuple(float(x) for x in sr))


@dataclass
class SelfCalibration:
    """What :func:`calibrate_in_fit` found: the film's parameters ``values`` with ``stderr``,
    the weights ``weights`` (K, 3) of the fit's lobes (``wavelengths`` nm, ``sigma`` 1/nm)
    with their covariance ``covariance`` (3 (K-1) free coefficients, channel after
    channel, the last lobe's weight of each channel being 1 minus the others), the rank
    test, the reduced chi^2 and the render."""

    values: dict
    stderr: dict
    weights: np.ndarray
    covariance: np.ndarray
    coefficient_names: list
    wavelengths: np.ndarray
    sigma: np.ndarray
    start_weights: np.ndarray
    rank: Degeneracy
    reduced_chi2: float
    iterations: int
    converged: bool
    render: np.ndarray
    groups: list = None

    def response_nm(self, grid=None):
        """The fitted camera-times-lamp density per nm on ``grid`` (default 380-780 nm, 5 nm
        steps), each channel's maximum 1: ``sum_k W_kc G_k(1/lambda) / lambda^2``."""
        lam = np.arange(380.0, 781.0, 5.0) if grid is None else np.asarray(grid, np.float64)
        nu = 1.0 / lam
        g = np.exp(-0.5 * ((nu[:, None] - 1.0 / self.wavelengths) / self.sigma) ** 2) / self.sigma
        d = (g @ self.weights) / lam[:, None] ** 2
        return lam, d / np.max(np.abs(d), axis=0)

    def response_stderr(self, grid=None) -> np.ndarray:
        """Standard errors of :meth:`response_nm` (L, 3) from the coefficients' covariance
        (linear propagation; the normalisation's own uncertainty left out); NaN when the
        photo did not determine the response."""
        lam = np.arange(380.0, 781.0, 5.0) if grid is None else np.asarray(grid, np.float64)
        nu = 1.0 / lam
        g = np.exp(-0.5 * ((nu[:, None] - 1.0 / self.wavelengths) / self.sigma) ** 2) / self.sigma / lam[:, None] ** 2
        peak = np.max(np.abs(g @ self.weights), axis=0)
        e = _directions(self.groups, len(self.wavelengths))  # (G-1, K)
        ge = g @ e.T  # (L, G-1): the density's change per coefficient
        ng = e.shape[0]
        out = np.empty((len(lam), 3))
        for c in range(3):
            cov = self.covariance[c * ng:(c + 1) * ng, c * ng:(c + 1) * ng]
            out[:, c] = np.sqrt(np.clip(np.einsum("lg,gh,lh->l", ge, cov, ge), 0.0, None)) / peak[c]
        return out

    def to_json(self) -> dict:
        lam, resp = self.response_nm()
        return {
            "basis": "fourier lobes (bubblefit.optics.spectral.FOURIER_LOBES)",
            "lobe_wavelength_nm": self.wavelengths.tolist(),
            "lobe_sigma_per_nm": self.sigma.tolist(),
            "weights": self.weights.tolist(), "start_weights": self.start_weights.tolist(),
            "coefficients": self.coefficient_names, "tied_lobes": self.groups,
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "response_wavelength_nm": lam.tolist(), "response": resp.tolist(),
            "response_stderr": self.response_stderr().tolist(),
            "rank": self.rank.to_json(), "reduced_chi2": self.reduced_chi2,
            "iterations": self.iterations, "converged": self.converged,
            "film": {k: float(v) for k, v in self.values.items()},
            "film_stderr": {k: float(v) for k, v in self.stderr.items()},
        }


def _probes(st, opts, env, vals: dict, lev) -> np.ndarray:
    """Probe images ``B`` (K, h, w, 3) of ``lev`` at the film ``vals``: ``B[k, ..., c]`` is
    channel ``c`` rendered with lobe ``k`` alone."""
    from ._programs import final_params, render_level

    base = st.fx.spectral
    k = base.samples
    p = final_params(st.table, vals, opts)
    out = np.empty((k,) + lev.y.shape, np.float64)
    for shift in range(k):
        cfg = replace(lev.cfg, effects=replace(lev.cfg.effects, spectral=ProbeBasis(base, shift)))
        img = np.asarray(render_level(p, lev, env, cfg=cfg), np.float64)
        for c in range(3):
            out[(shift + c) % k, ..., c] = img[..., c]
    return out


def _combine(b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``render_c = sum_k W_kc B_kc`` for probe images ``b`` (K, ..., 3)."""
    return np.einsum("k...c,kc->...c", b, w)


#: Lobes whose Gaussians overlap more than this (normalised inner product in wavenumber)
#: share one free weight: the fit's 8 lobes (FOURIER_LOBES[8]) hold two such pairs,
#: 577.4/578.4 nm (0.9998) and 463.0/467.5 nm (0.9948), whose weights a photo cannot tell
#: apart (a joint Jacobian with them separate has rank 3 short); the next closest pair
#: overlaps 0.80.
TIED_OVERLAP = 0.99


def lobe_groups(centres_nm, sigma_per_nm) -> list:
    """The lobes tied into groups (:data:`TIED_OVERLAP`), in the order of their first lobe.
    The overlap of two Gaussians of unit norm is ``sqrt(2 s1 s2 / (s1^2 + s2^2))
    exp(-(mu1 - mu2)^2 / (4 (s1^2 + s2^2) / 2))`` in closed form."""
    mu = 1.0 / np.asarray(centres_nm, np.float64)
    s = np.asarray(sigma_per_nm, np.float64)
    ss = s[:, None] ** 2 + s[None, :] ** 2
    overlap = np.sqrt(2 * np.outer(s, s) / ss) * np.exp(-((mu[:, None] - mu[None, :]) ** 2) / (2 * ss))
    groups, seen = [], set()
    for i in range(len(mu)):
        if i in seen:
            continue
        g = [j for j in range(len(mu)) if j not in seen and overlap[i, j] > TIED_OVERLAP]
        seen.update(g)
        groups.append(g)
    return groups


def _directions(groups, k: int) -> np.ndarray:
    """(G - 1, K): how each free coefficient changes every lobe's weight of its channel.
    Coefficient ``g`` adds 1 to each lobe of group ``g`` and takes ``|g| / |last|`` from each
    lobe of the last group, so the weights' sum (a flat reflector's grey) is kept."""
    last = groups[-1]
    e = np.zeros((len(groups) - 1, k))
    for i, g in enumerate(groups[:-1]):
        e[i, g] = 1.0
        e[i, last] = -len(g) / len(last)
    return e


def _weights(w0: np.ndarray, coef: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(K, 3) weights: the start's ``w0`` moved by ``coef`` (3 (G-1),) along ``e``."""
    return w0 + e.T @ coef.reshape(3, -1).T


def _coefficient_columns(bm: np.ndarray, e: np.ndarray, wgt: np.ndarray) -> np.ndarray:
    """Whitened Jacobian columns (n 3, 3 (G-1)) of the coefficients, from probe values
    ``bm`` (K, n, 3) of the fitted pixels and their weights ``wgt`` (n, 3)."""
    n = bm.shape[1]
    dirs = np.einsum("gk,knc->gnc", e, bm)  # d render_c / d coef_gc
    cols = []
    for c in range(3):
        for g in range(e.shape[0]):
            col = np.zeros((n, 3))
            col[:, c] = dirs[g, :, c] * wgt[:, c]
            cols.append(col.reshape(-1))
    return np.stack(cols, axis=1)


def _project(bm, w0, e, y, wgt):
    """The coefficients of least cost at fixed probe values ``bm`` (linear least squares per
    channel: the variable projection of Golub & Pereyra, SIAM J. Numer. Anal. 10(2), 1973)
    and that cost."""
    coef = []
    cost = 0.0
    for c in range(3):
        a = np.einsum("gk,kn->ng", e, bm[..., c]) * wgt[:, c:c + 1]
        r0 = (np.einsum("kn,k->n", bm[..., c], w0[:, c]) - y[:, c]) * wgt[:, c]
        x, *_ = np.linalg.lstsq(a, -r0, rcond=None)
        cost += float(np.sum((a @ x + r0) ** 2))
        coef.append(x)
    return np.concatenate(coef), cost


def _search(st, opts, env, vals, film, lev, w0, e, y, wgt, step_nm: float, keep: int):
    """Starts of the joint solve: drainage profiles ``top <= bottom`` (or constant films) on
    a grid of ``step_nm`` over the thickness range, each with its best response
    (:func:`_project`); the ``keep`` lowest costs."""
    lo, hi = opts.thickness_range
    grid = np.arange(lo, hi + 0.5 * step_nm, step_nm)
    m = lev.mask
    if "thickness_nm" in film:
        cands = [{"thickness_nm": float(d)} for d in grid]
    else:
        cands = [{"top_nm": float(a), "bottom_nm": float(b), "exponent": 1.0} for a in grid for b in grid if a <= b]
    scored = []
    for cand in cands:
        v = dict(vals, **cand)
        bm = _probes(st, opts, env, v, lev)[:, m, :]
        coef, cost = _project(bm, w0, e, y, wgt)
        scored.append((cost, cand, coef))
    scored.sort(key=lambda t: t[0])
    return scored[:keep]


def calibrate_in_fit(st, opts, env, vals: dict, max_steps: int = 30, search_step_nm: float = 100.0,
                     starts: int = 1, rounds: int = 3) -> SelfCalibration:
    """Fit the film's parameters (those free in ``st.table``, the disc's refinement apart)
    together with the response's lobe weights (module docstring): a search over films of
    the thickness range, each with its best response, then Levenberg-Marquardt from the
    ``starts`` best and from ``vals`` (the ordinary fit's film); the lowest cost wins, and
    the search is repeated at its brightness parameters (at most ``rounds`` times, while
    it finds a lower cost).
    ``st``: the fit's :class:`~bubblefit.inverse._setup.Setup`, whose fit level's pixels
    and noise are used."""
    from ._parameters import THICKNESSES

    lev = st.lev_fit
    base = st.fx.spectral
    if base.method != "fourier":
        from ..errors import InputError

        raise InputError(f"--calibrate-camera frees the fit's fourier lobes; the spectral method is {base.method}")
    k = base.samples
    groups = lobe_groups(base.wavelengths, base.sigma)
    e = _directions(groups, k)
    from ._parameters import DISC_PARAMETERS

    film = [n for n in st.table.free if n not in DISC_PARAMETERS]
    m = lev.mask
    wgt = lev.w[m]  # 1/sigma per fitted pixel and channel
    y = lev.y[m]
    w0 = np.asarray(base.weights, np.float64)
    w0 = w0 / w0.sum(axis=0, keepdims=True)
    ng = e.shape[0]
    names = film + [f"{'rgb'[c]}{g}" for c in range(3) for g in range(ng)]

    def evaluate(theta, coef, jac: bool):
        v = dict(vals, **dict(zip(film, theta)))
        b = _probes(st, opts, env, v, lev)
        w = _weights(w0, coef, e)
        r = ((_combine(b, w)[m] - y) * wgt).reshape(-1)
        if not jac:
            return r, None, b
        cols = []
        for i, n in enumerate(film):
            h = _STEP.get(n, 1e-3) * (1.0 if n in THICKNESSES else max(abs(theta[i]), 1.0))
            t2 = theta.copy()
            t2[i] += h
            b2 = _probes(st, opts, env, dict(vals, **dict(zip(film, t2))), lev)
            cols.append(((_combine(b2, w) - _combine(b, w))[m] * wgt).reshape(-1) / h)
        jm = np.concatenate([np.stack(cols, axis=1), _coefficient_columns(b[:, m, :], e, wgt)], axis=1)
        return r, jm, b

    def solve(theta, coef):
        lam = 1e-3
        r, jm, b = evaluate(theta, coef, True)
        cost = float(r @ r)
        steps, converged = 0, False
        for steps in range(1, max_steps + 1):
            jtj, jtr = jm.T @ jm, jm.T @ r
            d = np.sqrt(np.diag(jtj))
            d = np.where(d > 0, d, 1.0)
            step = -np.linalg.solve(jtj / np.outer(d, d) + lam * np.eye(len(d)), jtr / d) / d
            t_new, c_new = theta + step[:len(film)], coef + step[len(film):]
            r_new, _, _ = evaluate(t_new, c_new, False)
            new_cost = float(r_new @ r_new)
            if np.isfinite(new_cost) and new_cost < cost:
                rel = (cost - new_cost) / max(cost, 1e-300)
                theta, coef, cost = t_new, c_new, new_cost
                lam = max(lam / 3.0, 1e-9)
                r, jm, b = evaluate(theta, coef, True)
                if rel < 1e-6:
                    converged = True
                    break
            else:
                lam *= 4.0
                if lam > 1e8:
                    converged = True  # no step lowers the cost: a minimum to the renders' resolution
                    break
        return cost, theta, coef, r, jm, b, steps, converged

    best = None
    current, coef0 = dict(vals), np.zeros(3 * ng)
    for _ in range(rounds):
        # the search scores films at the current brightness parameters (t, roughness,
        # exposure), which the previous round's joint solve has corrected
        found = _search(st, opts, env, current, film, lev, w0, e, y, wgt, search_step_nm, starts)
        improved = False
        for _, cand, coef in [(None, {}, coef0)] + found:
            theta = np.array([float(cand.get(n, current[n])) for n in film])
            out = solve(theta, coef)
            if best is None or out[0] < best[0]:
                best, improved = out, True
        if not improved:
            break
        current, coef0 = dict(vals, **dict(zip(film, best[1]))), best[2]
    cost, theta, coef, r, jm, b, steps, converged = best
    dof = max(r.size - len(names), 1)
    chi2 = cost / dof
    rank = degeneracy(jm, names, len(film), float(opts.judge.model_error))
    cov = np.linalg.pinv(jm.T @ jm) * max(chi2, 1.0)
    if not rank.determined:
        cov = np.full_like(cov, np.nan)
    err = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    nf = len(film)
    w = _weights(w0, coef, e)
    return SelfCalibration(
        values=dict(zip(film, theta.tolist())), stderr=dict(zip(film, err[:nf].tolist())), weights=w,
        covariance=cov[nf:, nf:], coefficient_names=names[nf:], wavelengths=np.asarray(base.wavelengths, np.float64),
        sigma=np.asarray(base.sigma, np.float64), start_weights=w0, rank=rank, reduced_chi2=chi2, iterations=steps,
        converged=converged, render=_combine(b, w), groups=groups)


def response_csv(record: dict) -> str | None:
    """The fitted response of a ``camera_calibration`` record as the CSV that
    ``--camera-response`` reads (:meth:`bubblefit.capture.camera_calibration.CameraCalibration.csv_text`:
    the camera-times-lamp product, so calibrated under illuminant ``E``; negative values
    clipped to 0), or None when the photo did not determine it."""
    from ..capture.camera_calibration import CameraCalibration

    if not record["rank"]["determined"]:
        return None
    # a sum of lobes dips below zero where the weights do (the Nikon's own projection's red
    # channel, to -4 % of its peak); it is written clipped at zero
    resp = np.clip(np.asarray(record["response"], np.float64), 0.0, None)
    nan = np.full(3, np.nan)
    cal = CameraCalibration(np.asarray(record["response_wavelength_nm"], np.float64), resp,
                            np.asarray(record["response_stderr"], np.float64), nan, nan, nan,
                            0, "E", ["a film fitted with bubblefit fit --calibrate-camera"])
    return cal.csv_text()


def summary(record: dict) -> str:
    """One line on a ``camera_calibration`` record (:meth:`SelfCalibration.to_json` with the
    stated response's fit): the rank test and the stated response's verdict."""
    rank, first = record["rank"], record["stated_response_fit"]
    said = "determined" if rank["determined"] else "NOT determined"
    return (f"camera response fitted with the film: {said} (rank {rank['rank']} of {rank['parameters']}, "
            f"condition {rank['condition']:.3g}, {len(record['coefficients'])} coefficients); the stated "
            f"response's fit was {'ok' if first['ok'] else 'not ok'}")


def _misfit(r_white: np.ndarray, y: np.ndarray, wgt: np.ndarray, model_error: float, n_free: int):
    """The :class:`~bubblefit.inverse._uncertainty.Misfit` of whitened residuals ``r_white``
    (n, 3) of photo values ``y`` with weights ``1/sigma`` ``wgt``, as the fit's own."""
    from ._uncertainty import OUTLIER_CHI2, Misfit

    dof = max(r_white.size - n_free, 1)
    var = 1.0 / wgt**2
    per = r_white**2 * var / (var + (model_error * np.clip(y, 0.0, None)) ** 2)
    pix = per.sum(axis=-1)
    bad = pix > OUTLIER_CHI2
    dof_in = max(int(3 * np.count_nonzero(~bad)) - n_free, 1)
    return Misfit(float(np.sum(r_white**2)) / dof, float(per.sum()) / dof, float(pix[~bad].sum()) / dof_in,
                  float(np.mean(bad)), float(np.minimum(pix, OUTLIER_CHI2).sum()) / dof)


def self_calibrated(first, photo, env, options, background, scene, saturated):
    """The fit ``first`` (made with the stated response) refitted with the response freed
    (:func:`calibrate_in_fit`), on the same disc and view: a
    :class:`~bubblefit.inverse._result.FitResult` whose params, standard errors, render and
    verdict are the joint fit's, with ``camera_calibration`` holding the coefficients, their
    covariance, the rank test and the stated response's fit (``stated_response_fit``). Not
    ``ok`` when the photo does not determine the response (:func:`degeneracy`), the joint
    fit does not explain the photo, or the colour check fails with the fitted response."""
    import jax.numpy as jnp

    from ..model.thickness import drainage_profile
    from ._parameters import THICKNESSES
    from ._setup import setup
    from ._verdict import verdict
    from .colour_check import judge_colours

    t0 = time.perf_counter()
    opts = replace(options, calibrate_camera=False, disc=first.disc if first.disc is not None else options.disc,
                   fit_disc=False)
    cam = first.camera
    if cam is not None:  # the view the first fit kept (an assumed one compared two)
        from ..capture.view import View

        opts = replace(opts, view=View(cam["kind"], cam.get("fov_deg"),
                                       "option" if cam.get("source") == "assumed" else cam["source"],
                                       cam.get("detail", "")))
    init = {k: v for k, v in first.params.items() if np.isfinite(v)}
    st = setup(photo, env, opts, background, init, scene, saturated)
    cal = calibrate_in_fit(st, opts, env, dict(st.vals))
    vals = dict(st.vals, **cal.values)
    full = st.level(1, opts)
    b = _probes(st, opts, env, vals, full)
    img = _combine(b, cal.weights)
    m = full.mask
    r_white = (img[m] - full.y[m]) * full.w[m]
    n_free = len(cal.values) + len(cal.coefficient_names)
    mis = _misfit(r_white, full.y[m], full.w[m], float(opts.judge.model_error), n_free)
    notes = [] if cal.rank.determined else [cal.rank.reason()]
    lo, hi = opts.thickness_range
    bounds = [f"{k} = {v:.1f} nm lies outside the searched thickness range {lo:g}-{hi:g} nm"
              for k, v in cal.values.items() if k in THICKNESSES and not lo - 1.0 <= v <= hi + 1.0]
    ok, warnings = verdict(converged=bool(cal.converged), disc_found=True, bound_warnings=bounds, misfit=mis,
                           ok_chi2=float(opts.judge.ok_chi2), model_error=float(opts.judge.model_error), notes=notes)
    ok = ok and cal.rank.determined
    share = opts.noise.photosite_share
    sigma = st.sigma if share is None else st.sigma / np.sqrt(np.asarray(share))
    # the joint fit's values as the fit reports them; standard errors for the fitted names
    # (a value derived from them, e.g. r_d and r_s from the split, has none here)
    params, stderr = dict(first.params), dict(first.stderr)
    floor = float(opts.judge.thickness_model_error_nm)
    for k, v in st.table.reported({k: np.float32(v) for k, v in vals.items()}).items():
        if k in params:
            params[k] = float(v)
            stderr[k] = float("nan")
    for k in cal.values:
        if k in params:
            e = cal.stderr[k]
            stderr[k] = float(np.hypot(e, floor)) if k in THICKNESSES else float(e)
    thickness_map = first.thickness_map
    if "top_nm" in cal.values:
        prof = (params["top_nm"], params["bottom_nm"], params["exponent"])
        thickness_map = np.where(full.inside, np.asarray(drainage_profile(jnp.asarray(full.height), *prof)), np.nan)
    # the check's cells split by the joint fit's optical path, as the fit with a stated
    # response splits them (bubblefit.inverse.colour_check.PATH_BIN)
    thick = thickness_map if thickness_map is not None else params.get("thickness_nm", np.nan)
    ok, warnings, colour_record = judge_colours(ok, warnings, st.photo, img, m, full.cos, sigma,
                                                float(opts.judge.model_error), mis.chi2_floor <= float(opts.judge.ok_chi2),
                                                opts.judge.colour_check == "decide", thickness=thick,
                                                n_film=float(vals["n_film"]))
    record = cal.to_json()
    record["stated_response_fit"] = {"ok": bool(first.ok), "params": {k: float(v) for k, v in first.params.items()},
                                     "colour_check": first.colour_check, "warnings": list(first.warnings)}
    return replace(first, params=params, stderr=stderr, render=img, residual=st.photo - img, ok=bool(ok),
                   warnings=warnings, converged=bool(cal.converged), status="converged" if cal.converged else "max_steps",
                   reduced_chi2=mis.chi2_nu, chi2_floor=mis.chi2_floor, chi2_inliers=mis.chi2_inliers,
                   outliers=mis.outliers, chi2_capped=mis.chi2_capped, thickness_map=thickness_map,
                   iterations=int(cal.iterations), colour_check=colour_record, camera_calibration=record,
                   residual_rms=float(np.sqrt(np.mean((st.photo - img)[m] ** 2))),
                   time_s=first.time_s + time.perf_counter() - t0, names=(), covariance=None)
