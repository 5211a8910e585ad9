"""Newton's rings: the radius of a lens on a plate, fitted to a colour photo of the gap.

A spherical surface of radius ``R`` touching a flat plate leaves the gap
``h(r) = R - sqrt(R^2 - r^2) + h0`` at the distance ``r`` from the contact point
``(cx, cy)`` (``h0``: an offset at contact, dust or a pressed lens; ``h >= 0``). The
parameters ``(R, cx, cy, h0, g)`` are fitted to the pixels' colours by Levenberg-Marquardt,
started from a per-pixel map: the centre of the thinnest pixels, and ``R``, ``h0`` from a
straight line of the map against ``r^2`` (``h ~ h0 + r^2 / (2 R)``) where the map is
below half the searched range. With a calibrated response that states its errors, the
rings' order (the contact offset's, one fringe either way) is tested
(:func:`bubblefit.inverse._planar_lm.fit_order`).

References
----------
M. Born and E. Wolf, *Principles of Optics*, 7th ed., sec. 7.5.3 (Newton's rings);
D. W. Marquardt, J. SIAM 11, 431-441 (1963).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ComputationError
from ._planar_lm import ModelFit, fit_colours, fit_order

__all__ = ["fit_newton", "newton_gap"]


def newton_gap(r_um, radius_um, h0_nm):
    """Gap (nm) at ``r_um`` from the contact point of a lens of radius ``radius_um`` on a plate."""
    r2 = jnp.minimum(r_um * r_um, 0.999999 * radius_um * radius_um)
    sag = r2 / (radius_um + jnp.sqrt(radius_um * radius_um - r2))  # = R - sqrt(R^2 - r^2), without cancellation
    return jnp.maximum(1000.0 * sag + h0_nm, 0.0)


def fit_newton(fwd, y, lum, sin2, view, mask, dmap, gain, sigma, lo, hi, high=np.inf, iters: int = 40) -> ModelFit:
    """Levenberg-Marquardt fit of ``(R, cx, cy, h0, g)`` (see the module), started from ``dmap``."""
    x = view.x_um[mask]
    yy = view.y_um[mask]
    bright = y.sum(-1) / np.maximum(lum, 1e-9)
    thin = (dmap <= np.percentile(dmap, 2)) & (bright <= 0.35 * np.median(bright))
    if thin.sum() < 3:
        raise ComputationError("no contact point: the photo has no dark centre of Newton's rings")
    cx, cy = float(x[thin].mean()), float(yy[thin].mean())
    r2 = (x - cx) ** 2 + (yy - cy) ** 2
    use = dmap < lo + 0.5 * (hi - lo)
    for _ in range(4):  # a line in r^2, dropping pixels 3 MADs off it (order hops of the map)
        A = np.column_stack([np.ones(use.sum()), r2[use]])
        (h0, slope), *_ = np.linalg.lstsq(A, dmap[use], rcond=None)
        dev = np.abs(dmap - (h0 + slope * r2))
        use = use & (dev <= 3.0 * 1.4826 * np.median(dev[use]) + 1.0)
    if slope <= 0:
        raise ComputationError("no lens: the gap does not grow away from the thinnest point")
    radius = 1000.0 / (2.0 * slope)  # um: h[nm] = 1000 r^2 / (2 R)
    theta = jnp.asarray([np.log(radius), cx, cy, h0, np.log(gain)])
    xj, yj, lj, sj, obs = (jnp.asarray(a) for a in (x, yy, lum, sin2, y))

    def model(t):
        r = jnp.sqrt((xj - t[1]) ** 2 + (yj - t[2]) ** 2)
        h = jnp.clip(newton_gap(r, jnp.exp(t[0]), t[3]), lo, hi)
        return jnp.exp(t[4]) * lj[:, None] * fwd.rgb(h, sj)

    def gap(t):
        return jnp.clip(newton_gap(jnp.sqrt((xj - t[1]) ** 2 + (yj - t[2]) ** 2), jnp.exp(t[0]), t[3]), lo, hi)

    theta, r, cost, J = fit_colours(model, obs, sigma, high, theta, iters)
    # the rings' order is the contact offset's: every ring moves with it (bubblefit.inverse.order_check)
    order = fit_order(fwd, model, gap, obs, sigma, high, (theta, r, cost, J), {"contact_offset_nm": 3}, sin2, lo, hi,
                      iters)
    dof = max(len(r) - 5, 1)
    cov = np.linalg.pinv(J.T @ J) * (cost / dof)
    t = np.asarray(theta, np.float64)
    radius_um = float(np.exp(t[0]))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    rr = np.sqrt((x - t[1]) ** 2 + (yy - t[2]) ** 2)
    h = np.asarray(newton_gap(jnp.asarray(rr), radius_um, t[3]))
    # standard error of h(r) from the covariance of (log R, cx, cy, h0)
    hj = jax.jacfwd(lambda q: newton_gap(jnp.sqrt((xj - q[1]) ** 2 + (yj - q[2]) ** 2), jnp.exp(q[0]), q[3]))(theta)
    hj = np.asarray(hj, np.float64)
    h_se = np.sqrt(np.clip(np.einsum("pi,ij,pj->p", hj, cov, hj), 0.0, None))
    params = {"radius_mm": radius_um / 1000.0, "center_x_um": float(t[1]), "center_y_um": float(t[2]),
              "contact_offset_nm": float(t[3]), "exposure": float(np.exp(t[4]))}
    stderr = {"radius_mm": radius_um / 1000.0 * float(se[0]), "center_x_um": float(se[1]),
              "center_y_um": float(se[2]), "contact_offset_nm": float(se[3]), "exposure": float(np.exp(t[4]) * se[4])}
    return ModelFit(params=params, stderr=stderr, thickness=h, thickness_stderr=h_se,
                     model=np.asarray(model(theta), np.float64), gain=float(np.exp(t[4])), order=order)
