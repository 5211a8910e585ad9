"""Spectral sampling (paper sec. 3.4): 10, 30 and 100 uniform samples, and the banding of
thick films.

The paper saw interference bands with 10 and 30 wavelength samples once the film got
thick, and none with 100. Two views of the same effect:

* strips of the eq. (10) interference colour against thickness 0-8000 nm for 10, 30 and
  100 uniform samples and the 800-sample reference, with the colour error against the
  reference (max over RGB, relative to the reference's mean) against thickness;
* a draining bubble (thickness 150 nm at the top to 8000 nm at the bottom, reflections
  only, paper model) rendered with each sampling: with too few samples, false colour
  bands reappear low on the bubble where the real colours have washed out to grey.

The JSON gives, per sampling, the thickness beyond which the error first exceeds 0.05.

    python experiments/spectral_sampling.py [--out DIR] [--size 160]
"""

from __future__ import annotations

import _figures as F

SAMPLINGS = (("uniform", 10), ("uniform", 30), ("uniform", 100), ("reference", 800))
THRESHOLD = 0.05


def main(argv=None) -> int:
    args = F.parser("spectral_sampling", __doc__.split("\n")[0]).parse_args(argv)
    F.setup_jax()
    import numpy as np

    from bubblefit.optics.chart import interference_colours
    from bubblefit.model.scene import shipped_envmap
    from bubblefit.optics.spectral import spectral_basis

    size = args.size or (80 if args.quick else 160)
    out = F.Path(args.out)
    d = np.linspace(0.0, 8000.0, 501 if args.quick else 1001)
    strips = {}
    for method, k in SAMPLINGS:
        strips[(method, k)] = interference_colours(d, model="paper", basis=spectral_basis(method, k))
    ref = strips[("reference", 800)]
    scale = float(np.mean(ref))
    errors, onset = {}, {}
    for (method, k), c in strips.items():
        err = np.max(np.abs(c - ref), axis=1) / scale
        errors[f"{method}/{k}"] = err
        bad = np.nonzero(err > THRESHOLD)[0]
        onset[f"{method}/{k}"] = float(d[bad[0]]) if bad.size else None
        F.log(f"{method}/{k}: error > {THRESHOLD} from {onset[f'{method}/{k}']} nm; max {err.max():.3f}")

    envpath = str(shipped_envmap("courtyard"))
    env = None
    imgs, times = [], []
    for method, k in SAMPLINGS:
        sc = F.scene(camera=F.view_camera(size),
                     bubble={"roughness": 0.01, "f": 0.3, "t": 0.972,
                             "thickness": {"profile": "drainage", "top_nm": 150.0, "bottom_nm": 8000.0,
                                           "exponent": 1.0}},
                     lighting={"envmap": envpath, "rotation_deg": F.VIEW_ROTATION, "background": "black"},
                     effects={"model": "paper", "interference": "two_beam", "transmission": False,
                              "spectral": {"method": method, "samples": k}})
        env = env or sc.load_envmap()
        img, dt = F.render(sc, env)
        F.log(f"{method}/{k}: bubble {size}x{size} in {dt:.2f} s")
        imgs.append(img)
        times.append(dt)
    exp = F.exposure_for(*imgs, percentile=99.5)
    for (method, k), img in zip(SAMPLINGS, imgs):
        F.save(out, f"bubble_{method}{k}", img, exp)

    plt = F.matplotlib()
    fig = plt.figure(figsize=(12, 6.4))
    gs = fig.add_gridspec(3, 4, height_ratios=[4, 1.6, 2.2])
    cmax = max(float(c.max()) for c in strips.values())
    for i, ((method, k), img) in enumerate(zip(SAMPLINGS, imgs)):
        a = fig.add_subplot(gs[0, i])
        a.imshow(F.to_display(img, exp))
        a.set_title(f"{k} samples" + (" (reference)" if method == "reference" else ""), fontsize=10)
        a.set_axis_off()
    a = fig.add_subplot(gs[1, :])
    rows = np.stack([np.repeat(strips[s][None], 12, axis=0) for s in SAMPLINGS]).reshape(-1, len(d), 3)
    a.imshow(F.to_display(rows / cmax), aspect="auto", extent=(d[0], d[-1], len(SAMPLINGS), 0))
    a.set_yticks(np.arange(len(SAMPLINGS)) + 0.5, [f"{k}" for _, k in SAMPLINGS])
    a.set_ylabel("samples")
    a.set_title("eq. (10) interference colour against thickness (normal incidence)", fontsize=9)
    a = fig.add_subplot(gs[2, :])
    for (method, k) in SAMPLINGS[:-1]:
        a.plot(d, errors[f"{method}/{k}"], label=f"{k} samples", lw=1)
    a.axhline(THRESHOLD, color="k", lw=0.6, ls="--")
    a.set_yscale("log")
    a.set_ylim(1e-4, 2)
    a.set_xlim(d[0], d[-1])
    a.set_xlabel("film thickness d (nm)")
    a.set_ylabel("colour error vs reference")
    a.legend(fontsize=8, loc="lower right")
    fig.suptitle("Spectral sampling (sec. 3.4): too few samples band on thick films; draining bubble 150-8000 nm",
                 fontsize=10)
    fig.tight_layout()
    png = F.save_figure(fig, out, "spectral_sampling", dpi=75)
    F.write_settings(out, {"envmap": "courtyard", "size": size, "model": "paper",
                           "thickness": {"profile": "drainage", "top_nm": 150.0, "bottom_nm": 8000.0, "exponent": 1.0},
                           "samplings": [f"{m}/{k}" for m, k in SAMPLINGS], "error_threshold": THRESHOLD,
                           "error_onset_nm": onset,
                           "max_error": {k: float(v.max()) for k, v in errors.items()}, "render_s": times})
    dst = F.publish(png, "spectral_sampling", not args.no_copy)
    print(f"wrote {png}" + (f" and {dst}" if dst else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
