"""Fitting the forward model to a photograph of a bubble (DESIGN.md, ``bubblefit fit``).

:func:`fit_photo` recovers ``t``, the split of ``1 - t`` into ``r_d`` and ``r_s`` (eq. 14,
or both free), Ward's roughness ``a`` (eq. 1), the film thickness (one value, a drainage
profile, or a per-pixel map), a camera gain and optionally the environment's rotation
about +y, from a linear (H, W, 3) photo and its environment map.

Method
------
1. Effects are decided once (:func:`bubblefit.model.effects.resolve`) from the starting values
   and the whole thickness search range; a parameter whose effect is skipped (``r_d``
   without the diffuse term, roughness with a mirror lookup, thickness without
   interference; ``t`` and ``r_s`` in the ``physical`` model, where Fresnel sets them) is
   held and reported in ``held``, never fitted into noise.
2. Global thickness search (:mod:`bubblefit.inverse.search`) on a downsampled image: a dense
   grid of thicknesses, each scored with its best camera gain; the lowest local minima
   are refined.
3. Local refinement with optimistix' Levenberg-Marquardt on the whitened, robust residual
   vector. LM rather than Gauss-Newton because the starting points from a grid are only
   close, and its trust-region damping keeps steps inside one colour fringe of the
   thickness; rather than Dogleg because with few parameters its damped solve is as
   cheap and it needs no separate trust-region geometry. The Jacobian is forward-mode
   (few parameters, many residuals).
4. Standard errors: ``cov = s^2 (J^T J)^-1`` in the unconstrained coordinates at the
   optimum, ``s^2`` the residual variance, propagated to the reported parameters by the
   Jacobian of the transform (delta method).

Parameters are fitted in unconstrained coordinates: ``t`` and the split through a
logistic, ``a``, the gain, the exponent and free ``r_d``/``r_s`` through ``exp``,
thicknesses (>= 0) through a softplus in units of 100 nm.

Residual: ``(render - photo) / sigma`` inside the disc (pixels with ``rho < rim``), not
saturated, with ``sigma^2 = read^2 + shot * I + q^2`` (``q`` the linear size of one code
value of an 8-bit sRGB file over sqrt(12)), passed through a pseudo-Huber loss of scale
``robust_scale`` sigmas.

Transmission tint: with the ``paper`` model the fit turns on ``transmission_tint``
(:mod:`bubblefit.model.effects`) unless told otherwise: a real film transmits the complement of
the colour it reflects, which over a bright background is as strong as the reflection
itself, and eq. (11)'s grey ``t^4`` would then prefer another colour order. The search
keeps its speed (the tint is a function of the same tabulated ``Phi``). A drainage search
also scans one camera gain for all pixels instead of hue matching alone (a gain per pixel
could cancel the reflected colour against the tint's), and searches the profile's own
parameters through the per-pixel costs (:func:`bubblefit.inverse.search.best_profile`).

Thickness maps: after a drainage fit gives the global parameters, each pixel's thickness
is searched and refined separately (a pixel's colour depends on its own thickness only:
the rear film and internal bounces read the map at the same pixel, see
:func:`bubblefit.model.thickness.thickness_at`), with a weak Gaussian prior of
``map_prior_nm`` around the fitted profile against the ambiguity of repeated colours.
With the ``paper`` model the search is exact and fast (eq. 11 is linear in eq. 10's
factor) and the per-pixel refinement is optimistix LM vmapped over pixels; other models
use renders of the profile plus offsets and a diagonal Gauss-Newton.

Compiled solvers are cached per static configuration (camera, effects, parameter layout),
so a sequence of photos with the same size and disc (give ``FitOptions.disc``) compiles
once. :func:`fit_batch` fits several warm-started frames of a sequence in one solve
vmapped over frames (for devices that one small frame does not fill; on a 2-core CPU it
is slower than frame after frame).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from . import search
from ..model.effects import resolve
from ..lighting.envmap import EnvMap
from ..errors import InputError
from ..optics.film import fringe_attenuation
from ..model.geometry import OrthographicCamera, intersect_sphere
from ..model.render import Params, RenderConfig, render, render_terms

__all__ = ["FitOptions", "FitResult", "fit_photo", "fit_batch", "detect_disc", "noise_sigma"]

_THICK_UNIT = 100.0  # nm per unit of the unconstrained thickness coordinate
_LOGISTIC = ("t", "split")
#: A warm-started fit whose noise-weighted reduced chi^2 exceeds this is checked against a
#: global thickness search (see :func:`fit_photo`).
WARM_START_CHI2 = 4.0

_LOG = ("r_d", "r_s", "roughness", "exposure", "exponent")
_SOFT = ("thickness", "top", "bottom")


@dataclass(frozen=True)
class FitOptions:
    """Static settings of a fit.

    Attributes:
        thickness: ``constant`` | ``drainage`` | ``map``.
        model: ``paper`` | ``physical`` forward model.
        fit_rotation: also fit the environment's rotation about +y.
        free_split: fit ``r_d`` and ``r_s`` freely instead of ``r_d + r_s = 1 - t`` (eq. 14).
        disc: ``(cx, cy, r)`` of the bubble in pixels, or None to detect it.
        t_init: starting ``t`` (e.g. from ``bubblefit calibrate``).
        roughness_init: starting roughness (also decides whether filtering is simulated).
        thickness_range: (min, max) nm searched (and used to decide the effects).
        max_steps, rtol, atol: Levenberg-Marquardt limits and tolerances.
        downsample: factor of the image the local fit runs on (None: so that its larger
            side is at most ``fit_size``).
        fit_size, search_size: larger side of the fit and search images (pixels).
        search_step_nm: thickness grid step of the global search.
        candidates: local minima of the search refined (each with at most ``search_steps``
            LM steps on the search image).
        robust_scale: pseudo-Huber scale in noise sigmas.
        noise_read, noise_shot, bits: noise model (``bits`` None for float photos).
        saturation: photo values at or above this (in files with a maximum of 1) are clipped.
        rim: fraction of the disc radius used (the rim mixes with the background).
        map_prior_nm: width of the prior tying a thickness map to the fitted profile.
        hold: names of parameters to hold at their starting values.
        effects: extra ``[effects]`` settings as ``((key, value), ...)``.
    """

    thickness: str = "constant"
    model: str = "paper"
    fit_rotation: bool = False
    free_split: bool = False
    disc: tuple | None = None
    t_init: float | None = None
    roughness_init: float | None = None
    thickness_range: tuple = (50.0, 2000.0)
    max_steps: int = 80
    rtol: float = 1e-5
    atol: float = 1e-6
    downsample: int | None = None
    fit_size: int = 96
    search_size: int = 48
    search_step_nm: float = 4.0
    candidates: int = 2
    search_steps: int = 20
    robust_scale: float = 3.0
    noise_read: float = 2e-3
    noise_shot: float = 2e-4
    bits: int | None = 8
    saturation: float = 0.995
    rim: float = 0.96
    map_prior_nm: float = 150.0
    hold: tuple = ()
    effects: tuple = ()

    def __post_init__(self):
        if self.thickness not in ("constant", "drainage", "map"):
            raise InputError(f"thickness must be constant, drainage or map, got {self.thickness!r}")
        if self.model not in ("paper", "physical"):
            raise InputError(f"model must be paper or physical, got {self.model!r}")
        lo, hi = self.thickness_range
        if not 0 <= lo < hi:
            raise InputError(f"thickness range must be 0 <= min < max, got {lo}..{hi}")


@dataclass
class FitResult:
    """What a fit found (see :meth:`to_json` for the DESIGN.md keys).

    Attributes:
        params: reported values (t, r_d, r_s, f, roughness, thickness_nm, exposure,
            rotation_deg, n_film; top_nm, bottom_nm, exponent for a drainage profile).
        stderr: standard errors of the same keys (None for held ones).
        held: ``[(name, reason)]`` of parameters not fitted.
        converged: True only when the solver met its tolerances and the errors are finite.
        message: why not, or notes.
        iterations: solver steps of the final refinement.
        residual_rms: RMS of the linear residual over the fitted pixels (full resolution).
        time_s: wall time of the fit.
        effects: the :class:`~bubblefit.model.effects.Decision` list.
        render, residual: (H, W, 3) fitted image and ``photo - render``.
        thickness_map: (H, W) front-film thickness (nm), NaN outside the bubble, or None
            for a constant film.
        thickness_stderr_map: (H, W) standard error of a fitted map, or None.
        disc: (cx, cy, r) used (orthographic camera) or None.
    """

    params: dict
    stderr: dict
    held: list
    converged: bool
    message: str
    iterations: int
    residual_rms: float
    time_s: float
    effects: list
    render: np.ndarray
    residual: np.ndarray
    thickness_map: np.ndarray | None = None
    thickness_stderr_map: np.ndarray | None = None
    disc: tuple | None = None
    thickness_kind: str = "constant"
    model: str = "paper"
    reduced_chi2: float = float("nan")
    pixels_used: int = 0

    def to_json(self) -> dict:
        """The DESIGN.md result: params, stderr, converged, iterations, residual_rms, time_s, and more."""
        clean = lambda d: {k: (None if v is None or not np.isfinite(v) else float(v)) for k, v in d.items()}
        return {
            "params": clean(self.params),
            "stderr": clean(self.stderr),
            "held": [{"name": n, "reason": r} for n, r in self.held],
            "converged": bool(self.converged),
            "message": self.message,
            "iterations": int(self.iterations),
            "residual_rms": float(self.residual_rms),
            "reduced_chi2": float(self.reduced_chi2),
            "pixels_used": int(self.pixels_used),
            "time_s": float(self.time_s),
            "thickness": self.thickness_kind,
            "model": self.model,
            "solver": "optimistix.LevenbergMarquardt",
            "disc": None if self.disc is None else {"cx": self.disc[0], "cy": self.disc[1], "r": self.disc[2]},
            "effects": [{"effect": d.effect, "simulated": d.simulated, "setting": d.setting, "reason": d.reason}
                        for d in self.effects],
        }


# ---------------------------------------------------------------------------------------
# Noise model and the bubble's disc
# ---------------------------------------------------------------------------------------


def noise_sigma(photo: np.ndarray, read: float, shot: float, bits: int | None) -> np.ndarray:
    """Per-pixel noise standard deviation (H, W, 3) of a linear photo.

    ``sigma^2 = read^2 + shot * I + q^2``: read noise, shot noise proportional to the
    signal, and, for an integer sRGB file of ``bits`` bits, the quantisation error
    ``q = (dI/dV) / (2^bits - 1) / sqrt(12)`` of one code value ``V`` mapped to linear
    (IEC 61966-2-1 slope).
    """
    i = np.clip(photo, 0.0, None)
    var = read**2 + shot * i
    if bits:
        lin = np.clip(i, 0.0, 1.0)
        v = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055)
        slope = np.where(v <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((v + 0.055) / 1.055) ** 1.4)
        var = var + (slope / (2**bits - 1)) ** 2 / 12.0
    return np.sqrt(var)


def detect_disc(photo: np.ndarray, background: np.ndarray | None = None) -> tuple[float, float, float]:
    """Find the bubble's disc ``(cx, cy, r)`` in pixels.

    With a background photo: :func:`bubblefit.capture.calibrate.detect_bubble` on the pair (the
    bubble is where the two differ). Without: the strongest circle of the photo's edges
    (OpenCV's Hough gradient on the sRGB-encoded grey image), which finds the rim that a
    bubble's Fresnel brightening outlines.
    """
    gray = np.mean(np.clip(photo, 0, None), axis=-1)
    if background is not None:
        from ..capture.calibrate import detect_bubble, usable_mask

        bgray = np.mean(np.clip(background, 0, None), axis=-1)
        sat = (np.max(photo, axis=-1) >= 0.999) | (np.max(background, axis=-1) >= 0.999)
        try:
            usable, _ = usable_mask(bgray, gray, sat)
            return detect_bubble(bgray, gray, usable)
        except InputError:
            pass  # a dark background: fall back to the edges of the photo alone
    import cv2

    h, w = gray.shape
    enc = np.clip(gray / max(np.percentile(gray, 99.5), 1e-6), 0, 1) ** (1 / 2.2)
    img = cv2.GaussianBlur((enc * 255).astype(np.uint8), (5, 5), 1.2)
    circles = cv2.HoughCircles(img, cv2.HOUGH_GRADIENT, dp=1, minDist=max(h, w),
                               param1=60, param2=20, minRadius=max(4, min(h, w) // 10),
                               maxRadius=min(h, w) // 2 + 2)
    if circles is None:
        raise InputError("no bubble found in the photo; give its disc (--disc CX,CY,R) or a background photo")
    cx, cy, r = (float(v) for v in circles[0, 0])
    return cx, cy, r


# ---------------------------------------------------------------------------------------
# Parameters in unconstrained coordinates
# ---------------------------------------------------------------------------------------


def _forward(name, u):
    if name in _LOGISTIC:
        return jax.nn.sigmoid(u)
    if name in _LOG:
        return jnp.exp(u)
    if name in _SOFT:
        return _THICK_UNIT * jax.nn.softplus(u)
    return u


def _inverse(name, v) -> float:
    v = float(v)
    if name in _LOGISTIC:
        v = min(max(v, 1e-6), 1 - 1e-6)
        return math.log(v / (1 - v))
    if name in _LOG:
        return math.log(max(v, 1e-12))
    if name in _SOFT:
        x = max(v, 1e-3) / _THICK_UNIT
        return x + math.log(-math.expm1(-x)) if x < 30 else x
    return v


def _values(z, layout: tuple, fixed: dict) -> dict:
    vals = dict(fixed)
    for i, name in enumerate(layout):
        vals[name] = _forward(name, z[i])
    return vals


def _params(vals: dict, kind: str, free_split: bool) -> Params:
    t = vals["t"]
    if free_split:
        r_d, r_s = vals["r_d"], vals["r_s"]
    else:
        r_s = (1.0 - t) * vals["split"]
        r_d = (1.0 - t) * (1.0 - vals["split"])
    if kind == "constant":
        th = vals["thickness"]
    elif kind == "drainage":
        th = jnp.stack([vals["top"], vals["bottom"], vals["exponent"]])
    else:
        th = vals["map"]
    f32 = lambda v: jnp.asarray(v, jnp.float32)
    return Params(f32(t), f32(r_d), f32(r_s), f32(vals["roughness"]), f32(th), f32(vals["n_film"]),
                  f32(vals["exposure"]), f32(vals["rotation"]))


def _reported(vals: dict, kind: str, free_split: bool) -> dict:
    """The JSON's parameters (jnp scalars) from constrained values."""
    p = _params(vals, kind, free_split)
    out = {"t": p.t, "r_d": p.r_d, "r_s": p.r_s, "f": p.r_d / p.r_s, "roughness": p.roughness,
           "exposure": p.exposure, "rotation_deg": p.rotation * (180.0 / math.pi)}
    if kind == "constant":
        out["thickness_nm"] = p.thickness
    elif kind == "drainage":
        out["top_nm"], out["bottom_nm"], out["exponent"] = p.thickness[0], p.thickness[1], p.thickness[2]
    return out


# ---------------------------------------------------------------------------------------
# Compiled solvers, cached per static configuration
# ---------------------------------------------------------------------------------------


def _robust(r, scale):
    """Pseudo-Huber residual: ``sign(r) sqrt(2 rho(r))``, written to stay smooth at 0."""
    x2 = (r / scale) ** 2
    return r * jnp.sqrt(2.0 / (jnp.sqrt(1.0 + x2) + 1.0))


@functools.lru_cache(maxsize=64)
def _solver(cfg: RenderConfig, layout: tuple, kind: str, free_split: bool, robust: float,
            max_steps: int, rtol: float, atol: float):
    """Jitted ``solve(z0, args) -> (z, ok, maxed, steps, residual, J)`` and ``resid``."""

    def resid(z, args):
        fixed, env, bg, y, w = args
        p = _params(_values(z, layout, fixed), kind, free_split)
        img = render(p, cfg, env, bg)
        return _robust((img - y) * w, robust).reshape(-1)

    lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    @jax.jit
    def solve(z0, args):
        sol = optx.least_squares(resid, lm, z0, args, max_steps=max_steps, throw=False)
        z = sol.value
        r = resid(z, args)
        jac = jax.jacfwd(resid)(z, args)
        maxed = (sol.result == optx.RESULTS.max_steps_reached) | (
            sol.result == optx.RESULTS.nonlinear_max_steps_reached)
        return (z, sol.result == optx.RESULTS.successful, maxed, sol.stats["num_steps"], r, jac)

    return solve, jax.jit(resid)


@functools.lru_cache(maxsize=64)
def _reporter(layout: tuple, kind: str, free_split: bool):
    def rep(z, fixed):
        return _reported(_values(z, layout, fixed), kind, free_split)

    return jax.jit(rep), jax.jit(jax.jacfwd(rep))


# ---------------------------------------------------------------------------------------
# Images at a resolution
# ---------------------------------------------------------------------------------------


@dataclass
class _Level:
    """The photo, weights and geometry at one resolution (``k`` times smaller)."""

    k: int
    cfg: RenderConfig
    y: np.ndarray  # (h, w, 3)
    w: np.ndarray  # (h, w, 3) 1 / sigma inside the mask, 0 outside
    bg: np.ndarray | None
    mask: np.ndarray  # (h, w) fitted pixels
    inside: np.ndarray  # (h, w) pixels on the bubble
    cos: np.ndarray  # (h, w) incidence cosine on the film
    height: np.ndarray  # (h, w) front film point's height over the radius


def _block(a: np.ndarray, k: int, h: int, w: int, how="mean"):
    if k == 1:
        return a
    b = a[: h * k, : w * k].reshape(h, k, w, k, *a.shape[2:])
    return b.mean(axis=(1, 3)) if how == "mean" else b.any(axis=(1, 3))


def _camera_at(camera, k: int, h: int, w: int):
    if isinstance(camera, OrthographicCamera):
        cx, cy, r = camera.disc()
        return OrthographicCamera(w, h, cx / k, cy / k, r / k)
    return replace(camera, width=w, height=h)


def _geometry(cfg: RenderConfig):
    h, w = cfg.shape
    rows, cols = np.mgrid[0:h, 0:w]
    o, d = cfg.camera.rays(jnp.asarray(rows.reshape(-1), jnp.float32), jnp.asarray(cols.reshape(-1), jnp.float32),
                           cfg.center, cfg.radius)
    hits = intersect_sphere(o, d, cfg.center, cfg.radius)
    cos = np.asarray(hits.cos).reshape(h, w)
    inside = np.asarray(hits.inside).reshape(h, w)
    height = np.asarray(hits.local0[:, 1]).reshape(h, w)
    return inside, cos, height


def _make_level(k, base_cfg, photo, sigma, bg, saturated, opts) -> _Level:
    H, W = photo.shape[:2]
    h, w = H // k, W // k
    cfg = replace(base_cfg, camera=_camera_at(base_cfg.camera, k, h, w))
    inside, cos, height = _geometry(cfg)
    cos_min = math.sqrt(max(0.0, 1.0 - opts.rim**2))
    y = _block(photo, k, h, w)
    var = _block(sigma**2, k, h, w) / (k * k)
    sat = _block(saturated, k, h, w, how="any")
    mask = inside & (cos > cos_min) & ~sat & np.all(np.isfinite(y), axis=-1)
    wts = np.where(mask[..., None], 1.0 / np.sqrt(var), 0.0)
    bgk = None if bg is None else _block(bg, k, h, w).astype(np.float32)
    return _Level(k, cfg, np.nan_to_num(y).astype(np.float32), wts.astype(np.float32), bgk, mask, inside, cos, height)


# ---------------------------------------------------------------------------------------
# Candidate images for the thickness search
# ---------------------------------------------------------------------------------------


def _fixed_params(vals, kind_values=None):
    return {k: jnp.asarray(v, jnp.float32) for k, v in vals.items()} if kind_values is None else kind_values


def _candidates_paper(lev: _Level, vals: dict, grid: np.ndarray, free_split: bool, env):
    """(G, P, 3) gain-scaled part and (P, 3) fixed part for constant films (paper model, exact)."""
    fx = lev.cfg.effects
    off = replace(lev.cfg, effects=replace(fx, interference="off", spectral=None, thickness="constant"))
    v = dict(vals, exposure=1.0, thickness=0.0)
    p = _params({k: jnp.asarray(x, jnp.float32) for k, x in v.items() if k != "map"}, "constant", free_split)
    _, terms = _render_terms_jit(p, off, env, None if lev.bg is None else jnp.asarray(lev.bg))
    zero = jnp.zeros(lev.y.shape, jnp.float32)
    m = terms.get("front", zero) + terms.get("rear", zero)
    c = terms.get("background", zero)
    n = float(vals["n_film"])
    cos_t = np.sqrt(np.clip(1.0 - (1.0 - lev.cos**2) / n**2, 0.0, 1.0))
    table = jnp.asarray(search.phi_table(fx.spectral, 2 * n * float(grid.max())))
    sel = lev.mask.reshape(-1)
    m = np.asarray(m).reshape(-1, 3)[sel]
    c = np.asarray(c).reshape(-1, 3)[sel]
    x = 2 * n * grid[:, None] * cos_t.reshape(-1)[sel][None, :]
    t = float(vals["t"])
    phi = search.phi_rgb(table, jnp.asarray(x, jnp.float32))  # (G, P, 3)
    r_s = float(p.r_s) if fx.tint and fx.transmission else 0.0
    refl, back = search.paper_candidates(phi, jnp.asarray(m)[None], jnp.asarray(c)[None], t, r_s)
    if fx.background == "photo":
        return refl, back
    return refl + back, jnp.zeros(back.shape[1:], back.dtype)


@functools.partial(jax.jit, static_argnames=("cfg",))
def _render_terms_jit(p, cfg, env, bg):
    return render_terms(p, cfg, env, bg)


@functools.partial(jax.jit, static_argnames=("cfg", "free_split"))
def _candidates_render(base: dict, thick, cfg, env, bg, free_split):
    """Render each candidate thickness array ``thick`` (G, ...) with exposure 1: (G, H, W, 3) x2."""

    def one(th):
        p = _params(dict(base, exposure=jnp.float32(1.0), thickness=th, map=th), cfg.effects.thickness, free_split)
        _, terms = render_terms(p, cfg, env, bg)
        zero = jnp.zeros(cfg.shape + (3,), jnp.float32)
        refl = terms.get("front", zero) + terms.get("rear", zero)
        back = terms.get("background", zero)
        if cfg.effects.background == "photo":
            return refl, back
        return refl + back, zero

    return jax.lax.map(one, thick)


def _candidates_generic(lev: _Level, vals: dict, grid: np.ndarray, free_split: bool, env):
    cfg = replace(lev.cfg, effects=replace(lev.cfg.effects, thickness="constant"))
    base = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k != "map"}
    refl, back = _candidates_render(base, jnp.asarray(grid, jnp.float32), cfg, env,
                                    None if lev.bg is None else jnp.asarray(lev.bg), free_split)
    sel = lev.mask.reshape(-1)
    g = len(grid)
    return refl.reshape(g, -1, 3)[:, sel], back.reshape(g, -1, 3)[:, sel]


