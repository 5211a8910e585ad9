"""``bubblefit render SCENE.toml`` for a scene whose ``[film]`` table is a cap on a liquid
or a whole bubble under an area light (:mod:`bubblefit.model.cap_scene`).

The film's thickness to render is given in ``[film]`` beside the fit's keys:
``thickness_nm`` for a ``constant`` film, ``top_nm``, ``bottom_nm`` and ``exponent`` for
``drainage``; the camera's gain is 1 and ``[camera] samples_per_pixel`` (default 4) rays
box-filter each pixel. ``--explain`` prints the light paths the render traces and skips.
"""

from __future__ import annotations

import dataclasses

import time

import numpy as np

from ..errors import InputError


def film_values(path, kind: str) -> np.ndarray:
    """The thickness parameters of the ``[film]`` table to render (nm; the exponent bare)."""
    from ..model.planar_scene import _num, _read_toml

    f = _read_toml(path).get("film", {})
    if kind == "constant":
        return np.array(_num(f, "thickness_nm", "film", None, 0.0, 20000.0))
    top = _num(f, "top_nm", "film", None, 0.0, 20000.0)
    return np.array([top, _num(f, "bottom_nm", "film", None, top, 20000.0), _num(f, "exponent", "film", 1.0, 0.05, 20.0)])


def run_film_render(args) -> int:
    from ..inverse.cap_fit import _params, cap_config
    from ..io.atomic import output_set
    from ..io.images import preview_path, write_image
    from ..lighting.envmap import dark_room
    from ..model.cap_render import SKIPPED, SKIPPED_SPHERE, TRACED_SPHERE, render_cap
    from ..model.cap_scene import load_cap_scene
    from ..model.planar_scene import _num, _read_toml
    from ..model.scene import read_envmap
    from ..progress import stage
    from .common import auto_exposure, guard_args, write_json

    for name in ("illuminant", "camera_response", "tolerance"):
        if getattr(args, name, None) is not None:
            raise InputError(f"--{name.replace('_', '-')} does not apply to a scene with a [film] table "
                             "(give the illuminant as [light] lamp or [lighting] illuminant)")
    scene = load_cap_scene(args.scene)
    if getattr(args, "film_rgb", None):
        scene = dataclasses.replace(scene, film_rgb=args.film_rgb)
    values = film_values(args.scene, scene.thickness)
    spp = int(_num(_read_toml(args.scene).get("camera", {}), "samples_per_pixel", "camera", 4, 1, 64))
    if round(spp ** 0.5) ** 2 != spp:
        raise InputError(f"camera.samples_per_pixel must be a square number (1, 4, 9, ...), got {spp}")
    preview = preview_path(args.output)
    guard_args(args, inputs=[scene.envmap] if scene.envmap is not None else [], outputs=[preview])
    env = read_envmap(scene.envmap, scale=scene.env_scale, convention=scene.env_convention) if scene.envmap is not None else dark_room()
    cfg = cap_config(scene, scene.thickness, samples_per_pixel=spp)
    t0 = time.perf_counter()
    with stage(f"rendering {scene.camera.width}x{scene.camera.height}"):
        img = np.asarray(render_cap(_params(scene, values, 1.0), cfg, env), np.float64)
    elapsed = time.perf_counter() - t0
    exposure = args.preview_exposure if args.preview_exposure is not None else auto_exposure(img)
    with stage("writing"), output_set():
        write_image(args.output, img.astype(np.float32))
        write_image(preview, img * exposure)
    traced = TRACED_SPHERE if scene.sphere else ()
    skipped = SKIPPED_SPHERE if scene.sphere else SKIPPED
    if args.explain:
        for line in traced:
            print(f"traced   {line}")
        for line in skipped:
            print(f"skipped  {line}")
    print(f"wrote {args.output} ({scene.camera.width}x{scene.camera.height}, {elapsed:.2f} s)")
    if args.json:
        write_json(args.json, {"output": str(args.output), "time_s": elapsed, "preview_exposure": exposure,
                               "traced_light_paths": list(traced), "skipped_light_paths": list(skipped)})
    return 0
