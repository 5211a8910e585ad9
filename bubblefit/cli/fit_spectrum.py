"""``bubblefit fit-spectrum SPECTRUM... [--dark DARK] [--reference REF] [--n-film N | --cauchy A,B[,C]]
[--thickness-range MIN,MAX] [--wavelength-range MIN,MAX] [--normalised] [--background-terms K] [--incoherent]
[--shared-lamp] [--csv OUT] [--json OUT] [-o PLOT_PREFIX]``.

Film thickness from spectrometer readings (:mod:`bubblefit.inverse.spectrum`): one CSV row
and one JSON entry per file, and with ``-o`` a plot per file of the measured and fitted
spectra, the residual and the profile likelihood over thickness. With ``--shared-lamp``
the files are one series under one lamp (:func:`bubblefit.inverse.spectrum.fit_spectrum_series`):
the readings that can be read alone fit the lamp, and the others (films too thin for
fringes) are read with it; ``-o`` then also plots the series' thicknesses in file order.
Files on one instrument that form several series (several folders or name stems,
``--series-by``) share that lamp, and each series keeps its own time order
(:func:`bubblefit.inverse.series_groups`).

A spectral image (a cube: ENVI ``.hdr``, ``.npy``/``.npz``, HDF5, Zarr; or a line scan, a
2-D array) gives a thickness map (:func:`bubblefit.inverse.spectral_map.fit_cube`):
``-o PREFIX`` writes ``PREFIX_thickness.exr``/``.png`` and ``PREFIX_thickness_stderr.exr``/``.png``
(a line scan: ``PREFIX_profile.csv``/``.png``), ``--json`` the summary.
"""

from __future__ import annotations

import sys

from pathlib import Path

from ..errors import InputError

_CSV_COLUMNS = ("file", "thickness_nm", "thickness_nm_stderr", "ok", "order", "fringes", "reduced_chi2",
                "residual_rms", "resolution_nm", "n_film", "second_minimum_nm", "delta_chi2",
                "stderr_statistical_nm", "stderr_lamp_nm", "normalised", "reasons", "warnings")


