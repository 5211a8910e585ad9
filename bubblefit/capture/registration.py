"""Registration of two shots from a fixed camera: phase correlation, ECC and shifting.

The camera may move by a few pixels between the shot without the bubble and the shot
with it. :func:`phase_correlate` (Kuglin & Hines 1975) gives the translation to about a
pixel, :func:`register_translation` refines it with ECC (Evangelidis & Psarakis 2008),
and :func:`shift_image` applies it. Shifts are ``(dx, dy)`` in pixels, x right, y down.
See ``docs/design.md`` (capture).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

__all__ = ["phase_correlate", "register_translation", "shift_image"]

#: Interpolation of :func:`shift_image`: bilinear for images, nearest for masks.
Interpolation = Literal["linear", "nearest"]


def phase_correlate(reference: np.ndarray, moving: np.ndarray, *, window: bool = True) -> tuple[float, float]:
    """Translation of ``moving`` onto ``reference`` by phase correlation.

    The peak of the inverse Fourier transform of the normalised cross-power spectrum
    (``cv2.phaseCorrelate``, sub-pixel by a weighted centroid), over a Hann window that
    suppresses the wrap-around of the image borders.

    Parameters
    ----------
    reference, moving : (H, W) float arrays
        Gray images of the same size (any preprocessing, e.g. linear or log luminance, is
        the caller's).
    window : bool
        Apply a Hann window first.

    Returns
    -------
    (dx, dy)
        A feature at (x, y) in ``moving`` appears at (x + dx, y + dy) in ``reference``.

    References
    ----------
    C. D. Kuglin and D. C. Hines, "The phase correlation image alignment method",
    Proc. IEEE Int. Conf. Cybernetics and Society, 1975.
    """
    ref = np.ascontiguousarray(reference, dtype=np.float32)
    mov = np.ascontiguousarray(moving, dtype=np.float32)
    win = cv2.createHanningWindow(ref.shape[::-1], cv2.CV_32F) if window else None
    (dx, dy), _resp = cv2.phaseCorrelate(mov, ref, win)
    return float(dx), float(dy)


def _reg_view(gray: np.ndarray) -> np.ndarray:
    """A linear gray image scaled to about [0, 1] (float32) for OpenCV.

    Linear, not sRGB-encoded: a camera integrates linear light over each pixel, so only
    the linear image of a shifted scene is the shifted image (a non-linear transfer curve
    distorts partially covered edge pixels and biases a sub-pixel shift).
    """
    scale = float(np.percentile(gray, 99.5)) or 1.0
    return np.clip(gray / scale, 0.0, 2.0).astype(np.float32)


def register_translation(
    reference: np.ndarray, moving: np.ndarray, mask: np.ndarray | None = None, init: tuple[float, float] | None = None
) -> tuple[tuple[float, float], float]:
    """Sub-pixel translation between two gray images.

    Phase correlation (:func:`phase_correlate`) gives the integer-accurate shift, which
    ECC (``cv2.findTransformECC`` with ``MOTION_TRANSLATION``) refines.

    Parameters
    ----------
    reference, moving : (H, W) float arrays
        Linear gray images (e.g. ``after`` and ``before``).
    mask : (H, W) bool, optional
        Pixels of ``moving`` that may be used by ECC (e.g. outside the bubble).
    init : (dx, dy), optional
        Initial shift; phase correlation is skipped when given.

    Returns
    -------
    (dx, dy), cc
        ``reference(x, y) ~ moving(x - dx, y - dy)``: a feature at (x, y) in ``moving``
        appears at (x + dx, y + dy) in ``reference``. ``cc`` is ECC's correlation
        coefficient (1 for identical images up to gain and offset); 0 if ECC failed.

    References
    ----------
    G. D. Evangelidis and E. Z. Psarakis, "Parametric image alignment using enhanced
    correlation coefficient maximization", IEEE TPAMI 30(10), 2008.
    """
    ref = _reg_view(reference)
    mov = _reg_view(moving)
    if init is None:
        dx, dy = phase_correlate(ref, mov)
    else:
        dx, dy = init
    warp = np.array([[1, 0, -dx], [0, 1, -dy]], dtype=np.float32)
    m = None if mask is None else (mask.astype(np.uint8) * 255)
    try:
        cc, warp = cv2.findTransformECC(
            ref, mov, warp, cv2.MOTION_TRANSLATION,
            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-7), m, 5,
        )
    except cv2.error:
        return (float(dx), float(dy)), 0.0
    return (float(-warp[0, 2]), float(-warp[1, 2])), float(cc)


def shift_image(img: np.ndarray, shift: tuple[float, float], *, order: Interpolation = "linear") -> np.ndarray:
    """Translate an image by ``shift = (dx, dy)`` pixels: ``out(x, y) = img(x - dx, y - dy)``.

    Bilinear (``order="linear"``) or nearest (``"nearest"``, for masks) interpolation;
    pixels that come from outside the image are 0 (False for masks).
    """
    dx, dy = shift
    if abs(dx) < 1e-9 and abs(dy) < 1e-9:
        return img.copy()
    h, w = img.shape[:2]
    warp = np.array([[1, 0, dx], [0, 1, dy]], dtype=np.float64)
    flag = cv2.INTER_NEAREST if order == "nearest" else cv2.INTER_LINEAR
    src = img.astype(np.uint8) if img.dtype == bool else img.astype(np.float32)
    out = cv2.warpAffine(src, warp, (w, h), flags=flag, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if img.dtype == bool:
        return out.astype(bool)
    return out.astype(np.float64)

