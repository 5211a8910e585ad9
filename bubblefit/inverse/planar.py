"""Thickness of a flat film or a gap from one colour photo: per-pixel maps and Newton's rings.

The forward model of a pixel ``p`` on the film is

    ``y_p = g L_p rgb(R(d_p, lambda, theta_p))``

with ``R`` the film's reflectance between its two media (the three-media Airy sum,
:func:`bubblefit.optics.film.airy_reflectance`), averaged over the objective's cone for
coaxial light (:mod:`bubblefit.optics.coaxial`) or taken at the pixel's angle under an
area light (:mod:`bubblefit.lighting.area`, radiance ``L_p``), integrated to the camera's
RGB under the lamp (:mod:`bubblefit.optics.spectral`), and ``g`` the unknown exposure.

A per-pixel map (``thickness = "map"``) is found in four vectorised stages:

1. *Table and exposure*: the colours of thicknesses ``d_j`` on a 2 nm grid (per angle
   node for an area light, interpolated linearly in ``sin^2``), and the exposure ``g``
   minimising the summed best-candidate misfit over a subsample of pixels.
2. *Cost volume*: ``C[p, j] = |y_p - g L_p T_j|^2`` for every pixel and candidate.
3. *Order from a reference*: colour alone is ambiguous between interference orders, so
   the order is carried from a reference (the thinnest, darkest first-order pixels -- a
   black film or a contact point -- or a region of known thickness) to its neighbours, a
   front at a time: each pixel on the front takes the best candidate within a window of
   +-0.3 fringe around the linear extrapolation of its assigned neighbours. The window
   (0.3 of the fringe spacing ``lambda / (2 n)`` at 550 nm) is narrower than the distance
   to the next order's similar colour and wider than a pixel-to-pixel step of a resolved
   fringe pattern (at least 3.3 pixels per fringe).
4. *Refinement*: Gauss-Newton in ``d`` per pixel on the exact forward model (vmapped), with
   the standard error ``sigma / |dy/dd|`` from the noise ``sigma`` estimated from the
   residuals (median absolute deviation).

Newton's rings (``thickness = "newton"``): a lens of radius ``R`` on a plate leaves the gap
``h(r) = R - sqrt(R^2 - r^2) + h0`` around the contact point ``(cx, cy)``; the map gives
the start (centre of the thinnest pixels, ``R`` and ``h0`` from a line in ``r^2``) and
Levenberg-Marquardt fits ``(R, cx, cy, h0, g)`` to the colours directly, with standard
errors from ``sigma^2 (J^T J)^-1``; with them, by default, a grey reflectance ``b >= 0``
added to the gap's, the light of the other surfaces that does not interfere, and where the
rings span enough fringes the lamp's smooth envelope ``E`` across the field
(``y_p = g E_p L_p rgb(R(h_p) + b)``; :func:`._newton.fit_newton`).

With a calibrated response that states its errors, a constant film, a drainage profile,
Newton's rings and a map whose order is its drainage profile's carry the order test of
:mod:`bubblefit.inverse.order_check` (:func:`._planar_lm.fit_order`: the model refitted one
fringe away, the candidates compared with the response's errors marginalised); a map
ordered from the black film or a named region takes the reference's order. With a
response taken as exact, a constant film whose colour another order matches within a
pixel's noise is flagged instead (:func:`_constant_thickness`).

References
----------
M. Born and E. Wolf, *Principles of Optics*, 7th ed., sec. 7.5.3 (Newton's rings) and
7.6 (multiple-beam fringes); D. W. Marquardt, "An algorithm for least-squares estimation
of nonlinear parameters", J. SIAM 11, 431-441 (1963).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ComputationError, InputError
from ..optics import coaxial
from ..model.planar_scene import ENVELOPE_DEFAULT, STRAY_DEFAULT
from ..optics import dispersion, spectral
from ._censored import BLACK_CLIP, censored_residual
from ._drainage_plane import EXPONENT_RANGE, film_height, fit_drainage
from ._options import JudgeSettings

__all__ = ["PlanarView", "PlanarForward", "PlanarResult", "fit_planar", "view_of"]

#: Step of the thickness candidates (nm): below a tenth of the narrowest fringe of the
#: colour table (lambda / (2 n) = 140 nm at 380 nm, n = 1.35), so the search lands within
#: the refinement's reach.
GRID_STEP_NM = 2.0
#: Deviation from the mean of the four neighbours (nm) that the relaxation weighs like one
#: pixel's noise (3 sigma^2): ten times the 1.5 nm a 1 um-per-100-pixel drainage slope
#: bends per pixel, far above a Newton lens's curvature (0.8 nm per pixel^2 at R = 100 mm,
#: 9 um pixels), and below the 20-30 nm between neighbouring minima of the colour cost.
#: The planar fit (this relaxation, the censoring of clipped channels) was developed on the
#: validation cases film_drain_water_area and film_newton_bk7_na010.
RELAX_NM = 15.0
#: Spectral samples of the fitting basis: 5 nm bins, fine enough for fringes 50 nm wide
#: (a 3 um air gap at 550 nm).
SPECTRAL_SAMPLES = 80
#: Optical thickness ``n d`` (nm) whose fringes :data:`SPECTRAL_SAMPLES` resolve: at 550 nm
#: the fringes of ``n d`` are ``550^2 / (2 n d)`` nm apart in wavelength (Born and Wolf,
#: *Principles of Optics*, sec. 7.5.3), 50 nm at 3000 nm, ten bins of 5 nm.
#: :meth:`PlanarForward.reaching` narrows the bins in proportion beyond it.
SPECTRAL_REACH_NM = 3000.0


@dataclass(frozen=True)
class PlanarView:
    """Per pixel (H, W): on the film (``mask``), ``sin2`` of the incidence in air, the light's
    ``radiance`` there, the film coordinates in microns (``x_um``, ``y_um``; scene units
    under an area light), and the ``height`` along the film's up direction normalised to
    its frame (+1 at the top edge, -1 at the bottom; :func:`._drainage_plane.film_height`;
    under coaxial light the image's top row is the film's top)."""

    mask: np.ndarray
    sin2: np.ndarray
    radiance: np.ndarray
    x_um: np.ndarray
    y_um: np.ndarray
    height: np.ndarray


def view_of(scene) -> PlanarView:
    """The :class:`PlanarView` of a :class:`~bubblefit.model.planar_scene.PlanarScene`."""
    h, w = scene.height, scene.width
    if scene.light == "coaxial":
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
        return PlanarView(mask=np.ones((h, w), bool), sin2=np.zeros((h, w)), radiance=np.ones((h, w)),
                          x_um=xx * scene.pixel_um, y_um=yy * scene.pixel_um,
                          height=film_height(yy - 0.5 * h, h, top_is_positive=False))
    from ..lighting.area import view_plane

    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    o, d = scene.camera.rays(jnp.asarray(rows), jnp.asarray(cols))
    v = view_plane(np.asarray(o, np.float64), np.asarray(d, np.float64), scene.plane, scene.area)
    # A pixel counts when its whole footprint shows the film and the light: the rays
    # through its four corners too. A pixel that the frame's edge or the light's mirror
    # image crosses mixes the film with what lies beyond (a camera integrates over the
    # pixel), and reads as a dimmer film of another colour (on Blender Cycles' framed film,
    # validation case cyc_film_drain_panel, such edge pixels read as order hops).
    cr, cc = np.mgrid[0:h + 1, 0:w + 1].astype(np.float64) - 0.5
    oc, dc = scene.camera.rays(jnp.asarray(cr), jnp.asarray(cc))
    vc = view_plane(np.asarray(oc, np.float64), np.asarray(dc, np.float64), scene.plane, scene.area, strict=False)
    seen = vc.mask & (vc.radiance > 0)
    whole = seen[:-1, :-1] & seen[1:, :-1] & seen[:-1, 1:] & seen[1:, 1:]
    mask = v.mask & (v.radiance > 0) & whole
    if not np.any(mask):
        raise InputError("the area light is not seen in the film from this camera (no pixel reflects it)")
    return PlanarView(mask=mask, sin2=v.sin2_air, radiance=v.radiance, x_um=v.x, y_um=v.y,
                      height=film_height(v.y, scene.plane.size[1]))


class PlanarForward:
    """``rgb(d, sin2)``: the film's colour under the scene's lamp and camera (module equation)."""

    def __init__(self, stack: coaxial.Stack, lamp: str, response: str, na: float, max_nm: float,
                 samples: int = SPECTRAL_SAMPLES):
        self.basis = spectral.spectral_basis("uniform", samples, illuminant=lamp, response=response)
        self.stack, self.lamp, self.response = stack, lamp, response
        # the wavelengths the lamp lights and the camera sees: the others weigh 0 in every
        # channel and add nothing to the colour (a line lamp lights a few of the bins)
        lit = np.any(np.asarray(self.basis.weights) != 0.0, axis=1)
        lam = self.basis.wavelengths[lit]
        #: (K, 3) the RGB weights of the lit wavelengths :attr:`lam` (the basis's rows).
        self.weights = np.asarray(self.basis.weights)[lit]
        self.lam = jnp.asarray(lam)
        self.n = stack.indices(lam)
        self.na = float(na)
        #: The thickness (nm) up to which the cone's nodes and the spectral bins suffice.
        self.max_nm = float(max_nm)
        n_min = float(np.min(self.n.film))
        self.nodes = coaxial.cone_nodes_needed(max_nm, self.na, n_min) if self.na > 0 else 1
        #: Fringe spacing at 550 nm (nm of thickness), for the order window.
        self.fringe_nm = 550.0 / (2.0 * float(dispersion.refractive_index(stack.film, 550.0)))

    def rgb(self, d, sin2, stray=0.0, span=None):
        """(..., 3) colour of thickness ``d`` seen at ``sin2`` (ignored under coaxial light),
        with ``stray`` (a grey reflectance, scalar) added to the film's: the light of the
        other surfaces that reaches the camera without interfering with the film's two
        beams (a lens's top, a plate's bottom, scatter), summed in intensity (Born and Wolf,
        *Principles of Optics*, sec. 7.5.1: beams without a fixed phase relation add their
        intensities; sec. 7.5.3, Newton's rings as the interference of the gap's two
        reflections). ``span``: the mean over a pixel's box, as in :meth:`reflectance`."""
        return spectral.integrate(self.reflectance(d, sin2, span=span) + stray, self)  # the lit rows' weights

    def reaching(self, max_nm: float) -> "PlanarForward":
        """The same forward for thicknesses up to ``max_nm``: the cone's nodes
        (:func:`~bubblefit.optics.coaxial.cone_nodes_needed`) and spectral bins narrowed
        in proportion to the optical thickness beyond :data:`SPECTRAL_REACH_NM` (a tenth of
        a fringe at 550 nm each; at most the reference basis's
        :data:`~bubblefit.optics.spectral.REFERENCE_SAMPLES`); itself where it already
        reaches ``max_nm``."""
        if max_nm <= self.max_nm:
            return self
        optical = float(np.max(np.asarray(self.n.film))) * max_nm
        samples = int(min(spectral.REFERENCE_SAMPLES,
                          max(SPECTRAL_SAMPLES, math.ceil(SPECTRAL_SAMPLES * optical / SPECTRAL_REACH_NM))))
        return PlanarForward(self.stack, self.lamp, self.response, self.na, max_nm, samples)

    def reflectance(self, d, sin2, lam=None, span=None):
        """(..., L) the stack's reflectance at thickness ``d`` seen at ``sin2`` (ignored under
        coaxial light), at the basis's wavelengths or at ``lam`` (nm). ``span`` ``(span_x,
        span_y)`` shaped like ``d``: the thickness's change across each pixel's box along its
        two sides (nm), whose mean over the box is taken
        (:func:`~bubblefit.optics.coaxial.reflectance_at_angles`); None: at ``d``."""
        d = jnp.asarray(d)[..., None]
        if span is not None:
            span = tuple(jnp.asarray(s)[..., None] for s in span)
        n = self.n if lam is None else self.stack.indices(np.asarray(lam))
        lam = self.lam if lam is None else jnp.asarray(lam)
        if self.na > 0:
            return coaxial.coaxial_reflectance(d, lam, n, self.na, self.nodes, span)
        return coaxial.reflectance_at_angles(d, lam, n, jnp.asarray(sin2)[..., None], span)

    def response_error(self):
        """The response's stated errors (:func:`~bubblefit.inverse.response_error.response_error`
        at the film's median index), or None for a response taken as exact."""
        from .response_error import response_error

        return response_error(self.response, self.lamp, float(np.median(np.asarray(self.n.film))))

    def marginal_chi2(self, err, jac, resid, model, d, sin2, sigma: float) -> tuple[float, float]:
        """:func:`~bubblefit.inverse.response_error.marginal_chi2` of a few-parameter fit:
        ``jac`` (P 3, p) and ``resid`` (P 3,) the residual whitened by the noise ``sigma``
        and its Jacobian, ``model`` (P, 3) the pixels' colours at thicknesses ``d`` (P,)
        seen at ``sin2`` (P,), through the stack's reflectance; ``err`` None: the response
        taken as exact."""
        from .response_error import marginal_chi2

        d, s2 = np.asarray(d, np.float64), np.asarray(sin2, np.float64)

        def refl(i):
            return np.asarray(self.reflectance(d[i], s2[i], err.wavelengths), np.float64)

        n = len(d)
        return marginal_chi2(err, jac, resid, np.full((n, 1, 3), 1.0 / sigma), np.asarray(model)[:, None], None,
                             d[:, None], np.ones((n, 1)), refl)

    def camera_covariance(self, jac, model, d, sin2, sigma: float):
        """``(J^T J)^-1 G_R (J^T J)^-1``: a calibrated response's share of a few-parameter
        model's covariance, ``G_R`` from :func:`~bubblefit.inverse.response_error.response_gram`
        over the pixels' colours ``model`` (P, 3) at thicknesses ``d`` (P,) seen at ``sin2``
        (P,), through the stack's reflectance, with ``jac`` (P 3, p) the Jacobian of the
        residual whitened by the noise ``sigma``; None for a response taken as exact."""
        from .response_error import response_error, response_gram

        err = response_error(self.response, self.lamp, float(np.median(np.asarray(self.n.film))))
        if err is None:
            return None
        d, s2 = np.asarray(d, np.float64), np.asarray(sin2, np.float64)

        def refl(i):
            return np.asarray(self.reflectance(d[i], s2[i], err.wavelengths), np.float64)

        n = len(d)
        gram = response_gram(err, jac, np.full((n, 1, 3), 1.0 / sigma), np.asarray(model)[:, None], None,
                             d[:, None], np.ones((n, 1)), refl)
        a_inv = np.linalg.pinv(jac.T @ jac)
        return a_inv @ gram @ a_inv

    def camera_shifts(self, model, d, sin2, sigma: float):
        """:func:`~bubblefit.inverse.response_error.pixel_thickness_shifts` of the pixels'
        colours ``model`` (P, 3) at thicknesses ``d`` (P,) seen at ``sin2`` (P,) with the
        noise ``sigma``, through the stack's reflectance (no background: the film's
        reflection is the whole pixel); None for a response taken as exact."""
        from .response_error import pixel_thickness_shifts, response_error

        err = response_error(self.response, self.lamp, float(np.median(np.asarray(self.n.film))))
        if err is None:
            return None
        s2 = np.asarray(sin2, np.float64)
        def refl(x):
            return np.asarray(self.reflectance(np.asarray(x, np.float64), s2, err.wavelengths), np.float64)

        return pixel_thickness_shifts(err, model, None, d, np.ones(len(d)), np.full(np.shape(model), 1.0 / sigma), refl)


