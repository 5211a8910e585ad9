"""The fitted parameters, each described once (in the manner of lmfit's ``Parameters``).

:data:`PARAMETERS` names every quantity a fit can vary, with its unit, its bounds, the
transform to the unconstrained coordinate the solver moves in, and the paper's equation
it enters. A :class:`ParameterTable` is one fit's layout: which of them are free, which
are held and why, and how their values become the renderer's
:class:`~bubblefit.model.render.Params` and the reported values of the JSON. Names are
the JSON's keys (``thickness_nm``, ``rotation_deg``, ...), so no alias maps are needed;
the one fitted quantity the JSON does not report is ``split``, the specular share
``r_s / (r_d + r_s)`` of eq. (14) (the JSON reports ``f = r_d / r_s``).

Transforms (``docs/design.md``, "Fitting"): ``logistic`` for fractions in (0, 1),
``log`` for positive scales, ``softplus`` in units of 100 nm for thicknesses (>= 0),
``angle`` for the rotation (the solver moves in radians, the value is in degrees),
``shift`` for the disc's refinement (``DISC_LIMIT tanh(u DISC_UNIT / DISC_LIMIT)``: the
solver moves in units of 1% of the radius, the value stays within 10% of it).

The disc: a disc found in the photo is good to a fraction of a pixel, yet the Fresnel
rim of a physical film changes fast with the distance from the centre, and on photos of
independent renderers a disc 0.6 px off doubled the misfit (reduced chi^2 with the
floor 3.1 against 1.9 with the true disc). ``disc_x``, ``disc_y``, ``disc_r`` move the
disc found by fractions of its radius (:meth:`~bubblefit.model.geometry.OrthographicCamera.rays`)
and are fitted with the rest; the JSON reports the refined disc in pixels, not these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import jax
import jax.numpy as jnp

from ..errors import InputError
from ..model.modes import ThicknessKind
from ..model.render import NO_PROFILE, Params

__all__ = ["Parameter", "PARAMETERS", "ParameterTable", "ParameterRole", "parameter_roles", "ParameterSetting",
           "parse_setting", "starts", "ALIASES", "STARTS", "THICK_UNIT", "THICKNESSES", "DISC_PARAMETERS", "forward", "inverse", "plausible_box", "value_and_slope", "refined_disc", "disc_start", "extrapolated"]

#: nm per unit of the unconstrained thickness coordinate.
THICK_UNIT = 100.0
#: The disc's refinement: disc radii per unit of the unconstrained coordinate, and the
#: largest move (a disc found is never that far off; a fit that wants more sits at a bound).
DISC_UNIT, DISC_LIMIT = 0.01, 0.1
#: The disc's refinement parameters (:meth:`~bubblefit.model.geometry.OrthographicCamera.rays`).
DISC_PARAMETERS = ("disc_x", "disc_y", "disc_r")

Transform = Literal["logistic", "log", "softplus", "angle", "shift", "none"]
#: The part of the render a parameter reaches (:attr:`Parameter.reaches`).
Reach = Literal["weights", "light", "film", "disc"]


@dataclass(frozen=True)
class Parameter:
    """One fitted quantity: its name (a JSON key), unit, bounds, transform and reference.

    ``bounds`` are where the transform keeps the value; a value within the ``plausible``
    range's ends (or outside it) is reported as sitting at a bound (for thicknesses the
    range searched, ``FitOptions.thickness_range``, is used instead).
    """

    name: str
    unit: str
    bounds: tuple
    transform: Transform
    reference: str
    plausible: tuple = (-math.inf, math.inf)
    #: The part of the render it reaches: ``"weights"`` (a linear weight of the terms,
    #: eq. (1) and (14), or the camera's gain), ``"light"`` (the filtered map's lookups,
    #: eq. (13)), ``"film"`` (the film's thickness, eq. (8)) or ``"disc"`` (the rays); the
    #: Jacobian's columns of one part are computed together
    #: (:func:`~bubblefit.inverse._local.column_jacobian`).
    reaches: Reach = "film"


PARAMETERS: dict[str, Parameter] = {p.name: p for p in (
    Parameter("t", "", (0.0, 1.0), "logistic", "transmission fraction per interface, eqs. (10)-(11), (14)",
              (0.5, 0.9995), reaches="weights"),
    Parameter("split", "", (0.0, 1.0), "logistic", "specular share r_s / (r_d + r_s) of 1 - t, eq. (14)",
              (1e-3, 1 - 1e-3), reaches="weights"),
    Parameter("r_d", "", (0.0, math.inf), "log", "diffuse reflectance, eq. (1) (with free_split)", reaches="weights"),
    Parameter("r_s", "", (0.0, math.inf), "log", "specular reflectance, eq. (1) (with free_split)", reaches="weights"),
    Parameter("roughness", "", (0.0, math.inf), "log", "Ward's roughness a, eq. (1)", (0.0, 1.0), reaches="light"),
    Parameter("exposure", "", (0.0, math.inf), "log", "camera gain on the rendered radiance", (1e-6, 1e6),
              reaches="weights"),
    Parameter("rotation_deg", "deg", (-math.inf, math.inf), "angle", "environment rotation about +y", reaches="light"),
    Parameter("thickness_nm", "nm", (0.0, math.inf), "softplus", "film thickness d, eq. (8)"),
    Parameter("top_nm", "nm", (0.0, math.inf), "softplus", "drainage profile at the top, docs/design.md"),
    Parameter("bottom_nm", "nm", (0.0, math.inf), "softplus", "drainage profile at the bottom, docs/design.md"),
    Parameter("exponent", "", (0.0, math.inf), "log", "drainage profile exponent, docs/design.md",
              (0.1, 10.0)),
    *(Parameter(name, "radius", (-DISC_LIMIT, DISC_LIMIT), "shift", what + " of the disc found, in its radius",
                (-0.95 * DISC_LIMIT, 0.95 * DISC_LIMIT), reaches="disc")
      for name, what in (("disc_x", "shift right"), ("disc_y", "shift down"), ("disc_r", "relative change of the radius"))),
)}

#: The parameters that are film thicknesses (unit nm): those the search, the range
#: checks and the plots treat as thicknesses.
THICKNESSES = tuple(name for name, p in PARAMETERS.items() if p.unit == "nm")

#: Free parameters of each thickness model (a map starts from a drainage profile).
THICKNESS_PARAMETERS = {"constant": ("thickness_nm",), "drainage": ("top_nm", "bottom_nm", "exponent"),
                        "map": ("top_nm", "bottom_nm", "exponent")}


def forward(name: str, u):
    """Value of parameter ``name`` at unconstrained coordinate ``u`` (jnp)."""
    tr = PARAMETERS[name].transform
    if tr == "logistic":
        return jax.nn.sigmoid(u)
    if tr == "log":
        return jnp.exp(u)
    if tr == "softplus":
        return THICK_UNIT * jax.nn.softplus(u)
    if tr == "angle":
        return u * (180.0 / math.pi)
    if tr == "shift":
        return DISC_LIMIT * jnp.tanh(u * (DISC_UNIT / DISC_LIMIT))
    return u


def extrapolated(init: dict, previous: dict | None, k: int = 1) -> dict:
    """A sequence's warm start ``k`` frames after the fitted values ``init``: its film
    thicknesses carried on linearly from ``previous`` (the fitted frame before),
    ``d + k (d - d_previous)``, at least 1 nm; the other values as they were. A film that
    drains smoothly then starts within a fraction of a nanometre: on 64 px frames thinning
    by 20 nm each, a solve of 2 steps instead of 4."""
    out = dict(init)
    for name in THICKNESSES:
        if previous and name in init and name in previous and math.isfinite(previous[name]):
            out[name] = max(init[name] + k * (init[name] - previous[name]), 1.0)
    return out


def value_and_slope(name: str, u: float) -> tuple[float, float]:
    """``(value, d value / d u)`` of parameter ``name`` at ``u``, in float64 (numpy): a
    saturated transform (a logistic at ``u = 15``) resolves there, where float32 does not."""
    u = float(u)
    tr = PARAMETERS[name].transform
    if tr == "logistic":
        v = 0.5 * (1.0 + math.tanh(0.5 * u))
        return v, v * (1.0 - v)
    if tr == "log":
        v = math.exp(min(u, 700.0))
        return v, v
    if tr == "softplus":
        return THICK_UNIT * (max(u, 0.0) + math.log1p(math.exp(-abs(u)))), THICK_UNIT * 0.5 * (1.0 + math.tanh(0.5 * u))
    if tr == "angle":
        return u * (180.0 / math.pi), 180.0 / math.pi
    if tr == "shift":
        th = math.tanh(u * (DISC_UNIT / DISC_LIMIT))
        return DISC_LIMIT * th, DISC_UNIT * (1.0 - th * th)
    return u, 1.0


def inverse(name: str, v) -> float:
    """Unconstrained coordinate of value ``v`` of parameter ``name`` (clamped inside its bounds)."""
    v = float(v)
    tr = PARAMETERS[name].transform
    if tr == "logistic":
        v = min(max(v, 1e-6), 1 - 1e-6)
        return math.log(v / (1 - v))
    if tr == "log":
        return math.log(max(v, 1e-12))
    if tr == "softplus":
        x = max(v, 1e-3) / THICK_UNIT
        return x + math.log(-math.expm1(-x)) if x < 30 else x
    if tr == "angle":
        return math.radians(v)
    if tr == "shift":
        v = min(max(v / DISC_LIMIT, -0.999), 0.999)
        return math.atanh(v) * (DISC_LIMIT / DISC_UNIT)
    return v


def plausible_box(free: tuple) -> tuple[tuple, tuple]:
    """``(lo, hi)``: for each parameter of ``free``, the unconstrained coordinates of the
    ends of its ``plausible`` range, ``-inf``/``inf`` where the range is open or ends at
    the transform's own bound (a roughness at 0, the mirror). The local solve projects
    its trial points onto this box (:class:`~bubblefit.inverse._lm_solver.LevenbergMarquardt`).

    A logistic or log coordinate moved far past its plausible range saturates: at
    ``split = 1 - 1e-7`` the slope ``d split / d z`` is 1e-7, the parameter's column of the
    Jacobian vanishes, and no damped step brings it back (the demo's drainage fit
    left it there, f = 1e-6 for a true 0.3, at a robust chi^2 of 13216 against the
    interior optimum's 11904). At the box's ends the slope is that of the plausible
    range's ends (1e-3 for the split), which the solve still resolves, and a value there
    is reported as sitting at a bound (:func:`~bubblefit.inverse._verdict.at_bounds`).

    References
    ----------
    C. Kanzow, N. Yamashita & M. Fukushima, "Levenberg-Marquardt methods with strong
    local convergence properties for solving nonlinear equations with convex
    constraints", *J. Comput. Appl. Math.* 172 (2004), 375-397 (the projected LM step).
    """
    lo, hi = [], []
    for name in free:
        p = PARAMETERS[name]
        ends = []
        for end, bound, inf in zip(p.plausible, p.bounds, (-math.inf, math.inf)):
            ends.append(inf if not math.isfinite(end) or end == bound else inverse(name, end))
        lo.append(ends[0])
        hi.append(ends[1])
    return tuple(lo), tuple(hi)


@dataclass(frozen=True)
class ParameterTable:
    """One fit's parameters: ``free`` (in the solver's order) and ``held`` ``((name, reason), ...)``.

    Hashable (on what changes the computation, not on the reasons), so compiled solvers
    are cached per table.
    """

    free: tuple
    held: tuple = field(default=(), compare=False)  # reasons do not change what is compiled
    thickness_model: ThicknessKind = "constant"
    free_split: bool = False

    @property
    def jacobian_groups(self) -> tuple:
        """Indices into ``free`` grouped by the part of the render they reach
        (:attr:`Parameter.reaches`), in order of first appearance."""
        groups: dict[str, list[int]] = {}
        for i, name in enumerate(self.free):
            groups.setdefault(PARAMETERS[name].reaches, []).append(i)
        return tuple(tuple(g) for g in groups.values())

    def unconstrained(self, values: dict):
        """The solver's start ``z`` (float32) for ``values``."""
        return jnp.asarray([inverse(n, values[n]) for n in self.free], jnp.float32)

    def values(self, z, fixed: dict) -> dict:
        """All values: ``fixed`` updated with the free ones at ``z``."""
        vals = dict(fixed)
        for i, name in enumerate(self.free):
            vals[name] = forward(name, z[i])
        return vals

    def render_params(self, vals: dict, thickness_model: ThicknessKind | None = None) -> Params:
        """The renderer's :class:`Params` for ``vals`` (``thickness_model`` default: the table's;
        ``map`` reads ``vals["map"]``)."""
        model = thickness_model or self.thickness_model
        t = vals["t"]
        if self.free_split:
            r_d, r_s = vals["r_d"], vals["r_s"]
        else:  # eq. (14): r_d + r_s = 1 - t
            r_s = (1.0 - t) * vals["split"]
            r_d = (1.0 - t) * (1.0 - vals["split"])
        if model == "constant":
            th = vals["thickness_nm"]
        elif model == "drainage":
            th = jnp.stack([vals["top_nm"], vals["bottom_nm"], vals["exponent"]])
        else:
            th = vals["map"]
        f32 = lambda v: jnp.asarray(v, jnp.float32)
        disc = jnp.stack([f32(vals.get(n, 0.0)) for n in DISC_PARAMETERS])
        # a map keeps the drainage profile it was fitted after, for the films the photo does not show
        prof = (jnp.stack([f32(vals[n]) for n in ("top_nm", "bottom_nm", "exponent")])
                if model == "map" and all(n in vals for n in ("top_nm", "bottom_nm", "exponent"))
                else f32(jnp.asarray(NO_PROFILE)))
        return Params(f32(t), f32(r_d), f32(r_s), f32(vals["roughness"]), f32(th), f32(vals["n_film"]),
                      f32(vals["exposure"]), f32(vals["rotation_deg"] * (math.pi / 180.0)), disc, prof,
                      f32(vals.get("divergence", 0.0)))

    def reported(self, vals: dict) -> dict:
        """The JSON's parameters (jnp scalars) from values."""
        p = self.render_params(vals)
        out = {"t": p.t, "r_d": p.r_d, "r_s": p.r_s, "f": p.r_d / p.r_s, "roughness": p.roughness,
               "exposure": p.exposure, "rotation_deg": p.rotation * (180.0 / math.pi)}
        if self.thickness_model == "constant":
            out["thickness_nm"] = p.thickness
        else:
            out["top_nm"], out["bottom_nm"], out["exponent"] = p.thickness[0], p.thickness[1], p.thickness[2]
        for i, name in enumerate(DISC_PARAMETERS):  # refined disc: converted to pixels by the fit
            if name in self.free:
                out[name] = p.disc[i]
        return out