def register(sub):
    from .common import input_file, output_file, output_prefix

    p = sub.add_parser(
        "fit-spectrum", help="film thickness from spectrometer readings (two-column text files)",
        description="Film thickness from spectrometer readings: two-column text files wavelength_nm,intensity "
                    "(comma or whitespace, header lines allowed), arbitrary units, not divided by the lamp "
                    "(or, with --normalised, already divided by it). "
                    "Without --reference the lamp is an unknown smooth spectrum fitted with the film. "
                    "The order is found by a global search; ok is false (with the reason) when it is ambiguous.")
    p.add_argument("spectra", nargs="+", metavar="SPECTRUM", type=input_file, help="spectrum file(s)")
    p.add_argument("--dark", type=input_file, help="dark reading (no film, no light), subtracted from every reading first")
    p.add_argument("--reference", type=input_file, help="reading of the lamp (or of a reflector) alone, same spectrometer")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--n-film", default=None,
                   help="film index: a number or a preset (soap, water); default soap (1.324188 + 3102.06/lambda^2)")
    g.add_argument("--cauchy", metavar="A,B[,C]", help="film index n = A + B/lambda^2 + C/lambda^4, lambda in nm")
    p.add_argument("--thickness-range", default="0,15000", metavar="MIN,MAX",
                   help="thicknesses searched, nm (default 0,15000)")
    p.add_argument("--wavelength-range", metavar="MIN,MAX", help="wavelengths used, nm (default: the whole reading)")
    p.add_argument("--wavelength-unit", choices=("nm", "Angstrom", "um", "m"), default=None,
                   help="unit of the files' wavelengths (default: read from their range: nm 100-2500, Angstrom "
                        "1000-25000, um 0.1-2.5, m 1e-7-2.5e-6)")
    p.add_argument("--lamp-terms", type=int, default=None,
                   help="smooth lamp terms (Legendre in wavenumber, kept non-negative); default 5, 1 with "
                        "--reference, 3 with --normalised")
    g2 = p.add_mutually_exclusive_group()
    g2.add_argument("--normalised", dest="normalised", action="store_const", const=True, default=None,
                    help="the readings were already divided by the lamp (a flat envelope up to a tilt): the lamp "
                         "left is a scale, tilt and curvature (3 terms) and the stray light gets a tilt, so that "
                         "neither can imitate a fringe (default: decided from the readings' envelopes, and said)")
    g2.add_argument("--not-normalised", dest="normalised", action="store_const", const=False,
                    help="the readings are raw (not divided by the lamp), whatever their envelopes look like")
    p.add_argument("--background-terms", type=int, default=None, metavar="K",
                   help="smooth stray-light terms added beyond the offset (Legendre in wavenumber, or the "
                        "reference times a series with --reference); default 0, or 1 with --normalised")
    p.add_argument("--incoherent", action="store_true",
                   help="also fit lamp light that reaches the spectrometer without interfering, L (R + b) (a window "
                        "or frame in the beam, a spot spanning many orders: fringe minima lifted in proportion to "
                        "the lamp); more freedom, so thin films without a reference become more ambiguous")
    p.add_argument("--no-offset", action="store_true", help="do not fit a constant stray-light offset")
    g3 = p.add_mutually_exclusive_group()
    g3.add_argument("--shared-lamp", "--series", dest="series", action="store_const", const=True, default=None,
                    help="the files are one series under the same lamp (a draining film): the readings that can be "
                         "read alone fit the lamp, and the others (films under a fringe, down to the black film) "
                         "are read with it, from their brightness; needs at least 3 readings that are ok alone "
                         "(default: on for 5 or more files on the same wavelengths)")
    g3.add_argument("--no-series", dest="series", action="store_const", const=False,
                    help="read every file alone, even when they look like one series")
    p.add_argument("--series-by", choices=("auto", "folder", "name", "one"), default="auto",
                   help="what tells the series apart when the files on one instrument come from several films: each "
                        "folder, each name stem (the name less its trailing number), or none (one series in the "
                        "order given); they share the lamp, each keeps its own time order (default auto: by folder "
                        "when the files lie in several, else by name stem when there are several)")
    p.add_argument("--unordered", action="store_true",
                   help="the series' files are not in time order (default: in order when their names, or else "
                        "their modification times, are; a reading that jumps to its neighbours' twin is then "
                        "not ok)")
    p.add_argument("--wavelengths", metavar="FILE", type=input_file,
                   help="a .npy cube's wavelengths, one a line (other cube formats carry their own)")
    p.add_argument("--band-fwhm", type=float, default=0.0, metavar="NM",
                   help="a cube's bands' width (FWHM, nm): fringes finer than a band are washed out (default 0)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler (tcp://host:port) whose workers fit a cube's blocks (they must read the "
                        "cube at the same path)")
    p.add_argument("--csv", type=output_file, help="CSV, one row per file: " + ",".join(_CSV_COLUMNS[:4]) + ",...")
    p.add_argument("--json", type=output_file, help="JSON with one entry per file")
    p.add_argument("-o", "--output", metavar="PLOT_PREFIX", type=output_prefix,
                   help="write PLOT_PREFIX_<file>.png per file (a spectral image: PREFIX_thickness.exr/.png and "
                        "PREFIX_thickness_stderr.exr/.png, or a line scan's PREFIX_profile.csv/.png)")
    p.add_argument("--strict", action="store_true", help="exit 1 when any file's result is not ok")
    p.set_defaults(func=run)


def _pair(text: str, name: str) -> tuple[float, float]:
    from .common import parse_floats

    lo, hi = parse_floats(text, 2, name)
    if not (0 <= lo < hi) or hi == float("inf"):
        raise InputError(f"{name} must be MIN,MAX with 0 <= MIN < MAX, got {text!r}")
    return lo, hi


