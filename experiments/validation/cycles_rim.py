"""Which of Blender Cycles' ways makes the rough constant film's rim less red than bubblefit's
model: Cycles' rough soap film traced again in numpy, one of its ways changed at a time.

cyc_const700_sunset_ortho_rough (Principled BSDF, IOR 1.0, Transmission 1, Roughness 0.15,
Thin Film 700 nm, IOR 1.4; Blender 5.0.1) is re-rendered here by a Monte Carlo tracer that
follows the Cycles 5.0 source for that material (no bubblefit code; numpy and
``reference_renderer.py`` only):

* ``svm/closure.h`` (Principled BSDF): with Transmission Weight 1 the only closure is the
  GGX glass (``bsdf_microfacet_ggx_glass_setup``) of IOR 1.0 with the
  ``GENERALIZED_SCHLICK`` Fresnel carrying the thin film; the specular and diffuse layers
  get weight 0.
* ``closure/bsdf_microfacet.h`` (``bsdf_microfacet_sample``): a microfacet normal ``H`` is
  drawn from GGX's distribution of visible normals (Heitz 2018, JCGT 7(4)); the film's
  reflectance ``F`` (RGB) is evaluated at ``cos_HI = H . wi``, the MICROFACET's angle, not
  the surface normal's; reflection is chosen with probability ``mean(F)`` and weighted
  ``F / mean(F)`` times the Smith ratio ``(1 + L_I) / (1 + L_I + L_O)`` (Heitz 2014,
  eq. 72 for ``L``), and a reflected ray below the shading normal's horizon ends the path;
  transmission at IOR 1 keeps the ray's direction (``refract_angle`` with ``eta = 1``,
  treated as singular) and is weighted ``(1 - F) / (1 - mean(F))``.
* ``closure/bsdf_util.h`` (``fresnel_iridescence``, Belcour & Barla 2017): per polarisation
  the Airy series ``R12 + Rs + 2 sum_m C_m cos(m phi)``, ``C_m = (Rs - T121) r123^m``,
  TRUNCATED after ``m = 3``, integrated against the colour space's matching functions
  (a Fourier-space table, ``scene/shader.cpp`` ``compute_thin_film_table``: the CIE 1931
  functions resampled with the Jacobian ``1/nu^2``, i.e. illuminant E, each channel
  normalised to a unit DC term); ``saturate(mix(R_s, R_p, 0.5))`` per channel.
* the world: the map (``Linear`` interpolation) read at Blender's texel centres.

The multiscatter energy compensation of the Principled BSDF (``microfacet_ggx_preserve_energy``)
uses the GGX glass table at IOR 1 with a transmissive Fss of 1, where a glass of IOR 1 loses
no energy: it is left out (``energy_scale`` = 1). Mesh facets, Russian roulette and the
pixel filter's exact weights are left out too (a smooth sphere, 8 bounces, box-filtered
uniform sub-pixel positions).

Variants (``VARIANTS``), each ONE change from ``cycles`` (the tracer as above):

* ``film_macro``: the film at the surface normal's angle ``cos_NI`` (as bubblefit's model
  evaluates it), the directions still drawn from the microfacets;
* ``airy_exact``: the full Airy sum instead of the series cut after ``m = 3``;
* ``no_shadowing``: no Smith ratio, and a reflection below the horizon mirrored about the
  mean surface instead of ending the path (the lobe's albedo kept at ``F``);
* ``no_clamp``: the RGB film not clamped to [0, 1];
* ``bubblefit_film``: ``film_macro`` and ``airy_exact`` together;
* ``macro_no_shadowing``: ``film_macro`` and ``no_shadowing`` together;
* ``decorrelated``: the film at a second facet drawn independently of the one that
  reflects (the mean of the film times the mean of the light, not the mean of products);
* ``ggx_no_shadowing``: no Smith ratio, the paths below the horizon kept (mirrored);
* ``ward``: the facets drawn from Ward's lobe (Gaussian slopes of variance ``a^2 / 2`` per
  component, paper eq. 1, ``a`` = GGX's alpha) and weighted by their visible area
  (:func:`ward_facet`), no Smith ratio (bubblefit's normalised lobe); ``ward_decorrelated``
  the same with the film at an independent Ward facet (bubblefit's model:
  ``--film-rgb clamped``);
* ``ggx_dir_ward_film`` / ``ward_dir_ggx_film``: the directions from GGX's facets and the
  film at an independent Ward facet, or the other way round.

For each the photo over the render per channel in rings of the disc radius (pixels a fit
uses: inside 0.96, no clipped channel), the regions of ``rough_misfit.py`` and its chi^2
with the 3 % floor. The tracer's own Monte Carlo error per ring is the spread of the ratio
over ``SPLITS`` independent quarters of the samples.

    PYTHONPATH=. .venv/bin/python experiments/validation/cycles_rim.py [--spp 64] [--only V,...] \
        [--json OUT] [--bubblefit NPZ]

``--bubblefit NPZ`` adds the rings of the renders a ``rough_misfit.py --json`` run saved
(bubblefit's model, times the true exposure), for the same table. ``--compare A B ...``
prints, instead of tracing, ``A / B - 1`` per channel in each ring (sum over the ring's
used pixels, and the median of the per-pixel ratio) for pairs of saved renders, each
``FILE.npz:KEY`` or ``photo``:

    ... cycles_rim.py --compare OUT.npz:cycles/OUT.npz:film_macro photo/OUT.npz:cycles
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import reference_renderer as rr  # noqa: E402
import vio  # noqa: E402

CASE = "cyc_const700_sunset_ortho_rough"
FLOOR = 0.03
RINGS = np.round(np.arange(0.0, 0.961, 0.08), 2)
REGIONS = {"centre": (0.0, 0.5), "mid": (0.5, 0.8), "rim": (0.8, 0.96)}
BOUNCES = 8
SPLITS = 4
COS_GRID = 8001
#: the sun's texels: above 2 % of the brightest (as cap_glint_paths.py)
SUN_LEVEL = 0.02

BASE = dict(facets="ggx", film_angle="microfacet", series="belcour3", shadowing=True, clamp=True)
VARIANTS = {
    "cycles": {},
    "film_macro": dict(film_angle="macro"),
    "airy_exact": dict(series="exact"),
    "no_shadowing": dict(shadowing=False),
    "no_clamp": dict(clamp=False),
    "bubblefit_film": dict(film_angle="macro", series="exact"),
    "macro_no_shadowing": dict(film_angle="macro", shadowing=False),
    "decorrelated": dict(film_angle="independent"),
    "ggx_no_shadowing": dict(shadowing=False),
    "ward": dict(facets="ward", shadowing=False),
    "ward_decorrelated": dict(facets="ward", shadowing=False, film_angle="independent"),
    "ggx_dir_ward_film": dict(film_angle="independent_ward"),
    "ward_dir_ggx_film": dict(facets="ward", shadowing=False, film_angle="independent_ggx"),
}


# ------------------------------------------------------------------------- the film
def film_series(n: float, d_nm: float, cos_i: np.ndarray, lam: np.ndarray, terms: int | None):
    """Mean of s and p of the film's power reflectance (air | n, d | air) per wavelength,
    by Belcour & Barla (2017) eq. 10 cut after ``terms`` orders, or the closed Airy sum
    (``terms=None``, ``reference_renderer.airy_film``, Born & Wolf eq. 7.6(13)).

    For this stack ``R23 = R12``, ``r123 = R12`` and the phasor of each polarisation is +1
    (``fresnel_dielectric_polarized``'s signs of r_s, r_p at the two interfaces cancel in
    Cycles' ``phasor23 * -phasor12``), so order ``m`` adds ``2 C_m cos(m phi)``, ``phi`` the
    round-trip phase ``4 pi n d cos_t / lambda``. Returns ``cos_i.shape + lam.shape``."""
    if terms is None:
        rs, rp = rr.airy_film(n, d_nm, cos_i, lam)
        return 0.5 * (rs + rp)
    r_s, r_p, cos_t = rr.fresnel_r01(n, cos_i)
    phi = (4.0 * np.pi * n * d_nm) * cos_t[..., None] / lam
    out = 0.0
    for r in (r_s, r_p):
        r12 = (r * r)[..., None]
        t121 = 1.0 - r12
        rs_ = t121 * t121 * r12 / (1.0 - r12 * r12)
        total = r12 + rs_
        cm = rs_ - t121
        for m in range(1, terms + 1):
            cm = cm * r12
            total = total + 2.0 * cm * np.cos(m * phi)
        out = out + 0.5 * total
    return out


def film_table(spec: rr.Spectral, series: str, clamp: bool, d_nm: float = 700.0, n: float = 1.4):
    """RGB reflectance of the film on a grid of ``cos`` in [0, 1] (COS_GRID points)."""
    cos = np.linspace(0.0, 1.0, COS_GRID)
    r = film_series(n, d_nm, cos, spec.lam, None if series == "exact" else 3)   # (G, K)
    rgb = np.nan_to_num(r, nan=1.0) @ spec.weights.T                             # (G, 3); R = 1 at cos 0
    return cos, (np.clip(rgb, 0.0, 1.0) if clamp else rgb)


def film_rgb(table, c):
    cos, rgb = table
    return np.stack([np.interp(np.clip(c, 0, 1), cos, rgb[:, k]) for k in range(3)], axis=-1)


# ------------------------------------------------------------------------- GGX
def ggx_vndf(wi_l: np.ndarray, alpha: float, u1, u2) -> np.ndarray:
    """Heitz (2018) visible-normal sample in the local frame (z = shading normal), as
    Cycles' ``microfacet_ggx_sample_vndf``."""
    v = np.stack([alpha * wi_l[:, 0], alpha * wi_l[:, 1], wi_l[:, 2]], -1)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    lensq = v[:, 0] ** 2 + v[:, 1] ** 2
    ok = lensq > 1e-7
    inv = np.where(ok, 1.0 / np.sqrt(np.where(ok, lensq, 1.0)), 0.0)
    t1 = np.where(ok[:, None], np.stack([-v[:, 1] * inv, v[:, 0] * inv, 0 * inv], -1), [1.0, 0.0, 0.0])
    t2 = np.cross(v, t1)
    r, ph = np.sqrt(u1), 2 * np.pi * u2
    a, b = r * np.cos(ph), r * np.sin(ph)
    s = 0.5 * (1.0 + v[:, 2])
    b = (1.0 - s) * np.sqrt(np.clip(1.0 - a * a, 0, None)) + s * b
    h = a[:, None] * t1 + b[:, None] * t2 + np.sqrt(np.clip(1.0 - a * a - b * b, 0, None))[:, None] * v
    h = np.stack([alpha * h[:, 0], alpha * h[:, 1], np.maximum(h[:, 2], 0.0)], -1)
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


def ggx_lambda(alpha: float, cos: np.ndarray) -> np.ndarray:
    """Smith's Lambda for GGX (Heitz 2014, eq. 72), as Cycles' ``bsdf_lambda``."""
    c2 = np.clip(cos * cos, 1e-12, 1.0)
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * np.maximum(1.0 / c2 - 1.0, 0.0)) - 1.0)


