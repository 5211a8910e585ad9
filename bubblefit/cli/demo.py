"""``bubblefit demo [--out DIR] [--size N] [--seed S]``: the whole pipeline on shipped data."""

from __future__ import annotations


def register(sub):
    p = sub.add_parser(
        "demo", help="synthesise a capture on a shipped map, calibrate, fit, and report true vs recovered",
        description="Synthesise a capture on the shipped courtyard map (calibration pair and a bubble photo "
                    "with known parameters, noise, 8-bit files), run calibrate and fit, print true against "
                    "recovered values with standard errors, and write the fit's page (index.html).")
    from .common import output_file, output_folder

    p.add_argument("--out", default=output_folder("bubblefit-demo"), type=output_folder, help="output folder (default: %(default)s)")
    p.add_argument("--size", type=int, default=96, help="side of the synthetic photos in pixels (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise (default: %(default)s)")
    p.add_argument("--json", metavar="PATH", type=output_file, help="also write the results JSON here")
    p.add_argument("--quiet", action="store_true", help="print only the table")
    p.set_defaults(func=run)


def run(args) -> int:
    import time

    from ..demo import fit_status, format_table, run_demo
    from ..errors import InputError
    from .common import guard_args, write_json

    guard_args(args)
    if not 32 <= args.size <= 1024:
        raise InputError(f"--size must be between 32 and 1024 pixels, got {args.size}")
    t0 = time.perf_counter()
    result = run_demo(args.out, size=args.size, seed=args.seed, progress=not args.quiet)
    print(format_table(result["rows"]))
    print(fit_status(result["fit"]))
    if args.json:
        write_json(args.json, result)
    ok = sum(r["ok"] for r in result["rows"])
    print(f"{ok}/{len(result['rows'])} recovered values within tolerance; "
          f"report: {result['paths']['html']} ({time.perf_counter() - t0:.0f} s)")
    return 0