def _check_outputs(args) -> None:
    """No output may be one of the inputs or another output, and every output's folder is writable
    (:func:`.common.guard_args`)."""
    from .common import guard_args

    if args.output and len({Path(s).stem for s in args.spectra}) < len(args.spectra):
        raise InputError("two spectra have the same file name; their plots would collide (run them separately)")
    plots = [f"{args.output}_{Path(s).stem}.png" for s in args.spectra] if args.output else []
    if args.output and _is_series(args, None):
        plots.append(f"{args.output}_series.png")
    guard_args(args, outputs=plots)


def run(args) -> int:
    from ..inverse.spectrum import SpectrumOptions, fit_spectrum
    from ..inverse import series_groups
    from ..inverse.spectrum_series import fit_spectrum_series, series_brightness
    from ..io.spectra import read_spectrum
    from ..optics import dispersion
    from ..progress import status
    from .common import film_index, write_json

    index = film_index(args.n_film, args.cauchy, "soap")
    opts = SpectrumOptions(
        n_film=index, thickness_range=_pair(args.thickness_range, "--thickness-range"),
        wavelength_range=_pair(args.wavelength_range, "--wavelength-range") if args.wavelength_range else None,
        lamp_terms=args.lamp_terms, offset=not args.no_offset, normalised=args.normalised,
        background_terms=args.background_terms, incoherent=args.incoherent)
    if args.lamp_terms is not None and not 1 <= args.lamp_terms <= 20:
        raise InputError(f"--lamp-terms must be within 1..20, got {args.lamp_terms}")
    if args.background_terms is not None and not 0 <= args.background_terms <= 10:
        raise InputError(f"--background-terms must be within 0..10, got {args.background_terms}")
    from ..io.cubes import is_cube_path

    if any(is_cube_path(p) for p in args.spectra):
        if len(args.spectra) > 1:
            raise InputError("give one spectral image (cube or line scan) per run, without other spectra")
        return _run_cube(args, opts)
    _check_outputs(args)
    unit = args.wavelength_unit
    dark = read_spectrum(args.dark, unit, dark=True) if args.dark else None
    reference = read_spectrum(args.reference, unit) if args.reference else None
    spectra = [read_spectrum(p, unit) for p in args.spectra]  # every file is checked before any work
    for spec in [s for s in (dark, reference) if s is not None] + spectra:
        if spec.unit != "nm" and unit is None:
            print(f"note: {spec.path}: wavelengths read as {spec.unit} (from their range), converted to nm")
        if spec.skipped:
            print(f"warning: {spec.path}: skipped {spec.skipped} rows that are not finite numbers", file=sys.stderr)
    series = _is_series(args, spectra)
    groups = None
    if series:
        groups = series_groups([s.path for s in spectra], args.series_by, False if args.unordered else None)
        why = "--series" if args.series else "same wavelengths; --no-series to read each alone"
        if len(groups) == 1:
            g = groups[0]
            print(f"series: the {len(spectra)} files are read as one series under one lamp ({why}); "
                  + (f"in time order ({g.order_why})" if g.ordered else f"not in time order ({g.order_why})"))
        else:
            print(f"series: the {len(spectra)} files are {len(groups)} series (one per {groups[0].by}) on one "
                  f"instrument, read under one lamp shared by all ({why}); each keeps its own time order "
                  "(--series-by one: a single series)")
            for g in groups:
                print(f"  {g.key or '(given)'}: {len(g.indices)} files, "
                      + (f"in time order ({g.order_why})" if g.ordered else f"not in time order ({g.order_why})"))
        from ..inverse import same_grid

        if not same_grid(spectra):
            print("warning: the series' files have different wavelengths: the shared lamp is one smooth series over "
                  "their common wavenumber range, each reading read at its own wavelengths", file=sys.stderr)
        results, lamp = fit_spectrum_series(spectra, dark=dark, reference=reference, options=opts,
                                            progress=lambda stage, k, n: status(
                                                f"reading {spectra[k].path} ({stage}, {k + 1}/{n}) ..."),
                                            groups=groups)
        if results and results[0].normalised_why:
            print(f"series: {results[0].normalised_why}")
        if lamp is not None:
            print(f"shared lamp: fitted to {len(lamp.pinning)} of {len(spectra)} readings; their brightness "
                  f"spreads by {lamp.scale_spread:.1%}")
            if len(groups) > 1:
                bright = series_brightness(lamp, groups)
                for g in groups:
                    b = bright[g.indices[0]]
                    print(f"  {g.key}: read at {b.why}, spread {b.spread:.1%}")
    else:
        results, lamp = None, None
    rows = []
    for k, spec in enumerate(spectra):
        if results is None:
            status(f"fitting {spec.path} ({k + 1}/{len(spectra)}) ...")
            res = fit_spectrum(spec, dark=dark, reference=reference, options=opts)
        else:
            res = results[k]
        row = {"file": spec.path, **res.summary()}
        rows.append(row)
        if args.output:
            _plot(res, Path(f"{args.output}_{Path(spec.path).stem}.png"), spec.path)
        sd = res.thickness_nm_stderr
        print(f"{spec.path}: {res.thickness_nm:.1f} +- {sd:.2g} nm, order {res.order}, "
              + ("ok" if res.ok else "NOT ok: " + "; ".join(res.reasons)))
        if not series and res.normalised_why and args.normalised is None:
            print(f"  {res.normalised_why}")
        for w in res.warnings:
            print(f"  warning: {w}")
    if args.output and series:
        _plot_series(rows, Path(f"{args.output}_series.png"))
    if args.csv:
        _write_csv(args.csv, rows)
    if args.json:
        paths = [s.path for s in spectra]
        shared = None if lamp is None else {
            "pinning": [paths[i] for i in lamp.pinning], "scale_spread": lamp.scale_spread,
            "coefficients": [float(c) for c in lamp.coefficients],
            "stray_coefficients": None if lamp.stray is None else [float(c) for c in lamp.stray],
            "wavenumber_range_per_nm": list(lamp.nu_range), "series_sharing": len(groups),
            "why": ("one series under one lamp" if len(groups) == 1 else
                    f"{len(groups)} series (one per {groups[0].by}) on the same wavelengths (one spectrometer): one "
                    "lamp fitted to the readings of all of them that can be read alone, each series' time order its own")}
        write_json(args.json, {"n_film": dispersion.describe(index), "dark": args.dark, "reference": args.reference,
                               "series": None if groups is None else _series_json(groups, paths, lamp),
                               "shared_lamp": shared, "ok": all(r["ok"] for r in rows), "spectra": rows})
    return 1 if args.strict and not all(r["ok"] for r in rows) else 0