def _candidates(lev, vals, grid, free_split, env):
    """Candidate images for the thickness grid: ``(refl, fixed)``, see :func:`search.score_global`."""
    if lev.cfg.effects.model == "paper" and lev.cfg.effects.interference == "two_beam":
        return _candidates_paper(lev, vals, grid, free_split, env)
    return _candidates_generic(lev, vals, grid, free_split, env)


# ---------------------------------------------------------------------------------------
# The fit
# ---------------------------------------------------------------------------------------


def _defaults(scene, init, opts, t_from_calibration):
    """Starting values and the parameters held by the scene/options."""
    vals = {"t": 0.972, "f": 0.3, "r_d": None, "r_s": None, "roughness": 0.01, "thickness": 500.0,
            "top": 200.0, "bottom": 1000.0, "exponent": 1.0, "exposure": 1.0, "rotation": 0.0, "n_film": 1.4}
    held = {}
    if scene is not None:
        b = scene.table("bubble")
        for key, name in (("t", "t"), ("roughness", "roughness"), ("f", "f"), ("r_d", "r_d"), ("r_s", "r_s"),
                          ("n_film", "n_film")):
            if key in b:
                vals[name] = float(b[key])
                if name != "n_film":
                    held[name] = "set by the scene file"
        kind, values = scene.thickness_spec()
        if "thickness_nm" in b or "thickness" in b:
            if kind == "constant":
                vals["thickness"] = float(values)
                held["thickness"] = "set by the scene file"
            elif kind == "drainage":
                vals["top"], vals["bottom"], vals["exponent"] = (float(x) for x in values)
                held.update(top="set by the scene file", bottom="set by the scene file",
                            exponent="set by the scene file")
        if "rotation_deg" in scene.table("lighting"):
            vals["rotation"] = math.radians(scene.table("lighting")["rotation_deg"])
            held["rotation"] = "set by the scene file"
    if init:
        keymap = {"thickness_nm": "thickness", "top_nm": "top", "bottom_nm": "bottom"}
        for k, v in init.items():
            if v is None:
                continue
            if k == "rotation_deg":
                vals["rotation"] = math.radians(float(v))
            elif keymap.get(k, k) in vals:
                vals[keymap.get(k, k)] = float(v)
    if t_from_calibration is not None:
        vals["t"] = float(t_from_calibration)
    if opts.roughness_init is not None and "roughness" not in held:
        vals["roughness"] = float(opts.roughness_init)
    if not 0 < vals["t"] < 1:
        raise InputError(f"starting t must lie in (0, 1), got {vals['t']}")
    if vals["r_d"] is None or vals["r_s"] is None:
        vals["r_s"] = (1 - vals["t"]) / (1 + vals["f"])
        vals["r_d"] = (1 - vals["t"]) - vals["r_s"]
    vals["split"] = vals["r_s"] / max(vals["r_s"] + vals["r_d"], 1e-12)
    aliases = {"thickness_nm": "thickness", "top_nm": "top", "bottom_nm": "bottom", "rotation_deg": "rotation",
               "f": "split"}
    known = ("t", "split", "r_d", "r_s", "roughness", "exposure", "rotation", "thickness", "top", "bottom", "exponent")
    for name in opts.hold:
        name = aliases.get(name, name)
        if name not in known:
            raise InputError(f"cannot hold {name!r}: known parameters are t, f, r_d, r_s, roughness, thickness_nm, "
                             "exposure, rotation_deg, top_nm, bottom_nm, exponent")
        held[name] = "held by request"
    return vals, held


