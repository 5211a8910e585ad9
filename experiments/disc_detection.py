"""Disc detection on independent photos: error of find_disc against the true disc.

Runs :func:`bubblefit.capture.disc.find_disc` on every case of the validation set
(photos rendered by Blender Cycles, Mitsuba 3 and a separate reference renderer), with
and without the background photo, and prints, for each, whether a disc was found, the
centre and radius errors in pixels, the rim support and contrast, and the time. Saves
``disc_detection.json``, ``disc_detection.csv`` and ``disc_detection.png`` (radius
error per case) in the output folder.

    PYTHONPATH=. python experiments/disc_detection.py [DATA_DIR] [-o OUT_DIR]
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from bubblefit.capture.disc import find_disc
from bubblefit.io.images import read_image

DEFAULT_DATA = Path(__file__).resolve().parent / "validation" / "data"


def run_case(folder: Path) -> list[dict]:
    truth = json.loads((folder / "truth.json").read_text())
    names = ("photo.png", "background.png") if (folder / "photo.png").exists() else ("after.png", "before.png")
    photo, back = (read_image(folder / n).pixels for n in names)
    disc = truth.get("disc")
    rows = []
    for with_bg in (True, False):
        t0 = time.perf_counter()
        d = find_disc(photo, back if with_bg else None)
        row = {"case": folder.name, "background": with_bg, "found": d.found, "cx": d.cx, "cy": d.cy, "r": d.r,
               "support": d.support, "contrast": d.contrast, "time_s": time.perf_counter() - t0,
               "expect_disc": disc is not None and "nobubble" not in folder.name, "reason": d.reason}
        if disc is not None and d.found:
            row.update(err_cx=d.cx - disc["cx"], err_cy=d.cy - disc["cy"], err_r=d.r - disc["r"])
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(DEFAULT_DATA))
    ap.add_argument("-o", "--out", default="experiments/results")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [r for f in sorted(Path(args.data).glob("*/truth.json")) for r in run_case(f.parent)]
    keys = ["case", "background", "found", "expect_disc", "err_cx", "err_cy", "err_r", "support", "contrast", "time_s",
            "reason"]
    for r in rows:
        errs = " ".join(f"{k}={r[k]:+.2f}" for k in ("err_cx", "err_cy", "err_r") if k in r)
        print(f"{r['case']:34s} bg={'yes' if r['background'] else 'no ':3s} found={r['found']!s:5s} {errs:38s} "
              f"support={r['support']:.2f} {r['time_s']:.1f}s {r['reason']}")
    for bg in (True, False):
        sel = [r for r in rows if r["background"] == bg and r["expect_disc"]]
        good = [r for r in sel if r["found"] and max(abs(r["err_cx"]), abs(r["err_cy"]), abs(r["err_r"])) < 1.5]
        wrong = [r for r in sel if r["found"] and r not in good]
        print(f"{'with' if bg else 'without'} background: {len(good)}/{len(sel)} within 1.5 px, "
              f"{len(wrong)} wrong, {len(sel) - len(good) - len(wrong)} not found")
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
    fig, ax = plt.subplots(figsize=(9, 4))
    for bg, mk in ((True, "o"), (False, "x")):
        sel = [r for r in rows if r["background"] == bg and "err_r" in r]
        ax.plot([r["case"] for r in sel], [abs(r["err_r"]) for r in sel], mk, label="with" if bg else "without")
    ax.axhline(1.5, color="gray", lw=0.8)
    ax.set_ylabel("|radius error| (px)")
    ax.set_yscale("log")
    ax.legend(title="background photo")
    ax.tick_params(axis="x", rotation=80, labelsize=7)
    fig.tight_layout()
    fig.savefig(out / "disc_detection.png", dpi=120)
    print("wrote", out / "disc_detection.json", out / "disc_detection.csv", out / "disc_detection.png")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
