"""``bubblefit envmap PROBE [PROBE ...] -o ENV.exr``: mirror-ball photographs to an HDR map.

Several exposures of the ball are merged to HDR (:func:`bubblefit.capture.hdr.merge_exposures`),
the ball is found (:func:`bubblefit.capture.ball.find_ball`) or given with ``--ball``, and it is
unwrapped (:func:`bubblefit.capture.probe.unwrap_mirror_ball`) to an equirectangular map in the
convention of ``docs/design.md`` (camera frame: the camera looked along -z). Writes a linear EXR and
an sRGB PNG preview beside it; ``--mask`` writes the valid-texel mask, ``--json`` a summary.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

NAME = "envmap"


def register(subparsers) -> None:
    from .common import input_file, output_file

    p = subparsers.add_parser(
        NAME,
        help="unwrap mirror-ball photo(s) (several exposures merge to HDR) to an environment map",
        description=(
            "Find the mirror ball in PROBE (one photograph or a bracket of exposures of the "
            "same view), merge the exposures to HDR and unwrap the ball to an "
            "equirectangular map (width = 2 x height, Mitsuba's convention, camera frame: "
            "the camera looks along -z, +y up). Directions near the one straight behind the "
            "ball and the camera's own reflection are masked and filled from their "
            "neighbours. Writes a linear EXR and a PNG preview."
        ),
    )
    p.add_argument("probes", nargs="+", metavar="PROBE", type=input_file, help="photograph(s) of the mirror ball")
    p.add_argument("-o", "--output", required=True, metavar="ENV.exr", type=output_file, help="output map (EXR)")
    p.add_argument("--height", type=int, default=256, help="map height in texels [256]")
    p.add_argument("--ball", metavar="CX,CY,R",
                   help="the ball's circle in pixels (x right, y down, pixel centres at +0.5); found automatically if omitted")
    p.add_argument("--times", type=float, nargs="+", metavar="SECONDS",
                   help="exposure times, one per PROBE (default: the files' EXIF ExposureTime)")
    p.add_argument("--response", default="file",
                   choices=["file", "linear", "recover-debevec", "recover-robertson"],
                   help="camera response: 'file' decodes 8/16-bit files as sRGB (EXR as linear), "
                        "'linear' takes integer codes as linear, 'recover-*' recovers it from the "
                        "8-bit bracket with OpenCV (Debevec & Malik 1997 / Robertson et al. 2003) [file]")
    p.add_argument("--merge", default="robertson", choices=["robertson", "debevec"],
                   help="HDR estimator [robertson]")
    p.add_argument("--distance", type=float, default=None, metavar="RADII",
                   help="camera-to-ball distance in ball radii (perspective); default orthographic")
    p.add_argument("--rim-mask-deg", type=float, default=20.0,
                   help="mask directions within this angle of the one straight behind the ball [20]")
    p.add_argument("--camera-mask-deg", type=float, default=8.0,
                   help="mask the camera's reflection within this angle of the view direction [8]; 0 keeps it")
    p.add_argument("--rotation-deg", type=float, default=0.0,
                   help="rotate the map about +y (degrees) [0]")
    p.add_argument("--no-fill", action="store_true", help="leave masked texels black instead of inpainting them")
    p.add_argument("--mask", metavar="MASK.png", type=output_file, help="also write the valid-texel mask (white = sampled by the ball)")
    p.add_argument("--hdr", metavar="MERGED.exr", type=output_file, help="also write the merged HDR photograph")
    p.add_argument("--json", metavar="PATH", type=output_file, help="write a JSON summary (ball, exposure times, masks)")
    from .photo_args import add_photo_options

    add_photo_options(p)
    p.set_defaults(func=run)


def _parse_ball(text: str):
    from ..capture.ball import Circle

    try:
        cx, cy, r = (float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise InputError(f"--ball expects CX,CY,R in pixels, got {text!r}") from None
    if not (r > 0 and all(math.isfinite(v) for v in (cx, cy, r))):
        raise InputError(f"--ball radius must be positive, got {text!r}")
    return Circle(cx, cy, r)


def _check_options(args) -> str:
    """The output path, once the options are known to make sense."""
    from ..io.images import preview_path

    out = str(args.output)
    if not out.lower().endswith(".exr"):
        raise InputError(f"the output map must be an .exr file, got {out}")
    from .common import guard_args

    guard_args(args, outputs=[preview_path(out)])
    if args.height < 8:
        raise InputError(f"--height must be at least 8, got {args.height}")
    if args.distance is not None and not (math.isfinite(args.distance) and args.distance > 1.0):
        raise InputError(f"--distance is the camera-to-ball-centre distance in ball radii and must exceed 1 "
                         f"(the camera outside the ball), got {args.distance:g}")
    return out


def _exposure_times(args, images) -> list[float]:
    """One exposure time per probe: ``--times``, else the files' EXIF ExposureTime."""
    from ..capture.measure import metadata_value

    if args.times is not None:
        if len(args.times) != len(images):
            raise InputError(f"{len(args.times)} --times for {len(images)} probe(s)")
        times = list(args.times)
    elif len(images) == 1:
        times = [float(metadata_value(images[0], "exposure_time") or 1.0)]
    else:
        times = []
        for im in images:
            t = metadata_value(im, "exposure_time")
            if not isinstance(t, (int, float)) or t <= 0:
                raise InputError(f"{im.path} has no ExposureTime metadata: give the exposure times with --times")
            times.append(float(t))
    if any(not (t > 0 and math.isfinite(t)) for t in times):
        raise InputError(f"exposure times must be positive, got {times}")
    if len(images) > 1 and len(set(round(math.log2(t), 3) for t in times)) < len(times):
        raise InputError("two probes have the same exposure time: a bracket needs different exposures")
    return times


