"""Where bubblefit's model at the TRUE parameters misses Blender Cycles' rough films, and
which of Cycles' approximations carries it (one changed at a time, in this script only).

For a Cycles rough case (data/cyc_*_rough) bubblefit renders the photo at the true
thickness, disc (or camera) and exposure with the fit's model as ``truth_misfit.py`` sets it
up (physical model, exact Airy film at 100 uniform wavelengths, 8 internal bounces, the
pixel footprint, the ``mipmap`` lobe quadrature, the background photo) and Ward's lobe
(paper eq. 1) of width ``a`` = Cycles' GGX alpha (Principled roughness squared) unless a
variant says otherwise. Each variant changes ONE thing:

* ``E``: the fit's model as ``validate.py`` fits these cases (``--illuminant E``, the white
  Cycles integrates its film under); every later variant keeps E;
* ``D65``: bubblefit's default white instead;
* ``E_avgpol``: s and p averaged at every film hit (``cycles_colour.film_mode
  ("per_surface")``: Cycles' ``fresnel_iridescence`` returns ``mix(R_s, R_p, 0.5)``);
* ``E_rgb_noclamp``: s and p averaged and the film integrated to linear sRGB at every hit,
  the path a product of per-channel reflectances (an RGB renderer), without a clamp;
* ``E_rgb_clamp``: the same with each channel clamped to [0, 1] per hit (Cycles 5.0.1's
  ``saturate``; ``cycles_colour.film_mode("cycles_rgb")``);
* ``E_ggx``: Cycles' GGX lobe of the same alpha through the same filtering. GGX's slope
  distribution ``(1 + |s|^2/alpha^2)^-2 / (pi alpha^2)`` (Walter et al. 2007, eq. 33, in
  slope space) is a bivariate Student t with 2 degrees of freedom, a scale mixture of
  Gaussians: ``s | w ~ N(0, alpha^2/(2 w))``, ``w ~ Exp(1)`` (Andrews & Mallows 1974), i.e.
  of Ward lobes (``N(0, a^2/2)`` in slope space) of ``a = alpha / sqrt(w)``. The render is
  linear in the lobe, so ``E_ggx`` is the mean of Ward renders at ``a_k = alpha/sqrt(w_k)``,
  ``w_k`` the mid-quantiles ``-ln((k + 1/2)/K)`` of Exp(1) (K = :data:`GGX_NODES`, equal
  weights);
* ``E_ward_fitted``: Ward at the fit's roughness (results/test/results.json), the best a
  Ward lobe did on the photo;
* ``E_texel_centres``: the map read at Blender's texel centres (row ``i`` at
  ``v = (i + 1/2)/H``, bubblefit's at ``i/(H - 1)``): the map resampled (linear in rows)
  so that bubblefit's row ``k`` holds Blender's reading at ``v = k/(H - 1)`` (columns agree);
  the resampling blurs by at most 1/4 texel^2 in variance;
* ``E_cycles_all``: Cycles' RGB film with its clamp, the GGX lobe and Blender's rows at once;
* ``E_cycles_all_nosun``: ``E_cycles_all`` on the map without its sun
  (``cycles_rim.clip_sun``), to compare with ``cycles_rim.py --clip-sun``;
* ``E_cycles_walter``: ``E_cycles_all`` with each lobe node weighted as a microfacet BRDF
  weighs it (:func:`walter_weights`) instead of by Ward's eq. (1);
* ``E_clamped``: the fit's ``--film-rgb clamped`` (the clamped RGB film averaged over Ward's
  visible facets, ``model.render.clamped_series``) with the map at Blender's texel centres;
* ``E_clamped_ggx_facets``: ``E_clamped`` with the film averaged over GGX's visible facets
  instead (:func:`ggx_facets`; the lobe stays Ward's).

Each variant also gives the thickness change a linearised fit would make to turn the ``E``
render into it (:func:`thickness_shift`), and the photo's.

Scored per variant over the pixels a fit uses (inside 0.96 of the radius, no clipped
channel nearby), with the fit's noise model and the 3 % floor, channels the photo clipped
at black censored: reduced chi^2 with the floor and outliers; per region (centre rho < 0.5,
mid 0.5-0.8, rim 0.8-0.96) and per channel, the chi^2 and the photo's mean over the
render's minus 1; and the fit's colour statistic (``inverse.colour_check``, model-error
0.03 for its outliers, over ``cos > INNER_COS``), over the disc and over each region alone. The noise: the photo against
background.png outside the disc (two independent draws of Cycles' Monte Carlo noise and
the sensor's; chi^2 with twice the noise model's variance, 1 when the noise model holds)
and ``cycles_colour.noise_excess`` (the residual's high-frequency variance over the sensor
model's) inside the disc; ``chi2_floor_pixel_scale``: the chi^2 with the floor of the
residual less its 3 x 3 mean (scaled by 9/8: what white noise keeps), the part of the
misfit that changes from pixel to pixel (Monte Carlo noise), and its outliers.

    PYTHONPATH=. .venv/bin/python experiments/validation/rough_misfit.py CASE [--only V,...] [--json OUT]
    ... rough_misfit.py CASE --from-npz OUT_renders.npz --json OUT2   # re-score saved renders
    ... rough_misfit.py CASE --emulate OUT_renders.npz VARIANT DIR     # a photo from a render, for
        validate.py --data DIR CASE (fits on Cycles' film without its Monte Carlo noise)
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import cycles_colour as cc  # noqa: E402
import vio  # noqa: E402

from bubblefit.inverse import censored_residual, noise_sigma, saturation_mask  # noqa: E402
from bubblefit.inverse.colour_check import INNER_COS, colour_check  # noqa: E402
from bubblefit.io.images import read_image  # noqa: E402
from bubblefit.lighting.filtering import FilterConfig  # noqa: E402
from bubblefit.model.render import render  # noqa: E402
from bubblefit.model.scene import Scene, read_envmap  # noqa: E402

D = vio.DATA
FLOOR, OUTLIER = 0.03, 30.0
GGX_NODES = 6
REGIONS = {"centre": (0.0, 0.5), "mid": (0.5, 0.8), "rim": (0.8, 0.96)}


def ggx_ward_widths(alpha: float, k: int = GGX_NODES) -> np.ndarray:
    """Ward widths whose equal-weight mean is GGX's slope distribution of ``alpha``
    (:func:`bubblefit.optics.brdf.ggx_ward_widths`, ``k`` of them)."""
    from bubblefit.optics.brdf import ggx_ward_widths as widths

    return widths(alpha, k)


def blender_rows(pixels: np.ndarray) -> np.ndarray:
    """The map resampled so that bubblefit's bilinear lookup (row ``k`` at ``v = k/(H-1)``,
    ``lighting.envmap.lookup_uv``) reads at its rows what Blender's reads there (row ``i``
    at ``v = (i + 1/2)/H``): continuous row ``y = v H - 1/2`` of the original, clamped."""
    h = pixels.shape[0]
    y = np.clip(np.arange(h) / (h - 1) * h - 0.5, 0.0, h - 1.0)
    y0 = np.minimum(np.floor(y).astype(int), h - 2)
    f = (y - y0)[:, None, None]
    return pixels[y0] * (1 - f) + pixels[y0 + 1] * f


@contextlib.contextmanager
def walter_weights():
    """Within the block the lobe quadrature (``lighting.filtering.specular_mipmap``) weighs
    each node as a microfacet BRDF does instead of by Ward's eq. (1): per unit slope-space
    density ``f cos th_i dw_i = D(h) (w_o . h) G2 / cos th_r dw_h`` and ``D(h) dw_h =
    P(s) d^2 s / cos(delta)`` (Walter et al. 2007, eqs. 20 and 33; Heitz 2014 for the slope
    form), i.e. ``(w_o . h) / (cos th_r cos delta)`` where Ward's lobe gives
    ``cos th_i (w_o . h) cos^3(delta) / sqrt(cos th_i cos th_r)``
    (``optics.brdf.half_vector_weight``): at grazing Ward's ``sqrt(cos th_i)`` favours the
    part of the lobe that leaves the horizon. The masking-shadowing ``G2`` is left out (at
    GGX alpha 0.0225 it takes 0.4 % of the reflection at 0.96 of the radius, grey), and the
    normalised lobe (the physical model) drops the constant factors."""
    import jax
    import jax.numpy as jnp
    from bubblefit.lighting import filtering

    ward = filtering.half_vector_weight

    def walter(cos_i, cos_r, o_dot_h, cos_h):
        above = (cos_i > 0) & (cos_r > 0)
        den = jnp.maximum(jnp.where(above, cos_r * cos_h, 1.0), 1e-6)
        return jnp.where(above, o_dot_h / den, 0.0)

    jax.clear_caches()
    filtering.half_vector_weight = walter
    try:
        yield
    finally:
        filtering.half_vector_weight = ward
        jax.clear_caches()


#: GGX facet quadrature of :func:`ggx_facets`: Gauss-Legendre nodes in ``u1``, midpoints in ``u2``
GGX_FACET_NODES = (16, 4)


@contextlib.contextmanager
def ggx_facets(alpha: float, nodes: tuple = GGX_FACET_NODES):
    """Within the block ``--film-rgb clamped`` averages its film over the visible facets of
    GGX's distribution of width ``alpha`` (Walter et al. 2007, eq. 33), as Blender Cycles
    draws them, instead of Ward's (``optics.brdf.facet_cosines``). Heitz's map of the unit
    square onto the visible normals (JCGT 7(4), 2018, sections 3-4: the view stretched by
    ``alpha``, a disc point ``(t1, t2)`` of radius ``sqrt(u1)`` and angle ``2 pi u2`` warped
    towards the view, lifted onto the hemisphere and unstretched) is uniform in ``(u1, u2)``,
    so a product rule in ``(u1, u2)`` (Gauss-Legendre in ``u1``; midpoints in the angle over
    the half the film is even in) gives the nodes ``w_i . h`` and their weights."""
    import jax
    import jax.numpy as jnp
    from bubblefit.optics import brdf

    ward = brdf.facet_cosines
    x, wx = np.polynomial.legendre.leggauss(nodes[0])
    angles = (np.arange(nodes[1]) + 0.5) / nodes[1] * np.pi - np.pi / 2

    def ggx(cos_i, _width):
        c = jnp.clip(jnp.asarray(cos_i), 1e-6, 1.0)
        s = jnp.sqrt(jnp.maximum(1.0 - c * c, 0.0))
        norm = jnp.sqrt((alpha * s) ** 2 + c * c)
        vx, vz = alpha * s / norm, c / norm        # the stretched view; T1 = y, T2 = (-vz, 0, vx)
        cos_nodes, weights = [], []
        for u1, w1 in zip(0.5 * (x + 1.0), 0.5 * wx):
            for phi in angles:
                t1, t2 = np.sqrt(u1) * np.cos(phi), np.sqrt(u1) * np.sin(phi)
                t2 = 0.5 * (1.0 - vz) * np.sqrt(1.0 - t1 * t1) + 0.5 * (1.0 + vz) * t2
                up = jnp.sqrt(jnp.maximum(1.0 - t1 * t1 - t2 * t2, 0.0))
                hx, hy, hz = alpha * (up * vx - t2 * vz), alpha * t1, jnp.maximum(up * vz + t2 * vx, 0.0)
                cos_nodes.append(jnp.clip((hx * s + hz * c) / jnp.sqrt(hx * hx + hy * hy + hz * hz), 1e-6, 1.0))
                weights.append(jnp.full_like(c, w1 / nodes[1]))
        return cos_nodes, weights

    jax.clear_caches()
    brdf.facet_cosines = ggx
    try:
        yield
    finally:
        brdf.facet_cosines = ward
        jax.clear_caches()


@contextlib.contextmanager
def rgb_film(basis, clamp: bool):
    """Cycles' RGB film per hit (``cycles_colour.film_mode("cycles_rgb")``) with the
    per-channel clamp optional: Born & Wolf eq. 7.6(13) averaged over s and p, integrated over
    ``basis`` to linear sRGB, clipped to [0, 1] only with ``clamp``."""
    if clamp:
        with cc.film_mode("cycles_rgb", basis):
            yield
        return
    import jax
    import jax.numpy as jnp
    from bubblefit.optics import film

    exact = film.airy_reflectance

    def per_channel(thickness, wavelength, n, cos_i):
        lam = jnp.asarray(basis.wavelengths, dtype=jnp.result_type(cos_i))
        r = jnp.mean(exact(thickness, lam, n, cos_i), axis=-1)
        r = r @ jnp.asarray(basis.weights, dtype=r.dtype)
        return jnp.broadcast_to(r[..., None], r.shape + (2,))

    jax.clear_caches()
    film.airy_reflectance = per_channel
    try:
        yield
    finally:
        film.airy_reflectance = exact
        jax.clear_caches()


def front_cos(t: dict, h: int, w: int) -> np.ndarray:
    """Cosine of incidence at the front film per pixel centre (0 off the sphere)."""
    cam = t["camera"]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    if cam["type"] == "orthographic":
        d = t["disc"]
        rho2 = ((jj - d["cx"]) ** 2 + (ii - d["cy"]) ** 2) / d["r"] ** 2
        return np.sqrt(np.clip(1 - rho2, 0, None))
    o = np.asarray(cam["origin"], float)
    fwd = np.asarray(cam["target"], float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, cam["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tn = np.tan(np.radians(cam["fov_deg"]) / 2)
    x, y = (jj - w / 2) / (w / 2) * tn, -(ii - h / 2) / (w / 2) * tn
    dv = fwd + x[..., None] * right + y[..., None] * up
    dv /= np.linalg.norm(dv, axis=-1, keepdims=True)
    c = np.asarray(t["bubble"]["center"], float)
    b = dv @ (o - c)
    disc = b * b - (np.sum((o - c) ** 2) - 1.0)
    s = -b - np.sqrt(np.clip(disc, 0, None))
    p = o + s[..., None] * dv
    return np.where(disc > 0, np.clip(-np.sum(dv * (p - c), axis=-1), 0, 1), 0.0)


def setup(case: str, illuminant: str, env_path: str, shift: dict | None = None):
    t = json.load(open(f"{D}/{case}/truth.json"))
    for k, v in (shift or {}).items():   # thickness_nm, or top_nm / bottom_nm / exponent
        t["thickness"][k] += v
    cam = dict(t["camera"])
    cam.pop("fov_axis", None)
    th = t["thickness"]
    bub = ({"thickness_nm": th["thickness_nm"]} if th["profile"] == "constant" else
           {"thickness": {"profile": "drainage", "top_nm": th["top_nm"], "bottom_nm": th["bottom_nm"],
                          "exponent": th["exponent"]}})
    bub.update({"roughness": float(t["roughness"]) ** 2, "r_d": 0.0, "r_s": 0.03, "n_film": 1.4})
    sc = Scene.from_dict({"camera": cam, "bubble": bub, "lighting": {"envmap": env_path, "illuminant": illuminant},
                          "effects": {"model": "physical", "interference": "airy", "filtering": "mipmap", "nodes": 4,
                                      "diffuse": False, "bounces": 8, "spectral": {"method": "uniform", "samples": 100},
                                      "front_reflection": True, "rear_reflection": True, "transmission": True}})
    env = read_envmap(env_path)
    bg = read_image(f"{D}/{case}/background.png").pixels
    cfg, _ = sc.config(env, background=bg)
    cfg = dataclasses.replace(cfg, pixel_footprint=True, effects=dataclasses.replace(
        cfg.effects, background="photo", filtering=FilterConfig("mipmap", nodes=4)))
    p = dataclasses.replace(sc.params(), exposure=np.float32(t["exposure"]))
    return t, cfg, p, env, bg


#: What each variant changes (module docstring): illuminant, film per hit (None: s and p
#: carried; "avgpol"; "rgb" / "rgb_clamp": Cycles' RGB film), lobe ("ward" at GGX's alpha,
#: "ggx", "ward_fitted"), rows ("bubblefit" or Blender's texel centres).
SETTINGS = {
    "E": dict(),
    "D65": dict(ill="D65"),
    "E_avgpol": dict(film="avgpol"),
    "E_rgb_noclamp": dict(film="rgb"),
    "E_rgb_clamp": dict(film="rgb_clamp"),
    "E_ggx": dict(lobe="ggx"),
    "E_ward_fitted": dict(lobe="ward_fitted"),
    "E_texel_centres": dict(rows="blender"),
    "E_cycles_all": dict(film="rgb_clamp", lobe="ggx", rows="blender"),
    "E_cycles_all_nosun": dict(film="rgb_clamp", lobe="ggx", rows="blender", sun="clipped"),
    "E_cycles_walter": dict(film="rgb_clamp", lobe="ggx", rows="blender", weights="walter"),
    "E_clamped": dict(film="clamped", rows="blender"),
    "E_clamped_ggx_facets": dict(film="clamped", rows="blender", facets="ggx"),
}
VARIANTS = tuple(SETTINGS)


def draw(case: str, variant: str, fitted_roughness: float | None, shift: dict | None = None,
         rough_scale: float = 1.0) -> np.ndarray:
    """bubblefit's linear render of ``case`` at its true parameters under ``variant``
    (the thickness parameters moved by ``shift``, the lobe widths times ``rough_scale``)."""
    s = {"ill": "E", "film": None, "lobe": "ward", "rows": "bubblefit", "weights": "ward", "sun": "kept", "facets": "ward",
         **SETTINGS[variant]}
    t = json.load(open(f"{D}/{case}/truth.json"))
    env_path = f"{D}/{t['envmap']}"
    with tempfile.TemporaryDirectory() as tmp:
        if s["rows"] == "blender" or s["sun"] == "clipped":
            pixels = vio.read_image(f"{D}/{t['envmap']}")[..., :3].astype(np.float64)
            if s["sun"] == "clipped":
                import cycles_rim
                pixels = cycles_rim.clip_sun(pixels)
            if s["rows"] == "blender":
                pixels = blender_rows(pixels)
            env_path = os.path.join(tmp, "map.exr")
            vio.write_exr(env_path, pixels.astype(np.float32))
        t, cfg, p, env, bg = setup(case, s["ill"], env_path, shift)
    alpha = float(t["roughness"]) ** 2
    widths = {"ward": [alpha], "ggx": list(ggx_ward_widths(alpha)), "ward_fitted": [fitted_roughness]}[s["lobe"]]
    widths = [w * rough_scale for w in widths]
    film = contextlib.nullcontext()
    if s["film"] == "avgpol":
        film = cc.film_mode("per_surface")
    elif s["film"] in ("rgb", "rgb_clamp"):
        basis = cfg.effects.spectral
        cfg = dataclasses.replace(cfg, effects=dataclasses.replace(cfg.effects, spectral=cc._ChannelBasis(basis)))
        film = rgb_film(basis, s["film"] == "rgb_clamp")
    elif s["film"] == "clamped":
        cfg = dataclasses.replace(cfg, film_rgb="clamped")
        if s["facets"] == "ggx":
            film = ggx_facets(alpha)
    weights = walter_weights() if s["weights"] == "walter" else contextlib.nullcontext()
    with film, weights:
        imgs = [np.asarray(render(dataclasses.replace(p, roughness=np.float32(a)), cfg, env, bg)) for a in widths]
    return np.mean(imgs, axis=0)


def score(case: str, img: np.ndarray, photo, sigma, used, rho, cos) -> dict:
    """chi^2 with the floor, outliers, per region and channel, and the colour statistic."""
    res = censored_residual(photo, img, xp=np)
    var = sigma**2 + (FLOOR * np.clip(photo, 0, None)) ** 2
    chi_c = res**2 / var
    chi = chi_c.sum(-1)
    out = {"chi2_floor": float(chi[used].sum() / (3 * used.sum())), "outliers": float(np.mean(chi[used] > OUTLIER))}
    # one gain on the render (a fit's exposure), weighted least squares over the used pixels
    g = float(np.sum((photo * img / var)[used]) / np.sum((img * img / var)[used]))
    chig = np.sum(censored_residual(photo, g * img, xp=np) ** 2 / var, axis=-1)
    out.update(gain=g, chi2_floor_gain=float(chig[used].sum() / (3 * used.sum())),
               outliers_gain=float(np.mean(chig[used] > OUTLIER)))
    share = {}
    for name, (a, b) in REGIONS.items():
        m = used & (rho >= a) & (rho < b)
        share[name] = {"pixels": int(m.sum()), "chi2_share": float(chi[m].sum() / chi[used].sum()),
                       "chi2_rgb": [float(v) for v in chi_c[m].mean(0)],
                       "photo_over_render_rgb": [float(v) for v in photo[m].sum(0) / img[m].sum(0) - 1],
                       "outliers": float(np.mean(chi[m] > OUTLIER))}
    out["regions"] = share
    # the pixel-to-pixel part: the residual less its 3 x 3 mean (white noise keeps 8/9 of its
    # variance; a model error smooth over 3 pixels drops out), as chi^2 with the floor
    hf = res - cc.box_blur(res, 3)
    chi_hf = np.sum(hf**2 / (var * 8 / 9), axis=-1)
    out.update(chi2_floor_pixel_scale=float(chi_hf[used].sum() / (3 * used.sum())),
               outliers_pixel_scale=float(np.mean(chi_hf[used] > OUTLIER)))
    def colour(mask):
        chk = colour_check(photo, img, mask & (cos > INNER_COS), sigma, model_error=FLOOR)
        return None if chk is None else {"chi2_per_dof": chk.chi2_per_dof, "limit": chk.threshold_per_dof,
                                         "chroma_rms": chk.chroma_rms, "kappa": chk.noise_scale, "cells": chk.cells}

    out["colour"] = colour(used)
    # the statistic over each region alone (its own cells and kappa): where the hue error sits
    out["colour_by_region"] = {name: colour(used & (rho >= a) & (rho < b)) for name, (a, b) in REGIONS.items()}
    return out


#: finite-difference steps of :func:`thickness_shift`'s Jacobian: the fit's free thickness
#: parameters (nm; the exponent in its own unit) and the lobe width (relative)
STEPS = {"constant": {"thickness_nm": 1.0}, "drainage": {"top_nm": 1.0, "bottom_nm": 1.0, "exponent": 0.01}}
ROUGH_STEP = 0.05


def jacobian(case: str, profile: str, base: np.ndarray, fitted) -> dict:
    """Finite-difference columns (render change per unit) of the ``E`` render: each thickness
    parameter of :data:`STEPS` and the lobe width's log (:data:`ROUGH_STEP`)."""
    cols = {k: (draw(case, "E", fitted, {k: h}) - base) / h for k, h in STEPS[profile].items()}
    cols["log_roughness"] = (draw(case, "E", fitted, rough_scale=1 + ROUGH_STEP) - base) / np.log1p(ROUGH_STEP)
    return cols


