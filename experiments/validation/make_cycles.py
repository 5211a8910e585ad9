"""Blender Cycles soap bubbles (run with the render venv: .venv-render/bin/python).

A bubble in Cycles: a smooth UV sphere (256 x 128 segments, radius 1) with a Principled
BSDF of IOR 1.0, Transmission Weight 1, Roughness 0 and a Thin Film (Thickness from a node
tree, Thin Film IOR 1.4): Cycles' thin film over a base of IOR 1 is an air | film | air
soap film. World: an Environment Texture of a map in data/envmaps/.

Frames. bubblefit (docs/design.md) is +y up with the camera looking along -z; Blender is +z
up. A bubblefit point (x, y, z) is the Blender point (X, Y, Z) = (x, -z, y) (a proper
rotation), so the bubblefit camera looking along -z looks along +Y in Blender, and the
film height y of the drainage profile is Blender's object-space Z. Blender's Environment
Texture reads direction D at u = 0.5 - atan2(D_Y, D_X)/(2 pi); docs/design.md's u of the same
direction is atan2(x, -z)/(2 pi) = atan2(X, Y)/(2 pi) = u_Blender - 1/4, so the world's
lookup vector is turned by +90 degrees about Z (a Mapping node) before the texture. The
rows agree (zenith at the top in both). check_conventions.py verifies this by comparing
a Cycles mirror sphere with bubblefit's own envmap lookup.

Known approximations of Cycles (recorded in each truth.json): the thin film's reflectance
averages s and p polarisation at each surface hit (unpolarised light after every bounce,
not carried per polarisation through the path); the film is integrated spectrally and
converted to RGB under illuminant E (not D65); Monte Carlo noise (denoiser off).

Sampling. Each image gets SPP = 256 samples per pixel unless its case says otherwise. A glint
of the sun reached through internal bounces is then a few path samples, each many times the
clip level (the films' reflect-or-transmit choice is sampled, and a mirror film cannot be
connected to the sun by light sampling), so the photo's glints are not the pixel integral a
camera records. The two glinting cases of the sunrise and city maps
(cyc_drain_lin_sunrise_persp, cyc_bump_city_ortho_offc) therefore render their photo with
adaptive sampling, threshold 0.01, between 8192 and 32768 samples (photo_spp,
photo_adaptive_threshold, photo_min_spp in CASES); 256 first samples leave a faint glint
that none of them reaches looking converged. The two rough films (cyc_const700_sunset_ortho_rough,
cyc_drain_lin_forest_persp_rough) render their photo with 8192 samples: the sun seen
through a rough lobe is sampled well, but 256 left the disc's pixels far noisier than a
camera. --spp N gives the photo (not the background,
which has no film) N samples per pixel for every case rendered;
--adaptive-threshold T turns on Cycles' adaptive sampling for it (at least --min-spp samples,
SPP by default, at most N, stopping a pixel when its noise estimate is below T). A glint
that no sample reaches in the first samples looks converged to adaptive sampling, so
faint glints need --min-spp high enough for a few samples to reach them. --data DIR writes the case
folders under DIR instead of data/ (the maps are still read from data/envmaps/). The
settings used go into the case's truth.json.

    python make_cycles.py [mirror] [cases | CASE ...] [--spp N] [--adaptive-threshold T [--min-spp M]] [--data DIR]
"""

from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import reference_renderer as rr  # noqa: E402  (cameras and thickness fields only: numpy)
import vio  # noqa: E402

import bpy  # noqa: E402

FULL_WELL, READ_NOISE = 4000.0, 3.0
N_FILM = 1.4
SPP = 256


def to_blender(v):
    x, y, z = v
    return (x, -z, y)


def reset(width, height, spp):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sampling(sc, spp)
    sc.cycles.use_denoising = False
    sc.cycles.seed = 1
    sc.cycles.pixel_filter_type = "BOX"
    sc.cycles.filter_width = 1.0
    sc.cycles.max_bounces = 64
    sc.cycles.transmission_bounces = 64
    sc.cycles.glossy_bounces = 64
    sc.cycles.transparent_max_bounces = 64
    sc.cycles.diffuse_bounces = 0
    sc.cycles.sample_clamp_direct = 0.0
    sc.cycles.sample_clamp_indirect = 0.0
    sc.cycles.blur_glossy = 0.0
    sc.cycles.caustics_reflective = True
    sc.cycles.caustics_refractive = True
    sc.render.threads_mode = "FIXED"
    sc.render.threads = 2
    sc.render.resolution_x = width
    sc.render.resolution_y = height
    sc.render.resolution_percentage = 100
    sc.render.film_transparent = False
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.render.image_settings.exr_codec = "ZIP"
    return sc


