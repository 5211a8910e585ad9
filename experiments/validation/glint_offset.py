"""Where a mirror sphere's glints land: bubblefit against Mitsuba 3 against the reflection law.

A perfect mirror sphere (radius 1 at the origin) over a black map with eight Gaussian
spots (``sigma`` radians) is rendered by Mitsuba 3 (``scalar_rgb``, ``conductor`` with
material none, box filter) and by bubblefit (paper model, front film only, ``r_s = 1``,
roughness 0, ``mirror`` filtering; with the pixel footprint, and with 16 rays per pixel
without it), same camera and resolution. The spots are placed by the law of reflection
``r = d - 2 (d.n) n`` so that an orthographic view shows their glints at eight sphere
normals from the centre to 0.82 of the radius; a perspective view's glint is the pixel
whose pinhole ray (docs/design.md's camera, Mitsuba's ``fov_axis = "x"``) reflects into
the spot, found by Newton's method. Each glint's centroid (11 x 11 window, pixel centres
at +1/2) is compared between the renderers and with that point. The map's texels are
filled at docs/design.md's texel positions (``u = (j + 1/2) / W``, ``v = i / (H - 1)``).

Run with the project's venv (it has ``mitsuba``), from the repository root:

    PYTHONPATH=. .venv/bin/python experiments/validation/glint_offset.py OUT.json [CONFIG ...]

experiments/results/glints/mirror_offsets.json summarises a run of every configuration.
"""
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import vio  # noqa

import mitsuba as mi  # noqa

mi.set_variant("scalar_rgb")
T = mi.ScalarTransform4f

import jax.numpy as jnp  # noqa
from bubblefit.lighting.envmap import EnvMap  # noqa
from bubblefit.lighting.filtering import FilterConfig  # noqa
from bubblefit.model.effects import Effects  # noqa
from bubblefit.model.geometry import OrthographicCamera, PerspectiveCamera  # noqa
from bubblefit.model.render import Params, RenderConfig, render  # noqa

TMP = os.environ.get("TMPDIR", "/tmp")


def texel_dirs(h):
    """Directions of the texel positions of docs/design.md (Mitsuba's): u = (j + 1/2)/W, v = i/(H-1)."""
    w = 2 * h
    u = (np.arange(w) + 0.5) / w
    v = np.arange(h) / (h - 1)
    ph, th = 2 * np.pi * u[None, :], np.pi * v[:, None]
    x = np.sin(th) * np.sin(ph)
    y = np.cos(th) * np.ones_like(ph)
    z = -np.sin(th) * np.cos(ph)
    return np.stack([x, y, z], -1)


def spot_map(h, suns, sigma):
    """A black (h, 2h, 3) map with a Gaussian spot of angular width ``sigma`` at each direction of ``suns``."""
    d = texel_dirs(h)
    px = np.zeros(d.shape[:2])
    for s in suns:
        ang = np.arccos(np.clip(d @ s, -1, 1))
        px += 100.0 * np.exp(-0.5 * (ang / sigma) ** 2)
    return np.repeat(px[..., None], 3, -1)


def reflect(d, n):
    """The law of reflection: ``d`` mirrored about the unit normal ``n``."""
    return d - 2 * np.dot(d, n) * n


def ortho_suns(normals):
    """Sun directions whose mirror image in an orthographic view sits at sphere normal n."""
    out = []
    for nx, ny in normals:
        n = np.array([nx, ny, math.sqrt(1 - nx * nx - ny * ny)])
        out.append(reflect(np.array([0.0, 0.0, -1.0]), n))
    return out


