"""``bubblefit fit PHOTO --envmap ENV [...]``: recover t, r_d, r_s, roughness and thickness.

See :func:`bubblefit.inverse.fit.fit_photo` for the method. Prints each parameter with its
standard error and a summary line (ok, reduced chi^2, the disc); ``--json`` writes the
result of docs/design.md (``params``, ``stderr``, ``converged``, ``ok``, ``warnings``,
``reduced_chi2``, ``disc``, ``covariance``, ``iterations``, ``residual_rms``, ``time_s``
and more); ``-o PREFIX`` writes ``PREFIX_render.exr``, ``PREFIX_residual.exr`` and, for a
drainage profile or a map, ``PREFIX_thickness.exr`` (nm, NaN outside the bubble; its PNG
has a colour bar in nm), for a map also ``PREFIX_thickness_stderr.exr``. A fit that is
not ``ok`` says why (and exits 1 with ``--strict``).
"""

from __future__ import annotations

import argparse
import json
import os
import math

import numpy as np

from ..errors import ComputationError, InputError
from .fit_cap import run_cap
from .fit_planar import run_planar

NAME = "fit"


def register(sub):
    from .common import input_file, output_file, output_prefix
    from .view_options import add_view_options
    from ..model.modes import MODEL_CHOICES, THICKNESS_KINDS  # no JAX: --help stays fast

    p = sub.add_parser(
        NAME, help="fit the bubble model to a photo (t, r_d, r_s, roughness, film thickness)",
        description="Recover the transmission t, the diffuse/specular split, Ward's roughness and the film "
                    "thickness (one value, a drainage profile or a per-pixel map) from a linear photo of a "
                    "bubble and its environment map, with standard errors.")
    p.add_argument("photo", metavar="PHOTO", type=input_file, help="photo of the bubble (EXR/HDR linear; PNG/JPEG/TIFF sRGB)")
    p.add_argument("--envmap", type=input_file, help="environment map (equirectangular, linear EXR/HDR), aligned "
                                    "with the camera (it looks along -z of the map's frame); required for a bubble, "
                                    "not for a flat film ([film] shape = \"plane\" in the scene)")
    p.add_argument("--envmap-convention", choices=("mitsuba", "texel-centre"), default=None,
                   help="where the map's texel rows sit: mitsuba (row i at v = i/(H-1), bubblefit's and Mitsuba 3's) "
                        "or texel-centre (v = (i+1/2)/H: a map made for Blender or PBRT) [mitsuba; a dish scene's "
                        "[environment] convention]")
    p.add_argument("--reference-region", metavar="X0,Y0,X1,Y1=NM",
                   help="flat films: a region (pixels, half-open) of known thickness NM that fixes the "
                        "interference order of the map")
    p.add_argument("--background", metavar="BEFORE", type=input_file, help="photo of the same view without the bubble")
    cal = p.add_mutually_exclusive_group()
    cal.add_argument("--calibration", metavar="CAL.json", type=input_file, help="output of `bubblefit calibrate` (starting t, disc)")
    cal.add_argument("--t", type=float, help="starting transmission fraction t (0 < t < 1)")
    p.add_argument("--scene", metavar="SCENE.toml", type=input_file,
                   help="scene file: its camera (orthographic disc or perspective, response, white balance, "
                        "samples per pixel), n_film (with dispersion), illuminant, effects, and every value its "
                        "[bubble] table sets, which is held fixed; the flags below override it")
    p.add_argument("--thickness", choices=THICKNESS_KINDS, default="constant",
                   help="thickness model (default: constant)")
    p.add_argument("--model", choices=MODEL_CHOICES, default=None,
                   help="forward model: paper, physical, or auto (the model that explains the paper model's "
                        "search image better first, the other one when it does not explain the photo; "
                        "default: the scene's, else auto)")
    p.add_argument("--disc", metavar="CX,CY,R", help="the bubble's disc in pixels (default: detected; a disc "
                                                      "found is refined with the fit, one given is not)")
    p.add_argument("--refine-disc", action="store_true",
                   help="refine the disc given by --disc or the scene too (it is then the start)")
    p.add_argument("--thickness-range", metavar="MIN,MAX", default="50,2000", help="searched thickness, nm [50,2000]")
    p.add_argument("--hold", metavar="NAMES", default="",
                   help="comma-separated parameters held at their starting values (t, f, r_d, r_s, roughness, "
                        "thickness_nm, exposure, rotation_deg, top_nm, bottom_nm, exponent; disc: the disc as found)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[],
                   help="a parameter's starting value (t, f, r_d, r_s, roughness, thickness_nm, exposure, "
                        "rotation_deg, top_nm, bottom_nm, exponent); repeat for several, --hold NAME to hold it")
    p.add_argument("--free-split", action="store_true", help="fit r_d and r_s freely instead of r_d + r_s = 1 - t")
    p.add_argument("--fit-rotation", action="store_true", help="also fit the environment's rotation about +y")
    p.add_argument("--max-steps", type=int, default=None, help="Levenberg-Marquardt step limit")
    p.add_argument("--json", metavar="OUT", type=output_file, help="write the result as JSON")
    p.add_argument("-o", "--output", metavar="PREFIX", type=output_prefix, help="write PREFIX_render.exr, PREFIX_residual.exr "
                                                             "(and PREFIX_thickness.exr) with PNG previews")
    p.add_argument("--explain", action="store_true", help="print which effects are simulated or skipped, and why")
    p.add_argument("--strict", action="store_true", help="exit with status 1 when the fit did not converge")
    p.add_argument("--calibrate-camera", action="store_true",
                   help="also fit the camera response's coefficients with the film, from the stated (or default) "
                        "response; needs a film spanning several interference orders, e.g. --thickness drainage "
                        "(docs/cameras.md)")
    add_model_options(p)
    add_view_options(p)
    from .photo_args import add_photo_options

    add_photo_options(p)
    p.set_defaults(func=run)


