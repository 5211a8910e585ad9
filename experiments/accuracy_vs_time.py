"""What accuracy costs in time: every approximation's knob against a converged reference.

Each knob is swept on its own, the others held at converged or typical values, and each
point records the error a user would feel and the time it costs:

* ``spectral_uniform`` / ``spectral_fourier`` / ``spectral_harmonic``: K uniform samples
  (the paper's 3-100), the alias-free ``fourier`` basis (Gaussian lobes in wavenumber,
  after Belcour & Barla 2017) and K samples in the phase of eq. (8) (``harmonic``, exact
  for a film of one thickness). Error: mean CIEDE2000 of the Airy film colour (normal incidence, n = 1.4) against
  the 800-sample reference over 100-6000 nm, shown at a display level that maps the
  incoherent grey to 0.5 (columns ``error_thin`` 100-1500 nm and ``error_thick``
  3000-6000 nm split it). Time: a render of the physical model with that basis.
* ``filter_<method>_a<roughness>``: environment filtering (``mirror``, ``window`` size k,
  ``mipmap`` nodes, ``full`` sum over mip level L, listed from coarse to fine) at
  roughness 0.005-0.1. Error: relative RMSE in linear radiance of the film's reflection
  against the full sum of eq. (12) at level 0 of the same (256-wide) map.
* ``envmap_width``: the map downsampled (power preserving) to 64-1024 texels wide,
  ``mipmap`` filtering; reference: the 1024-wide map.
* ``image_size``: render size in pixels; reference: a 4x larger render averaged down to the
  same pixels (what a camera pixel integrates).
* ``precision``: float32 against float64 (reference) for a 5000 nm film.
* ``fit_max_steps`` / ``fit_rtol``: :func:`bubblefit.inverse.fit.fit_photo` on a synthetic photo
  (8-bit, noisy) of a known 700 nm film; error: |fitted - true| thickness in nm.

Times are medians over warm runs (``time_s``); the first call's extra time, mostly JAX
compilation (less when bubblefit's persistent cache already holds it), is ``compile_s``.
Settings in ``results.csv`` are listed from cheapest to most accurate.

    python experiments/accuracy_vs_time.py [--quick] [--out DIR] [--no-copy]
    python experiments/accuracy_vs_time.py --fit-lobes 8   # refit spectral.FOURIER_LOBES[8]

Writes ``DIR/results.csv`` (``knob,setting,error,error_unit,time_s,compile_s,...``), one
Pareto plot per knob family ``DIR/pareto_<family>.png``, all of them in
``DIR/pareto.png``, ``DIR/banding.png`` (thick-film colours with each basis) and
``DIR/summary.json``; without ``--quick`` it copies ``pareto.png`` and ``banding.png`` to
``experiments/figures/accuracy_*.png`` for the README.
"""

from __future__ import annotations

import csv
import sys
import time
from pathlib import Path

import numpy as np

import _figures as F

COLUMNS = ("knob", "setting", "error", "error_unit", "time_s", "compile_s", "error_thin", "error_thick", "note")
N_FILM = 1.4


# --- timing --------------------------------------------------------------------------------

def timed(fn, repeats: int):
    """Run ``fn`` once cold and ``repeats`` times warm: (result, median warm s, cold extra s)."""
    import jax

    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        warm.append(time.perf_counter() - t0)
    med = float(np.median(warm)) if warm else cold
    return out, med, max(cold - med, 0.0)


