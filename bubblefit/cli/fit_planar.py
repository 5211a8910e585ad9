"""``bubblefit fit PHOTO --scene FILM.toml``: the thickness of a flat film or a gap.

Reached from ``fit`` when the scene's ``[film]`` says ``shape = "plane"``; the method is
:func:`bubblefit.inverse.planar.fit_planar`. Writes, with ``-o PREFIX``,
``PREFIX_thickness.exr`` and ``PREFIX_thickness_stderr.exr`` (nm, NaN off the film; PNG
previews with a colour bar in nm), ``PREFIX_render.exr`` and ``PREFIX_residual.exr``;
``--json`` the result (``ok``, ``warnings``, the parameters and their standard errors).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import ComputationError, InputError

#: Options of ``fit`` that belong to bubbles only: refused for a flat film, not ignored.
_BUBBLE_ONLY = ("envmap", "background", "calibration", "t", "disc", "fit_rotation")


def film_outputs(args) -> list[str]:
    """The files ``-o PREFIX`` writes for a film's fit (the maps, the render, the residual, their previews)."""
    from ..io.atomic import preview_path

    names = ["render", "residual", "thickness", "thickness_stderr"]
    outs = [f"{args.output}_{n}.exr" for n in names] if args.output else []
    return outs + [str(preview_path(p)) for p in outs]


def report_film_fit(args, result, photo_record: dict | None = None) -> int:
    """Print a film's fit, write its maps and JSON together (or none), exit as ``--strict`` says;
    ``photo_record``: how the photo was read (:func:`~bubblefit.io.camera_files.reading_record`)."""
    from ..io.atomic import output_set, preview_path
    from ..io.images import write_image
    from ..progress import stage
    from .common import write_fit_images, write_json

    print(result.report())
    out = result.to_json()
    out["photo"] = str(args.photo)
    if photo_record is not None:
        out["photo_reading"] = photo_record
    with output_set():  # the maps and the JSON replace the earlier ones together, or none does
        if args.output:
            with stage("writing the maps"):
                out["outputs"] = write_fit_images(args.output, result, write_image, preview_path)
        if args.json:
            write_json(args.json, out)
    if args.strict and not result.ok:
        raise ComputationError("the fit is not ok: " + "; ".join(result.warnings))
    return 0


def read_film_photo(args):
    """``(photo, record)``: the photo of a film's fit read as every command reads a camera's
    file (:func:`~bubblefit.io.camera_files.read_photo`: RAW development, ``--encoding``, the
    levels, ``--flat`` and ``--dark``), and the record of how it was read, for the JSON."""
    from ..io.camera_files import read_photo, reading_record
    from .photo_args import photo_reading

    photo = read_photo(args.photo, photo_reading(args), dtype=np.float64)
    return photo, reading_record(photo)


def run_planar(args) -> int:
    from ..inverse.planar import fit_planar
    from ..model.planar_scene import load_planar, parse_region
    from ..progress import stage
    from .common import guard_args

    for name in _BUBBLE_ONLY:
        if getattr(args, name, None):
            raise InputError(f"--{name.replace('_', '-')} applies to bubbles, not to a flat film's scene")
    scene = load_planar(args.scene)
    kind = args.thickness if args.thickness != "constant" or scene.thickness == "constant" else scene.thickness
    region = nm = None
    if args.reference_region:
        region, nm = parse_region(args.reference_region, scene.width, scene.height)
    guard_args(args, outputs=film_outputs(args))
    with stage("reading the photo"):
        photo, record = read_film_photo(args)
    if getattr(args, "flat", None) and scene.envelope == "auto":
        scene = replace(scene, envelope="none")  # the flat field has divided the lamp's envelope out
    with stage(f"fitting a flat film ({scene.stack.describe()}, {scene.light} light, {kind})"):
        result = fit_planar(photo.pixels[..., :3], scene, reference_region=region, reference_nm=nm, kind=kind,
                            clip_high=np.inf if photo.linear_file else 1.0)
    return report_film_fit(args, result, record)
