"""Colour agreement of bubblefit with Blender Cycles' thin-film bubbles (CIEDE2000).

For each Cycles case of the validation set (data/cyc_*), bubblefit renders the bubble with
the TRUE parameters through its public scene API (:func:`bubblefit.model.scene.render_scene`
on a :meth:`~bubblefit.model.scene.Scene.from_dict` scene): the ``physical`` model (exact
Airy film, Fresnel per polarisation, 8 internal bounces), roughness 0 (mirror lookup), no
diffuse term, the case's map as light and as background (Cycles' world: truth.json
``background = "env"``), and the true thickness field. The render is scaled by the case's
``exposure`` (make_cycles.py multiplies Cycles' linear render by it before the sensor noise)
and clipped to [0, 1] as the photo's sensor was, then compared per pixel with the decoded
8-bit photo in CIEDE2000 over the inner 70 % of the disc (pixel centres at +1/2, radius
< 0.7 r).

Variants (each a row of the table):

* ``matched``: illuminant E (``[lighting] illuminant``, as Cycles integrates its film) and
  4x4 samples per pixel (``[camera] samples_per_pixel = 16``; Cycles' box filter).
* ``matched_avgpol``: as ``matched`` but with s and p averaged at every film hit, the way
  Cycles treats light as unpolarised after each surface. bubblefit has no such option (its
  physical model carries s and p through the whole path, docs/design.md); here the Airy
  reflectance is replaced, for this render only, by its polarisation mean broadcast to both
  polarisations (:func:`film_mode`), so every product along a path becomes a product of
  means.
* ``matched_cycles_rgb``: a diagnostic emulation of Cycles' film on bubblefit's geometry:
  s and p averaged per hit, and the film's reflectance integrated to linear sRGB per hit and
  clamped to [0, 1] (Cycles 5.0.1 ``fresnel_iridescence`` in kernel/closure/bsdf_util.h
  returns ``saturate(mix(R_s, R_p, 0.5))`` per RGB channel), the path a product of
  per-channel reflectances and transmittances ``1 - R``.
* ``E_1spp`` and ``D65_16spp``: one of the two settings at a time.
* ``mismatched``: bubblefit's defaults, D65 and one ray per pixel centre.

For the bump case a scene cannot express the Gaussian bump, so ``matched`` passes the
front-film thickness of thickness_true.exr as a ``map`` with the drainage part as the
profile under it (the rear film and the bounces take the map's value at their pixel
changed by the profile between the heights, so the rear film carries the bump too, unlike
Cycles'; sub-pixel rays share the pixel centre's value); ``drainage_only`` renders the
drainage part alone. Statistics are also given outside the bump (front point more than
3 sigma from its centre).

Each statistic (median, mean, 90th percentile of dE00) is given on the raw images and
after a 5x5 box blur of both. The photo carries Cycles' Monte Carlo noise (256 spp),
Poisson-Gaussian sensor noise and 8-bit quantisation; two noise floors are reported:
``floor_sensor``: the matched render passed through the same sensor model
(vio.add_noise_and_quantise, 4000 e- at 1.0, 3 e- read noise, 8-bit sRGB) against itself
clean, over the same pixels (what a perfect renderer would score without Monte Carlo
noise; mean of 4 seeds); ``floor_background``: background.png against bubblefit's
noise-free map background outside the disc (rho > 1.1). ``hf_noise_excess_rgb`` is the
photo's high-frequency residual variance over the sensor model's, per channel (> 1: Monte
Carlo noise on top of the sensor's).

    PYTHONPATH=. python experiments/validation/cycles_colour.py [CASE ...] [--out DIR]

Writes results/cycles_colour.json and results/cycles_colour.png beside this file.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import vio  # noqa: E402

CASES = ["cyc_const500_courtyard_ortho", "cyc_drain_lin_sunrise_persp", "cyc_bump_city_ortho_offc"]
INNER = 0.7          # inner disc: pixel centres within 0.7 r
BLUR = 5             # box blur (pixels) of the denoised comparison
SPECTRAL = {"method": "uniform", "samples": 100}   # the paper's 100 uniform samples (sec. 3.4)
BOUNCES = 8
NOISE_SEEDS = (101, 102, 103, 104)
VARIANTS = {          # name: (illuminant, samples per pixel, film mode: FILM_MODES)
    "matched": ("E", 16, "carried"),
    "matched_avgpol": ("E", 16, "per_surface"),
    "matched_cycles_rgb": ("E", 16, "cycles_rgb"),
    "E_1spp": ("E", 1, "carried"),
    "D65_16spp": ("D65", 16, "carried"),
    "mismatched": ("D65", 1, "carried"),
}


def load_truth(case: str) -> dict:
    with open(os.path.join(vio.DATA, case, "truth.json")) as fh:
        return json.load(fh)


def crop_window(truth: dict, margin: int = 3) -> tuple[slice, slice]:
    """Rows and columns of the smallest window holding the inner disc plus ``margin``
    pixels beyond the blur's reach (orthographic cases: the render of the window equals
    that window of the full render, pixel for pixel)."""
    d, c = truth["disc"], truth["camera"]
    half = INNER * d["r"] + BLUR // 2 + margin
    x0, x1 = max(0, int(np.floor(d["cx"] - half))), min(c["width"], int(np.ceil(d["cx"] + half)))
    y0, y1 = max(0, int(np.floor(d["cy"] - half))), min(c["height"], int(np.ceil(d["cy"] + half)))
    return slice(y0, y1), slice(x0, x1)


def scene_dict(truth: dict, *, illuminant: str, spp: int, thickness: str = "truth", crop=None,
               map_path: str | None = None) -> dict:
    """The scene (docs/design.md, "Scene files") of a Cycles case with its true parameters.

    ``thickness``: ``"truth"`` (constant or drainage from truth.json; the bump case as the
    per-pixel map thickness_true.exr) or ``"drainage"`` (the drainage part alone). Paths are
    relative to data/ (the scene's base folder); ``map_path`` is the thickness map to read
    (bubblefit refuses NaN pixels, so :func:`render` passes a copy of thickness_true.exr
    with 0 off the bubble). ``crop`` (rows, cols slices; orthographic
    only, constant or drainage film) renders that window alone: a smaller camera with the
    disc moved by the window's corner.
    """
    cam = dict(truth["camera"])
    camera = {"type": cam["type"], "width": int(cam["width"]), "height": int(cam["height"]),
              "samples_per_pixel": int(spp)}
    if cam["type"] == "orthographic":
        camera["disc"] = [float(v) for v in cam["disc"]]
        if crop is not None:
            rows, cols = crop
            camera.update(width=cols.stop - cols.start, height=rows.stop - rows.start)
            camera["disc"] = [camera["disc"][0] - cols.start, camera["disc"][1] - rows.start, camera["disc"][2]]
    elif crop is not None:
        raise ValueError("a crop needs an orthographic camera")
    else:
        if cam.get("fov_axis", "width") != "width":
            raise ValueError("bubblefit's fov_deg is along the image width")
        camera.update(origin=[float(v) for v in cam["origin"]], target=[float(v) for v in cam["target"]],
                      up=[float(v) for v in cam["up"]], fov_deg=float(cam["fov_deg"]))
    th = truth["thickness"]
    bubble = {"center": [float(v) for v in truth["bubble"]["center"]], "radius": float(truth["bubble"]["radius"]),
              "n_film": float(truth["bubble"]["n_film"]), "roughness": float(truth["roughness"]), "r_d": 0.0,
              "t": float(truth["t"])}
    if th["profile"] == "constant":
        bubble["thickness_nm"] = float(th["thickness_nm"])
    elif th["profile"] == "drainage" or thickness == "drainage":
        bubble["thickness"] = {"profile": "drainage", "top_nm": float(th["top_nm"]),
                               "bottom_nm": float(th["bottom_nm"]), "exponent": float(th["exponent"])}
    else:
        if crop is not None:
            raise ValueError("a crop cannot take the full-frame thickness map")
        bubble["thickness"] = {"profile": "map", "path": map_path, "top_nm": float(th["top_nm"]),
                               "bottom_nm": float(th["bottom_nm"]), "exponent": float(th["exponent"])}
    if truth["background"] != "env":
        raise ValueError(f"{truth['case']}: background {truth['background']!r} is not the map")
    lighting = {"envmap": truth["envmap"], "rotation_deg": float(truth["rotation_deg"]), "background": "envmap",
                "illuminant": illuminant}
    effects = {"model": "physical", "interference": "airy", "spectral": dict(SPECTRAL), "filtering": "mirror",
               "diffuse": False, "front_reflection": True, "rear_reflection": True, "transmission": True,
               "bounces": BOUNCES}
    return {"camera": camera, "bubble": bubble, "lighting": lighting, "effects": effects}


#: How the film enters the path: bubblefit's model ("carried": s and p and the spectrum
#: kept through every product, averaged at the end), s and p averaged at every hit
#: ("per_surface"), or Cycles' RGB film ("cycles_rgb": s and p averaged and the spectrum
#: integrated to linear sRGB at every hit, the path a product of per-channel reflectances).
FILM_MODES = ("carried", "per_surface", "cycles_rgb")


class _ChannelBasis:
    """A stand-in spectral basis whose three "samples" are the sRGB channels (identity
    weights), so that the physical model's products along a path (T_0 T_1, T_0 R_1 T_2 ...)
    multiply per-channel reflectances, as an RGB renderer does. Only the attributes the
    renderer reads are given (bubblefit.optics.spectral.SpectralBasis)."""

    def __init__(self, basis):
        self.basis = basis
        self.method, self.samples, self.sigma, self.phases = "cycles_rgb", 3, None, None
        self.illuminant, self.response, self.white_balance = basis.illuminant, basis.response, basis.white_balance
        self.wavelengths = np.array([600.0, 550.0, 450.0])   # placeholders: the film ignores them
        self.weights = np.eye(3)
        self.bin_width = np.ones(3)

    def _key(self):
        return ("cycles_rgb",) + self.basis._key()

    def __hash__(self):
        return hash(self._key())

    def __eq__(self, other):
        return isinstance(other, _ChannelBasis) and self._key() == other._key()


@contextlib.contextmanager
def film_mode(mode: str, basis=None):
    """Within the block, bubblefit's Airy film (Born & Wolf eq. 7.6(13),
    :func:`bubblefit.optics.film.airy_reflectance`) follows ``mode`` (:data:`FILM_MODES`):

    * ``per_surface``: returns ``(R_s + R_p) / 2`` for both polarisations: light is
      unpolarised after every film hit (Cycles' ``fresnel_iridescence`` averages R_s and
      R_p per hit), so every product along a path becomes a product of means.
    * ``cycles_rgb``: as ``per_surface``, and integrated at once over ``basis`` (the
      scene's spectral quadrature) to linear sRGB, then clamped to [0, 1] per channel (the
      ``saturate`` that ends Cycles' ``fresnel_iridescence``: out of gamut, the sRGB red of
      a green-peaked film is negative); with :class:`_ChannelBasis` in the render the path
      is then a product of per-channel reflectances, ``T = 1 - R`` per channel, Cycles' RGB
      film (Belcour & Barla 2017 eq. 10 evaluated per channel).

    Only the ``uniform``/``reference`` bases are covered (the ``fourier`` one corrects the
    exact value per polarisation). JAX's compiled programs are dropped on entry and exit so
    that no model reuses another's."""
    import jax
    import jax.numpy as jnp
    from bubblefit.optics import film

    if mode == "carried":
        yield
        return
    exact = film.airy_reflectance

    def averaged(thickness, wavelength, n, cos_i):
        if mode == "cycles_rgb":
            lam = jnp.asarray(basis.wavelengths, dtype=jnp.result_type(cos_i))
            r = jnp.mean(exact(thickness, lam, n, cos_i), axis=-1)          # (..., K)
            r = jnp.clip(r @ jnp.asarray(basis.weights, dtype=r.dtype), 0.0, 1.0)   # (..., 3), saturate()
            return jnp.broadcast_to(r[..., None], r.shape + (2,))
        r = exact(thickness, wavelength, n, cos_i)
        return jnp.broadcast_to(jnp.mean(r, axis=-1, keepdims=True), r.shape)

    jax.clear_caches()
    film.airy_reflectance = averaged
    try:
        yield
    finally:
        film.airy_reflectance = exact
        jax.clear_caches()