def add_model_options(p) -> None:
    """The forward model's light, camera and film options of ``fit`` and ``fit-sequence``:
    ``--illuminant``, ``--camera-response`` (as ``render``), ``--n-film``/``--cauchy`` (as
    ``chart``), ``--samples-per-pixel`` and ``--film-rgb``; each overrides the scene's value; and
    ``--colour-check``, what a failed test of the camera response does."""
    from .common import add_colour_options, add_film_rgb_option, add_index_options

    add_colour_options(p)
    add_index_options(p, default="the scene's, else 1.4")
    add_film_rgb_option(p)
    p.add_argument("--samples-per-pixel", type=int, default=None, metavar="N",
                   help="rays per rendered pixel, a square number (1, 4, 9, ...): each pixel is the mean over its "
                        "area; default the scene's [camera] samples_per_pixel, else 1")
    p.add_argument("--pixel-footprint", action=argparse.BooleanOptionalAction, default=None,
                   help="average each film's map lookup over the pixel's footprint (ray differentials), as a "
                        "camera integrates the glints of a sun or lamp; default: on when the map holds a compact "
                        "bright source (its peak over 100x its mean), off otherwise (docs/trust.md)")
    p.add_argument("--colour-check", choices=("decide", "warn"), default="decide",
                   help="when the stated camera response cannot produce the photo's hues: decide (the fit is not "
                        "ok, with the reason) or warn (the reason only) [decide] (docs/cameras.md)")


