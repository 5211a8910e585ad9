"""Which effects a scene simulates, decided once per scene from cheap bounds.

Each effect is its own term of the forward model (:mod:`bubblefit.model.render`). The scene's
``[effects]`` table sets each to on (``true`` or a named method), off (``false``) or
``auto``; :func:`resolve` turns ``auto`` into on or off by bounding how much the image
can change, in linear radiance, between the cheaper choice and the converged
everything-on model (:func:`all_on_settings`), and compares that bound with one
tolerance (``DEFAULT_TOLERANCE`` unless the scene sets ``effects.tolerance``). The
decision is static: a term that is off is never traced nor computed.

The bounds (each reason printed by ``--explain`` names the bound and its value):

- film terms (interference, spectral sampling, internal bounces): the film's coefficient
  of each term (eq. 10's factor ``4 t^2 cos^2(delta/2)`` for ``paper``; the Airy
  ``R``, ``T T`` and ``T R^k T`` for ``physical``) is evaluated with the renderer's own
  functions (:mod:`bubblefit.optics.film`, :mod:`bubblefit.optics.spectral`) on a grid of thickness
  over the scene's range and incidence cosine over the image's range, for the cheaper
  choice and for the converged one; the largest RGB difference times the largest
  radiance the term multiplies is the bound.
- roughness filtering: the mirror lookup and the filtered lookup differ by (i) the
  lobe's albedo against the mirror's (eq. 1's ``cos th_r`` limit) times the map's peak and
  (ii) how much the bilinear map can change over the lobe's angular radius (a Lipschitz
  bound from neighbouring texel differences, row by row, with the row's full range near
  the poles).
- front/rear reflection, background transmission, diffuse: the term's largest film
  coefficient times the largest radiance it can carry (map peak, point-light peak of
  eq. 3, irradiance-table peak over pi, background peak).
- transmission tint (``paper`` only): eq. (11) transmits a grey ``t^4``; a film that does
  not absorb transmits the complement of what it reflects, so with the tint each film
  transmits ``t^2 - r_s (F - 2 t^2)`` per wavelength (``F`` eq. 10's factor, ``2 t^2`` its
  spectral mean; see :mod:`bubblefit.model.render`). It changes the image by at most
  ``4 r_s t^4`` times the background peak. ``auto`` keeps eq. (11) as written (the
  ``paper`` model is the paper's) and states that bound; ``true`` adds the tint. Fits
  of photographs turn it on (:mod:`bubblefit.inverse.fit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..lighting.filtering import FilterConfig
from ..optics.spectral import LAMBDA_MIN, SpectralBasis, spectral_basis

__all__ = ["Effects", "Decision", "resolve", "all_on_settings", "DEFAULT_TOLERANCE"]

#: Default tolerance, in linear radiance of the rendered image (1/1000 of a white of 1).
DEFAULT_TOLERANCE = 1e-3
#: Most internal bounces (``physical``): the all-on model's count and the cap of ``auto``.
MAX_AUTO_BOUNCES = 8
#: Uniform spectral sample counts ``auto`` tries, cheapest first (then ``reference``).
SPECTRAL_CANDIDATES = (10, 16, 20, 24, 32, 40, 48, 64, 80, 100, 128, 160, 200, 256, 320, 400)
#: Gauss-Hermite nodes per axis of the all-on (and ``auto``) mipmap filter.
ALL_ON_NODES = 4


@dataclass(frozen=True)
class Effects:
    """The resolved, static set of effects a render computes."""

    model: str = "paper"
    front_reflection: bool = True
    rear_reflection: bool = True
    transmission: bool = True
    interference: str = "two_beam"  # off | two_beam | airy | incoherent
    diffuse: bool = True
    environment: bool = True
    point_lights: bool = False
    filtering: FilterConfig = FilterConfig()
    spectral: SpectralBasis | None = None
    bounces: int = 1
    thickness: str = "constant"
    background: str = "envmap"  # envmap | black | photo
    tint: bool = False  # paper model: the film's complementary colour in transmission

    @property
    def fresnel(self) -> bool:
        return self.model == "physical"


@dataclass(frozen=True)
class Decision:
    """One line of ``--explain``: the effect, whether it is simulated, and why."""

    effect: str
    simulated: bool
    reason: str
    setting: str = ""

    def line(self) -> str:
        state = "simulated" if self.simulated else "skipped"
        setting = f" [{self.setting}]" if self.setting else ""
        return f"{self.effect:<20} {state:<9}{setting} {self.reason}"


def all_on_settings(model: str = "paper", settings: dict | None = None) -> dict:
    """The ``[effects]`` table of the converged everything-on model (the reference of ``auto``).

    Every term on (front, rear, transmission, diffuse), interference ``two_beam`` (paper)
    or ``airy`` (physical) with the 800-sample ``reference`` spectral integration,
    ``mipmap`` filtering with :data:`ALL_ON_NODES` nodes, and :data:`MAX_AUTO_BOUNCES`
    internal bounces (physical). Keys of ``settings`` other than these (``tolerance``)
    are kept. Returns a new dict usable as a scene's ``[effects]`` table.
    """
    out = dict(settings or {})
    out.update(model=model, front_reflection=True, rear_reflection=True, transmission=True, diffuse=True,
               interference="airy" if model == "physical" else "two_beam", filtering="mipmap",
               nodes=ALL_ON_NODES, spectral={"method": "reference"})
    if model == "physical":
        out["bounces"] = MAX_AUTO_BOUNCES
    else:
        out.pop("bounces", None)
    return out


# ----------------------------------------------------------------------------------------
# Bounds of the film terms
# ----------------------------------------------------------------------------------------

def _grids(thickness_range, min_cos, n_film, max_points: int = 800):
    """Thickness (D, C) and incidence-cosine (C,) grids covering the scene.

    Interference depends on the optical path ``x = 2 n d cos t`` (eq. 8) and, weakly, on
    the Fresnel factors of ``cos``. Every pixel's ``x`` lies in
    ``[2 n d_min cos t_min, 2 n d_max]``; the grid pairs each of a few cosines with that
    whole range of ``x`` (a superset of the image's pairs), in steps of lambda_min / 24 (the
    two-beam colour is sampled 24 times per shortest period), at most ``max_points``.
    """
    dmin, dmax = thickness_range
    c_lo = max(min(min_cos, 1.0), 1e-3)
    cos = np.unique(np.concatenate([np.linspace(c_lo, 1.0, 6), [1.0]]))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - cos**2) / n_film**2))
    x_lo, x_hi = 2 * n_film * dmin * float(cos_t.min()), 2 * n_film * dmax
    step = LAMBDA_MIN / 24.0
    npts = int(min(max_points, max(2, math.ceil((x_hi - x_lo) / step) + 1)))
    x = np.linspace(x_lo, x_hi, npts) if x_hi > x_lo else np.array([x_lo])
    d = x[:, None] / (2 * n_film * np.maximum(cos_t[None, :], 1e-6))
    return d, cos


def _film_spectra(model, mode, lam, d, cos, t, n_film) -> np.ndarray:
    """Per-wavelength film values on the grid: eq. (10)'s factor (D, C, K) for ``paper``,
    the reflectance R (D, C, K, 2) of :func:`film.airy_reflectance` or
    :func:`film.two_beam_reflectance` for ``physical``. One evaluation for all ``lam`` (K,)."""
    import jax.numpy as jnp

    from ..optics import film

    dd = jnp.asarray(d, dtype=jnp.float32)[..., None]
    cc = jnp.asarray(cos, dtype=jnp.float32)[None, :, None]
    ll = jnp.asarray(lam, dtype=jnp.float32)[None, None, :]
    if model == "paper":
        return np.asarray(film.paper_interference_factor(dd, ll, n_film, cc, t))
    fn = film.two_beam_reflectance if mode == "two_beam" else film.airy_reflectance
    return np.asarray(fn(dd, ll, n_film, cc))


def _film_coefficients(model, mode, weights, spectra, cos, t, n_film, bounces, tint_rs=None):
    """RGB coefficients of the model's terms on a (thickness, cosine) grid.

    Args:
        model: ``paper`` | ``physical``; mode: ``off`` | ``incoherent`` | ``two_beam`` | ``airy``.
        weights: (K, 3) spectral weights (:class:`SpectralBasis`), ignored for grey modes.
        spectra: :func:`_film_spectra` at the basis's wavelengths (D, C, K[, 2]), or for the
            grey modes any array whose first axis is D.
        cos: (C,) incidence cosines; bounces: internal bounces to return (physical).
        tint_rs: ``r_s`` when the paper model's transmission tint is on, else None.

    Returns:
        dict with ``front`` (D, C, 3), ``background`` (D, C, 3) and ``rear`` a list of
        (D, C, 3), one per bounce (paper: one, eq. 11's ``t^2 F``).
    """
    grey = mode in ("off", "incoherent")
    shape = (np.shape(spectra)[0], len(cos), 1)
    if grey:
        rgb = lambda s: np.broadcast_to(s, s.shape[:-1] + (3,))
    else:
        rgb = lambda s: s @ np.asarray(weights, dtype=s.dtype)
    if model == "paper":
        if mode == "off":
            f = np.ones(shape)
        elif mode == "incoherent":
            f = np.full(shape, 2.0 * t * t)
        else:
            f = spectra
        bg = np.full(f.shape[:-1] + (3,), t**4)
        if tint_rs is not None and not grey:
            from ..optics.film import paper_tinted_transmission

            bg = rgb(np.asarray(paper_tinted_transmission(f, t, tint_rs)) ** 2)
        f = rgb(f)
        return {"front": f, "rear": [t * t * f], "background": bg}
    if grey:
        from ..optics.film import incoherent_reflectance

        r1 = np.asarray(incoherent_reflectance(np.asarray(cos, dtype=np.float32), n_film), dtype=np.float64)
        r = np.broadcast_to(r1[None, :, None, :], shape + (2,))
    else:
        r = spectra
    tr = 1.0 - r
    mean = lambda x: np.mean(x, axis=-1)
    out = {"front": rgb(mean(r)), "background": rgb(mean(tr * tr)), "rear": []}
    path = tr * r
    for _ in range(bounces):
        out["rear"].append(rgb(mean(path * tr)))
        path = path * r
    return out


def _coeff_diff(a, b, w_front, w_rear, w_bg, bounces=None):
    """Largest radiance difference of two coefficient sets, each term times its radiance bound."""
    nb = len(a["rear"]) if bounces is None else bounces
    diff = w_front * np.max(np.abs(a["front"] - b["front"]))
    diff += w_bg * np.max(np.abs(a["background"] - b["background"]))
    rear = 0.0
    for k in range(max(len(a["rear"]), len(b["rear"]))):
        ra = a["rear"][k] if k < len(a["rear"]) and k < nb else 0.0
        rb = b["rear"][k] if k < len(b["rear"]) else 0.0
        rear = rear + np.abs(ra - rb)
    return float(diff + w_rear * np.max(rear))


# ----------------------------------------------------------------------------------------
# Bound of the roughness filter (mirror lookup against the filtered lookup)
# ----------------------------------------------------------------------------------------

def _lookup_variation(pixels: np.ndarray, radius: float, theta_range=(0.0, math.pi)) -> float:
    """Largest change of the bilinear lookup of an equirectangular map over ``radius`` rad.

    Only directions whose polar angle lies in ``theta_range`` (widened by ``radius``)
    count. Per band of texel rows the change is bounded by the largest neighbouring-texel
    difference along the rows times the number of columns ``radius`` spans there
    (``radius / (sin(theta) 2 pi / W)`` at the band's smallest ``sin(theta)``), capped by
    the band's full range (at a pole, where the columns meet), plus the largest difference
    between rows times ``radius / (pi / (H - 1))``.
    """
    px = np.asarray(pixels, dtype=np.float64)
    h, w = px.shape[:2]
    dth = math.pi / (h - 1)
    dph = 2 * math.pi / w
    gc = np.max(np.abs(np.roll(px, -1, axis=1) - px), axis=(1, 2))  # (H,)
    gr = np.max(np.abs(px[1:] - px[:-1]), axis=(1, 2))  # (H-1,)
    lo, hi = max(theta_range[0] - radius, 0.0), min(theta_range[1] + radius, math.pi)
    best = 0.0
    for i in range(h - 1):
        # Directions in the cell between rows i and i+1, moved by up to one more row.
        c_lo, c_hi = max((i - 1) * dth, lo), min((i + 2) * dth, hi)
        if c_lo > c_hi:
            continue
        band = slice(max(i - 1, 0), min(i + 3, h))
        s_min = min(math.sin(c_lo), math.sin(c_hi))
        rng = float(np.max(px[band]) - np.min(px[band]))
        cols = radius / (s_min * dph) if s_min > 1e-12 else math.inf
        col_term = min(rng, float(np.max(gc[band])) * cols)
        row_term = float(np.max(gr[max(i - 1, 0): min(i + 2, h - 1)])) * radius / dth
        best = max(best, min(rng, col_term + row_term))
    return best


def reflection_theta_range(camera, center, radius: float, bounces: int = MAX_AUTO_BOUNCES) -> tuple[float, float]:
    """Range of polar angles (rad, from +y) of the mirror directions the image reads.

    Mirror directions of the front film, the rear film (inward normal) and the internal
    bounces (as :func:`bubblefit.model.geometry.intersect_sphere` and ``internal_bounce``, in
    numpy float64) for every pixel centre whose ray hits the bubble. A rotation of the map
    about +y leaves polar angles unchanged, so the range holds for any ``rotation``.
    Returns ``(0, pi)`` when no pixel hits the bubble.
    """
    h, w = camera.height, camera.width
    rows, cols = np.divmod(np.arange(h * w, dtype=np.float64), w)
    o, d = (np.asarray(v, dtype=np.float64) for v in camera.rays(rows, cols, center, radius))
    c = np.asarray(center, dtype=np.float64)
    dot = lambda u, v: np.sum(u * v, axis=-1, keepdims=True)
    unit = lambda v: v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)
    d = unit(np.broadcast_to(d, o.shape))
    oc = o - c
    bq = dot(oc, d)
    disc = bq * bq - (dot(oc, oc) - radius * radius)
    inside = disc[:, 0] > 0
    if not inside.any():
        return 0.0, math.pi
    o, d, bq, disc = o[inside], d[inside], bq[inside], disc[inside]
    root = np.sqrt(disc)
    p0 = o + (-bq - root) * d
    p1 = o + (-bq + root) * d
    n0, n1 = unit(p0 - c), unit(p1 - c)
    reflect = lambda v, n: 2.0 * dot(v, n) * n - v
    dirs = [reflect(-d, n0), reflect(-d, -n1)]
    q, e = p1, unit(d - 2.0 * dot(d, n1) * n1)  # reflected inside at the rear film
    for _ in range(bounces):
        dirs.append(e)
        q = q + (-2.0 * dot(q - c, e)) * e
        nq = unit(q - c)
        q = c + radius * nq
        e = unit(e - 2.0 * dot(e, nq) * nq)
    y = np.concatenate([unit(v)[:, 1] for v in dirs])
    theta = np.arccos(np.clip(y, -1.0, 1.0))
    return float(theta.min()), float(theta.max())


def _mipmap_albedo(roughness: float, cos: np.ndarray, nodes: int) -> np.ndarray:
    """Albedo (C,) of the unnormalised ``mipmap`` lobe (white map) at incidence cosines (C,).

    The sum of :func:`bubblefit.lighting.filtering.specular_mipmap`'s node weights
    ``W_j W_k g(s)`` (:func:`bubblefit.optics.brdf.half_vector_weight`), in numpy, for the
    normal +z (whose tangent frame is +x, +y).
    """
    from ..lighting.filtering import _slope_nodes

    x, wts, _ = _slope_nodes(nodes)
    sx, sy = (v.ravel() for v in np.meshgrid(x, x))
    ww = (wts[:, None] * wts[None, :]).ravel()
    hv = np.stack([roughness * sx, roughness * sy, np.ones_like(sx)], axis=-1)
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)  # (M, 3)
    s = np.sqrt(np.maximum(0.0, 1.0 - cos**2))
    wo = np.stack([s, np.zeros_like(s), cos], axis=-1)  # (C, 3)
    o_h = wo @ hv.T  # (C, M)
    wi = 2.0 * o_h[..., None] * hv[None] - wo[:, None, :]
    cos_i, cos_h, cos_r = wi[..., 2], hv[None, :, 2], cos[:, None]
    above = (cos_i > 0) & (cos_r > 0)
    root = np.sqrt(np.maximum(np.where(above, cos_i * cos_r, 1.0), 1e-8))
    g = np.where(above, cos_i * o_h * cos_h**3 / root, 0.0)
    return g @ ww


def _filter_bound(pixels, texel_angle, roughness, min_cos, nodes, normalize, theta_range=(0.0, math.pi)):
    """Bound of |mirror lookup - mipmap lookup| for a white film (multiply by the specular weight).

    Returns ``(bound, detail)``; ``bound`` is ``inf`` when the lobe reads coarser mip levels.
    """
    from ..lighting.filtering import _slope_nodes, mip_footprint_level

    x, _, width = _slope_nodes(nodes)
    cell = float(np.sqrt(np.max(width) * np.max(width)))
    level = float(mip_footprint_level(roughness * cell, texel_angle))
    radius = 2.0 * roughness * math.sqrt(2.0) * float(np.max(np.abs(x)))
    if level > 0:
        return math.inf, f"lobe reads mip level {level:.2f} > 0"
    var = _lookup_variation(pixels, radius, theta_range)
    peak = float(np.max(pixels))
    if normalize:
        alb_err, alb_max = 0.0, 1.0
    else:
        cos = np.linspace(max(min_cos, 1e-3), 1.0, 8)
        alb = _mipmap_albedo(roughness, cos, nodes)
        alb_err, alb_max = float(np.max(np.abs(alb - cos))), max(1.0, float(np.max(alb)))
    bound = alb_max * var + peak * alb_err
    return bound, (f"lobe radius {radius:.2e} rad moves the lookup by <= {var:.2e}, "
                   f"albedo vs mirror {alb_err:.1e} x peak {peak:.3g}")


def _bool_setting(value, name: str):
    if value in ("auto", None):
        return "auto"
    if isinstance(value, bool):
        return value
    raise InputError(f"effects.{name} must be true, false or \"auto\", got {value!r}")


def resolve(
    *,
    model: str,
    settings: dict,
    t: float,
    r_d: float,
    r_s: float,
    roughness: float,
    thickness_range: tuple[float, float],
    thickness_kind: str,
    n_film: float,
    env_texel_angle: float | None,
    env_peak: float,
    env_mean: float,
    background: str,
    background_peak: float,
    n_point_lights: int,
    light_peak: float,
    min_cos: float,
    tolerance: float = DEFAULT_TOLERANCE,
    env_pixels: np.ndarray | None = None,
    env_irradiance_peak: float | None = None,
    reflect_theta_range: tuple[float, float] = (0.0, math.pi),
) -> tuple[Effects, list[Decision]]:
    """Decide every effect of a scene.

    Args:
        model: ``paper`` or ``physical``.
        settings: the scene's ``[effects]`` table (strings/bools/tables as in DESIGN.md).
        t, r_d, r_s, roughness, n_film: the scene's (or a fit's starting) values.
        thickness_range: (min, max) film thickness over the bubble, nm.
        thickness_kind: ``constant`` | ``drainage`` | ``map``.
        env_texel_angle: angular size of one environment texel (None without a map).
        env_peak, env_mean: the map's largest and mean radiance (0 without a map).
        background: ``envmap`` | ``black`` | ``photo``; ``background_peak``: its largest value.
        n_point_lights, light_peak: number of point lights and their largest irradiance.
        min_cos: smallest incidence cosine on the film among the image's pixels (the rim).
        tolerance: largest change, in linear radiance, a skipped effect may make.
        env_pixels: the (H, W, 3) map (for the filtering bound; without it mirror is
            never chosen by ``auto``).
        env_irradiance_peak: largest value of the map's irradiance table (else ``4 pi``
            times ``env_mean``, a bound of any irradiance).
        reflect_theta_range: polar angles of the mirror directions the image reads
            (:func:`reflection_theta_range`); the filtering bound looks only there.

    Returns:
        The static :class:`Effects` and one :class:`Decision` per effect.
    """
    if model not in ("paper", "physical"):
        raise InputError(f"effects.model must be paper or physical, got {model!r}")
    out: list[Decision] = []
    tol = float(tolerance)
    has_env = env_texel_angle is not None
    a = max(float(roughness), 1e-12)
    peak_env = env_peak if has_env else 0.0
    irr_env = (env_irradiance_peak if env_irradiance_peak is not None else 4 * math.pi * env_mean) if has_env else 0.0
    # eq. (3): the lobe times cos th_i peaks at 1 / (4 pi a^2 sqrt(cos th_r)) for a light of irradiance 1.
    light_spec = light_peak / (4 * math.pi * a * a * math.sqrt(max(min_cos, 1e-3))) if n_point_lights else 0.0
    light_irr = light_peak * max(n_point_lights, 0)
    spec_peak = max(peak_env, 0.0) + light_spec * max(n_point_lights, 0)
    irr_peak = irr_env + light_irr
    bg_peak = background_peak if background != "black" else 0.0
    nodes = int(settings.get("nodes", ALL_ON_NODES))
    # Largest albedo of the lobe (eq. 1 as written, unnormalised, for paper; 1 when normalised).
    alb = 1.0
    if model == "paper" and has_env:
        alb = max(1.0, float(np.max(_mipmap_albedo(a, np.linspace(max(min_cos, 1e-3), 1.0, 8), nodes))))
    if model == "paper":
        # L' = r_s S + r_d E / pi (eq. 2), the radiance the paper's factors multiply.
        w_refl = max(r_s, 0.0) * spec_peak * alb + max(r_d, 0.0) * irr_peak / math.pi
    else:
        w_refl = spec_peak + max(r_d, 0.0) * irr_peak / math.pi
    out.append(Decision("fresnel", model == "physical",
                        "physical model: Fresnel film reflectance per polarisation" if model == "physical"
                        else "paper model: constant t, r_s (eqs. 1-14)", model))

    # --- interference and spectral sampling ----------------------------------------------------
    dmin, dmax = (float(thickness_range[0]), float(thickness_range[1]))
    d_grid, c_grid = _grids((dmin, dmax), min_cos, n_film)
    interference = settings.get("interference", "auto")
    if interference not in ("auto", "off", "two_beam", "airy", "incoherent"):
        raise InputError(f"effects.interference must be auto, off, two_beam, airy or incoherent, got {interference!r}")
    on_mode = "airy" if model == "physical" else "two_beam"
    tint_set = _bool_setting(settings.get("transmission_tint", "auto"), "transmission_tint")
    tint_rs = max(r_s, 0.0) if model == "paper" and tint_set is True else None
    bset = settings.get("bounces", "auto") if model == "physical" else 1
    n_b = MAX_AUTO_BOUNCES if bset == "auto" else int(bset)
    ref_basis = spectral_basis("reference")
    cache, spectra = {}, {}
    spectral_setting = settings.get("spectral", "auto")
    wanted = [ref_basis] + ([spectral_basis("uniform", k) for k in SPECTRAL_CANDIDATES]
                            if spectral_setting == "auto" else [])

    def coeffs(mode, basis=None):
        """Coefficients for ``mode`` with ``basis``; all wavelengths evaluated in one call."""
        key = (mode, None if basis is None else basis.samples)
        if key in cache:
            return cache[key]
        if mode in ("off", "incoherent"):
            cache[key] = _film_coefficients(model, mode, None, d_grid, c_grid, t, n_film, n_b, tint_rs)
            return cache[key]
        if mode not in spectra:
            lam_all = np.unique(np.concatenate([bb.wavelengths for bb in wanted + [basis]]))
            spectra[mode] = (lam_all, _film_spectra(model, mode, lam_all, d_grid, c_grid, t, n_film))
        lam_all, vals = spectra[mode]
        idx = np.searchsorted(lam_all, basis.wavelengths)
        if not np.allclose(lam_all[np.minimum(idx, len(lam_all) - 1)], basis.wavelengths):
            lam_all = np.unique(np.concatenate([lam_all, basis.wavelengths]))
            spectra[mode] = (lam_all, _film_spectra(model, mode, lam_all, d_grid, c_grid, t, n_film))
            lam_all, vals = spectra[mode]
            idx = np.searchsorted(lam_all, basis.wavelengths)
        cache[key] = _film_coefficients(model, mode, basis.weights, vals[:, :, idx], c_grid, t, n_film, n_b, tint_rs)
        return cache[key]

    weights = (w_refl, w_refl, bg_peak)
    if interference == "auto":
        bound = _coeff_diff(coeffs("incoherent"), coeffs(on_mode, ref_basis), *weights)
        if bound < tol:
            interference = "incoherent"
            out.append(Decision("interference", False,
                                f"film {dmin:.0f}-{dmax:.0f} nm: colours average out over the spectrum, "
                                f"incoherent grey vs {on_mode} changes the image by <= {bound:.2e} < tolerance {tol:g}",
                                "incoherent"))
        else:
            interference = on_mode
            out.append(Decision("interference", True,
                                f"film {dmin:.0f}-{dmax:.0f} nm keeps colours: incoherent grey would change the image "
                                f"by up to {bound:.2e} >= tolerance {tol:g}", on_mode))
    else:
        on = interference not in ("off", "incoherent")
        out.append(Decision("interference", on, "set by the scene", interference))
    if model == "physical" and interference == "off":
        interference = "incoherent"  # a physical film always reflects; without colours it is grey

    spectral_basis_ = None
    if interference in ("two_beam", "airy"):
        if spectral_setting == "auto":
            ref = coeffs(interference, ref_basis)
            chosen, err = None, math.inf
            for k in SPECTRAL_CANDIDATES:
                err = _coeff_diff(coeffs(interference, spectral_basis("uniform", k)), ref, *weights)
                if err < tol:
                    chosen = spectral_basis("uniform", k)
                    break
            if chosen is None:
                spectral_basis_ = ref_basis
                out.append(Decision("spectral", True,
                                    f"{SPECTRAL_CANDIDATES[-1]} uniform samples still differ by {err:.2e} >= {tol:g} "
                                    f"from the reference: reference integration",
                                    f"reference/{ref_basis.samples}"))
            else:
                spectral_basis_ = chosen
                out.append(Decision("spectral", True,
                                    f"{chosen.samples} uniform samples: differ from the {ref_basis.samples}-sample "
                                    f"reference by <= {err:.2e} < tolerance {tol:g}",
                                    f"uniform/{chosen.samples}"))
        else:
            if isinstance(spectral_setting, dict):
                method = spectral_setting.get("method", "uniform")
                samples = int(spectral_setting.get("samples", 30))
            else:
                method, samples = str(spectral_setting), 30
            try:
                spectral_basis_ = spectral_basis(method, samples)
            except ValueError as exc:
                raise InputError(f"effects.spectral: {exc}") from None
            out.append(Decision("spectral", True, "set by the scene", f"{method}/{spectral_basis_.samples}"))
    else:
        out.append(Decision("spectral", False, "no interference: the film is grey, no spectral loop"))

    cur = coeffs(interference, spectral_basis_)
    f_front = float(np.max(cur["front"]))
    f_rear = float(np.max(sum(cur["rear"]))) if cur["rear"] else 0.0
    f_bg = float(np.max(cur["background"]))

    # --- environment filtering -------------------------------------------------------------------
    filt = settings.get("filtering", "auto")
    knobs = {k: settings[k] for k in ("nodes", "window", "level") if k in settings}
    if not has_env:
        fconf = FilterConfig("mirror")
        out.append(Decision("roughness_filtering", False, "no environment map: nothing to filter"))
    elif filt == "auto":
        spec_w = (max(r_s, 0.0) if model == "paper" else 1.0) * (f_front + f_rear)
        if env_pixels is not None:
            fb, detail = _filter_bound(env_pixels, env_texel_angle, a, min_cos, nodes, model == "physical",
                                           reflect_theta_range)
        else:
            fb, detail = math.inf, "no map given to bound the mirror lookup"
        bound = spec_w * fb
        if bound < tol:
            fconf = FilterConfig("mirror")
            out.append(Decision("roughness_filtering", False,
                                f"a = {a:.2e}: mirror lookup differs from the filtered one by <= {bound:.2e} "
                                f"< tolerance {tol:g} ({detail}; specular weight {spec_w:.3g})", "mirror"))
        else:
            fconf = FilterConfig("mipmap", nodes=nodes)
            out.append(Decision("roughness_filtering", True,
                                f"a = {a:.2e}: mirror lookup could differ by {bound:.2e} >= {tol:g} ({detail})",
                                f"mipmap/{fconf.nodes}"))
    else:
        try:
            fconf = FilterConfig(str(filt), **knobs)
        except ValueError as exc:
            raise InputError(f"effects.filtering: {exc}") from None
        out.append(Decision("roughness_filtering", filt != "mirror", "set by the scene", fconf.method))

    # --- terms -------------------------------------------------------------------------------------
    def term(name, setting, bound, what):
        s = _bool_setting(setting, name)
        if s == "auto":
            needed = bound >= tol
            rel = ">=" if needed else "<"
            out.append(Decision(name, needed, f"{what} = {bound:.2e} {rel} tolerance {tol:g}"))
            return needed
        out.append(Decision(name, bool(s), "set by the scene"))
        return bool(s)

    front = term("front_reflection", settings.get("front_reflection", "auto"), f_front * w_refl,
                 f"film coefficient {f_front:.3g} x reflected radiance bound {w_refl:.3g}")
    rear = term("rear_reflection", settings.get("rear_reflection", "auto"), f_rear * w_refl,
                f"rear coefficient {f_rear:.3g} x reflected radiance bound {w_refl:.3g}")
    if background == "black" and _bool_setting(settings.get("transmission", "auto"), "transmission") == "auto":
        transmission = False
        out.append(Decision("transmission", False, "black background: nothing to transmit (bound 0)"))
    else:
        transmission = term("transmission", settings.get("transmission", "auto"), f_bg * bg_peak,
                            f"transmission {f_bg:.3g} x background peak {bg_peak:.3g}")
    tint_bound = 4.0 * max(r_s, 0.0) * t**4 * bg_peak
    if model == "physical":
        tint = False
        out.append(Decision("transmission_tint", transmission and interference in ("two_beam", "airy"),
                            "physical model: every film transmits T = 1 - R per wavelength"))
    elif not transmission or interference in ("off", "incoherent"):
        tint = False
        out.append(Decision("transmission_tint", False,
                            "no background transmission" if not transmission else
                            f"interference {interference}: the film is grey, so is its transmission"))
    elif tint_set == "auto":
        tint = False
        out.append(Decision("transmission_tint", False,
                            f"eq. (11) as written (grey t^4); the film's complementary colour could change "
                            f"the image by {tint_bound:.2e} (4 r_s t^4 x background peak)"))
    else:
        tint = bool(tint_set)
        out.append(Decision("transmission_tint", tint, f"set by the scene (bound 4 r_s t^4 x background peak "
                                                        f"= {tint_bound:.2e})"))
    if model == "paper":
        diff_w = (f_front if front else 0.0) + (f_rear if rear else 0.0)
    else:
        diff_w = (1.0 if front else 0.0) + (1.0 if rear else 0.0)
    diff_bound = max(r_d, 0.0) * irr_peak / math.pi * diff_w
    if r_d <= 0 and _bool_setting(settings.get("diffuse", "auto"), "diffuse") == "auto":
        diffuse = False
        out.append(Decision("diffuse", False, "r_d = 0: no irradiance needed (bound 0)"))
    else:
        diffuse = term("diffuse", settings.get("diffuse", "auto"), diff_bound,
                       f"r_d E_max / pi x film coefficient ({max(r_d, 0):.3g} x {irr_peak:.3g} / pi x {diff_w:.3g})")
    out.append(Decision("environment", has_env and (front or rear or transmission),
                        f"environment map given (peak {peak_env:.3g})" if has_env else "no environment map (dark room)"))
    out.append(Decision("point_lights", n_point_lights > 0 and (front or rear),
                        f"{n_point_lights} light(s): eq. (3)" if n_point_lights else "no point lights"))
    out.append(Decision("thickness_field", thickness_kind != "constant",
                        "one thickness for the whole film" if thickness_kind == "constant" else f"{thickness_kind} profile",
                        thickness_kind))

    # --- internal bounces (physical) ------------------------------------------------------------
    bounces = 1
    if model == "physical":
        if bset == "auto":
            # Bounces beyond b change the image by sum_{k>b} max T R^k T x the reflected radiance bound.
            tail = [float(np.max(sum(cur["rear"][k:]))) * w_refl if k < len(cur["rear"]) else 0.0
                    for k in range(len(cur["rear"]) + 1)]
            bounces = next((b for b in range(1, MAX_AUTO_BOUNCES + 1) if tail[b] < tol), MAX_AUTO_BOUNCES)
            out.append(Decision("internal_bounces", rear and bounces > 1,
                                (f"{bounces} bounce(s): the all-on model's bounces {bounces + 1}-{MAX_AUTO_BOUNCES} add "
                                 f"<= {tail[bounces]:.2e} < tolerance {tol:g}" if bounces < MAX_AUTO_BOUNCES else
                                 f"{bounces} bounce(s), the cap: bounce {bounces} still adds up to "
                                 f"{tail[bounces - 1]:.2e} >= tolerance {tol:g}"), str(bounces)))
        else:
            bounces = int(bset)
            out.append(Decision("internal_bounces", rear and bounces > 1, "set by the scene", str(bounces)))
    else:
        out.append(Decision("internal_bounces", False, "paper model: eq. (11) keeps one rear reflection"))

    fx = Effects(
        model=model,
        front_reflection=front,
        rear_reflection=rear,
        transmission=transmission,
        interference=interference,
        diffuse=diffuse and (front or rear),
        environment=has_env and (front or rear or background == "envmap"),
        point_lights=n_point_lights > 0 and (front or rear),
        filtering=fconf,
        spectral=spectral_basis_,
        bounces=bounces,
        thickness=thickness_kind,
        background=background,
        tint=tint,
    )
    return fx, out
