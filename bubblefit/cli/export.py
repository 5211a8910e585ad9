"""``bubblefit export FIT.json --to gltf|blender|openpbr|mitsuba -o DIR``: the fitted bubble for other renderers."""

from __future__ import annotations

FORMAT_NAMES = ("gltf", "blender", "openpbr", "mitsuba")
#: Every file name an export may write into its folder (for the output guard).
EXPORT_FILES = ("bubble.gltf", "bubble_blender.py", "bubble.mtlx", "bubble_mitsuba.xml", "export.json",
                "export_log.txt", "thickness.png", "sphere.obj", "background.exr", "tint_reflectance.exr",
                "tint_transmittance.exr", "envmap.exr", "envmap.hdr")


def register(sub):
    p = sub.add_parser(
        "export", help="write a fitted bubble as glTF, a Blender scene, OpenPBR/MaterialX or a Mitsuba 3 scene",
        description="Write the bubble a fit found (sphere, film thickness and index, roughness, the camera of the "
                    "photo, the environment map where the format holds one) into a folder, with export_log.txt "
                    "saying where the format cannot express the fit. See docs/export.md.")
    from .common import input_file, output_folder

    p.add_argument("fit", metavar="FIT.json", type=input_file, help="result of `bubblefit fit --json` (with -o PREFIX for a map)")
    p.add_argument("--to", required=True, choices=FORMAT_NAMES, help="format to write")
    p.add_argument("-o", "--output", required=True, metavar="DIR", type=output_folder, help="output folder (created if missing)")
    p.add_argument("--envmap", type=input_file, help="environment map (default: the one the fit result names)")
    p.add_argument("--background", type=input_file, help="background photo (default: the one the fit result names)")
    p.add_argument("--scene", type=input_file, help="scene file with the camera (default: the one the fit result names)")
    p.set_defaults(func=run)


def run(args) -> int:
    import os
    from pathlib import Path

    from ..errors import OutputError
    from ..export import export_bubble, load_fit
    from .common import guard_args, guard_outputs

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        same = os.path.realpath(out) == os.path.realpath(args.fit)
        raise OutputError(f"refusing to write into {out}: it is " + ("the input fit result" if same else
                                                                     "a file, not a folder"))
    bubble = load_fit(args.fit, envmap=args.envmap, background=args.background, scene=args.scene)
    inputs = [args.fit, bubble.photo, bubble.envmap, bubble.background, args.scene]
    envmap_copy = out / ("envmap" + Path(bubble.envmap).suffix.lower()) if bubble.envmap else None
    outputs = [out / n for n in EXPORT_FILES if not n.startswith("envmap")]
    if envmap_copy is not None and not (envmap_copy.exists() and os.path.samefile(envmap_copy, bubble.envmap)):
        outputs.append(envmap_copy)
    guard_args(args, inputs)  # the output folder: creatable; it is made by the export
    guard_outputs(inputs, outputs)  # no file written into it is an input
    result = export_bubble(bubble, args.to, out)
    print(f"wrote {result.main} ({len(result.files)} files in {out})")
    for note in result.notes:
        print(f"  cannot express: {note}")
    print(f"log: {result.log}")
    return 0