def sampling(sc, spp, adaptive_threshold=None, min_samples=SPP):
    """Samples per pixel: fixed (adaptive_threshold None) or Cycles' adaptive sampling between
    min_samples and spp (Blender 5.0 manual, Render > Cycles > Sampling: Noise Threshold, Min
    and Max Samples). Returns the setting as a sentence for truth.json."""
    sc.cycles.samples = spp
    sc.cycles.use_adaptive_sampling = adaptive_threshold is not None
    if adaptive_threshold is None:
        return f"{spp} spp"
    sc.cycles.adaptive_threshold = float(adaptive_threshold)
    sc.cycles.adaptive_min_samples = int(min_samples)
    return f"adaptive sampling, threshold {adaptive_threshold:g}, {min_samples}-{spp} spp"


def world(sc, envmap_path):
    w = bpy.data.worlds.new("env")
    sc.world = w
    w.use_nodes = True
    nt = w.node_tree
    nt.nodes.clear()
    tc = nt.nodes.new("ShaderNodeTexCoord")
    mp = nt.nodes.new("ShaderNodeMapping")
    mp.vector_type = "VECTOR"
    mp.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(90.0))
    tex = nt.nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(envmap_path)
    tex.image.colorspace_settings.name = "Linear Rec.709"
    tex.interpolation = "Linear"
    tex.projection = "EQUIRECTANGULAR"
    bg = nt.nodes.new("ShaderNodeBackground")
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(tc.outputs["Generated"], mp.inputs["Vector"])
    nt.links.new(mp.outputs["Vector"], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 1.0
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])


def camera(sc, cam: rr.Camera):
    data = bpy.data.cameras.new("cam")
    obj = bpy.data.objects.new("cam", data)
    sc.collection.objects.link(obj)
    sc.camera = obj
    data.sensor_fit = "HORIZONTAL"
    data.clip_start = 0.01
    data.clip_end = 1000.0
    if cam.kind == "ortho":
        cx, cy, r = cam.disc
        data.type = "ORTHO"
        data.ortho_scale = cam.width / r              # world units across the width (sphere radius 1)
        # move the camera so the sphere (at the origin) lands at pixel (cx, cy)
        ox = (cam.width / 2 - cx) / r                 # bubblefit x of the view centre
        oy = -(cam.height / 2 - cy) / r               # bubblefit y of the view centre
        obj.location = to_blender((ox, oy, 10.0))
        obj.rotation_euler = (math.pi / 2, 0.0, 0.0)  # Blender camera looks along -Z; +90 about X: along +Y
    else:
        data.type = "PERSP"
        data.angle = math.radians(cam.fov_deg)
        o = np.asarray(cam.origin, float)
        t = np.asarray(cam.target, float)
        ob = np.asarray(to_blender(o))
        tb = np.asarray(to_blender(t))
        obj.location = tuple(ob)
        fwd = tb - ob
        fwd /= np.linalg.norm(fwd)
        # Blender camera: local -Z forward, +Y up. Build the rotation from forward and world up (+Z)
        up_b = np.asarray(to_blender(cam.up), float)
        right = np.cross(fwd, up_b)
        right /= np.linalg.norm(right)
        upv = np.cross(right, fwd)
        from mathutils import Matrix
        m = Matrix(((right[0], upv[0], -fwd[0]), (right[1], upv[1], -fwd[1]), (right[2], upv[2], -fwd[2])))
        obj.rotation_euler = m.to_euler()
    return obj


def sphere(sc, material):
    mesh = bpy.data.meshes.new("sphere")
    import bmesh
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=256, v_segments=128, radius=1.0)
    bm.to_mesh(mesh)
    bm.free()
    for p in mesh.polygons:
        p.use_smooth = True
    obj = bpy.data.objects.new("bubble", mesh)
    sc.collection.objects.link(obj)
    mesh.materials.append(material)
    return obj


def mirror_material():
    m = bpy.data.materials.new("mirror")
    m.use_nodes = True
    nt = m.node_tree
    nt.nodes.clear()
    g = nt.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"
    g.inputs["Roughness"].default_value = 0.0
    g.inputs["Color"].default_value = (1, 1, 1, 1)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(g.outputs["BSDF"], out.inputs["Surface"])
    return m


