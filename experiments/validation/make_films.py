"""Render the flat-film and gap cases into data/<case>/ (project venv; reference_films.py).

Each case folder gets photo.png (8-bit sRGB, Poisson-Gaussian noise), thickness_true.exr
(nm, NaN off the film), truth.json and scene.toml (what `bubblefit fit --scene` needs:
the media, the lamp, the camera; nothing about the thickness).

    python make_films.py [CASE ...]       # default: all
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import reference_films as rf  # noqa: E402
import vio  # noqa: E402

FULL_WELL, READ_NOISE = 4000.0, 3.0

CASES = {
    "film_newton_bk7_na010": dict(kind="newton", seed=11, fit_args=[], size=128, pixel_um=9.0, radius_mm=100.0, na=0.1,
                                  center=(61.3, 66.8), lamp="3200K", media=("bk7", "air", "bk7")),
    # the order's reference: the film's top three rows, 20 pixels wide, at their rendered mean
    "film_drain_water_area": dict(kind="area", seed=12, fit_args=["--reference-region", "54,28,74,31=126"], size=128, top_nm=120.0, bottom_nm=1100.0, exponent=1.3,
                                  lamp="D65", n_film="water"),
}


def newton_scene(c) -> str:
    return (
        "# Newton's rings: a BK7 lens on a BK7 plate, air gap, coaxial light through an NA 0.1 objective\n"
        "[film]\nshape = \"plane\"\nn = \"air\"\nabove = \"bk7\"\nbelow = \"bk7\"\n"
        "thickness = \"newton\"\nrange_nm = [0.0, 4000.0]\n\n"
        f"[light]\ntype = \"coaxial\"\nna = {c['na']}\nlamp = \"{c['lamp']}\"\n\n"
        f"[camera]\nwidth = {c['size']}\nheight = {c['size']}\npixel_um = {c['pixel_um']}\n")


def area_scene(c) -> str:
    return (
        "# A vertical soap film (water) in a frame, a diffuse panel behind the camera\n"
        "[film]\nshape = \"plane\"\nn = \"water\"\nabove = \"air\"\nbelow = \"air\"\nthickness = \"map\"\n"
        "range_nm = [0.0, 1600.0]\ncenter = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nup = [0.0, 1.0, 0.0]\n"
        "size = [0.18, 0.18]\n\n"
        f"[light]\ntype = \"area\"\nshape = \"rect\"\ncenter = [0.0, 0.0, 0.7]\nnormal = [0.0, 0.0, -1.0]\n"
        f"up = [0.0, 1.0, 0.0]\nsize = [1.0, 1.0]\nradiance = 1.0\nlamp = \"{c['lamp']}\"\n\n"
        f"[camera]\ntype = \"perspective\"\nwidth = {c['size']}\nheight = {c['size']}\norigin = [0.0, 0.0, 0.6]\n"
        "target = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov_deg = 30.0\n")


def make(name: str, c: dict) -> None:
    out = os.path.join(vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    if c["kind"] == "newton":
        d, rgb = rf.newton_case(c["size"], c["pixel_um"], c["radius_mm"], c["na"], c["center"], 0.0, c["lamp"],
                                c["media"])
        scene = newton_scene(c)
        truth = {"radius_mm": c["radius_mm"], "center_px": list(c["center"]), "pixel_um": c["pixel_um"],
                 "na": c["na"], "media": list(c["media"]), "lamp": c["lamp"],
                 "gap": "h(r) = R - sqrt(R^2 - r^2), r = pixel_um x distance to the centre (pixel centres +0.5)",
                 "pixel": "the mean colour over the pixel's square, 16 x 16 points"}
    else:
        d, rgb, _ = rf.drainage_area_case(c["size"], c["top_nm"], c["bottom_nm"], c["exponent"], c["lamp"],
                                          c["n_film"])
        scene = area_scene(c)
        truth = {"top_nm": c["top_nm"], "bottom_nm": c["bottom_nm"], "exponent": c["exponent"],
                 "n_film": c["n_film"], "lamp": c["lamp"],
                 "profile": "d = top + (bottom - top) f^exponent, f = 0 at the film's top edge, 1 at its bottom"}
    exposure = 0.9 / float(np.nanpercentile(rgb, 99.5))
    rng = np.random.default_rng(c["seed"])
    photo = vio.add_noise_and_quantise(rgb * exposure, rng, FULL_WELL, READ_NOISE)
    vio.write_png8(os.path.join(out, "photo.png"), None, photo)
    vio.write_exr(os.path.join(out, "thickness_true.exr"), d.astype(np.float32))
    with open(os.path.join(out, "scene.toml"), "w") as fh:
        fh.write(scene)
    truth.update(case=name, renderer="reference_films.py (numpy, complex Airy sum, three media)",
                 renderer_version=rf.VERSION, exposure=exposure,
                 noise={"model": "Poisson-Gaussian then 8-bit sRGB", "full_well_e_at_1.0": FULL_WELL,
                        "read_noise_e": READ_NOISE, "seed": c["seed"]},
                 kind="film", fits=["newton"] if c["kind"] == "newton" else ["map", "drainage"],
                 fit_args=["--scene", "scene.toml", *c["fit_args"]])
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: d {np.nanmin(d):.0f}..{np.nanmax(d):.0f} nm, exposure {exposure:.3g}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("cases", nargs="*")
    args = ap.parse_args(argv)
    for name in args.cases or list(CASES):
        make(name, CASES[name])


if __name__ == "__main__":
    main()
