"""Mitsuba 3 references (run with the render venv, .venv-render/bin/python).

Variant scalar_rgb. The bubble is a `sphere` with a `thindielectric` BSDF (int_ior 1.4,
ext_ior 1.0): Mitsuba's thin slab with all incoherent reflections inside it, R_slab =
2R/(1+R) of the unpolarised Fresnel R of one interface, no interference (the thick-film
limit). Outputs:

  data/cal_*/before.png, after.png, truth.json      dark-box calibration pairs
  data/mts_*/photo.png, background.png, truth.json   thin-dielectric bubbles in a map
  ../../tests/data/probes/*                          mirror balls for `bubblefit envmap`
  data/conventions/mitsuba_mirror_*.exr              mirror spheres for check_conventions.py

The thick bubbles' photos get 256 samples per pixel unless their case says otherwise. A glint
of the sun reached through internal bounces is then a few path samples, each many times the
clip level (the slab's reflect-or-transmit choice is sampled), so the photo's glints are not
the pixel integral a camera records; the sunrise bubble (mts_thick_sunrise_ortho), whose sun
glints through the slab, therefore renders its photo with 32768 samples per pixel
(photo_spp in MTS_CASES). --spp N renders the photo (not the background, which has no film)
of every thick bubble rendered with N samples per pixel, the same seed. --data DIR writes the case folders under DIR
instead of data/. The settings used go into the case's truth.json.

    python make_mitsuba.py [cal] [mts | CASE ...] [probes] [mirror] [--spp N] [--data DIR]   # default: all
"""

from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import vio  # noqa: E402

import mitsuba as mi  # noqa: E402

mi.set_variant("scalar_rgb")
T = mi.ScalarTransform4f
N_FILM = 1.4
PROBES = os.path.normpath(os.path.join(vio.HERE, "..", "..", "tests", "data", "probes"))
FULL_WELL, READ_NOISE = 4000.0, 3.0


def t_truth(n=N_FILM):
    """Per-interface t: sqrt of the slab's transmission 1 - 2R/(1+R), R at normal incidence."""
    r = ((n - 1) / (n + 1)) ** 2
    return math.sqrt(1 - 2 * r / (1 + r))


def film(w, h, spp):
    return {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}, "pixel_format": "rgb"}


def persp_sensor(w, h, origin, target, fov, spp, seed=0):
    return {"type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": T().look_at(origin=origin, target=target, up=[0, 1, 0]),
            "film": film(w, h, spp), "sampler": {"type": "independent", "sample_count": spp, "seed": seed}}


def ortho_sensor(w, h, center_xy, half_width, spp, seed=0):
    cx, cy = center_xy
    return {"type": "orthographic",
            "to_world": T().look_at(origin=[cx, cy, 10], target=[cx, cy, 0], up=[0, 1, 0]) @ T().scale([half_width, half_width, 1]),
            "film": film(w, h, spp), "sampler": {"type": "independent", "sample_count": spp, "seed": seed}}


def render(scene_dict, spp=None):
    scene = mi.load_dict(scene_dict)
    img = np.array(mi.render(scene, spp=spp or 0), dtype=np.float64)
    return img[..., :3]


def bubble(center=(0, 0, 0), radius=1.0):
    return {"type": "sphere", "center": list(center), "radius": radius,
            "bsdf": {"type": "thindielectric", "int_ior": N_FILM, "ext_ior": 1.0}}


# ------------------------------------------------------------------ dark-box calibration
def dark_box(w, h, cam, bubble_on, spp, seed, card_z=-2.0, checks=8):
    box = {"type": "cube", "to_world": T().scale([6, 6, 8]),
           "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.01, 0.01, 0.01]}},
           "flip_normals": True}
    card = {"type": "rectangle", "to_world": T().translate([0, 0, card_z]) @ T().scale([3.0, 3.0, 1.0]),
            "emitter": {"type": "area", "radiance": {
                "type": "checkerboard", "color0": {"type": "rgb", "value": [0.25, 0.25, 0.25]},
                "color1": {"type": "rgb", "value": [1.0, 1.0, 1.0]},
                "to_uv": T().scale([checks, checks, 1])}}}
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": 16}, "sensor": cam, "box": box, "card": card}
    if bubble_on:
        d["bubble"] = bubble()
    return d