def render(truth: dict, *, illuminant: str, spp: int, film: str = "carried", thickness: str = "truth",
           crop=None) -> np.ndarray:
    """bubblefit's linear render of the case (:func:`bubblefit.model.scene.render_scene`;
    for ``film = "cycles_rgb"`` the same plan through
    :func:`bubblefit.model.render.render_plan` with :class:`_ChannelBasis`), times the
    case's exposure and clipped to [0, 1] as the photo's sensor clipped it (make_cycles.py:
    ``photo * exposure``, then vio.add_noise_and_quantise)."""
    import dataclasses

    from bubblefit.model.programs import STORED
    from bubblefit.model.regions import render_plan
    from bubblefit.model.scene import Scene, render_scene

    if film not in FILM_MODES:
        raise ValueError(f"film must be one of {FILM_MODES}, got {film!r}")
    with tempfile.TemporaryDirectory() as tmp:
        map_path = None
        if "bump_nm" in truth["thickness"] and thickness == "truth":
            tm = vio.read_image(os.path.join(vio.DATA, truth["case"], "thickness_true.exr"))[..., 0]
            map_path = os.path.join(tmp, "thickness.exr")
            vio.write_exr(map_path, np.nan_to_num(tm, nan=0.0))
        scene = Scene.from_dict(scene_dict(truth, illuminant=illuminant, spp=spp, thickness=thickness, crop=crop,
                                           map_path=map_path), base_dir=vio.DATA)
        if film != "cycles_rgb":
            with film_mode(film):
                img = render_scene(scene)
        else:
            env = scene.load_envmap()
            parts, _ = scene.plan(env)
            basis = parts[0][0].effects.spectral
            swap = lambda cfg: dataclasses.replace(
                cfg, effects=dataclasses.replace(cfg.effects, spectral=_ChannelBasis(cfg.effects.spectral)))
            parts = [(swap(cfg), px) for cfg, px in parts]
            if any(cfg.effects.spectral.basis != basis for cfg, _ in parts):
                raise ValueError("the regions of the plan use different spectral bases")
            with film_mode("cycles_rgb", basis):
                img = render_plan(scene.params(), parts, env, None, programs=STORED)
    return np.clip(np.asarray(img, dtype=np.float64) * truth["exposure"], 0.0, 1.0)


