"""Setting up a fit of one photo: starting values, the effects, the parameter table, the
camera and the observation at the fit's resolution (:func:`setup`)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..capture.view import divergence, perspective_from_disc
from ._observation import Frame, Level, analysis_frame, make_level, resolve_disc, saturation_mask
from ._pair import LUMINANCE, PairCheck, check_pair
from ._options import FitOptions
from ._result import ColourSettings
from ._parameters import ALIASES, DISC_PARAMETERS, ParameterTable, THICKNESS_PARAMETERS, disc_start
from ..errors import InputError
from ..lighting.envmap import EnvMap, downsample
from ..model.bounds import SceneSummary
from ..model.effects import Decision, check_harmonic, resolve
from ..model.geometry import DivergentCamera, OrthographicCamera
from ..model.render import RenderConfig
from ..optics.dispersion import REFERENCE_WAVELENGTH_NM, Cauchy, refractive_index

__all__ = ["Setup", "setup", "defaults", "colour_settings", "map_start", "MAP_START_KEYS"]

# ---------------------------------------------------------------------------------------
# Starting values, effects and the parameter table
# ---------------------------------------------------------------------------------------


def _scene_values(scene, vals: dict, held: dict) -> None:
    """Values the scene file sets explicitly: used, and held (``n_film`` used only)."""
    b = scene.table("bubble")
    for name in ("t", "roughness", "f", "r_d", "r_s"):
        if name in b:
            vals[name] = float(b[name])
            held[ALIASES.get(name, name)] = "set by the scene file"
    if "n_film" in b:  # a number, a Cauchy law or a preset: its index at 589.3 nm
        vals["n_film"] = float(scene.params().n_film)
    model, values = scene.thickness_spec()
    if "thickness_nm" in b or "thickness" in b:
        if model == "constant":
            vals["thickness_nm"] = float(values)
            held["thickness_nm"] = "set by the scene file"
        elif model == "drainage":
            vals["top_nm"], vals["bottom_nm"], vals["exponent"] = (float(x) for x in values)
            held.update(top_nm="set by the scene file", bottom_nm="set by the scene file",
                        exponent="set by the scene file")
    if "rotation_deg" in scene.table("lighting"):
        vals["rotation_deg"] = float(scene.table("lighting")["rotation_deg"])
        held["rotation_deg"] = "set by the scene file"


def defaults(scene, init, opts: FitOptions):
    """Starting values (keyed by :data:`PARAMETERS` names) and the parameters held by the
    scene or the options, with the reasons.

    In this order: the fit's defaults, the scene file's values (held), a warm start
    ``init``, the options' ``n_film``, then ``opts.parameters`` in their order; a
    parameter's starting value does not replace a value the scene file sets, a measured
    one does (:class:`~bubblefit.inverse._parameters.ParameterSetting`)."""
    vals = {"t": 0.972, "f": 0.3, "r_d": None, "r_s": None, "roughness": 0.01, "thickness_nm": 500.0,
            "top_nm": 200.0, "bottom_nm": 1000.0, "exponent": 1.0, "exposure": 1.0, "rotation_deg": 0.0,
            "n_film": 1.4, **{n: 0.0 for n in DISC_PARAMETERS}}
    held = {}
    if scene is not None:
        _scene_values(scene, vals, held)
    for k, v in (init or {}).items():
        k = k if k == "f" else ALIASES.get(k, k)
        if v is not None and k in vals:
            vals[k] = float(v)
    if opts.n_film is not None:  # the command line's index wins over the scene's and a warm start's
        vals["n_film"] = float(refractive_index(opts.n_film, REFERENCE_WAVELENGTH_NM))
    for setting in opts.parameters:  # the user's own values; a scene file's stays, unless measured
        if setting.value is not None and (setting.measured or ALIASES.get(setting.name, setting.name) not in held):
            vals[setting.start] = float(setting.value)
    if not 0 < vals["t"] < 1:
        raise InputError(f"starting t must lie in (0, 1), got {vals['t']}")
    if vals["r_d"] is None or vals["r_s"] is None:
        vals["r_s"] = (1 - vals["t"]) / (1 + vals["f"])
        vals["r_d"] = (1 - vals["t"]) - vals["r_s"]
    vals["split"] = vals["r_s"] / max(vals["r_s"] + vals["r_d"], 1e-12)
    for name in (ALIASES.get(s.name, s.name) for s in opts.parameters if s.hold):  # names checked by the setting
        if name == "disc":
            held.update({n: "held by request" for n in DISC_PARAMETERS})
        else:
            held[name] = "held by request"
    return vals, held


def _decide(opts: FitOptions, vals, env, bg, settings, camera, lights):
    """The effects the fit simulates (:func:`bubblefit.model.effects.resolve`) from the
    starting values, the map, the background and the rim's incidence."""
    envpx = np.asarray(env.pixels)
    bg_kind = "photo" if bg is not None else "envmap"
    summary = SceneSummary(
        model=opts.model, t=vals["t"], r_d=vals["r_d"], r_s=vals["r_s"], roughness=vals["roughness"],
        thickness_range=tuple(float(x) for x in opts.thickness_range), n_film=vals["n_film"],
        env_texel_angle=env.texel_angle, env_peak=float(envpx.max()), env_mean=float(envpx.mean()),
        background=bg_kind, background_peak=float(np.max(bg)) if bg is not None else float(envpx.max()),
        n_point_lights=len(lights), light_peak=max([max(l.irradiance) for l in lights], default=0.0),
        min_cos=math.sqrt(max(0.0, 1 - opts.rim**2)), env_pixels=envpx,
        env_irradiance_peak=float(np.max(np.asarray(env.irradiance))),
    )
    tolerance = float(settings.get("tolerance", 1e-3))
    # the decision is a function of the summary's values, the map and the settings: a
    # sequence's frames that hold the same values (every frame that carries the global
    # parameters) take the decision their first frame made instead of bounding the films
    # again (about a tenth of such a frame's CPU time)
    key = (repr(summary), id(env), json.dumps(settings, sort_keys=True, default=repr), opts.thickness, tolerance)
    made = _DECIDED.get(key)
    if made is None or made[0] is not env:
        made = (env, resolve(summary, settings, thickness_kind=opts.thickness, tolerance=tolerance))
        while len(_DECIDED) >= _DECIDED_KEPT:
            _DECIDED.pop(next(iter(_DECIDED)))
        _DECIDED[key] = made
    fx, decisions = made[1]
    return fx, list(decisions)