def _decide(opts, vals, env, bg, settings, camera, lights):
    envpx = np.asarray(env.pixels)
    bg_kind = "photo" if bg is not None else "envmap"
    return resolve(
        model=opts.model, settings=settings, t=vals["t"], r_d=vals["r_d"], r_s=vals["r_s"],
        roughness=vals["roughness"], thickness_range=tuple(float(x) for x in opts.thickness_range),
        thickness_kind=opts.thickness, n_film=vals["n_film"], env_texel_angle=env.texel_angle,
        env_peak=float(envpx.max()), env_mean=float(envpx.mean()), background=bg_kind,
        background_peak=float(np.max(bg)) if bg is not None else float(envpx.max()),
        n_point_lights=len(lights), light_peak=max([max(l.irradiance) for l in lights], default=0.0),
        min_cos=math.sqrt(max(0.0, 1 - opts.rim**2)), tolerance=float(settings.get("tolerance", 1e-3)),
        env_pixels=envpx, env_irradiance_peak=float(np.max(np.asarray(env.irradiance))),
    )


def _layout(opts, fx, held: dict) -> tuple[tuple, dict]:
    """Fitted parameter names in order, and the reasons for those held."""
    hold = dict(held)
    names = []
    if fx.model == "physical":
        hold.setdefault("t", "physical model: Fresnel reflectance from n_film sets t and r_s")
        hold.setdefault("r_s", "physical model: Fresnel reflectance from n_film sets t and r_s")
        if not fx.diffuse:
            hold.setdefault("r_d", "diffuse term skipped: r_d cannot change the image")
        split_names = ("r_d",) if opts.free_split else ()
    else:
        if opts.free_split:
            if not fx.diffuse:
                hold.setdefault("r_d", "diffuse term skipped: r_d cannot change the image")
            split_names = ("r_d", "r_s")
        else:
            if not fx.diffuse:
                hold.setdefault("split", "diffuse term skipped: r_d cannot change the image and the split "
                                         "(eq. 14) would only trade r_s against the camera gain")
            split_names = ("split",)
    if fx.filtering.method == "mirror" or not fx.environment:
        hold.setdefault("roughness", f"roughness filtering skipped ({fx.filtering.method} lookup): "
                                     "roughness cannot change the image")
    if fx.interference in ("off", "incoherent"):
        for n in ("thickness", "top", "bottom", "exponent"):
            hold.setdefault(n, "interference skipped: thickness cannot change the image")
    if not opts.fit_rotation:
        hold.setdefault("rotation", "not fitted (FitOptions.fit_rotation is off)")
    cand = ["t", *split_names, "roughness", "exposure", "rotation"]
    if opts.thickness == "constant":
        cand.append("thickness")
    else:  # a map starts from a drainage fit
        cand += ["top", "bottom", "exponent"]
    if fx.model == "physical":
        cand = [c for c in cand if c not in ("t", "r_s", "split")]
    names = [c for c in cand if c not in hold]
    return tuple(names), hold