def read_photo(case: str, name: str = "photo.png") -> np.ndarray:
    """A case's 8-bit sRGB image, decoded to linear (IEC 61966-2-1)."""
    return vio.srgb_decode(vio.read_image(os.path.join(vio.DATA, case, name))[..., :3])


def linear_srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (CIE 15:2004) of linear sRGB: Rec.709 primaries to XYZ with the D65 white
    (IEC 61966-2-1), then L*a*b* against D65 (Y = 1), through colour-science."""
    import colour

    xyz = colour.RGB_to_XYZ(rgb, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def delta_e00(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-pixel CIEDE2000 (Sharma, Wu & Dalal 2005; ``colour.delta_E(..., method="CIE 2000")``)
    between two linear sRGB images."""
    import colour

    return colour.delta_E(linear_srgb_to_lab(a), linear_srgb_to_lab(b), method="CIE 2000")


def box_blur(img: np.ndarray, k: int = BLUR) -> np.ndarray:
    """Mean over a k x k box per channel (edges replicated)."""
    from scipy.ndimage import uniform_filter

    return uniform_filter(img, size=(k, k, 1), mode="nearest")


def radius_map(truth: dict, shape) -> np.ndarray:
    """Distance of each pixel centre (+1/2) from the disc centre, over the disc radius."""
    h, w = shape[:2]
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    d = truth["disc"]
    return np.hypot(xx - d["cx"], yy - d["cy"]) / d["r"]