@dataclass
class PlanarResult:
    """What a planar fit found (typed record; :meth:`to_json` for the command line)."""

    kind: str
    ok: bool
    thickness_map: np.ndarray           # nm, NaN off the film
    thickness_stderr_map: np.ndarray    # nm
    render: np.ndarray
    residual: np.ndarray
    gain: float
    sigma: float
    params: dict = field(default_factory=dict)
    stderr: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    order_hops: int = 0
    reduced_chi2: float = float("nan")
    reduced_chi2_floor: float = float("nan")
    order_from: str = ""
    #: Each value's standard error from a calibrated response's stated errors alone
    #: (already in ``stderr``; :mod:`bubblefit.inverse.response_error`), or None where the
    #: response is taken as exact or the term is not computed.
    stderr_camera: dict | None = None
    #: The order test with a calibrated response's errors marginalised
    #: (:meth:`bubblefit.inverse.order_check.OrderCheck.to_json`) of a constant film, a
    #: drainage profile, Newton's rings or a map whose order is its profile's; None otherwise.
    order_check: dict | None = None
    #: What the fit says that does not make it wrong (Newton's rings aliased beyond the
    #: pixels' Nyquist limit, left out of the fit and of the chi-squared).
    notes: list = field(default_factory=list)

    @property
    def residual_rms(self) -> float:
        """RMS of ``photo - render`` over the film's pixels (as a bubble fit's ``residual_rms``)."""
        r = self.residual[np.isfinite(self.thickness_map)]
        return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")

    def to_json(self) -> dict:
        m = self.thickness_map[np.isfinite(self.thickness_map)]
        return {"kind": self.kind, "ok": self.ok, "warnings": self.warnings, "params": self.params,
                "stderr": self.stderr, "gain": self.gain, "noise_sigma": self.sigma,
                "reduced_chi2": self.reduced_chi2, "reduced_chi2_floor": self.reduced_chi2_floor,
                "order_from": self.order_from, "order_hops": self.order_hops, "stderr_camera": self.stderr_camera,
                "order_check": self.order_check, "notes": self.notes,
                "thickness_nm": {"min": float(m.min()), "median": float(np.median(m)), "max": float(m.max()),
                                 "median_stderr": float(np.nanmedian(self.thickness_stderr_map))} if m.size else None}

    def report(self) -> str:
        lines = [f"{k} = {v:.6g} +- {self.stderr.get(k, float('nan')):.3g}" for k, v in self.params.items()]
        j = self.to_json()["thickness_nm"]
        if j:
            lines.append(f"thickness {j['min']:.1f} .. {j['max']:.1f} nm (median {j['median']:.1f}, "
                         f"median standard error {j['median_stderr']:.2f} nm)")
        lines.append(f"ok: {'yes' if self.ok else 'no'}; reduced chi^2 {self.reduced_chi2:.3g} "
                     f"({self.reduced_chi2_floor:.3g} with the model-error floor); "
                     f"order hops {self.order_hops}" + ("; " + "; ".join(self.warnings) if self.warnings else "")
                     + ("; note: " + "; ".join(self.notes) if self.notes else ""))
        return "\n".join(lines)