def load_envmap(path: str, convention: str | None = None):
    """Read the environment map for a fit (:func:`~bubblefit.model.scene.read_map_file`, its
    rows in ``convention``, ``"mitsuba"`` by default), refuse a map without light (nothing
    to fit against) and warn of one stored in integers."""
    from ..io.images import ImageWarning
    from ..model.scene import read_map_file

    read = read_map_file(path, convention=convention or "mitsuba")
    env, bits = read.env, read.bit_depth
    if not np.any(np.asarray(env.pixels) > 0):
        raise InputError(f"environment map {path} is black or unreadable")
    if bits < 32:
        import warnings

        warnings.warn(f"environment map {path} has {bits} bits per channel: its sun and lamps are clipped, and the fitted "
                      "exposure and reflectance absorb the missing light; use a linear HDR map (EXR, HDR)",
                      ImageWarning, stacklevel=2)
    return env


#: Largest pixel coordinate or radius a disc may have: the side of an image at the pixel
#: limit (:data:`bubblefit.io.images.MAX_PIXELS`) is far below it, and numbers beyond
#: would print with hundreds of digits.
MAX_PIXEL_COORDINATE = 1e6

#: Largest calibration file read (``bubblefit calibrate`` writes about 2 KB); a larger
#: one (``/dev/zero``, a photo given by mistake) is refused before it fills the memory.
MAX_CALIBRATION_BYTES = 1024 * 1024


def read_calibration(path: str) -> tuple[float, tuple | None, tuple | None]:
    """``(t, disc or None, image_size or None)`` from a ``bubblefit calibrate`` JSON
    (``image_size`` [w, h] of the calibration frame, when it records it)."""
    try:
        with open(path, "rb") as fh:
            text = fh.read(MAX_CALIBRATION_BYTES + 1)
        if len(text) > MAX_CALIBRATION_BYTES:
            raise InputError(f"calibration {path} is larger than {MAX_CALIBRATION_BYTES // 1024} KiB: "
                             "not the output of bubblefit calibrate")
        data = json.loads(text.decode("utf-8"))
    except OSError as exc:
        raise InputError(f"cannot read calibration {path}: {exc.strerror}") from None
    except ValueError:  # JSON and UTF-8 errors
        raise InputError(f"calibration {path} is not valid JSON") from None
    t = data.get("t") if isinstance(data, dict) else None
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not 0 < t < 1:
        raise InputError(f"calibration {path} has no valid 't' (a number with 0 < t < 1)")
    disc = None
    b = data.get("bubble")
    if isinstance(b, dict) and all(isinstance(b.get(k), (int, float)) for k in ("cx", "cy", "r")):
        disc = (float(b["cx"]), float(b["cy"]), float(b["r"]))
        if not all(abs(v) < MAX_PIXEL_COORDINATE for v in disc) or disc[2] <= 0:
            raise InputError(f"calibration {path} has an impossible disc: centre and radius must be pixel "
                             f"coordinates below {MAX_PIXEL_COORDINATE:g} and the radius positive")
    size = data.get("image_size")
    if not (isinstance(size, (list, tuple)) and len(size) == 2 and all(isinstance(v, int) for v in size)):
        size = None
    return float(t), disc, None if size is None else (int(size[0]), int(size[1]))