def make_cal():
    framings = {
        # name: (w, h, origin, fov, spp)
        "cal_box_256x192": (256, 192, [0.0, 0.0, 4.2], 45.0, 256),
        "cal_box_512x384_offc": (512, 384, [0.9, -0.5, 5.5], 38.0, 96),
    }
    for name, (w, h, origin, fov, spp) in framings.items():
        out = os.path.join(vio.DATA, name)
        os.makedirs(out, exist_ok=True)
        cam = persp_sensor(w, h, origin, cam_target(origin), fov, spp)
        t0 = time.time()
        before = render(dark_box(w, h, cam, False, spp, 1))
        cam["sampler"]["seed"] = 7
        after = render(dark_box(w, h, cam, True, spp, 2))
        secs = time.time() - t0
        expo = 0.85 / float(np.percentile(before, 99.5))
        rng = np.random.default_rng(11)
        vio.write_png8(os.path.join(out, "before.png"), None, vio.add_noise_and_quantise(before * expo, rng, FULL_WELL, READ_NOISE))
        vio.write_png8(os.path.join(out, "after.png"), None, vio.add_noise_and_quantise(after * expo, rng, FULL_WELL, READ_NOISE))
        disc = sphere_disc(w, h, origin, cam_target(origin), fov, (0, 0, 0), 1.0)
        # what the clean pair itself says inside 0.5 r: the ratio a perfect estimator would see
        yy, xx = np.mgrid[0:h, 0:w] + 0.5
        inner = (xx - disc["cx"]) ** 2 + (yy - disc["cy"]) ** 2 < (0.5 * disc["r"]) ** 2
        ratio = after[inner].sum(0) / before[inner].sum(0)
        truth = {
            "case": name, "kind": "calibration",
            "renderer": f"Mitsuba {mi.__version__} scalar_rgb, path tracer max_depth 16, {spp} spp, box filter",
            "scene": "backlit checkered card (area emitter, checkerboard 1.0 / 0.25) at z = -2 inside a matte "
                     "black box (albedo 0.01); bubble: sphere r = 1 at the origin, thindielectric int_ior 1.4",
            "camera": {"type": "perspective", "width": w, "height": h, "origin": origin,
                       "target": cam_target(origin), "up": [0, 1, 0], "fov_deg": fov, "fov_axis": "width"},
            "disc": disc, "disc_given": False,
            "t": t_truth(), "t4": t_truth() ** 4,
            "t_note": "sqrt(T_slab), T_slab = 1 - 2R/(1+R), R = ((n-1)/(n+1))^2 at normal incidence, s = p",
            "clean_ratio_inner_half_radius": ratio.tolist(),
            "clean_ratio_note": "after/before of the noise-free renders within 0.5 r: t^4 times (1 + the small "
                                "inter-film reflections and the lower transmission off normal incidence)",
            "exposure": expo,
            "noise": {"model": "Mitsuba Monte Carlo noise, then Poisson-Gaussian and 8-bit sRGB",
                      "full_well_e_at_1.0": FULL_WELL, "read_noise_e": READ_NOISE, "seed": 11},
            "render_seconds": round(secs, 1),
        }
        vio.save_json(os.path.join(out, "truth.json"), truth)
        print(f"{name}: {secs:.1f} s, disc {disc}, clean ratio {np.round(ratio, 5)} vs t^4 {t_truth() ** 4:.5f}")


def cam_target(origin):
    return [0.35 * origin[0], 0.35 * origin[1], 0.0]