def bump_mask(truth: dict, shape, n_sigma: float = 3.0) -> np.ndarray | None:
    """Pixels whose front film point (orthographic camera) lies within ``n_sigma`` of the
    bump's centre on the unit sphere (truth.json ``bump_formula``); None without a bump."""
    th = truth["thickness"]
    if "bump_nm" not in th or truth["camera"]["type"] != "orthographic":
        return None
    h, w = shape[:2]
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    d = truth["disc"]
    x, y = (xx - d["cx"]) / d["r"], -(yy - d["cy"]) / d["r"]
    z = np.sqrt(np.clip(1.0 - x * x - y * y, 0.0, None))
    c = np.asarray(th["bump_center_unit"], float)
    c = c / np.linalg.norm(c)
    dist = np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2)
    return dist < n_sigma * th["bump_sigma_radii"]


def stats(de: np.ndarray) -> dict:
    """Median, mean and 90th percentile of a set of dE00 values."""
    return {"median": float(np.median(de)), "mean": float(np.mean(de)), "p90": float(np.percentile(de, 90)),
            "n": int(de.size)}


def compare(render_img: np.ndarray, photo: np.ndarray, mask: np.ndarray) -> dict:
    """dE00 statistics over ``mask``, raw and after a box blur of both images."""
    return {"raw": stats(delta_e00(render_img, photo)[mask]),
            "blur": stats(delta_e00(box_blur(render_img), box_blur(photo))[mask])}