def _table(fwd: PlanarForward, grid: np.ndarray, sin2_nodes: np.ndarray) -> np.ndarray:
    """(S, D, 3) colours of every candidate thickness at each ``sin2`` node."""
    f = jax.jit(lambda d, s: fwd.rgb(d, s))
    return np.stack([np.asarray(f(jnp.asarray(grid), jnp.full(grid.shape, s))) for s in sin2_nodes])


def _pixel_tables(table: np.ndarray, sin2_nodes: np.ndarray, sin2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices and weights interpolating the table linearly in ``sin2`` for each pixel."""
    if len(sin2_nodes) == 1:
        z = np.zeros(sin2.shape, int)
        return z, z, np.zeros(sin2.shape)
    pos = np.interp(sin2, sin2_nodes, np.arange(len(sin2_nodes)))
    i0 = np.minimum(np.floor(pos).astype(int), len(sin2_nodes) - 2)
    return i0, i0 + 1, pos - i0


@jax.jit
def _cost_chunk(y, lum, table, i0, i1, a, gain, high):
    t = (1.0 - a)[:, None, None] * table[i0] + a[:, None, None] * table[i1]
    r = censored_residual(y[:, None, :], gain * lum[:, None, None] * t, high)
    return jnp.sum(r * r, axis=-1)


def _costs(y, lum, table, i0, i1, a, gain, high=np.inf, chunk=1024):
    """(P, D) cost volume ``|y - g L T|^2`` (censored, :func:`censored_residual`), compiled and
    chunked over pixels (one shape for every chunk)."""
    n = len(y)
    out = np.empty((n, table.shape[1]), np.float32)
    tab = jnp.asarray(table, jnp.float32)
    for s in range(0, n, chunk):
        part = [np.asarray(v[s:s + chunk]) for v in (y, lum, i0, i1, a)]
        k = len(part[0])
        if k < chunk:
            part = [np.concatenate([v, np.repeat(v[-1:], chunk - k, axis=0)]) for v in part]
        yc, lc, ic0, ic1, ac = part
        c = _cost_chunk(jnp.asarray(yc, jnp.float32), jnp.asarray(lc, jnp.float32), tab, jnp.asarray(ic0),
                        jnp.asarray(ic1), jnp.asarray(ac, jnp.float32), jnp.float32(gain), jnp.float32(high))
        out[s:s + k] = np.asarray(c)[:k]
    return out


def _find_gain(y, lum, table, i0, i1, a, rng, high=np.inf) -> float:
    """The exposure minimising the summed best-candidate misfit (its best 90 %) over 1500
    pixels: 16 factors over [0.5, 2.5] x the ratio of the photo's and the table's peaks,
    then 16 within one step of the best (1.4 % apart; the least-squares update after the
    refinement takes it the rest of the way)."""
    idx = rng.choice(len(y), size=min(len(y), 1500), replace=False)
    peak = float(np.percentile(y[idx].max(-1) / np.maximum(lum[idx], 1e-9), 99.5))
    base = peak / max(float(table.max()), 1e-9)

    def score(g):
        c = _costs(y[idx], lum[idx], table, i0[idx], i1[idx], a[idx], g, high).min(1)
        return np.sort(c)[: int(0.9 * len(idx))].sum()

    coarse = base * np.geomspace(0.5, 2.5, 16)
    best = coarse[int(np.argmin([score(g) for g in coarse]))]
    ratio = (2.5 / 0.5) ** (1 / 15)
    fine = best * np.geomspace(1 / ratio, ratio, 16)
    return float(fine[int(np.argmin([score(g) for g in fine]))])


def _propagate(cost: np.ndarray, grid: np.ndarray, mask: np.ndarray, seed_d: np.ndarray, window_nm: float,
               smooth: float, relax_weight: float, relax_passes: int = 12) -> np.ndarray:
    """Carry the interference order from the seeds over the film, a front of pixels at a time.

    ``cost`` (P, D) over the mask's pixels, ``seed_d`` (H, W) with the seeds' thickness and
    NaN elsewhere. Each front pixel takes the candidate within ``window_nm`` of the mean
    linear extrapolation of its assigned 4-neighbours that minimises
    ``C + smooth (d - prediction)^2``. Vectorised over pixels with ``jax.lax.while_loop``.
    """
    h, w = mask.shape
    step = grid[1] - grid[0]
    half = int(math.ceil(window_nm / step))
    offsets = jnp.arange(-half, half + 1)
    pix = np.flatnonzero(mask.ravel())
    full_cost = np.full((h * w, cost.shape[1]), np.inf, np.float32)
    full_cost[pix] = cost
    full_cost = jnp.asarray(full_cost)
    gridj = jnp.asarray(grid, jnp.float32)
    maskj = jnp.asarray(mask)

    def shifted(a, dy, dx, fill):
        a = jnp.roll(a, (dy, dx), axis=(0, 1))
        if dy > 0:
            a = a.at[:dy].set(fill)
        if dy < 0:
            a = a.at[dy:].set(fill)
        if dx > 0:
            a = a.at[:, :dx].set(fill)
        if dx < 0:
            a = a.at[:, dx:].set(fill)
        return a

    def step_fn(state):
        d, _ = state
        known = jnp.isfinite(d)
        pred_sum = jnp.zeros_like(d)
        count = jnp.zeros_like(d)
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            d1 = shifted(d, dy, dx, jnp.nan)
            d2 = shifted(d, 2 * dy, 2 * dx, jnp.nan)
            p = jnp.where(jnp.isfinite(d2), 2 * d1 - d2, d1)
            ok = jnp.isfinite(d1)
            pred_sum = pred_sum + jnp.where(ok, p, 0.0)
            count = count + ok
        front = maskj & ~known & (count > 0)
        pred = (pred_sum / jnp.maximum(count, 1)).ravel()
        best = choose(pred, smooth).reshape(h, w)
        return jnp.where(front, best, d), jnp.any(front)

    def choose(pred, weight):
        centre = jnp.clip(jnp.round((pred - gridj[0]) / step).astype(jnp.int32), 0, len(grid) - 1)
        idx = jnp.clip(centre[:, None] + offsets[None, :], 0, len(grid) - 1)
        c = jnp.take_along_axis(full_cost, idx, axis=1) + weight * (gridj[idx] - pred[:, None]) ** 2
        return gridj[jnp.take_along_axis(idx, jnp.argmin(c, axis=1)[:, None], axis=1)[:, 0]]

    d0 = jnp.asarray(np.where(mask, seed_d, np.nan), jnp.float32)
    d, _ = jax.lax.while_loop(lambda s: s[1], step_fn, (d0, jnp.array(True)))

    # Relaxation: each pixel again takes the best candidate near the mean of its four
    # neighbours, now with the smoothness of a plane (a Laplacian prior, unbiased for a
    # linear slope), updating the two colours of a checkerboard in turn (iterated
    # conditional modes). It mends whole fronts that took a neighbouring local minimum.
    checker = jnp.asarray((np.add.outer(np.arange(h), np.arange(w)) % 2).astype(bool))

    def relax(_, d):
        for colour in (checker, ~checker):
            acc = jnp.zeros_like(d)
            cnt = jnp.zeros_like(d)
            for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                d1 = shifted(d, dy, dx, jnp.nan)
                ok = jnp.isfinite(d1)
                acc = acc + jnp.where(ok, d1, 0.0)
                cnt = cnt + ok
            pred = jnp.where(cnt > 0, acc / jnp.maximum(cnt, 1), d).ravel()
            best = choose(pred, relax_weight).reshape(h, w)
            d = jnp.where(colour & maskj & jnp.isfinite(d), best, d)
        return d

    d = jax.lax.fori_loop(0, relax_passes, relax, d)
    return np.asarray(d, np.float64)


def _refine(fwd: PlanarForward, y, lum, sin2, d, gain, lo, hi, high=np.inf, iters: int = 6):
    """Gauss-Newton in ``d`` per pixel on the exact colours (censored residuals), within two
    grid steps of the start (the order and the minimum were chosen on the grid); returns
    (d, |dr/dd|^2, model)."""
    key = (float(lo), float(hi), float(high), iters)
    if getattr(fwd, "_refine_key", None) != key:

        def one(yp, lp, sp, dp, g):
            def resid(t):
                return censored_residual(yp, g * lp * fwd.rgb(t, sp), high)

            def body(_, t):
                r, dr = jax.jvp(resid, (t,), (jnp.ones_like(t),))
                step = -jnp.sum(dr * r) / jnp.maximum(jnp.sum(dr * dr), 1e-20)
                return jnp.clip(t + step, jnp.maximum(dp - 2 * GRID_STEP_NM, lo), jnp.minimum(dp + 2 * GRID_STEP_NM, hi))

            t = jax.lax.fori_loop(0, iters, body, dp)
            _, dr = jax.jvp(resid, (t,), (jnp.ones_like(t),))
            return t, jnp.sum(dr * dr), g * lp * fwd.rgb(t, sp)

        fwd._refine_fn = jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, None)))
        fwd._refine_key = key
    f = fwd._refine_fn
    n = len(y)
    size = 4096
    out = []
    for s in range(0, n, size):
        part = [a[s:s + size] for a in (y, lum, sin2, d)]
        pad = size - len(part[0])
        if pad:  # one compiled shape for every chunk
            part = [np.concatenate([a, np.repeat(a[-1:], pad, axis=0)]) for a in part]
        r = f(*(jnp.asarray(a) for a in part), float(gain))
        out.append([np.asarray(v)[: size - pad] for v in r])
    return tuple(np.concatenate([o[k] for o in out]) for k in range(3))


def _recorded(y: np.ndarray, high: float) -> np.ndarray:
    """(n, 3) which readings the sensor recorded: neither clipped at black (``BLACK_CLIP``)
    nor at white (``high``): the censored channels carry no measure of the noise."""
    return (y > BLACK_CLIP) & (y < high)


#: Median of chi^2 with 1 and 2 degrees of freedom (2 ln 2 for 2).
_CHI2_MEDIAN = {1: 0.454936423119573, 2: 2.0 * math.log(2.0)}


def _noise_sigma(res: np.ndarray, y: np.ndarray, high: float) -> float:
    """Per-channel noise ``sigma`` from the residuals ``res`` (n, 3) of each pixel's own best
    thickness, over the photo's readings ``y`` (n, 3) that the sensor recorded
    (:func:`_recorded`): ``k`` recorded readings less one fitted thickness leave a residual
    whose squared length is ``sigma^2`` times a chi^2 of ``k - 1`` degrees of freedom,
    whatever the thickness's slope (the residual of a linear least-squares fit projects the
    noise; Seber & Lee, *Linear Regression Analysis*, 2nd ed., thm. 3.5). So ``sigma^2`` is
    the median of ``|r_p|^2`` over the pixels with the commonest ``k`` (3, or 2 where a
    channel is clipped on most of the film) over that chi^2's median, robust to the
    outliers a median ignores. The residuals' per-channel spread alone would read
    ``sqrt(2/3)`` of it or less: the fitted thickness takes up a third of the noise. With
    fewer than 20 such pixels, 1.4826 times the residuals' median absolute deviation."""
    r = np.asarray(res, np.float64)
    rec = _recorded(np.asarray(y, np.float64), high)
    k = rec.sum(axis=-1)
    counts = {dof: int(np.count_nonzero(k == dof + 1)) for dof in _CHI2_MEDIAN}
    dof = max(counts, key=counts.get)
    if counts[dof] < 20:
        return float(max(1.4826 * np.median(np.abs(r - np.median(r))), 1e-6))
    sq = np.sum(np.where(rec, r, 0.0) ** 2, axis=-1)[k == dof + 1]
    return float(max(np.sqrt(np.median(sq) / _CHI2_MEDIAN[dof]), 1e-6))


