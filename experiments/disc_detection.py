"""Disc detection on independent photos: error of find_disc against the true disc.

Runs :func:`bubblefit.capture.disc.find_disc` on every case of the validation set
(photos rendered by Blender Cycles, Mitsuba 3 and a separate reference renderer), with
and without the background photo, and prints, for each, whether a disc was found, the
centre and radius errors in pixels, the rim support and contrast, and the time. Saves
``disc_detection.json``, ``disc_detection.csv`` and ``disc_detection.png`` (radius
error per case, and with several scales or Hough sizes the median time per photo size)
in the output folder.

Each row also says what ``bubblefit fit`` does with the photo when no disc is given
(:func:`bubblefit.inverse._observation.resolve_disc`: the disc it fits, or its one-line
refusal). ``--demo-sizes 48,64,96,160,320`` adds the demo's synthetic capture
(:func:`bubblefit.demo.synthesize`) with the map unrotated, ``--demo-seeds`` times per
size: the bright wall is then behind the bubble and its rim is faint against the dark
sky, while edges inside the bubble (the wall's transmitted image, the reflection's
bands) are strong. A disc more than 1.5 px off that is declared found is counted wrong.

``--scales 1,2,3`` also runs each case enlarged (both photos resized by the factor,
bilinear: the same scene seen by a sensor with more pixels; errors are reported in the
original pixels), and ``--hough-sizes 200,0`` runs each photo once per size of the copy
that the Hough transform searches (``bubblefit.capture.disc.HOUGH_SIZE``; 0: the photo
itself), the settings taking turns photo by photo, so that each is the other's
yardstick in the same run.

    PYTHONPATH=. python experiments/disc_detection.py [DATA_DIR] [-o OUT_DIR] [--scales 1,2,3] [--hough-sizes 200,0]
        [--demo-sizes 48,64,96,160,320 --demo-seeds 0,1,2]
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

import bubblefit.capture.disc as disc_module
from bubblefit.capture.disc import find_disc
from bubblefit.errors import InputError
from bubblefit.io.images import read_image

DEFAULT_DATA = Path(__file__).resolve().parent / "validation" / "data"


def demo_cases(out: Path, sizes, seeds) -> list[Path]:
    """Folders of the demo's capture with the map unrotated (photo, background, truth.json)."""
    from bubblefit.demo import DemoTruth, synthesize

    folders = []
    for size in sizes:
        for seed in seeds:
            folder = out / "demo_faint_rim" / f"demo_rot0_{size}px_seed{seed}"
            if not (folder / "truth.json").exists():
                syn = synthesize(folder, size, seed, DemoTruth(rotation_deg=0.0))
                cx, cy, r = syn["disc"]
                (folder / "truth.json").write_text(json.dumps({"disc": {"cx": cx, "cy": cy, "r": r}}) + "\n")
            folders.append(folder)
    return folders


def fit_disc(photo, background, disc) -> dict:
    """What ``bubblefit fit`` does without ``--disc``: the disc's errors, or its refusal."""
    from bubblefit.inverse._observation import resolve_disc
    from bubblefit.inverse.fit import FitOptions

    try:
        (cx, cy, r), _ = resolve_disc(photo, background, FitOptions())
    except InputError as exc:
        return {"fit_found": False, "fit_reason": str(exc)}
    out = {"fit_found": True, "fit_reason": ""}
    if disc is not None:
        out["fit_err"] = max(abs(cx - disc["cx"]), abs(cy - disc["cy"]), abs(r - disc["r"]))
    return out


