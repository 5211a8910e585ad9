"""The paper's indoor model (eqs. 2-3): a bubble in a dark room lit by one point light.

Eq. (3) sums Ward's BRDF (eq. 1) over the lights; eq. (2) adds the front film, the rear
film (times t^2) and the background (times t^4, black here). No environment map. The
grid varies the roughness a (columns) and the diffuse-to-specular ratio f (rows) with
the light up and to the left of the camera; the highlight's size grows with a and the
diffuse glow with f. The plot is a row of pixels through the highlight, against the
prediction of eq. (3) at the same film points computed here independently in numpy
(front film only, with two-beam interference off).

    python experiments/point_light.py [--out DIR] [--size 160]
"""

from __future__ import annotations

import _figures as F

ROUGHNESS = (0.02, 0.05, 0.15)
RATIOS = (0.0, 0.3, 1.0)
LIGHT = (-0.5, 0.5, 1.0)
RADIANCE = 1.0


def disc(size: int) -> list:
    """The bubble's disc [cx, cy, r] in pixels."""
    return [size / 2, size / 2, 0.45 * size]


def ward_eq3(size: int, a: float, f: float, t: float = 0.972):
    """Eq. (1)/(3) for the front film of an orthographic unit bubble on ``disc(size)``, (size, size)."""
    import numpy as np

    r_s = (1 - t) / (1 + f)
    r_d = (1 - t) - r_s
    c, r = disc(size)[0], disc(size)[2]
    jj, ii = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    x = (jj - c) / r
    y = -(ii - c) / r
    rho2 = x * x + y * y
    z = np.sqrt(np.clip(1 - rho2, 0, None))
    n = np.stack([x, y, z], -1)
    wo = np.array([0.0, 0.0, 1.0])
    l = np.asarray(LIGHT) / np.linalg.norm(LIGHT)
    h = (wo + l) / np.linalg.norm(wo + l)
    ci, cr, ch = n @ l, n @ wo, n @ h
    tan2 = (1 - ch**2) / np.maximum(ch**2, 1e-12)
    ok = (ci > 0) & (cr > 0) & (rho2 < 1)
    spec = np.exp(-tan2 / a**2) / (4 * np.pi * a * a * np.sqrt(np.maximum(ci * cr, 1e-12)))
    val = (r_d / np.pi + r_s * spec) * np.maximum(ci, 0) * RADIANCE
    return np.where(ok, val, np.nan)


def main(argv=None) -> int:
    args = F.parser("point_light", __doc__.split("\n")[0]).parse_args(argv)
    F.setup_jax()
    import numpy as np

    size = args.size or (80 if args.quick else 160)
    out = F.Path(args.out)
    grid, times = {}, []
    for f in RATIOS:
        for a in ROUGHNESS:
            sc = F.scene(camera={"width": size, "height": size, "disc": disc(size)},
                         bubble={"roughness": a, "f": f, "t": 0.972, "thickness_nm": 500.0},
                         lighting={"point_lights": [{"direction": list(LIGHT), "radiance": [RADIANCE] * 3}],
                                   "background": "black"},
                         effects={"model": "paper", "spectral": {"method": "uniform", "samples": 100}})
            img, dt = F.render(sc)
            times.append(dt)
            grid[(f, a)] = img
            F.log(f"f = {f}, a = {a}: {size}x{size} in {dt:.2f} s")
    # Eq. (3) check: front film only, interference off.
    check = {}
    for a in ROUGHNESS:
        sc = F.scene(camera={"width": size, "height": size, "disc": disc(size)},
                     bubble={"roughness": a, "f": 0.3, "t": 0.972, "thickness_nm": 500.0},
                     lighting={"point_lights": [{"direction": list(LIGHT), "radiance": [RADIANCE] * 3}],
                               "background": "black"},
                     effects={"model": "paper", "interference": "off", "rear_reflection": False})
        img, _ = F.render(sc)
        ref = ward_eq3(size, a, 0.3)
        inside = np.isfinite(ref)
        rel = float(np.max(np.abs(img[..., 0][inside] - ref[inside])) / np.nanmax(ref))
        check[a] = (img[..., 0], ref, rel)
        F.log(f"eq. (3) check a = {a}: max |render - numpy| / peak = {rel:.2e}")
    exp = F.exposure_for(*grid.values(), percentile=99.9)
    for (f, a), img in grid.items():
        F.save(out, f"bubble_f{f}_a{a}", img, exp)

    plt = F.matplotlib()
    fig = plt.figure(figsize=(10, 8.6))
    gs = fig.add_gridspec(len(RATIOS) + 1, len(ROUGHNESS), height_ratios=[3] * len(RATIOS) + [2.2])
    for i, f in enumerate(RATIOS):
        for j, a in enumerate(ROUGHNESS):
            ax = fig.add_subplot(gs[i, j])
            ax.imshow(F.to_display(grid[(f, a)], exp))
            ax.set_title(f"a = {a}, f = {f}", fontsize=9)
            ax.set_axis_off()
    ax = fig.add_subplot(gs[-1, :])
    row = None
    for a in ROUGHNESS:
        img, ref, rel = check[a]
        row = row if row is not None else int(np.nanargmax(ref) // size)
        xs = np.arange(size)
        ax.plot(xs, img[row], lw=1.2, label=f"render a = {a} (max rel. diff {rel:.1e})")
        ax.plot(xs, ref[row], "k:", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel("pixel column through the highlight")
    ax.set_ylabel("radiance (front film)")
    ax.legend(fontsize=8)
    ax.set_title("render (coloured) vs eq. (3) in numpy (dotted)", fontsize=9)
    fig.suptitle("Indoor model, eqs. (2)-(3): one point light, dark room", fontsize=10)
    fig.tight_layout()
    png = F.save_figure(fig, out, "point_light", dpi=70)
    F.write_settings(out, {"size": size, "light_direction": list(LIGHT), "radiance": RADIANCE,
                           "roughness": list(ROUGHNESS), "f": list(RATIOS), "model": "paper", "exposure": exp,
                           "eq3_max_relative_difference": {str(a): check[a][2] for a in ROUGHNESS},
                           "render_s": times})
    dst = F.publish(png, "point_light", not args.no_copy)
    print(f"wrote {png}" + (f" and {dst}" if dst else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
