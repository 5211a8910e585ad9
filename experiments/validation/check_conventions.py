"""Verify the environment-map convention of every renderer with a mirror sphere.

A perfect mirror sphere of radius 1 at the origin, seen by an orthographic camera (disc
(64, 64) r = 50 px in a 128 x 128 image) and a perspective one (origin (0, 0, 4), fov 40
degrees along the width), reflects the map in the direction r = d - 2 (d.n) n. The
expected image is computed here with bubblefit's own `envmap.lookup` (4 x 4 supersamples
per pixel) and compared with the Mitsuba and Cycles renders in data/conventions/ and with
the reference renderer's independent lookup. Three wrong conventions (map mirrored
left-right, turned 90 degrees, upside down) are scored too, to show the check can tell.

Run with the project's venv (it imports bubblefit): writes data/conventions/report.json
and prints the relative RMS differences inside 0.95 of the disc.
"""

from __future__ import annotations

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.normpath(os.path.join(HERE, "..", "..")))
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402

CONV = os.path.join(vio.DATA, "conventions")


def cameras():
    return {"ortho": rr.Camera("ortho", 128, 128, disc=(64.0, 64.0, 50.0)),
            "persp": rr.Camera("persp", 128, 128, origin=(0.0, 0.0, 4.0), target=(0.0, 0.0, 0.0), fov_deg=40.0)}


def mirror_image(cam, lookup, ss=4):
    H, W = cam.height, cam.width
    off = (np.arange(ss) + 0.5) / ss
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    px = np.broadcast_to(jj[..., None, None] + off[None, None, None, :], (H, W, ss, ss)).reshape(-1)
    py = np.broadcast_to(ii[..., None, None] + off[None, None, :, None], (H, W, ss, ss)).reshape(-1)
    o, d = cam.rays(px.astype(float), py.astype(float), np.zeros(3), 1.0)
    hit, s = rr._intersect(o, d, np.zeros(3), 1.0)
    out = np.zeros((px.size, 3))
    p = o[hit] + s[hit, None] * d[hit]
    n = p
    r = d[hit] - 2 * (d[hit] * n).sum(-1, keepdims=True) * n
    out[hit] = lookup(r)
    cover = hit.reshape(H, W, ss * ss).mean(-1)
    return out.reshape(H, W, ss * ss, 3).mean(2), cover


def main():
    import jax.numpy as jnp
    from bubblefit.lighting import envmap as bf_env

    env = vio.read_image(os.path.join(vio.ENVMAPS, "courtyard.exr"))[..., :3]
    envj = jnp.asarray(env, dtype=jnp.float32)

    def bf_lookup(dirs, transform=None):
        if transform is not None:
            dirs = transform(dirs)
        return np.asarray(bf_env.lookup(envj, jnp.asarray(dirs, dtype=jnp.float32)), dtype=np.float64)

    wrong = {
        "mirrored_x": lambda v: v * np.array([-1.0, 1.0, 1.0]),
        "turned_90": lambda v: np.stack([v[:, 2], v[:, 1], -v[:, 0]], -1),
        "upside_down": lambda v: v * np.array([1.0, -1.0, 1.0]),
    }
    report = {"what": __doc__.split("\n\n")[1].replace("\n", " "), "metric": "relative RMS over pixels fully inside 0.95 r",
              "results": {}}
    for kind, cam in cameras().items():
        ref, cover = mirror_image(cam, bf_lookup)
        mine, _ = mirror_image(cam, lambda v: rr.env_lookup(env, v))
        cx, cy, r = cam.disc_pixels((0, 0, 0), 1.0)
        yy, xx = np.mgrid[0:128, 0:128] + 0.5
        inner = ((xx - cx) ** 2 + (yy - cy) ** 2 <= (0.95 * r) ** 2) & (cover == 1)

        def rel(img):
            return float(np.sqrt(np.mean((img[inner] - ref[inner]) ** 2)) / np.sqrt(np.mean(ref[inner] ** 2)))

        res = {"reference_renderer_lookup": rel(mine)}
        for name, f in wrong.items():
            res[f"bubblefit_lookup_{name}"] = rel(mirror_image(cam, lambda v, f=f: bf_lookup(v, f))[0])
        for renderer in ("mitsuba", "cycles"):
            path = os.path.join(CONV, f"{renderer}_mirror_{kind}.exr")
            if os.path.exists(path):
                img = vio.read_image(path)[..., :3]
                res[renderer] = rel(img)
                # best global gain, to separate a brightness scale from a geometric mismatch
                g = float((img[inner] * ref[inner]).sum() / (img[inner] ** 2).sum())
                res[f"{renderer}_gain_to_bubblefit"] = g
                res[f"{renderer}_after_gain"] = rel(img * g)
        report["results"][kind] = res
        vio.write_exr(os.path.join(CONV, f"bubblefit_lookup_mirror_{kind}.exr"), ref)
    vio.save_json(os.path.join(CONV, "report.json"), report)
    for kind, res in report["results"].items():
        print(kind)
        for k, v in res.items():
            print(f"  {k:<40} {v:.4f}")


if __name__ == "__main__":
    main()