def _merge(args, images, times):
    """The bracket linearised (``--response``) and merged to one radiance image. Float files
    (EXR, HDR) hold radiance above 1 unclipped; 8/16-bit codes clip at full scale."""
    from ..capture import hdr
    from ..io.images import srgb_encode

    pix = [im.pixels for im in images]
    if args.response.startswith("recover"):
        if len(images) < 2 or any(im.bit_depth != 8 for im in images):
            raise InputError("--response recover-* needs at least two 8-bit exposures")
        codes = [np.round((im.pixels if im.linear_file else srgb_encode(im.pixels)) * 255).astype(np.uint8)
                 for im in images]
        resp = hdr.recover_response(codes, times, method=args.response.split("-", 1)[1])
        pix = [hdr.apply_response(c, resp) for c in codes]
    integer = [im.bit_depth in (8, 16) for im in images]
    sat = [im.saturated if i else None for im, i in zip(images, integer)]
    clip = [hdr.file_clip_level(im.bit_depth) for im in images]
    from ..progress import stage

    with stage(f"merging {len(pix)} exposure(s)"):
        return hdr.merge_exposures(pix, times, saturated=sat, clip_level=clip, method=args.merge)


def run(args) -> int:
    import sys

    from ..capture import ball, hdr, probe
    from ..io.images import preview_path, write_image, write_preview
    from ..progress import stage
    from .common import write_json

    out = _check_options(args)
    from dataclasses import replace

    from ..io.camera_files import read_photo, reading_record
    from .photo_args import photo_reading

    reading = photo_reading(args)
    if args.response == "linear":
        reading = replace(reading, encoding="linear", force=True)
    images = [read_photo(p, reading, what="probe") for p in args.probes]
    shapes = {im.shape for im in images}
    if len(shapes) > 1:
        raise InputError("the probes differ in size: " + ", ".join(f"{im.path} {im.shape[1]}x{im.shape[0]}" for im in images))
    times = _exposure_times(args, images)
    merged = _merge(args, images, times)
    with stage("finding the ball"):
        circle = _parse_ball(args.ball) if args.ball else ball.find_ball(merged.radiance)
    h, w = merged.radiance.shape[:2]
    if circle.cx + circle.r < 0 or circle.cy + circle.r < 0 or circle.cx - circle.r > w or circle.cy - circle.r > h:
        raise InputError(f"the ball ({circle.cx:g}, {circle.cy:g}, r {circle.r:g}) lies outside the {w}x{h} image")
    pm = probe.unwrap_mirror_ball(
        merged.radiance, circle, height=args.height, distance=args.distance,
        rim_mask_deg=args.rim_mask_deg, camera_mask_deg=args.camera_mask_deg,
        rotation=math.radians(args.rotation_deg), fill=not args.no_fill,
    )
    env = pm.pixels if not args.no_fill else np.where(pm.valid[..., None], pm.pixels, 0.0)
    clipped_in_ball = int((merged.clipped & ball.ball_mask((h, w), circle)).sum())
    write_image(out, env, bit_depth=32 if float(np.max(env)) > 60000 else None)
    lum = env @ np.array([0.2126, 0.7152, 0.0722])
    ref = float(np.median(lum[pm.valid])) if pm.valid.any() else float(np.median(lum))
    write_preview(preview_path(out), env, exposure=0.18 / ref if ref > 0 else 1.0)
    if args.mask:
        write_image(args.mask, np.repeat(pm.valid[..., None].astype(np.float64), 3, axis=2))
    if args.hdr:
        write_image(args.hdr, merged.radiance, bit_depth=32 if float(np.max(merged.radiance)) > 60000 else None)
    summary = {
        "output": out,
        "preview": str(preview_path(out)),
        "probes": [im.path for im in images],
        "exposure_times_s": times,
        "bracket_stops": hdr.exposure_stops(times),
        "merge": args.merge,
        "response": args.response,
        "photo_reading": [reading_record(im) for im in images],
        "ball": circle.as_dict(),
        "ball_source": "given" if args.ball else "detected",
        "clipped_pixels_in_ball": clipped_in_ball,
        **pm.info,
    }
    if args.json:
        write_json(args.json, summary)
    print(f"wrote {out} ({pm.pixels.shape[1]}x{pm.pixels.shape[0]}) and {preview_path(out)}; ball at "
          f"({circle.cx:.1f}, {circle.cy:.1f}) r {circle.r:.1f} px ({summary['ball_source']}); "
          f"{len(images)} exposure(s) over {summary['bracket_stops']:.1f} stops; "
          f"{100 * pm.info['valid_fraction']:.0f}% of directions sampled")
    if clipped_in_ball:
        print(f"bubblefit: warning: {clipped_in_ball} pixel(s) of the ball are clipped in every exposure "
              "(their radiance is a lower bound): add a shorter exposure", file=sys.stderr)
    return 0
