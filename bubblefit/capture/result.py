"""What a calibration measured, and its two outputs: the JSON record and the debug image.

:class:`CalibrationResult` is the record of :func:`bubblefit.capture.calibrate.calibrate`;
:func:`save_json` writes it in the command line's JSON contract (keys ``t``, ``t_rgb``,
``t4``, ``t_ci95``, ``bubble``, ``pixels_used``, ``warnings`` first, see
``docs/design.md``) and :func:`write_debug_image` draws the ratio map, the pixels used
and the circle. Both write atomically.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..io.atomic import write_json
from ..io.images import srgb_decode, srgb_encode, write_image

__all__ = ["CalibrationResult", "save_json", "write_debug_image"]


@dataclass
class CalibrationResult:
    """What :func:`calibrate` measured.

    Attributes:
        t: per-interface transmission fraction (all channels together).
        t_rgb: t per channel (R, G, B).
        t4: ``t**4``, the measured after/before ratio inside the bubble.
        t_ci95, t_rgb_ci95, t4_ci95: 95% intervals: the block bootstrap (noise) widened in
            quadrature by 1.96 times the model error ``t4_model_stderr``.
        t4_model_stderr: standard deviation of ``t^4`` from the model (half the spread
            between the inner and outer half of the pixels used and, when the rim confirms
            neither radial model, between the Fresnel and the flat estimate).
        image_size: ``[width, height]`` of the frame the circle belongs to.
        bubble: ``{"cx", "cy", "r"}`` in pixels of the ``after`` image (pixel centres at
            +1/2, as :class:`bubblefit.model.geometry.OrthographicCamera`).
        bubble_source: ``"detected"`` or ``"given"``.
        pixels_used: pixels that entered the estimate of t.
        shift_px: ``[dx, dy]``, where a point of ``before`` lies in ``after``, minus where
            it lay in ``before`` (camera shift in pixels).
        registration_cc: ECC correlation coefficient outside the bubble after alignment.
        exposure_ratio: after/before ratio of the background outside the bubble (1 when
            the exposure did not change); t is normalised by it when ``exposure_corrected``.
        radial: the radial fit (``beta``, its standard error, ``model`` = ``"fresnel"``,
            ``"constant"`` or ``"undetermined"``, ...).
        n_film, n_film_stderr, n_film_ci95: refractive index of the film when determined,
            else ``None``.
        warnings: things the user should know, one sentence each.
        maps: arrays for the debug image (not written to JSON): ``ratio`` (H, W),
            ``used`` (H, W) bool, ``rim`` (H, W) bool, ``after`` (H, W, 3).
    """

    t: float
    t_rgb: list[float]
    t4: float
    t_ci95: list[float]
    t_rgb_ci95: list[list[float]]
    t4_ci95: list[float]
    bubble: dict[str, float]
    bubble_source: str
    pixels_used: int
    shift_px: list[float]
    registration_cc: float
    exposure_ratio: float
    exposure_corrected: bool
    radial: dict[str, Any]
    n_film: float | None = None
    n_film_stderr: float | None = None
    n_film_ci95: list[float] | None = None
    t_fresnel_corrected: bool = False
    inner_fraction: float = 0.6
    image_size: list[int] | None = None
    t4_model_stderr: float = 0.0
    warnings: list[str] = field(default_factory=list)
    inputs: dict[str, str] = field(default_factory=dict)
    maps: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict[str, Any]:
        """The result as a JSON-ready dict (the keys of the command-line contract first, extra keys after)."""
        out: dict[str, Any] = {
            "t": _r(self.t),
            "t_rgb": [_r(v) for v in self.t_rgb],
            "t4": _r(self.t4),
            "t_ci95": [_r(v) for v in self.t_ci95],
            "bubble": {k: _r(v, 3) for k, v in self.bubble.items()},
            "pixels_used": int(self.pixels_used),
            "warnings": list(self.warnings),
            "image_size": None if self.image_size is None else [int(v) for v in self.image_size],
            "t_rgb_ci95": [[_r(a), _r(b)] for a, b in self.t_rgb_ci95],
            "t4_ci95": [_r(v) for v in self.t4_ci95],
            "bubble_source": self.bubble_source,
            "shift_px": [_r(v, 3) for v in self.shift_px],
            "registration_cc": _r(self.registration_cc, 5),
            "exposure_ratio": _r(self.exposure_ratio),
            "exposure_corrected": bool(self.exposure_corrected),
            "t_fresnel_corrected": bool(self.t_fresnel_corrected),
            "inner_fraction": self.inner_fraction,
            "t4_model_stderr": _r(self.t4_model_stderr, 7),
            "radial_fit": {k: (_r(v) if isinstance(v, float) else v) for k, v in self.radial.items()},
        }
        if self.n_film is not None:
            out["n_film"] = _r(self.n_film, 5)
            out["n_film_stderr"] = _r(self.n_film_stderr, 5)
            out["n_film_ci95"] = [_r(v, 5) for v in self.n_film_ci95]
        if self.inputs:
            out["inputs"] = dict(self.inputs)
        return out

    def summary(self) -> str:
        """A short human-readable summary (a few lines)."""
        lo, hi = self.t_ci95
        b = self.bubble
        lines = [
            f"t = {self.t:.4f}  (95% CI {lo:.4f} .. {hi:.4f}),  t^4 = {self.t4:.4f}",
            "t_rgb = " + ", ".join(f"{v:.4f}" for v in self.t_rgb),
            f"bubble ({self.bubble_source}): centre ({b['cx']:.1f}, {b['cy']:.1f}) px, "
            f"radius {b['r']:.1f} px; {self.pixels_used} pixels used",
            f"camera shift ({self.shift_px[0]:+.2f}, {self.shift_px[1]:+.2f}) px, "
            f"exposure ratio {self.exposure_ratio:.4f}",
        ]
        if self.n_film is not None:
            lines.append(f"n_film = {self.n_film:.3f} +/- {self.n_film_stderr:.3f} (Fresnel film fit over radius)")
        for w in self.warnings:
            lines.append(f"warning: {w}")
        return "\n".join(lines)


def _r(v, digits: int = 6):
    return None if v is None else round(float(v), digits)


def save_json(path: str | os.PathLike, result: CalibrationResult) -> None:
    """Write ``result.to_json()`` through the one atomic write path (:func:`bubblefit.io.atomic.write_json`)."""
    write_json(path, result.to_json())


def write_debug_image(path: str | os.PathLike, result: CalibrationResult) -> None:
    """Write a two-panel debug image (atomically).

    Left: the ``after`` shot. Right: the after/before ratio map (gray, from ``t^4 - 0.15``
    to 1.05; unusable pixels dark blue), pixels used for t tinted green, rim pixels of the
    radial fit tinted blue, the bubble circle in red. Small images are enlarged (nearest)
    so the panel is at least 400 pixels wide.
    """
    m = result.maps
    after = m["after"]
    h, w = after.shape[:2]
    scale = max(1, int(math.ceil(400 / max(w, 1))))
    left = srgb_encode(after / max(float(np.percentile(after, 99.5)), 1e-6))
    lo, hi = result.t4 - 0.15, 1.05
    g = np.clip((np.nan_to_num(m["ratio"], nan=lo) - lo) / (hi - lo), 0, 1)
    right = np.repeat(g[..., None], 3, axis=2)
    right[~np.isfinite(m["ratio"])] = (0.05, 0.05, 0.25)
    green = np.array([0.1, 0.9, 0.1])
    blue = np.array([0.2, 0.4, 1.0])
    right[m["used"]] = 0.6 * right[m["used"]] + 0.4 * green
    right[m["rim"]] = 0.6 * right[m["rim"]] + 0.4 * blue
    panel = np.concatenate([left, right], axis=1)
    panel = np.repeat(np.repeat(panel, scale, axis=0), scale, axis=1)
    panel = np.ascontiguousarray((panel * 255).astype(np.uint8))
    b = result.bubble
    sh = 4
    for off in (0, w * scale):
        c = (int(round((b["cx"] * scale + off) * (1 << sh))), int(round(b["cy"] * scale * (1 << sh))))
        cv2.circle(panel, c, int(round(b["r"] * scale * (1 << sh))), (255, 0, 0), 1, cv2.LINE_AA, sh)
        cv2.drawMarker(panel, (c[0] >> sh, c[1] >> sh), (255, 0, 0), cv2.MARKER_CROSS, 7, 1)
    write_image(path, srgb_decode(panel.astype(np.float64) / 255.0))
