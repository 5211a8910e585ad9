"""A dark-box pair: reading the two shots and checking that they can be compared.

:func:`load_pair` reads the shot without the bubble (``before``) and the one with it
(``after``) and refuses pairs of different sizes or kinds; :func:`check_exposures`
refuses black or saturated shots. See ``docs/design.md`` (calibration).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import InputError
from ..io.images import Image, read_image

__all__ = ["load_pair", "check_exposures", "gray"]


def gray(px: np.ndarray) -> np.ndarray:
    """(H, W) gray value of an (H, W, 3) linear image: the sum of its channels."""
    return px.sum(axis=2)


def _as_image(x: Image | np.ndarray | str | os.PathLike, name: str) -> Image:
    if isinstance(x, Image):
        return x
    if isinstance(x, np.ndarray):
        arr = np.asarray(x, dtype=np.float64)
        if arr.ndim == 2:
            arr = np.repeat(arr[:, :, None], 3, axis=2)
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise InputError(f"{name}: expected an (H, W, 3) image array, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: the image array has NaN or Inf values")
        return Image(pixels=arr, path=name, saturated=np.zeros(arr.shape[:2], bool))
    return read_image(x)


def _channels(img: Image) -> int:
    if img.was_gray:
        return 2 if img.alpha_dropped else 1
    return 4 if img.alpha_dropped else 3


def load_pair(before, after) -> tuple[Image, Image]:
    """Read and check a before/after pair.

    Parameters
    ----------
    before, after : path, :class:`~bubblefit.io.images.Image` or (H, W, 3) array
        Files are read with OpenImageIO and decoded to linear radiance
        (:func:`bubblefit.io.images.read_image`).

    Returns
    -------
    (Image, Image)

    Raises
    ------
    InputError
        A file cannot be read, or the two images differ in size or channel count.
    """
    b = _as_image(before, "before")
    a = _as_image(after, "after")
    nb, na = os.path.basename(b.path) or "before", os.path.basename(a.path) or "after"
    if b.shape != a.shape:
        raise InputError(
            f"{nb} is {b.shape[1]}x{b.shape[0]} but {na} is {a.shape[1]}x{a.shape[0]} pixels: "
            "the two photographs must come from the same fixed camera"
        )
    cb, ca = _channels(b), _channels(a)
    if cb != ca:
        raise InputError(f"{nb} has {cb} channel(s) but {na} has {ca}: the two photographs must be of the same kind")
    return b, a


def check_exposures(img_b: Image, img_a: Image, names: tuple[str, str], warnings: list[str]) -> None:
    """Refuse black or saturated shots; warn about pairs from different pipelines."""
    h, w = img_b.shape
    for name, img in zip(names, (img_b, img_a)):
        g = gray(img.pixels)
        sat = img.saturated if img.saturated is not None else np.zeros((h, w), bool)
        level = float(np.percentile(g, 99.0))
        if level <= 0:
            raise InputError(f"{name} is black: nothing to measure (check the exposure and the lighting)")
        lit = g > 0.2 * level
        frac = float(sat[lit].mean()) if lit.any() else 0.0
        if frac > 0.5:
            raise InputError(
                f"{name} is saturated: {100 * frac:.0f}% of its lit pixels are at the maximum code value "
                "(reduce the exposure and retake both shots)"
            )
    if img_b.bit_depth != img_a.bit_depth:
        warnings.append(f"the shots have different bit depths ({img_b.bit_depth} and {img_a.bit_depth})")
    if img_b.linear_file != img_a.linear_file:
        warnings.append("one shot is linear and the other sRGB-encoded; check that both come from the same pipeline")
