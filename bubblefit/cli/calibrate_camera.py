"""``bubblefit calibrate-camera -o RESPONSE.csv [--chart PHOTO [--patches P.csv] | --chart-values V.csv] [--film F.csv]``.

Fits the camera-times-lamp spectral response per channel
(:mod:`bubblefit.capture.camera_calibration`) from a ColorChecker photographed under the
lamp and/or the colours of a film of known thicknesses, and writes the CSV that
``--camera-response`` reads (with its standard errors), plus ``--json`` with the fit's
details. See docs/cameras.md.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

NAME = "calibrate-camera"


def register(sub):
    p = sub.add_parser(
        NAME, help="fit the camera's spectral response (times the lamp) from a colour chart or a film of known thickness",
        description="Fit each channel's spectral response of the camera times the lamp, a smooth curve over "
                    "380-780 nm, from a ColorChecker photographed under the lamp and/or the colours of a film of "
                    "known thicknesses. Writes a CSV for --camera-response.")
    from .common import input_file, output_file

    p.add_argument("-o", "--output", required=True, metavar="RESPONSE.csv", type=output_file, help="the fitted response (CSV)")
    p.add_argument("--chart", metavar="PHOTO", type=input_file, help="photo of an X-Rite ColorChecker (24 patches) under the lamp")
    p.add_argument("--patches", metavar="P.csv", type=input_file,
                   help="with --chart: 24 rows x,y,half_size (pixels) of the patches' centres, in the chart's "
                        "reading order (row by row from 'dark skin' to 'black'); without it the chart is found "
                        "in the photo (needs the colour-checker-detection package: pip install 'bubblefit[chart]')")
    p.add_argument("--chart-values", metavar="V.csv", type=input_file, help="instead of --chart: 24 rows r,g,b of the patches' "
                                                           "linear values, in the chart's reading order")
    p.add_argument("--film", metavar="F.csv", type=input_file,
                   help="rows thickness_nm,r,g,b: linear colours of a film of known thicknesses, seen at --angle-deg "
                        "against black, under the same lamp and exposure as the chart")
    from .common import add_index_options

    add_index_options(p, default="1.33")
    p.add_argument("--angle-deg", type=float, default=0.0, help="the film's angle of incidence [0]")
    p.add_argument("--illuminant", default="E", type=input_file,
                   help="the lamp's spectrum (a CIE name or a CSV): the response is divided by it; E (default) "
                        "keeps the camera-times-lamp product, to be used with --illuminant E")
    p.add_argument("--json", metavar="OUT", type=output_file, help="write the calibration's details as JSON")
    from .photo_args import add_photo_options

    add_photo_options(p)
    p.set_defaults(func=run)


def _rows(path: str, columns: int, what: str) -> np.ndarray:
    """Rows of ``columns`` numbers (:func:`bubblefit.optics.spectral.read_number_rows`), at least one."""
    from ..optics.spectral import read_number_rows

    rows = read_number_rows(path, columns, what)
    if not len(rows):
        raise InputError(f"{what} {path} has no rows of {columns} numbers")
    return rows


def run(args) -> int:
    from ..capture import camera_calibration as cc
    from ..io.atomic import write_text
    from ..io.camera_files import read_photo, reading_record
    from ..optics import spectral
    from .common import colour_option, film_index, guard_args, write_json
    from .photo_args import photo_reading

    if not args.output.lower().endswith(".csv"):
        raise InputError(f"the output must be a .csv file, got {args.output}")
    if args.chart and args.chart_values:
        raise InputError("give --chart (with --patches) or --chart-values, not both")
    if args.patches and not args.chart:
        raise InputError("--patches goes with --chart")
    if not (args.chart or args.chart_values or args.film):
        raise InputError("nothing to calibrate from: give --chart/--patches, --chart-values or --film")
    reading = photo_reading(args)
    guard_args(args)
    ill = colour_option(args.illuminant, spectral.is_named_illuminant, "--illuminant")
    spectral.illuminant_spectrum(ill)
    sources, record = [], {}
    if args.chart or args.chart_values:
        names, refl = cc.chart_reflectances()
        if args.chart:
            img = read_photo(args.chart, reading, what="chart")
            if args.patches:
                patches = _rows(args.patches, 3, "patches")
                if len(patches) != len(names):
                    raise InputError(f"--patches {args.patches} has {len(patches)} rows; the chart has "
                                     f"{len(names)} patches")
                values = cc.patch_means(img.pixels, patches, img.saturated)
            else:  # found in the photo (colour-checker-detection)
                values = cc.detect_chart(img.pixels)
                record["chart_detected"] = True
            record["chart_reading"] = reading_record(img)
        else:
            values = _rows(args.chart_values, 3, "chart values")
            if len(values) != len(names):
                raise InputError(f"--chart-values {args.chart_values} has {len(values)} rows; the chart has "
                                 f"{len(names)} patches")
        sources.append((f"ColorChecker ({cc.CHART})", refl, values))
    if args.film:
        rows = _rows(args.film, 4, "film colours")
        if np.any(rows[:, 0] < 0):
            raise InputError(f"--film {args.film}: thicknesses must be >= 0 nm")
        n_film = film_index(args.n_film, args.cauchy, 1.33)
        sources.append((f"film of {len(rows)} thicknesses {rows[:, 0].min():.0f}-{rows[:, 0].max():.0f} nm",
                        cc.film_reflectances(rows[:, 0], n_film, args.angle_deg), rows[:, 1:]))
    cal = cc.fit_response(sources, ill)
    write_text(args.output, cal.csv_text())
    print(f"wrote {args.output}: {cal.samples} samples, relative residual r/g/b "
          + "/".join(f"{v:.2%}" for v in cal.residual_rel)
          + ", median standard error " + "/".join(f"{v:.3f}" for v in np.median(cal.stderr, axis=0))
          + (f"; fit with --camera-response {args.output} --illuminant {args.illuminant}"))
    if args.json:
        write_json(args.json, {**cal.to_json(), "output": args.output, **record})
    return 0
