"""Real photographs through bubblefit, run as a new user runs it (the command line, the docs).

The photos are public but carry no licence that allows redistributing them, so this
script fetches them by commit (or reads them from ``--from DIR``) and the repository keeps
only the numbers, in ``experiments/results/real_photos/real_photos.json``:

* ``iTTiAQA/NewtonRingRadiusDetection`` (commit 9e52a64): three Newton's-rings photos of a
  student lab, sodium lamp, lenses of stated radius 850, 1000 and 1432 mm
  (``牛顿环_<R>.jpg``, 640x480 JPEG), a photo of a scale of 0.2 mm divisions, and the
  diameters of rings 5-14 the students measured on each photo (``Newton_data.py``: in
  Visio millimetres, 3.78 px each; the scale's five divisions span 77.3 px, 12.94 um/px).
* ``hemangdtu/Newtons_Rings_IR_Algorithm`` (commit dd494aa): two sodium-lamp ring photos
  through a travelling microscope (``test_1.jpg``, ``test_2.jpg``), no radius stated.
* ``exiftool/exiftool`` (commit 38bdbac, the Perl licence): ``t/images/DNG.dng``, a DNG
  whose image data is stripped (the tags kept).

What is run, for each ring photo with a stated radius:

1. ``bubblefit fit PHOTO --scene`` in colour, under the sodium doublet (a lamp CSV of two
   lines 0.05 nm wide at 588.995 and 589.592 nm, 2:1, the D lines' ratio): refused in
   one line, the sRGB response's blue channel sees no 589 nm light.
2. The grey reading a user can make of such a photo: the green channel (red is clipped at
   255 on most of the photo, blue is at the 8-bit floor), binned 2x2 (25.9 um pixels), a
   response CSV of three equal flat channels, so every channel is the one 589 nm
   intensity; the ``newton`` model of docs/films.md (air gap between BK7 glasses,
   coaxial light, NA 0.02), with its default stray reflectance fitted (``stray = "fit"``:
   light that does not interfere) and its default lamp envelope (``envelope = "auto"``:
   the lamp's fall-off across the field, fitted where the rings span enough fringes).
3. The yardstick on the same photo: the textbook line ``D_k^2 = 4 k lambda R + c`` through
   the students' ring diameters (k = 5..14, lambda = 589.3 nm), least squares, its slope's
   standard error from the residuals.

Run: ``python experiments/real_photos.py [--from DIR] [--only 1000] [--range-nm 20000]``
(minutes per photo on the 2-core machine: each fit's ``seconds``, ``cpu_seconds`` and
``peak_rss_mb`` are in its record). ``--range-nm`` is the top of the scene's ``range_nm``,
which bounds the per-pixel map the fit starts from (its table of every 2 nm at every
pixel: the memory grows with it); the lens's gap is not held within it.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "experiments" / "results" / "real_photos"

RINGS_REPO = "iTTiAQA/NewtonRingRadiusDetection"
RINGS_COMMIT = "9e52a64de9ab5b1d5cfd94ab85bdd58921863602"
RINGS_DIR = "实验1/原始数据/Pictures"
#: The students' ring diameters (k = 5..14) in Visio millimetres, from Newton_data.py.
DIAMETERS = {850: [77.36, 83.068, 88.211, 93.139, 97.625, 102.172, 106.361, 110.419, 114.423, 118.486],
             1000: [80.562, 87.22, 92.549, 98.281, 103.354, 108.574, 113.566, 118.178, 122.276, 126.548],
             1432: [92.007, 100.06, 107.338, 113.815, 120.044, 126.847, 131.975, 137.271, 142.982, 148.156]}
VISIO_PX_PER_MM = (640 / 169.333 + 480 / 127) / 2  # the students' Visio page of the 640x480 photo
MM_PER_PX = 0.2 * 5 / float(np.hypot(333 - 257, 83 - 69))  # five 0.2 mm divisions between their two dots
SODIUM_NM = 589.3

SCENE = """[film]
shape = "plane"
n = "air"
above = "bk7"
below = "bk7"
thickness = "newton"
range_nm = [0.0, {range_hi:.1f}]

[light]
type = "coaxial"
na = 0.02
lamp = "sodium.csv"