def persp_ray(cam, px, py):
    """The pinhole's ray through image point (px, py): docs/design.md's perspective camera looking at the origin."""
    o = np.asarray(cam["origin"], float)
    f = -o / np.linalg.norm(o)
    right = np.cross(f, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    t = math.tan(math.radians(cam["fov"]) / 2)
    x = (2 * px / cam["w"] - 1) * t
    y = (1 - 2 * py / cam["h"]) * t * cam["h"] / cam["w"]
    d = x * right + y * up + f
    return o, d / np.linalg.norm(d)


def persp_glint_pixel(cam, s):
    """Image point (continuous, pixel centres at +1/2) whose ray reflects into s, by Newton."""
    def refl(p):
        o, d = persp_ray(cam, *p)
        b = np.dot(o, d)
        disc = b * b - (np.dot(o, o) - 1)
        if disc < 0:
            return None
        q = o + (-b - math.sqrt(disc)) * d
        return reflect(d, q)
    # start: the normal halfway between the view and the sun
    o = np.asarray(cam["origin"], float)
    n = s + o / np.linalg.norm(o)
    n /= np.linalg.norm(n)
    # project n (a point on the unit sphere) into the image
    f = -o / np.linalg.norm(o)
    right = np.cross(f, [0.0, 1.0, 0.0]); right /= np.linalg.norm(right)
    up = np.cross(right, f)
    v = n - o
    t = math.tan(math.radians(cam["fov"]) / 2)
    p = np.array([(np.dot(v, right) / np.dot(v, f) / t + 1) * cam["w"] / 2,
                  (1 - np.dot(v, up) / np.dot(v, f) / (t * cam["h"] / cam["w"])) * cam["h"] / 2])
    for _ in range(30):
        r0 = refl(p)
        e = 1e-4
        J = np.stack([(refl(p + [e, 0]) - refl(p - [e, 0])) / (2 * e), (refl(p + [0, e]) - refl(p - [0, e])) / (2 * e)], -1)
        step = np.linalg.lstsq(J, s - r0, rcond=None)[0]
        p = p + step
        if np.abs(step).max() < 1e-7:
            break
    return p


def mitsuba_image(cam, envfile, spp):
    """Mitsuba 3's mirror sphere, framed as make_mitsuba.py frames the validation photos."""
    if cam["type"] == "ortho":
        w, h, (cxp, cyp, rp) = cam["w"], cam["h"], cam["disc"]
        hw = w / (2 * rp)
        ccx, ccy = (w / 2 - cxp) / rp, -(h / 2 - cyp) / rp
        sensor = {"type": "orthographic",
                  "to_world": T().look_at(origin=[ccx, ccy, 10], target=[ccx, ccy, 0], up=[0, 1, 0]) @ T().scale([hw, hw, 1])}
    else:
        w, h = cam["w"], cam["h"]
        sensor = {"type": "perspective", "fov": cam["fov"], "fov_axis": "x",
                  "to_world": T().look_at(origin=cam["origin"], target=[0, 0, 0], up=[0, 1, 0])}
    sensor["film"] = {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    sensor["sampler"] = {"type": "independent", "sample_count": spp}
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 4}, "sensor": sensor,
             "env": {"type": "envmap", "filename": envfile},
             "ball": {"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "bsdf": {"type": "conductor", "material": "none"}}}
    return np.array(mi.render(mi.load_dict(scene), spp=spp), dtype=np.float64)[..., :3]


def bubblefit_image(cam, px, footprint=True, spp=1, method="mirror"):
    """bubblefit's front film as a mirror (eq. 1 of the paper with roughness 0, r_s = 1)."""
    if cam["type"] == "ortho":
        c = OrthographicCamera(cam["w"], cam["h"], *cam["disc"])
    else:
        c = PerspectiveCamera(cam["w"], cam["h"], tuple(cam["origin"]), (0.0, 0.0, 0.0), fov_deg=cam["fov"])
    fx = Effects(model="paper", rear_reflection=False, transmission=False, interference="off", diffuse=False,
                 filtering=FilterConfig(method))
    p = Params.make(r_s=1.0, r_d=0.0, roughness=0.0)
    env = EnvMap.from_array(px)
    return np.asarray(render(p, RenderConfig(effects=fx, camera=c, pixel_footprint=footprint, samples_per_pixel=spp), env),
                      dtype=np.float64)


def centroid(img, at, half=5):
    """Intensity-weighted centre (x, y) of the green channel in a (2 half + 1)^2 window, and its sum."""
    x0, y0 = at
    j0, i0 = int(round(x0 - 0.5)), int(round(y0 - 0.5))
    sl = img[max(i0 - half, 0):i0 + half + 1, max(j0 - half, 0):j0 + half + 1, 1]
    ii, jj = np.mgrid[max(i0 - half, 0):i0 + half + 1, max(j0 - half, 0):j0 + half + 1]
    ii, jj = ii[:sl.shape[0], :sl.shape[1]], jj[:sl.shape[0], :sl.shape[1]]
    wsum = sl.sum()
    return [float((sl * (jj + 0.5)).sum() / wsum), float((sl * (ii + 0.5)).sum() / wsum)], float(wsum)


NORMALS = [(0.0, 0.0), (0.3, 0.25), (-0.45, 0.35), (0.55, -0.4), (-0.25, -0.65), (0.8, 0.15), (-0.78, -0.3), (0.1, 0.8)]


def run(name, cam, maph, sigma, spp_m):
    """Render one configuration in both renderers and compare each glint's centroid."""
    if cam["type"] == "ortho":
        suns = ortho_suns(NORMALS)
        cx, cy, r = cam["disc"]
        expect = [[cx + r * nx, cy - r * ny] for nx, ny in NORMALS]
    else:
        # suns chosen as for an orthographic view, their glints found by Newton on the pinhole's rays
        suns = ortho_suns([(0.7 * a, 0.7 * b) for a, b in NORMALS])
        expect = [persp_glint_pixel(cam, s).tolist() for s in suns]
    px = spot_map(maph, suns, sigma)
    envfile = os.path.join(TMP, f"spots_{maph}_{sigma:.4f}.exr")
    vio.write_exr(envfile, px)
    t0 = time.time()
    m = mitsuba_image(cam, envfile, spp_m)
    tm = time.time() - t0
    b = bubblefit_image(cam, px, footprint=True)
    b1 = bubblefit_image(cam, px, footprint=False, spp=16)
    out = {"camera": cam, "map_height": maph, "sigma_rad": sigma, "mitsuba_spp": spp_m, "mitsuba_s": tm, "glints": []}
    for k, e in enumerate(expect):
        cm, fm = centroid(m, e)
        cb, fb = centroid(b, e)
        c1, f1 = centroid(b1, e)
        out["glints"].append({"expected": e, "mitsuba": cm, "bubblefit_footprint": cb, "bubblefit_16spp": c1,
                              "flux_m": fm, "flux_b": fb, "flux_b16": f1})
    dm = np.array([[g["mitsuba"][0] - g["expected"][0], g["mitsuba"][1] - g["expected"][1]] for g in out["glints"]])
    db = np.array([[g["bubblefit_footprint"][0] - g["expected"][0], g["bubblefit_footprint"][1] - g["expected"][1]] for g in out["glints"]])
    d1 = np.array([[g["bubblefit_16spp"][0] - g["expected"][0], g["bubblefit_16spp"][1] - g["expected"][1]] for g in out["glints"]])
    print(f"== {name}: map {2*maph}x{maph}, sigma {sigma:.4f} rad, mitsuba {tm:.0f} s")
    for k, g in enumerate(out["glints"]):
        print(f"  glint {k} at ({g['expected'][0]:6.2f},{g['expected'][1]:6.2f})  mts-exp ({dm[k,0]:+.3f},{dm[k,1]:+.3f})"
              f"  bf_fp-exp ({db[k,0]:+.3f},{db[k,1]:+.3f})  bf16-exp ({d1[k,0]:+.3f},{d1[k,1]:+.3f})  "
              f"flux m {g['flux_m']:.1f} bf {g['flux_b']:.1f} bf16 {g['flux_b16']:.1f}")
    print(f"  mean mts-bf_fp ({(dm-db)[:,0].mean():+.3f},{(dm-db)[:,1].mean():+.3f})  max |.| {np.abs(dm-db).max():.3f}")
    out["name"] = name
    np.save(os.path.join(TMP, f"{name}_m.npy"), m)
    np.save(os.path.join(TMP, f"{name}_b.npy"), b)
    return out


def convention_shifts():
    """The sub-pixel shift ``s`` and gain ``g`` with ``X(p) = g B(p + s)`` between each renderer's
    mirror sphere in data/conventions/ (``X``: Mitsuba's, Cycles') and bubblefit's lookup of
    the same sphere (``B``, check_conventions.py), by linearised least squares
    (Lucas & Kanade 1981: ``X = g B + g s . grad B``) inside 0.9 of the disc."""
    conv = os.path.join(vio.DATA, "conventions")
    out = {}
    for kind in ("ortho", "persp"):
        b = vio.read_image(os.path.join(conv, f"bubblefit_lookup_mirror_{kind}.exr"))[..., :3].mean(-1)
        gy, gx = np.gradient(b)
        yy, xx = np.mgrid[0:b.shape[0], 0:b.shape[1]] + 0.5
        radius = 50.0 if kind == "ortho" else math.sqrt((b > 0).sum() / math.pi)
        m = np.hypot(xx - b.shape[1] / 2, yy - b.shape[0] / 2) < 0.9 * radius
        for r in ("mitsuba", "cycles"):
            x = vio.read_image(os.path.join(conv, f"{r}_mirror_{kind}.exr"))[..., :3].mean(-1)
            g, sx, sy = np.linalg.lstsq(np.stack([b[m], gx[m], gy[m]], -1), x[m], rcond=None)[0]
            out[f"{r}_{kind}"] = {"gain": round(float(g), 4), "shift_px_xy": [round(float(sx / g), 3), round(float(sy / g), 3)]}
    return out


CONFIGS = {
    "ortho160_map128": (dict(type="ortho", w=160, h=160, disc=[72.0, 84.0, 52.0]), 128, 0.03, 256),
    "ortho160_map512": (dict(type="ortho", w=160, h=160, disc=[72.0, 84.0, 52.0]), 512, 0.03, 256),
    "ortho320_map128": (dict(type="ortho", w=320, h=320, disc=[144.0, 168.0, 104.0]), 128, 0.03, 64),
    "persp160_map128": (dict(type="persp", w=160, h=160, origin=[0.0, 0.0, 4.0], fov=42.0), 128, 0.03, 256),
    "persp176x144_map128": (dict(type="persp", w=176, h=144, origin=[0.0, 0.0, 4.0], fov=40.0), 128, 0.03, 256),
}

if __name__ == "__main__":
    outp = sys.argv[1]
    names = sys.argv[2:] or list(CONFIGS) + ["conventions"]
    res = []
    if "conventions" in names:
        names.remove("conventions")
        res.append({"name": "conventions", "mirror_sphere_shifts": convention_shifts()})
        print(res[-1])
    for n in names:
        cam, mh, sg, spp = CONFIGS[n]
        res.append(run(n, cam, mh, sg, spp))
    json.dump(res, open(outp, "w"), indent=1)
