"""Thickness of a bubble standing on a dish (a spherical cap on a liquid) from one photo.

The forward model is the cap's render (:mod:`bubblefit.model.cap_render`: the sphere's
``physical`` film, airy interference, one rear reflection, the liquid's Fresnel
reflectance, mirror reflection of the environment), times the unknown exposure ``g``.
Fitted pixels: those whose centre and four corner rays all meet the cap directly, or all
meet its mirror image in the liquid (a pixel the cap's outline or the foot crosses mixes
what lies on either side and is left out, as a flat film's frame edge is).

1. *Table*: the colour ``T[j, p]`` of every candidate thickness ``d_j`` (2 nm steps) at
   every fitted pixel ``p`` with the exposure 1, a film of one thickness.
2. *Search* (each pixel's chi^2 capped at an outlier's, :func:`_ls_cost`): ``constant``:
   each candidate with its own least-squares exposure (clipped channels left out), the
   best one kept; another order within one noise variance per
   pixel is a warning (:func:`bubblefit.inverse.planar._constant_thickness`'s rule).
   ``drainage``: every profile ``(top, bottom, exponent)`` on a grid (6 nm steps,
   ``bottom >= top``, exponents 0.5 ... 3) reads each pixel's colour from the table at
   its front film's thickness, with its own least-squares exposure; the best is kept.
3. *Levenberg-Marquardt* on ``(thickness or top, bottom, exponent, log g)`` against the
   fitted pixels' colours on the exact render (front and rear films at their own
   thicknesses), with the censored residual of clipped channels
   (:func:`._censored.censored_residual`) made robust as the bubble fit's
   (:func:`._lm.robust`, ``SolverSettings.robust_scale``; :func:`._planar_lm.levenberg_marquardt`),
   whitened by each channel's noise ``sigma`` (the
   bubble fit's model of read, shot and quantisation noise,
   :func:`._observation.noise_sigma`), each pixel the mean of 2 x 2 rays.
4. *Standard errors*: ``(J^T J)^-1`` widened by the Birge ratio, plus the thickness
   model error (:attr:`JudgeSettings.thickness_model_error_nm`) in quadrature, as for flat
   films. ``ok`` by the bubble fit's verdict (:func:`._verdict.verdict`): no warning and
   a reduced chi^2 with the model-error floor (:attr:`JudgeSettings.model_error`) at most
   :attr:`JudgeSettings.ok_chi2`; a local misfit (glints of the sun) is named, and not ok.

References
----------
D. W. Marquardt, J. SIAM 11, 431-441 (1963); R. T. Birge, Phys. Rev. 40, 207-227 (1932)
(the ratio that widens errors of a misfit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ComputationError, InputError
from ..lighting.filtering import FilterConfig
from ..model.cap_render import (SKIPPED, SKIPPED_SPHERE, TRACED_SPHERE, CapConfig, area_light_hits, cap_classes, cap_drainage,
                                render_cap, render_cap_pixels)
from ..model.effects import Effects
from ..model.render import Params, RenderConfig, pixel_chunks
from ..optics import spectral
from ._censored import BLACK_CLIP, censored_residual
from ._drainage_plane import EXPONENT_RANGE
from ._options import FitOptions
from ._lm import robust
from ._planar_lm import levenberg_marquardt
from ._uncertainty import OUTLIER_CHI2, Misfit
from .response_error import response_error, response_gram
from ._verdict import verdict
from ._observation import noise_sigma
from .planar import GRID_STEP_NM, PlanarResult, _on_image, range_edge_warning

__all__ = ["fit_cap", "cap_config", "fitted_pixels", "CapResult", "CAP_SPECTRAL_SAMPLES"]

#: Spectral samples of the cap's render: 10 nm bins over the visible, about seven per
#: spectral fringe of the thickest film searched (1.5 um, n = 1.4: lambda^2 / (2 n d) =
#: 69 nm at 380 nm).
CAP_SPECTRAL_SAMPLES = 40
#: Drainage search grid: ends on 6 nm steps (a fraction of the 25 nm between the colour
#: cost's minima), exponents over the flat films' range.
DRAIN_STEP_NM = 6.0
#: Internal bounces: the sphere fit's count (inverse/_setup.py, chosen on ref_const300).
CAP_BOUNCES = 3
#: Rays per pixel of the fit's render (a 2 x 2 box): the map's sharp features (a window's
#: edge) seen in the film change within a pixel. On the development case
#: cyc_cap_const_courtyard one ray per pixel left the exposure 8 % low and the reduced
#: chi^2 with the floor at 11.7; four rays 0.6 % and 7.4, nine 0.3 % and 6.95 at twice
#: the cost of four.
SAMPLES_PER_PIXEL = 4
DRAIN_EXPONENTS = np.geomspace(0.5, 3.0, 12)
#: Pixels the drainage search scores (every k-th in order of height): a few per nm of the
#: 25 nm between the colour cost's minima over a profile's range.
SEARCH_PIXELS = 600


@dataclass
class CapResult(PlanarResult):
    """A flat film's result record (:class:`~bubblefit.inverse.planar.PlanarResult`) with the
    cap's fitted pixel counts and the light paths its render skips."""

    pixels_direct: int = 0
    pixels_mirrored: int = 0
    skipped: tuple = SKIPPED
    shape: str = "cap"
    #: The light paths the render traces, reported for a whole bubble under an area light.
    traced: tuple = ()
    #: Fraction of the fitted pixels that are outliers (chi^2 with the model-error floor over
    #: :data:`~._uncertainty.OUTLIER_CHI2`) and the reduced chi^2 with the floor of the rest
    #: (:class:`~._uncertainty.Misfit`), as a bubble's fit reports them.
    outliers: float = float("nan")
    chi2_inliers: float = float("nan")
    #: Where the environment map's texel rows were read (:data:`~bubblefit.lighting.envmap.CONVENTIONS`).
    envmap_convention: str = "mitsuba"

    def report(self) -> str:
        """The flat films' report, the cap's pixel counts and the light paths its render skips."""
        if self.shape == "sphere":
            counts = f"\nbubble pixels fitted (seeing the area light): {self.pixels_direct}"
        else:
            counts = (f"\ncap pixels fitted: {self.pixels_direct} seen directly, "
                      f"{self.pixels_mirrored} mirrored in the liquid")
        traced = "\nlight paths traced: " + "; ".join(self.traced) if self.traced else ""
        return super().report() + counts + traced + "\nlight paths skipped: " + "; ".join(self.skipped)

    def to_json(self) -> dict:
        out = super().to_json()
        out.update(shape=self.shape, pixels_direct=self.pixels_direct, pixels_mirrored=self.pixels_mirrored,
                   outlier_fraction=self.outliers, reduced_chi2_inliers=self.chi2_inliers,
                   skipped_light_paths=list(self.skipped), envmap_convention=self.envmap_convention)
        if self.traced:
            out["traced_light_paths"] = list(self.traced)
        return out