def _series_json(groups, paths, lamp) -> list[dict]:
    """Each series' files, time order and, with a shared lamp, the brightness it was read at."""
    from ..inverse.spectrum_series import series_brightness

    out = [g.summary(paths) for g in groups]
    if lamp is not None:
        bright = series_brightness(lamp, groups)
        for g, entry in zip(groups, out):
            b = bright[g.indices[0]]
            entry.update(lamp_scale=b.scale, lamp_scale_spread=b.spread, lamp_scale_from=b.why)
    return out


def _cube_outputs(args, line: bool) -> list[str]:
    if not args.output:
        return []
    if line:
        return [f"{args.output}_profile.csv", f"{args.output}_profile.png"]
    return [f"{args.output}_{name}.{ext}" for name in ("thickness", "thickness_stderr") for ext in ("exr", "png")]


def _run_cube(args, opts) -> int:
    """A spectral image: its thickness map (see the module's description)."""
    import numpy as np

    from ..inverse.spectral_map import MapOptions, fit_cube
    from ..io.cubes import read_cube
    from ..io.spectra import read_spectrum
    from ..optics import dispersion
    from ..progress import status
    from .common import guard_args, write_json

    if args.series or args.normalised or args.incoherent:
        raise InputError("--shared-lamp, --normalised and --incoherent are for single readings; a cube's lamp is "
                         "shared by its pixels already")
    if not (args.output or args.json):
        raise InputError("a spectral image needs -o PREFIX (the maps) or --json")
    cube = read_cube(args.spectra[0], wavelengths=args.wavelengths, unit=args.wavelength_unit)
    outputs = _cube_outputs(args, cube.is_line)
    guard_args(args, outputs=outputs)
    if not np.isfinite(args.band_fwhm) or not 0 <= args.band_fwhm <= 50:
        raise InputError(f"--band-fwhm must be within 0..50 nm, got {args.band_fwhm:g}")
    dark = read_spectrum(args.dark, args.wavelength_unit, dark=True) if args.dark else None
    reference = read_spectrum(args.reference, args.wavelength_unit) if args.reference else None
    mopts = MapOptions(n_film=opts.n_film, thickness_range=opts.thickness_range,
                       wavelength_range=opts.wavelength_range, resolution_nm=args.band_fwhm,
                       lamp_terms=args.lamp_terms or MapOptions.lamp_terms)
    h, w = cube.shape
    if cube.unit != "nm" and args.wavelength_unit is None:
        print(f"note: {cube.path}: wavelengths read as {cube.unit} (from their range), converted to nm")
    tmap = fit_cube(cube, options=mopts, dark=dark, reference=reference, scheduler=args.scheduler,
                    progress=lambda stage, k, n: status(f"{cube.path}: {stage} block {k + 1}/{n} ..."))
    summ = tmap.summary()
    kind = "line scan" if cube.is_line else "cube"
    print(f"{cube.path}: {kind} {h}x{w}x{len(cube.wavelength_nm)}, median thickness {summ['median_thickness_nm']:.1f} nm, "
          f"median stderr {summ['median_stderr_nm']:.2g} nm, {summ['fraction_ok']:.1%} of pixels ok")
    for note in tmap.notes:
        print(f"  {note}")
    if args.output:
        _write_cube_outputs(args.output, tmap, cube.is_line)
    if args.json:
        write_json(args.json, {"cube": cube.path, "kind": kind, "n_film": dispersion.describe(opts.n_film),
                               "dark": args.dark, "reference": args.reference, "outputs": outputs, **summ})
    return 1 if args.strict and summ["fraction_ok"] < 1.0 else 0