def refined_disc(disc: tuple, reported: dict, stderr: dict) -> tuple[tuple, dict | None]:
    """``(disc, disc_stderr)`` in pixels: ``disc`` ``(cx, cy, r)`` moved by the fitted
    ``disc_x``, ``disc_y``, ``disc_r`` (removed from ``reported`` and ``stderr``), and
    their standard errors (in radii, with the Type B term ``FitOptions.disc_model_error``
    that the covariance holds, :func:`~bubblefit.inverse._uncertainty.disc_type_b`);
    ``(disc, None)`` when the disc was not fitted."""
    if disc is None or not any(n in reported for n in DISC_PARAMETERS):
        return disc, None
    cx, cy, r = disc
    sx, sy, sr = (float(reported.pop(n, 0.0)) for n in DISC_PARAMETERS)
    ex, ey, er = (stderr.pop(n, None) for n in DISC_PARAMETERS)
    px = lambda e: None if e is None else round(float(e) * r, 3)
    new = (round(cx + sx * r, 3), round(cy + sy * r, 3), round(r * (1.0 + sr), 3))
    return new, {"cx": px(ex), "cy": px(ey), "r": px(er)}


def disc_start(disc: tuple, refined) -> dict:
    """The disc's refinement (``disc_x``, ``disc_y``, ``disc_r``) that moves ``disc``
    ``(cx, cy, r)`` onto ``refined`` (a disc in pixels, as :func:`refined_disc` reports it):
    ``((cx' - cx) / r, (cy' - cy) / r, r' / r - 1)``, the inverse of :func:`refined_disc`
    (the refinement of :meth:`~bubblefit.model.geometry.OrthographicCamera.rays`). A
    sequence's frame starts its disc where its predecessor's fit left it. Empty when
    ``refined`` is not a disc or a move lies outside the refinement's range (``DISC_LIMIT``)."""
    try:
        cx, cy, r = (float(v) for v in disc)
        rx, ry, rr = (float(v) for v in refined)
    except (TypeError, ValueError):
        return {}
    if not (r > 0 and all(math.isfinite(v) for v in (cx, cy, r, rx, ry, rr))):
        return {}
    out = dict(zip(DISC_PARAMETERS, ((rx - cx) / r, (ry - cy) / r, rr / r - 1.0)))
    return out if all(abs(v) < DISC_LIMIT for v in out.values()) else {}


