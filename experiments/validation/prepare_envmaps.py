"""Copy the CC0 maps the validation needs into data/envmaps/ as 256x128 float EXRs.

Power-preserving box downsample (vio.box_downsample_envmap) of the 1024x512 originals in
../shared/data/envmaps/ (or --src). Run once; the copies are committed so that the
validation runs from the repository alone.

The held-out test cases use two more of the same CC0 set (Greg Zaal, Poly Haven), which
the shared folder lacks but Blender's ``bpy`` wheel ships as studio lights:

    .venv/bin/python prepare_envmaps.py --maps forest sunset \
        --src ../../.venv-render/lib/python3.11/site-packages/bpy/5.0/datafiles/studiolights/world
"""
import argparse
import os
from pathlib import Path

import numpy as np

import vio

MAPS = ["courtyard", "sunrise", "night", "studio", "city", "interior"]

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--src", default=os.path.join(vio.HERE, "..", "..", "..", "..", "shared", "data", "envmaps"))
    ap.add_argument("--factor", type=int, default=4)
    ap.add_argument("--maps", nargs="+", default=MAPS, help="map names (files NAME.exr in --src)")
    a = ap.parse_args()
    src = a.src if os.path.isdir(a.src) else str(Path(__file__).resolve().parents[3] / "shared" / "data" / "envmaps")
    os.makedirs(vio.ENVMAPS, exist_ok=True)
    for m in a.maps:
        env = vio.read_image(os.path.join(src, m + ".exr"))[..., :3]
        small = vio.box_downsample_envmap(env, a.factor)
        h, w, _ = env.shape
        th = np.pi * (np.arange(h) + 0.5) / h
        p0 = (env * np.sin(th)[:, None, None]).sum((0, 1)) / (h * w)
        th2 = np.pi * (np.arange(small.shape[0]) + 0.5) / small.shape[0]
        p1 = (small * np.sin(th2)[:, None, None]).sum((0, 1)) / small.shape[0] / small.shape[1]
        vio.write_exr(os.path.join(vio.ENVMAPS, m + ".exr"), small, half=True)
        print(m, env.shape, "->", small.shape, "power ratio", np.round(p1 / p0, 5), "max", small.max())