def sphere_disc(w, h, origin, target, fov, center, radius):
    """Projected centre and mean radius (pixels) of a sphere's outline in a perspective view."""
    o = np.asarray(origin, float)
    f = np.asarray(target, float) - o
    f /= np.linalg.norm(f)
    right = np.cross(f, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    fpx = (w / 2) / math.tan(math.radians(fov) / 2)
    v = np.asarray(center, float) - o
    dist = np.linalg.norm(v)
    alpha = math.asin(radius / dist)
    # sample the outline: the tangent cone's rim, projected
    k = v / dist
    a = np.cross(k, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(k, a)
    ph = np.linspace(0, 2 * np.pi, 721)[:-1]
    rim = np.cos(alpha) * k[None] + np.sin(alpha) * (np.cos(ph)[:, None] * a + np.sin(ph)[:, None] * b)
    x = w / 2 + fpx * (rim @ right) / (rim @ f)
    y = h / 2 - fpx * (rim @ up) / (rim @ f)
    cx, cy = 0.5 * (x.max() + x.min()), 0.5 * (y.max() + y.min())
    r = 0.25 * (x.max() - x.min() + y.max() - y.min())
    return {"cx": float(cx), "cy": float(cy), "r": float(r),
            "ellipse_axes_px": [float(0.5 * (x.max() - x.min())), float(0.5 * (y.max() - y.min()))]}


# ------------------------------------------------------------------ environment
def envmap_emitter(name):
    return {"type": "envmap", "filename": os.path.join(vio.ENVMAPS, name + ".exr")}


MTS_SPP = 256
MTS_CASES = {
    "mts_thick_courtyard_persp": dict(envmap="courtyard", kind="persp", w=176, h=144),
    "mts_thick_sunrise_ortho": dict(envmap="sunrise", kind="ortho", w=160, h=160, photo_spp=32768),
}


def make_mts(names=None, data=None, spp=None):
    """Render the thick bubbles (or those named) into DATA/<case>/; spp, when given, is the
    photo's samples per pixel (else the case's photo_spp, MTS_SPP by default)."""
    for name, c in MTS_CASES.items():
        if names and name not in names:
            continue
        c = dict(c, spp=MTS_SPP)
        photo_spp = spp or c.get("photo_spp", MTS_SPP)
        out = os.path.join(data or vio.DATA, name)
        os.makedirs(out, exist_ok=True)
        w, h = c["w"], c["h"]
        if c["kind"] == "persp":
            origin, fov = [0.0, 0.0, 4.0], 40.0
            cam = persp_sensor(w, h, origin, [0, 0, 0], fov, c["spp"])
            disc = sphere_disc(w, h, origin, [0, 0, 0], fov, (0, 0, 0), 1.0)
            camd = {"type": "perspective", "width": w, "height": h, "origin": origin, "target": [0, 0, 0],
                    "up": [0, 1, 0], "fov_deg": fov, "fov_axis": "width"}
        else:
            # disc centre (72, 84) px, r = 52 px: half width of the view = W / (2 r)
            cxp, cyp, rp = 72.0, 84.0, 52.0
            hw = w / (2 * rp)
            ccx = (w / 2 - cxp) / rp          # camera centre in world units so the sphere sits at (cxp, cyp)
            ccy = -(h / 2 - cyp) / rp
            cam = ortho_sensor(w, h, (ccx, ccy), hw, c["spp"])
            disc = {"cx": cxp, "cy": cyp, "r": rp}
            camd = {"type": "orthographic", "width": w, "height": h, "disc": [cxp, cyp, rp]}
        scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 24}, "sensor": cam,
                 "env": envmap_emitter(c["envmap"])}
        t0 = time.time()
        back = render(scene)
        scene["bubble"] = bubble()
        cam["sampler"]["seed"] = 3
        cam["sampler"]["sample_count"] = photo_spp
        photo = render(scene)
        secs = time.time() - t0
        expo = 0.9 / float(np.percentile(photo, 99.5))
        rng = np.random.default_rng(21)
        vio.write_png8(os.path.join(out, "photo.png"), None, vio.add_noise_and_quantise(photo * expo, rng, FULL_WELL, READ_NOISE))
        vio.write_png8(os.path.join(out, "background.png"), None, vio.add_noise_and_quantise(back * expo, rng, FULL_WELL, READ_NOISE))
        scene_toml = ["# this case's film is thick (incoherent): no interference; nothing about the bubble is held"]
        if c["kind"] == "persp":
            scene_toml += ["[camera]", 'type = "perspective"', f"width = {w}", f"height = {h}",
                           f"origin = {origin}", "target = [0.0, 0.0, 0.0]", "up = [0.0, 1.0, 0.0]", f"fov_deg = {fov}"]
        scene_toml += ["", "[effects]", 'interference = "off"', ""]
        with open(os.path.join(out, "scene.toml"), "w") as fh:
            fh.write("\n".join(scene_toml))
        truth = {
            "case": name, "kind": "positive",
            "renderer": f"Mitsuba {mi.__version__} scalar_rgb, path tracer max_depth 24, box filter; "
                        f"photo {photo_spp} spp, background {c['spp']} spp",
            "sampling": {"photo_samples": photo_spp, "background_samples": c["spp"], "seed_photo": 3, "seed_background": 0},
            "renderer_version": mi.__version__,
            "bubble": {"center": [0, 0, 0], "radius": 1.0, "n_film": N_FILM, "bsdf": "thindielectric"},
            "camera": camd, "disc": disc, "disc_given": False,
            "thickness": {"profile": "incoherent", "note": "thick-film limit: no interference"},
            "t": t_truth(), "t_note": "sqrt(1 - 2R/(1+R)) at normal incidence, n = 1.4",
            "roughness": 0.0, "reflection": "smooth (mirror)",
            "envmap": f"envmaps/{c['envmap']}.exr", "rotation_deg": 0.0, "background": "env",
            "illuminant": "none (RGB renderer)",
            "approximations": ["unpolarised Fresnel per interface (s and p averaged before the slab sum)",
                               "RGB rendering, no spectra", "Monte Carlo noise"],
            "exposure": expo,
            "noise": {"model": "Mitsuba Monte Carlo noise, then Poisson-Gaussian and 8-bit sRGB",
                      "full_well_e_at_1.0": FULL_WELL, "read_noise_e": READ_NOISE, "seed": 21},
            "fits": ["constant"], "fit_args": ["--scene", "scene.toml"],
            "render_seconds": round(secs, 1),
        }
        vio.save_json(os.path.join(out, "truth.json"), truth)
        print(f"{name}: {secs:.1f} s, disc {disc}")


