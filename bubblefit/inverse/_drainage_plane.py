"""Drainage of a vertical flat film: a thickness profile along gravity, fitted to its colours.

A film drawn in a frame drains under gravity: it thins from the top and thickens towards
the bottom. Its thickness is taken as a function of the height in the film's own plane
alone,

    ``d(y) = top + (bottom - top) ((1 - y) / 2)^exponent``,

the bubble's drainage profile (:func:`bubblefit.model.thickness.drainage_profile`) with
``y`` the film coordinate along the plane's ``up`` direction normalised to the frame:
``y = +1`` at the frame's top edge, ``-1`` at its bottom (:func:`film_height`). ``top``
and ``bottom`` are thus the thicknesses at the frame's edges and ``exponent`` the shape
(1: a wedge, > 1: thin over most of the film and thickening near the bottom, as a
draining film's profile between the black top and the bottom's Plateau border).

The parameters are found in two steps:

1. *Global search* on the cost volume ``C[p, j]`` of the per-pixel fit (the misfit of
   every candidate thickness at every pixel, :mod:`bubblefit.inverse.planar`): the
   pixels are summed into bins of ``y``, and every profile of a grid of (top, bottom,
   exponent) with the bottom at least as thick as the top is scored by the summed bin
   costs at its thicknesses. A profile spans the
   whole film, so the order of interference is settled by the colour sequence along it,
   without a reference; a region of known thickness, when named, keeps only the profiles
   that pass within 0.3 fringe of its value there.
2. *Levenberg-Marquardt* (:func:`._planar_lm.fit_colours`) on
   ``(top, bottom, log exponent, log exposure)`` against every film pixel's colours
   (censored residuals, :mod:`._censored`), whitened by the noise of the per-pixel fit.

Standard errors: ``(J^T J)^-1`` widened by the larger of the Birge ratio and the cluster
sandwich over blocks of the film (:func:`._uncertainty.widened_over_film`, as for a bubble), plus
the thickness model error of :class:`~bubblefit.inverse._options.JudgeSettings` taken
independently at the film's top, bottom and middle height and carried to the parameters
(:func:`drainage_covariance`: the ends get it in quadrature, the exponent what the middle's
share implies); each pixel's thickness error follows by the delta method.

References
----------
K. J. Mysels, K. Shinoda and S. Frankel, *Soap Films: Studies of Their Thinning and a
Bibliography*, Pergamon (1959) (vertical films draining under gravity); D. W. Marquardt,
J. SIAM 11, 431-441 (1963); K.-Y. Liang and S. L. Zeger, Biometrika 73, 13-22 (1986).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ComputationError
from ..model.thickness import drainage_profile
from ._options import JudgeSettings
from ._planar_lm import ModelFit, fit_colours, fit_order
from ._uncertainty import widened_over_film

__all__ = ["film_height", "search_drainage", "fit_drainage", "drainage_covariance"]

#: Bins of the film height in the global search: 96 over the film, so that a profile
#: spanning 1000 nm changes by about 10 nm within a bin (a third of the width of a
#: minimum of the colour cost), for a search that costs seconds.
HEIGHT_BINS = 96
#: Exponents tried by the global search (the refinement takes it the rest of the way).
EXPONENTS = (0.5, 0.7, 0.85, 1.0, 1.2, 1.4, 1.7, 2.0, 2.5, 3.0)
#: Step (nm) of the searched ends: a few candidates across a minimum of the colour cost.
END_STEP_NM = 6.0
#: Range of the exponent kept by the refinement.
EXPONENT_RANGE = (0.2, 5.0)


def film_height(view_y: np.ndarray, frame_height: float, top_is_positive: bool = True) -> np.ndarray:
    """The film coordinate ``y`` of the module, from a coordinate along the film's up
    direction measured from the frame's centre (``frame_height`` the frame's extent);
    ``top_is_positive=False`` for a coordinate that grows downwards (image rows)."""
    y = 2.0 * np.asarray(view_y, np.float64) / float(frame_height)
    return y if top_is_positive else -y


def _binned(cost: np.ndarray, height: np.ndarray, bins: int):
    """Sum of the cost volume's rows per bin of the height, and each bin's mean ``(1 - y) / 2``."""
    f = (1.0 - height) * 0.5
    lo, hi = float(f.min()), float(f.max())
    k = np.minimum(((f - lo) / max(hi - lo, 1e-12) * bins).astype(int), bins - 1)
    order = np.argsort(k, kind="stable")
    ks = k[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    sums = np.add.reduceat(cost[order].astype(np.float64), starts, axis=0)
    counts = np.diff(np.r_[starts, len(ks)])
    fk = np.add.reduceat(f[order], starts) / counts
    return sums, fk


def search_drainage(cost: np.ndarray, grid: np.ndarray, height: np.ndarray, reference=None,
                    window_nm: float = np.inf) -> tuple[float, float, float]:
    """(top, bottom, exponent) of the profile whose summed binned cost is least (step 1).

    ``cost`` (P, D) the pixels' costs of the thicknesses ``grid`` (D,), ``height`` (P,)
    their film coordinate; ``reference`` an optional ``(f, nm)``: a point ``(1 - y) / 2``
    of the film whose thickness is known, with profiles more than ``window_nm`` away
    there left out.
    """
    sums, fk = _binned(cost, height, HEIGHT_BINS)
    flat = sums.astype(np.float32).ravel()
    step = float(grid[1] - grid[0])
    stride = max(1, int(round(END_STEP_NM / step)))
    ends = grid[::stride]
    base = (np.arange(len(fk)) * len(grid))[None, :]
    # drainage: the bottom at least as thick as the top; every such pair of ends
    ti, bi = np.triu_indices(len(ends))
    tt, bb = ends[ti][:, None], ends[bi][:, None]
    best = (np.inf, None)
    for e in EXPONENTS:
        w = (fk ** e)[None, :]                                    # (1, K)
        j = np.clip(np.rint((tt + (bb - tt) * w - grid[0]) / step), 0, len(grid) - 1).astype(np.int32)
        total = flat[base + j].sum(-1)                            # (pairs,)
        if reference is not None:
            fr, nm = reference
            dr = ends[ti] + (ends[bi] - ends[ti]) * fr ** e
            total = np.where(np.abs(dr - nm) <= window_nm, total, np.inf)
        i = int(np.argmin(total))
        if total[i] < best[0]:
            best = (float(total[i]), (float(ends[ti[i]]), float(ends[bi[i]]), float(e)))
    if best[1] is None:
        raise ComputationError("no drainage profile passes through the reference region's thickness")
    return best[1]


def drainage_covariance(top: float, bottom: float, exponent: float) -> np.ndarray:
    """Covariance of ``(top, bottom, log exponent)`` from the thickness model error
    (:class:`~bubblefit.inverse._options.JudgeSettings`) taken independently at the film's top,
    bottom and middle height: ``G^-1 s^2 G^-T`` with ``G`` the Jacobian of those three
    thicknesses; the ends get ``s^2`` itself. A film whose ends are equal has no exponent
    (infinite variance)."""
    s2 = float(JudgeSettings.thickness_model_error_nm) ** 2
    half = 0.5 ** exponent
    slope = (bottom - top) * half * math.log(0.5) * exponent   # d d(mid) / d log(exponent)
    if abs(slope) < 1e-9:
        return np.diag([s2, s2, np.inf])
    g = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0 - half, half, slope]])
    gi = np.linalg.inv(g)
    return s2 * gi @ gi.T


def fit_drainage(fwd, y, lum, sin2, height, start, gain, sigma, lo, hi, shape, pixels, high=np.inf,
                 iters: int = 40) -> ModelFit:
    """Levenberg-Marquardt fit of the profile and the exposure (step 2), from ``start``
    = (top, bottom, exponent); ``shape`` the photo's (H, W) and ``pixels`` the flat
    indices of the film's pixels, for the cluster sandwich."""
    top, bottom, expo = start
    theta = jnp.asarray([top, bottom, np.log(expo), np.log(gain)])
    hj, lj, sj, obs = (jnp.asarray(a) for a in (height, lum, sin2, y))
    elo, ehi = (float(np.log(v)) for v in EXPONENT_RANGE)

    def profile(t):
        return drainage_profile(hj, t[0], t[1], jnp.exp(jnp.clip(t[2], elo, ehi)))

    def model(t):
        return jnp.exp(t[3]) * lj[:, None] * fwd.rgb(jnp.clip(profile(t), lo, hi), sj)

    theta, r, cost, J = fit_colours(model, obs, sigma, high, theta, iters)
    # the profile's order: its ends one fringe away (bubblefit.inverse.order_check)
    order = fit_order(fwd, model, lambda t: jnp.clip(profile(t), lo, hi), obs, sigma, high, (theta, r, cost, J),
                      {"top_nm": 0, "bottom_nm": 1}, sin2, lo, hi, iters)
    a_inv = np.linalg.pinv(J.T @ J)
    chi2 = cost / max(len(r) - 4, 1)
    # the cluster sandwich over blocks of the film
    cov, scale = widened_over_film(max(1.0, chi2) * a_inv, a_inv, J, r, pixels, shape)
    t = np.asarray(theta, np.float64)
    cov[:3, :3] += drainage_covariance(t[0], t[1], float(np.exp(np.clip(t[2], elo, ehi))))
    d = np.asarray(profile(theta), np.float64)
    # a calibrated response's share (bubblefit.inverse.response_error.response_gram)
    cam = fwd.camera_covariance(J, np.asarray(model(theta), np.float64), np.clip(d, lo, hi), sin2, sigma)
    if cam is not None:
        cov = cov + cam
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    dj = np.asarray(jax.jacfwd(profile)(theta), np.float64)[:, :3]
    d_se = np.sqrt(np.clip(np.einsum("pi,ij,pj->p", dj, cov[:3, :3], dj), 0.0, None))
    expo = float(np.exp(np.clip(t[2], elo, ehi)))
    params = {"top_nm": float(t[0]), "bottom_nm": float(t[1]), "exponent": expo, "exposure": float(np.exp(t[3]))}
    stderr = {"top_nm": float(se[0]), "bottom_nm": float(se[1]), "exponent": expo * float(se[2]),
              "exposure": float(np.exp(t[3]) * se[3])}
    camera = None
    if cam is not None:
        cse = np.sqrt(np.clip(np.diag(cam), 0.0, None))
        camera = {"top_nm": float(cse[0]), "bottom_nm": float(cse[1]), "exponent": expo * float(cse[2]),
                  "exposure": float(np.exp(t[3]) * cse[3])}
    return ModelFit(params=params, stderr=stderr, thickness=np.clip(d, lo, hi), thickness_stderr=d_se,
                    model=np.asarray(model(theta), np.float64), gain=float(np.exp(t[3])), stderr_scale=scale,
                    stderr_camera=camera, order=order)