#: What a fit did with a reported parameter (:class:`ParameterRole`).
Role = Literal["fitted", "derived", "held", "given", "unused"]


@dataclass(frozen=True)
class ParameterRole:
    """One row of a fit's parameter table: a reported parameter and what the fit did with it.

    Attributes
    ----------
    name : str
        The reported name (a key of the JSON's ``params``).
    role : Role
        ``fitted`` (free in the solve), ``derived`` (computed from fitted ones), ``held`` (at
        its starting value), ``given`` (an input, never fitted: ``n_film``) or ``unused``
        (reported, but the model does not render with it).
    reason : str
        From what a derived value comes, why a parameter was held or is unused.
    """

    name: str
    role: Role
    reason: str = ""


#: eq. (14)'s split of ``1 - t`` in words, for the derived reflectances.
_SPLIT_RULE = "t and the split of eq. (14): r_s = split (1 - t), r_d = (1 - split)(1 - t)"


def _split_role(name: str, free: set, held: dict) -> ParameterRole:
    """``r_d``, ``r_s`` or ``f`` of a fit whose split of ``1 - t`` is eq. (14)'s."""
    split_free = "split" in free
    why_split = f"; the split held: {held['split']}" if "split" in held and not split_free else ""
    if name == "f":  # r_d / r_s = (1 - split) / split: the split alone
        if split_free:
            return ParameterRole(name, "derived", "r_d / r_s = (1 - split) / split, from the fitted split (eq. 14)")
        return ParameterRole(name, "held", held.get("split", "the split held at its starting value"))
    if split_free or "t" in free:
        return ParameterRole(name, "derived", f"from {_SPLIT_RULE}{why_split}")
    return ParameterRole(name, "held", f"t and the split held ({held.get('split') or held.get('t', 'start')})")