def _write_cube_outputs(prefix: str, tmap, line: bool) -> None:
    """The map and its standard error as EXR (32-bit float, nm) and PNG with a colour bar in
    nm; a line scan's profile as CSV and a plot."""
    import numpy as np

    from ..io.atomic import write_text
    from ..io.images import write_image
    from ..report.figures import map_figure

    t = np.where(tmap.ok, tmap.thickness_nm, np.nan)
    if line:
        rows = ["row,thickness_nm,thickness_nm_stderr,ok"]
        rows += [f"{i},{d:.6g},{e:.6g},{'true' if k else 'false'}" for i, (d, e, k) in
                 enumerate(zip(tmap.thickness_nm[:, 0], tmap.stderr_nm[:, 0], tmap.ok[:, 0]))]
        write_text(f"{prefix}_profile.csv", "\n".join(rows) + "\n")
        _plot_profile(tmap, f"{prefix}_profile.png")
        return
    write_image(f"{prefix}_thickness.exr", tmap.thickness_nm, bit_depth=32)
    write_image(f"{prefix}_thickness_stderr.exr", np.where(np.isfinite(tmap.stderr_nm), tmap.stderr_nm, np.nan),
                bit_depth=32)
    map_figure(Path(f"{prefix}_thickness.png"), t, "film thickness", "viridis", "thickness (nm)")
    map_figure(Path(f"{prefix}_thickness_stderr.png"), np.where(tmap.ok, tmap.stderr_nm, np.nan),
               "its standard error", "magma", "standard error (nm)")


