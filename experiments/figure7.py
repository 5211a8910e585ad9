"""Figure 7 of the paper: bubbles with roughness a = 0.01 and 0.02 (f = 0.3), and their
filtered environment maps.

The bubbles use the paper model (eqs. 1-14) on the shipped courtyard map (HDR, not the
paper's clipped bulb photo). The "filtered environment map" of a roughness ``a`` is
drawn as an equirectangular image whose pixel in direction ``w`` is
``filtering.specular(env, n = w, w_o = w, a)``: the Ward-filtered radiance (eq. 12,
r_s = 1, mipmap quadrature) that a film facing ``w`` reflects back along ``w``, i.e. the
map blurred by the lobe, as the paper's Fig. 7c-d shows.

    python experiments/figure7.py [--out DIR] [--size 256]
"""

from __future__ import annotations

import _figures as F


def filtered_map(env, a: float, height: int):
    """(height, 2 height, 3) equirectangular image of the filtered map for roughness ``a``."""
    import jax.numpy as jnp
    import numpy as np

    from bubblefit.lighting.envmap import texel_directions
    from bubblefit.lighting.filtering import FilterConfig, specular

    dirs = jnp.asarray(texel_directions(height, 2 * height).reshape(-1, 3), dtype=jnp.float32)
    out = specular(env, dirs, dirs, jnp.float32(a), FilterConfig("mipmap", nodes=6), normalize=False)
    return np.asarray(out, dtype=np.float64).reshape(height, 2 * height, 3)


def main(argv=None) -> int:
    args = F.parser("figure7", __doc__.split("\n")[0]).parse_args(argv)
    F.setup_jax()
    from bubblefit.model.scene import shipped_envmap

    size = args.size or (96 if args.quick else 256)
    out = F.Path(args.out)
    envpath = str(shipped_envmap("courtyard"))
    roughness = (0.01, 0.02)
    settings = {"envmap": "courtyard", "size": size, "f": 0.3, "t": 0.972, "thickness_nm": 500.0, "model": "paper", "spectral": "uniform/100",
                "camera": F.view_camera(size), "rotation_deg": F.VIEW_ROTATION,
                "roughness": list(roughness),
                "filtered_map": "specular(env, n=w, w_o=w, a), r_s = 1, mipmap 6x6 nodes, per map direction w"}
    env = None
    bubbles, maps, times = [], [], []
    for a in roughness:
        sc = F.scene(camera=F.view_camera(size), bubble={"roughness": a, "f": 0.3, "t": 0.972, "thickness_nm": 500.0},
                     lighting={"envmap": envpath, "rotation_deg": F.VIEW_ROTATION}, effects={"model": "paper", "spectral": {"method": "uniform", "samples": 100}})
        env = env or sc.load_envmap()
        img, dt = F.render(sc, env)
        F.log(f"a = {a}: rendered {size}x{size} in {dt:.2f} s")
        bubbles.append(img)
        times.append(dt)
        maps.append(filtered_map(env, a, 128 if not args.quick else 64))
    exp_b = F.exposure_for(*bubbles)
    exp_m = F.exposure_for(*maps, percentile=99.5)
    for a, img, m in zip(roughness, bubbles, maps):
        F.save(out, f"bubble_a{a:.2f}", img, exp_b)
        F.save(out, f"filtered_a{a:.2f}", m, exp_m)

    plt = F.matplotlib()
    fig, ax = plt.subplots(2, 2, figsize=(9, 6.4), gridspec_kw={"width_ratios": [1, 2]})
    for i, a in enumerate(roughness):
        ax[i, 0].imshow(F.to_display(bubbles[i], exp_b))
        ax[i, 0].set_title(f"{'ab'[i]}) a = {a}, f = 0.3")
        ax[i, 1].imshow(F.to_display(maps[i], exp_m))
        ax[i, 1].set_title(f"{'cd'[i]}) filtered map, a = {a}")
        for x in ax[i]:
            x.set_axis_off()
    fig.suptitle("Figure 7: paper model on the courtyard map; filtered map = specular(n = w_o = w) per direction w",
                 fontsize=9)
    png = F.save_figure(fig, out, "figure7", dpi=80)
    settings["render_s"] = times
    F.write_settings(out, settings)
    dst = F.publish(png, "figure7", not args.no_copy)
    print(f"wrote {png}" + (f" and {dst}" if dst else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
