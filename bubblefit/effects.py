"""Which effects a scene simulates, decided once per scene from cheap bounds.

Each effect is its own term of the forward model (:mod:`bubblefit.render`). The scene's
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
  functions (:mod:`bubblefit.film`, :mod:`bubblefit.spectral`) on a grid of thickness
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
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .filtering import FilterConfig
from .spectral import LAMBDA_MAX, LAMBDA_MIN, SpectralBasis, spectral_basis

__all__ = ["Effects", "Decision", "resolve", "all_on_settings", "DEFAULT_TOLERANCE", "interference_contrast"]

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

@functools.lru_cache(maxsize=4)
def _contrast_table(illuminant: str = "D65"):
    """Interference contrast after spectral integration against optical path difference.

    For the two-beam film, reflectance is ``A (1 + cos(2 pi x / lambda))`` with ``x`` the
    optical path difference ``2 n d cos t``; after integration the colour deviates from the
    incoherent grey by ``max_c |sum_k w_kc cos(2 pi x / lambda_k)|`` (relative). The table
    gives that deviation's running maximum from ``x`` to infinity (so it bounds every
    thicker film too), on a grid of ``x`` in nm.
    """
    basis = spectral_basis("reference", illuminant=illuminant)
    x = np.linspace(0.0, 60000.0, 6001)
    cos = np.cos(2 * np.pi * x[:, None] / basis.wavelengths[None, :])
    dev = np.max(np.abs(cos @ basis.weights), axis=1)
    tail = np.maximum.accumulate(dev[::-1])[::-1]
    return x, tail


def interference_contrast(opd_nm: float, illuminant: str = "D65") -> float:
    """Upper bound of the relative colour contrast of interference for paths >= ``opd_nm``."""
    x, tail = _contrast_table(illuminant)
    if opd_nm >= x[-1]:
        return float(tail[-1])
    return float(np.interp(opd_nm, x, tail))


def _grids(thickness_range, min_cos, n_film, max_points: int = 1200):
    """Thickness (D,) and incidence-cosine (C,) grids covering the scene.

    Thickness steps keep the optical path step below lambda_min / 24 (the two-beam
    colour is then sampled at 24 points per shortest period), up to ``max_points``.
    """
    dmin, dmax = thickness_range
    step = LAMBDA_MIN / (24.0 * 2.0 * n_film)
    npts = int(min(max_points, max(2, math.ceil((dmax - dmin) / step) + 1)))
    d = np.linspace(dmin, dmax, npts) if dmax > dmin else np.array([dmin])
    c_lo = max(min(min_cos, 1.0), 1e-3)
    cos = np.unique(np.concatenate([np.linspace(c_lo, 1.0, 6), [1.0]]))
    return d, cos


def _film_coefficients(model, mode, basis, d, cos, t, n_film, bounces):
    """RGB coefficients of the model's terms on a (thickness, cosine) grid.

    Args:
        model: ``paper`` | ``physical``; mode: ``off`` | ``incoherent`` | ``two_beam`` | ``airy``.
        basis: the :class:`SpectralBasis` (ignored for the grey modes).
        d: (D,) thicknesses in nm; cos: (C,) incidence cosines.
        bounces: internal bounces to return (physical).

    Returns:
        dict with ``front`` (D, C, 3), ``background`` (D, C, 3) and ``rear`` a list of
        (D, C, 3), one per bounce (paper: one, eq. 11's ``t^2 F``).
    """
    import jax.numpy as jnp

    from . import film

    grey = mode in ("off", "incoherent")
    dd = jnp.asarray(d)[:, None, None]
    cc = jnp.asarray(cos)[None, :, None]
    if not grey:
        lam = jnp.asarray(basis.wavelengths)[None, None, :]
        w = jnp.asarray(basis.weights)
        rgb = lambda s: np.asarray(s @ w.astype(s.dtype))
    else:
        rgb = lambda s: np.asarray(jnp.broadcast_to(s, s.shape[:-1] + (1,)) * jnp.ones(3, s.dtype))
    shape = (len(d), len(cos), 1)
    if model == "paper":
        if mode == "off":
            f = jnp.ones(shape)
        elif mode == "incoherent":
            f = jnp.full(shape, 2.0 * t * t)
        else:
            f = film.paper_interference_factor(dd, lam, n_film, cc, t)
        f = rgb(f)
        return {"front": f, "rear": [t * t * f], "background": np.full(f.shape, t**4)}
    if grey:
        r = jnp.broadcast_to(film.incoherent_reflectance(cc, n_film), shape + (2,))
    elif mode == "two_beam":
        r = film.two_beam_reflectance(dd, lam, n_film, cc)
    else:
        r = film.airy_reflectance(dd, lam, n_film, cc)
    tr = 1.0 - r
    mean = lambda x: jnp.mean(x, axis=-1)
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

def _lookup_variation(pixels: np.ndarray, radius: float) -> float:
    """Largest change of the bilinear lookup of an equirectangular map over ``radius`` rad.

    Per texel row band the change is bounded by the largest neighbouring-texel difference
    along the row times the number of columns ``radius`` spans there
    (``radius / (sin(theta) 2 pi / W)``), capped by the band's full range (near the
    poles), plus the largest difference between rows times ``radius / (pi / (H - 1))``.
    """
    px = np.asarray(pixels, dtype=np.float64)
    h, w = px.shape[:2]
    dth = math.pi / (h - 1)
    dph = 2 * math.pi / w
    gc = np.max(np.abs(np.roll(px, -1, axis=1) - px), axis=(1, 2))  # (H,)
    gr = np.max(np.abs(px[1:] - px[:-1]), axis=(1, 2))  # (H-1,)
    theta = np.arange(h) * dth
    best = 0.0
    for i in range(h - 1):
        band = slice(max(i - 1, 0), min(i + 3, h))
        s_min = max(0.0, min(math.sin(theta[max(i - 1, 0)]), math.sin(theta[min(i + 2, h - 1)]),
                             math.sin(theta[i]), math.sin(theta[i + 1])))
        rng = float(np.max(px[band]) - np.min(px[band]))
        cols = radius / (s_min * dph) if s_min > 0 else math.inf
        col_term = min(rng, float(np.max(gc[band])) * cols)
        row_term = float(np.max(gr[max(i - 1, 0): min(i + 2, h - 1)])) * radius / dth
        best = max(best, min(rng, col_term + row_term))
    return best


def _mipmap_albedo(roughness: float, cos: np.ndarray, nodes: int) -> np.ndarray:
    """The unnormalised mipmap lobe's albedo at incidence cosines (C,) (white map)."""
    import jax.numpy as jnp

    from .envmap import EnvMap
    from .filtering import specular_mipmap

    white = EnvMap.constant(1.0, height=16)
    s = np.sqrt(np.maximum(0.0, 1.0 - cos**2))
    n = jnp.asarray(np.tile([[0.0, 0.0, 1.0]], (len(cos), 1)), dtype=jnp.float32)
    wo = jnp.asarray(np.stack([s, np.zeros_like(s), cos], axis=-1), dtype=jnp.float32)
    out = specular_mipmap(white, n, wo, jnp.float32(roughness), nodes=nodes, normalize=False)
    return np.asarray(out)[:, 0]