#: The last :data:`_DECIDED_KEPT` decisions of :func:`_decide` by their inputs (the map held
#: with its decision, so that its ``id`` names it while it is kept); the oldest goes first.
_DECIDED: dict = {}
_DECIDED_KEPT = 4


#: A map holds a compact bright source (a sun, a lamp, city lights), whose glints one ray
#: per pixel point-samples, when its brightest texel at :data:`COMPACT_SOURCE_ROWS` rows
#: exceeds the map's mean luminance by more than this; the fit then integrates the map over
#: each pixel's footprint. The ratio on the development cases' maps
#: (experiments/validation/split.toml): courtyard 27 (ref_const300_courtyard_ortho,
#: ref_drain_lin_courtyard_ortho, cyc_const500_courtyard_ortho, mts_thick_courtyard_persp;
#: the shipped 1024 x 512 copy also 27), studio 630 (ref_drain_exp15_studio_persp), night
#: 2800 (ref_const1200_night_ortho_offc), city 4000 (ref_drain_lin_city_ortho_offc,
#: cyc_bump_city_ortho_offc), interior 8000 (ref_const450_interior_ortho), sunrise 11600
#: (ref_const620_sunrise_persp, cyc_drain_lin_sunrise_persp, ref_bump_sunrise_ortho);
#: 100 lies 3.7x above the first and 6x below the second group.
COMPACT_SOURCE_RATIO = 100.0