def run_case(folder: Path, scales=(1,), hough_sizes=(disc_module.HOUGH_SIZE,)) -> list[dict]:
    import cv2

    truth = json.loads((folder / "truth.json").read_text())
    names = ("photo.png", "background.png") if (folder / "photo.png").exists() else ("after.png", "before.png")
    photo, back = (read_image(folder / n).pixels for n in names)
    disc = truth.get("disc")
    rows = []
    for scale in scales:
        size = lambda a: a if scale == 1 else cv2.resize(a.astype(np.float32), None, fx=scale, fy=scale,  # noqa: E731
                                                         interpolation=cv2.INTER_LINEAR).astype(np.float64)
        p, b = size(photo), size(back)
        for with_bg in (True, False):
            for hough in hough_sizes:
                disc_module.HOUGH_SIZE = hough or 10**9
                t0 = time.perf_counter()
                d = find_disc(p, b if with_bg else None)
                row = {"case": folder.name, "set": "demo" if folder.parent.name == "demo_faint_rim" else "validation",
                       "scale": scale, "hough_size": hough, "background": with_bg,
                       "found": d.found, "cx": d.cx / scale, "cy": d.cy / scale, "r": d.r / scale,
                       "support": d.support, "contrast": d.contrast, "time_s": time.perf_counter() - t0,
                       "pixels": p.shape[0] * p.shape[1],
                       "expect_disc": disc is not None and "nobubble" not in folder.name, "reason": d.reason}
                if disc is not None and d.found:
                    row.update(err_cx=row["cx"] - disc["cx"], err_cy=row["cy"] - disc["cy"], err_r=row["r"] - disc["r"])
                if scale == 1:
                    row.update(fit_disc(p, b if with_bg else None, disc))
                rows.append(row)
    return rows


