"""Peak memory of `bubblefit fit` on a large photo (issue "nothing lost": 6000x4000 peaked at 5 GB).

A 160x160 photo of a bubble (the paper model on the shipped courtyard map, noise, 8-bit)
is enlarged by pixel repetition into a WxH canvas, written as an 8-bit PNG with its
background photo (the same canvas without the bubble), and fitted through the command
line in a child process; the child's peak
resident memory (``ru_maxrss``) is printed and saved with the fit's result to
``experiments/results/fit_memory.json``.

    PYTHONPATH=. python experiments/fit_memory.py [--width 6000 --height 4000]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--out", default=os.path.join("experiments", "results", "fit_memory.json"))
    a = ap.parse_args()
    from bubblefit.io.images import write_image
    from bubblefit.model.scene import Scene, render_scene, shipped_envmap
    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.io.images import read_image

    n, rep = 160, max(1, min(a.width, a.height) // 200)
    px = read_image(shipped_envmap("courtyard")).pixels
    while px.shape[0] > 128:
        px = downsample(px)
    env = EnvMap.from_array(px)
    rng = np.random.default_rng(0)
    bg = np.full((n, n, 3), 0.25) + 0.05 * rng.random((n, n, 3))
    scene = Scene.from_dict({"camera": {"width": n, "height": n, "disc": [n / 2, n / 2, 0.4 * n]},
                             "bubble": {"t": 0.97, "roughness": 0.05, "thickness_nm": 450.0},
                             "lighting": {"envmap": "unused.exr"}, "effects": {"model": "paper"}})
    photo = np.asarray(render_scene(scene, bg, env=env))
    # the bubble was rendered over `bg`: the canvas around it and the background photo
    # passed to the fit are that same background, enlarged the same way
    y0, x0 = (a.height - rep * n) // 2, (a.width - rep * n) // 3
    with tempfile.TemporaryDirectory() as tmp:
        for name, img in (("photo.png", photo), ("background.png", bg)):
            big = np.full((a.height, a.width, 3), 0.27)
            big[y0:y0 + rep * n, x0:x0 + rep * n] = np.repeat(np.repeat(img, rep, axis=0), rep, axis=1)
            write_image(os.path.join(tmp, name), big)
            del big
        write_image(os.path.join(tmp, "env.exr"), px, bit_depth=32)
        disc = f"{x0 + rep * n / 2},{y0 + rep * n / 2},{rep * 0.4 * n}"
        t0 = time.time()
        p = subprocess.run([sys.executable, "-m", "bubblefit", "fit", os.path.join(tmp, "photo.png"), "--envmap",
                            os.path.join(tmp, "env.exr"), "--background", os.path.join(tmp, "background.png"),
                            "--disc", disc, "--json", os.path.join(tmp, "fit.json")],
                           capture_output=True, text=True)
        wall = time.time() - t0
        peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
        fit = json.load(open(os.path.join(tmp, "fit.json"))) if p.returncode == 0 else None
    out = {"width": a.width, "height": a.height, "peak_rss_mb": peak_mb, "wall_s": wall, "rc": p.returncode,
           "stderr_tail": p.stderr.strip().splitlines()[-1:] if p.returncode else [],
           "thickness_nm": None if fit is None else fit["params"]["thickness_nm"], "truth_nm": 450.0,
           "frame": None if fit is None else fit.get("frame"), "disc": None if fit is None else fit.get("disc")}
    print(json.dumps(out, indent=1))
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as fh:
        json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