[camera]
width = 320
height = 240
pixel_um = {pixel_um:.4f}
{response}"""


def fetch(radius: int, source: Path | None, work: Path) -> Path:
    """The ring photo of the lens of stated ``radius`` (mm), from ``source`` or GitHub."""
    name = f"牛顿环_{radius}.jpg"
    dst = work / f"rings_{radius}.jpg"
    if source is not None:
        dst.write_bytes((source / name).read_bytes())
    else:
        quoted = urllib.request.quote(f"{RINGS_DIR}/{name}")
        url = f"https://raw.githubusercontent.com/{RINGS_REPO}/{RINGS_COMMIT}/{quoted}"
        with urllib.request.urlopen(url, timeout=60) as resp:
            dst.write_bytes(resp.read())
    return dst


def sodium_lamp(path: Path) -> None:
    """The sodium D doublet: Gaussian lines 0.05 nm wide, D2 (588.995 nm) twice D1 (589.592 nm)."""
    lam = np.arange(380.0, 780.0001, 0.01)
    power = np.exp(-0.5 * ((lam - 588.995) / 0.05) ** 2) + 0.5 * np.exp(-0.5 * ((lam - 589.592) / 0.05) ** 2)
    np.savetxt(path, np.column_stack([lam, power]), delimiter=",", header="wavelength_nm,power", comments="",
               fmt="%.2f,%.6g")


def grey_photo(jpg: Path, dst: Path) -> None:
    """The green channel binned 2x2, written as a grey 8-bit PNG (sRGB-coded, as the JPEG)."""
    from PIL import Image

    g = np.asarray(Image.open(jpg), np.float64)[..., 1]
    h, w = g.shape
    b = g[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
    Image.fromarray(np.repeat(np.round(b).astype(np.uint8)[..., None], 3, axis=2)).save(dst)


def textbook_radius(radius: int) -> tuple[float, float]:
    """R (mm) and its standard error from the students' ring diameters: D^2 = 4 k lambda R + c."""
    d_mm = np.asarray(DIAMETERS[radius]) * VISIO_PX_PER_MM * MM_PER_PX
    k = np.arange(5, 5 + len(d_mm))
    a = np.column_stack([4 * SODIUM_NM * 1e-6 * k, np.ones(len(k))])
    coef, res, *_ = np.linalg.lstsq(a, d_mm ** 2, rcond=None)
    cov = res[0] / (len(k) - 2) * np.linalg.inv(a.T @ a)
    return float(coef[0]), float(np.sqrt(cov[0, 0]))


def rings_start(png: Path, pixel_um: float, stated_mm: float) -> dict:
    """The fit's colour-free start on the grey photo alone (bubblefit.inverse._newton: the
    rings' centre of symmetry, their period ``lambda R`` in r^2), sRGB-decoded, at 589.3 nm;
    and the pixel scale that would make R the stated radius (R scales as the pixel squared)."""
    from PIL import Image

    from bubblefit.inverse._newton import _fringes, rings_centre, rings_period

    code = np.asarray(Image.open(png), np.float64)[..., 1] / 255.0
    lin = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)
    h, w = lin.shape
    mask = np.ones((h, w), bool)
    yy, xx = np.mgrid[0:h, 0:w]
    x, y = ((xx - w / 2) * pixel_um)[mask], ((yy - h / 2) * pixel_um)[mask]
    v = _fringes(lin[mask], mask)
    cx, cy = rings_centre(x, y, v, pixel_um)
    r2 = (x - cx) ** 2 + (y - cy) ** 2
    period, _ = rings_period(r2, v, 4.0 * pixel_um * float(np.median(np.sqrt(r2))))
    radius_mm = period / (SODIUM_NM / 1000.0) / 1000.0
    return {"radius_mm": radius_mm, "centre_px": [cx / pixel_um + w / 2, cy / pixel_um + h / 2],
            "pixel_um_for_stated": pixel_um / 2 * float(np.sqrt(stated_mm / radius_mm))}


def run_fit(photo: Path, scene: Path, work: Path, tag: str) -> dict:
    js = work / f"{tag}.json"
    t0 = time.perf_counter()
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(photo), "--scene", str(scene),
                           "--json", str(js)], capture_output=True, text=True, cwd=work)
    message = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else ""
    for folder in {str(work.resolve()), str(work)}:  # the record names files as the work folder holds them
        message = message.replace(folder.rstrip("/") + "/", "")
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    # the largest resident memory of the script's fits so far: this fit's where it is the
    # largest (one photo at a time, its colour fit refused in seconds, its grey fit after)
    rec = {"exit": proc.returncode, "seconds": round(time.perf_counter() - t0, 1),
           "cpu_seconds": round(cpu.ru_utime + cpu.ru_stime - cpu0.ru_utime - cpu0.ru_stime, 1),
           "peak_rss_mb": round(cpu.ru_maxrss / 1024.0), "message": message}
    if proc.returncode == 0:
        out = json.loads(js.read_text())
        rec.update({k: out.get(k) for k in ("ok", "warnings", "params", "stderr", "reduced_chi2",
                                            "reduced_chi2_floor", "order_hops")})
    return rec


