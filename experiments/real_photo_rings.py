"""The sodium ring photos' dark-ring diameters by direction and by ring, against the fit's R.

For each ring photo of experiments/real_photos.py (640x480 JPEG, the green channel decoded
from sRGB), intensity profiles along four lines through the fitted contact point (0, 45,
90 and 135 degrees; the mean of a 3-pixel-wide strip, smoothed by a Gaussian of half a
pixel) give the dark rings' positions on both sides (the vertex of a parabola through
each clear minimum: 3 % below the local median and the lowest within 12 pixels). The
rings' diameters then give the lens's radius from the textbook line ``D_k^2 = 4 k lambda R
+ c`` (Born and Wolf, *Principles of Optics*, sec. 7.5.3; Hecht, *Optics*, sec. 9.4), per
direction, for the students' rings (k = 5..14, matched by their first diameter), and for
the inner and outer halves of the rings found. An imaging aspect ratio shows as radii
that differ with the direction (an ellipse: ``R(theta)`` varies as ``cos 2 theta``); a gap
that is not ``h0 + r^2 / (2 R)`` as radii that differ with the rings used.

Run: ``python experiments/real_photo_rings.py --from DIR`` (DIR holds ``rings_<R>.jpg``
as experiments/real_photos.py writes them; seconds). Writes
``experiments/results/real_photos/ring_diameters.json``; reads the fit's contact point and
R from ``real_photos.json`` beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_photos as rp  # noqa: E402

DIRECTIONS = (0, 45, 90, 135)
#: Radius (full-resolution pixels) inside which no ring is sought: the photos' central
#: spot, flat out to 60-65 pixels.
CORE_PX = 70.0


def srgb_decode(code):
    """IEC 61966-2-1 sRGB code values in [0, 1] to linear."""
    return np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)


def dark_ring_diameters(lin, cx: float, cy: float, angle_deg: float) -> np.ndarray:
    """Diameters (pixels) of the dark rings along the line through ``(cx, cy)`` at ``angle_deg``,
    innermost first: the i-th minimum beyond :data:`CORE_PX` on one side with the i-th on the other."""
    from scipy import ndimage

    h, w = lin.shape
    t = np.deg2rad(angle_deg)
    s = np.arange(-800.0, 800.0, 0.25)
    xs, ys = cx + s * np.cos(t), cy + s * np.sin(t)
    ok = (xs >= 2) & (xs <= w - 3) & (ys >= 2) & (ys <= h - 3)
    s, xs, ys = s[ok], xs[ok], ys[ok]
    prof = np.mean([ndimage.map_coordinates(lin, [ys + d * np.cos(t), xs - d * np.sin(t)], order=1)
                    for d in (-1, 0, 1)], axis=0)
    prof = ndimage.gaussian_filter1d(prof, 2.0)  # 2 steps of 0.25 px
    idx = np.flatnonzero((prof[1:-1] < prof[:-2]) & (prof[1:-1] <= prof[2:])) + 1
    mins = []
    for k in idx:
        if not 3 <= k < len(prof) - 4:
            continue
        if prof[k] < 0.97 * np.median(prof[max(k - 24, 0):k + 25]) and prof[k] == prof[max(k - 12, 0):k + 13].min():
            a, b, _ = np.polyfit(s[k - 3:k + 4], prof[k - 3:k + 4], 2)
            mins.append(-b / (2 * a))
    mins = np.asarray(mins)
    left, right = np.sort(-mins[mins < -CORE_PX]), np.sort(mins[mins > CORE_PX])
    n = min(len(left), len(right))
    return left[:n] + right[:n]


def radius_mm(d_px, k) -> tuple[float, float]:
    """R (mm) and its standard error from the least-squares line ``D^2 = 4 k lambda R + c``."""
    d_mm = np.asarray(d_px) * rp.MM_PER_PX
    a = np.column_stack([4.0 * rp.SODIUM_NM * 1e-6 * np.asarray(k, float), np.ones(len(k))])
    coef, res, *_ = np.linalg.lstsq(a, d_mm ** 2, rcond=None)
    se = np.sqrt(res[0] / (len(k) - 2) * np.linalg.inv(a.T @ a)[0, 0]) if len(k) > 2 and res.size else float("nan")
    return float(coef[0]), float(se)


def main() -> int:
    from PIL import Image

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="source", type=Path, required=True, help="folder holding rings_<R>.jpg")
    args = ap.parse_args()
    fits = {p["stated_radius_mm"]: p for p in json.loads((rp.OUT / "real_photos.json").read_text())["photos"]}
    out = {"script": "experiments/real_photo_rings.py", "photos": []}
    for stated, rec in sorted(fits.items()):
        jpg = args.source / f"rings_{stated}.jpg"
        if not jpg.exists():
            print(f"{jpg} is missing: skipped", file=sys.stderr)
            continue
        lin = srgb_decode(np.asarray(Image.open(jpg), np.float64)[..., 1] / 255.0)
        g = rec["grey"]["params"]
        full = rec["pixel_um_binned"] / 2.0  # the fit's pixels are 2x2 bins; its centre in um from the corner
        cx, cy = g["center_x_um"] / full - 0.5, g["center_y_um"] / full - 0.5
        students = np.asarray(rp.DIAMETERS[stated]) * rp.VISIO_PX_PER_MM
        row = {"stated_radius_mm": stated, "fit_radius_mm": g["radius_mm"], "centre_px": [cx, cy],
               "students_radius_mm": radius_mm(students, np.arange(5, 15)), "directions": {}}
        for ang in DIRECTIONS:
            d = dark_ring_diameters(lin, cx, cy, ang)
            first = int(np.argmin(np.abs(d - students[0])))  # the students' k = 5
            m = min(len(d) - first, len(students))
            half = len(d) // 2
            row["directions"][str(ang)] = {
                "diameters_px": [round(float(v), 2) for v in d],
                "students_rings": {"k": [5, 4 + m], "radius_mm": radius_mm(d[first:first + m], np.arange(5, 5 + m)),
                                   "diameter_minus_students_px": [round(float(v), 2) for v in
                                                                  d[first:first + m] - students[:m]]},
                "inner_half": radius_mm(d[:half], np.arange(half)),
                "outer_half": radius_mm(d[half:], np.arange(half, len(d))),
            }
        out["photos"].append(row)
        print(stated, "fit", round(g["radius_mm"], 1), "students", np.round(row["students_radius_mm"], 1))
        for ang, v in row["directions"].items():
            print(f"  {ang:>3} deg: students' rings k {v['students_rings']['k']} R {v['students_rings']['radius_mm'][0]:.1f} "
                  f"+- {v['students_rings']['radius_mm'][1]:.1f}; inner half {v['inner_half'][0]:.1f}, "
                  f"outer half {v['outer_half'][0]:.1f} ({len(v['diameters_px'])} rings)")
    (rp.OUT / "ring_diameters.json").write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
