"""The figures of a fit's page (matplotlib, written through :mod:`bubblefit.io.atomic`).

Each figure has a title, and every false-colour image a colour bar with its unit:
radiance residuals in the photo's linear units (1 = the file's white), thicknesses and
their standard errors in nm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["photo_render_figure", "residual_figure", "thickness_figure", "map_figure", "profile_figure", "drainage_band"]

#: Font size of labels and titles: legible at the page's 1:1 scale.
FONT = 12


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": FONT, "axes.titlesize": FONT + 1})
    return plt


def _save(fig, path: Path) -> Path:
    from ..io.atomic import atomic_path, check_png

    with atomic_path(path, check=check_png) as tmp:
        fig.savefig(tmp, dpi=100, format="png", bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _display(img: np.ndarray) -> np.ndarray:
    from ..io.images import srgb_encode

    return np.clip(srgb_encode(np.clip(np.nan_to_num(img), 0.0, 1.0)), 0.0, 1.0)


def _disc_circle(ax, disc):
    if disc:
        import matplotlib.patches as mp

        ax.add_patch(mp.Circle((disc["cx"] - 0.5, disc["cy"] - 0.5), disc["r"], fill=False, ec="w", lw=0.8, ls=":"))


def photo_render_figure(path: Path, photo: np.ndarray | None, render: np.ndarray | None, disc: dict | None,
                        photo_title: str = "photo") -> Path:
    """Photo and fitted render side by side, as sRGB, with the fitted disc dotted."""
    plt = _plt()
    panels = [(photo, photo_title), (render, "fitted render")]
    panels = [(img, t) for img, t in panels if img is not None]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 5.0), squeeze=False)
    for ax, (img, title) in zip(axes[0], panels):
        ax.imshow(_display(img), interpolation="nearest")
        _disc_circle(ax, disc)
        ax.set_title(title)
        ax.set_axis_off()
    return _save(fig, path)


def residual_figure(path: Path, residual: np.ndarray, rms: float | None) -> Path:
    """``photo - render`` averaged over the three channels, on a symmetric scale (99th
    percentile of its magnitude), with a colour bar in the photo's linear units."""
    plt = _plt()
    res = np.nanmean(residual, axis=-1)
    lim = max(float(np.nanpercentile(np.abs(res), 99)), 1e-6)
    fig, ax = plt.subplots(figsize=(6.4, 5.0))
    im = ax.imshow(res, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
    ax.set_axis_off()
    ax.set_title("residual: photo - render" + ("" if rms is None else f" (rms {rms:.3g})"))
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03,
                 label="mean of R, G, B (linear radiance; 1 = the photo's white)")
    return _save(fig, path)


def map_figure(path: Path, img: np.ndarray, title: str, cmap: str, label: str, disc: dict | None = None) -> Path:
    """One map (NaN off the bubble) with a title and a colour bar labelled with its unit."""
    return _maps_figure(path, [(img, title, cmap, label)], disc)


def thickness_figure(path: Path, tmap: np.ndarray, stderr: np.ndarray | None, disc: dict | None) -> Path:
    """The fitted front-film thickness map and its standard error, each with a colour bar in nm."""
    panels = [(tmap, "film thickness", "viridis", "thickness (nm)")]
    if stderr is not None:
        panels.append((stderr, "its standard error", "magma", "standard error (nm)"))
    return _maps_figure(path, panels, disc)


def _maps_figure(path: Path, panels: list, disc: dict | None) -> Path:
    plt = _plt()
    fig, axes = plt.subplots(1, len(panels), figsize=(6.4 * len(panels), 5.0), squeeze=False)
    for ax, (img, title, cmap, label) in zip(axes[0], panels):
        m = np.ma.masked_invalid(img)
        lo, hi = (np.nanpercentile(img, [1, 99]) if np.isfinite(img).any() else (0.0, 1.0))
        im = ax.imshow(m, cmap=cmap, vmin=lo, vmax=max(hi, lo + 1e-6), interpolation="nearest")
        _disc_circle(ax, disc)
        ax.set_title(title)
        ax.set_axis_off()
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03, label=label)
    return _save(fig, path)


def drainage_band(y: np.ndarray, profile: tuple, cov: np.ndarray | None, model_error_nm: float) -> tuple:
    """``(d(y), sigma(y))`` of :func:`bubblefit.model.thickness.drainage_profile`: the
    standard error propagated from the covariance of (top, bottom, exponent) by the
    profile's derivatives (central differences), with the Type B thickness error in
    quadrature (``thickness_model_error_nm``, docs/design.md "Fitting")."""
    from ..model.thickness import drainage_profile

    f = lambda p: np.asarray(drainage_profile(y, *p), np.float64)
    p = np.asarray(profile, np.float64)
    d = f(p)
    var = np.full_like(d, model_error_nm ** 2)
    if cov is not None and np.all(np.isfinite(cov)):
        jac = []
        for k in range(3):
            h = 1e-3 * max(abs(p[k]), 1.0)
            e = np.zeros(3)
            e[k] = h
            jac.append((f(p + e) - f(p - e)) / (2 * h))
        jac = np.stack(jac, axis=-1)
        var = var + np.einsum("ni,ij,nj->n", jac, cov, jac)
    return d, np.sqrt(var)


def profile_figure(path: Path, y: np.ndarray, d: np.ndarray, sigma: np.ndarray | None, label: str,
                   truth: tuple | None = None) -> Path:
    """Thickness against height on the bubble with a one-standard-error band (and the truth, when known)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 5.0))
    ok = np.isfinite(d)
    if sigma is not None:
        s = np.where(np.isfinite(sigma), sigma, 0.0)
        med = float(np.median(s[ok])) if ok.any() else float("nan")
        ax.fill_betweenx(y[ok], (d - s)[ok], (d + s)[ok], color="C1", alpha=0.3, lw=0,
                         label=f"± 1 standard error (median {med:.2g} nm)")
    ax.plot(d[ok], y[ok], "C1-", lw=2, label=label)
    if truth is not None:
        ty, td = truth
        ax.plot(td, ty, "k--", lw=1.5, label="true")
    ax.set_ylim(-1, 1)
    ax.set_xlabel("film thickness (nm)")
    ax.set_ylabel("height y on the bubble (radii; +1 = top)")
    ax.set_title("thickness profile")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    return _save(fig, path)
