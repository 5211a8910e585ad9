"""``bubblefit chart [--thickness 0:3000:5] [--angle-deg 0] [--model airy] -o CHART.png [--csv OUT]``."""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def register(sub):
    from .common import input_file, output_file

    p = sub.add_parser("chart", help="interference colour against film thickness (PNG and CSV)",
                       description="Chart of the film's interference colour against thickness, from a "
                                   "converged spectral integration (linear sRGB, D65, flat = grey).")
    p.add_argument("--thickness", default="0:3000:5", help="START:STOP:STEP in nm (default 0:3000:5)")
    p.add_argument("--angle-deg", type=float, default=0.0, help="angle of incidence in degrees (default 0)")
    p.add_argument("--model", default="airy", choices=["airy", "two_beam", "paper", "incoherent"])
    from .common import add_colour_options, add_index_options

    add_index_options(p)
    p.add_argument("--above", metavar="MEDIUM", help="medium the light comes from: a number or a preset (air, water, "
                                                     "bk7, soda-lime, fused-silica); default air")
    p.add_argument("--below", metavar="MEDIUM", help="medium behind the film (as --above); default air")
    p.add_argument("--na", type=float, default=0.0,
                   help="numerical aperture of a coaxial objective: average over its cone of incidence (default 0)")
    p.add_argument("--lamp", default=None, type=input_file, help="the lamp's spectrum: D65, A, a colour temperature such as 3200K, "
                                                "or a CSV wavelength_nm,power (same as --illuminant)")
    p.add_argument("-o", "--output", required=True, type=output_file, help="chart image (PNG)")
    p.add_argument("--csv", type=output_file, help="CSV with columns thickness_nm,r,g,b (linear RGB reflectance, white = 1)")
    p.add_argument("--json", type=output_file, help="write a JSON summary")
    add_colour_options(p)
    p.set_defaults(func=run)


def parse_range(text: str) -> np.ndarray:
    try:
        start, stop, step = (float(x) for x in text.split(":"))
    except ValueError:
        raise InputError(f"--thickness must be START:STOP:STEP in nm, got {text!r}") from None
    if not all(np.isfinite((start, stop, step))):
        raise InputError(f"--thickness {text!r}: START, STOP and STEP must be finite numbers")
    if step <= 0 or stop < start or start < 0:
        raise InputError(f"--thickness {text!r}: need 0 <= START <= STOP and STEP > 0")
    n = int(np.floor((stop - start) / step + 1e-9)) + 1
    if n > 200000:
        raise InputError(f"--thickness {text!r} asks for {n} samples; at most 200000")
    return start + step * np.arange(n)


def _medium(text: str):
    """A medium option: a number or a preset name."""
    try:
        return float(text)
    except ValueError:
        return text


def run(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.atomic import check_png, output_set, write_text
    from ..io.images import atomic_path, srgb_encode
    from ..optics.chart import display_scale, interference_colours
    from ..progress import stage
    from .common import guard_args, write_json

    if not 0 <= args.angle_deg <= 90:
        raise InputError(f"--angle-deg must be within [0, 90], got {args.angle_deg}")
    from ..optics import dispersion
    from ..optics.dispersion import describe
    from .common import film_index

    from ..optics import spectral
    from .common import colour_option

    n_film = film_index(args.n_film, args.cauchy, 1.4)
    if args.lamp and args.illuminant:
        raise InputError("give the lamp once: --lamp or --illuminant")
    if not 0.0 <= args.na < 1.0:
        raise InputError(f"--na must lie in [0, 1), got {args.na}")
    above = dispersion.parse_index(_medium(args.above), "--above") if args.above else None
    below = dispersion.parse_index(_medium(args.below), "--below") if args.below else None
    if (above is not None or below is not None or args.na > 0) and args.model != "airy":
        raise InputError("--above, --below and --na need --model airy")
    if args.na > 0 and args.angle_deg != 0:
        raise InputError("--na spreads the incidence around the objective's axis: leave --angle-deg at 0")
    lamp = args.lamp or args.illuminant
    basis = spectral.spectral_basis(
        "reference", illuminant=colour_option(lamp, spectral.is_named_illuminant, "--lamp") or "D65",
        response=colour_option(args.camera_response, spectral.is_named_response, "--camera-response") or "srgb")
    d = parse_range(args.thickness)
    guard_args(args)
    fmt = args.output.rsplit(".", 1)[-1].lower() if "." in args.output else "png"
    supported = plt.figure().canvas.get_supported_filetypes()
    plt.close("all")
    if fmt not in supported:
        raise InputError(f"cannot write chart {args.output}: unknown image format .{fmt} "
                         f"(use one of {', '.join(sorted(supported))})")
    with stage(f"interference colours of {len(d)} thicknesses"):
        rgb = interference_colours(d, angle_deg=args.angle_deg, model=args.model, n_film=n_film, basis=basis,
                                   above=above, below=below, na=args.na)
    scale = (0.5 / max(float(rgb.mean()), 1e-12) if above is not None or below is not None
             else display_scale(args.model, angle_deg=args.angle_deg, n_film=n_film))
    shown = srgb_encode(rgb * scale)
    fig, ax = plt.subplots(figsize=(10, 1.8), dpi=120)
    ax.imshow(shown[None, :, :], aspect="auto", extent=(d[0], d[-1], 0, 1), interpolation="nearest")
    ax.set_yticks([])
    ax.set_xlabel("film thickness (nm)")
    media = f"{describe(above) if above is not None else 'air'} | {describe(n_film)} | " \
            f"{describe(below) if below is not None else 'air'}"
    ax.set_title(f"interference colour, {args.model}, {media}, "
                 + (f"NA {args.na:g}" if args.na > 0 else f"{args.angle_deg:g} deg"))
    fig.tight_layout()
    with output_set():
        with atomic_path(args.output, check=check_png if fmt == "png" else None) as tmp:
            fig.savefig(tmp, format=fmt)
        plt.close(fig)
        if args.csv:
            write_text(args.csv, "thickness_nm,r,g,b\n" + "".join(
                ",".join(f"{v:.10g}" for v in row) + "\n" for row in np.column_stack([d, rgb])))
        if args.json:
            write_json(args.json, {"output": args.output, "csv": args.csv, "samples": len(d), "model": args.model,
                                   "media": media, "na": args.na, "lamp": lamp or "D65"})
    print(f"wrote {args.output}" + (f" and {args.csv}" if args.csv else "") + f" ({len(d)} thicknesses)")
    return 0
