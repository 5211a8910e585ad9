"""Figure 9 of the paper: the same bubble with film thickness d = 260, 460, 860, 1660, 3260 nm.

Paper model (eqs. 1-14: two-beam interference of eq. 10 integrated over 100 uniform
spectral samples, as the paper did), a = 0.01, f = 0.3, on the shipped courtyard map.
Thin films show strong first- and second-order colours; by 3 um the colours wash out
to the grey of an incoherent film. One exposure for all five images, so the paper's
remark that interference brightens the bubble can be seen. The middle row shows the
front and rear reflections alone (no background, a brighter exposure). The bottom row is the
interference factor of eq. (10) at normal incidence (the colour that multiplies the
filtered radiance).

    python experiments/figure9.py [--out DIR] [--size 192]
"""

from __future__ import annotations

import _figures as F

THICKNESSES = (260.0, 460.0, 860.0, 1660.0, 3260.0)


def main(argv=None) -> int:
    args = F.parser("figure9", __doc__.split("\n")[0]).parse_args(argv)
    F.setup_jax()
    import numpy as np

    from bubblefit.optics.chart import interference_colours
    from bubblefit.model.scene import shipped_envmap
    from bubblefit.optics.spectral import spectral_basis

    size = args.size or (96 if args.quick else 192)
    out = F.Path(args.out)
    envpath = str(shipped_envmap("courtyard"))
    env = None
    imgs, refl, times = [], [], []
    for d in THICKNESSES:
        for only_reflection in (False, True):
            fx = {"model": "paper", "interference": "two_beam", "spectral": {"method": "uniform", "samples": 100}}
            lighting = {"envmap": envpath, "rotation_deg": F.VIEW_ROTATION}
            if only_reflection:
                fx["transmission"] = False
                lighting["background"] = "black"
            sc = F.scene(camera=F.view_camera(size),
                         bubble={"roughness": 0.01, "f": 0.3, "t": 0.972, "thickness_nm": d},
                         lighting=lighting, effects=fx)
            env = env or sc.load_envmap()
            img, dt = F.render(sc, env)
            F.log(f"d = {d:.0f} nm{' (reflection only)' if only_reflection else ''}: {size}x{size} in {dt:.2f} s")
            (refl if only_reflection else imgs).append(img)
            times.append(dt)
    exp = F.exposure_for(*imgs)
    exp_r = F.exposure_for(*refl, percentile=99.5)
    for d, img, r in zip(THICKNESSES, imgs, refl):
        F.save(out, f"bubble_d{d:.0f}", img, exp)
        F.save(out, f"reflection_d{d:.0f}", r, exp_r)
    factors = interference_colours(np.asarray(THICKNESSES), model="paper",
                                   basis=spectral_basis("uniform", 100))

    plt = F.matplotlib()
    fig, ax = plt.subplots(3, 5, figsize=(12, 6.0), gridspec_kw={"height_ratios": [5, 5, 1]})
    for i, (d, img) in enumerate(zip(THICKNESSES, imgs)):
        ax[0, i].imshow(F.to_display(img, exp))
        ax[0, i].set_title(f"d = {d:.0f} nm", fontsize=10)
        ax[1, i].imshow(F.to_display(refl[i], exp_r))
        ax[1, i].set_title("reflections only (x%.0f)" % (exp_r / exp), fontsize=8)
        sw = np.ones((8, 40, 3)) * factors[i] / max(float(factors.max()), 1e-9)
        ax[2, i].imshow(F.to_display(sw))
        ax[2, i].set_title("eq. (10) factor " + ", ".join(f"{v:.2f}" for v in factors[i]), fontsize=7)
        for a in ax[:, i]:
            a.set_axis_off()
    fig.suptitle("Figure 9: film thickness d (paper model, 100 spectral samples, a = 0.01, f = 0.3)", fontsize=10)
    png = F.save_figure(fig, out, "figure9", dpi=80)
    F.write_settings(out, {"envmap": "courtyard", "size": size, "thickness_nm": list(THICKNESSES), "roughness": 0.01,
                           "f": 0.3, "t": 0.972, "model": "paper", "spectral": "uniform/100", "exposure": exp, "exposure_reflection_only": exp_r,
                           "camera": F.view_camera(size), "rotation_deg": F.VIEW_ROTATION,
                           "interference_factor_rgb": factors.tolist(), "render_s": times})
    dst = F.publish(png, "figure9", not args.no_copy)
    print(f"wrote {png}" + (f" and {dst}" if dst else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
