"""Render the reference-renderer cases into data/<case>/ (run with the project's venv).

Each case folder gets photo.png, background.png (8-bit sRGB, Poisson-Gaussian noise),
thickness_true.exr (front film thickness per pixel, NaN off the bubble), truth.json and,
for a perspective camera, scene.toml (the camera only, for `bubblefit fit --scene`).

    python make_reference.py [CASE ...]       # default: all

``--size N --out DIR`` renders a case at N x N pixels into DIR/<case>_N/ instead (the disc
keeps its place and its share of the photo's larger side; a perspective camera keeps its
field of view along the width), for benchmarks on photos of the size users take; the
folder is not part of the validation set:

    python make_reference.py --size 320 --out ../results/photos320 ref_const380_sunset_ortho
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402

FULL_WELL = 4000.0
READ_NOISE = 3.0


def persp(w, h, dist, fov, target=(0.0, 0.0, 0.0)):
    return rr.Camera("persp", w, h, origin=(0.0, 0.0, dist), target=target, up=(0.0, 1.0, 0.0), fov_deg=fov)


T = rr.Thickness
# name: (camera, thickness, envmap, background, illuminant, fits, notes)
CASES = {
    "ref_const300_courtyard_ortho": dict(
        camera=rr.Camera("ortho", 160, 160, disc=(80.0, 80.0, 48.0)), thickness=T("constant", 300.0),
        envmap="courtyard", background="backdrop", fits=["constant"], seed=1),
    "ref_const620_sunrise_persp": dict(
        camera=persp(176, 144, 4.0, 40.0), thickness=T("constant", 620.0),
        envmap="sunrise", background="env", fits=["constant"], seed=2),
    "ref_const1200_night_ortho_offc": dict(
        camera=rr.Camera("ortho", 192, 160, disc=(112.5, 70.0, 44.0)), thickness=T("constant", 1200.0),
        envmap="night", background="env", fits=["constant"], seed=3),
    "ref_const450_interior_ortho": dict(
        camera=rr.Camera("ortho", 160, 160, disc=(76.0, 84.0, 62.0)), thickness=T("constant", 450.0),
        envmap="interior", background="backdrop", fits=["constant"], seed=4),
    "ref_drain_lin_courtyard_ortho": dict(
        camera=rr.Camera("ortho", 160, 160, disc=(80.0, 80.0, 56.0)),
        thickness=T("drainage", top_nm=150.0, bottom_nm=900.0, exponent=1.0),
        envmap="courtyard", background="backdrop", fits=["drainage", "map"], seed=5),
    "ref_drain_exp15_studio_persp": dict(
        camera=persp(160, 160, 3.6, 45.0), thickness=T("drainage", top_nm=250.0, bottom_nm=900.0, exponent=1.5),
        envmap="studio", background="env", fits=["drainage"], seed=6),
    "ref_drain_lin_city_ortho_offc": dict(
        camera=rr.Camera("ortho", 200, 160, disc=(88.0, 86.0, 52.0)),
        thickness=T("drainage", top_nm=150.0, bottom_nm=900.0, exponent=1.0),
        envmap="city", background="backdrop", fits=["drainage", "map"], seed=7),
    "ref_bump_sunrise_ortho": dict(
        camera=rr.Camera("ortho", 160, 160, disc=(84.0, 78.0, 56.0)),
        thickness=T("bump", top_nm=150.0, bottom_nm=900.0, exponent=1.0, bump_nm=40.0,
                    bump_center=(0.3, 0.25, 0.92), bump_sigma=0.15),
        envmap="sunrise", background="backdrop", fits=["map"], seed=8),
    # held-out test cases (split.toml): a sun in view in two maps no earlier case used,
    # a narrow and a wide perspective camera, orthographic, constant and drainage
    "ref_drain_lin_forest_persp": dict(
        camera=persp(160, 160, 14.0, 12.0), thickness=T("drainage", top_nm=150.0, bottom_nm=900.0, exponent=1.0),
        envmap="forest", background="env", fits=["drainage"], seed=11),
    "ref_const850_forest_persp": dict(
        camera=persp(192, 160, 4.5, 35.0), thickness=T("constant", 850.0),
        envmap="forest", background="env", fits=["constant"], seed=12),
    "ref_const380_sunset_ortho": dict(
        camera=rr.Camera("ortho", 176, 160, disc=(90.0, 78.0, 52.0)), thickness=T("constant", 380.0),
        envmap="sunset", background="backdrop", fits=["constant"], seed=13),
    "ref_drain_exp12_sunset_ortho_offc": dict(
        camera=rr.Camera("ortho", 192, 160, disc=(104.0, 84.0, 56.0)),
        thickness=T("drainage", top_nm=200.0, bottom_nm=1000.0, exponent=1.2),
        envmap="sunset", background="backdrop", fits=["drainage", "map"], seed=14),
}
# the same photo fitted without its camera: a user who does not know the view
NO_CAMERA = {
    "ref_drain_lin_forest_persp_nocam": "ref_drain_lin_forest_persp",
    "ref_const850_forest_persp_nocam": "ref_const850_forest_persp",
}
# negative cases built from the positives' pixels
NEGATIVES = {
    "neg_nobubble_courtyard": dict(source="ref_const300_courtyard_ortho", kind="no_bubble", fits=["constant"]),
    "neg_wrongmap_courtyard_as_night": dict(source="ref_const300_courtyard_ortho", kind="wrong_map",
                                            envmap="night", fits=["constant"]),
    "neg_rotated90_drain_courtyard": dict(source="ref_drain_lin_courtyard_ortho", kind="rotated90",
                                          fits=["drainage"]),
}


def scene_toml(cam: rr.Camera, center=(0, 0, 0), radius=1.0) -> str:
    d = cam.describe()
    return (
        "# camera of this case, for `bubblefit fit --scene` (nothing about the bubble is held)\n"
        "[camera]\n"
        f'type = "perspective"\nwidth = {d["width"]}\nheight = {d["height"]}\n'
        f'origin = {list(map(float, d["origin"]))}\ntarget = {list(map(float, d["target"]))}\n'
        f'up = {list(map(float, d["up"]))}\nfov_deg = {float(d["fov_deg"])}\n\n'
        "[bubble]\n"
        f"center = {list(map(float, center))}\nradius = {float(radius)}\n"
    )


def load_env(name):
    return vio.read_image(os.path.join(vio.ENVMAPS, name + ".exr"))[..., :3]


def resized(cam: rr.Camera, size: int) -> rr.Camera:
    """The camera at size x size pixels: an orthographic disc keeps its relative place and
    its share of the larger side; a perspective camera keeps its field of view (width)."""
    if cam.kind == "ortho":
        cx, cy, r = cam.disc
        disc = (cx / cam.width * size, cy / cam.height * size, r * size / max(cam.width, cam.height))
        return rr.Camera("ortho", size, size, disc=disc)
    return rr.Camera("persp", size, size, origin=cam.origin, target=cam.target, up=cam.up, fov_deg=cam.fov_deg)


def make_case(name: str, spec: dict, illuminant: str = "D65", root: str | None = None,
              source: str | None = None) -> None:
    out = os.path.join(root or vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    env = load_env(spec["envmap"])
    sp = rr.spectral_setup(illuminant, 2.0)
    bubble = rr.Bubble(thickness=spec["thickness"])
    cam = spec["camera"]
    t0 = time.time()
    img, tmap = rr.render(cam, bubble, env, sp, background=spec["background"])
    bg, _ = rr.render(cam, None, env, sp, background=spec["background"])
    secs = time.time() - t0
    exposure = 0.9 / float(np.percentile(img, 99.5))
    rng = np.random.default_rng(spec["seed"])
    photo = vio.add_noise_and_quantise(img * exposure, rng, FULL_WELL, READ_NOISE)
    back = vio.add_noise_and_quantise(bg * exposure, rng, FULL_WELL, READ_NOISE)
    vio.write_png8(os.path.join(out, "photo.png"), None, photo)
    vio.write_png8(os.path.join(out, "background.png"), None, back)
    vio.write_exr(os.path.join(out, "thickness_true.exr"), tmap.astype(np.float32))
    cx, cy, r = cam.disc_pixels(bubble.center, bubble.radius)
    truth = {
        "case": name,
        **({"resized_from": source} if source else {}),
        "kind": "positive",
        "renderer": "reference_renderer.py (numpy, exact Airy film, s/p carried separately)",
        "renderer_version": rr.VERSION,
        "render_seconds": round(secs, 1),
        "camera": cam.describe(),
        "disc": {"cx": cx, "cy": cy, "r": r},
        "disc_given": False,
        "bubble": {"center": list(bubble.center), "radius": bubble.radius, "n_film": bubble.n_film},
        "thickness": spec["thickness"].describe(),
        "t": rr.t_incoherent_normal(bubble.n_film),
        "t_note": "no single t exists in the physical model: this is sqrt(1 - 2R/(1+R)) of the thick-film "
                  "limit at normal incidence for n = 1.4; the Airy film's own normal-incidence T varies with d",
        "roughness": 0.0,
        "reflection": "smooth (mirror)",
        "envmap": f"envmaps/{spec['envmap']}.exr",
        "rotation_deg": 0.0,
        "background": spec["background"],
        "background_note": ("the map seen along each camera ray" if spec["background"] == "env" or cam.kind == "persp"
                            else "a textured backdrop: the map as a 50-degree perspective camera looking along -z "
                                 "sees it, seen only by rays straight through the bubble"),
        "illuminant": illuminant,
        "observer": "CIE 1931 2 degree (colour-science), 380-780 nm every 2 nm, linear sRGB, flat 1 -> (1,1,1)",
        "internal_bounces": 8,
        "supersampling": "4x4 regular, box filter",
        "exposure": exposure,
        "noise": {"model": "Poisson-Gaussian then 8-bit sRGB", "full_well_e_at_1.0": FULL_WELL,
                  "read_noise_e": READ_NOISE, "seed": spec["seed"]},
        "fits": spec["fits"],
        "fit_args": (["--scene", "scene.toml"] if cam.kind == "persp" else []),
    }
    if cam.kind == "persp":
        with open(os.path.join(out, "scene.toml"), "w") as fh:
            fh.write(scene_toml(cam, bubble.center, bubble.radius))
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: {secs:.1f} s, exposure {exposure:.4g}, disc {cx:.1f},{cy:.1f},{r:.1f}")


def make_no_camera(name: str, source: str) -> None:
    """A copy of a perspective case without its scene.toml: the fit is not told the camera."""
    import json
    import shutil

    src, out = os.path.join(vio.DATA, source), os.path.join(vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(src, "truth.json")) as fh:
        truth = json.load(fh)
    for f in ("photo.png", "background.png", "thickness_true.exr"):
        shutil.copy(os.path.join(src, f), os.path.join(out, f))
    truth.update(case=name, source_case=source, fit_args=[],
                 camera_note="perspective photo fitted without a scene file: the fit is not told the camera")
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: {source} without its camera")


def make_negative(name: str, spec: dict) -> None:
    import json
    import shutil

    src = os.path.join(vio.DATA, spec["source"])
    out = os.path.join(vio.DATA, name)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(src, "truth.json")) as fh:
        truth = json.load(fh)
    truth.update(case=name, kind="negative", negative=spec["kind"], source_case=spec["source"], fits=spec["fits"])
    photo = vio.read_image(os.path.join(src, "photo.png"))
    back = vio.read_image(os.path.join(src, "background.png"))
    to8 = lambda a: np.round(a * 255).astype(np.uint8)  # noqa: E731
    if spec["kind"] == "no_bubble":
        # the same empty view rendered again with fresh noise: photo and background both without bubble
        cs = CASES[spec["source"]]
        bg, _ = rr.render(cs["camera"], None, load_env(cs["envmap"]), rr.spectral_setup("D65", 2.0),
                          background=cs["background"])
        rng = np.random.default_rng(99)
        vio.write_png8(os.path.join(out, "photo.png"), None,
                       vio.add_noise_and_quantise(bg * truth["exposure"], rng, FULL_WELL, READ_NOISE))
        shutil.copy(os.path.join(src, "background.png"), os.path.join(out, "background.png"))
        truth["expect"] = "no bubble: the fit should refuse or report ok: false"
        truth.pop("disc", None)
    elif spec["kind"] == "wrong_map":
        shutil.copy(os.path.join(src, "photo.png"), os.path.join(out, "photo.png"))
        shutil.copy(os.path.join(src, "background.png"), os.path.join(out, "background.png"))
        truth["envmap_true"] = truth["envmap"]
        truth["envmap"] = f"envmaps/{spec['envmap']}.exr"
        truth["expect"] = "the photo was rendered in another map: ok: false expected"
    elif spec["kind"] == "rotated90":
        vio.write_png8(os.path.join(out, "photo.png"), None, to8(np.rot90(photo[..., :3], 1)))
        vio.write_png8(os.path.join(out, "background.png"), None, to8(np.rot90(back[..., :3], 1)))
        d = truth["disc"]
        w = truth["camera"]["width"]
        # np.rot90(k=1) turns the image counter-clockwise: (x, y) -> (y, W - x)
        truth["disc"] = {"cx": d["cy"], "cy": w - d["cx"], "r": d["r"]}
        truth["expect"] = "photo and background turned 90 degrees: reflections and drainage no longer match the map; ok: false expected"
    truth["fit_args"] = []
    vio.save_json(os.path.join(out, "truth.json"), truth)
    print(f"{name}: from {spec['source']} ({spec['kind']})")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*")
    ap.add_argument("--size", type=int, help="render the cases at SIZE x SIZE into --out/<case>_SIZE/")
    ap.add_argument("--out", help="folder for --size's cases (not the validation set's data/)")
    a = ap.parse_args()
    if a.size:
        if not a.out or not a.cases or not set(a.cases) <= set(CASES):
            sys.exit("--size needs --out and positive case names")
        os.makedirs(a.out, exist_ok=True)
        link = os.path.join(a.out, "envmaps")  # truth.json names its map relative to the data folder
        if not os.path.exists(link):
            os.symlink(os.path.relpath(vio.ENVMAPS, a.out), link)
        for n in a.cases:
            make_case(f"{n}_{a.size}", dict(CASES[n], camera=resized(CASES[n]["camera"], a.size)),
                      root=a.out, source=n)
        sys.exit(0)
    names = a.cases or list(CASES) + list(NEGATIVES) + list(NO_CAMERA)
    for n in names:
        if n in CASES:
            make_case(n, CASES[n])
        elif n in NO_CAMERA:
            make_no_camera(n, NO_CAMERA[n])
        elif n in NEGATIVES:
            make_negative(n, NEGATIVES[n])
        else:
            sys.exit(f"unknown case {n}")