#: Rows (1.4 degree texels) of the map, halved with its power kept, at which
#: :func:`compact_source` reads its peak, so that the measure does not depend on the map's
#: resolution (a smaller map is read as it is).
COMPACT_SOURCE_ROWS = 128


def compact_source(env: EnvMap) -> tuple[bool, str]:
    """Whether the map ``env`` holds a compact bright source, and the reason in words: its
    luminance peak at :data:`COMPACT_SOURCE_ROWS` rows (the map halved with its power kept,
    :func:`~bubblefit.lighting.envmap.downsample`) over its solid-angle mean luminance
    (:func:`~bubblefit.inverse._exposure.map_levels`) above :data:`COMPACT_SOURCE_RATIO`.
    Where it does, one ray per pixel point-samples the source's glints, which a camera
    integrates over its pixel."""
    from ._exposure import map_levels

    px = np.asarray(env.pixels, np.float64)
    while px.shape[0] > COMPACT_SOURCE_ROWS:
        px = downsample(px)
    _, mean = map_levels(px)
    ratio = float(np.max(px @ LUMINANCE)) / mean if mean > 0 else float("inf")
    if ratio > COMPACT_SOURCE_RATIO:
        return True, (f"the map's peak is {ratio:.0f}x its mean at 1.4 degrees (a compact bright source): each "
                      "lookup is averaged over the pixel's footprint")
    return False, f"the map's peak is {ratio:.0f}x its mean at 1.4 degrees (no compact source): one ray per pixel"


def _held_by_effects(opts: FitOptions, fx, hold: dict) -> tuple:
    """Add to ``hold`` the parameters the decided effects make invisible; return the split's names."""
    skipped_diffuse = "diffuse term skipped: r_d cannot change the image"
    if fx.model == "physical":
        hold.setdefault("t", "physical model: Fresnel reflectance from n_film sets t and r_s")
        hold.setdefault("r_s", "physical model: Fresnel reflectance from n_film sets t and r_s")
        # Fresnel sets the specular reflectance; the diffuse one (eq. 2's r_d), which a
        # real film hardly has, is fitted wherever the diffuse term is simulated
        if not fx.diffuse:
            hold.setdefault("r_d", skipped_diffuse)
        hold.setdefault("split", "physical model: Fresnel sets r_s; r_d is fitted on its own")
        split_names = ("r_d",)
    elif opts.free_split:
        if not fx.diffuse:
            hold.setdefault("r_d", skipped_diffuse)
        split_names = ("r_d", "r_s")
    else:
        if not fx.diffuse:
            hold.setdefault("split", skipped_diffuse + " and the split (eq. 14) would only trade r_s against "
                                                       "the camera gain")
        split_names = ("split",)
    if fx.filtering.method == "mirror" or not fx.environment:
        hold.setdefault("roughness", f"roughness filtering skipped ({fx.filtering.method} lookup): "
                                     "roughness cannot change the image")
    if fx.interference in ("off", "incoherent"):
        for n in ("thickness_nm", "top_nm", "bottom_nm", "exponent"):
            hold.setdefault(n, "interference skipped: thickness cannot change the image")
    if not opts.fit_rotation:
        hold.setdefault("rotation_deg", "not fitted (FitOptions.fit_rotation is off)")
    return split_names


def _table(opts: FitOptions, fx, held: dict, fit_disc: bool) -> ParameterTable:
    """The fit's :class:`ParameterTable`: free parameters in order, and those held with
    reasons (the disc's refinement is free only with ``fit_disc``, and not reported held)."""
    hold = dict(held)
    split_names = _held_by_effects(opts, fx, hold)
    cand = ["t", *split_names, "roughness", "exposure", "rotation_deg", *THICKNESS_PARAMETERS[opts.thickness]]
    if fit_disc and not any(n in hold for n in DISC_PARAMETERS):
        cand += list(DISC_PARAMETERS)
    hold = {k: v for k, v in hold.items() if k not in DISC_PARAMETERS}
    if fx.model == "physical":
        cand = [c for c in cand if c not in ("t", "r_s", "split")]
    free = tuple(c for c in cand if c not in hold)
    model = "constant" if opts.thickness == "constant" else "drainage"
    # r_d read on its own (a free split, or the physical model, where Fresnel sets r_s)
    # unless the fit's split parameter is eq. (14)'s
    return ParameterTable(free, tuple(hold.items()), model, "split" not in split_names)