def frame(n: np.ndarray):
    a = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    x = np.cross(a, n)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return x, np.cross(n, x)


def ward_facet(wi_l: np.ndarray, alpha: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """A facet of Ward's lobe (paper eq. 1: slopes Gaussian, variance ``alpha^2 / 2`` per
    component) in the local frame, and its weight as a visible facet: its projected area
    seen from ``wi`` per unit of the mean surface, ``max(wi . h, 0) / (h_z cos_i)`` (Heitz,
    JCGT 3(2), 2014, the distribution of visible normals; mean 1 over the slopes)."""
    s = rng.normal(0.0, alpha / np.sqrt(2.0), (len(wi_l), 2))
    h = np.stack([-s[:, 0], -s[:, 1], np.ones(len(wi_l))], -1)
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    return h, np.maximum(np.sum(h * wi_l, -1), 0.0) / (h[:, 2] * wi_l[:, 2])


# ------------------------------------------------------------------------- the world
def env_blender(env: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear map lookup at Blender's texel centres (row i at v = (i + 1/2)/H, column j at
    u = (j + 1/2)/W, rows clamped, columns wrapped) in docs/design.md's u, v."""
    h, w, _ = env.shape
    u = np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)
    u -= np.floor(u)
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    x, y = u * w - 0.5, np.clip(v * h - 0.5, 0.0, h - 1.0)
    x0 = np.floor(x)
    y0 = np.minimum(np.floor(y), h - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0 = x0.astype(int) % w
    x1 = (x0 + 1) % w
    y0 = y0.astype(int)
    top = env[y0, x0] * (1 - fx) + env[y0, x1] * fx
    bot = env[y0 + 1, x0] * (1 - fx) + env[y0 + 1, x1] * fx
    return top * (1 - fy) + bot * fy


# ------------------------------------------------------------------------- the tracer
def trace(truth: dict, env: np.ndarray, table, opts: dict, pixels, spp: int, seed: int) -> np.ndarray:
    """Mean radiance (linear, before the exposure) of ``pixels`` ((P, 2) rows, cols) with
    ``spp`` paths each, split into :data:`SPLITS` independent parts: (SPLITS, P, 3)."""
    alpha = float(truth["roughness"]) ** 2
    d = truth["disc"]
    rng = np.random.default_rng(seed)
    out = np.zeros((SPLITS, len(pixels), 3))
    per = spp // SPLITS
    chunk = max(1, 200_000 // per)
    for s in range(SPLITS):
        for c0 in range(0, len(pixels), chunk):
            pix = pixels[c0:c0 + chunk]
            rows = np.repeat(pix[:, 0], per) + rng.random(len(pix) * per)
            cols = np.repeat(pix[:, 1], per) + rng.random(len(pix) * per)
            x, y = (cols - d["cx"]) / d["r"], -(rows - d["cy"]) / d["r"]
            rad = np.zeros((len(x), 3))
            hit = x * x + y * y < 1.0
            dirn = np.tile([0.0, 0.0, -1.0], (len(x), 1))
            rad[~hit] = env_blender(env, dirn[~hit])
            idx = np.nonzero(hit)[0]
            p = np.stack([x[idx], y[idx], np.sqrt(1.0 - x[idx] ** 2 - y[idx] ** 2)], -1)
            dv, thr = dirn[idx], np.ones((len(idx), 3))
            for _ in range(BOUNCES):
                if not len(idx):
                    break
                front = np.sum(dv * p, -1) < 0
                nrm = np.where(front[:, None], p, -p)
                wi = -dv
                cos_ni = np.sum(nrm * wi, -1)
                tx, ty = frame(nrm)
                wl = np.stack([np.sum(tx * wi, -1), np.sum(ty * wi, -1), cos_ni], -1)
                if opts["facets"] == "ward":
                    hl, vis = ward_facet(wl, alpha, rng)
                else:
                    hl, vis = ggx_vndf(wl, alpha, rng.random(len(idx)), rng.random(len(idx))), np.ones(len(idx))
                h = hl[:, :1] * tx + hl[:, 1:2] * ty + hl[:, 2:] * nrm
                cos_hi = np.sum(h * wi, -1)
                angle = opts["film_angle"]
                if angle == "independent":
                    angle = "independent_" + opts["facets"]
                if angle == "independent_ward":          # the film at a second, independent facet
                    h2, vis2 = ward_facet(wl, alpha, rng)
                    vis = vis * vis2
                elif angle == "independent_ggx":
                    h2 = ggx_vndf(wl, alpha, rng.random(len(idx)), rng.random(len(idx)))
                if angle.startswith("independent"):
                    f = film_rgb(table, np.clip(np.sum(h2 * wl, -1), 0, 1))
                else:
                    f = film_rgb(table, cos_hi if angle == "microfacet" else cos_ni)
                pr = np.clip(f.mean(-1), 1e-6, 1 - 1e-6)
                refl = rng.random(len(idx)) < pr
                wo = 2.0 * cos_hi[:, None] * h - wi
                cos_no = np.sum(nrm * wo, -1)
                below = refl & (cos_no <= 0)
                if opts["shadowing"]:
                    li, lo = ggx_lambda(alpha, cos_ni), ggx_lambda(alpha, np.abs(cos_no))
                    g = (1 + li) / (1 + li + lo)
                    keep = ~below
                else:
                    g = np.ones(len(idx))
                    mirror = 2.0 * cos_ni[:, None] * nrm - wi
                    wo = np.where(below[:, None], mirror, wo)
                    keep = np.ones(len(idx), bool)
                w = np.where(refl[:, None], f / pr[:, None] * g[:, None], (1 - f) / (1 - pr)[:, None])
                thr = thr * w * vis[:, None]
                nd = np.where(refl[:, None], wo, dv)
                escape = (front == refl) & keep
                inside = (front != refl) & keep
                rad[idx[escape]] += thr[escape] * env_blender(env, nd[escape])
                t = -2.0 * np.sum(p[inside] * nd[inside], -1)
                p = p[inside] + t[:, None] * nd[inside]
                p /= np.linalg.norm(p, axis=-1, keepdims=True)
                dv, thr, idx = nd[inside], thr[inside], idx[inside]
            out[s, c0:c0 + len(pix)] = rad.reshape(len(pix), per, 3).mean(1)
    return out


def clip_sun(env: np.ndarray) -> np.ndarray:
    """The map with every texel brighter (sum of RGB) than :data:`SUN_LEVEL` of the
    brightest scaled down to that level: the sky without the sun, whose rare paths through
    GGX's long tail are most of a 256-sample render's noise in red."""
    lum = env.sum(-1, keepdims=True)
    cap = SUN_LEVEL * lum.max()
    return env * np.minimum(1.0, cap / np.maximum(lum, 1e-30))


# ------------------------------------------------------------------------- scoring
def rings(photo, model, rho, used):
    """photo / model - 1 per channel in each ring of :data:`RINGS` and each region."""
    prof = []
    for a, b in zip(RINGS[:-1], RINGS[1:]):
        m = used & (rho >= a) & (rho < b)
        prof.append({"rho": [float(a), float(b)], "pixels": int(m.sum()),
                     "photo_over_model_rgb": [float(v) for v in photo[m].sum(0) / model[m].sum(0) - 1]})
    reg = {}
    for name, (a, b) in REGIONS.items():
        m = used & (rho >= a) & (rho < b)
        reg[name] = [float(v) for v in photo[m].sum(0) / model[m].sum(0) - 1]
    return prof, reg


def compare(pairs, photo, rho, used):
    """Print ``A / B - 1`` per ring and region for saved renders (``FILE.npz:KEY`` or ``photo``)."""
    load = lambda spec: photo if spec == "photo" else np.load(spec.split(":")[0])[spec.split(":")[1]].astype(np.float64)
    edges = np.round(np.arange(0.0, 0.961, 0.08), 2)
    for pair in pairs:
        left, right = pair.split("/", 1) if pair.count("/") == 1 else _split_pair(pair)
        x, y = load(left), load(right)
        print(f"{left} / {right} - 1 (%, R G B): ring sum | median of the pixels' ratio")
        for lo, hi in list(zip(edges[:-1], edges[1:])) + list(REGIONS.values()):
            m = used & (rho >= lo) & (rho < hi)
            s_ = x[m].sum(0) / y[m].sum(0) - 1
            med = np.median(x[m] / np.maximum(y[m], 1e-9), 0) - 1
            print(f"   {lo:.2f}-{hi:.2f} ({m.sum():4d} px): " + " ".join(f"{100 * v:+6.2f}" for v in s_) + "  | "
                  + " ".join(f"{100 * v:+6.2f}" for v in med))


def _split_pair(pair):
    """``A/B`` where A and B may hold slashes (paths): split before the second operand,
    which starts with ``photo`` or ``/`` (an absolute path)."""
    for k in range(1, len(pair)):
        if pair[k - 1] == "/" and (pair[k:] == "photo" or pair[k] == "/"):
            return pair[:k - 1], pair[k:]
    raise SystemExit(f"cannot split {pair!r} into A/B")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--only", default=",".join(VARIANTS))
    ap.add_argument("--clip-sun", action="store_true",
                    help="the map's texels above SUN_LEVEL of its brightest scaled down to that level (no sun)")
    ap.add_argument("--rho-min", type=float, default=0.0, help="trace only the pixels at or beyond this radius")
    ap.add_argument("--json")
    ap.add_argument("--save", help="write the tracer's renders (linear, times the exposure) to this .npz")
    ap.add_argument("--compare", nargs="+", metavar="A/B", help="ring ratios of saved renders (no tracing)")
    ap.add_argument("--bubblefit", help="renders saved by rough_misfit.py --json (OUT_renders.npz)")
    a = ap.parse_args(argv)
    from bubblefit.inverse import noise_sigma, saturation_mask  # scoring only, as rough_misfit.py
    from bubblefit.io.images import read_image

    t = json.load(open(f"{vio.DATA}/{CASE}/truth.json"))
    env = vio.read_image(f"{vio.DATA}/{t['envmap']}")[..., :3].astype(np.float64)
    if a.clip_sun:
        env = clip_sun(env)
    photo = read_image(f"{vio.DATA}/{CASE}/photo.png").pixels.astype(np.float64)
    sigma = noise_sigma(photo, 2e-3, 2e-4, 8)
    h, w = photo.shape[:2]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = t["disc"]
    rho = np.hypot(jj - d["cx"], ii - d["cy"]) / d["r"]
    used = (rho < 0.96) & (rho >= a.rho_min) & ~saturation_mask(photo, 1.0, None)
    traced = (rho < 0.96) & (rho >= a.rho_min)
    pix = np.argwhere(traced)
    if a.compare:
        compare(a.compare, photo, rho, used)
        return
    spec = rr.spectral_setup("E", 1.0)
    report = {"case": CASE, "spp": a.spp, "bounces": BOUNCES, "rings": RINGS.tolist(), "used_pixels": int(used.sum()),
              "note": "photo / model - 1 per channel (R, G, B); mc_error: the spread of the ring's ratio over "
                      f"{SPLITS} independent parts of the tracer's samples, over sqrt({SPLITS})", "variants": {}}
    if a.bubblefit:
        saved = np.load(a.bubblefit)
        for v in saved.files:
            if v == "photo":
                continue
            model = t["exposure"] * saved[v].astype(np.float64)
            prof, reg = rings(photo, model, rho, used)
            var = sigma**2 + (FLOOR * np.clip(photo, 0, None)) ** 2
            chi = ((photo - model) ** 2 / var)
            report["variants"]["bubblefit_" + v] = {"rings": prof, "regions": reg,
                                                    "chi2_floor": float(chi[used].mean())}
            print(f"bubblefit {v}: chi2 {chi[used].mean():.2f} rim {np.round(100 * np.array(reg['rim']), 2)} %", flush=True)
    saved_imgs = {}
    for v in a.only.split(","):
        opts = {**BASE, **VARIANTS[v]}
        t0 = time.time()
        table = film_table(spec, opts["series"], opts["clamp"])
        parts = trace(t, env, table, opts, pix, a.spp, seed=7)
        img = np.zeros((SPLITS, h, w, 3))
        img[:, pix[:, 0], pix[:, 1]] = parts
        model = t["exposure"] * img.mean(0)
        inside = traced
        model[~inside] = photo[~inside]
        prof, reg = rings(photo, model, rho, used)
        # Monte Carlo error of each ring's ratio: spread over the independent parts
        part_prof = [rings(photo, t["exposure"] * np.where(inside[..., None], img[k], photo / t["exposure"]),
                           rho, used)[0] for k in range(SPLITS)]
        for i, r in enumerate(prof):
            vals = np.array([pp[i]["photo_over_model_rgb"] for pp in part_prof])
            r["mc_error_rgb"] = [float(x) for x in vals.std(0, ddof=1) / np.sqrt(SPLITS)]
        var = sigma**2 + (FLOOR * np.clip(photo, 0, None)) ** 2
        chi = (photo - model) ** 2 / var
        regchi = {n_: [float(x) for x in chi[used & (rho >= lo) & (rho < hi)].mean(0)] for n_, (lo, hi) in REGIONS.items()}
        report["variants"][v] = {"options": opts, "rings": prof, "regions": reg, "chi2_floor": float(chi[used].mean()),
                                 "chi2_rgb_by_region": regchi, "seconds": round(time.time() - t0, 1)}
        print(f"{v} [{time.time() - t0:.0f} s]: chi2 {chi[used].mean():.2f}; photo/model-1 (%) "
              + "; ".join(f"{k} {np.round(100 * np.array(x), 2)}" for k, x in reg.items()), flush=True)
        print("   rings R: " + " ".join(f"{100 * r['photo_over_model_rgb'][0]:+.1f}" for r in prof), flush=True)
        saved_imgs[v] = model.astype(np.float32)
        write(a.save, a.json, saved_imgs, report)


def write(npz: str | None, out: str | None, images: dict, report: dict) -> None:
    """Save the renders so far (``--save``) and the report (``--json``)."""
    if npz:
        np.savez_compressed(npz, **images)
    if out:
        with open(out, "w") as fh:
            json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