def thickness_shift(base: np.ndarray, steps: list, img: np.ndarray, photo, sigma, used) -> dict:
    """The parameters (and one gain) a fit would move by to turn ``base`` into ``img``:
    the Gauss-Newton step ``(J^T W J)^-1 J^T W (img - base)`` (Press et al., Numerical
    Recipes, 3rd ed., sec. 15.5) with ``J`` the render's change per unit of each parameter
    (``steps``, :func:`jacobian`'s columns) and per unit gain (``base``), ``W`` the fit's
    weights (noise model and 3 % floor) over ``used``; once over all used pixels, once
    without the pixels where ``img`` is an outlier of ``base`` (chi^2 > 30)."""
    var = sigma**2 + (FLOOR * np.clip(photo, 0, None)) ** 2
    cols = list(steps) + [base]
    r = img - base
    chi = np.sum(r**2 / var, axis=-1)
    out = {}
    for name, m in (("all", used), ("inliers", used & (chi <= OUTLIER))):
        wsq = 1 / np.sqrt(var[m])
        j = np.stack([c[m] * wsq for c in cols], axis=-1).reshape(-1, len(cols))
        x = np.linalg.lstsq(j, (r[m] * wsq).reshape(-1), rcond=None)[0]
        out[name] = [float(v) for v in x[:-1]] + [float(1 + x[-1])]
    return out