def _neighbour_sigma(image: np.ndarray, mask: np.ndarray) -> float | None:
    """The noise of a grey photo's pixels from differences between neighbours: at every film
    pixel whose four neighbours are film pixels too, ``d = e - mean(e of the 4 neighbours)``
    of the (H, W, 3) ``image`` ``e`` (channel 0: a grey photo's channels are one reading),
    and ``sigma = 1.4826 MAD(d) / sqrt(5/4)``, the variance of ``d`` being ``(1 + 4/16)``
    times a pixel's for noise independent between pixels. A signal that is smooth over a
    few pixels cancels in ``d`` to first order (a Laplacian: J. Immerkaer, "Fast noise
    variance estimation", Computer Vision and Image Understanding 64(2), 1996; the median
    keeps it robust to the pixels where it does not, as for
    :func:`bubblefit.inverse.colour_check.neighbour_scale`). None with fewer than 20 such
    pixels. A grey photo needs it: each pixel's own thickness reproduces its one reading
    exactly, so the residuals of :func:`_noise_sigma` hold no noise."""
    inner = np.zeros_like(mask)
    inner[1:-1, 1:-1] = mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2] & mask[1:-1, 2:]
    ys, xs = np.nonzero(inner)
    if ys.size < 20:
        return None
    e = np.asarray(image, np.float64)[..., 0]
    d = e[ys, xs] - 0.25 * (e[ys - 1, xs] + e[ys + 1, xs] + e[ys, xs - 1] + e[ys, xs + 1])
    return float(max(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(1.25), 1e-6))