def ring_spans(rec: dict) -> dict:
    """The gap's span across the binned photo (320x240), in fringes of 589.3 nm in air, of
    the colour-free start (its centre and R; the rings' period) and of the full fit (its
    parameters; the gap ``h = max(R - sqrt(R^2 - r^2) + h0, 0)``): the figures of the fit's
    lost-rings warning (bubblefit.inverse._newton.lost_rings_warning)."""
    pitch, fringe = rec["pixel_um_binned"], SODIUM_NM / 2.0 / 1.000277
    xs, ys = np.meshgrid(np.arange(320), np.arange(240))
    s, g = rec["start"], rec["grey"]["params"]
    # the start's centre in pixels; the fit's in um from the photo's corner (pixel centres at +0.5)
    r2s = ((xs - s["centre_px"][0]) ** 2 + (ys - s["centre_px"][1]) ** 2) * pitch ** 2
    start = 1000.0 * float(np.ptp(r2s)) / (2.0 * s["radius_mm"] * 1000.0)
    r2f = ((xs + 0.5) * pitch - g["center_x_um"]) ** 2 + ((ys + 0.5) * pitch - g["center_y_um"]) ** 2
    rf = g["radius_mm"] * 1000.0
    fit = np.maximum(1000.0 * r2f / (rf + np.sqrt(rf * rf - r2f)) + g["contact_offset_nm"], 0.0)
    return {"start": start / fringe, "fit": float(np.ptp(fit)) / fringe}


#: The top (nm) of the scene's searched range, which bounds the per-pixel start's map: the
#: default; another (``--range-nm``) writes its records beside, in ``real_photos_range<HI>.json``.
RANGE_NM = 4000.0


def _record_path(range_hi: float) -> Path:
    return OUT / ("real_photos.json" if range_hi == RANGE_NM else f"real_photos_range{range_hi:g}.json")


def _recorded(range_hi: float = RANGE_NM) -> dict:
    """The records in :func:`_record_path` by stated radius (empty without one)."""
    path = _record_path(range_hi)
    return {p["stated_radius_mm"]: p for p in json.loads(path.read_text())["photos"]} if path.exists() else {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="source", type=Path, default=None,
                    help="a folder holding the ring photos (牛顿环_<R>.jpg) instead of fetching them")
    ap.add_argument("--only", type=int, nargs="*", default=sorted(DIAMETERS))
    ap.add_argument("--work", type=Path, default=Path("real_photos_work"))
    ap.add_argument("--range-nm", type=float, default=RANGE_NM,
                    help="the top of the scene's searched gap range (nm), which bounds the per-pixel map the fit "
                         "starts from (its memory grows with it; the lens's gap is not held within it). Another "
                         "than 4000 writes its record to real_photos_range<HI>.json")
    ap.add_argument("--start-only", action="store_true",
                    help="only the colour-free start (seconds), merged into the existing record")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    sodium_lamp(args.work / "sodium.csv")
    (args.work / "grey.csv").write_text("wavelength_nm,r,g,b\n" + "".join(f"{l},1,1,1\n" for l in range(380, 781, 5)))
    pixel_um = 2 * MM_PER_PX * 1000.0
    (args.work / "colour.toml").write_text(SCENE.format(pixel_um=pixel_um / 2, response="", range_hi=args.range_nm).replace(
        "width = 320\nheight = 240", "width = 640\nheight = 480"))
    (args.work / "grey.toml").write_text(SCENE.format(pixel_um=pixel_um, response='response = "grey.csv"\n', range_hi=args.range_nm))
    records = []
    old = _recorded(args.range_nm)
    for radius in args.only:
        jpg = fetch(radius, args.source, args.work)
        grey_photo(jpg, args.work / f"rings_{radius}_grey.png")
        start = rings_start(args.work / f"rings_{radius}_grey.png", pixel_um, radius)
        if args.start_only:
            records.append({**old.get(radius, {}), "start": start})
            print(radius, start)
            continue
        r_text, se_text = textbook_radius(radius)
        rec = {"photo": f"{RINGS_REPO}@{RINGS_COMMIT[:7]}:{RINGS_DIR}/牛顿环_{radius}.jpg",
               "stated_radius_mm": radius, "pixel_um_binned": pixel_um,
               "textbook_radius_mm": r_text, "textbook_stderr_mm": se_text,
               "colour": run_fit(jpg, args.work / "colour.toml", args.work, f"colour_{radius}"),
               "grey": run_fit(args.work / f"rings_{radius}_grey.png", args.work / "grey.toml", args.work,
                               f"grey_{radius}"), "start": start}
        records.append(rec)
        print(json.dumps(rec, indent=1, ensure_ascii=False))
    OUT.mkdir(parents=True, exist_ok=True)
    old = _recorded(args.range_nm)  # read again: the photos not run keep their records (one photo at a time: --only R)
    new = {r["stated_radius_mm"]: r for r in records}
    records = [new.get(r, old.get(r)) for r in sorted(set(old) | set(new))]
    for rec in records:
        if rec.get("grey", {}).get("params"):
            rec["spans_fringes"] = ring_spans(rec)
    _record_path(args.range_nm).write_text(json.dumps({"script": "experiments/real_photos.py", "photos": records},
                                                     indent=1, ensure_ascii=False) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
