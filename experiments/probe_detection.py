"""Mirror-ball detection (``bubblefit envmap`` without ``--ball``): accuracy, refusals, time.

Cases: balls from the independent numpy generator of ``tests/test_probe.py`` (courtyard and
procedural maps; plain, dark and busy backdrops; orthographic and perspective at 5 radii;
8-bit sRGB with noise; radii 30-240 px), backdrops without a ball and uniform noise (which
must be refused), and the Mitsuba 3 probes of ``tests/data/probes``. Per case: the outline
found (or the refusal), its error against the truth, the rim support and its chance level,
and the wall time of :func:`bubblefit.capture.ball.find_ball`.

    python experiments/probe_detection.py [--out DIR] [--quick]

Writes ``probe_detection.json``, ``probe_detection.csv`` and ``probe_detection.png`` (centre
and radius error per case, refusals marked) to ``--out`` (default
``experiments/results/probe_detection``).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))


def _generator():
    """The test suite's independent mirror-ball generator (numpy only)."""
    spec = importlib.util.spec_from_file_location("_probe_tests", ROOT / "tests" / "test_probe.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def cases(gen, quick: bool):
    """(name, image, truth (cx, cy, r) or None) for every case."""
    envs = {k: gen.gen_env(k) for k in ("courtyard", "procedural")}
    sizes = [(192, 208, 58.2)] if quick else [(120, 128, 30.0), (192, 208, 58.2), (400, 520, 150.0), (720, 960, 240.0)]
    for h, w, r in sizes:
        cx, cy = w / 2 - 2.7, h / 2 - 5.4
        for env_name, env in envs.items():
            for backdrop in ("plain", "dark", "busy"):
                for distance in (None, 5.0):
                    if quick and env_name == "procedural" and distance:
                        continue
                    ss = 4 if r < 100 else 2
                    rad = gen.gen_ball(env, (h, w), cx, cy, r, distance=distance, backdrop=backdrop, ss=ss)
                    cam = "ortho" if distance is None else "persp"
                    yield f"{env_name}_{backdrop}_{cam}_r{r:.0f}", gen.gen_photo(rad), (cx, cy, r)
    for seed in (1, 2, 3):
        yield f"busy_no_ball_{seed}", gen.gen_photo(gen.gen_backdrop("busy", 192, 208, seed)), None
    yield "uniform_noise", np.random.default_rng(3).random((192, 192, 3)) ** 2.2, None
    from bubblefit.io.images import read_image

    probes = ROOT / "tests" / "data" / "probes"
    truth = json.loads((probes / "probes_truth.json").read_text())["probes"]
    for key, v in truth.items():
        for f in v.get("files", [key + ".png"]):
            b = v["ball"]
            yield f"mitsuba_{f}", read_image(probes / f).pixels, (b["cx"], b["cy"], b["r"]) if b else None


def measure(name: str, img: np.ndarray, truth) -> dict:
    from bubblefit.capture.ball import ball_evidence, find_ball
    from bubblefit.errors import InputError

    t0 = time.perf_counter()
    try:
        c = find_ball(img)
        found, reason = (c.cx, c.cy, c.r), ""
    except InputError as exc:
        found, reason = None, str(exc)
    dt = time.perf_counter() - t0
    ev = ball_evidence(img)
    row = {"case": name, "size": f"{img.shape[1]}x{img.shape[0]}", "has_ball": truth is not None,
           "found": found is not None, "time_s": dt,
           "support": ev.support if ev else 0.0, "chance": ev.chance if ev else 0.0,
           "centre_err_px": math.nan, "radius_err_px": math.nan, "refusal": reason}
    if found and truth:
        row["centre_err_px"] = math.hypot(found[0] - truth[0], found[1] - truth[1])
        row["radius_err_px"] = found[2] - truth[2]
    row["outcome"] = ("correct" if found and truth and row["centre_err_px"] < 1 and abs(row["radius_err_px"]) < 1
                      else "refused" if not found else "false ball" if not truth else "wrong circle")
    return row


def write_outputs(rows: list[dict], out: Path, meta: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bubblefit.cli.common import write_json
    from bubblefit.io.images import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "probe_detection.json", {"meta": meta, "cases": rows})
    keys = ["case", "size", "has_ball", "found", "outcome", "centre_err_px", "radius_err_px", "support", "chance", "time_s"]
    with atomic_path(out / "probe_detection.csv") as tmp:
        with open(tmp, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(keys)
            for r in rows:
                wr.writerow([r[k] if not isinstance(r[k], float) else f"{r[k]:.4g}" for k in keys])
    fig, ax = plt.subplots(figsize=(10, 0.22 * len(rows) + 1.5))
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r["centre_err_px"] if r["found"] else 0 for r in rows], 0.4, label="centre error (px)")
    ax.barh(y + 0.2, [abs(r["radius_err_px"]) if r["found"] else 0 for r in rows], 0.4, label="|radius error| (px)")
    for i, r in enumerate(rows):
        if not r["found"]:
            ax.text(0.02, i, "refused" + (" (no ball: right)" if not r["has_ball"] else ""), va="center", fontsize=7)
    ax.set_yticks(y, [r["case"] for r in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("pixels")
    ax.legend(loc="lower right")
    fig.tight_layout()
    with atomic_path(out / "probe_detection.png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(HERE / "results" / "probe_detection"), help="output folder (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="one image size, fewer cases")
    args = p.parse_args()
    gen = _generator()
    rows = []
    for name, img, truth in cases(gen, args.quick):
        rows.append(measure(name, img, truth))
        r = rows[-1]
        print(f"{name:40s} {r['size']:>9s} {r['outcome']:12s} centre {r['centre_err_px']:6.2f} radius "
              f"{r['radius_err_px']:+6.2f} support {r['support']:.2f} chance {r['chance']:.2f} {r['time_s']:.2f} s")
    summary = {k: sum(r["outcome"] == k for r in rows) for k in ("correct", "refused", "false ball", "wrong circle")}
    ok = [r for r in rows if r["outcome"] == "correct"]
    meta = {"summary": summary, "quick": args.quick,
            "max_centre_err_px": max((r["centre_err_px"] for r in ok), default=math.nan),
            "max_abs_radius_err_px": max((abs(r["radius_err_px"]) for r in ok), default=math.nan),
            "median_time_s": float(np.median([r["time_s"] for r in rows]))}
    print(json.dumps(meta))
    write_outputs(rows, Path(args.out), meta)
    print(f"wrote {args.out}/probe_detection.json, .csv, .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
