"""Shared helpers of the paper-figure scripts in ``experiments/``.

Every script renders with the public API (:func:`bubblefit.model.scene.render_scene` on a
scene given as data), writes its PNGs and a ``settings.json`` to ``--out`` (default
``experiments/results/<name>``), and copies one small summary PNG into
``experiments/figures/`` for the README.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FIGURES = HERE / "figures"


def parser(name: str, description: str) -> argparse.ArgumentParser:
    """An argument parser with ``--out`` (default ``experiments/results/NAME``) and ``--quick``."""
    p = argparse.ArgumentParser(prog=f"experiments/{name}.py", description=description)
    p.add_argument("--out", default=str(HERE / "results" / name), help="output folder (default: %(default)s)")
    p.add_argument("--size", type=int, default=None, help="image size in pixels (default: the script's)")
    p.add_argument("--quick", action="store_true", help="small images, for a smoke test")
    p.add_argument("--no-copy", action="store_true", help="do not copy the summary PNG into experiments/figures/")
    return p


def setup_jax() -> None:
    """Use bubblefit's persistent compilation cache, as the CLI does."""
    from bubblefit.io.jaxcache import jax_setup

    jax_setup()


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def to_display(img: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear (H, W, 3) radiance times ``exposure`` -> sRGB-encoded floats in [0, 1] for plotting."""
    from bubblefit.io.images import srgb_encode

    return np.clip(srgb_encode(np.clip(np.nan_to_num(img) * exposure, 0.0, 1.0)), 0.0, 1.0)


def exposure_for(*imgs: np.ndarray, percentile: float = 99.0, target: float = 0.9) -> float:
    """One exposure for several linear images: their joint ``percentile`` maps to ``target``."""
    vals = np.concatenate([np.asarray(i, dtype=np.float64).ravel() for i in imgs])
    hi = float(np.percentile(vals, percentile))
    return target / hi if hi > 0 else 1.0


#: The view of the shipped courtyard map used by the figures (sky, trees and a building).
VIEW_ROTATION = 180.0


def view_camera(size: int) -> dict:
    """Camera table: a perspective view of a unit bubble 4 units away, 40 degree field."""
    return {"type": "perspective", "width": size, "height": size, "origin": [0.0, 0.0, 4.0],
            "target": [0.0, 0.2, 0.0], "fov_deg": 40.0}


def scene(**tables):
    """A :class:`bubblefit.model.scene.Scene` from keyword tables (``camera=..., bubble=...``)."""
    from bubblefit.model.scene import Scene

    return Scene.from_dict({k: v for k, v in tables.items() if v is not None})


def render(sc, env=None, background=None):
    """Render a scene to a numpy (H, W, 3) linear image, and the seconds it took."""
    from bubblefit.model.scene import render_scene

    t0 = time.perf_counter()
    img = render_scene(sc, background=background, env=env)
    return np.asarray(img, dtype=np.float64), time.perf_counter() - t0


def save(out: Path, name: str, img: np.ndarray, exposure: float) -> Path:
    """Write the linear image as EXR and an sRGB PNG at ``exposure``; returns the PNG path."""
    from bubblefit.io.images import write_image

    out.mkdir(parents=True, exist_ok=True)
    write_image(out / f"{name}.exr", img)
    write_image(out / f"{name}.png", np.clip(img * exposure, 0.0, 1.0))
    return out / f"{name}.png"


def save_figure(fig, out: Path, name: str, *, dpi: int = 100) -> Path:
    """Save a matplotlib figure as ``out/name.png`` (atomically) and close it."""
    import matplotlib.pyplot as plt

    from bubblefit.io.images import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format="png")
    plt.close(fig)
    return path


def write_settings(out: Path, data: dict) -> Path:
    from bubblefit.cli.common import write_json

    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "settings.json", data)
    return out / "settings.json"


def publish(png: Path, name: str, enabled: bool = True, limit: int = 300_000) -> Path | None:
    """Copy the summary PNG to ``experiments/figures/NAME.png`` if it is under ``limit`` bytes."""
    if not enabled:
        return None
    size = png.stat().st_size
    if size > limit:
        log(f"not copying {png} ({size} bytes > {limit}); lower --size or the figure's dpi")
        return None
    FIGURES.mkdir(exist_ok=True)
    dst = FIGURES / f"{name}.png"
    shutil.copyfile(png, dst)
    return dst


def matplotlib():
    """matplotlib with the non-interactive Agg backend."""
    import matplotlib as mpl

    mpl.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def dumps(data) -> str:
    return json.dumps(data, indent=2, default=float)