def parameter_roles(table: ParameterTable, model: str, names) -> tuple[ParameterRole, ...]:
    """The fit's parameter table: for each reported name (in ``names``' order) whether it
    was fitted, derived (and from what), held (and why), given or unused by ``model``'s
    render (the physical model's ``t`` and ``r_s``, which Fresnel's equations replace).
    It agrees with the numbers: exactly the fitted and the derived parameters have
    standard errors (:mod:`._uncertainty`)."""
    free, held = set(table.free), dict(table.held)
    rows = []
    for name in names:
        if name == "n_film":
            rows.append(ParameterRole(name, "given", "the film's index at 589.3 nm: the options', the scene's or "
                                                     "1.4; never fitted"))
        elif name in free:
            rows.append(ParameterRole(name, "fitted"))
        elif name == "thickness_nm" and table.thickness_model != "constant":  # a thickness map's
            rows.append(ParameterRole(name, "derived", "the median of the fitted thickness map over the film"))
        elif model == "physical" and name in ("t", "r_s"):
            rows.append(ParameterRole(name, "unused", "the physical model reflects and transmits by Fresnel's "
                                                      "equations from n_film; the value shown is the start"))
        elif model == "physical" and name == "f":
            rows.append(ParameterRole(name, "unused", "r_d / r_s, and the physical model does not use r_s"))
        elif name in ("r_d", "r_s", "f") and not table.free_split:
            rows.append(_split_role(name, free, held))
        elif name == "f":  # r_d and r_s on their own
            moving = [n for n in ("r_d", "r_s") if n in free]
            rows.append(ParameterRole(name, "derived", f"r_d / r_s, from the fitted {' and '.join(moving)}")
                        if moving else ParameterRole(name, "held", "r_d and r_s held"))
        else:
            rows.append(ParameterRole(name, "held", held.get(name, "held at its starting value")))
    return tuple(rows)