def _tally(rows, set_, scale, hough, bg) -> dict:
    """Cases with a bubble found within 1.5 px, wrong (found further off) and not found, by
    ``find_disc`` and by the fit (a refusal is neither right nor wrong)."""
    sel = [r for r in rows if r["set"] == set_ and r["background"] == bg and r["expect_disc"] and r["scale"] == scale
           and r["hough_size"] == hough]
    good = [r for r in sel if r["found"] and max(abs(r["err_cx"]), abs(r["err_cy"]), abs(r["err_r"])) < 1.5]
    wrong = [r for r in sel if r["found"] and r not in good]
    times = [r["time_s"] for r in rows if r["set"] == set_ and r["background"] == bg and r["scale"] == scale
             and r["hough_size"] == hough]
    fits = [r for r in sel if "fit_found" in r]
    fit_good = [r for r in fits if r["fit_found"] and r["fit_err"] < 1.5]
    fit_wrong = [r for r in fits if r["fit_found"] and r["fit_err"] >= 1.5]
    return {"set": set_, "scale": scale, "hough_size": hough, "background": bg, "cases": len(sel),
            "within_1_5_px": len(good), "wrong": len(wrong), "not_found": len(sel) - len(good) - len(wrong),
            "fit_within_1_5_px": len(fit_good) if fits else None, "fit_wrong": len(fit_wrong) if fits else None,
            "fit_refused": len(fits) - len(fit_good) - len(fit_wrong) if fits else None,
            "median_time_s": float(np.median(times)), "max_time_s": float(np.max(times))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(DEFAULT_DATA))
    ap.add_argument("-o", "--out", default="experiments/results")
    ap.add_argument("--scales", default="1", help="comma-separated enlargements of every case (default: 1)")
    ap.add_argument("--demo-sizes", default="", help="comma-separated sizes of the demo's capture with the map "
                    "unrotated (a faint rim), run as further cases (default: none)")
    ap.add_argument("--demo-seeds", default="0", help="comma-separated noise seeds of those (default: 0)")
    ap.add_argument("--hough-sizes", default=str(disc_module.HOUGH_SIZE),
                    help="comma-separated HOUGH_SIZE values, 0 for the photo itself (default: %(default)s)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scales = [int(v) for v in args.scales.split(",")]
    hough_sizes = [int(v) for v in args.hough_sizes.split(",")]
    rows = []
    # a case is a photo with its background photo (or a calibration pair); the cap and flat
    # film cases have neither, and their bubbles are not discs
    folders = [f.parent for f in sorted(Path(args.data).glob("*/truth.json"))
               if (f.parent / "background.png").exists() or (f.parent / "before.png").exists()]
    demo = demo_cases(out, [int(v) for v in args.demo_sizes.split(",")],
                      [int(v) for v in args.demo_seeds.split(",")]) if args.demo_sizes else []
    for folder in folders + demo:
        for r in run_case(folder, scales if folder not in demo else (1,), hough_sizes):
            errs = " ".join(f"{k}={r[k]:+.2f}" for k in ("err_cx", "err_cy", "err_r") if k in r)
            bg = "yes" if r["background"] else "no "
            fit = "" if "fit_found" not in r else (f" fit: {r['fit_err']:.2f} px" if r["fit_found"] and "fit_err" in r
                                                   else f" fit: {r['fit_reason'] or 'a disc'}")
            print(f"{r['case']:34s} x{r['scale']} hough {r['hough_size']:4d} bg={bg} "
                  f"found={r['found']!s:5s} {errs:38s} support={r['support']:.2f} {r['time_s']:.2f}s {r['reason']}"
                  f"{fit}", flush=True)
            rows.append(r)
    keys = ["case", "set", "scale", "hough_size", "pixels", "background", "found", "expect_disc", "err_cx", "err_cy", "err_r",
            "support", "contrast", "time_s", "reason", "fit_found", "fit_err", "fit_reason"]
    summary = []
    for set_ in sorted({r["set"] for r in rows}, reverse=True):
        for scale in sorted({r["scale"] for r in rows if r["set"] == set_}):
            for hough in hough_sizes:
                for bg in (True, False):
                    summary.append(_tally(rows, set_, scale, hough, bg))
                    s_ = summary[-1]
                    fit = "" if s_["fit_within_1_5_px"] is None else (
                        f"; fit: {s_['fit_within_1_5_px']} within 1.5 px, {s_['fit_wrong']} wrong, "
                        f"{s_['fit_refused']} refused")
                    print(f"{set_} x{scale} hough {hough:4d} {'with' if bg else 'without'} background: "
                          f"{s_['within_1_5_px']}/{s_['cases']} within 1.5 px, {s_['wrong']} wrong, "
                          f"{s_['not_found']} not found{fit}; median {s_['median_time_s']:.2f} s, "
                          f"max {s_['max_time_s']:.2f} s per photo")
    (out / "disc_detection_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out / "disc_detection.json").write_text(json.dumps(rows, indent=2, default=float) + "\n")
    with open(out / "disc_detection.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    timing = len(scales) > 1 or len(hough_sizes) > 1
    fig, axes = plt.subplots(1, 2 if timing else 1, figsize=(13 if timing else 9, 4), squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1]} if timing else None)
    ax = axes[0, 0]
    for bg, mk in ((True, "o"), (False, "x")):
        sel = [r for r in rows if r["background"] == bg and "err_r" in r and r["scale"] == scales[0]
               and r["hough_size"] == hough_sizes[0]]
        ax.plot([r["case"] for r in sel], [abs(r["err_r"]) for r in sel], mk, label="with" if bg else "without")
    ax.axhline(1.5, color="gray", lw=0.8)
    ax.set_ylabel("|radius error| (px)")
    ax.set_yscale("log")
    ax.legend(title="background photo")
    ax.tick_params(axis="x", rotation=80, labelsize=7)
    if timing:
        ax = axes[0, 1]
        for i, hough in enumerate(hough_sizes):
            for bg, ls in ((True, "-"), (False, "--")):
                sel = [s_ for s_ in summary if s_["hough_size"] == hough and s_["background"] == bg
                       and s_["set"] == "validation"]
                px = [np.median([r["pixels"] for r in rows if r["scale"] == s_["scale"]]) for s_ in sel]
                ax.plot(px, [s_["median_time_s"] for s_ in sel], ls, marker="o", color=f"C{i}",
                        label=f"Hough on {hough or 'the photo'}{' px' if hough else ''}, "
                              f"{'with' if bg else 'without'} background")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("pixels per photo (median)")
        ax.set_ylabel("find_disc, median seconds")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "disc_detection.png", dpi=120)
    print("wrote", out / "disc_detection.json", out / "disc_detection.csv", out / "disc_detection.png")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
