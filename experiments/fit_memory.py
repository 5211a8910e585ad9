"""Peak memory of `bubblefit fit` on a large photo (issue "nothing lost": 6000x4000 peaked at 5 GB).

A 160x160 photo of a bubble (the paper model on the shipped courtyard map, noise, 8-bit)
is enlarged by pixel repetition into a WxH canvas, written as an 8-bit PNG with its
background photo (the same canvas without the bubble), and fitted through the command
line. The same fit of the 160x160 original is the yardstick: the difference is what the
photo's size costs. Each child's own peak resident memory (``ru_maxrss``, measured by
the child itself: a forked child would count its parent's pages) is printed and saved
with the fits' results to ``experiments/results/fit_memory.json``.

    PYTHONPATH=. python experiments/fit_memory.py [--width 6000 --height 4000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

N = 160  # the original photo's size


def make(folder: str, width: int, height: int) -> list[str]:
    """Write photo/background at N x N and enlarged to width x height; return the discs."""
    from bubblefit.io.images import read_image, write_image
    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.model.scene import Scene, render_scene, shipped_envmap

    rep = max(1, min(width, height) // 200)
    px = read_image(shipped_envmap("courtyard")).pixels
    while px.shape[0] > 128:
        px = downsample(px)
    rng = np.random.default_rng(0)
    bg = np.full((N, N, 3), 0.25) + 0.05 * rng.random((N, N, 3))
    scene = Scene.from_dict({"camera": {"width": N, "height": N, "disc": [N / 2, N / 2, 0.4 * N]},
                             "bubble": {"t": 0.97, "roughness": 0.05, "thickness_nm": 450.0},
                             "lighting": {"envmap": "unused.exr"}, "effects": {"model": "paper"}})
    photo = np.asarray(render_scene(scene, bg, env=EnvMap.from_array(px)))
    write_image(os.path.join(folder, "env.exr"), px, bit_depth=32)
    # the bubble was rendered over `bg`: the canvas around it and the background photo
    # passed to the fit are that same background, enlarged the same way
    y0, x0 = (height - rep * N) // 2, (width - rep * N) // 3
    for name, img in (("photo", photo), ("background", bg)):
        write_image(os.path.join(folder, f"{name}_small.png"), img)
        big = np.full((height, width, 3), 0.27)
        big[y0:y0 + rep * N, x0:x0 + rep * N] = np.repeat(np.repeat(img, rep, axis=0), rep, axis=1)
        write_image(os.path.join(folder, f"{name}_big.png"), big)
        del big
    return [f"{N / 2},{N / 2},{0.4 * N}", f"{x0 + rep * N / 2},{y0 + rep * N / 2},{rep * 0.4 * N}"]


_CHILD = ("import resource, sys; from bubblefit.cli import main; rc = main(sys.argv[1:]); "
          "print('PEAK_MB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0); sys.exit(rc)")


def fit(folder: str, size: str, disc: str) -> dict:
    """Fit ``photo_<size>.png`` in a child process; its peak memory, time and result."""
    js = os.path.join(folder, f"fit_{size}.json")
    args = ["fit", os.path.join(folder, f"photo_{size}.png"), "--envmap", os.path.join(folder, "env.exr"),
            "--background", os.path.join(folder, f"background_{size}.png"), "--disc", disc, "--json", js]
    t0 = time.time()
    p = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True, text=True)
    peak = [float(line.split()[1]) for line in p.stdout.splitlines() if line.startswith("PEAK_MB")]
    res = json.load(open(js)) if p.returncode == 0 else {}
    return {"peak_rss_mb": peak[0] if peak else None, "wall_s": time.time() - t0, "rc": p.returncode,
            "stderr_tail": p.stderr.strip().splitlines()[-1:] if p.returncode else [],
            "thickness_nm": res.get("params", {}).get("thickness_nm"), "frame": res.get("frame"),
            "disc": res.get("disc")}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--out", default=os.path.join("experiments", "results", "fit_memory.json"))
    ap.add_argument("--make", metavar="DIR", help=argparse.SUPPRESS)  # the child that writes the photos
    a = ap.parse_args()
    if a.make:
        print(json.dumps(make(a.make, a.width, a.height)))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        p = subprocess.run([sys.executable, __file__, "--make", tmp, "--width", str(a.width), "--height",
                            str(a.height)], capture_output=True, text=True, check=True)
        discs = json.loads(p.stdout.strip().splitlines()[-1])
        small, big = fit(tmp, "small", discs[0]), fit(tmp, "big", discs[1])
    out = {"width": a.width, "height": a.height, "truth_nm": 450.0, "small": dict(small, width=N, height=N),
           "big": big, "extra_mb": (big["peak_rss_mb"] or 0) - (small["peak_rss_mb"] or 0),
           "two_float32_photos_mb": 2 * a.width * a.height * 3 * 4 / 2**20}
    print(json.dumps(out, indent=1))
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    with open(a.out, "w") as fh:
        json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