def math_node(nt, op, a=None, b=None):
    n = nt.nodes.new("ShaderNodeMath")
    n.operation = op
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            n.inputs[i].default_value = float(v)
        else:
            nt.links.new(v, n.inputs[i])
    return n.outputs[0]


def bubble_material(th: rr.Thickness, roughness=0.0):
    m = bpy.data.materials.new("bubble")
    m.use_nodes = True
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (1, 1, 1, 1)
    p.inputs["IOR"].default_value = 1.0
    p.inputs["Transmission Weight"].default_value = 1.0
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Metallic"].default_value = 0.0
    p.inputs["Thin Film IOR"].default_value = N_FILM
    if th.kind == "constant":
        p.inputs["Thin Film Thickness"].default_value = th.value_nm
        return m
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    nt.links.new(tc.outputs["Object"], sep.inputs[0])
    z = sep.outputs["Z"]                                         # bubblefit y (height / radius, r = 1)
    s = math_node(nt, "SUBTRACT", 1.0, z)                        # 1 - y
    s = math_node(nt, "MULTIPLY", s, 0.5)                        # (1 - y)/2
    s = math_node(nt, "MAXIMUM", s, 0.0)
    s = math_node(nt, "POWER", s, th.exponent)
    s = math_node(nt, "MULTIPLY", s, th.bottom_nm - th.top_nm)
    d = math_node(nt, "ADD", s, th.top_nm)
    if th.kind == "bump":
        c = np.asarray(th.bump_center, float)
        c = c / np.linalg.norm(c)
        vm = nt.nodes.new("ShaderNodeVectorMath")
        vm.operation = "DISTANCE"
        nt.links.new(tc.outputs["Object"], vm.inputs[0])
        vm.inputs[1].default_value = to_blender(c)
        dist = vm.outputs["Value"]
        e = math_node(nt, "MULTIPLY", dist, dist)
        e = math_node(nt, "MULTIPLY", e, -1.0 / (2 * th.bump_sigma ** 2))
        e = math_node(nt, "EXPONENT", e)
        e = math_node(nt, "MULTIPLY", e, th.bump_nm)
        d = math_node(nt, "ADD", d, e)
    nt.links.new(d, p.inputs["Thin Film Thickness"])
    return m


def render_to_array(sc, path):
    sc.render.filepath = path
    bpy.ops.render.render(write_still=True)
    return vio.read_image(path)[..., :3]


def persp(w, h, dist, fov):
    return rr.Camera("persp", w, h, origin=(0.0, 0.0, dist), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg=fov)


def make_mirror():
    out = os.path.join(vio.DATA, "conventions")
    os.makedirs(out, exist_ok=True)
    for kind, cam in (("ortho", rr.Camera("ortho", 128, 128, disc=(64.0, 64.0, 50.0))), ("persp", persp(128, 128, 4.0, 40.0))):
        sc = reset(128, 128, 64)
        world(sc, os.path.join(vio.ENVMAPS, "courtyard.exr"))
        camera(sc, cam)
        sphere(sc, mirror_material())
        render_to_array(sc, os.path.join(out, f"cycles_mirror_{kind}.exr"))
        print("cycles mirror", kind, flush=True)


T = rr.Thickness
CASES = {
    "cyc_const500_courtyard_ortho": dict(camera=rr.Camera("ortho", 160, 160, disc=(84.0, 76.0, 50.0)),
                                         thickness=T("constant", 500.0), envmap="courtyard",
                                         fits=["constant"], seed=31),
    "cyc_drain_lin_sunrise_persp": dict(camera=persp(160, 160, 4.0, 42.0),
                                        thickness=T("drainage", top_nm=150.0, bottom_nm=900.0, exponent=1.0),
                                        envmap="sunrise", fits=["drainage", "map"], seed=32,
                                        photo_spp=32768, photo_adaptive_threshold=0.01, photo_min_spp=8192),
    "cyc_bump_city_ortho_offc": dict(camera=rr.Camera("ortho", 176, 160, disc=(96.0, 84.0, 54.0)),
                                     thickness=T("bump", top_nm=200.0, bottom_nm=850.0, exponent=1.5, bump_nm=40.0,
                                                 bump_center=(-0.25, 0.3, 0.92), bump_sigma=0.15),
                                     envmap="city", fits=["map"], seed=33,
                                     photo_spp=32768, photo_adaptive_threshold=0.01, photo_min_spp=8192),
    # held-out test cases (experiments/validation/split.toml): rough films with a sun in view,
    # in two maps no earlier case used; "roughness" is the Principled BSDF's (GGX alpha = roughness^2).
    # 8192 samples per pixel: at 256 the sun's light through the rough lobe left Monte Carlo
    # noise of 7-19 times the sensor model's variance inside the disc
    "cyc_const700_sunset_ortho_rough": dict(camera=rr.Camera("ortho", 176, 160, disc=(90.0, 78.0, 54.0)),
                                            thickness=T("constant", 700.0), envmap="sunset",
                                            fits=["constant"], seed=41, roughness=0.15, photo_spp=8192),
    "cyc_drain_lin_forest_persp_rough": dict(camera=persp(160, 160, 4.5, 32.0),
                                             thickness=T("drainage", top_nm=200.0, bottom_nm=950.0, exponent=1.0),
                                             envmap="forest", fits=["drainage"], seed=42, roughness=0.1,
                                             photo_spp=8192),
    # the test part's rough constant film, added when cyc_const700_sunset_ortho_rough moved to
    # development (split.toml): another map, thickness, roughness and disc
    "cyc_const450_forest_ortho_rough": dict(camera=rr.Camera("ortho", 160, 160, disc=(78.0, 82.0, 52.0)),
                                            thickness=T("constant", 450.0), envmap="forest",
                                            fits=["constant"], seed=43, roughness=0.2, photo_spp=8192),
}


