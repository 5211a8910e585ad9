"""``bubblefit fit PHOTO --scene CAP.toml``: the film of a bubble standing on a dish.

Reached from ``fit`` when the scene's ``[film]`` says ``shape = "cap"``, or ``"sphere"``
under a ``[light] type = "area"`` (a whole bubble lit by a panel: the same fit without a
liquid, the map optional); the method is
:func:`bubblefit.inverse.cap_fit.fit_cap`. The environment map is the scene's
``[environment] path`` (``--envmap`` replaces it). Writes, with ``-o PREFIX``,
``PREFIX_thickness.exr`` and ``PREFIX_thickness_stderr.exr`` (nm, NaN off the cap's
directly seen pixels; PNG previews), ``PREFIX_render.exr`` and ``PREFIX_residual.exr``;
``--json`` the result, with the light paths the cap's render skips.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputError

#: Options of ``fit`` that belong to a floating bubble only: refused for a cap, not ignored.
_SPHERE_ONLY = ("background", "calibration", "t", "disc", "fit_rotation", "reference_region")


def run_cap(args) -> int:
    from ..inverse.cap_fit import fit_cap
    from ..model.cap_scene import KINDS, load_cap_scene
    from ..lighting.envmap import dark_room
    from ..model.scene import read_envmap
    from ..progress import stage
    from .common import guard_args
    from .fit_planar import film_outputs, read_film_photo, report_film_fit

    for name in _SPHERE_ONLY:
        if getattr(args, name, None):
            raise InputError(f"--{name.replace('_', '-')} does not apply to a scene with a [film] table "
                             "(a bubble on a dish or under an area light)")
    scene = load_cap_scene(args.scene)
    if args.envmap:
        from pathlib import Path

        scene = dataclasses.replace(scene, envmap=Path(args.envmap))
    if getattr(args, "envmap_convention", None):
        scene = dataclasses.replace(scene, env_convention=args.envmap_convention)
    if getattr(args, "film_rgb", None):
        scene = dataclasses.replace(scene, film_rgb=args.film_rgb)
    kind = args.thickness if args.thickness != "constant" or scene.thickness == "constant" else scene.thickness
    if kind not in KINDS:
        raise InputError(f"--thickness {kind} is not available for a cap (use {' or '.join(KINDS)})")
    guard_args(args, inputs=[str(scene.envmap)] if scene.envmap is not None else [], outputs=film_outputs(args))
    with stage("reading the photo and the environment map"):
        photo, record = read_film_photo(args)
        env = read_envmap(scene.envmap, scale=scene.env_scale, convention=scene.env_convention) if scene.envmap is not None else dark_room()
    what = (f"a bubble of radius {scene.cap.radius:g} under an area light" if scene.sphere else
            f"a bubble on a dish (cap {scene.cap.height:g} high on a sphere of radius {scene.cap.radius:g}")
    with stage(f"fitting {what}, {kind})" if not scene.sphere else f"fitting {what} ({kind})"):
        result = fit_cap(photo.pixels[..., :3], scene, env, kind=kind,
                         clip_high=np.inf if photo.linear_file else 1.0,
                         bits=None if photo.linear_file else photo.bit_depth)
    return report_film_fit(args, result, record)