def _run_lm(lev: _Level, layout, kind, opts, vals, env, free_split, max_steps=None):
    solve, resid = _solver(lev.cfg, layout, kind, free_split, float(opts.robust_scale), int(max_steps or opts.max_steps),
                           float(opts.rtol), float(opts.atol))
    z0 = jnp.asarray([_inverse(n, vals[n]) for n in layout], jnp.float32)
    fixed = {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k not in layout}
    args = (fixed, env, None if lev.bg is None else jnp.asarray(lev.bg), jnp.asarray(lev.y), jnp.asarray(lev.w))
    z, ok, maxed, steps, r, jac = solve(z0, args)
    z = np.asarray(z, np.float64)
    new = dict(vals)
    for i, n in enumerate(layout):
        new[n] = float(_forward(n, z[i]))
    return new, z, bool(ok), bool(maxed), int(steps), np.asarray(r, np.float64), np.asarray(jac, np.float64), fixed


def _cost(r):
    return float(np.sum(r * r))


def _profile_from_pixels(height, d, w):
    """Robust least-squares drainage profile (top, bottom, exponent) through per-pixel thicknesses."""
    best = None
    x = np.clip((1 - height) / 2, 0, 1)
    for e in search.PROFILE_EXPONENTS:
        basis = np.stack([1 - x**e, x**e], axis=1)
        wt = w.copy()
        for _ in range(6):
            sw = np.sqrt(wt)
            coef, *_ = np.linalg.lstsq(basis * sw[:, None], d * sw, rcond=None)
            res = d - basis @ coef
            s = 1.4826 * np.median(np.abs(res)) + 1.0
            wt = w / np.maximum(1.0, np.abs(res) / (2.0 * s))
        score = np.median(np.abs(res))
        if best is None or score < best[0]:
            best = (score, coef[0], coef[1], e)
    _, top, bottom, e = best
    return max(top, 1.0), max(bottom, 1.0), e