def _photo_noise(photo: np.ndarray, mask: np.ndarray, y: np.ndarray, res: np.ndarray,
                 high: float) -> tuple[bool, float]:
    """``(grey, sigma)``: whether the photo is grey (its film pixels' three channels equal: a
    monochrome camera, a sodium lamp through a grey response) and its noise. A grey photo's
    one reading a pixel leaves each pixel's own thickness no residual, so its noise is read
    from neighbouring pixels (:func:`_neighbour_sigma`, on the photo here; :func:`fit_planar`
    reads it again on the fitted model's residual); a colour photo's from the residuals
    ``res`` of each pixel's own thickness (:func:`_noise_sigma`, clip ``high``)."""
    grey = bool(np.array_equal(y[:, 0], y[:, 1]) and np.array_equal(y[:, 1], y[:, 2]))
    sigma = (_neighbour_sigma(np.asarray(photo, np.float64), mask) if grey else None) or _noise_sigma(res, y, high)
    return grey, sigma


def _hops(dmap: np.ndarray, limit: float) -> int:
    """Neighbour pairs whose thickness differs by more than ``limit`` nm (order hops)."""
    a = np.abs(np.diff(dmap, axis=0))
    b = np.abs(np.diff(dmap, axis=1))
    return int(np.nansum(a > limit) + np.nansum(b > limit))


def _checked_region(scene, view, reference_region, reference_nm, w: int, h: int):
    """``(region, reference_nm)``: the reference region and its thickness, given or the
    scene's; a region outside the film is refused."""
    region = reference_region if reference_region is not None else scene.reference_region
    ref_nm = reference_nm if reference_nm is not None else scene.reference_nm
    if region is not None:
        x0, y0, x1, y1 = region
        if x0 < 0 or y0 < 0 or x1 > w or y1 > h or not view.mask[y0:y1, x0:x1].any():
            raise InputError(f"the reference region {x0},{y0},{x1},{y1} lies outside the film")
    return region, ref_nm