def rel_rmse(img, ref) -> float:
    """Relative RMSE in linear radiance: ``||img - ref|| / ||ref||`` over all pixels."""
    img = np.asarray(img, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    return float(np.sqrt(np.mean((img - ref) ** 2)) / max(np.sqrt(np.mean(ref**2)), 1e-30))


# --- film colours and CIEDE2000 ----------------------------------------------------------------

def film_colours(basis, thickness_nm, cos_i: float = 1.0):
    """Linear sRGB (N, 3) of an Airy film (mean of s and p) with ``basis`` (prefiltered if it
    carries lobes)."""
    import jax.numpy as jnp

    from bubblefit.optics import film, spectral

    d = jnp.asarray(np.asarray(thickness_nm, dtype=np.float32))[:, None]
    if basis.phases is not None:  # harmonic: samples in phase, weights per thickness
        g = film.airy_at_phase(jnp.asarray(basis.phases, dtype=jnp.float32), N_FILM, cos_i).mean(-1)  # (K,)
        w = spectral.harmonic_weights(film.optical_path(d[:, 0], N_FILM, cos_i), basis)  # (N, K, 3)
        return np.asarray(jnp.einsum("k,nkc->nc", g, w), dtype=np.float64)
    lam = jnp.asarray(basis.wavelengths, dtype=jnp.float32)
    if basis.sigma is None:
        s = film.airy_reflectance(d, lam, N_FILM, cos_i)
    else:
        s = film.filtered_airy_reflectance(d, lam, N_FILM, cos_i, jnp.asarray(basis.sigma, dtype=jnp.float32))
    return np.asarray(spectral.integrate(s.mean(-1), basis), dtype=np.float64)


def display_rgb(rgb, cos_i: float = 1.0):
    """Scale film reflectance so that its incoherent grey is 0.5 (how a chart shows it)."""
    from bubblefit.optics import film

    grey = float(np.asarray(film.incoherent_reflectance(cos_i, N_FILM)).mean())
    return np.asarray(rgb) * 0.5 / grey


def ciede2000(rgb_a, rgb_b):
    """CIEDE2000 (colour-science) between linear sRGB colours (N, 3) shown by :func:`display_rgb`."""
    import colour

    def lab(rgb):
        xyz = colour.RGB_to_XYZ(np.clip(display_rgb(rgb), 0.0, None), colour.RGB_COLOURSPACES["sRGB"],
                                apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, colour.RGB_COLOURSPACES["sRGB"].whitepoint)

    return np.asarray(colour.delta_E(lab(rgb_a), lab(rgb_b), method="CIE 2000"))


# --- scenes ------------------------------------------------------------------------------------

def load_env(width: int):
    """Courtyard map (float32 EnvMap) downsampled to ``width`` texels across."""
    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.io.images import read_image
    from bubblefit.model.scene import shipped_envmap

    px = read_image(shipped_envmap("courtyard")).pixels
    while px.shape[1] > width:
        px = downsample(px)
    return EnvMap.from_array(px)


def make_scene(size: int, effects: dict, *, thickness=500.0, roughness=0.01, drainage=None, background="black",
               rotation_deg=F.VIEW_ROTATION):
    bubble = {"roughness": roughness}
    if drainage is None:
        bubble["thickness_nm"] = thickness
    else:
        bubble["thickness"] = {"profile": "drainage", "top_nm": drainage[0], "bottom_nm": drainage[1],
                               "exponent": 1.0}
    return F.scene(camera={"type": "orthographic", "width": size, "height": size},
                   bubble=bubble,
                   lighting={"envmap": str(_env_path()), "rotation_deg": rotation_deg, "background": background},
                   effects=dict(effects))


def _env_path():
    from bubblefit.model.scene import shipped_envmap

    return shipped_envmap("courtyard")


def renderer(sc, env, dtype=None):
    """A zero-argument function rendering ``sc`` with ``env`` (jitted per config)."""
    from bubblefit.model.render import render

    cfg, _ = sc.config(env)
    p = sc.params() if dtype is None else sc.params(dtype=dtype)
    return lambda: render(p, cfg, env)


# --- the sweeps --------------------------------------------------------------------------------

def sweep_spectral(rows, q, env):
    from bubblefit.optics.spectral import spectral_basis

    ref = spectral_basis("reference")
    d_thin = np.linspace(100.0, 1500.0, 141 if q.quick else 561)
    d_thick = np.linspace(3000.0, 6000.0, 151 if q.quick else 601)
    c_thin, c_thick = film_colours(ref, d_thin), film_colours(ref, d_thick)
    for method, ks in (("uniform", q.uniform), ("fourier", q.fourier), ("harmonic", q.harmonic)):
        for k in ks:
            b = spectral_basis(method, k)
            e_thin = ciede2000(film_colours(b, d_thin), c_thin)
            e_thick = ciede2000(film_colours(b, d_thick), c_thick)
            err = float(np.mean(np.concatenate([e_thin, e_thick])))
            sc = make_scene(q.size, {"model": "physical", "interference": "airy", "filtering": "mirror",
                                     "spectral": {"method": method, "samples": k}}, thickness=4000.0)
            _, t, c = timed(renderer(sc, env), q.repeats)
            rows.append(dict(knob=f"spectral_{method}", setting=k, error=err, error_unit="CIEDE2000",
                             time_s=t, compile_s=c, error_thin=float(e_thin.mean()),
                             error_thick=float(e_thick.mean()),
                             note=f"physical render {q.size}px; max dE {max(e_thin.max(), e_thick.max()):.2f}"))
            F.log(f"spectral {method:8s} K={k:<4d} dE {err:7.3f} (thin {e_thin.mean():.3f}, thick "
                  f"{e_thick.mean():.3f})  {t * 1e3:8.1f} ms")


def reference_window(a: float, texel: float) -> int:
    """Half-size k of a level-0 window that holds the whole lobe of roughness ``a``: the
    reflected direction's spread is about ``sqrt(2) a``; +-5 of it, in texels."""
    return max(8, int(np.ceil(5.0 * np.sqrt(2.0) * a / texel)))


def sweep_filtering(rows, q):
    base = {"model": "paper", "interference": "off", "transmission": False}
    env = load_env(q.filter_env_width)
    for a in q.roughness:
        tag = f"a{a:g}"
        k_ref = reference_window(a, env.texel_angle)
        ref_sc = make_scene(q.size, {**base, "filtering": "window", "window": k_ref, "level": 0}, roughness=a)
        ref, _, _ = timed(renderer(ref_sc, env), 0)
        ref = np.asarray(ref)
        families = [("mirror", [None]), ("mipmap", q.nodes), ("window", q.windows), ("full", q.levels)]
        for method, values in families:
            for v in values:
                if method == "window" and v >= k_ref:
                    continue
                fx = {**base, "filtering": method}
                if method == "mipmap":
                    fx["nodes"] = v
                elif method == "window":
                    fx["window"], fx["level"] = v, 0
                elif method == "full":
                    fx["level"] = v
                sc = make_scene(q.size, fx, roughness=a)
                img, t, c = timed(renderer(sc, env), q.repeats)
                err = rel_rmse(img, ref)
                setting = {"mirror": "mirror", "mipmap": f"nodes={v}", "window": f"k={v}",
                           "full": f"level={v}"}[method]
                rows.append(dict(knob=f"filter_{method}_{tag}", setting=setting, error=err,
                                 error_unit="rel_rmse", time_s=t, compile_s=c,
                                 note=f"paper model, front+rear reflection, {q.size}px, map {env.width} wide; "
                                      f"reference: eq. 12 over +-{k_ref} texels of level 0"))
                F.log(f"filter a={a:<6g} {setting:10s} err {err:.2e}  {t * 1e3:8.1f} ms")


def sweep_envmap(rows, q):
    fx = {"model": "paper", "interference": "off", "transmission": False, "filtering": "mipmap", "nodes": 4}
    envs = {w: load_env(w) for w in q.env_widths}
    ref_w = max(q.env_widths)
    sc = make_scene(q.size, fx, roughness=0.01)
    ref, _, _ = timed(renderer(sc, envs[ref_w]), 0)
    for w in q.env_widths:
        img, t, c = timed(renderer(sc, envs[w]), q.repeats)
        err = rel_rmse(img, ref)
        rows.append(dict(knob="envmap_width", setting=w, error=err, error_unit="rel_rmse", time_s=t,
                         compile_s=c, note=f"mipmap 4 nodes, a=0.01, reference {ref_w} wide"))
        F.log(f"envmap width {w:<5d} err {err:.2e}  {t * 1e3:8.1f} ms")


def sweep_image(rows, q, env):
    fx = {"model": "paper", "interference": "two_beam", "transmission": False, "filtering": "mipmap", "nodes": 2,
          "spectral": {"method": "fourier", "samples": 8}}
    big = max(q.image_sizes) * 4
    ref_big, _, _ = timed(renderer(make_scene(big, fx, drainage=(200.0, 1500.0)), env), 0)
    ref_big = np.asarray(ref_big, dtype=np.float64)
    for s in q.image_sizes:
        f = big // s
        ref = ref_big.reshape(s, f, s, f, 3).mean(axis=(1, 3))
        img, t, c = timed(renderer(make_scene(s, fx, drainage=(200.0, 1500.0)), env), q.repeats)
        err = rel_rmse(img, ref)
        rows.append(dict(knob="image_size", setting=s, error=err, error_unit="rel_rmse", time_s=t, compile_s=c,
                         note=f"drainage 200-1500 nm; reference {big}px averaged to {s}px"))
        F.log(f"image {s:<4d}px err {err:.2e}  {t * 1e3:8.1f} ms")


def sweep_pixel_area(rows, q, env):
    """``[camera] samples_per_pixel``: point-sampled pixels against the box average a camera
    integrates (reference: a render 6x larger, averaged over 6x6 blocks, whose samples
    coincide with none of the tested grids), at the bubble's rim and across a drainage
    profile's fine fringes."""
    fx = {"model": "physical", "interference": "airy", "filtering": "mipmap", "nodes": 2,
          "spectral": {"method": "fourier", "samples": 8}}
    size = q.size
    ref_big, _, _ = timed(renderer(make_scene(6 * size, fx, drainage=(200.0, 3000.0)), env), 0)
    ref = np.asarray(ref_big, dtype=np.float64).reshape(size, 6, size, 6, 3).mean(axis=(1, 3))
    for spp in (1, 4, 9, 16):
        sc = make_scene(size, fx, drainage=(200.0, 3000.0))
        sc.data["camera"]["samples_per_pixel"] = spp
        img, t, c = timed(renderer(sc, env), q.repeats)
        err = rel_rmse(img, ref)
        rows.append(dict(knob="pixel_area", setting=spp, error=err, error_unit="rel_rmse", time_s=t, compile_s=c,
                         note=f"physical airy, drainage 200-3000 nm, {size}px; reference {6 * size}px box-averaged"))
        F.log(f"samples/pixel {spp:<3d} err {err:.2e}  {t * 1e3:8.1f} ms")


def sweep_precision(rows, q):
    import jax
    import jax.numpy as jnp

    from bubblefit.lighting.envmap import EnvMap, downsample
    from bubblefit.io.images import read_image
    from bubblefit.model.scene import shipped_envmap

    jax.config.update("jax_enable_x64", True)
    try:
        px = read_image(shipped_envmap("courtyard")).pixels
        while px.shape[1] > 256:
            px = downsample(px)
        fx = {"model": "physical", "interference": "airy", "filtering": "mipmap", "nodes": 2,
              "spectral": {"method": "uniform", "samples": 100}}
        sc = make_scene(q.size, fx, thickness=5000.0)
        out = {}
        for name, dt in (("float32", jnp.float32), ("float64", jnp.float64)):
            env = EnvMap.from_array(px, dtype=dt)
            out[name] = timed(renderer(sc, env, dtype=dt), q.repeats)
        ref = np.asarray(out["float64"][0], dtype=np.float64)
        for name in ("float32", "float64"):
            img, t, c = out[name]
            err = rel_rmse(img, ref)
            rows.append(dict(knob="precision", setting=name, error=err, error_unit="rel_rmse", time_s=t,
                             compile_s=c, note="physical airy, 5000 nm film, 100 samples; float64 is the reference"))
            F.log(f"precision {name} err {err:.2e}  {t * 1e3:8.1f} ms")
    finally:
        jax.config.update("jax_enable_x64", False)


def sweep_fit(rows, q, env):
    try:
        from bubblefit.inverse.fit import FitOptions, ImageSizes, SolverSettings, fit_photo
        from bubblefit.inverse import starts
        from bubblefit.capture.view import ORTHOGRAPHIC
    except ImportError as exc:  # the fit module is optional for this script
        F.log(f"fit sweep skipped: {exc}")
        return
    if not (q.fit_steps or q.fit_rtols):
        return
    size, truth = q.fit_size, 700.0
    # the photo's film transmits the complement of its reflection, as the fit assumes
    sc = make_scene(size, {"model": "paper", "transmission_tint": True}, thickness=truth, background="envmap")
    # What the fit is told: camera and lighting (the map's rotation), nothing about the bubble.
    known = F.scene(camera={"type": "orthographic", "width": size, "height": size},
                    lighting={"envmap": str(_env_path()), "rotation_deg": F.VIEW_ROTATION, "background": "envmap"},
                    effects={"model": "paper"})
    clean = np.asarray(renderer(sc, env)(), dtype=np.float64)
    rng = np.random.default_rng(1)
    noisy = clean + rng.normal(0.0, 2e-3, clean.shape) + rng.normal(0.0, 1.0, clean.shape) * np.sqrt(2e-4 * np.abs(clean))
    photo = np.round(np.clip(noisy, 0.0, 1.0) * 255.0) / 255.0
    disc = sc.camera().disc()
    t_true = float(sc.params().t)
    for knob, values in (("fit_max_steps", q.fit_steps), ("fit_rtol", q.fit_rtols)):
        for v in values:
            solver = SolverSettings(max_steps=v) if knob == "fit_max_steps" else SolverSettings(rtol=v, atol=v * 0.1)
            opts = FitOptions(disc=disc, parameters=starts(t=t_true), sizes=ImageSizes(fit=size, search=min(48, size)), model="paper", view=ORTHOGRAPHIC,
                              solver=solver)
            t0 = time.perf_counter()
            res = fit_photo(photo, env, options=opts, scene=known)
            first = time.perf_counter() - t0
            err = abs(float(res.params["thickness_nm"]) - truth)
            rows.append(dict(knob=knob, setting=v, error=err, error_unit="nm", time_s=float(res.time_s),
                             compile_s=max(first - float(res.time_s), 0.0),
                             note=f"{size}px synthetic 8-bit photo, true 700 nm; converged={res.converged}, "
                                  f"iterations={res.iterations}"))
            F.log(f"{knob} {v:<8g} |d - d_true| {err:8.3f} nm  {res.time_s:6.2f} s  it={res.iterations}")


# --- outputs -----------------------------------------------------------------------------------

def family(knob: str) -> str:
    if knob.startswith("filter_"):
        return "filtering_" + knob.rsplit("_", 1)[1]
    if knob.startswith("spectral_"):
        return "spectral"
    if knob.startswith("fit_"):
        return "fit"
    return knob


def write_csv(path: Path, rows) -> None:
    from bubblefit.io.images import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=COLUMNS)
            w.writeheader()
            for r in rows:
                w.writerow({k: ("" if r.get(k) is None else (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]))
                            for k in COLUMNS})