def thickness_truth(cam: rr.Camera, th: rr.Thickness):
    """Front film thickness at pixel centres (NaN off the sphere), from the same camera model."""
    H, W = cam.height, cam.width
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    o, d = cam.rays(jj.reshape(-1), ii.reshape(-1), np.zeros(3), 1.0)
    hit, s = rr._intersect(o, d, np.zeros(3), 1.0)
    tm = np.full(H * W, np.nan)
    p = o[hit] + s[hit, None] * d[hit]
    tm[hit] = th(p)
    return tm.reshape(H, W)


def make_cases(names=None, data=None, spp=None, adaptive_threshold=None, min_spp=None):
    """Render each case (or those named) into DATA/<case>/; spp, when given, sets the photo's
    sampling with adaptive_threshold and min_spp (see the module's docstring), else the case's
    own (photo_spp, photo_adaptive_threshold, photo_min_spp; SPP fixed by default)."""
    for name, c in CASES.items():
        if names and name not in names:
            continue
        out = os.path.join(data or vio.DATA, name)
        os.makedirs(out, exist_ok=True)
        cam = c["camera"]
        env = os.path.join(vio.ENVMAPS, c["envmap"] + ".exr")
        t0 = time.time()
        sc = reset(cam.width, cam.height, SPP)
        world(sc, env)
        camera(sc, cam)
        back = render_to_array(sc, os.path.join("/tmp", name + "_bg.exr"))
        rough = float(c.get("roughness", 0.0))
        sphere(sc, bubble_material(c["thickness"], roughness=rough))
        sc.cycles.seed = 2
        if spp or adaptive_threshold is not None:
            photo_spp, thr, min_photo = spp or SPP, adaptive_threshold, min_spp or SPP
        else:
            photo_spp, thr, min_photo = (c.get("photo_spp", SPP), c.get("photo_adaptive_threshold"),
                                         c.get("photo_min_spp", SPP))
        photo_sampling = sampling(sc, photo_spp, thr, min_photo)
        photo = render_to_array(sc, os.path.join("/tmp", name + "_photo.exr"))
        secs = time.time() - t0
        expo = 0.9 / float(np.percentile(photo, 99.5))
        rng = np.random.default_rng(c["seed"])
        vio.write_png8(os.path.join(out, "photo.png"), None, vio.add_noise_and_quantise(photo * expo, rng, FULL_WELL, READ_NOISE))
        vio.write_png8(os.path.join(out, "background.png"), None, vio.add_noise_and_quantise(back * expo, rng, FULL_WELL, READ_NOISE))
        vio.write_exr(os.path.join(out, "thickness_true.exr"), thickness_truth(cam, c["thickness"]).astype(np.float32))
        cx, cy, r = cam.disc_pixels((0, 0, 0), 1.0)
        fit_args = []
        if cam.kind == "persp":
            dsc = cam.describe()
            with open(os.path.join(out, "scene.toml"), "w") as fh:
                fh.write("# camera of this case, for `bubblefit fit --scene` (nothing about the bubble is held)\n"
                         f'[camera]\ntype = "perspective"\nwidth = {cam.width}\nheight = {cam.height}\n'
                         f'origin = {list(map(float, dsc["origin"]))}\ntarget = {list(map(float, dsc["target"]))}\n'
                         f'up = {list(map(float, dsc["up"]))}\nfov_deg = {float(cam.fov_deg)}\n\n'
                         "[bubble]\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\n")
            fit_args = ["--scene", "scene.toml"]
        truth = {
            "case": name, "kind": "positive",
            "renderer": f"Blender {bpy.app.version_string} Cycles (CPU), box filter 1 px, denoiser off; "
                        f"photo {photo_sampling}, background {SPP} spp",
            "sampling": {"photo_samples": photo_spp, "photo_adaptive_threshold": thr,
                         "photo_adaptive_min_samples": min_photo if thr is not None else None,
                         "background_samples": SPP, "seed_photo": 2, "seed_background": 1},
            "renderer_version": f"bpy {bpy.app.version_string}",
            "render_seconds": round(secs, 1),
            "camera": cam.describe(), "disc": {"cx": cx, "cy": cy, "r": r}, "disc_given": False,
            "bubble": {"center": [0, 0, 0], "radius": 1.0, "n_film": N_FILM,
                       "material": f"Principled BSDF: IOR 1.0, Transmission Weight 1, Roughness {rough:g}, Thin Film IOR 1.4",
                       "mesh": "UV sphere 256 x 128, smooth shading"},
            "thickness": c["thickness"].describe(),
            "t": rr.t_incoherent_normal(N_FILM),
            "t_note": "sqrt(1 - 2R/(1+R)) of the thick-film limit at normal incidence, n = 1.4 (reference value)",
            "roughness": rough,
            "reflection": ("smooth (mirror)" if rough == 0 else
                           f"rough: Principled BSDF Roughness {rough:g} (GGX, alpha = {rough ** 2:.4g}); "
                           "not on bubblefit's roughness scale, so not scored"),
            "envmap": f"envmaps/{c['envmap']}.exr", "rotation_deg": 0.0, "background": "env",
            "illuminant": "E",
            "approximations": [
                "Cycles averages s and p polarisation at each surface (light is unpolarised after every hit)",
                "Cycles integrates the film's spectrum under illuminant E (bubblefit's default is D65)",
                "UV-sphere mesh (256 x 128) with interpolated normals, not an exact sphere",
                "Monte Carlo noise (denoiser off)"],
            "exposure": expo,
            "noise": {"model": "Cycles Monte Carlo noise, then Poisson-Gaussian and 8-bit sRGB",
                      "full_well_e_at_1.0": FULL_WELL, "read_noise_e": READ_NOISE, "seed": c["seed"]},
            "fits": c["fits"], "fit_args": fit_args,
        }
        vio.save_json(os.path.join(out, "truth.json"), truth)
        print(f"{name}: {secs:.1f} s, exposure {expo:.4g}", flush=True)