#: Other names ``--hold``, ``--set`` and a warm start accept for the parameters' own
#: (``f``, the ratio ``r_d / r_s``, is held as eq. (14)'s ``split``).
ALIASES = {"f": "split", "thickness": "thickness_nm", "top": "top_nm", "bottom": "bottom_nm",
           "rotation": "rotation_deg"}
#: The starting values a fit takes (:func:`bubblefit.inverse._setup.defaults`): the
#: parameters of :data:`PARAMETERS` but eq. (14)'s split and the disc's refinement, and
#: ``f = r_d / r_s``, from which the split starts.
STARTS = ("t", "f", "r_d", "r_s", "roughness", "exposure", "rotation_deg", "thickness_nm", "top_nm", "bottom_nm",
          "exponent")


@dataclass(frozen=True)
class ParameterSetting:
    """What a user says about one parameter before a fit (``FitOptions.parameters``,
    ``--set NAME=VALUE``, ``--hold NAME``, ``--t``, ``--calibration``), in the manner of
    lmfit's ``Parameter``: its starting value (None: the fit's default), whether it is held
    at it, and whether the value is a measurement of this bubble.

    A value the scene file sets is held at the scene's value, and a starting value does
    not replace it; a measured value (a dark-box calibration's ``t``) does, and stays held
    (:func:`~bubblefit.inverse._setup.defaults`, ``docs/fit-pipeline.md``).

    Attributes
    ----------
    name : str
        One of :data:`STARTS` (or an alias of :data:`ALIASES`); a setting that only holds
        (no value) may name any parameter of :data:`PARAMETERS`, or ``disc`` (the disc's
        refinement).
    value : float or None
        The starting value, in the parameter's unit (:data:`PARAMETERS`).
    hold : bool
        Held at its starting value instead of fitted.
    measured : bool
        The value is a measurement of this bubble (``bubblefit calibrate``'s ``t``): it
        replaces a value the scene file sets.
    """

    name: str
    value: float | None = None
    hold: bool = False
    measured: bool = False

    @property
    def start(self) -> str:
        """The name of the starting value it sets (``thickness`` is ``thickness_nm``; ``f`` stays ``f``)."""
        return self.name if self.name == "f" else ALIASES.get(self.name, self.name)

    def check(self, where: str = "parameters") -> None:
        """Raise :class:`~bubblefit.errors.InputError` (one line) for an unknown name or a
        value outside the parameter's bounds."""
        if self.hold and self.value is None:  # held at the fit's own start
            name = ALIASES.get(self.name, self.name)
            if name != "disc" and name not in PARAMETERS:
                raise InputError(f"cannot hold {name!r}: known parameters are t, f, r_d, r_s, roughness, thickness_nm, "
                                 "exposure, rotation_deg, top_nm, bottom_nm, exponent, disc")
            return
        if self.start not in STARTS:
            raise InputError(f"{where}: unknown parameter {self.name!r} (known: {', '.join(STARTS)})")
        if self.value is None:
            if self.measured:
                raise InputError(f"{where}: a measured {self.name} needs its value")
            return
        v = float(self.value)
        lo, hi = (0.0, math.inf) if self.start == "f" else PARAMETERS[self.start].bounds
        strict = self.start == "f" or PARAMETERS[self.start].transform in ("logistic", "log")
        inside = (lo < v < hi) if strict else (lo <= v <= hi)
        if not (math.isfinite(v) and inside):
            raise InputError(f"{where}: {self.name} = {self.value} lies outside its range ({lo:g}, {hi:g})")


def starts(**values: float) -> tuple[ParameterSetting, ...]:
    """Starting values as ``FitOptions.parameters`` entries, in the order given:
    ``starts(t=0.968, roughness=0.04)`` (each is checked by :class:`FitOptions`)."""
    return tuple(ParameterSetting(name, float(v)) for name, v in values.items())


def parse_setting(text: str, where: str = "--set") -> ParameterSetting:
    """``NAME=VALUE`` (``--set``) as a checked :class:`ParameterSetting`; one-line
    :class:`~bubblefit.errors.InputError` otherwise."""
    name, sep, value = (part.strip() for part in str(text).partition("="))
    try:
        setting = ParameterSetting(name, float(value))
    except ValueError:
        raise InputError(f"{where} takes NAME=VALUE with a number, got {text!r}") from None
    if not sep or not name:
        raise InputError(f"{where} takes NAME=VALUE, got {text!r}")
    setting.check(where)
    return setting