@dataclass
class _Setup:
    """What a fit of one photo knows before it solves (:func:`_setup`)."""

    photo: np.ndarray
    background: np.ndarray | None
    vals: dict
    held: dict
    layout: tuple
    lm_kind: str
    fx: object
    decisions: list
    base_cfg: RenderConfig
    map_cfg: RenderConfig
    disc: tuple | None
    sigma: np.ndarray
    saturated: np.ndarray
    k_search: int
    lev_fit: _Level


def _setup(photo, env, opts: FitOptions, background, init, scene, saturated_in, decided=None) -> _Setup:
    """Validate the inputs, decide the effects (unless ``decided`` gives ``(fx, decisions)``),
    lay out the parameters and build the photo's fit level."""
    photo = np.asarray(photo, dtype=np.float64)
    if photo.ndim != 3 or photo.shape[2] != 3:
        raise InputError(f"the photo must be an RGB image (H, W, 3), got shape {photo.shape}")
    if not isinstance(env, EnvMap):
        raise InputError("the environment map must be an EnvMap")
    H, W = photo.shape[:2]
    if background is not None:
        background = np.asarray(background, dtype=np.float64)
        if background.shape != photo.shape:
            raise InputError(f"the background photo is {background.shape[1]}x{background.shape[0]}, "
                             f"the photo is {W}x{H}")
    vals, held0 = _defaults(scene, init, opts, opts.t_init)
    settings = dict(scene.table("effects")) if scene is not None else {}
    settings.update(dict(opts.effects))
    settings["model"] = opts.model
    # Unless told otherwise, fit with the alias-free 8-lobe spectral quadrature: its colour
    # error is below uniform 30 samples' at the cost of ~8 (experiments/accuracy_vs_time.py),
    # whereas "auto" may ask for hundreds of samples to bound the error everywhere.
    settings.setdefault("spectral", {"method": "fourier", "samples": 8})
    # A photographed film transmits the complement of the colour it reflects; over a bright
    # background that tint is as strong as the reflection, and eq. (11)'s grey t^4 would
    # push the thickness to another colour order (tests/test_fit.py::test_model_mismatch).
    settings.setdefault("transmission_tint", True)

    # camera
    lights = scene.point_lights() if scene is not None else ()
    center, radius = (0.0, 0.0, 0.0), 1.0
    if scene is not None and scene.table("camera").get("type", "orthographic") == "perspective":
        camera = scene.camera()
        if (camera.height, camera.width) != (H, W):
            raise InputError(f"the scene's camera is {camera.width}x{camera.height}, the photo is {W}x{H}")
        b = scene.table("bubble")
        center, radius = tuple(float(x) for x in b.get("center", (0, 0, 0))), float(b.get("radius", 1.0))
        disc = None
    else:
        disc = opts.disc
        if disc is None and scene is not None and "disc" in scene.table("camera"):
            disc = tuple(scene.table("camera")["disc"])
        if disc is None:
            disc = detect_disc(photo, background)
            disc = tuple(round(float(v), 2) for v in disc)
        disc = tuple(float(v) for v in disc)
        if len(disc) != 3 or disc[2] <= 2:
            raise InputError(f"the bubble's disc must be (cx, cy, r) with r > 2 pixels, got {disc}")
        camera = OrthographicCamera(W, H, *disc)

    fx, decisions = decided if decided is not None else _decide(opts, vals, env, background, settings, camera, lights)
    base_cfg = RenderConfig(effects=fx, camera=camera, center=center, radius=radius, point_lights=tuple(lights))
    layout, held = _layout(opts, fx, held0)
    lm_kind = "constant" if opts.thickness == "constant" else "drainage"
    map_cfg = base_cfg  # a map is fitted after a drainage profile: the local fits render the profile
    base_cfg = replace(base_cfg, effects=replace(fx, thickness=lm_kind))

    # data at the fit and search resolutions
    sigma = noise_sigma(photo, opts.noise_read, opts.noise_shot, opts.bits)
    saturated = (np.max(photo, axis=-1) >= opts.saturation) if photo.max() <= 1.0 + 1e-6 else np.zeros((H, W), bool)
    if saturated_in is not None:
        if np.shape(saturated_in) != (H, W):
            raise InputError(f"the saturation mask is {np.shape(saturated_in)}, the photo is {W}x{H}")
        saturated = saturated | np.asarray(saturated_in, bool)
    if saturated.any():
        from scipy import ndimage as ndi

        saturated = ndi.binary_dilation(saturated)
    k_fit = opts.downsample or max(1, math.ceil(max(H, W) / opts.fit_size))
    k_search = max(k_fit, math.ceil(max(H, W) / opts.search_size))
    lev_fit = _make_level(k_fit, base_cfg, photo, sigma, background, saturated, opts)
    if lev_fit.mask.sum() < 10:
        raise InputError("fewer than 10 usable pixels on the bubble (disc too small, or saturated)")
    return _Setup(photo, background, vals, held, layout, lm_kind, fx, decisions, base_cfg, map_cfg, disc, sigma,
                  saturated, k_search, lev_fit)


def _warm_doubt(st: _Setup, opts: FitOptions, new: dict, ok: bool, r) -> str | None:
    """Why a warm-started solution is doubtful, or None: the solver failed, the thickness
    left the searched range, or the noise-weighted reduced chi^2 exceeds WARM_START_CHI2."""
    lo, hi = opts.thickness_range
    dof0 = max(int(np.count_nonzero(st.lev_fit.w)) - len(st.layout), 1)
    chi2 = _cost(r) / dof0
    thick = [new[k] for k in ("thickness", "top", "bottom") if k in st.layout]
    if not (ok and np.all(np.isfinite(r))):
        return "the solver failed"
    if any(not lo - 1 <= d <= hi + 1 for d in thick):
        return "the thickness left the searched range"
    if not chi2 <= WARM_START_CHI2:
        return f"reduced chi^2 = {chi2:.1f}"
    return None