# ------------------------------------------------------------------ mirror balls
def mirror_ball(center=(0, 0, 0), radius=1.0):
    return {"type": "sphere", "center": list(center), "radius": radius,
            "bsdf": {"type": "conductor", "material": "none"}}


def busy_texture(path, n=256, seed=5):
    rng = np.random.default_rng(seed)
    base = rng.random((n // 8, n // 8, 3))
    img = np.kron(base, np.ones((8, 8, 1)))
    yy, xx = np.mgrid[0:n, 0:n] / n
    img = 0.6 * img + 0.4 * (0.5 + 0.5 * np.sin(40 * xx + 25 * yy)[..., None] * np.array([1.0, 0.6, 0.2]))
    vio.write_png8(path, img ** 2.2)


def make_probes():
    os.makedirs(PROBES, exist_ok=True)
    tex = os.path.join(PROBES, "_busy_texture.png")
    busy_texture(tex)
    W = H = 192
    truth = {"renderer": f"Mitsuba {mi.__version__} scalar_rgb", "envmap": "experiments/validation/data/envmaps/courtyard.exr",
             "ball": "perfect mirror (conductor, material none: R = 1) of radius 1",
             "pixel_convention": "x right, y down, pixel centres at +0.5", "probes": {}}
    for bgname in ("dark", "busy"):
        if bgname == "dark":
            plane_bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.02, 0.02, 0.02]}}
        else:
            plane_bsdf = {"type": "diffuse", "reflectance": {"type": "bitmap", "filename": tex}}
        for cam in ("ortho", "persp"):
            if cam == "ortho":
                cxp, cyp, rp = 104.0, 88.0, 60.0
                hw = W / (2 * rp)
                sensor = ortho_sensor(W, H, ((W / 2 - cxp) / rp, -(H / 2 - cyp) / rp), hw, 128)
                ball = {"cx": cxp, "cy": cyp, "r": rp}
                camd = {"type": "orthographic"}
            else:
                origin, fov = [0.0, 0.0, 6.0], 30.0
                sensor = persp_sensor(W, H, origin, [0, 0, 0], fov, 128)
                ball = sphere_disc(W, H, origin, [0, 0, 0], fov, (0, 0, 0), 1.0)
                camd = {"type": "perspective", "origin": origin, "target": [0, 0, 0], "fov_deg": fov,
                        "fov_axis": "width", "distance_radii": 6.0}
            scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 8}, "sensor": sensor,
                     "env": envmap_emitter("courtyard"), "ball": mirror_ball(),
                     "plane": {"type": "rectangle", "to_world": T().translate([0, 0, -3.0]) @ T().scale([8.0, 8.0, 1.0]),
                               "bsdf": plane_bsdf}}
            img = render(scene)
            stem = f"ball_{bgname}_{cam}"
            expo = 0.9 / float(np.percentile(img, 99.0))
            vio.write_png8(os.path.join(PROBES, stem + ".png"), img * expo)
            if bgname == "dark" and cam == "ortho":
                vio.write_exr(os.path.join(PROBES, stem + ".exr"), img, half=True)
            truth["probes"][stem] = {"ball": ball, "camera": camd, "background": bgname, "size": [W, H],
                                     "png_exposure": expo, "files": [stem + ".png"] + ([stem + ".exr"] if (bgname == "dark" and cam == "ortho") else [])}
            print(stem, ball)
    rng = np.random.default_rng(3)
    vio.write_png8(os.path.join(PROBES, "noise.png"), None, rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8))
    truth["probes"]["noise"] = {"ball": None, "note": "uniform random 8-bit noise: no ball; the command should refuse"}
    os.remove(tex)
    vio.save_json(os.path.join(PROBES, "probes_truth.json"), truth)


