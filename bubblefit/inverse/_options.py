"""What a fit is told: :class:`FitOptions` and the settings records it groups.

What a fit returns is :class:`~bubblefit.inverse._result.FitResult`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import InputError
from ..model.modes import MODEL_CHOICES, THICKNESS_KINDS, Model, ModelChoice, ThicknessKind, in_words
from ._parameters import ParameterSetting

__all__ = ["ThicknessModel", "ForwardModel", "ModelChoice", "FitOptions", "NoiseSettings", "MapSettings",
           "JudgeSettings", "SolverSettings", "ImageSizes"]

#: How the film's thickness varies over the bubble: :data:`bubblefit.model.modes.ThicknessKind`
#: under the name the fit's API has used (its values are ``thickness_nm``,
#: ``top_nm``/``bottom_nm``/``exponent`` or a per-pixel map in nm).
ThicknessModel = ThicknessKind
#: The forward model fitted: :data:`bubblefit.model.modes.Model` (``docs/design.md``, "Two model variants").
ForwardModel = Model

@dataclass(frozen=True)
class NoiseSettings:
    """The photo's noise model (:func:`~bubblefit.inverse._observation.noise_sigma`) and
    the level at which its values are clipped.

    Attributes
    ----------
    read : float
        Read noise: the standard deviation of a linear pixel value at zero signal.
    shot : float
        Shot noise: the variance per unit of linear signal (Poisson).
    bits : int or None
        Bits per channel of an integer sRGB file (its quantisation step is noise too);
        None for a float photo.
    photosite_share : tuple or None
        For a photo demosaiced from a colour filter mosaic (a RAW file read by
        :func:`bubblefit.io.camera_files.read_raw`), the fraction of the photosites behind
        each of R, G, B (1/4, 1/2, 1/4 for a Bayer sensor): a mean over ``n`` pixels then
        holds the noise of ``share * n`` photosites, which the colour check uses
        (:mod:`bubblefit.inverse.colour_check`). None: every pixel measured each channel.
    saturation : float
        Photo values at or above this (in files with a maximum of 1) are clipped.
    """

    read: float = 2e-3
    shot: float = 2e-4
    bits: int | None = 8
    photosite_share: tuple | None = None
    saturation: float = 0.995


@dataclass(frozen=True)
class ImageSizes:
    """The resolutions a fit works at: the frame it analyses
    (:func:`~bubblefit.inverse._observation.analysis_frame`), the local fit's image and the
    global search's image (:func:`~bubblefit.inverse._setup.setup`).

    Attributes
    ----------
    analysis : int
        A photo whose larger side exceeds this is cropped to the bubble (1.15 radii around
        its disc) and block-averaged so that the crop's larger side is at most this,
        before anything else: memory stays bounded by this size, not the photo's. The
        fit's images (render, residual, maps) are then in that frame
        (:attr:`FitResult.frame`); the disc is always reported in the photo's pixels.
    fit, search : int
        Larger side of the local fit's and the global search's images (pixels).
    downsample : int or None
        Factor of the image the local fit runs on (None: so that its larger side is at
        most ``fit``).
    """

    analysis: int = 1024
    fit: int = 96
    search: int = 48
    downsample: int | None = None


@dataclass(frozen=True)
class MapSettings:
    """The priors of a thickness map (:func:`~bubblefit.inverse._maps.fit_map`).

    Attributes
    ----------
    prior_nm : float
        Width of the prior tying a thickness map to the fitted profile.
    smoothness_nm : float
        The smoothness prior: the standard deviation (nm) of the difference between
        neighbouring pixels' thicknesses at the photo's resolution. Smaller values smooth
        more; a film's real features (a 40 nm bump a few pixels wide) change by a few nm
        per pixel and survive the default.
    """

    prior_nm: float = 150.0
    smoothness_nm: float = 8.0


@dataclass(frozen=True)
class JudgeSettings:
    """How a fit is judged (:func:`~bubblefit.inverse._verdict.verdict`) and what its
    standard errors carry beyond the photo's noise (:mod:`bubblefit.inverse._uncertainty`).

    Attributes
    ----------
    model_error : float
        The model-error floor: a fraction of each pixel's value added in quadrature to its
        noise when judging whether the photo is explained (``ok``). Renderers disagree by
        about this much on the same film (experiments/validation/cross_check.py on development cases cyc_const500, cyc_drain_lin_sunrise, cyc_bump_city, mts_thick_courtyard, mts_thick_sunrise; spectral sampling, observer tables, the rim's
        filtering), so a fit is not failed for differences of that size.
    thickness_model_error_nm : float
        Added in quadrature to the standard error of every fitted thickness (and of each
        pixel of a map): the scatter of bubblefit's thicknesses against independent
        renderers on the validation set's constant films (development cases ref_const300, ref_const620, ref_const1200, ref_const450, cyc_const500: experiments/validation/split.toml), RMS 0.6 nm, which no estimate from the photo's
        residual shows (:mod:`bubblefit.inverse._uncertainty`). 0 gives the photo's own.
    ok_chi2 : float
        A fit is ``ok`` only when the reduced chi^2 with the model-error floor is at most
        this.
    colour_check : str
        What the colour check (:mod:`bubblefit.inverse.colour_check`: can the stated camera
        response produce the photo's hues?) does when it fails: ``"decide"`` makes the fit
        not ``ok``, with its reason among the warnings; ``"warn"`` adds the reason and
        leaves ``ok`` to the other tests.
    """

    model_error: float = 0.03
    thickness_model_error_nm: float = 0.6
    ok_chi2: float = 3.0
    colour_check: str = "decide"

    def __post_init__(self):
        if self.colour_check not in COLOUR_CHECK_MODES:
            raise ValueError(f"colour_check must be one of {', '.join(COLOUR_CHECK_MODES)}, got {self.colour_check!r}")


#: What a failed colour check does (:attr:`JudgeSettings.colour_check`).
COLOUR_CHECK_MODES = ("decide", "warn")


@dataclass(frozen=True)
class SolverSettings:
    """The global thickness search (:mod:`bubblefit.inverse.search`) and the local
    Levenberg-Marquardt solves (:func:`~bubblefit.inverse._local.solve_local`) of a fit.

    Attributes
    ----------
    max_steps : int
        Levenberg-Marquardt's step limit of the final solve.
    rtol, atol : float
        Its tolerances (optimistix' Cauchy test: every unconstrained coordinate and every
        whitened residual changes by less than ``atol + rtol |value|`` in a step). Looser
        tolerances (1e-4) stop drainage fits early, far from the optimum
        (tests/test_fit.py::test_drainage_and_map).
    search_step_nm : float
        Thickness grid step of the global search.
    candidates, search_steps : int
        Local minima of the search refined, each with at most ``search_steps`` LM steps
        on the search image.
    robust_scale : float
        Pseudo-Huber scale in noise sigmas.
    """

    max_steps: int = 80
    rtol: float = 1e-5
    atol: float = 1e-6
    #: The global search's grid cost (each thickness with its best gain, the other
    #: parameters at their starts) can rank a pale thick film's neighbour orders above its
    #: own: on 48 px Nikon photos of a constant 1500 nm film (experiments/order_ambiguity.py,
    #: seeds 35 and 36) the true order was the grid's third minimum (1506 nm, after 1730 and
    #: 1950 nm), and refined it has the lowest cost by 400 (chi^2 1997 against 2413). Four
    #: candidates reach it; the refinement, not the grid, then picks the order.
    candidates: int = 4
    search_steps: int = 20
    search_step_nm: float = 4.0
    robust_scale: float = 3.0


@dataclass(frozen=True)
class FitOptions:
    """Static settings of a fit.

    Attributes
    ----------
    thickness : ThicknessKind
        The thickness model: ``constant`` | ``drainage`` | ``map``.
    model : ModelChoice
        ``paper`` | ``physical`` forward model, or ``auto`` (the default, as on the command
        line): the paper model's global search, then the model that explains the search
        image better solved first (the physical one from the search's start) and, when
        it does not explain the photo (reduced chi^2 with the model-error floor above
        ``judge.ok_chi2``; for the physical model solved first, that reduced chi^2 with
        each pixel's share capped at an outlier's above it), the other one; the fit that
        explains the photo better is returned (:func:`bubblefit.inverse.fit.fit_photo`).
    fit_rotation : bool
        Also fit the environment's rotation about +y.
    free_split : bool
        Fit ``r_d`` and ``r_s`` freely instead of ``r_d + r_s = 1 - t`` (eq. 14).
    disc : tuple or None
        ``(cx, cy, r)`` of the bubble in pixels, or None to detect it.
    fit_disc : bool or None
        Refine the disc in the local solve: its centre and radius are fitted with the
        other parameters (:data:`~bubblefit.inverse._parameters.DISC_PARAMETERS`), and the
        result's disc is the refined one, with standard errors. None (default): refine a
        disc found in the photo (or read from a calibration), use a disc given
        (``disc``, the scene's camera) as it is; True: refine a given disc too (it is
        then the start); False, or ``ParameterSetting("disc", hold=True)`` (``--hold disc``): never.
    thickness_range : tuple
        (min, max) nm searched (and used to decide the effects).
    sizes : ImageSizes
        The resolutions of the analysed frame, the local fit and the global search.
    solver : SolverSettings
        The global search's grid and refinement, and the local solver's limits.
    noise : NoiseSettings
        The photo's noise model and clipping level.
    rim : float
        Fraction of the disc radius used (the rim mixes with the background).
    map : MapSettings
        The priors of a thickness map (``thickness = "map"``).
    parameters : tuple
        :class:`~bubblefit.inverse._parameters.ParameterSetting` s: a starting value,
        whether it is held and whether it is measured, per parameter (``--set NAME=VALUE``,
        ``--hold NAME``, ``--t``, a calibration's ``t``; :func:`~bubblefit.inverse._parameters.starts`),
        applied in order after a warm start. A starting value never replaces a value the
        scene file sets; a measured one does (it stays held). The starting roughness also
        decides whether filtering is simulated.
    effects : tuple
        Extra ``[effects]`` settings as ``((key, value), ...)``.
    calibration_disc : tuple or None
        ``(cx, cy, r)`` from ``bubblefit calibrate``: used (instead of detecting the disc)
        only when the photo has ``calibration_size`` (when known) and the disc found in the
        photo agrees with it; otherwise the detected disc is used and a warning says why.
    calibration_size : tuple or None
        ``(width, height)`` of the calibration frame, when the calibration JSON records it.
    judge : JudgeSettings
        How the fit is judged: its model-error floors and the chi^2 that counts as explained.
    disc_model_error : float
        Added in quadrature to the standard errors of a refined disc, in radii: on the
        orthographic validation photos (radius 48-57 px; development cases ref_const300, ref_drain_lin_courtyard, ref_drain_lin_city, ref_bump_sunrise, cyc_const500, cyc_bump_city, mts_thick_sunrise in experiments/validation/split.toml) the refined disc was 0.02-0.18 px
        from the truth (RMS 0.08 px per centre coordinate, 0.11 px in radius, about 0.2 %
        of the radius) while the noise said 0.01-0.02 px.
    illuminant, camera_response, white_balance : str, str, str or tuple, or None
        The light's spectrum, the camera's channel responses and its white balance
        (:mod:`bubblefit.optics.spectral`); None: the scene's (``[lighting] illuminant``,
        ``[camera] response``, ``white_balance``), else ``D65``, ``srgb``, ``illuminant``.
    n_film : float, Cauchy, str or None
        The film's index (:mod:`bubblefit.optics.dispersion`: a number, a Cauchy law or a
        preset); None: the scene's ``[bubble] n_film``, else 1.4. A law's dispersion is
        rendered everywhere the fit evaluates the model; it is never fitted.
    samples_per_pixel : int or None
        Rays per rendered pixel (a square number, :class:`~bubblefit.model.render.RenderConfig`);
        None: the scene's ``[camera] samples_per_pixel``, else 1.
    film_rgb : str or None
        How the physical model colours each film
        (:attr:`~bubblefit.model.render.RenderConfig.film_rgb`): ``"spectral"`` (the physics
        a camera sees) or ``"clamped"`` (each film's RGB reflectance clamped to [0, 1], as
        Blender Cycles' thin film shades: for its renders, not photographs); None: the
        scene's ``[film] film_rgb``, else ``"spectral"``. The paper model ignores it.
    calibrate_camera : bool
        Free the camera response's coefficients (the spectral lobes' weights) together with
        the film, after the fit with the stated response, and report them with their
        covariance (JSON key ``camera_calibration``;
        :mod:`bubblefit.inverse.self_calibration`). A photo that does not determine them
        (a constant film) is not ``ok``, with the reason.
    pixel_footprint : bool or None
        Average each film's map lookup over the pixel's footprint (ray differentials,
        :attr:`~bubblefit.model.render.RenderConfig.pixel_footprint`). None: on when the map
        holds a compact bright source, a sun, a lamp or city lights
        (:func:`~bubblefit.inverse._setup.compact_source`), off otherwise.
    view : View or None
        The camera's view (:class:`~bubblefit.capture.view.View`: a field of view from an
        option or the photo's EXIF, :func:`~bubblefit.capture.view.resolve_view`). A
        perspective view builds the pinhole camera from the disc
        (:func:`~bubblefit.capture.view.perspective_from_disc`). None, or a view whose
        source is ``assumed``: the view's divergence fitted from the photo
        (:func:`~bubblefit.inverse._view.fit_divergence`), else orthographic or a
        plausible lens with the standard errors widened by what the other changes
        (:func:`~bubblefit.inverse.fit.fit_photo`). A scene file's
        camera is its own view.
    """

    thickness: ThicknessKind = "constant"
    model: ModelChoice = "auto"
    fit_rotation: bool = False
    free_split: bool = False
    disc: tuple | None = None
    fit_disc: bool | None = None
    thickness_range: tuple = (50.0, 2000.0)
    sizes: ImageSizes = ImageSizes()
    solver: SolverSettings = SolverSettings()
    noise: NoiseSettings = NoiseSettings()
    rim: float = 0.96
    map: MapSettings = MapSettings()
    effects: tuple = ()
    calibration_disc: tuple | None = None
    calibration_size: tuple | None = None
    judge: JudgeSettings = JudgeSettings()
    disc_model_error: float = 0.002
    illuminant: str | None = None
    camera_response: str | None = None
    white_balance: str | tuple | None = None
    n_film: object = None
    samples_per_pixel: int | None = None
    film_rgb: str | None = None
    pixel_footprint: bool | None = None
    calibrate_camera: bool = False
    parameters: tuple = ()
    view: object = None

    def __post_init__(self):
        from ..capture.view import View

        if self.view is not None and not isinstance(self.view, View):
            raise InputError(f"view must be a bubblefit.capture.view.View, got {self.view!r}")
        from ..model import samples_per_pixel, white_balance
        from ..optics.dispersion import parse_index

        if self.n_film is not None:  # a preset name becomes its law
            object.__setattr__(self, "n_film", parse_index(self.n_film, "n_film"))
        if self.white_balance is not None:
            object.__setattr__(self, "white_balance", white_balance(self.white_balance, "white_balance"))
        if self.samples_per_pixel is not None:
            samples_per_pixel(self.samples_per_pixel, "samples_per_pixel")
        if self.film_rgb not in (None, "spectral", "clamped"):
            raise InputError(f"film_rgb must be spectral or clamped, got {self.film_rgb!r}")
        for setting in self.parameters:
            if not isinstance(setting, ParameterSetting):
                raise InputError(f"parameters must be ParameterSetting records, got {setting!r}")
            setting.check()
        if self.thickness not in THICKNESS_KINDS:
            raise InputError(f"thickness must be {in_words(THICKNESS_KINDS)}, got {self.thickness!r}")
        if self.model not in MODEL_CHOICES:
            raise InputError(f"model must be {in_words(MODEL_CHOICES)}, got {self.model!r}")
        lo, hi = self.thickness_range
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise InputError(f"thickness range must be finite (nm), got {lo}..{hi}")
        if not 0 <= lo < hi:
            raise InputError(f"thickness range must be 0 <= min < max, got {lo}..{hi}")
        if hi > 20000:
            raise InputError(f"thickness range must end below 20000 nm (20 um), got {hi}")