def _finish(st: _Setup, env, opts: FitOptions, new: dict, z, ok: bool, maxed: bool, steps: int, r, jac, fixed: dict,
            notes: list, t_start: float) -> FitResult:
    """Standard errors, the thickness map, the full-resolution render and the result of a
    solved fit (``new, z, ok, maxed, steps, r, jac, fixed`` as :func:`_run_lm` returns)."""
    photo, background, vals, held, layout, lm_kind = st.photo, st.background, st.vals, st.held, st.layout, st.lm_kind
    decisions, base_cfg, map_cfg, disc, sigma, saturated = (st.decisions, st.base_cfg, st.map_cfg, st.disc, st.sigma,
                                                            st.saturated)
    lev_fit, envj = st.lev_fit, env
    # standard errors (delta method)
    nres = int(np.count_nonzero(lev_fit.w)) if lev_fit.w.size else 0
    dof = max(nres - len(layout), 1)
    s2 = _cost(r) / dof
    rep, rep_jac = _reporter(layout, lm_kind, opts.free_split)
    reported = {k: float(v) for k, v in rep(jnp.asarray(z, jnp.float32), fixed).items()}
    stderr = {k: None for k in reported}
    finite_err = True
    if layout:
        jtj = jac.T @ jac
        try:
            cov_z = s2 * np.linalg.inv(jtj)
            if not np.all(np.isfinite(cov_z)) or np.any(np.diag(cov_z) < 0):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            cov_z = np.full((len(layout), len(layout)), np.nan)
            finite_err = False
        gmat = rep_jac(jnp.asarray(z, jnp.float32), fixed)
        for key, g in gmat.items():
            g = np.asarray(g, np.float64).reshape(-1)
            var = g @ cov_z @ g
            stderr[key] = float(math.sqrt(var)) if np.isfinite(var) and var >= 0 else float("nan")
        heldnames = {"thickness": "thickness_nm", "top": "top_nm", "bottom": "bottom_nm", "rotation": "rotation_deg"}
        for n in held:
            key = heldnames.get(n, n)
            if key in stderr and n not in layout:
                stderr[key] = None
        if "split" in held:  # f = r_d / r_s is then fixed; r_d and r_s still move with t
            stderr["f"] = None
            if "t" not in layout:
                stderr.update(r_d=None, r_s=None)

    converged = ok and bool(np.all(np.isfinite(r))) and finite_err
    if not ok:
        notes.insert(0, "solver reached max_steps without meeting its tolerances" if maxed
                     else "the solver failed (diverged or a non-finite residual)")
    if not finite_err:
        notes.insert(0, "the Jacobian is singular at the optimum: some parameter is not constrained by the photo")
    lo, hi = opts.thickness_range
    for key in ("thickness_nm", "top_nm", "bottom_nm"):
        if key in reported and (key != "thickness_nm" or "thickness" in layout):
            if not lo - 1 <= reported[key] <= hi + 1:
                notes.append(f"{key} = {reported[key]:.0f} nm lies outside the searched range {lo:.0f}-{hi:.0f} nm")

    # per-pixel map
    thickness_map = None
    stderr_map = None
    final_vals = dict(new)
    prof = None
    if opts.thickness != "constant":
        prof = (new["top"], new["bottom"], new["exponent"])
    if opts.thickness == "map":
        full = _make_level(1, map_cfg, photo, sigma, background, saturated, opts)
        dmap, emap, map_ok = _fit_map(full, new, prof, opts, envj)
        final_vals["map"] = dmap
        thickness_map = np.where(full.inside, dmap, np.nan)
        stderr_map = np.where(full.mask, emap, np.nan)
        film = full.mask
        reported["thickness_nm"] = float(np.median(dmap[film])) if film.any() else float("nan")
        stderr["thickness_nm"] = float(np.median(emap[film])) if film.any() else float("nan")
        if not map_ok:
            converged = False
            notes.append("the per-pixel thickness refinement did not converge everywhere")

    # full-resolution render and residual
    full_cfg = map_cfg if opts.thickness == "map" else base_cfg
    p_final = _params({k: jnp.asarray(v, jnp.float32) for k, v in final_vals.items()},
                      "map" if opts.thickness == "map" else lm_kind, opts.free_split)
    img = np.asarray(render(p_final, full_cfg, envj, None if background is None else jnp.asarray(background, jnp.float32)),
                     np.float64)
    resid_img = photo - img
    full_mask = _make_level(1, base_cfg, photo, sigma, background, saturated, opts).mask if opts.thickness != "map" else film
    rms = float(np.sqrt(np.mean(resid_img[full_mask] ** 2))) if full_mask.any() else float("nan")
    if opts.thickness == "drainage":
        from ..model.thickness import drainage_profile

        _, _, hgt = _geometry(full_cfg)
        inside = _geometry(full_cfg)[0]
        thickness_map = np.where(inside, np.asarray(drainage_profile(jnp.asarray(hgt), *prof)), np.nan)
    reported["n_film"] = float(vals["n_film"])
    heldlist = [(n, why) for n, why in held.items()]
    message = "; ".join(notes) if notes else "converged"
    return FitResult(
        params=reported, stderr=stderr, held=heldlist, converged=bool(converged), message=message,
        iterations=steps, residual_rms=rms, time_s=time.perf_counter() - t_start, effects=decisions,
        render=img, residual=resid_img, thickness_map=thickness_map, thickness_stderr_map=stderr_map,
        disc=disc, thickness_kind=opts.thickness, model=opts.model, reduced_chi2=s2, pixels_used=int(lev_fit.mask.sum()),
    )


def fit_photo(photo: np.ndarray, env: EnvMap, *, options: FitOptions = FitOptions(), background=None,
              init: dict | None = None, scene=None, saturated: np.ndarray | None = None) -> FitResult:
    """Fit the forward model to a photo.

    Args:
        photo: (H, W, 3) linear photo of the bubble.
        env: the environment map (aligned with the camera: it looks along -z of the map's
            frame; ``rotation`` about +y unless fitted or set by the scene).
        options: :class:`FitOptions`.
        background: optional (H, W, 3) linear photo without the bubble: the transmitted
            background then comes from it (gain 1) instead of the map.
        init: warm start, a dict of the JSON's params (e.g. the previous frame's); the
            global thickness search is then skipped unless this fit fails.
        scene: optional :class:`~bubblefit.model.scene.Scene`: its camera (perspective or a
            disc), n_film, effects settings, and every value its ``[bubble]`` table (and
            ``lighting.rotation_deg``) sets explicitly, which is then held fixed.
        saturated: optional (H, W) bool of clipped pixels (e.g. :attr:`Image.saturated`),
            excluded in addition to values >= ``options.saturation``.

    Returns:
        A :class:`FitResult`.
    """
    t_start = time.perf_counter()
    opts = options
    st = _setup(photo, env, opts, background, init, scene, saturated)
    photo, background, vals, layout, lm_kind = st.photo, st.background, st.vals, st.layout, st.lm_kind
    base_cfg, sigma, saturated, k_search, lev_fit = st.base_cfg, st.sigma, st.saturated, st.k_search, st.lev_fit
    envj = env
    notes = []
    search_thickness = "thickness" in layout or "top" in layout

    def search_start(v):
        lev_s = _make_level(k_search, base_cfg, photo, sigma, background, saturated, opts)
        lo, hi = opts.thickness_range
        grid = search.thickness_grid(lo, hi, opts.search_step_nm)
        refl, fixedpart = _candidates(lev_s, v, grid, opts.free_split, envj)
        y = jnp.asarray(lev_s.y.reshape(-1, 3)[lev_s.mask.reshape(-1)])
        w2 = jnp.asarray(lev_s.w.reshape(-1, 3)[lev_s.mask.reshape(-1)] ** 2)
        starts = []
        if lm_kind == "constant":
            cost, gain = search.score_global(refl, fixedpart, y, w2)
            cost, gain = np.asarray(cost), np.asarray(gain)
            for d in search.local_minima(cost, grid, opts.candidates, separation=20.0):
                g = float(gain[int(np.argmin(np.abs(grid - d)))])
                starts.append(dict(v, thickness=d, exposure=max(g, 1e-6) if "exposure" in layout else v["exposure"]))
        else:
            zero = jnp.zeros(refl.shape[:2])
            best, _, gain = search.score_pixels(refl, fixedpart, y, w2, zero, per_pixel_gain=True)
            gain = np.asarray(gain)
            g = float(np.median(gain[gain > 0])) if np.any(gain > 0) else v["exposure"]
            if base_cfg.effects.tint:
                # A gain per pixel can cancel the reflected colour against the tint's
                # complementary one; scan one gain for all pixels around the hue-matched
                # median instead.
                scan = []
                for gg in g * np.geomspace(1 / 3, 3, 17):
                    _, c, _ = search.score_pixels(gg * refl, fixedpart, y, w2, zero, per_pixel_gain=False)
                    c = np.asarray(c)
                    scan.append((float(np.sum(np.minimum(c, 4 * np.median(c)))), gg))
                g = min(scan)[1]
            hgt = lev_s.height.reshape(-1)[lev_s.mask.reshape(-1)]
            d_pix = grid[np.asarray(best)]
            profiles = [_profile_from_pixels(hgt, d_pix, np.ones_like(d_pix))]
            # and a global search over the profile's own parameters: every pixel's cost of
            # every grid thickness at gain g, summed along each candidate profile
            cost = np.asarray(search.pixel_costs(g * refl, fixedpart, y, w2))
            profiles.append(search.best_profile(cost, grid, hgt))
            for top, bottom, e in profiles:
                nv = dict(v, exposure=g if "exposure" in layout else v["exposure"])
                for n, val in (("top", top), ("bottom", bottom), ("exponent", e)):
                    if n in layout:
                        nv[n] = val
                starts.append(nv)
        # refine each start on the search image, keep the best
        best_v, best_c = None, np.inf
        for s in starts:
            out = _run_lm(lev_s, layout, lm_kind, opts, s, envj, opts.free_split, max_steps=opts.search_steps)
            c = _cost(out[5])
            if np.isfinite(c) and c < best_c:
                best_v, best_c = out[0], c
        return best_v if best_v is not None else starts[0]

    warm = bool(init)
    start = vals
    if search_thickness and not warm:
        start = search_start(vals)
    new, z, ok, maxed, steps, r, jac, fixed = _run_lm(lev_fit, layout, lm_kind, opts, start, envj, opts.free_split)
    why = _warm_doubt(st, opts, new, ok, r) if warm and search_thickness else None
    if why:
        # A warm start can settle in a neighbouring colour order: search globally and keep
        # whichever fit explains the photo better.
        start = search_start(vals)
        second = _run_lm(lev_fit, layout, lm_kind, opts, start, envj, opts.free_split)
        if np.isfinite(_cost(second[5])) and (not np.isfinite(_cost(r)) or _cost(second[5]) < _cost(r)):
            new, z, ok, maxed, steps, r, jac, fixed = second
            notes.append(f"warm start rejected ({why}); searched globally")
        else:
            notes.append(f"warm start doubtful ({why}); a global search did not do better")

    return _finish(st, env, opts, new, z, ok, maxed, steps, r, jac, fixed, notes, t_start)


