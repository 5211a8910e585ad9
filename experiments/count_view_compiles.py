"""Programs compiled by each fit of ``fit_photo`` when nothing states the view: the 48 px
photo of ``tests/test_camera_view.py::test_the_view_of_a_perspective_photo_is_fitted``
(the package's renderer through a 25 degree pinhole, noise, 8-bit sRGB), fitted with
JAX's compile log on; each fit through one view (orthographic, the lens, the refits of
the divergence) is counted apart.

Run from the repository root with an empty program store for a cold count:

    BUBBLEFIT_CACHE_DIR=$(mktemp -d) python experiments/count_view_compiles.py [RECORD.json]
"""

import json
import logging
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import jax  # noqa: E402
import numpy as np  # noqa: E402

COUNT = {"lowered": 0, "compiled": 0}


class _Counter(logging.Handler):
    """Counts JAX's compile log: a program lowered ("Compiling ...") and compiled by XLA."""

    def emit(self, record):
        msg = record.getMessage()
        COUNT["lowered"] += msg.startswith("Compiling")
        COUNT["compiled"] += "Finished XLA compilation" in msg


def main(out=None):
    jax.config.update("jax_log_compiles", True)
    logging.getLogger("jax").addHandler(_Counter())
    logging.getLogger("jax").setLevel(logging.DEBUG)

    import test_fit as tf
    from conftest import DATA

    import bubblefit.inverse.fit as F
    from bubblefit.capture import view as V
    from bubblefit.inverse import FitOptions, fit_photo
    from bubblefit.io.images import read_image
    from bubblefit.lighting.envmap import downsample
    from bubblefit.model.scene import Scene, render_scene

    px = read_image(DATA / "courtyard.exr").pixels
    while px.shape[0] > 64:
        px = downsample(px)
    fov, N = 25.0, tf.N
    dist = 1.0 / math.sin(math.atan(0.42 * N * 2 * V.divergence(fov) / N))
    rng = np.random.default_rng(11)
    bg = tf._background(rng)
    scene = Scene.from_dict({"camera": {"type": "perspective", "width": N, "height": N, "origin": [0, 0, dist],
                                        "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": fov},
                             "bubble": {"thickness_nm": 520.0, "t": 0.97, "roughness": 0.06},
                             "lighting": {"envmap": "unused.exr"},
                             "effects": {"model": "paper", "transmission_tint": True}})
    env = tf._env(px)
    photo = tf._quantise(np.asarray(render_scene(scene, bg, env=env)), rng)
    fits = []
    one = F._fit_model

    def counted(photo, env, options, *a, **k):
        before, t0 = dict(COUNT), time.perf_counter()
        r = one(photo, env, options, *a, **k)
        v = options.view
        fits.append({"kind": v.kind, "fov_deg": v.fov_deg, "source": v.source,
                     "lowered": COUNT["lowered"] - before["lowered"], "compiled": COUNT["compiled"] - before["compiled"],
                     "wall_s": round(time.perf_counter() - t0, 2)})
        print(fits[-1], flush=True)
        return r

    F._fit_model = counted
    t0 = time.perf_counter()
    res = fit_photo(photo, env, options=FitOptions(model="paper", disc=tf.DISC), background=bg)
    record = {"photo": "48 px, 25 degree pinhole (test_the_view_of_a_perspective_photo_is_fitted)",
              "fits": fits, "total": dict(COUNT, wall_s=round(time.perf_counter() - t0, 2)),
              "fitted_fov_deg": res.camera.get("fitted_fov_deg"), "fov_stderr_deg": res.camera.get("fov_stderr_deg"),
              "thickness_nm": res.params["thickness_nm"], "thickness_stderr_nm": res.stderr["thickness_nm"]}
    print(json.dumps(record["total"]), record["fitted_fov_deg"], record["thickness_nm"])
    if out:
        Path(out).write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:])