def sensor_floor(clean: np.ndarray, mask: np.ndarray) -> dict:
    """dE00 of the sensor model alone: the clean render through vio.add_noise_and_quantise
    (the photo's Poisson-Gaussian noise and 8-bit sRGB) against itself, mean over seeds."""
    rows = []
    for seed in NOISE_SEEDS:
        codes = vio.add_noise_and_quantise(clean, np.random.default_rng(seed))
        rows.append(compare(clean, vio.srgb_decode(codes / 255.0), mask))
    return {k: {s: float(np.mean([r[k][s] for r in rows])) for s in ("median", "mean", "p90")} for k in ("raw", "blur")}


def noise_excess(clean: np.ndarray, photo: np.ndarray, mask: np.ndarray, seed: int = NOISE_SEEDS[0]) -> list[float]:
    """Per channel, the variance of the high-frequency part (minus a 3x3 box mean) of the
    residual photo - render over ``mask``, over the same for the sensor model alone applied
    to the render: 1 when the photo holds no noise beyond the sensor's, above 1 with Monte
    Carlo noise (or detail the render lacks)."""
    hf = lambda x: x - box_blur(x, 3)
    sim = vio.srgb_decode(vio.add_noise_and_quantise(clean, np.random.default_rng(seed)) / 255.0)
    return (hf(photo - clean)[mask].var(0) / hf(sim - clean)[mask].var(0)).tolist()


def run_case(case: str, variants=None) -> tuple[dict, dict]:
    """All variants of one case: (report, images for the figure)."""
    truth = load_truth(case)
    photo = read_photo(case)
    rho = radius_map(truth, photo.shape)
    inner = rho < INNER
    clipped = photo.max(-1) >= 254.5 / 255
    bump = bump_mask(truth, photo.shape)
    report = {"case": case, "exposure": truth["exposure"], "inner_pixels": int(inner.sum()),
              "inner_clipped_fraction": float(clipped[inner].mean()), "variants": {}}
    images = {"photo": photo}
    todo = dict(VARIANTS) if variants is None else {k: VARIANTS[k] for k in variants}
    jobs = [(name, ill, spp, fm, "truth") for name, (ill, spp, fm) in todo.items()]
    if bump is not None and (variants is None or "drainage_only" in variants):
        jobs.append(("drainage_only", "E", 16, "carried", "drainage"))
    for name, ill, spp, fm, thick in jobs:
        t0 = time.time()
        img = render(truth, illuminant=ill, spp=spp, film=fm, thickness=thick)
        kind = truth["thickness"]["profile"]
        label = "drainage" if thick == "drainage" else ("map thickness_true.exr" if "bump_nm" in truth["thickness"]
                                                         else kind)
        row = {"illuminant": ill, "samples_per_pixel": spp, "film": fm,
               "thickness": label, "render_s": round(time.time() - t0, 1), **compare(img, photo, inner)}
        if bump is not None:
            row["outside_bump"] = compare(img, photo, inner & ~bump)
        report["variants"][name] = row
        images[name] = img
        print(f"  {case} {name}: median {row['raw']['median']:.3f} (blur {row['blur']['median']:.3f}) "
              f"[{row['render_s']} s]", flush=True)
    clean = images.get("matched")
    if clean is not None:
        report["floor_sensor"] = sensor_floor(clean, inner)
        report["hf_noise_excess_rgb"] = noise_excess(clean, photo, inner)
        outside = rho > 1.1
        back = read_photo(case, "background.png")
        report["floor_background"] = compare(clean, back, outside)
        report["floor_background"]["note"] = "background.png against bubblefit's map background, rho > 1.1"
    return report, images


