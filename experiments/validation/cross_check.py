"""Cross-check the three renderers against each other on the same scenes.

Re-renders the Cycles and Mitsuba bubble cases with the numpy reference renderer (same
camera, map, thickness; Cycles cases under illuminant E, Mitsuba's with the incoherent
thick film) and compares the noise-free linear renders... the stored photos are 8-bit and
noisy, so the comparison is of the decoded photo / exposure, averaged over rings of the
disc (centre 0-0.5 r, middle 0.5-0.8 r, rim 0.8-0.95 r), per channel, leaving out pixels the 8-bit photo clipped. Writes
data/conventions/cross_check.json.

    python cross_check.py          # the project's venv
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402


def camera_from(truth):
    c = truth["camera"]
    if c["type"] == "orthographic":
        return rr.Camera("ortho", c["width"], c["height"], disc=tuple(c["disc"]))
    return rr.Camera("persp", c["width"], c["height"], origin=tuple(c["origin"]), target=tuple(c["target"]),
                     up=tuple(c["up"]), fov_deg=c["fov_deg"])


def thickness_from(th):
    p = th["profile"]
    if p == "constant":
        return rr.Thickness("constant", th["thickness_nm"])
    if p == "incoherent":
        return rr.Thickness("constant", 0.0)
    kind = "drainage" if p == "drainage" else "bump"
    kw = dict(top_nm=th["top_nm"], bottom_nm=th["bottom_nm"], exponent=th["exponent"])
    if kind == "bump":
        kw.update(bump_nm=th["bump_nm"], bump_center=tuple(th["bump_center_unit"]), bump_sigma=th["bump_sigma_radii"])
    return rr.Thickness(kind, **kw)


def rings(img, disc, keep=None):
    h, w, _ = img.shape
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    rho = np.hypot(xx - disc["cx"], yy - disc["cy"]) / disc["r"]
    out = {}
    for name, (a, b) in {"centre": (0, 0.5), "middle": (0.5, 0.8), "rim": (0.8, 0.95)}.items():
        m = (rho >= a) & (rho < b)
        if keep is not None:
            m &= keep
        out[name] = img[m].mean(0)
    return out


def main(cases=None):
    report = {}
    names = cases or sorted(n for n in os.listdir(vio.DATA) if n.startswith(("cyc_", "mts_")))
    for name in names:
        with open(os.path.join(vio.DATA, name, "truth.json")) as fh:
            truth = json.load(fh)
        env = vio.read_image(os.path.join(vio.DATA, truth["envmap"]))[..., :3]
        ill = "E" if truth["illuminant"] == "E" else "D65"
        bub = rr.Bubble(thickness=thickness_from(truth["thickness"]),
                        interference=truth["thickness"]["profile"] != "incoherent")
        img, _ = rr.render(camera_from(truth), bub, env, rr.spectral_setup(ill, 2.0), background="env")
        codes = vio.read_image(os.path.join(vio.DATA, name, "photo.png"))[..., :3]
        keep = codes.max(-1) < 250 / 255          # saturated pixels (clipped by the 8-bit photo) left out
        photo = vio.srgb_decode(codes) / truth["exposure"]
        a, b = rings(photo, truth["disc"], keep), rings(img, truth["disc"], keep)
        report[name] = {k: {"renderer": a[k].tolist(), "reference": b[k].tolist(),
                            "ratio": (a[k] / b[k]).tolist()} for k in a}
        print(name, {k: np.round(a[k] / b[k], 3).tolist() for k in a}, flush=True)
    vio.save_json(os.path.join(vio.DATA, "conventions", "cross_check.json"), report)


if __name__ == "__main__":
    main(sys.argv[1:] or None)