def _constant_thickness(y, lum, table, i0, i1, a, grid, fringe_nm: float, sigma2: float, warnings: list | None,
                        clip_high: float = np.inf):
    """``(gain, thickness per pixel)`` of a film of one thickness: each candidate of ``grid``
    with its own least-squares exposure (``g_j = sum y.T_j / sum |T_j|^2``; the exposure
    found first belongs to one order). Another order that fits nearly as well adds a
    warning to ``warnings`` (a near-neutral film whose brightness the unknown exposure
    absorbs); ``warnings`` None: no such warning (a response that states its errors, whose
    order test, :func:`_constant_order`, decides instead).

    Channels clipped at black or white are left out of these sums: a film colour outside
    the gamut records 0 in a channel where the model is negative, and a plain least-squares
    misfit there favours the order whose model is least negative (on Blender Cycles' 480 nm
    water film, validation case cyc_film_const_panel, red clipped: the third order at
    672 nm, whose hue is within 1.5 % of the second's)."""
    seen = ((y > BLACK_CLIP) & (y < clip_high)).astype(np.float64)
    A = np.zeros(len(grid))
    B = np.zeros(len(grid))
    for s in range(0, len(y), 1024):
        sl = slice(s, s + 1024)
        t = lum[sl, None, None] * ((1 - a[sl, None, None]) * table[i0[sl]] + a[sl, None, None] * table[i1[sl]])
        t = t * seen[sl, None, :]
        A += np.einsum("pc,pdc->d", y[sl], t)
        B += np.einsum("pdc,pdc->d", t, t)
    total = float(np.sum((y * y)[seen > 0])) - A * A / np.maximum(B, 1e-30)
    j = int(np.argmin(total))
    gain = float(A[j] / B[j])
    dpix = np.full(len(y), grid[j])
    # "Nearly": worse by less than one noise variance (sigma^2, summed over the channels)
    # per pixel on average, i.e. colours closer than the noise of a single pixel: a small
    # mismatch of the model (a dispersion law, the lamp: ~1e-3 of the signal against the
    # independent renderer) is common to all pixels and does not average out.
    far = np.abs(grid - grid[j]) > 0.75 * fringe_nm  # past the neighbouring minima of this order
    if warnings is not None and far.any() and (total[far].min() - total[j]) / len(y) < sigma2:
        alt = grid[far][int(np.argmin(total[far]))]
        warnings.append(f"the colour fits {grid[j]:.0f} nm and {alt:.0f} nm nearly as well (another order); "
                        "name the thickness of a region with --reference-region")
    return gain, dpix


def _drainage_start(cost, grid, view, mask, region, ref_nm, window: float):
    """``(start, order_from)`` of a drainage profile along gravity: its order from the colour
    sequence over the whole film (:func:`._drainage_plane.search_drainage`); a named region,
    if any, narrows the search to profiles through its value."""
    from ._drainage_plane import search_drainage

    ref = None
    if region is not None:
        h, w = mask.shape
        x0, y0, x1, y1 = region
        inside = np.zeros((h, w), bool)
        inside[y0:y1, x0:x1] = True
        ref = (float(np.mean((1.0 - view.height[inside & mask]) * 0.5)), float(ref_nm))
    start = search_drainage(cost, grid, view.height[mask], ref, window)
    return start, "drainage profile" + (" through the reference region" if ref else "")


def _order_seeds(y, lum, cost, best, grid, mask, region, ref_nm, lo: float, fringe_nm: float, window: float,
                 frame_height=None):
    """``(seeds, order_from, profile)``: (H, W) thicknesses that fix the interference order
    (NaN elsewhere): the reference region's, each pixel's best candidate within ``window``
    of ``ref_nm``; without one, the black film or contact point; without those, on a
    framed film under an area light (``frame_height``: each pixel's height along the
    frame's up direction), its drainage profile, whose ``(top, bottom, exponent)`` is then
    ``profile`` (None otherwise: the order is the reference's)."""
    h, w = mask.shape
    seeds = np.full((h, w), np.nan)
    if region is not None:
        x0, y0, x1, y1 = region
        inside = np.zeros((h, w), bool)
        inside[y0:y1, x0:x1] = True
        sel = inside[mask]
        near = np.abs(grid - ref_nm) <= window
        jj = np.flatnonzero(near)
        pick = grid[jj[np.argmin(cost[sel][:, jj], axis=1)]]
        seeds[inside & mask] = pick
        return seeds, "reference region", None
    # A black film or a contact point: pixels that match a film thinner than 0.3
    # fringe (82 nm of air, 62 nm of water at 550 nm: the dark grey end of the colour
    # chart) and are dark (below 0.35 x the median brightness, which a thick film
    # fading to its grey mean reflectance, the other neutral colour, never is).
    bright = y.sum(-1) / np.maximum(lum, 1e-9)
    thin = best <= lo + 0.3 * fringe_nm
    good = cost.min(1) <= np.percentile(cost.min(1), 75)
    pick = thin & good & (bright <= 0.35 * np.median(bright))
    order_from, profile = "thinnest", None
    if pick.sum() < 3 and frame_height is not None:
        # A framed film without a black film: the order of its drainage profile along the
        # frame's up direction (a global fit over the whole film, :mod:`._drainage_plane`),
        # kept at the pixels whose best colour match lies within half the order window of
        # it; the rest follow from them, so a local departure from the profile (a thicker
        # swirl) keeps its own map (chosen on validation case cyc_film_drain_panel, which
        # has no black film).
        from ..model.thickness import drainage_profile
        from ._drainage_plane import search_drainage

        profile = search_drainage(cost, grid, frame_height[mask])
        prof = np.asarray(drainage_profile(frame_height[mask], *profile))
        pick = good & (np.abs(best - prof) <= 0.5 * window)
        order_from = "drainage profile"
    if pick.sum() < 3:
        raise InputError("no reference for the interference order: the photo has no black film or contact "
                         "point; name a region of known thickness with --reference-region x0,y0,x1,y1=NM")
    flat = seeds.reshape(-1)
    flat[np.flatnonzero(mask.ravel())[pick]] = best[pick]
    return flat.reshape(h, w), order_from, profile


def _exponent_at_edge(exponent: float) -> list[str]:
    """A warning when a drainage profile's exponent sits at the edge of its range: the film
    does not thin along its up direction as a drainage profile does."""
    lo, hi = EXPONENT_RANGE
    if min(abs(exponent / lo - 1), abs(exponent / hi - 1)) < 1e-3:
        return [f"the drainage exponent sits at the edge of its range {lo:g}-{hi:g}: the film does not follow "
                "a drainage profile along its up direction"]
    return []


def _on_image(mask, values, fill, channels: int = 0) -> np.ndarray:
    """``values`` of the film's pixels placed on the (H, W) or (H, W, channels) image, ``fill`` elsewhere."""
    out = np.full(mask.shape + ((channels,) if channels else ()), fill)
    out[mask] = values
    return out


def range_edge_warning(d, lo: float, hi: float, what: str) -> list[str]:
    """A warning when more than 5 % of the thicknesses ``d`` sit at an end of the searched
    range ``lo``-``hi`` nm (the film may lie outside it), else none; ``what``: the film's
    name in the message."""
    edge = (np.asarray(d) <= lo + 1e-6) | (np.asarray(d) >= hi - 1e-6)
    if edge.mean() <= 0.05:
        return []
    return [f"{100 * edge.mean():.0f} % of the {what} sits at the edge of the searched range {lo:g}-{hi:g} nm"]