# ---------------------------------------------------------------------------------------
# Setting up a fit of one photo
# ---------------------------------------------------------------------------------------


@dataclass
class Setup:
    """What a fit of one photo knows before it solves (:func:`setup`)."""

    photo: np.ndarray  # the analysed frame (:func:`analysis_frame`), as background, sigma, saturated
    background: np.ndarray | None
    vals: dict
    table: ParameterTable
    search_table: ParameterTable  # the table without the disc's refinement (the search's)
    fx: object
    decisions: list
    base_cfg: RenderConfig
    map_cfg: RenderConfig
    disc: tuple | None  # in the photo's pixels
    sigma: np.ndarray
    saturated: np.ndarray
    k_search: int
    lev_fit: Level
    frame: Frame
    warnings: list
    colour: ColourSettings
    #: what the background photo says about the pairing (None without one)
    pair: PairCheck | None = None
    #: a warm start's thickness map and the drainage profile it was fitted over
    #: (:func:`map_start`; None: the map is built coarse to fine from the profile)
    map_start: tuple | None = None
    levels: dict = field(default_factory=dict, repr=False)  # built by :meth:`level`, by (k, cfg, rim)

    def level(self, k: int, opts: FitOptions, cfg: RenderConfig | None = None) -> Level:
        """The photo ``k`` times smaller (:func:`make_level`), built once per ``k``,
        configuration and rim."""
        key = (k, cfg or self.base_cfg, float(opts.rim))
        if key not in self.levels:
            self.levels[key] = make_level(k, key[1], self.photo, self.sigma, self.background, self.saturated, key[2],
                                          self.frame.bg_sigma, float(self.vals.get("divergence", 0.0)))
        return self.levels[key]


def _float(a) -> np.ndarray:
    """``a`` as a float array, float32 kept (a large photo is not copied to float64)."""
    a = np.asarray(a)
    return a if a.dtype in (np.float32, np.float64) else a.astype(np.float64)


def _check_inputs(photo, env, background):
    photo = _float(photo)
    if photo.ndim != 3 or photo.shape[2] != 3:
        raise InputError(f"the photo must be an RGB image (H, W, 3), got shape {photo.shape}")
    if not isinstance(env, EnvMap):
        raise InputError("the environment map must be an EnvMap")
    H, W = photo.shape[:2]
    if background is not None:
        background = _float(background)
        if background.shape != photo.shape:
            raise InputError(f"the background photo is {background.shape[1]}x{background.shape[0]}, "
                             f"the photo is {W}x{H}")
    return photo, background


def _settings(scene, opts: FitOptions) -> dict:
    """The ``[effects]`` settings: the scene's, the options', and the fit's defaults."""
    settings = dict(scene.table("effects")) if scene is not None else {}
    settings.update(dict(opts.effects))
    settings["model"] = opts.model
    # Unless told otherwise, the spectral quadrature is chosen in :func:`setup` from the
    # films the fit may meet (:func:`~bubblefit.inverse._spectral_rule.fit_spectral_basis`),
    # whereas "auto" may ask for hundreds of samples to bound the error everywhere.
    # The physical model's internal bounces: 3 explain an independent 8-bounce render as
    # well as 8 do (reduced chi^2 3.30 against 3.35 on experiments/validation's
    # ref_const300, a development case in split.toml; 2 bounces: 4.25), whereas the absolute bound of "auto" asks for all 8.
    settings.setdefault("bounces", 3)
    # A photographed film transmits the complement of the colour it reflects; over a bright
    # background that tint is as strong as the reflection, and eq. (11)'s grey t^4 would
    # push the thickness to another colour order (tests/test_fit.py::test_model_mismatch).
    settings.setdefault("transmission_tint", True)
    return settings