def read_csv(path: Path) -> list[dict]:
    """Rows of a results.csv with numbers parsed back."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            for k in ("error", "time_s", "compile_s", "error_thin", "error_thick"):
                r[k] = float(r[k]) if r.get(k) not in (None, "") else None
            rows.append(r)
    return rows


def plot_family(plt, ax, rows, fam):
    knobs = []
    for r in rows:
        if family(r["knob"]) == fam and r["knob"] not in knobs:
            knobs.append(r["knob"])
    unit = ""
    for knob in knobs:
        # The reference itself (error 0) has no place on log axes: a dashed line at its time.
        for r in rows:
            if r["knob"] == knob and r["error"] <= 0:
                ax.axvline(r["time_s"], ls="--", color="grey", lw=0.8)
                ax.annotate(f"reference {r['setting']}", (r["time_s"], 0.5), xycoords=("data", "axes fraction"),
                            fontsize=7, rotation=90, color="grey")
        pts = [r for r in rows if r["knob"] == knob and r["error"] > 0]
        if not pts:
            continue
        t = np.array([r["time_s"] for r in pts])
        e = np.array([r["error"] for r in pts])
        ax.plot(t, e, "o-" if len(pts) > 1 else "s", label=knob.replace("filter_", "").rsplit("_a", 1)[0])
        for r, ti, ei in zip(pts, t, e):
            ax.annotate(str(r["setting"]), (ti, ei), fontsize=7, xytext=(3, 3), textcoords="offset points")
        unit = pts[0]["error_unit"]
    from matplotlib.ticker import NullFormatter

    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("time per call (s, warm median)")
    ax.set_ylabel(f"error ({unit})")
    ax.set_title(fam.replace("_", " "))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


def write_plots(out: Path, rows):
    plt = F.matplotlib()
    fams = []
    for r in rows:
        if family(r["knob"]) not in fams:
            fams.append(family(r["knob"]))
    paths = []
    for fam in fams:
        fig, ax = plt.subplots(figsize=(5, 4))
        plot_family(plt, ax, rows, fam)
        paths.append(F.save_figure(fig, out, f"pareto_{fam}"))
    ncol = 3
    nrow = -(-len(fams) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow))
    for ax, fam in zip(np.ravel(axes), fams):
        plot_family(plt, ax, rows, fam)
    for ax in np.ravel(axes)[len(fams):]:
        ax.axis("off")
    fig.tight_layout()
    paths.append(F.save_figure(fig, out, "pareto", dpi=70))
    return paths


def write_banding(out: Path, q, env):
    """Strips of film colour 0-6000 nm per basis, and their CIEDE2000 against the reference."""
    from bubblefit.optics.spectral import spectral_basis

    plt = F.matplotlib()
    d = np.linspace(0.0, 6000.0, 600 if q.quick else 1200)
    bases = [("uniform", 10), ("uniform", 30), ("fourier", q.fourier[-1]), ("uniform", 100), ("reference", 800)]
    cols = {b: film_colours(spectral_basis(*b), d) for b in bases}
    ref = cols[("reference", 800)]
    fig, axes = plt.subplots(len(bases) + 1, 1, figsize=(7, 4.2),
                             gridspec_kw={"height_ratios": [1] * len(bases) + [2.2]})
    for ax, b in zip(axes, bases):
        strip = F.to_display(display_rgb(cols[b]))[None, :, :]
        ax.imshow(np.repeat(strip, 12, axis=0), aspect="auto", extent=(0, 6000, 0, 1))
        ax.set_yticks([])
        ax.set_xticks([])
        ax.set_ylabel(f"{b[0]} {b[1]}", rotation=0, ha="right", va="center", fontsize=8)
    ax = axes[-1]
    for b in bases[:-1]:
        ax.plot(d, ciede2000(cols[b], ref), lw=0.8, label=f"{b[0]} {b[1]}")
    ax.set_xlim(0, 6000)
    ax.set_yscale("log")
    ax.set_ylim(1e-3, 100)
    ax.set_xlabel("film thickness (nm), normal incidence, n = 1.4")
    ax.set_ylabel("CIEDE2000")
    ax.legend(fontsize=6, ncol=4, loc="lower right")
    fig.tight_layout()
    return F.save_figure(fig, out, "banding", dpi=90)


def fit_lobes(k: int, illuminant: str = "D65", max_nfev: int = 60):
    """Least-squares fit of K shared Gaussian lobes in wavenumber to the sRGB weight densities
    (the table :data:`bubblefit.optics.spectral.FOURIER_LOBES`): centres (nm) and deviations (1/um),
    with the weights solved linearly for each trial (variable projection)."""
    from scipy.optimize import least_squares

    from bubblefit.optics import spectral

    nu, dens = spectral._wavenumber_density(illuminant)
    lo, hi = 1.0 / spectral.LAMBDA_MAX, 1.0 / spectral.LAMBDA_MIN
    scale = 1e-4

    def design(x):
        mu, sig = x[:k] * scale, np.exp(x[k:]) * scale
        return np.exp(-0.5 * ((nu[:, None] - mu) / sig) ** 2) / (np.sqrt(2 * np.pi) * sig)

    def resid(x):
        g = design(x)
        w, *_ = np.linalg.lstsq(g, dens, rcond=None)
        return ((g @ w - dens) * np.sqrt(nu[1] - nu[0])).ravel()

    x0 = np.concatenate([np.linspace(lo, hi, k + 2)[1:-1] / scale, np.log(np.full(k, 0.6 * (hi - lo) / k) / scale)])
    bounds = (np.concatenate([np.full(k, (lo - 1e-4) / scale), np.full(k, np.log(0.2))]),
              np.concatenate([np.full(k, (hi + 1e-4) / scale), np.full(k, np.log(5.0))]))
    r = least_squares(resid, x0, method="trf", bounds=bounds, max_nfev=max_nfev, x_scale="jac")
    order = np.argsort(r.x[:k])
    lam = [round(float(1.0 / (v * scale)), 3) for v in r.x[:k][order]]
    sig = [round(float(np.exp(v) * scale * 1e3), 5) for v in r.x[k:][order]]
    return tuple(lam), tuple(sig), float(np.sqrt(np.mean(r.fun**2)))


class Settings:
    def __init__(self, quick: bool):
        self.quick = quick
        self.size = 24 if quick else 48
        self.image_size = None
        self.repeats = 2 if quick else 3
        self.uniform = (3, 10, 100) if quick else (3, 5, 10, 30, 100)
        self.fourier = (3, 8) if quick else (3, 5, 6, 8, 12, 16)
        self.harmonic = (4, 16) if quick else (4, 6, 8, 12, 16, 32)
        self.roughness = (0.02,) if quick else (0.005, 0.02, 0.1)
        self.nodes = (1, 4) if quick else (1, 2, 4, 6)
        self.windows = (1, 4) if quick else (1, 2, 4, 8, 16, 32, 64)
        self.levels = (3, 1) if quick else (4, 3, 2)
        self.filter_env_width = 256 if quick else 1024
        self.env_widths = (64, 256) if quick else (64, 128, 256, 512, 1024)
        self.image_sizes = (16, 32) if quick else (32, 64, 128)
        self.fit_size = 48
        self.fit_steps = () if quick else (1, 3, 10, 80)  # each fit compiles; too slow for --quick
        self.fit_rtols = () if quick else (1e-1, 1e-3, 1e-5)


def main(argv=None) -> int:
    p = F.parser("accuracy_vs_time", __doc__.split("\n")[0])
    p.add_argument("--skip", default="", help="comma-separated sweeps to skip "
                   "(spectral, filtering, envmap, image, fit, precision, pixel_area)")
    p.add_argument("--replot", action="store_true", help="redraw the plots from DIR/results.csv and exit")
    p.add_argument("--fit-lobes", type=int, default=None, metavar="K",
                   help="print a refitted FOURIER_LOBES entry for K lobes and exit")
    args = p.parse_args(argv)
    if args.fit_lobes:
        lam, sig, rms = fit_lobes(args.fit_lobes)
        print(f"    {args.fit_lobes}: ({lam},\n        {sig}),  # rms {rms:.3g}")
        return 0
    F.setup_jax()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    q = Settings(args.quick)
    if args.size:
        q.size = args.size
    skip = set(filter(None, args.skip.split(",")))
    t_start = time.perf_counter()
    rows: list[dict] = []
    if args.replot:
        rows = read_csv(out / "results.csv")
        write_plots(out, rows)
        if not q.quick:
            F.publish(out / "pareto.png", "accuracy_pareto", not args.no_copy)
        return 0
    env = load_env(256)
    sweeps = [("spectral", lambda: sweep_spectral(rows, q, env)),
              ("filtering", lambda: sweep_filtering(rows, q)),
              ("envmap", lambda: sweep_envmap(rows, q)),
              ("image", lambda: sweep_image(rows, q, env)),
              ("precision", lambda: sweep_precision(rows, q)),
              ("fit", lambda: sweep_fit(rows, q, env)),
              ("pixel_area", lambda: sweep_pixel_area(rows, q, env))]
    timings = {}
    for name, fn in sweeps:
        if name in skip:
            continue
        t0 = time.perf_counter()
        fn()
        timings[name] = time.perf_counter() - t0
        write_csv(out / "results.csv", rows)  # partial results survive an interruption
    write_csv(out / "results.csv", rows)
    plots = write_plots(out, rows)
    banding = write_banding(out, q, env)
    from bubblefit.cli.common import write_json

    write_json(out / "summary.json", {"quick": q.quick, "sweep_seconds": timings,
                                      "total_seconds": time.perf_counter() - t_start,
                                      "plots": [str(x) for x in plots + [banding]]})
    if not q.quick:
        F.publish(out / "pareto.png", "accuracy_pareto", not args.no_copy)
        F.publish(banding, "accuracy_banding", not args.no_copy)
    F.log(f"wrote {out / 'results.csv'} ({len(rows)} points) in {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
