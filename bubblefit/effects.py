"""Which effects a scene simulates, decided once per scene from cheap bounds.

Each effect is its own term of the forward model (:mod:`bubblefit.render`). The scene's
``[effects]`` table sets each to on, off or ``auto``; :func:`resolve` turns ``auto`` into
on or off using bounds on the term's largest contribution to the image in linear
radiance, compared with one tolerance (``DEFAULT_TOLERANCE`` unless the scene sets
``tolerance``). The decision is static: a term that is off is never traced nor computed.

Every decision comes with a reason (``bubblefit render --explain`` prints them).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from .film import incoherent_reflectance
from .filtering import FilterConfig
from .spectral import LAMBDA_MAX, LAMBDA_MIN, SpectralBasis, spectral_basis

__all__ = ["Effects", "Decision", "resolve", "DEFAULT_TOLERANCE", "interference_contrast"]

#: Default tolerance, in linear radiance of the rendered image (1/1000 of a white of 1).
DEFAULT_TOLERANCE = 1e-3
#: Most internal bounces "auto" asks for (each costs one more filtered lookup per pixel).
MAX_AUTO_BOUNCES = 8


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


def _nyquist_samples(opd_nm: float) -> int:
    """Uniform samples over 380-780 nm that resolve ``cos(2 pi x / lambda)`` (phase step < pi/2)."""
    if opd_nm <= 0:
        return 1
    dphase_per_nm = 2 * math.pi * opd_nm / LAMBDA_MIN**2
    return int(math.ceil(dphase_per_nm * (LAMBDA_MAX - LAMBDA_MIN) / (math.pi / 2)))


def _bool_setting(value, name: str):
    if value in ("auto", None):
        return "auto"
    if isinstance(value, bool):
        return value
    raise ValueError(f"effects.{name} must be true, false or \"auto\", got {value!r}")


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
        tolerance: largest contribution, in linear radiance, an effect may have and still be skipped.

    Returns:
        The static :class:`Effects` and one :class:`Decision` per effect.
    """
    out: list[Decision] = []
    tol = tolerance
    has_env = env_texel_angle is not None
    radiance_peak = max(env_peak if has_env else 0.0, light_peak)

    # --- Fresnel (the model) --------------------------------------------------------
    out.append(Decision("fresnel", model == "physical",
                        "physical model: Fresnel film reflectance per polarisation" if model == "physical"
                        else "paper model: constant t, r_s (eqs. 1-14)", model))

    # --- thickness field and interference ----------------------------------------------
    dmin, dmax = thickness_range
    interference = settings.get("interference", "auto")
    spectral_setting = settings.get("spectral", "auto")
    cos_t_min = math.sqrt(max(0.0, 1.0 - (1.0 - min_cos**2) / n_film**2))
    opd_min = 2.0 * n_film * dmin * cos_t_min
    opd_max = 2.0 * n_film * dmax
    if interference not in ("auto", "off", "two_beam", "airy", "incoherent"):
        raise ValueError(f"effects.interference must be auto, off, two_beam, airy or incoherent, got {interference!r}")
    if interference == "auto":
        # Largest colour the interference can add over its incoherent mean, in radiance.
        amplitude = (4 * t * t * max(r_s, 1e-12) if model == "paper" else 0.2) * radiance_peak
        contrast = interference_contrast(opd_min)
        bound = amplitude * contrast
        if bound < tol:
            interference = "off" if model == "paper" else "incoherent"
            out.append(Decision("interference", False,
                                f"film >= {dmin:.0f} nm: colours average out (contrast {contrast:.2e} x radiance "
                                f"{amplitude:.3g} = {bound:.2e} < tolerance {tol:g}); incoherent reflectance, no spectral loop",
                                interference))
        else:
            interference = "two_beam" if model == "paper" else "airy"
            out.append(Decision("interference", True,
                                f"thickness {dmin:.0f}-{dmax:.0f} nm keeps colours (bound {bound:.2e} >= {tol:g})",
                                interference))
    else:
        on = interference not in ("off", "incoherent")
        out.append(Decision("interference", on, "set by the scene", interference))
    if model == "paper" and interference == "incoherent":
        interference = "off"
    spectral_basis_ = None
    if interference in ("two_beam", "airy"):
        if spectral_setting == "auto":
            k = min(max(_nyquist_samples(opd_max), 10), 100)
            spectral_basis_ = spectral_basis("uniform", k)
            out.append(Decision("spectral", True,
                                f"{k} uniform samples resolve the phase up to {dmax:.0f} nm (Nyquist bound, 10..100)",
                                f"uniform/{k}"))
        else:
            if isinstance(spectral_setting, dict):
                method = spectral_setting.get("method", "uniform")
                samples = int(spectral_setting.get("samples", 30))
            else:
                method, samples = str(spectral_setting), 30
            spectral_basis_ = spectral_basis(method, samples)
            out.append(Decision("spectral", True, "set by the scene", f"{method}/{spectral_basis_.samples}"))
    else:
        out.append(Decision("spectral", False, "no interference: the film is grey, one sample suffices"))

    # --- environment filtering -----------------------------------------------------------
    filt = settings.get("filtering", "auto")
    knobs = {k: settings[k] for k in ("nodes", "window", "level") if k in settings}
    if not has_env:
        fconf = FilterConfig("mirror")
        out.append(Decision("roughness_filtering", False, "no environment map"))
    elif filt == "auto":
        if roughness * 2.0 < env_texel_angle / 2:
            fconf = FilterConfig("mirror")
            out.append(Decision("roughness_filtering", False,
                                f"lobe width 2a = {2 * roughness:.2e} rad < half a texel ({env_texel_angle / 2:.2e} rad): mirror lookup",
                                "mirror"))
        else:
            fconf = FilterConfig("mipmap", **{k: v for k, v in knobs.items() if k == "nodes"})
            out.append(Decision("roughness_filtering", True,
                                f"lobe width 2a = {2 * roughness:.2e} rad >= half a texel ({env_texel_angle / 2:.2e} rad)",
                                f"mipmap/{fconf.nodes}"))
    else:
        fconf = FilterConfig(str(filt), **knobs)
        out.append(Decision("roughness_filtering", filt != "mirror", "set by the scene", fconf.method))

    # --- terms ------------------------------------------------------------------------------
    def term(name, setting, needed, why_on, why_off):
        s = _bool_setting(setting, name)
        if s == "auto":
            out.append(Decision(name, needed, why_on if needed else why_off))
            return needed
        out.append(Decision(name, bool(s), "set by the scene"))
        return bool(s)

    thin = dmax <= 0.0
    reflect_scale = (max(r_s, 0) + max(r_d, 0)) * radiance_peak if model == "paper" else 0.2 * radiance_peak
    if thin and interference != "off":
        reflect_bound = 0.0
        why_off = "film thickness 0: the half-wave shift cancels the reflection (a black film)"
    else:
        reflect_bound = reflect_scale * (4 * t * t if (model == "paper" and interference != "off") else 1.0)
        why_off = f"reflection bound {reflect_bound:.2e} < tolerance {tol:g}"
    front = term("front_reflection", settings.get("front_reflection", "auto"), reflect_bound >= tol,
                 f"reflection bound {reflect_bound:.2e} >= {tol:g}", why_off)
    rear_bound = reflect_bound * (t * t if model == "paper" else 1.0)
    rear = term("rear_reflection", settings.get("rear_reflection", "auto"), rear_bound >= tol,
                f"rear reflection bound {rear_bound:.2e} >= {tol:g}",
                why_off if thin else f"rear reflection bound {rear_bound:.2e} < tolerance {tol:g}")
    bg_peak = background_peak if background != "black" else 0.0
    trans_bound = bg_peak * (t**4 if model == "paper" else 1.0)
    transmission = term("transmission", settings.get("transmission", "auto"), trans_bound >= tol,
                        f"background peak {bg_peak:.3g} x t^4 >= {tol:g}",
                        "black background: nothing to transmit" if background == "black"
                        else f"background bound {trans_bound:.2e} < tolerance {tol:g}")
    diffuse_bound = max(r_d, 0.0) / math.pi * math.pi * max(env_mean if has_env else 0.0, light_peak)
    diffuse = term("diffuse", settings.get("diffuse", "auto"), diffuse_bound >= tol and (front or rear),
                   f"r_d E/pi bound {diffuse_bound:.2e} >= {tol:g}",
                   "r_d = 0: no irradiance needed" if r_d <= 0 else f"r_d E/pi bound {diffuse_bound:.2e} < tolerance {tol:g}")
    out.append(Decision("environment", has_env and (front or rear or background == "envmap"),
                        "environment map given" if has_env else "no environment map (dark room)"))
    out.append(Decision("point_lights", n_point_lights > 0,
                        f"{n_point_lights} light(s): eq. (3)" if n_point_lights else "no point lights"))
    out.append(Decision("thickness_field", thickness_kind != "constant",
                        "one thickness for the whole film" if thickness_kind == "constant" else f"{thickness_kind} profile",
                        thickness_kind))

    # --- internal bounces (physical) --------------------------------------------------------
    bounces = 1
    if model == "physical":
        setting = settings.get("bounces", "auto")
        if setting == "auto":
            # Largest film reflectance in the image (at the rim) bounds every bounce's weight.
            r_rim = float(np.max(np.asarray(incoherent_reflectance(max(min_cos, 1e-3), n_film))))
            bounces = 1
            while bounces < MAX_AUTO_BOUNCES and (r_rim ** (bounces + 1)) * radiance_peak >= tol:
                bounces += 1
            out.append(Decision("internal_bounces", rear and bounces > 1,
                                f"{bounces} bounce(s): R_rim^(k+1) x peak radiance < {tol:g} beyond (R_rim = {r_rim:.3f})",
                                str(bounces)))
        else:
            bounces = int(setting)
            out.append(Decision("internal_bounces", rear and bounces > 1, "set by the scene", str(bounces)))
    else:
        out.append(Decision("internal_bounces", False, "paper model: eq. (11) keeps one rear reflection"))

    fx = Effects(
        model=model,
        front_reflection=front,
        rear_reflection=rear,
        transmission=transmission,
        interference=interference,
        diffuse=diffuse,
        environment=has_env,
        point_lights=n_point_lights > 0,
        filtering=fconf,
        spectral=spectral_basis_,
        bounces=bounces,
        thickness=thickness_kind,
        background=background,
    )
    return fx, out
