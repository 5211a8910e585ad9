"""``bubblefit report FIT.json -o DIR``: the HTML page of a fit (photo, render, residual, maps, table, verdict)."""

from __future__ import annotations


def register(sub):
    p = sub.add_parser(
        "report", help="write the HTML page of a fit: images with colour bars, the parameter table and the verdict",
        description="Write DIR/index.html and its figures for a fit result: the photo, the fitted render, the "
                    "residual, the thickness map and its standard error (colour bars in nm), the profile with its "
                    "error band, every parameter with its standard error or why it was held, and whether the fit "
                    "is ok with every warning in words. See docs/report.md.")
    from .common import input_file, output_folder

    p.add_argument("fit", metavar="FIT.json", type=input_file, help="result of `bubblefit fit --json` (with -o PREFIX for the images)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", type=output_folder, help="output folder (created if missing)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..errors import OutputError
    from ..report import PAGE_FILES, load_report_inputs, write_fit_page
    from .common import guard_args, guard_outputs

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise OutputError(f"refusing to write into {out}: it is a file, not a folder")
    data = load_report_inputs(args.fit)
    guard_args(args, data.inputs())  # the output folder: creatable; the page writer makes it
    guard_outputs(data.inputs(), [out / n for n in PAGE_FILES])
    page = write_fit_page(data, out)
    print(f"wrote {page}")
    return 0