def calibrated_illuminant(response: str, illuminant: str, stated: bool) -> str:
    """The fit's illuminant for a ``response`` written by ``bubblefit calibrate-camera``
    (:func:`~bubblefit.optics.spectral.response_illuminant`): the lamp it was calibrated
    under when none was ``stated``; a response calibrated under ``E`` holds the lamp, so
    another stated illuminant would count the lamp twice and is refused in one line."""
    from ..optics.spectral import response_illuminant

    under = response_illuminant(response)
    if under is None:
        return illuminant
    if not stated:
        return under
    if under.upper() == "E" and illuminant.upper() not in ("E", "EQUAL", "EQUAL_ENERGY"):
        raise InputError(f"the camera response {response} was calibrated under illuminant E: it already holds the "
                         f"lamp, so fit it with --illuminant E (or leave --illuminant out), not {illuminant}")
    return illuminant


def colour_settings(scene, opts: FitOptions, n_film: float) -> ColourSettings:
    """The illuminant, camera response, white balance, index law, rays per pixel and film
    colouring of the fit: each from ``opts`` when given (the command line), else from the
    scene (:meth:`~bubblefit.model.scene.Scene.colour`, ``[bubble] n_film``, ``[camera]
    samples_per_pixel``, ``[film] film_rgb``), else the defaults (D65, sRGB, ``illuminant``,
    the constant ``n_film``, 1, ``spectral``). Names and files are checked here (one-line
    :class:`InputError`)."""
    from ..optics import spectral

    ill, resp, wb = scene.colour() if scene is not None else ("D65", "srgb", "illuminant")
    stated = opts.illuminant is not None or (scene is not None and "illuminant" in scene.table("lighting"))
    ill = opts.illuminant if opts.illuminant is not None else ill
    resp = opts.camera_response if opts.camera_response is not None else resp
    ill = calibrated_illuminant(resp, ill, stated)
    wb = opts.white_balance if opts.white_balance is not None else wb
    spectral.illuminant_spectrum(ill)
    spectral.response_functions(resp)
    law = opts.n_film if opts.n_film is not None else (scene.dispersion() if scene is not None else None)
    if not isinstance(law, Cauchy):  # a constant index: the value the fit uses
        law = float(n_film)
    spp = opts.samples_per_pixel
    if spp is None:
        spp = scene.samples_per_pixel if scene is not None else 1
    film_rgb = opts.film_rgb or (scene.film_rgb if scene is not None else "spectral")
    return ColourSettings(ill, resp, wb, law, int(spp), film_rgb)


def _quadrature(opts: FitOptions, vals: dict, colour: ColourSettings, bounces: int):
    """``(basis, decision)``: the spectral quadrature that films of ``opts.thickness_range``
    (index ``vals["n_film"]``, ``bounces`` internal bounces), seen down to the rim's
    incidence, need under ``colour``'s illuminant, response and white balance
    (:func:`~bubblefit.inverse._spectral_rule.fit_spectral_basis`)."""
    from ._spectral_rule import fit_spectral_basis

    return fit_spectral_basis(tuple(float(x) for x in opts.thickness_range), float(vals["n_film"]),
                              math.sqrt(max(0.0, 1.0 - float(opts.rim) ** 2)), int(bounces), colour.illuminant,
                              colour.response, colour.white_balance)


def _coloured(fx, colour: ColourSettings):
    """The effects with their spectral basis for ``colour``'s illuminant, response and white
    balance (:meth:`~bubblefit.optics.spectral.SpectralBasis.with_colour`, as
    :meth:`~bubblefit.model.scene.Scene.plan` renders)."""
    if fx.spectral is None or colour.default_colour:
        return fx
    return replace(fx, spectral=fx.spectral.with_colour(colour.illuminant, colour.response, colour.white_balance))


