"""``bubblefit render SCENE.toml -o OUT.exr [--explain]``."""

from __future__ import annotations

import time

import numpy as np

from ..errors import InputError


def register(sub):
    p = sub.add_parser("render", help="render a scene file to a linear EXR and an sRGB PNG preview",
                       description="Render a bubble scene (TOML, see docs/design.md) to a linear EXR plus a PNG preview.")
    from .common import input_file, output_file

    p.add_argument("scene", type=input_file, help="scene file (TOML)")
    p.add_argument("-o", "--output", required=True, type=output_file, help="output image (.exr recommended; a .png preview is written beside it)")
    p.add_argument("--explain", action="store_true", help="print which effects are simulated or skipped, and why")
    p.add_argument("--tolerance", type=float, default=None, metavar="FRACTION",
                   help="largest change a skipped or cheapened effect may make to a pixel, as a fraction of what the "
                        "pixel shows (plus 0.1 x that fraction of the bubble's bright level); overrides the scene's "
                        "[effects] tolerance (default 0.01)")
    p.add_argument("--json", metavar="PATH", type=output_file, help="write timing and effect decisions as JSON")
    p.add_argument("--preview-exposure", type=float, default=None,
                   help="exposure of the PNG preview (default: automatic, the 99.5th percentile maps to 0.9)")
    from .common import add_colour_options, add_film_rgb_option

    add_colour_options(p)
    add_film_rgb_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io.atomic import output_set
    from ..io.images import preview_path, write_image
    from ..model.scene import load_scene, render_scene
    from ..progress import stage
    from .common import auto_exposure, guard_args, scene_inputs, write_json

    from ..optics import spectral
    from .common import colour_option

    from ..model.cap_scene import is_cap_file

    if is_cap_file(args.scene):   # a cap on a liquid, or a whole bubble under an area light
        from .render_film import run_film_render

        return run_film_render(args)
    with stage("reading the scene"):
        scene = load_scene(args.scene)
    if args.tolerance is not None:
        if not (np.isfinite(args.tolerance) and args.tolerance > 0):
            raise InputError(f"--tolerance must be a positive number, got {args.tolerance:g}")
        scene = scene.with_effects(tolerance=float(args.tolerance))
    ill = colour_option(args.illuminant, spectral.is_named_illuminant, "--illuminant")
    resp = colour_option(args.camera_response, spectral.is_named_response, "--camera-response")
    if ill is not None:
        scene.data.setdefault("lighting", {})["illuminant"] = ill
    if resp is not None:
        scene.data.setdefault("camera", {})["response"] = resp
    if args.film_rgb is not None:
        scene.data.setdefault("film", {})["film_rgb"] = args.film_rgb
    preview = preview_path(args.output)
    guard_args(args, inputs=scene_inputs(scene), outputs=[preview])
    t0 = time.perf_counter()
    with stage(f"rendering {scene.shape[1]}x{scene.shape[0]}"):
        img, decisions = render_scene(scene, explain=True)
    elapsed = time.perf_counter() - t0
    if not np.all(np.isfinite(img)):
        raise InputError("the render produced non-finite values; check the scene's values")
    exposure = args.preview_exposure if args.preview_exposure is not None else auto_exposure(img)
    with stage("writing"), output_set():
        write_image(args.output, img)
        write_image(preview, img * exposure)
    if args.explain:
        print("effect               state     [setting] reason (errors are shares of each pixel's budget)")
        for d in decisions:
            print(d.line())
    print(f"wrote {args.output} ({scene.shape[1]}x{scene.shape[0]}, {elapsed:.2f} s)")
    if args.json:
        write_json(args.json, {"output": str(args.output), "time_s": elapsed, "preview_exposure": exposure,
                               "effects": [{"effect": d.effect, "simulated": d.simulated, "setting": d.setting,
                                            "reason": d.reason, "budget_used": d.budget_used} for d in decisions]})
    return 0