@functools.lru_cache(maxsize=16)
def _batched_solver(*key):
    """:func:`_solver`'s ``solve`` vmapped over frames: ``z0``, ``y`` and ``w`` carry a
    leading frame axis; the fixed values, the map and the background are shared."""
    solve, _ = _solver(*key)
    return jax.jit(jax.vmap(solve, in_axes=(0, (None, None, None, 0, 0))))


def fit_batch(photos, env: EnvMap, *, options: FitOptions = FitOptions(), background=None, init: dict,
              previous: dict | None = None, scene=None) -> list[FitResult]:
    """Fit consecutive frames of a sequence together, warm-started, in one vmapped solve.

    Frame ``k`` of the batch starts from ``init`` (the last fitted frame's params) with
    its thicknesses extrapolated linearly from ``previous`` (the frame before that):
    ``init + (k + 1) (init - previous)``. One Levenberg-Marquardt solve runs for all
    frames at once (:func:`jax.vmap` over frames; the loop runs until the slowest frame
    has converged). Each solution then gets :func:`fit_photo`'s warm-start check; a
    doubtful one is refitted alone by :func:`fit_photo` (global search included).
    Standard errors, renders and maps are computed per frame as in :func:`fit_photo`.

    Whether this is faster than fitting frame after frame depends on the machine: on a
    2-core CPU the solve is compute-bound and the batch is slower (the vmapped loop also
    runs every frame for as many steps as the slowest needs); see
    ``experiments/bench_sequence.py``.

    Frames must share their size, the disc (give ``options.disc``) and ``background``;
    otherwise, or for a single frame, each is fitted alone.

    Returns:
        One :class:`FitResult` per photo, in order.
    """
    photos = [np.asarray(p, np.float64) for p in photos]
    t_start = time.perf_counter()
    alone = lambda photo, start: fit_photo(photo, env, options=options, background=background, init=start,
                                           scene=scene)
    if len(photos) < 2 or options.disc is None or len({p.shape for p in photos}) != 1:
        return [alone(p, init) for p in photos]
    first = _setup(photos[0], env, options, background, init, scene, None)
    layout, kind = first.layout, first.lm_kind
    thick = [n for n in ("thickness", "top", "bottom") if n in layout]
    if not thick:
        return [alone(p, init) for p in photos]
    setups = [first] + [_setup(p, env, options, background, init, scene, None, decided=(first.fx, first.decisions))
                        for p in photos[1:]]
    prev_vals = _defaults(scene, previous, options, options.t_init)[0] if previous else None
    z0 = []
    for k in range(len(photos)):
        v = dict(first.vals)
        if prev_vals is not None:
            for n in thick:
                v[n] = max(v[n] + (k + 1) * (first.vals[n] - prev_vals[n]), 1.0)
        z0.append([_inverse(n, v[n]) for n in layout])
    fixed = {k: jnp.asarray(v, jnp.float32) for k, v in first.vals.items() if k not in layout}
    solve = _batched_solver(first.lev_fit.cfg, layout, kind, options.free_split, float(options.robust_scale),
                            int(options.max_steps), float(options.rtol), float(options.atol))
    bg = None if first.lev_fit.bg is None else jnp.asarray(first.lev_fit.bg)
    out = solve(jnp.asarray(z0, jnp.float32), (fixed, env, bg, jnp.asarray(np.stack([s.lev_fit.y for s in setups])),
                                               jnp.asarray(np.stack([s.lev_fit.w for s in setups]))))
    zs, oks, maxeds, steps, rs, jacs = (np.asarray(x) for x in out)
    share = (time.perf_counter() - t_start) / len(photos)  # each frame's part of the batch
    results = []
    for k, st in enumerate(setups):
        t0 = time.perf_counter() - share
        z = zs[k].astype(np.float64)
        new = dict(st.vals, **{n: float(_forward(n, z[i])) for i, n in enumerate(layout)})
        r = rs[k].astype(np.float64)
        why = _warm_doubt(st, options, new, bool(oks[k]), r)
        if why:
            start = {key: float(x) for key, x in _reporter(layout, kind, options.free_split)[0](zs[k], fixed).items()}
            ok_start = all(np.isfinite(x) for x in start.values())
            results.append(alone(photos[k], dict(init, **start) if ok_start else init))
            results[-1].message = f"batched warm start doubtful ({why}); refitted alone: {results[-1].message}"
            continue
        results.append(_finish(st, env, options, new, z, bool(oks[k]), bool(maxeds[k]), int(steps[k]), r,
                               jacs[k].astype(np.float64), fixed, ["batched warm start"], t0))
    return results


# ---------------------------------------------------------------------------------------
# Per-pixel thickness maps
# ---------------------------------------------------------------------------------------


def _prior_map(lev: _Level, prof):
    from ..model.thickness import drainage_profile

    return np.asarray(drainage_profile(jnp.asarray(lev.height), *prof), np.float64)


@functools.lru_cache(maxsize=16)
def _pixel_solver(basis, robust: float, max_steps: int):
    """Vmapped optimistix LM for one thickness per pixel (paper model, eq. 11 linear in eq. 10)."""
    lam = jnp.asarray(basis.wavelengths, jnp.float32)
    wts = jnp.asarray(basis.weights, jnp.float32)
    sigma = None if getattr(basis, "sigma", None) is None else jnp.asarray(basis.sigma, jnp.float32)

    def model(d, a):
        m, c, xfac, t, r_s = a  # r_s: 0 without the transmission tint
        x = d * xfac  # optical path 2 n d cos th_t of eq. (8)
        cos_delta = jnp.cos(2 * jnp.pi * x / lam + jnp.pi)
        if sigma is not None:  # ``fourier`` lobes: the fringe averaged over each lobe
            cos_delta = cos_delta * fringe_attenuation(x, sigma)
        phi = (0.5 * (1.0 + cos_delta)) @ wts  # cos^2(delta/2), integrated
        refl, back = search.paper_candidates(phi, m, c, t, r_s)
        return refl + back

    def resid(u, a):
        m, c, xfac, t, r_s, y, w, prior, sig = a
        d = _forward("thickness", u[0])
        r = _robust((model(d, (m, c, xfac, t, r_s)) - y) * w, robust)
        return jnp.concatenate([r, ((d - prior) / sig)[None]])

    lm = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-5)

    def one(u0, a):
        sol = optx.least_squares(resid, lm, u0, a, max_steps=max_steps, throw=False)
        r = resid(sol.value, a)
        j = jax.jacfwd(resid)(sol.value, a)[:, 0]
        dd = jax.grad(lambda u: _forward("thickness", u))(sol.value[0])
        return sol.value[0], sol.result == optx.RESULTS.successful, r, j, dd

    return jax.jit(jax.vmap(one))