def table(reports: list[dict]) -> str:
    """A Markdown table of the results."""
    lines = ["| case | variant | dE00 median | mean | p90 | blurred median | mean | p90 |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    f = lambda s: f"{s['median']:.2f} | {s['mean']:.2f} | {s['p90']:.2f}"
    for rep in reports:
        for name, row in rep["variants"].items():
            lines.append(f"| {rep['case']} | {name} | {f(row['raw'])} | {f(row['blur'])} |")
            if "outside_bump" in row:
                lines.append(f"| {rep['case']} | {name}, outside bump | {f(row['outside_bump']['raw'])} | "
                             f"{f(row['outside_bump']['blur'])} |")
        for key in ("floor_sensor", "floor_background"):
            if key in rep:
                lines.append(f"| {rep['case']} | {key} | {f(rep[key]['raw'])} | {f(rep[key]['blur'])} |")
    return "\n".join(lines)


def figure(reports: list[dict], images: dict, path: str) -> None:
    """Per case: bubblefit's matched render, Cycles' photo, and the blurred dE00 map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(reports)
    fig, axes = plt.subplots(n, 3, figsize=(7.2, 2.4 * n), squeeze=False)
    for i, rep in enumerate(reports):
        ims = images[rep["case"]]
        truth = load_truth(rep["case"])
        de = delta_e00(box_blur(ims["matched"]), box_blur(ims["photo"]))
        de = np.where(radius_map(truth, de.shape) < 1.0, de, np.nan)
        for j, (im, title) in enumerate(((ims["matched"], "bubblefit (E, 4x4)"), (ims["photo"], "Cycles photo"))):
            axes[i, j].imshow(vio.srgb_encode(im), interpolation="nearest")
            axes[i, j].set_title(title, fontsize=8)
        h = axes[i, 2].imshow(de, vmin=0, vmax=3, cmap="magma", interpolation="nearest")
        th = np.linspace(0, 2 * np.pi, 200)
        d = truth["disc"]
        axes[i, 2].plot(d["cx"] - 0.5 + INNER * d["r"] * np.cos(th), d["cy"] - 0.5 + INNER * d["r"] * np.sin(th),
                        "c-", lw=0.6)
        title = f"dE00 5x5 blur: median {rep['variants']['matched']['blur']['median']:.2f}"
        if "matched_cycles_rgb" in rep["variants"]:
            title += f"\n(Cycles-RGB film: {rep['variants']['matched_cycles_rgb']['blur']['median']:.2f})"
        axes[i, 2].set_title(title, fontsize=7)
        fig.colorbar(h, ax=axes[i, 2], fraction=0.046)
        axes[i, 0].set_ylabel(rep["case"], fontsize=7)
        for ax in axes[i]:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=68)
    plt.close(fig)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=CASES)
    ap.add_argument("--out", default=os.path.join(HERE, "results"))
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    reports, images = [], {}
    for case in args.cases:
        rep, ims = run_case(case)
        reports.append(rep)
        images[case] = ims
    md = table(reports)
    print(md)
    for rep in reports:
        print(f"{rep['case']}: high-frequency noise over the sensor model's (R, G, B) "
              + " ".join(f"{v:.2f}" for v in rep.get("hf_noise_excess_rgb", [])))
    vio.save_json(os.path.join(args.out, "cycles_colour.json"),
                  {"inner_radius": INNER, "blur_px": BLUR, "spectral": SPECTRAL, "bounces": BOUNCES,
                   "cases": reports, "table_md": md})
    figure(reports, images, os.path.join(args.out, "cycles_colour.png"))


if __name__ == "__main__":
    main()