def _perspective(scene, photo):
    """``(camera, center, radius)`` of a scene's perspective camera, or None."""
    if scene is None or scene.table("camera").get("type", "orthographic") != "perspective":
        return None
    H, W = photo.shape[:2]
    camera = scene.camera()
    if (camera.height, camera.width) != (H, W):
        raise InputError(f"the scene's camera is {camera.width}x{camera.height}, the photo is {W}x{H}")
    b = scene.table("bubble")
    return camera, tuple(float(x) for x in b.get("center", (0, 0, 0))), float(b.get("radius", 1.0))


def _disc(scene, opts: FitOptions, photo, background) -> tuple[tuple, list, bool]:
    """The orthographic camera's disc (given, the scene's, a calibration's or found), the
    warnings, and whether the fit refines it (``FitOptions.fit_disc``; by default when
    it was not given)."""
    given = opts.disc
    if given is None and scene is not None and "disc" in scene.table("camera"):
        given = tuple(scene.table("camera")["disc"])
    disc, warnings = resolve_disc(photo, background, opts, given)
    if given is None:
        disc = tuple(round(float(v), 2) for v in disc)
    if len(disc) != 3 or not disc[2] > 2:
        raise InputError(f"the bubble's disc must be (cx, cy, r) with r > 2 pixels, got {disc}")
    return disc, warnings, (given is None) if opts.fit_disc is None else bool(opts.fit_disc)


#: The sources of a view that a fit varies (:func:`~bubblefit.inverse._view.fit_divergence`
#: refits the photo through views of these sources): rendered through a
#: :class:`~bubblefit.model.geometry.DivergentCamera` whose divergence is the held value
#: ``divergence`` (:attr:`~bubblefit.model.render.Params.view`), data to the compiled
#: programs, not a part of them. A stated view renders through its pinhole.
VARIED_VIEWS = ("fitted", "assumed")