def fit_option_values(args) -> dict:
    """The :class:`~bubblefit.inverse.fit.FitOptions` values that ``fit`` and ``fit-sequence`` read
    the same way: starting t and disc (``--calibration``, ``--t``, ``--disc``), thickness
    kind and range, held parameters and the step limit. One-line errors for bad values."""
    from ..inverse import ParameterSetting, SolverSettings, parse_setting
    from .common import model_option_values, parse_floats

    t_init, disc, cal_disc, cal_size = None, None, None, None
    if args.calibration:  # its disc is checked against each photo (FitOptions.calibration_disc)
        t_init, cal_disc, cal_size = read_calibration(args.calibration)
    if args.t is not None:
        if not 0 < args.t < 1:
            raise InputError(f"--t must lie in (0, 1), got {args.t}")
        t_init = args.t
    if args.disc:
        disc = parse_floats(args.disc, 3, "--disc")
        if disc[2] <= 0:
            raise InputError(f"--disc radius must be positive, got {args.disc!r}")
        if not all(abs(v) < MAX_PIXEL_COORDINATE for v in disc):
            raise InputError(f"--disc must be pixel coordinates below {MAX_PIXEL_COORDINATE:g}, got {args.disc!r}")
    lo, hi = parse_floats(args.thickness_range, 2, "--thickness-range")
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise InputError(f"--thickness-range must be two finite thicknesses in nm, got {args.thickness_range}")
    measured = () if t_init is None else (ParameterSetting("t", t_init, measured=True),)  # replaces a scene's t
    held = tuple(ParameterSetting(h.strip(), hold=True) for h in args.hold.split(",") if h.strip())
    kw = dict(thickness=args.thickness, disc=disc, fit_disc=True if getattr(args, "refine_disc", False) else None,
              thickness_range=(lo, hi), calibration_disc=cal_disc, calibration_size=cal_size,
              parameters=measured + tuple(parse_setting(s) for s in getattr(args, "set", None) or ()) + held)
    if args.max_steps is not None:
        if args.max_steps < 1:
            raise InputError("--max-steps must be at least 1")
        kw["solver"] = SolverSettings(max_steps=args.max_steps)
    kw |= model_option_values(args)
    return kw


def output_paths(args) -> list[str]:
    """Every file ``fit -o PREFIX`` may write: ``PREFIX_{render,residual,thickness,thickness_stderr}.exr`` and
    their PNG previews (for :func:`~bubblefit.cli.common.guard_outputs`)."""
    from ..io.atomic import preview_path

    if not args.output:
        return []
    names = ["render", "residual"] + (["thickness"] if args.thickness != "constant" else [])
    names += ["thickness_stderr"] if args.thickness == "map" else []
    exrs = [f"{args.output}_{n}.exr" for n in names]
    return exrs + [str(preview_path(p)) for p in exrs]


#: Fewest pixels on each side of a photo that can hold a bubble for the fit: the disc's
#: detection smooths with a Gaussian of a few pixels and needs 50 pixels of bubble.
MIN_PHOTO_SIDE = 16


def check_photo_size(img, path) -> None:
    """Refuse a photo too small (on either side) to hold a bubble: :data:`MIN_PHOTO_SIDE`."""
    h, w = img.pixels.shape[:2]
    if min(h, w) < MIN_PHOTO_SIDE:
        raise InputError(f"photo {path} is {w}x{h} pixels: too small to hold a bubble "
                         f"(at least {MIN_PHOTO_SIDE} pixels on each side)")


def _bits(img) -> int | None:
    return None if img.linear_file else int(img.bit_depth)


def build_fit_options(args, scene, bits: int | None, view=None, photosite_share=None):
    """:class:`~bubblefit.inverse.fit.FitOptions` of ``fit`` and ``fit-sequence``, built in
    this one place so that a sequence of one frame is fitted as ``fit`` fits the photo:
    :func:`fit_option_values`, the model (``--model``, else the scene's, else ``auto``),
    the photo's bit depth for the noise model (``NoiseSettings.bits``) and, for a demosaiced
    RAW file, its channels' share of the photosites (``NoiseSettings.photosite_share``), and
    ``fit``'s own flags where the command has them."""
    from ..inverse.fit import FitOptions, NoiseSettings

    model = args.model or (scene.table("effects").get("model", "auto") if scene is not None else "auto")
    noise = NoiseSettings(bits=bits, photosite_share=None if photosite_share is None else tuple(photosite_share))
    kw = dict(fit_option_values(args), model=model, noise=noise, view=view)
    for flag in ("free_split", "fit_rotation", "calibrate_camera"):
        if hasattr(args, flag):
            kw[flag] = getattr(args, flag)
    return FitOptions(**kw)


def run(args) -> int:
    """``fit``: the command of the fit the scene file asks for
    (:func:`~bubblefit.model.planar_scene.scene_fit`; a floating bubble without one), from
    :data:`COMMANDS`."""
    from ..model.planar_scene import scene_fit

    return COMMANDS[scene_fit(args.scene) if args.scene else "bubble"](args)


