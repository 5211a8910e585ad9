"""Which effects a render simulates: the static :class:`Effects`, and decisions from scalar bounds.

Each effect is its own term of the forward model (:mod:`bubblefit.model.render`). The scene's
``[effects]`` table sets each to on (``true`` or a named method), off (``false``) or
``auto``. Scenes decide ``auto`` pixel by pixel, against a tolerance relative to what each
pixel shows (:mod:`bubblefit.model.auto`). This module holds what both paths share and the
scalar path that a fit uses (:func:`resolve`): :func:`decide` turns ``auto`` into on or off
by bounding how much the image can change anywhere, in linear radiance, between the
cheaper choice and the converged everything-on model (:func:`all_on_settings`), and
compares that bound with an absolute tolerance (:data:`ABSOLUTE_TOLERANCE` unless given).
The decision is static: a term that is off is never traced nor computed.

The bounds live in one record per scene (:class:`~bubblefit.model.bounds.SceneBounds`);
each decision is one function here that reads it and returns a :class:`Decision`
(printed by ``--explain``, naming the bound and its value):
:func:`decide_interference`, :func:`decide_spectral`, :func:`decide_filtering`,
:func:`decide_terms` (front and rear reflection, transmission), :func:`decide_tint`,
:func:`decide_diffuse`, :func:`decide_bounces`, and the point lights and thickness field
in :func:`decide`.

Transmission tint (``paper`` only): eq. (11) transmits a grey ``t^4``; a film that does
not absorb transmits the complement of what it reflects, so with the tint each film
transmits ``t^2 - r_s (F - 2 t^2)`` per wavelength (``F`` eq. 10's factor, ``2 t^2`` its
spectral mean; see :mod:`bubblefit.model.render`). It changes the image by at most
``4 r_s t^4`` times the background peak. ``auto`` keeps eq. (11) as written (the
``paper`` model is the paper's) and states that bound; ``true`` adds the tint. Fits of
photographs turn it on (:mod:`bubblefit.inverse.fit`).

References:
    ``docs/design.md``, "Effects and auto".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..lighting.filtering import FilterConfig
from ..optics.spectral import SpectralBasis, spectral_basis
from .bounds import MAX_BOUNCES, FilmTable, SceneBounds, SceneSummary, scene_bounds
from .modes import COLOURED, GREY, INTERFERENCE_MODES, MODELS, Background, Interference, Model, Switch, ThicknessKind

__all__ = ["Effects", "Decision", "resolve", "decide", "all_on_settings", "ABSOLUTE_TOLERANCE", "MAX_AUTO_BOUNCES",
           "decide_interference", "decide_spectral", "check_harmonic", "decide_filtering", "decide_terms",
           "decide_tint", "decide_diffuse", "decide_bounces", "as_switch"]

#: Default tolerance of the scalar path (:func:`resolve`), in linear radiance (1/1000 of a white of 1).
ABSOLUTE_TOLERANCE = 1e-3
#: Most internal bounces (``physical``): the all-on model's count and the cap of ``auto``.
MAX_AUTO_BOUNCES = MAX_BOUNCES
#: Uniform spectral sample counts ``auto`` tries, cheapest first (then ``reference``).
SPECTRAL_CANDIDATES = (10, 16, 20, 24, 32, 40, 48, 64, 80, 100, 128, 160, 200, 256, 320, 400)
#: Gauss-Hermite nodes per axis of the all-on (and ``auto``) mipmap filter.
ALL_ON_NODES = 4


@dataclass(frozen=True)
class Effects:
    """The resolved, static set of effects a render computes."""

    model: Model = "paper"
    front_reflection: bool = True
    rear_reflection: bool = True
    transmission: bool = True
    interference: Interference = "two_beam"
    diffuse: bool = True
    environment: bool = True
    point_lights: bool = False
    filtering: FilterConfig = FilterConfig()
    spectral: SpectralBasis | None = None
    bounces: int = 1
    thickness: ThicknessKind = "constant"
    background: Background = "envmap"
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
    #: Largest share of its budget the choice uses over the pixels (<= 1), where measured per pixel.
    budget_used: float | None = None

    def line(self) -> str:
        state = "simulated" if self.simulated else "skipped"
        setting = f" [{self.setting}]" if self.setting else ""
        return f"{self.effect:<20} {state:<9}{setting} {self.reason}"


def all_on_settings(model: Model = "paper", settings: dict | None = None) -> dict:
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


def as_switch(value, name: str) -> Switch:
    if value in ("auto", None):
        return "auto"
    if isinstance(value, bool):
        return value
    raise InputError(f"effects.{name} must be true, false or \"auto\", got {value!r}")


# ----------------------------------------------------------------------------------------
# One function per decision
# ----------------------------------------------------------------------------------------

def decide_interference(b: SceneBounds, table: FilmTable, setting, tol: float) -> tuple[Interference, Decision]:
    """Interference on (``two_beam`` paper, ``airy`` physical) or the incoherent grey film.

    ``auto`` bounds the change from the coloured film (800-sample reference) to the grey
    one (eq. 10's mean ``2 t^2``, or ``2 R / (1 + R)``) with
    :meth:`~bubblefit.model.bounds.FilmTable.difference`.
    """
    if setting not in ("auto",) + INTERFERENCE_MODES:
        raise InputError(f"effects.interference must be auto, off, two_beam, airy or incoherent, got {setting!r}")
    dmin, dmax = b.thickness_range
    on_mode = "airy" if b.model == "physical" else "two_beam"
    if setting != "auto":
        return setting, Decision("interference", setting not in GREY, "set by the scene", setting)
    bound = table.difference(table("incoherent"), table(on_mode, spectral_basis("reference")))
    if bound < tol:
        return "incoherent", Decision(
            "interference", False, f"film {dmin:.0f}-{dmax:.0f} nm: colours average out over the spectrum, "
            f"incoherent grey vs {on_mode} changes the image by <= {bound:.2e} < tolerance {tol:g}", "incoherent")
    return on_mode, Decision("interference", True, f"film {dmin:.0f}-{dmax:.0f} nm keeps colours: incoherent grey "
                             f"would change the image by up to {bound:.2e} >= tolerance {tol:g}", on_mode)


def decide_spectral(b: SceneBounds, table: FilmTable, setting, interference: Interference,
                    tol: float) -> tuple[SpectralBasis | None, Decision]:
    """The spectral quadrature: ``auto`` takes the fewest uniform samples within the
    tolerance of the 800-sample reference (:data:`SPECTRAL_CANDIDATES`), else the reference."""
    if interference not in COLOURED:
        return None, Decision("spectral", False, "no interference: the film is grey, no spectral loop")
    ref_basis = spectral_basis("reference")
    if setting == "auto":
        ref = table(interference, ref_basis)
        err = math.inf
        for k in SPECTRAL_CANDIDATES:
            basis = spectral_basis("uniform", k)
            err = table.difference(table(interference, basis), ref)
            if err < tol:
                return basis, Decision("spectral", True, f"{k} uniform samples: differ from the "
                                       f"{ref_basis.samples}-sample reference by <= {err:.2e} < tolerance {tol:g}",
                                       f"uniform/{k}")
        return ref_basis, Decision("spectral", True, f"{SPECTRAL_CANDIDATES[-1]} uniform samples still differ by "
                                   f"{err:.2e} >= {tol:g} from the reference: reference integration",
                                   f"reference/{ref_basis.samples}")
    if isinstance(setting, dict):
        method, samples = setting.get("method", "uniform"), int(setting.get("samples", 30))
    else:
        method, samples = str(setting), 30
    try:
        basis = spectral_basis(method, samples)
    except ValueError as exc:
        raise InputError(f"effects.spectral: {exc}") from None
    return basis, Decision("spectral", True, "set by the scene", f"{method}/{basis.samples}")


def check_harmonic(basis: SpectralBasis | None, thickness_kind: ThicknessKind, dispersive: bool,
                   where: str = "render") -> None:
    """Refuse the ``harmonic`` spectral basis where it is not exact: a thickness field (each
    film has its own optical path), a dispersive index, or a fit (``where``), whose tables
    sample wavelengths."""
    if basis is None or basis.phases is None:
        return
    if where != "render":
        raise InputError("effects.spectral: the harmonic basis renders scenes; a fit takes uniform, fourier or "
                         "reference")
    if thickness_kind != "constant":
        raise InputError("effects.spectral: the harmonic basis needs one film thickness; a thickness field "
                         f"({thickness_kind}) takes uniform, fourier or reference")
    if dispersive:
        raise InputError("effects.spectral: the harmonic basis needs a non-dispersive film index (n_film a number)")


def decide_filtering(b: SceneBounds, setting, knobs: dict, nodes: int, spec_weight: float,
                     tol: float) -> tuple[FilterConfig, Decision]:
    """Mirror lookup or Ward-filtered lookup (eqs. 12-13): ``auto`` takes the mirror when
    :meth:`~bubblefit.model.bounds.SceneBounds.filter_bound` times the specular weight stays
    below the tolerance."""
    if not b.has_env:
        return FilterConfig("mirror"), Decision("roughness_filtering", False, "no environment map: nothing to filter")
    if setting != "auto":
        try:
            conf = FilterConfig(str(setting), **knobs)
        except ValueError as exc:
            raise InputError(f"effects.filtering: {exc}") from None
        return conf, Decision("roughness_filtering", setting != "mirror", "set by the scene", conf.method)
    a = max(b.roughness, 1e-12)
    fb, detail = b.filter_bound(nodes)
    bound = spec_weight * fb
    if bound < tol:
        return FilterConfig("mirror"), Decision(
            "roughness_filtering", False, f"a = {a:.2e}: mirror lookup differs from the filtered one by <= "
            f"{bound:.2e} < tolerance {tol:g} ({detail}; specular weight {spec_weight:.3g})", "mirror")
    conf = FilterConfig("mipmap", nodes=nodes)
    return conf, Decision("roughness_filtering", True,
                          f"a = {a:.2e}: mirror lookup could differ by {bound:.2e} >= {tol:g} ({detail})",
                          f"mipmap/{conf.nodes}")


def _term(name: str, setting, bound: float, what: str, tol: float) -> tuple[bool, Decision]:
    """A term on or off: ``auto`` keeps it when its bound reaches the tolerance."""
    s = as_switch(setting, name)
    if s == "auto":
        needed = bound >= tol
        rel = ">=" if needed else "<"
        return needed, Decision(name, needed, f"{what} = {bound:.2e} {rel} tolerance {tol:g}")
    return bool(s), Decision(name, bool(s), "set by the scene")


def decide_terms(b: SceneBounds, settings: dict, coeffs: dict, tol: float) -> tuple[dict, list[Decision]]:
    """Front reflection, rear reflection and background transmission (eq. 11's three terms):
    each term's largest film coefficient times the radiance it carries."""
    f_front = float(np.max(coeffs["front"]))
    f_rear = float(np.max(sum(coeffs["rear"]))) if coeffs["rear"] else 0.0
    f_bg = float(np.max(coeffs["background"]))
    out = []
    front, d = _term("front_reflection", settings.get("front_reflection", "auto"), f_front * b.w_refl,
                     f"film coefficient {f_front:.3g} x reflected radiance bound {b.w_refl:.3g}", tol)
    out.append(d)
    rear, d = _term("rear_reflection", settings.get("rear_reflection", "auto"), f_rear * b.w_refl,
                    f"rear coefficient {f_rear:.3g} x reflected radiance bound {b.w_refl:.3g}", tol)
    out.append(d)
    if b.background == "black" and as_switch(settings.get("transmission", "auto"), "transmission") == "auto":
        transmission = False
        out.append(Decision("transmission", False, "black background: nothing to transmit (bound 0)"))
    else:
        transmission, d = _term("transmission", settings.get("transmission", "auto"), f_bg * b.bg_peak,
                                f"transmission {f_bg:.3g} x background peak {b.bg_peak:.3g}", tol)
        out.append(d)
    return {"front": front, "rear": rear, "transmission": transmission,
            "f_front": f_front, "f_rear": f_rear}, out


def decide_tint(b: SceneBounds, tint_set: Switch, transmission: bool, interference: Interference) -> tuple[bool, Decision]:
    """The paper model's transmission tint (module docstring): off under ``auto``, with its bound."""
    tint_bound = 4.0 * max(b.r_s, 0.0) * b.t**4 * b.bg_peak
    if b.model == "physical":
        return False, Decision("transmission_tint", transmission and interference in COLOURED,
                               "physical model: every film transmits T = 1 - R per wavelength")
    if not transmission or interference in GREY:
        return False, Decision("transmission_tint", False, "no background transmission" if not transmission else
                               f"interference {interference}: the film is grey, so is its transmission")
    if tint_set == "auto":
        return False, Decision("transmission_tint", False,
                               f"eq. (11) as written (grey t^4); the film's complementary colour could change "
                               f"the image by {tint_bound:.2e} (4 r_s t^4 x background peak)")
    return bool(tint_set), Decision("transmission_tint", bool(tint_set), f"set by the scene (bound 4 r_s t^4 x "
                                    f"background peak = {tint_bound:.2e})")


def decide_diffuse(b: SceneBounds, setting, terms: dict, tol: float) -> tuple[bool, Decision]:
    """The diffuse term ``r_d E / pi`` (eq. 2): ``r_d`` times the irradiance bound times the
    films' coefficients."""
    if b.model == "paper":
        weight = (terms["f_front"] if terms["front"] else 0.0) + (terms["f_rear"] if terms["rear"] else 0.0)
    else:
        weight = (1.0 if terms["front"] else 0.0) + (1.0 if terms["rear"] else 0.0)
    bound = max(b.r_d, 0.0) * b.irr_peak / math.pi * weight
    if b.r_d <= 0 and as_switch(setting, "diffuse") == "auto":
        return False, Decision("diffuse", False, "r_d = 0: no irradiance needed (bound 0)")
    return _term("diffuse", setting, bound, f"r_d E_max / pi x film coefficient ({max(b.r_d, 0):.3g} x "
                 f"{b.irr_peak:.3g} / pi x {weight:.3g})", tol)


def decide_bounces(b: SceneBounds, setting, coeffs: dict, rear: bool, tol: float) -> tuple[int, Decision]:
    """Internal bounces (physical): bounces beyond ``n`` change the image by
    ``sum_{k>n} max T R^k T`` times the reflected radiance bound."""
    if b.model != "physical":
        return 1, Decision("internal_bounces", False, "paper model: eq. (11) keeps one rear reflection")
    if setting != "auto":
        n = int(setting)
        return n, Decision("internal_bounces", rear and n > 1, "set by the scene", str(n))
    rears = coeffs["rear"]
    tail = [float(np.max(sum(rears[k:]))) * b.w_refl if k < len(rears) else 0.0 for k in range(len(rears) + 1)]
    n = next((k for k in range(1, MAX_AUTO_BOUNCES + 1) if tail[k] < tol), MAX_AUTO_BOUNCES)
    why = (f"{n} bounce(s): the all-on model's bounces {n + 1}-{MAX_AUTO_BOUNCES} add <= {tail[n]:.2e} < "
           f"tolerance {tol:g}" if n < MAX_AUTO_BOUNCES else
           f"{n} bounce(s), the cap: bounce {n} still adds up to {tail[n - 1]:.2e} >= tolerance {tol:g}")
    return n, Decision("internal_bounces", rear and n > 1, why, str(n))


# ----------------------------------------------------------------------------------------
# All decisions of a scene
# ----------------------------------------------------------------------------------------

def decide(b: SceneBounds, settings: dict, *, thickness_kind: ThicknessKind, tolerance: float = ABSOLUTE_TOLERANCE,
           nodes: int = ALL_ON_NODES) -> tuple[Effects, list[Decision]]:
    """Every effect of a scene from its bounds record and its ``[effects]`` table.

    Returns:
        The static :class:`Effects` and one :class:`Decision` per effect.
    """
    if b.model not in MODELS:
        raise InputError(f"effects.model must be paper or physical, got {b.model!r}")
    tol = float(tolerance)
    fresnel, tint_set, tint_rs, bset = model_settings(b, settings)
    out = [fresnel]
    spectral_setting = settings.get("spectral", "auto")
    wanted = [spectral_basis("reference")] + ([spectral_basis("uniform", k) for k in SPECTRAL_CANDIDATES]
                                              if spectral_setting == "auto" else [])
    table = FilmTable(b, MAX_AUTO_BOUNCES if bset == "auto" else int(bset), tint_rs, wanted)

    interference, d = decide_interference(b, table, settings.get("interference", "auto"), tol)
    out.append(d)
    if b.model == "physical" and interference == "off":
        interference = "incoherent"  # a physical film always reflects; without colours it is grey
    basis, d = decide_spectral(b, table, spectral_setting, interference, tol)
    out.append(d)
    coeffs = table(interference, basis)
    f_rear = float(np.max(sum(coeffs["rear"]))) if coeffs["rear"] else 0.0
    spec_weight = (max(b.r_s, 0.0) if b.model == "paper" else 1.0) * (float(np.max(coeffs["front"])) + f_rear)
    knobs = {k: settings[k] for k in ("nodes", "window", "level") if k in settings}
    fconf, d = decide_filtering(b, settings.get("filtering", "auto"), knobs, nodes, spec_weight, tol)
    out.append(d)
    terms, ds = decide_terms(b, settings, coeffs, tol)
    out.extend(ds)
    tint, d = decide_tint(b, tint_set, terms["transmission"], interference)
    out.append(d)
    diffuse, d = decide_diffuse(b, settings.get("diffuse", "auto"), terms, tol)
    out.append(d)
    front, rear, transmission = terms["front"], terms["rear"], terms["transmission"]
    out.extend(source_decisions(b, front, rear, transmission, thickness_kind))
    bounces, d = decide_bounces(b, bset, coeffs, rear, tol)
    out.append(d)
    fx = Effects(model=b.model, front_reflection=front, rear_reflection=rear, transmission=transmission,
                 interference=interference, diffuse=diffuse and (front or rear),
                 environment=b.has_env and (front or rear or b.background == "envmap"),
                 point_lights=b.n_point_lights > 0 and (front or rear), filtering=fconf, spectral=basis,
                 bounces=bounces, thickness=thickness_kind, background=b.background, tint=tint)
    return fx, out


def model_settings(b, settings: dict):
    """What the model variant decides before any bound: the Fresnel decision, the
    transmission tint's setting and the ``r_s`` it uses (``paper`` with the tint on, else
    None), and the bounce setting (1 in the ``paper`` model, eq. 11)."""
    fresnel = Decision("fresnel", b.model == "physical", "physical model: Fresnel film reflectance per polarisation"
                       if b.model == "physical" else "paper model: constant t, r_s (eqs. 1-14)", b.model)
    tint_set = as_switch(settings.get("transmission_tint", "auto"), "transmission_tint")
    tint_rs = max(b.r_s, 0.0) if b.model == "paper" and tint_set is True else None
    bset = settings.get("bounces", "auto") if b.model == "physical" else 1
    return fresnel, tint_set, tint_rs, bset


def source_decisions(b, front: bool, rear: bool, transmission: bool, thickness_kind: ThicknessKind) -> list:
    """The decisions that only report what the scene holds: its environment map, its point
    lights (eq. 3) and whether its thickness varies over the film."""
    return [
        Decision("environment", b.has_env and (front or rear or transmission),
                 f"environment map given (peak {b.env_peak:.3g})" if b.has_env else "no environment map (dark room)"),
        Decision("point_lights", b.n_point_lights > 0 and (front or rear),
                 f"{b.n_point_lights} light(s): eq. (3)" if b.n_point_lights else "no point lights"),
        Decision("thickness_field", thickness_kind != "constant",
                 "one thickness for the whole film" if thickness_kind == "constant" else f"{thickness_kind} profile",
                 thickness_kind),
    ]


def resolve(summary: SceneSummary, settings: dict, *, thickness_kind: ThicknessKind,
            tolerance: float = ABSOLUTE_TOLERANCE) -> tuple[Effects, list[Decision]]:
    """Decide every effect of a scene from its scalar summaries: :func:`scene_bounds`, then :func:`decide`.

    Parameters
    ----------
    summary : SceneSummary
        The scene's scalar summaries (:class:`~bubblefit.model.bounds.SceneSummary`).
    settings : dict
        The scene's ``[effects]`` table (its ``nodes`` sets the ``mipmap`` quadrature).
    thickness_kind : ThicknessKind
        The thickness model.
    tolerance : float
        The largest change, in linear radiance, a skipped effect may make.

    Returns
    -------
    tuple
        The static :class:`Effects` and one :class:`Decision` per effect.

    References
    ----------
    ``docs/design.md``, "Effects and auto".

    Examples
    --------
    A bubble in a dark room in front of a lit backdrop: nothing lights the film, so only
    the backdrop seen through it (eq. 11's ``t^4`` term) is simulated.

    >>> from bubblefit import SceneSummary, resolve_effects
    >>> dark = SceneSummary(model="paper", t=0.97, r_d=0.01, r_s=0.02, roughness=0.01,
    ...                     thickness_range=(400.0, 600.0), n_film=1.33, env_texel_angle=None,
    ...                     env_peak=0.0, env_mean=0.0, background="photo", background_peak=0.8,
    ...                     n_point_lights=0, light_peak=0.0, min_cos=0.3)
    >>> fx, decisions = resolve_effects(dark, {}, thickness_kind="constant")
    >>> fx.front_reflection, fx.rear_reflection, fx.transmission, fx.interference
    (False, False, True, 'incoherent')
    """
    if summary.model not in MODELS:
        raise InputError(f"effects.model must be paper or physical, got {summary.model!r}")
    nodes = int(settings.get("nodes", ALL_ON_NODES))
    b = scene_bounds(summary, nodes=nodes)
    return decide(b, settings, thickness_kind=thickness_kind, tolerance=tolerance, nodes=nodes)