def _with_camera_term(fwd, kind: str, model, dref, sin2, sigma, perr: dict, stderr):
    """A constant film's or a map's errors widened by the calibrated response's share
    (:meth:`PlanarForward.camera_shifts`: one draw of the response moves every pixel
    together, so a constant film's share is the shift of the pixels' Jacobian-weighted
    mean): ``(perr, stderr, stderr_camera)``, unchanged with ``None`` for a response taken
    as exact."""
    moved = fwd.camera_shifts(model, dref, sin2, sigma)
    if moved is None:
        return perr, stderr, None
    shifts, jj = moved
    if kind == "constant":
        cam = float(np.sqrt(np.sum((np.tensordot(jj, shifts, axes=1) / max(float(jj.sum()), 1e-300)) ** 2)))
        perr = {**perr, "thickness_nm": float(np.hypot(perr["thickness_nm"], cam))}
    else:
        pix = np.sqrt(np.sum(shifts**2, axis=(1, 2)))
        stderr = np.hypot(stderr, pix)
        cam = float(np.median(pix))
    return perr, stderr, {"thickness_nm": cam}


def _profile_order(fwd, y, lum, sin2, view, mask, profile, gain, sigma, lo, hi, high):
    """The order test (:func:`._planar_lm.fit_order`) of a map whose order is its drainage
    profile's ``(top, bottom, exponent)`` along ``view.height``: that profile's, fitted
    for it (:func:`._drainage_plane.fit_drainage`); None without a profile or for a
    response taken as exact."""
    if profile is None or fwd.response_error() is None:
        return None
    return fit_drainage(fwd, y, lum, sin2, view.height[mask], profile, gain, sigma, lo, hi, mask.shape,
                        np.flatnonzero(mask.ravel()), high).order


def _constant_order(fwd, y, lum, sin2, thickness: float, gain: float, sigma: float, lo: float, hi: float, high):
    """The order test (:func:`._planar_lm.fit_order`) of a film of one thickness: the
    module equation ``y_p = g L_p rgb(d, theta_p)`` with one ``d`` for every pixel, fitted in
    ``(d, log g)`` by :func:`._planar_lm.fit_colours` from the per-pixel fit's
    ``thickness`` and exposure ``gain``, then again from one fringe thinner and thicker;
    None for a response taken as exact."""
    if fwd.response_error() is None:
        return None
    from ._planar_lm import fit_colours, fit_order

    lj, sj, obs = (jnp.asarray(a) for a in (lum, sin2, y))

    def film(t):
        return jnp.full(sj.shape, jnp.clip(t[0], lo, hi))

    def model(t):
        return jnp.exp(t[1]) * lj[:, None] * fwd.rgb(film(t), sj)

    fitted = fit_colours(model, obs, sigma, high, jnp.asarray([thickness, np.log(gain)]))
    return fit_order(fwd, model, film, obs, sigma, high, fitted, {"thickness_nm": 0}, sin2, lo, hi)


def _verdict(warnings: list[str], order, chi2_floor: float) -> bool:
    """Whether a flat film's fit is ``ok``: no warning (the order test's included, which is
    added to ``warnings``) and a reduced chi^2 with the model-error floor under 4; a larger
    one adds its own warning."""
    warnings += [w for w in [order and order.warning()] if w]
    ok = not warnings and chi2_floor < 4.0
    if chi2_floor >= 4.0:
        warnings.append(f"the model does not explain the photo (residual {math.sqrt(chi2_floor):.1f} x the noise "
                        "and the model error)")
    return ok


def _map_start(kind, scene, view, y, lum, cost, best, grid, region, ref_nm, fringe_nm, window, sigma2, warnings):
    """A thickness map's (or Newton's rings') per-pixel start: ``(dpix, order_from,
    map_profile)``. The order comes from the reference region or the film's own profile
    (:func:`_order_seeds`) and is carried to every pixel by :func:`_propagate` along the
    film's continuity; rings whose dark fringes stray light fills in show no dark contact
    point and start from each pixel's best match (the rings' model, :func:`._newton.fit_newton`,
    finds its own start from their symmetry and period). Pixels the propagation does not
    reach keep their best match, with a warning appended to ``warnings``."""
    mask = view.mask
    try:
        seeds, order_from, map_profile = _order_seeds(y, lum, cost, best, grid, mask, region, ref_nm, grid[0],
                                                      fringe_nm, window, view.height if scene.light == "area" else None)
    except InputError:
        if kind != "newton":
            raise
        seeds, map_profile = None, None
    if seeds is None:
        dmap, order_from = _on_image(mask, best.astype(np.float64), np.nan), "rings"
    else:
        dmap = _propagate(cost, grid, mask, seeds, window, smooth=3.0 * sigma2 / window ** 2,
                          relax_weight=3.0 * sigma2 / RELAX_NM ** 2)
    dpix = dmap[mask]
    if not np.all(np.isfinite(dpix)):
        warnings.append(f"{int((~np.isfinite(dpix)).sum())} film pixels are not connected to the reference")
        dpix = np.where(np.isfinite(dpix), dpix, best)
    return dpix, order_from, map_profile


def _refined_with_exposure(fwd, y, lum, sin2, dpix, gain: float, lo: float, hi: float, clip_high: float):
    """``(thickness, J^T J per pixel, model, exposure)``: each pixel's thickness refined
    (:func:`_refine`), the exposure by least squares on it over the channels not clipped,
    then each pixel refined once more at that exposure."""
    dref, _, model = _refine(fwd, y, lum, sin2, dpix, gain, lo, hi, clip_high)
    unit = model / gain
    seen = (y > BLACK_CLIP) & (y < clip_high)
    gain = float(np.sum((y * unit)[seen]) / max(float(np.sum((unit * unit)[seen])), 1e-20))
    dref, jj_, model = _refine(fwd, y, lum, sin2, dref, gain, lo, hi, clip_high)
    return dref, jj_, model, gain


def _reduced_chi2(res, y, sigma: float, fitted=None, per_pixel: bool = False,
                  high: float = np.inf) -> tuple[float, float]:
    """The reduced chi^2 of the residual ``res`` over the pixels the model was fitted to
    (``fitted``; Newton's rings: not where they alias), and with each channel's variance
    ``sigma^2 + (model_error y)^2``, the floor by which a bubble's fit is judged
    (``JudgeSettings.model_error``: how much independent renderers differ on the same
    film); ``ok`` is judged by the second. Both are over the degrees of freedom: the
    readings the sensor recorded (:func:`_recorded`, clip ``high``; at least one a pixel:
    a pixel's censored residual still counts), less one a pixel where ``per_pixel`` (a
    thickness fitted at every pixel: a map, and the constant film's per-pixel refinement)."""
    rf, yf = (res, y) if fitted is None else (res[fitted], y[fitted])
    k = np.maximum(np.sum(_recorded(yf, high), axis=-1), 1)
    dof = max(float(np.sum(k - 1 if per_pixel else k)), 1.0)
    chi2 = float(np.sum(rf ** 2) / sigma ** 2 / dof)
    return chi2, float(np.sum(rf ** 2 / (sigma ** 2 + (JudgeSettings.model_error * yf) ** 2)) / dof)