def emulate(case: str, npz: str, variant: str, out: str) -> str:
    """A copy of ``case`` under ``out`` (for ``validate.py --data OUT``) whose photo is the
    saved render ``variant`` (linear, times the true exposure) through the case's own sensor
    model and seed (make_cycles.py: vio.add_noise_and_quantise, 4000 e- at 1.0, 3 e- read
    noise, 8-bit sRGB): the photo Cycles would give without its Monte Carlo noise if it
    rendered as ``variant`` does. The background, truth and scene files are the case's."""
    import shutil

    t = json.load(open(f"{D}/{case}/truth.json"))
    dst = os.path.join(out, case)
    os.makedirs(dst, exist_ok=True)
    if not os.path.exists(os.path.join(out, "envmaps")):
        os.symlink(os.path.join(D, "envmaps"), os.path.join(out, "envmaps"))
    for name in ("background.png", "truth.json", "scene.toml", "thickness_true.exr"):
        if os.path.exists(f"{D}/{case}/{name}"):
            shutil.copy(f"{D}/{case}/{name}", dst)
    rng = np.random.default_rng(t["noise"]["seed"])
    img = np.clip(np.load(npz)[variant].astype(np.float64), 0, None)
    vio.write_png8(os.path.join(dst, "photo.png"), None, vio.add_noise_and_quantise(
        img, rng, t["noise"]["full_well_e_at_1.0"], t["noise"]["read_noise_e"]))
    return dst


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("--only", default=",".join(VARIANTS))
    ap.add_argument("--json")
    ap.add_argument("--from-npz", help="score the renders an earlier run saved (OUT_renders.npz) instead of rendering")
    ap.add_argument("--no-shift", action="store_true", help="skip the linearised fit (and its renders)")
    ap.add_argument("--emulate", nargs=3, metavar=("NPZ", "VARIANT", "OUT"),
                    help="write the case with its photo replaced by a saved render (emulate) and stop")
    a = ap.parse_args(argv)
    if a.emulate:
        print(emulate(a.case, *a.emulate))
        return
    saved = np.load(a.from_npz) if a.from_npz else None
    t = json.load(open(f"{D}/{a.case}/truth.json"))
    fitted = None
    rows = json.load(open(os.path.join(HERE, "results", "test", "results.json")))["rows"]
    for r in rows:
        if r["case"].split(":")[0] == a.case:
            fitted = float(r["roughness"])
    photo = read_image(f"{D}/{a.case}/photo.png").pixels
    back = read_image(f"{D}/{a.case}/background.png").pixels
    sigma = noise_sigma(photo, 2e-3, 2e-4, 8)
    sat = saturation_mask(photo, 1.0, None)
    h, w = photo.shape[:2]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = t["disc"]
    rho = np.hypot(jj - d["cx"], ii - d["cy"]) / d["r"]
    used = (rho < 0.96) & ~sat
    cos = front_cos(t, h, w)
    outside = (rho > 1.1) & ~sat & ~saturation_mask(back, 1.0, None)
    sb = noise_sigma(back, 2e-3, 2e-4, 8)
    chib = (photo - back) ** 2 / (sigma**2 + sb**2)
    report = {"case": a.case, "ggx_alpha": float(t["roughness"]) ** 2, "fitted_ward_roughness": fitted,
              "ggx_ward_widths": ggx_ward_widths(float(t["roughness"]) ** 2).tolist(),
              "background_noise": {"chi2_rgb": [float(v) for v in chib[outside].mean(0)], "pixels": int(outside.sum()),
                                   "note": "photo against background.png outside the disc, twice the noise model"},
              "used_pixels": int(used.sum()), "variants": {}}
    print(a.case, "background photo vs background.png chi2 per channel", report["background_noise"]["chi2_rgb"], flush=True)
    # the base (illuminant E, Ward at alpha) and its derivatives, for the shifts
    base = saved["E"].astype(np.float64) if saved is not None else draw(a.case, "E", fitted)
    cols = {} if a.no_shift else jacobian(a.case, t["thickness"]["profile"], base, fitted)
    names = list(cols)
    thick = [cols[k] for k in names if k != "log_roughness"]
    report["shift_note"] = ("change of each parameter (" + ", ".join(names) + ", then the gain) of a linearised fit "
                            "turning the E render into the variant (thickness_shift); 'with_roughness' frees the "
                            "lobe width too; 'photo' turns it into the photo")
    shifts = lambda img: None if a.no_shift else {"thickness_only": thickness_shift(base, thick, img, photo, sigma, used),
                          "with_roughness": thickness_shift(base, [cols[k] for k in names], img, photo, sigma, used)}
    report["photo_shift"] = shifts(photo)
    print("photo shift from E at the truth:", report["photo_shift"], flush=True)
    images = {}
    for v in a.only.split(","):
        t0 = time.time()
        if saved is not None:
            if v not in saved:
                continue
            img = saved[v].astype(np.float64)
        else:
            img = base if v == "E" else draw(a.case, v, fitted)
        images[v] = img.astype(np.float32)
        row = score(a.case, img, photo, sigma, used, rho, cos)
        row["noise_excess_rgb_inner"] = cc.noise_excess(np.clip(img, 0, 1), photo, used & (rho < 0.8))
        row["shift"] = shifts(img)
        row["render_s"] = round(time.time() - t0, 1)
        report["variants"][v] = row
        c = row["colour"] or {}
        print(f"{a.case} {v}: chi2 {row['chi2_floor']:.2f} outliers {100 * row['outliers']:.1f} % "
              f"(gain {row['gain']:.3f}: {row['chi2_floor_gain']:.2f}, {100 * row['outliers_gain']:.1f} %; pixel scale "
              f"{row['chi2_floor_pixel_scale']:.2f}, {100 * row['outliers_pixel_scale']:.1f} %) colour "
              f"{c.get('chi2_per_dof', float('nan')):.2f}/{c.get('limit', float('nan')):.2f} kappa "
              f"{c.get('kappa', float('nan')):.2f} chroma {100 * c.get('chroma_rms', float('nan')):.2f} % "
              f"[{row['render_s']} s] shift from E {row['shift']}", flush=True)
        for name, s in row["regions"].items():
            print(f"    {name}: share {100 * s['chi2_share']:.0f} %, chi2 rgb "
                  + " ".join(f"{x:.2f}" for x in s["chi2_rgb"]) + ", photo/render-1 rgb "
                  + " ".join(f"{100 * x:+.1f}%" for x in s["photo_over_render_rgb"])
                  + f", outliers {100 * s['outliers']:.1f} %", flush=True)
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(report, fh, indent=1)
            np.savez_compressed(a.json.replace(".json", "") + "_renders.npz", photo=photo, **images)


if __name__ == "__main__":
    main()