def _filter_bound(pixels, texel_angle, roughness, min_cos, nodes, normalize):
    """Bound of |mirror lookup - mipmap lookup| for a white film (multiply by the specular weight).

    Returns ``(bound, detail)``; ``bound`` is ``inf`` when the lobe reads coarser mip levels.
    """
    from .filtering import _slope_nodes, mip_footprint_level

    x, _, width = _slope_nodes(nodes)
    cell = float(np.sqrt(np.max(width) * np.max(width)))
    level = float(mip_footprint_level(roughness * cell, texel_angle))
    radius = 2.0 * roughness * math.sqrt(2.0) * float(np.max(np.abs(x)))
    if level > 0:
        return math.inf, f"lobe reads mip level {level:.2f} > 0"
    var = _lookup_variation(pixels, radius)
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

    Returns:
        The static :class:`Effects` and one :class:`Decision` per effect.
    """
    if model not in ("paper", "physical"):
        raise InputError(f"effects.model must be paper or physical, got {model!r}")
    out: list[Decision] = []
    tol = float(tolerance)
    has_env = env_texel_angle is not None
    a = max(float(roughness), 1e-6)
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
    bset = settings.get("bounces", "auto") if model == "physical" else 1
    n_b = MAX_AUTO_BOUNCES if bset == "auto" else int(bset)
    ref_basis = spectral_basis("reference")
    cache = {}

    def coeffs(mode, basis=None):
        key = (mode, None if basis is None else basis.samples)
        if key not in cache:
            cache[key] = _film_coefficients(model, mode, basis, d_grid, c_grid, t, n_film, n_b)
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

    spectral_setting = settings.get("spectral", "auto")
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
            fb, detail = _filter_bound(env_pixels, env_texel_angle, a, min_cos, nodes, model == "physical")
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
                                f"{bounces} bounce(s): the bounces after them add <= {tail[bounces]:.2e} "
                                f"(< {tol:g} or capped at {MAX_AUTO_BOUNCES})", str(bounces)))
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
    )
    return fx, out