def fit_planar(photo: np.ndarray, scene, *, reference_region=None, reference_nm=None,
               kind: str | None = None, seed: int = 0, clip_high: float = np.inf) -> PlanarResult:
    """Fit a flat film's or a gap's thickness to a linear photo (H, W, 3) (the module's method).

    ``clip_high``: the sensor's white clip in the photo's units (1 for an 8/16-bit file,
    ``inf`` for linear EXR/HDR); channels at 0 or at ``clip_high`` are censored.
    """
    kind = kind or scene.thickness
    h, w = photo.shape[:2]
    if (h, w) != (scene.height, scene.width):
        raise InputError(f"the photo is {w}x{h}, the scene's camera {scene.width}x{scene.height}")
    view = view_of(scene)
    region, ref_nm = _checked_region(scene, view, reference_region, reference_nm, w, h)
    lo, hi = scene.thickness_range
    fwd = PlanarForward(scene.stack, scene.lamp, scene.response, scene.na, hi)
    grid = np.arange(lo, hi + 0.5 * GRID_STEP_NM, GRID_STEP_NM)
    mask = view.mask
    y = np.asarray(photo, np.float64).reshape(-1, 3)[mask.ravel()]
    lum = view.radiance[mask]
    sin2 = view.sin2[mask]
    # Every film reflects at least a few per cent of the lamp outside its black film; a
    # photo whose film pixels are 99 % darker than 0.02 (8-bit sRGB code 39) shows none.
    if float(np.percentile(y.max(-1), 99)) <= 0.02:
        raise InputError("the film does not appear in the photo (the pixels where it should be are dark)")
    if scene.light == "area" and sin2.max() - sin2.min() > 1e-6:
        nodes = np.linspace(sin2.min(), sin2.max(), 12)
    else:
        nodes = np.array([float(np.median(sin2))])
    table = _table(fwd, grid, nodes)
    i0, i1, a = _pixel_tables(table, nodes, sin2)
    gain = _find_gain(y, lum, table, i0, i1, a, np.random.default_rng(seed), clip_high)
    cost = _costs(y, lum, table, i0, i1, a, gain, clip_high)
    best = grid[np.argmin(cost, axis=1)]
    sigma2 = max(float(np.median(cost.min(1))) / 3.0, 1e-10)
    window = 0.3 * fwd.fringe_nm
    warnings: list[str] = []
    drain_camera = order = map_profile = fitted = None
    notes: list[str] = []

    if kind == "constant":  # the order test decides where the response states its errors
        gain, dpix = _constant_thickness(y, lum, table, i0, i1, a, grid, fwd.fringe_nm, sigma2,
                                         warnings if fwd.response_error() is None else None, clip_high)
        order_from = "colour"
    elif kind == "drainage":
        start, order_from = _drainage_start(cost, grid, view, mask, region, ref_nm, window)
        # the noise and the exposure come from each pixel's own best thickness, not from
        # the profile: a profile that does not describe the film (a film turned sideways)
        # must show as a misfit against the noise, not set the noise
        dpix = best.astype(np.float64)
    else:
        dpix, order_from, map_profile = _map_start(kind, scene, view, y, lum, cost, best, grid, region, ref_nm,
                                                   fwd.fringe_nm, window, sigma2, warnings)

    dref, jj_, model, gain = _refined_with_exposure(fwd, y, lum, sin2, dpix, gain, lo, hi, clip_high)
    res = censored_residual(y, model, clip_high, np)
    grey, sigma = _photo_noise(photo, mask, y, res, clip_high)
    stderr = sigma / np.sqrt(np.maximum(jj_, 1e-20))
    params, perr = {}, {}
    if kind == "constant":
        # the noise's error, widened by the Birge ratio for a misfit and with the
        # thickness model error of the bubble fits added in quadrature (as for a drainage
        # profile, :mod:`._drainage_plane`)
        dd = float(np.median(dref))
        params["thickness_nm"] = dd
        birge = max(1.0, float(np.mean(res ** 2) / sigma ** 2))
        perr["thickness_nm"] = float(np.hypot(sigma * np.sqrt(birge / np.sum(jj_)),
                                              JudgeSettings.thickness_model_error_nm))
        order = _constant_order(fwd, y, lum, sin2, dd, gain, sigma, lo, hi, clip_high)
    if kind == "drainage":
        dres = fit_drainage(fwd, y, lum, sin2, view.height[mask], start, gain, sigma, lo, hi, (h, w),
                            np.flatnonzero(mask.ravel()), clip_high)
        params, perr = dres.params, dres.stderr
        dref, model, gain = dres.thickness, dres.model, dres.gain
        stderr = dres.thickness_stderr
        drain_camera, order = dres.stderr_camera, dres.order
        res = censored_residual(y, model, clip_high, np)
        warnings.extend(_exponent_at_edge(params["exponent"]))
    if kind == "newton":
        from ._newton import fit_newton

        # the scene's stray light and lamp envelope where it names the newton model, else the model's defaults
        named = scene.thickness == "newton"
        nres = fit_newton(fwd, y, lum, sin2, view, mask, dref, gain, sigma, lo, hi, clip_high,
                          stray=scene.stray if named else STRAY_DEFAULT,
                          envelope=scene.envelope if named else ENVELOPE_DEFAULT)
        params, perr = nres.params, nres.stderr
        dref, model, gain = nres.thickness, nres.model, nres.gain
        stderr, order = nres.thickness_stderr, nres.order
        warnings.extend(nres.warnings)
        notes, fitted = nres.notes, nres.fitted
        res = censored_residual(y, model, clip_high, np)
    order = order or _profile_order(fwd, y, lum, sin2, view, mask, map_profile, gain, sigma, lo, hi, clip_high)
    if grey and kind != "map":  # the model's residual: the film's signal and a smooth misfit cancel
        sigma = _neighbour_sigma(_on_image(mask, res, 0.0, 3), mask) or sigma
    chi2, chi2_floor = _reduced_chi2(res, y, sigma, fitted, per_pixel=kind in ("constant", "map") and not grey,
                                     high=clip_high)
    stderr_camera = drain_camera if kind == "drainage" else None
    if kind in ("constant", "map"):
        perr, stderr, stderr_camera = _with_camera_term(fwd, kind, model, dref, sin2, sigma, perr, stderr)
    tmap = _on_image(mask, dref, np.nan)
    smap = _on_image(mask, stderr, np.nan)
    hops = _hops(tmap, window) if kind == "map" else 0
    if hops:
        warnings.append(f"{hops} neighbouring pixel pairs differ by more than {window:.0f} nm (possible order hops)")
    if kind != "newton":  # the lens's gap is not held within the range (:func:`._newton.fit_newton`)
        warnings.extend(range_edge_warning(dref, lo, hi, "film"))
    render = _on_image(mask, model, 0.0, 3)
    resid = _on_image(mask, res, 0.0, 3)
    ok = _verdict(warnings, order, chi2_floor)
    if not np.isfinite(tmap[mask]).all():
        raise ComputationError("the planar fit produced non-finite thicknesses")
    return PlanarResult(kind=kind, ok=ok, thickness_map=tmap, thickness_stderr_map=smap, render=render, residual=resid,
                        gain=gain, sigma=sigma, params=params, stderr=perr, warnings=warnings, order_hops=hops,
                        reduced_chi2=chi2, reduced_chi2_floor=chi2_floor, order_from=order_from,
                        stderr_camera=stderr_camera, order_check=None if order is None else order.to_json(),
                        notes=notes)