def run_bubble(args) -> int:
    """``fit`` of a floating bubble: read the photo, its background and map, fit
    (:func:`~bubblefit.inverse.fit.fit_photo`), print, write the maps and the JSON."""
    from ..inverse.fit import fit_photo
    from ..io.atomic import output_set
    from ..io.camera_files import read_photo, reading_record
    from ..io.images import preview_path, write_image
    from ..progress import stage
    from ..model.scene import load_scene
    from .common import guard_args, scene_inputs, write_fit_images, write_json
    from .photo_args import photo_reading
    from .view_options import check_view_args, view_from_args

    if not args.envmap:
        raise InputError("fit: --envmap is required for a bubble (a flat film's scene says [film] shape = \"plane\")")
    reading = photo_reading(args)
    scene = load_scene(args.scene) if args.scene else None
    guard_args(args, inputs=scene_inputs(scene) if scene is not None else [], outputs=output_paths(args))
    fit_option_values(args)  # bad values refused before any photo is read
    check_view_args(args)
    with stage("reading the photo and the environment map"):
        photo = read_photo(args.photo, reading, dtype=np.float32)  # the fit's arithmetic is float32
        photo_record = reading_record(photo)
        check_photo_size(photo, args.photo)
        env = load_envmap(args.envmap, args.envmap_convention)
    background = None
    if args.background:
        bimg = read_photo(args.background, reading, dtype=np.float32, what="background")
        if bimg.pixels.shape != photo.pixels.shape:
            raise InputError(f"the background {args.background} is {bimg.pixels.shape[1]}x{bimg.pixels.shape[0]}, "
                             f"the photo is {photo.pixels.shape[1]}x{photo.pixels.shape[0]}")
        background = bimg.pixels
    view = view_from_args(args, photo.metadata, photo.pixels.shape[1], photo.pixels.shape[0])
    options = build_fit_options(args, scene, _bits(photo), view,
                                (photo.metadata.get("raw") or {}).get("photosite_share"))
    with stage(f"fitting {photo.pixels.shape[1]}x{photo.pixels.shape[0]} ({options.thickness} thickness, "
               f"{options.model} model)"):
        result = fit_photo(photo.pixels, env, options=options, background=background, scene=scene,
                           saturated=photo.saturated)
    out = result.to_json()
    out["photo"] = str(args.photo)
    out["inputs"] = {k: None if v is None else os.path.abspath(v) for k, v in
                     (("envmap", args.envmap), ("background", args.background), ("scene", args.scene),
                      ("calibration", args.calibration))}
    out["photo_reading"] = photo_record
    out["envmap_convention"] = args.envmap_convention or "mitsuba"
    if args.explain:
        print("effect               state     [setting] reason")
        for d in result.effects:
            print(d.line())
    print(result.report())
    response = None  # the camera response fitted with the film, as the CSV written beside the maps
    if result.camera_calibration is not None:
        from ..inverse.self_calibration import response_csv, summary

        print(summary(result.camera_calibration))
        if args.output:
            response = response_csv(result.camera_calibration)
    with output_set():  # the maps and the JSON replace the earlier ones together, or none does
        if args.output:
            with stage("writing the maps"):
                out["outputs"] = write_fit_images(args.output, result, write_image, preview_path)
                if response is not None:
                    from ..io.atomic import write_text

                    write_text(f"{args.output}_response.csv", response)
                    out["outputs"]["response"] = f"{args.output}_response.csv"
        if args.json:
            write_json(args.json, out)
    if args.strict and not result.ok:
        raise ComputationError("the fit is not ok: " + ("; ".join(result.warnings) or result.message))
    return 0


#: ``fit``'s command for each fit a scene file may ask for (:func:`~bubblefit.model.planar_scene.scene_fit`).
COMMANDS = {"bubble": run_bubble, "cap": run_cap, "plane": run_planar}