# ------------------------------------------------------------------ convention check renders
def make_mirror():
    out = os.path.join(vio.DATA, "conventions")
    os.makedirs(out, exist_ok=True)
    W = H = 128
    for cam in ("ortho", "persp"):
        if cam == "ortho":
            sensor = ortho_sensor(W, H, (0.0, 0.0), W / (2 * 50.0), 64)
        else:
            sensor = persp_sensor(W, H, [0.0, 0.0, 4.0], [0, 0, 0], 40.0, 64)
        scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 4}, "sensor": sensor,
                 "env": envmap_emitter("courtyard"), "ball": mirror_ball()}
        vio.write_exr(os.path.join(out, f"mitsuba_mirror_{cam}.exr"), render(scene))
        print("mirror", cam)


def main(argv=None):
    """Command line: the jobs named (calibration pairs, thick bubbles, probes, mirror spheres)."""
    import argparse
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("jobs", nargs="*", help="cal, mts, probes, mirror or thick-bubble case names (default: all)")
    ap.add_argument("--spp", type=int, help=f"the thick bubbles' photo samples per pixel (default the case's, {MTS_SPP})")
    ap.add_argument("--data", help="write the thick bubbles' case folders under this folder (default data/)")
    a = ap.parse_args(argv)
    jobs = a.jobs or ["mirror", "cal", "mts", "probes"]
    bad = [j for j in jobs if j not in ("cal", "mts", "probes", "mirror", *MTS_CASES)]
    if bad:
        ap.error(f"unknown job or case: {', '.join(bad)}")
    if a.spp is not None and a.spp < MTS_SPP:
        ap.error(f"--spp must be at least {MTS_SPP}")
    for j in jobs:
        if j in MTS_CASES:
            continue
        if j == "mts":
            make_mts(data=a.data, spp=a.spp)
        else:
            {"cal": make_cal, "probes": make_probes, "mirror": make_mirror}[j]()
    named = [j for j in jobs if j in MTS_CASES]
    if named:
        make_mts(named, data=a.data, spp=a.spp)


if __name__ == "__main__":
    main()
