"""Where a dish bubble's specular light paths send a compact source (the sun) in the image.

An independent trace (numpy and reference_renderer.py's camera only, nothing from
bubblefit) of the scene of a ``cyc_cap_*`` case: the sphere (centre 0, radius 1) cut by the
opaque liquid plane ``y = plane_y`` (Blender's scene: the sphere is whole, its part below
the plane hidden by the plane). Every camera ray (8 x 8 per pixel) is followed through
every sequence of specular events up to ``--events``: at the sphere's film it reflects
(``R``) or goes straight through (``T``, a film of index n between air and air keeps the
ray's direction), at the liquid it reflects (``L``). Where a path leaves the scene it
reads the map's brightest texels only (those above 2 % of the brightest: the sun),
bilinearly, with rows at ``v = i / (H - 1)`` (``mitsuba``) and at ``v = (i + 1/2) / H``
(``texel-centre``, Blender's). The weights (film and liquid reflectances) are left out:
this says *where* each path puts the sun, and the photo's pixels there say whether the
renderer shows it (the photo's green over the median of its 5 x 5 neighbourhood).

Path names: ``R`` the front film's glint; ``TRLT`` through the front film, the rear
film's reflection, the liquid inside the foot, out through the wall; ``TLRLT`` through
the front film onto the liquid inside the foot, the wall's reflection, the liquid again,
out; ``LR`` the liquid outside, the front film's reflection (the mirror image's glint).

    PYTHONPATH=. .venv/bin/python experiments/validation/cap_glint_paths.py CASE [--events 5] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402

SS = 8


def sun_lookup(sun, d, convention):
    """Bilinear lookup of ``sun`` (H, W, 3) along unit directions ``d`` (docs/design.md's
    u, v), rows at ``i / (H - 1)`` or at ``(i + 1/2) / H``; columns wrap, rows clamp."""
    h, w = sun.shape[:2]
    u = (np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)) % 1.0
    v = np.arctan2(np.hypot(d[:, 0], d[:, 2]), d[:, 1]) / np.pi
    x = u * w - 0.5
    y = v * (h - 1) if convention == "mitsuba" else np.clip(v * h - 0.5, 0.0, h - 1.0)
    x0, y0 = np.floor(x), np.clip(np.floor(y), 0, h - 2)
    fx, fy = (x - x0)[:, None], np.clip(y - y0, 0.0, 1.0)[:, None]
    x0 = x0.astype(int) % w
    x1, y0 = (x0 + 1) % w, y0.astype(int)
    y1 = np.minimum(y0 + 1, h - 1)
    return (sun[y0, x0] * (1 - fx) + sun[y0, x1] * fx) * (1 - fy) + (sun[y1, x0] * (1 - fx) + sun[y1, x1] * fx) * fy


def next_hit(o, d, plane_y):
    """(distance, what): 0 the map, 1 the sphere above the plane, 2 the liquid plane."""
    b = np.sum(o * d, -1)
    disc = b * b - (np.sum(o * o, -1) - 1.0)
    sq = np.sqrt(np.maximum(disc, 0.0))
    t1, t2 = -b - sq, -b + sq
    ts = np.where(disc > 0, np.where(t1 > 1e-6, t1, np.where(t2 > 1e-6, t2, np.inf)), np.inf)
    down = d[:, 1] < 0
    tp = np.where(down, (plane_y - o[:, 1]) / np.where(down, d[:, 1], -1.0), np.inf)
    tp = np.where(tp > 1e-6, tp, np.inf)
    what = np.where(np.isinf(ts) & np.isinf(tp), 0, np.where(ts < tp, 1, 2))
    return np.minimum(ts, tp), what


def trace(case: str, events: int = 5) -> dict:
    cdir = os.path.join(HERE, "data", case)
    truth = json.load(open(os.path.join(cdir, "truth.json")))
    cam_t, plane_y = truth["camera"], truth["cap"]["plane_y"]
    env = vio.read_image(os.path.join(HERE, "data", truth["envmap"]))[..., :3]
    lum = env.sum(-1)
    sun = np.where((lum > 0.02 * lum.max())[..., None], env, 0.0)
    w, h = cam_t["width"], cam_t["height"]
    cam = rr.Camera("persp", w, h, origin=tuple(cam_t["origin"]), target=tuple(cam_t["target"]),
                    up=tuple(cam_t["up"]), fov_deg=cam_t["fov_deg"])
    off = (np.arange(SS) + 0.5) / SS
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    px = np.broadcast_to(jj[..., None, None] + off[None, None, None, :], (h, w, SS, SS)).reshape(-1)
    py = np.broadcast_to(ii[..., None, None] + off[None, None, :, None], (h, w, SS, SS)).reshape(-1)
    o, d = cam.rays(px.copy(), py.copy(), np.zeros(3), 1.0)
    pix = np.floor(py).astype(int) * w + np.floor(px).astype(int)
    acc: dict = {}

    def walk(o, d, idx, name, left):
        t, what = next_hit(o, d, plane_y)
        out = what == 0
        if out.any():
            for conv in ("mitsuba", "texel-centre"):
                a = acc.setdefault((name or "direct", conv), np.zeros(w * h))
                np.add.at(a, idx[out], sun_lookup(sun, d[out], conv).sum(-1) / SS**2)
        if left == 0:
            return
        for kind, choices in ((1, "RT"), (2, "L")):
            s = what == kind
            if not s.any():
                continue
            p = o[s] + t[s, None] * d[s]
            n = p if kind == 1 else np.tile([0.0, 1.0, 0.0], (int(s.sum()), 1))
            r = d[s] - 2.0 * np.sum(d[s] * n, -1)[:, None] * n
            for c in choices:
                walk(p, d[s] if c == "T" else r, idx[s], name + c, left - 1)

    walk(o, d, pix, "", events)
    photo = vio.read_image(os.path.join(cdir, "photo.png"))[..., :3]
    if photo.max() > 1.0:
        photo = photo / 255.0
    g = photo[..., 1]
    pad = np.pad(g, 2, mode="edge")
    local = np.median(np.stack([pad[a:a + h, b:b + w] for a in range(5) for b in range(5)]), axis=0)
    rows = []
    for (name, conv), a in sorted(acc.items()):
        if a.max() <= 0 or name == "direct":
            continue
        top = [int(k) for k in np.argsort(a)[::-1][:3] if a[k] > 0.05 * a.max()]
        rows.append({"path": name, "convention": conv, "sun_total": float(a.sum()),
                     "pixels": [{"row": k // w, "col": k % w, "sun": float(a[k]),
                                 "photo_green": float(g.flat[k]), "photo_local_median": float(local.flat[k])}
                                for k in top]})
        print(name, conv, round(float(a.sum()), 1), [(r["row"], r["col"], round(r["sun"], 1), round(r["photo_green"], 3),
                                                      round(r["photo_local_median"], 3)) for r in rows[-1]["pixels"]],
              flush=True)
    return {"case": case, "events": events, "rays_per_pixel": SS * SS, "paths": rows}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--events", type=int, default=5)
    ap.add_argument("--json")
    a = ap.parse_args()
    out = [trace(c, a.events) for c in a.cases]
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