def _fit_map(lev: _Level, vals: dict, prof, opts: FitOptions, env):
    """Per-pixel thickness (H, W), its standard error (H, W), and whether all pixels converged."""
    fx = lev.cfg.effects
    prior = _prior_map(lev, prof)
    sel = lev.mask.reshape(-1)
    y = lev.y.reshape(-1, 3)[sel]
    w = lev.w.reshape(-1, 3)[sel]
    pr = prior.reshape(-1)[sel]
    sig = float(opts.map_prior_nm)
    base = {k: v for k, v in vals.items() if k not in ("map",)}
    dmap = prior.copy()
    emap = np.full(prior.shape, np.nan)
    if fx.model == "paper" and fx.interference == "two_beam":
        lo, hi = opts.thickness_range
        grid = search.thickness_grid(lo, hi, opts.search_step_nm)
        # reflected radiance with interference off, at the fitted values (exposure included)
        off = replace(lev.cfg, effects=replace(fx, interference="off", spectral=None, thickness="constant"))
        p = _params({k: jnp.asarray(v, jnp.float32) for k, v in dict(base, thickness=0.0).items()}, "constant",
                    opts.free_split)
        _, terms = _render_terms_jit(p, off, env, None if lev.bg is None else jnp.asarray(lev.bg))
        zero = jnp.zeros(lev.y.shape, jnp.float32)
        m = np.asarray(terms.get("front", zero) + terms.get("rear", zero)).reshape(-1, 3)[sel]
        c = np.asarray(terms.get("background", zero)).reshape(-1, 3)[sel]
        n = float(vals["n_film"])
        cos_t = np.sqrt(np.clip(1.0 - (1.0 - lev.cos.reshape(-1)[sel] ** 2) / n**2, 0.0, 1.0))
        t = float(vals["t"])
        r_s = float(p.r_s) if fx.tint and fx.transmission else 0.0
        table = jnp.asarray(search.phi_table(fx.spectral, 2 * n * float(grid.max())))
        best_d = np.empty(len(pr))
        chunk = 2048
        for s in range(0, len(pr), chunk):
            e = slice(s, s + chunk)
            x = 2 * n * grid[:, None] * cos_t[e][None, :]
            phi = search.phi_rgb(table, jnp.asarray(x, jnp.float32))
            refl, back = search.paper_candidates(phi, jnp.asarray(m[e])[None], jnp.asarray(c[e])[None], t, r_s)
            pri = jnp.asarray(((grid[:, None] - pr[e][None, :]) / sig) ** 2, jnp.float32)
            best, _, _ = search.score_pixels(refl, back, jnp.asarray(y[e]), jnp.asarray(w[e] ** 2), pri,
                                             per_pixel_gain=False)
            best_d[e] = grid[np.asarray(best)]
        solve = _pixel_solver(fx.spectral, float(opts.robust_scale), 40)
        u0 = np.asarray([[_inverse("thickness", d)] for d in best_d], np.float32)
        ones = np.ones(len(pr), np.float32)
        args = (jnp.asarray(m, jnp.float32), jnp.asarray(c, jnp.float32), jnp.asarray(2 * n * cos_t, jnp.float32),
                jnp.asarray(t * ones), jnp.asarray(r_s * ones), jnp.asarray(y), jnp.asarray(w),
                jnp.asarray(pr, jnp.float32), jnp.asarray(sig * ones))
        u, ok, r, j, dd = solve(jnp.asarray(u0), args)
        d = np.asarray(_forward("thickness", u), np.float64)
        r, j = np.asarray(r, np.float64), np.asarray(j, np.float64)
        s2 = float(np.sum(r[:, :3] ** 2) / max(3 * len(pr) - len(pr), 1))
        var_u = s2 / np.maximum(np.sum(j[:, :3] ** 2, axis=1) + np.sum(j[:, 3:] ** 2, axis=1) / max(s2, 1e-12), 1e-30)
        err = np.abs(np.asarray(dd, np.float64)) * np.sqrt(var_u)
        all_ok = bool(np.mean(np.asarray(ok)) > 0.99)
    else:
        d, err, all_ok = _fit_map_generic(lev, base, prior, sel, y, w, pr, sig, opts, env)
    dmap.reshape(-1)[sel] = d
    emap.reshape(-1)[sel] = err
    return dmap, emap, all_ok


@functools.partial(jax.jit, static_argnames=("cfg", "free_split"))
def _map_jvp(base, dmap, cfg, env, bg, free_split):
    """Render with a thickness map and the per-pixel derivative (a map's Jacobian is diagonal)."""
    def f(m):
        return render(_params(dict(base, map=m), "map", free_split), cfg, env, bg)

    return jax.jvp(f, (dmap,), (jnp.ones_like(dmap),))


def _fit_map_generic(lev, base, prior, sel, y, w, pr, sig, opts, env):
    """Any model: search offsets around the profile by rendering, then diagonal Gauss-Newton."""
    cfg = replace(lev.cfg, effects=replace(lev.cfg.effects, thickness="map"))
    bg = None if lev.bg is None else jnp.asarray(lev.bg)
    b = {k: jnp.asarray(v, jnp.float32) for k, v in base.items()}
    offsets = np.arange(-2 * sig, 2 * sig + 1e-9, opts.search_step_nm)
    maps = np.maximum(prior[None] + offsets[:, None, None], 0.0).astype(np.float32)
    refl, back = _candidates_render(b, jnp.asarray(maps), cfg, env, bg, opts.free_split)
    g = len(offsets)
    refl = np.asarray(refl).reshape(g, -1, 3)[:, sel] * float(base["exposure"])
    back = np.asarray(back).reshape(g, -1, 3)[:, sel]
    pri = ((maps.reshape(g, -1)[:, sel] - pr[None]) / sig) ** 2
    best, _, _ = search.score_pixels(jnp.asarray(refl), jnp.asarray(back), jnp.asarray(y), jnp.asarray(w**2),
                                     jnp.asarray(pri, jnp.float32), per_pixel_gain=False)
    d = maps.reshape(g, -1)[:, sel][np.asarray(best), np.arange(len(pr))].astype(np.float64)
    full = prior.copy()
    lam = 1e-3
    for _ in range(8):
        full.reshape(-1)[sel] = d
        img, dimg = _map_jvp(b, jnp.asarray(full, jnp.float32), cfg, env, bg, opts.free_split)
        img = np.asarray(img).reshape(-1, 3)[sel]
        jd = np.asarray(dimg).reshape(-1, 3)[sel] * w
        res = (img - y) * w
        grad = np.sum(jd * res, axis=1) + (d - pr) / sig**2
        hess = np.sum(jd * jd, axis=1) + 1 / sig**2
        step = -grad / (hess * (1 + lam))
        d = np.maximum(d + np.clip(step, -30, 30), 0.0)
    s2 = float(np.sum(res**2) / max(2 * len(pr), 1))
    err = np.sqrt(s2 / hess)
    return d, err, bool(np.all(np.abs(step) < 1.0))