def _plot_profile(tmap, path: str) -> None:
    """A line scan's thickness along the slit, with its error bars; not-ok rows marked."""
    _plot_along(tmap.thickness_nm[:, 0], tmap.stderr_nm[:, 0], tmap.ok[:, 0], "row along the slit", path)


#: Fewest files read as one series without --series: enough for the shared lamp's
#: pinning readings (3) and some to read with it.
SERIES_MIN_FILES = 5


def _is_series(args, spectra) -> bool:
    """Whether the files are read as one series: as forced, else 5 or more files on the
    same wavelengths (before they are read: whether it may be, for the outputs' names)."""
    if args.series is not None:
        return args.series
    if len(args.spectra) < SERIES_MIN_FILES:
        return False
    if spectra is None:
        return True
    from ..inverse import same_grid

    return same_grid(spectra)


def _write_csv(path, rows) -> None:
    import csv

    from ..io.images import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(_CSV_COLUMNS)
            for r in rows:
                vals = []
                for c in _CSV_COLUMNS:
                    v = r[c]
                    if isinstance(v, list):
                        v = " | ".join(v)
                    elif isinstance(v, bool):
                        v = "true" if v else "false"
                    elif isinstance(v, float):
                        v = f"{v:.10g}"
                    vals.append(v)
                w.writerow(vals)


def _plot(res, path: Path, name: str) -> None:
    """Measured and fitted spectra, the residual, and the profile ``chi^2`` against thickness."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from ..io.images import atomic_path

    fig, ax = plt.subplots(3, 1, figsize=(8, 8), dpi=110, gridspec_kw={"height_ratios": [3, 1, 2]})
    ax[0].plot(res.wavelength_nm, res.measured, ".", ms=2, color="0.4", label="measured (dark subtracted)")
    ax[0].plot(res.wavelength_nm, res.fitted, "-", lw=1, color="C3",
               label=f"fit: {res.thickness_nm:.1f} +- {res.thickness_nm_stderr:.2g} nm")
    ax[0].set_ylabel("intensity")
    ax[0].legend(fontsize=8)
    ax[0].set_title(f"{Path(name).name}: order {res.order}, " + ("ok" if res.ok else "not ok"), fontsize=9)
    ax[1].plot(res.wavelength_nm, res.measured - res.fitted, ".", ms=2, color="C0")
    ax[1].axhline(0, color="k", lw=0.5)
    ax[1].set_ylabel("residual")
    ax[1].set_xlabel("wavelength (nm)")
    ax[2].semilogy(res.profile_nm, np.maximum(res.profile_chi2, 1e-2), lw=0.8)
    ax[2].axvline(res.thickness_nm, color="C3", lw=0.8)
    ax[2].set_xlabel("thickness (nm)")
    ax[2].set_ylabel("profile delta chi2")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def _plot_series(rows, path: Path) -> None:
    """The series' thicknesses in file order with their error bars, ok and not ok apart."""
    import numpy as np

    _plot_along(np.array([r["thickness_nm"] for r in rows]), np.array([r["thickness_nm_stderr"] for r in rows]),
                np.array([bool(r["ok"]) for r in rows]), "reading (file order)", path)


def _plot_along(d, e, ok, xlabel: str, path) -> None:
    """Thicknesses (nm) in order with their error bars (infinite ones drawn as none), ok
    and not ok apart (matplotlib, written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from ..io.images import atomic_path

    k = np.arange(len(d))
    e = np.where(np.isfinite(e), e, 0.0)
    fig, ax = plt.subplots(figsize=(8, 4), dpi=110)
    ax.errorbar(k[ok], d[ok], e[ok], fmt="o", ms=3, lw=0.8, color="C0", label="ok")
    ax.errorbar(k[~ok], d[~ok], e[~ok], fmt="x", ms=4, lw=0.8, color="C3", label="not ok")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("thickness (nm)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
