"""``bubblefit calibrate BEFORE AFTER``: the transmission fraction t (paper, sec. 3.3).

Photographs of the checkered background in the dark box without (BEFORE) and with
(AFTER) the bubble, from a fixed camera. Prints a short summary; ``--json`` writes the
result that ``bubblefit fit --calibration`` reads (keys ``t``, ``t_rgb``, ``t4``,
``t_ci95``, ``bubble``, ``pixels_used``, ``warnings`` and more), ``--debug-image`` a PNG of
the ratio map, the circle and the pixels used. See :mod:`bubblefit.capture.calibrate`.
"""

from __future__ import annotations

import math

from ..errors import BubblefitError, InputError

NAME = "calibrate"


def _circle(text: str) -> tuple[float, float, float]:
    parts = text.replace(" ", "").split(",")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals) or vals[2] <= 0:
        raise InputError(f"--circle expects CX,CY,R in pixels with R > 0, got {text!r}")
    return vals


def register(subparsers) -> None:
    p = subparsers.add_parser(
        NAME,
        help="transmission fraction t from photos without and with the bubble (paper sec. 3.3)",
        description=(
            "Measure the per-interface transmission fraction t of a bubble from two "
            "photographs taken by a fixed camera of a checkered background inside a matte "
            "black box: BEFORE without the bubble, AFTER with it. Inside the bubble "
            "AFTER/BEFORE = t^4 (four film interfaces). The pair is registered (camera "
            "shift of a few pixels), the bubble is found (or given with --circle), and t "
            "is estimated robustly from the lit, unsaturated pixels well inside the "
            "bubble, with a 95% interval. A radial fit with the Fresnel film model also "
            "gives the film's refractive index when the bubble is large enough."
        ),
    )
    from .common import input_file, output_file

    p.add_argument("before", metavar="BEFORE", type=input_file, help="photograph without the bubble (PNG, JPEG, TIFF, EXR, ...)")
    p.add_argument("after", metavar="AFTER", type=input_file, help="photograph with the bubble, same camera and exposure")
    p.add_argument("--json", metavar="OUT", type=output_file, help="write the result as JSON (input of 'bubblefit fit --calibration')")
    p.add_argument("--debug-image", metavar="OUT.png", type=output_file,
                   help="write a PNG: the AFTER shot, and the ratio map with the circle (red), the pixels "
                        "used for t (green) and the rim pixels of the radial fit (blue)")
    p.add_argument("--circle", metavar="CX,CY,R",
                   help="the bubble's circle in pixels of AFTER (x right, y down, pixel centres at +0.5); "
                        "found automatically if omitted")
    p.add_argument("--inner-fraction", type=float, default=0.6, metavar="F",
                   help="use pixels within F times the radius of the centre [0.6]")
    p.add_argument("--no-exposure-correction", action="store_true",
                   help="do not normalise by the after/before ratio of the background outside the bubble")
    p.add_argument("--bootstrap", type=int, default=2000, metavar="N", help="bootstrap resamples [2000]")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap [0]")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    from .photo_args import add_photo_options
    from .view_options import add_view_options

    add_photo_options(p)
    add_view_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..capture.calibrate import calibrate
    from ..capture.result import write_debug_image
    from ..progress import stage
    from ..io.camera_files import read_photo, reading_record
    from .common import guard_args, write_json
    from .view_options import check_view_args, view_from_args
    from .photo_args import photo_reading

    reading = photo_reading(args)
    guard_args(args)
    check_view_args(args)
    circle = _circle(args.circle) if args.circle else None
    if not (0.05 <= args.inner_fraction <= 0.95):
        raise InputError(f"--inner-fraction must be between 0.05 and 0.95, got {args.inner_fraction}")
    if args.bootstrap < 100:
        raise InputError(f"--bootstrap needs at least 100 resamples, got {args.bootstrap}")
    try:
        with stage("calibrating t (registration, circle, ratio, bootstrap)"):
            before = read_photo(args.before, reading, what="photo")
            after = read_photo(args.after, reading, what="photo")
            result = calibrate(
                before, after, circle,
                inner_fraction=args.inner_fraction,
                exposure_correction=not args.no_exposure_correction,
                n_boot=args.bootstrap, seed=args.seed,
            )
    except BubblefitError as exc:
        # one line on the terminal, even when a decoder's message spans several
        lines = str(exc).strip().splitlines() or ["unknown error"]
        if len(lines) > 1:
            raise type(exc)(lines[0]) from None
        raise
    if args.json:
        h, w = after.pixels.shape[:2]
        view = view_from_args(args, after.metadata, w, h)  # recorded: t comes from the inner disc, any view
        write_json(args.json, {**result.to_json(), "photo_reading": reading_record(after), "camera": view.to_json()})
    if args.debug_image:
        write_debug_image(args.debug_image, result)
    if not args.quiet:
        print(result.summary())
    return 0