def main(argv=None):
    """Command line: the jobs named (mirror spheres, the cases) with the photos' sampling options."""
    import argparse
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("jobs", nargs="*", help="mirror, cases or case names (default: mirror and cases)")
    ap.add_argument("--spp", type=int, help=f"the photo's samples per pixel (most, with adaptive sampling; default the case's, {SPP})")
    ap.add_argument("--adaptive-threshold", type=float, help="Cycles' adaptive sampling for the photo, at least SPP samples")
    ap.add_argument("--min-spp", type=int, help=f"the photo's fewest samples per pixel with adaptive sampling [{SPP}]")
    ap.add_argument("--data", help="write the case folders under this folder (default data/)")
    a = ap.parse_args(argv)
    jobs = a.jobs or ["mirror", "cases"]
    bad = [j for j in jobs if j not in ("mirror", "cases", *CASES)]
    if bad:
        ap.error(f"unknown job or case: {', '.join(bad)}")
    if a.spp is not None and a.spp < SPP:
        ap.error(f"--spp must be at least {SPP}")
    if a.adaptive_threshold is not None and a.adaptive_threshold <= 0:
        ap.error("--adaptive-threshold must be positive")
    if a.min_spp is not None and (a.adaptive_threshold is None or not SPP <= a.min_spp <= (a.spp or SPP)):
        ap.error(f"--min-spp needs --adaptive-threshold and lies between {SPP} and --spp")
    if "mirror" in jobs:
        make_mirror()
    if "cases" in jobs or any(j in CASES for j in jobs):
        make_cases([j for j in jobs if j in CASES] or None, data=a.data, spp=a.spp, adaptive_threshold=a.adaptive_threshold, min_spp=a.min_spp)


if __name__ == "__main__":
    main()