def setup(photo, env, opts: FitOptions, background, init, scene, saturated_in, decided=None) -> Setup:
    """Validate the inputs, decide the effects (unless ``decided`` gives ``(fx, decisions)``),
    lay out the parameters and build the photo's fit level."""
    photo, background = _check_inputs(photo, env, background)
    vals, held0 = defaults(scene, init, opts)
    lights = scene.point_lights() if scene is not None else ()
    persp = _perspective(scene, photo)
    disc, warnings, fit_disc = (None, [], False) if persp else _disc(scene, opts, photo, background)
    if persp is None and opts.view is not None and opts.view.kind == "perspective":
        # the pinhole the field of view and the disc fix; the sphere's rays then need no disc
        if opts.view.source in VARIED_VIEWS:  # one compiled program for every view tried
            persp = DivergentCamera(photo.shape[1], photo.shape[0], *disc), (0.0, 0.0, 0.0), 1.0
            vals["divergence"] = divergence(opts.view.fov_deg)
        else:
            persp = perspective_from_disc(disc, photo.shape[1], photo.shape[0], opts.view.fov_deg)
        disc, fit_disc = None, False
    if saturated_in is not None and np.shape(saturated_in) != photo.shape[:2]:
        raise InputError(f"the saturation mask is {np.shape(saturated_in)}, the photo is "
                         f"{photo.shape[1]}x{photo.shape[0]}")
    frame = analysis_frame(photo, background, saturation_mask(photo, opts.noise.saturation, saturated_in), disc, opts)
    del photo, background  # from here on, only the analysed frame
    H, W = frame.photo.shape[:2]
    camera, center, radius = persp or (OrthographicCamera(W, H, *frame.disc), (0.0, 0.0, 0.0), 1.0)
    # The one place the fit's colour, dispersion and pixel sampling enter: every render
    # (search, local solves, map, final image) starts from these configurations.
    colour = colour_settings(scene, opts, vals["n_film"])
    if colour.film_rgb != "spectral" and opts.model == "paper":
        warnings = [*warnings, f"film_rgb {colour.film_rgb} is ignored: the paper model (eq. 11) colours its "
                               "films with eq. (10)'s factor"]
    if decided is None:
        settings, quadrature = _settings(scene, opts), None
        if "spectral" not in settings:  # the quadrature the films of the searched range need
            bounces = settings.get("bounces", 3)  # "auto": as many as it may ask for
            basis, quadrature = _quadrature(opts, vals, colour, bounces if isinstance(bounces, int) else 8)
            settings["spectral"] = {"method": basis.method, "samples": basis.samples}
        fx, decisions = _decide(opts, vals, env, frame.background, settings, camera, lights)
        if quadrature is not None:
            decisions = [quadrature if d.effect == "spectral" and d.simulated else d for d in decisions]
    else:
        fx, decisions = decided
    check_harmonic(fx.spectral, opts.thickness, False, where="fit")
    fx = _coloured(fx, colour)
    footprint, why = compact_source(env) if opts.pixel_footprint is None else (
        bool(opts.pixel_footprint), "as asked (--pixel-footprint / --no-pixel-footprint)")
    decisions = [*(d for d in decisions if d.effect != "pixel footprint"), Decision("pixel footprint", footprint, why)]
    map_cfg = RenderConfig(effects=fx, camera=camera, center=center, radius=radius, point_lights=tuple(lights),
                           dispersion=colour.n_film if isinstance(colour.n_film, Cauchy) else None,
                           samples_per_pixel=colour.samples_per_pixel, pixel_footprint=footprint,
                           film_rgb=colour.film_rgb)
    table = _table(opts, fx, held0, fit_disc)
    if fit_disc and init and init.get("disc") is not None and all(n in table.free for n in DISC_PARAMETERS):
        vals.update(disc_start(disc, init["disc"]))  # a warm start's disc: where the last fit refined it
    # a map is fitted after a drainage profile: the local fits render the profile
    base_cfg = replace(map_cfg, effects=replace(fx, thickness=table.thickness_model))
    k_fit = opts.sizes.downsample or max(1, math.ceil(max(H, W) / opts.sizes.fit))
    k_search = max(k_fit, math.ceil(max(H, W) / opts.sizes.search))
    lev_fit = make_level(k_fit, base_cfg, frame.photo, frame.sigma, frame.background, frame.saturated, opts.rim,
                         frame.bg_sigma, float(vals.get("divergence", 0.0)))
    if lev_fit.mask.sum() < 10:
        raise InputError("fewer than 10 usable pixels on the bubble (disc too small, or saturated)")
    pair = check_pair(frame, lev_fit)  # a swapped pair or another scene is refused before any solve
    search_table = replace(table, free=tuple(n for n in table.free if n not in DISC_PARAMETERS))
    return Setup(frame.photo, frame.background, vals, table, search_table, fx, decisions, base_cfg, map_cfg, disc, frame.sigma,
                 frame.saturated, k_search, lev_fit, frame, warnings, colour, pair,
                 map_start=map_start(init, frame.photo.shape[:2]))


#: The keys of a warm start (``init``) that carry the previous frame's thickness map: the
#: map (h, w) in nm and the drainage profile ``(top, bottom, exponent)`` it was fitted over.
MAP_START_KEYS = ("map", "map_profile")


def map_start(init, shape) -> tuple | None:
    """``(map, profile)`` of a warm start that carries a thickness map of the analysed
    frame's ``shape`` (:data:`MAP_START_KEYS`), else None. The map starts the next frame's
    map (:func:`bubblefit.inverse._maps.fit_map`): a film's thickness changes little
    between the frames of a sequence."""
    if not init or init.get("map") is None or init.get("map_profile") is None:
        return None
    tmap = np.asarray(init["map"], np.float64)
    prof = tuple(float(v) for v in init["map_profile"])
    if tmap.shape != tuple(shape) or len(prof) != 3 or not all(math.isfinite(v) for v in prof):
        return None
    return tmap, prof