def cap_config(scene, kind: str, samples_per_pixel: int = 1) -> CapConfig:
    """The cap's static render settings from a :class:`~bubblefit.model.cap_scene.CapScene`."""
    fx = Effects(model="physical", interference="airy", diffuse=False, filtering=FilterConfig("mirror"),
                 spectral=spectral.spectral_basis("uniform", CAP_SPECTRAL_SAMPLES, illuminant=scene.illuminant,
                                                  response=scene.response),
                 bounces=CAP_BOUNCES, thickness=kind)
    cfg = RenderConfig(effects=fx, camera=scene.camera, center=tuple(scene.cap.center), radius=float(scene.cap.radius),
                       samples_per_pixel=samples_per_pixel)
    if getattr(scene, "sphere", False):
        return CapConfig.sphere(cfg, scene.area, scene.film_rgb)
    return CapConfig.of(cfg, scene.cap, scene.film_rgb)


def fitted_pixels(cfg: CapConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(direct, mirrored)`` (H, W) masks of the pixels whose centre and corners all meet
    the cap directly, or all its mirror image."""
    h, w = cfg.render.shape
    r, c = np.mgrid[0:h, 0:w].astype(np.float64)
    dc, mc, _ = cap_classes(cfg, r, c)
    dc, mc = dc.reshape(h, w), mc.reshape(h, w)
    cr, cc = np.mgrid[0:h + 1, 0:w + 1].astype(np.float64) - 0.5
    dk, mk, _ = cap_classes(cfg, cr, cc)
    dk, mk = dk.reshape(h + 1, w + 1), mk.reshape(h + 1, w + 1)
    all4 = lambda k: k[:-1, :-1] & k[1:, :-1] & k[:-1, 1:] & k[1:, 1:]
    direct, mirrored = dc & all4(dk), mc & all4(mk)
    if cfg.area is not None:
        direct = direct & _whole_in_light(cfg, (r, c), (cr, cc))
    return direct, mirrored


def _whole_in_light(cfg: CapConfig, centres, corners) -> np.ndarray:
    """(H, W): the pixels that see the area light in the front film or the first rear
    reflection, each film seeing it at the centre and the four corners alike (an outline of
    the light's image crossing a pixel mixes light and dark, as a flat film's frame edge,
    and a pixel that sees the light in neither film is dark). The flat films' rule under a
    panel, chosen there on the development case cyc_film_drain_panel (pixels crossed by the
    frame's edge read as order hops)."""
    h, w = cfg.render.shape
    fc, rc = (k.reshape(h, w) for k in area_light_hits(cfg, *centres))
    fk, rk = (k.reshape(h + 1, w + 1) for k in area_light_hits(cfg, *corners))
    same = lambda c, k: (k[:-1, :-1] == c) & (k[1:, :-1] == c) & (k[:-1, 1:] == c) & (k[1:, 1:] == c)
    return same(fc, fk) & same(rc, rk) & (fc | rc)


def _params(scene, thickness, exposure):
    return Params.make(thickness=thickness, n_film=scene.n_film, exposure=exposure, roughness=0.0,
                       rotation=math.radians(scene.rotation_deg))


def _table(scene, cfg: CapConfig, env, rows, cols, npix, grid) -> np.ndarray:
    """(G, P, 3) colours of a film of each thickness of ``grid`` at the fitted pixels (exposure 1)."""
    fn = jax.jit(lambda d: render_cap_pixels(_params(scene, d, 1.0), cfg, env, rows, cols))
    return np.stack([np.asarray(fn(jnp.float32(d)))[:npix] for d in grid])


def _ls_cost(y, model, seen, sigma):
    """Per candidate (leading axes of ``model``, (..., P, 3)): a robust exposure and the
    misfit at it, whitened by the noise ``sigma`` (P, 3) over the channels ``seen``, with
    each pixel's chi^2 capped at an outlier's (:data:`._uncertainty.OUTLIER_CHI2`, the
    bubble fit's truncated loss). The exposure is the median of the pixels' own
    least-squares exposures, then the least-squares one over the pixels within the cap:
    a glint of the sun, which one ray per pixel places differently from the photo's pixel
    box and which the photo clips, then moves neither the exposure nor the cost by more
    than an outlier's worth. Chosen on the development case cyc_cap_drain_sunrise, whose
    sun glints had drawn a least-squares search to a nearly black film."""
    w = seen / sigma
    yw, m = y * w, model * w
    a = np.einsum("pc,...pc->...p", yw, m)
    b = np.einsum("...pc,...pc->...p", m, m)
    own = np.where(b > 1e-12, a / np.maximum(b, 1e-12), np.nan)
    gain = np.nan_to_num(np.nanmedian(own, axis=-1))

    def chi(g):
        return np.sum((yw - g[..., None, None] * m) ** 2, axis=-1)

    inl = chi(gain) < OUTLIER_CHI2
    gain = np.sum(a * inl, axis=-1) / np.maximum(np.sum(b * inl, axis=-1), 1e-30)
    return gain, np.sum(np.minimum(chi(gain), OUTLIER_CHI2), axis=-1)


def _search_constant(y, table, grid, seen, fringe_nm, sigma, warnings):
    """Best ``(thickness, log g)`` of a film of one thickness; another order whose misfit
    is worse by less than one (whitened) noise variance per pixel is a warning."""
    gain, cost = _ls_cost(y, table, seen, sigma)
    j = int(np.argmin(cost))
    far = np.abs(grid - grid[j]) > 0.75 * fringe_nm
    if far.any() and (cost[far].min() - cost[j]) / len(y) < 1.0:
        alt = grid[far][int(np.argmin(cost[far]))]
        warnings.append(f"the colour fits {grid[j]:.0f} nm and {alt:.0f} nm nearly as well (another order)")
    return np.array([grid[j], math.log(max(gain[j], 1e-12))])


def _search_drainage(y, table, grid, seen, sigma, local_y, cfg: CapConfig):
    """Best ``(top, bottom, exponent, log g)`` on the grid, each pixel's colour read from the
    table at its front film's thickness (linear interpolation between candidates)."""
    lo, hi = grid[0], grid[-1]
    ends = np.arange(lo, hi + 0.5 * DRAIN_STEP_NM, DRAIN_STEP_NM)
    # every k-th pixel in order of height: the search needs the colour sequence along the
    # height, not every pixel (Levenberg-Marquardt then fits them all)
    pick = np.argsort(local_y)[:: max(1, len(y) // SEARCH_PIXELS)]
    y, table, seen, sigma, local_y = y[pick], table[:, pick], seen[pick], sigma[pick], local_y[pick]
    r = cfg.render
    u = np.clip((1.0 - local_y) * r.radius / (r.center[1] + r.radius - cfg.plane_y), 0.0, 1.0)
    best = (np.inf, None)
    idx = np.arange(len(y))
    for e in DRAIN_EXPONENTS:
        ue = u ** e
        for top in ends:
            bottoms = ends[ends >= top]
            d = top + (bottoms[:, None] - top) * ue[None, :]          # (B, P)
            f = (d - lo) / (grid[1] - grid[0])
            i0 = np.clip(np.floor(f).astype(int), 0, len(grid) - 2)
            a = np.clip(f - i0, 0.0, 1.0)[..., None]
            model = (1 - a) * table[i0, idx] + a * table[i0 + 1, idx]   # (B, P, 3)
            gain, cost = _ls_cost(y, model, seen, sigma)
            k = int(np.argmin(cost))
            if cost[k] < best[0]:
                best = (cost[k], np.array([top, bottoms[k], e, math.log(max(gain[k], 1e-12))]))
    return best[1]


def fit_cap(photo: np.ndarray, scene, env, *, kind: str | None = None, clip_high: float = np.inf,
            bits: int | None = 8, options: FitOptions | None = None) -> PlanarResult:
    """Fit a dish bubble's film (``constant`` or ``drainage`` along the cap's height) to a
    linear photo (H, W, 3) (the module's method). ``env``: the scene's map
    (:class:`~bubblefit.lighting.envmap.EnvMap`); ``bits``: the photo file's integer bit
    depth (None for a float file), for the noise model."""
    opts = options or FitOptions()
    kind = kind or scene.thickness
    h, w = photo.shape[:2]
    if (h, w) != (scene.camera.height, scene.camera.width):
        raise InputError(f"the photo is {w}x{h}, the scene's camera {scene.camera.width}x{scene.camera.height}")
    cfg = cap_config(scene, kind)
    fine = cap_config(scene, kind, samples_per_pixel=SAMPLES_PER_PIXEL)
    direct, mirrored = fitted_pixels(cfg)
    film = "bubble" if cfg.area is not None else "cap"
    if direct.sum() < 20:
        seen = " lit by the area light" if cfg.area is not None else ""
        raise InputError(f"the {film} does not appear in the photo (the camera sees fewer than 20 of its pixels "
                         f"whole{seen})")
    mask = direct | mirrored
    flat = np.flatnonzero(mask.ravel())
    rows, cols, _, npix = pixel_chunks(cfg.render, flat)
    y = np.asarray(photo, np.float64).reshape(-1, 3)[flat]
    if float(np.percentile(y[direct.ravel()[flat]].max(-1), 99)) <= 0.005:
        raise InputError(f"the {film} does not appear in the photo (the pixels where it should be are dark)")
    seen = ((y > BLACK_CLIP) & (y < clip_high)).astype(np.float64)
    # the bubble fit's noise model per pixel and channel (read, shot and quantisation noise)
    sigma = noise_sigma(y, opts.noise.read, opts.noise.shot, bits)
    lo, hi = scene.thickness_range
    grid = np.arange(lo, hi + 0.5 * GRID_STEP_NM, GRID_STEP_NM)
    table = _table(scene, cap_config(scene, "constant"), env, rows, cols, npix, grid)
    fringe_nm = 550.0 / (2.0 * scene.n_film)
    warnings: list[str] = []
    if kind == "constant":
        theta0 = _search_constant(y, table, grid, seen, fringe_nm, sigma, warnings)
    else:
        r, c = np.divmod(flat, w)
        _, _, local0 = cap_classes(cfg, r, c)
        theta0 = _search_drainage(y, table, grid, seen, sigma, local0[:, 1], cfg)

    def model(theta):
        th = jnp.abs(theta[0]) if kind == "constant" else jnp.abs(theta[:3])
        return render_cap_pixels(_params(scene, th, jnp.exp(theta[-1])), fine, env, rows, cols)[:npix]

    sig = jnp.asarray(sigma, jnp.float32)
    obs = jnp.asarray(y, jnp.float32)
    scale = opts.solver.robust_scale

    def resid(t):  # the bubble fit's robust (pseudo-Huber) residual of the censored, whitened misfit
        return robust(censored_residual(obs, model(t), clip_high) / sig, scale).ravel()

    rj = jax.jit(resid)
    jj = jax.jit(jax.jacfwd(resid))
    theta, _, _ = levenberg_marquardt(rj, jj, jnp.asarray(theta0, jnp.float32))
    jac = np.asarray(jj(theta), np.float64)
    theta = np.asarray(theta, np.float64)
    n_th = 1 if kind == "constant" else 3   # the colour is even in the thickness: values by their size
    theta[:n_th] = np.abs(theta[:n_th])
    fitted = np.asarray(model(jnp.asarray(theta, jnp.float32)), np.float64)
    res = censored_residual(y, fitted, clip_high, np)
    chi2 = float(np.mean((res / sigma) ** 2))
    try:
        # widened by the Birge ratio of a misfit
        cov = np.linalg.inv(jac.T @ jac) * max(1.0, chi2)
    except np.linalg.LinAlgError:
        raise ComputationError("the cap's fit is singular (no colour changes with the thickness)") from None
    names = ["thickness_nm"] if kind == "constant" else ["top_nm", "bottom_nm", "exponent"]
    dfront = _front_thickness(cfg, kind, theta, flat, w)
    cam_cov = _camera_covariance(scene, jac, seen / sigma, fitted, dfront)
    if cam_cov is not None:
        cov = cov + cam_cov
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    me = opts.judge.thickness_model_error_nm
    params = {n: float(v) for n, v in zip(names, theta)}
    stderr = {n: float(s) for n, s in zip(names, se)}
    for n in names:
        if n.endswith("_nm"):
            stderr[n] = float(np.hypot(stderr[n], me))
    gain = float(np.exp(theta[-1]))
    params["exposure"], stderr["exposure"] = gain, float(gain * se[-1])
    stderr_camera = None
    if cam_cov is not None:
        cam_se = np.sqrt(np.maximum(np.diag(cam_cov), 0.0))
        stderr_camera = {n: float(v) for n, v in zip(names, cam_se)}
        stderr_camera["exposure"] = float(gain * cam_se[-1])
    if kind == "drainage":
        e = params["exponent"]
        lo_e, hi_e = EXPONENT_RANGE
        if not lo_e < e < hi_e:
            warnings.append(f"the drainage exponent {e:.3g} lies outside {lo_e:g}-{hi_e:g}")
    warnings.extend(range_edge_warning(dfront, lo, hi, "cap"))
    fit_misfit = _misfit(res, sigma, y, opts.judge.model_error, len(theta))
    chi2_floor = fit_misfit.chi2_floor
    sigma = float(np.median(sigma))
    # the bubble fit's verdict: explained within ok_chi2 with the model-error floor; a
    # misfit it calls local (outliers, the rest explained) keeps the fit not ok
    ok, warnings = verdict(converged=True, disc_found=True, bound_warnings=[], misfit=fit_misfit,
                           ok_chi2=opts.judge.ok_chi2, model_error=opts.judge.model_error, notes=warnings)
    on_dir = direct.ravel()[flat]
    tmap = _on_image(direct, dfront[on_dir], np.nan)
    smap = _on_image(direct, np.full(int(on_dir.sum()), stderr[names[0]] if kind == "constant" else np.nan), np.nan)
    if kind == "drainage":
        smap = _on_image(direct, _profile_stderr(cfg, theta, cov, flat[on_dir], w, me), np.nan)
    full = np.asarray(render_cap(_params(scene, theta[0] if kind == "constant" else theta[:3], gain), cfg, env))
    resid = _on_image(mask, res, 0.0, 3)
    if not np.all(np.isfinite(theta)):
        raise ComputationError("the cap's fit produced non-finite parameters")
    return CapResult(kind=kind, ok=ok, thickness_map=tmap, thickness_stderr_map=smap, render=full, residual=resid,
                       gain=gain, sigma=sigma, params=params, stderr=stderr, warnings=warnings, order_hops=0,
                     reduced_chi2=chi2, reduced_chi2_floor=chi2_floor, order_from="colour", pixels_direct=int(direct.sum()),
                     pixels_mirrored=int(mirrored.sum()), shape="sphere" if cfg.area is not None else "cap",
                     skipped=SKIPPED_SPHERE if cfg.area is not None else SKIPPED,
                     traced=TRACED_SPHERE if cfg.area is not None else (), outliers=fit_misfit.outliers,
                     chi2_inliers=fit_misfit.chi2_inliers, stderr_camera=stderr_camera,
                     envmap_convention=scene.env_convention)


def _camera_covariance(scene, jac, weight, fitted, dfront):
    """The calibrated response's share of the parameters' covariance,
    ``(J^T J)^-1 G_R (J^T J)^-1`` with ``G_R`` from
    :func:`~bubblefit.inverse.response_error.response_gram` (the bubble fit's term,
    :mod:`bubblefit.inverse._uncertainty`), over the fitted pixels (P, 3) ``weight``
    (``1 / sigma``, 0 where censored) and ``fitted`` (the render) at each pixel's front
    film ``dfront`` (P,) seen at normal incidence (the cap's angles are not traced here;
    a ray at 30 degrees sees a 5 % shorter optical path), with no background (the light
    seen through the film counted as reflected, which overstates the response's share);
    None for a response taken as exact."""
    err = response_error(scene.response, scene.illuminant, float(scene.n_film))
    if err is None:
        return None
    n = len(fitted)
    gram = response_gram(err, jac, np.asarray(weight, np.float64)[:, None], np.asarray(fitted)[:, None], None,
                         np.asarray(dfront, np.float64)[:, None], np.ones((n, 1)))
    a_inv = np.linalg.inv(jac.T @ jac)
    return a_inv @ gram @ a_inv


def _misfit(res, sigma, y, model_error: float, n_free: int) -> Misfit:
    """The bubble fit's :class:`~._uncertainty.Misfit` of the fitted pixels (P, 3): reduced
    chi^2 of the noise alone and with each channel's variance ``sigma^2 + (model_error y)^2``,
    that split between outlier pixels (:data:`~._uncertainty.OUTLIER_CHI2`) and the rest,
    and capped, as :func:`._uncertainty.misfit` computes it for a bubble."""
    dof = max(res.size - n_free, 1)
    per = res ** 2 / (sigma ** 2 + (model_error * np.clip(y, 0, None)) ** 2)
    chi_pix = per.sum(-1)
    bad = chi_pix > OUTLIER_CHI2
    dof_in = max(3 * int((~bad).sum()) - n_free, 1)
    return Misfit(float(np.sum((res / sigma) ** 2)) / dof, float(per.sum()) / dof,
                  float(chi_pix[~bad].sum()) / dof_in, float(bad.mean()),
                  float(np.minimum(chi_pix, OUTLIER_CHI2).sum()) / dof)


def _front_thickness(cfg: CapConfig, kind: str, theta, flat, w) -> np.ndarray:
    """The fitted thickness of the film each fitted pixel's ray meets first."""
    if kind == "constant":
        return np.full(len(flat), float(theta[0]))
    r, c = np.divmod(flat, w)
    _, _, local0 = cap_classes(cfg, r, c)
    return np.asarray(cap_drainage(jnp.asarray(local0[:, 1]), jnp.asarray(theta[:3]), cfg), np.float64)


def _profile_stderr(cfg: CapConfig, theta, cov, flat, w, model_error_nm: float) -> np.ndarray:
    """Standard error of the profile's thickness at each pixel's front film: the
    parameters' covariance carried by the profile's gradient, plus the model error."""
    r, c = np.divmod(flat, w)
    _, _, local0 = cap_classes(cfg, r, c)
    ly = jnp.asarray(local0[:, 1])
    jac = np.asarray(jax.jacfwd(lambda t: cap_drainage(ly, t, cfg))(jnp.asarray(theta[:3])), np.float64)
    var = np.einsum("pi,ij,pj->p", jac, cov[:3, :3], jac)
    return np.sqrt(np.maximum(var, 0.0) + model_error_nm ** 2)
