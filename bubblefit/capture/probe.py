"""Light probes: finding a mirror ball, unwrapping it to an environment map, HDR merging.

A mirror ball photographed from the bubble's viewpoint reflects almost the whole sphere of
directions around it (paper sec. 3.2; Miller & Hoffman 1984, "Illumination and reflection
maps"; Debevec 1998, "Rendering synthetic objects into real scenes"). This module turns such
photographs into an equirectangular map in the convention of ``docs/design.md``:

1. :func:`bubblefit.capture.hdr.merge_exposures` merges a bracket of exposures into one linear radiance image
   (Debevec & Malik 1997, or Robertson, Borman & Stevenson 2003), with weights that ignore
   clipped pixels and a fallback for pixels clipped in every exposure (a sun);
   :func:`bubblefit.capture.hdr.recover_response` recovers a camera's response with OpenCV when it is unknown.
2. :func:`bubblefit.capture.ball.find_ball` finds the ball's outline (Hough transform, then a sub-pixel
   least-squares circle fit to radial edge positions, Kasa 1976).
3. :func:`unwrap_mirror_ball` maps every texel direction of the output map to the point of
   the ball that reflects it (the mirror reflection law ``r = d - 2 (d.n) n``), samples the
   photograph there, and masks the directions the ball cannot show reliably.

Frames and pixel coordinates
----------------------------
The unwrapped map is expressed in the camera's frame: the camera looks along -z with +y up
in the image, which is the default camera of ``docs/design.md``, so a map captured from the bubble's
viewpoint lines up with a default render (rotate it about +y with ``rotation`` otherwise).
Image positions are continuous with pixel ``(row i, column j)`` centred at
``(x, y) = (j + 1/2, i + 1/2)``; a ball exactly filling a 128 x 128 image has centre
(64, 64) and radius 64.

For an orthographic view (a ball far from the camera) the ball point at normalised image
offset ``(a, b) = ((x - cx)/r, -(y - cy)/r)`` has normal ``n = (a, b, sqrt(1 - a^2 - b^2))``
and reflects the direction ``w = 2 n_z n - (0, 0, 1)``: the centre reflects the camera
(+z), the rim reflects the direction straight behind the ball (-z). Conversely the normal
that reflects ``w`` is the half vector ``normalize(w + z)``. Near -z this map is singular
(the whole rim shows one direction), so those directions are masked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputError
from ..lighting.envmap import texel_directions
from .ball import Circle

__all__ = ["ProbeMap", "mirror_ball_directions", "unwrap_mirror_ball", "fill_masked"]


def mirror_ball_directions(
    shape: tuple[int, int], circle: Circle, *, distance: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Direction reflected by the ball at each pixel centre (mirror reflection law).

    The camera looks along -z; a viewing ray ``d`` meeting the ball where its normal is ``n``
    leaves along ``r = d - 2 (d.n) n`` (law of specular reflection).

    Args:
        shape: (H, W) of the photograph.
        circle: the ball's outline.
        distance: camera-to-ball-centre distance in ball radii for a perspective camera;
            ``None`` for an orthographic view (a ball far from the camera).

    Returns:
        ``(dirs, inside)``: (H, W, 3) unit reflected directions in the camera frame (0 outside
        the ball) and the (H, W) bool mask of pixels that see the ball.
    """
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    a = (xx + 0.5 - circle.cx) / circle.r
    b = -(yy + 0.5 - circle.cy) / circle.r
    if distance is None:
        rho2 = a * a + b * b
        inside = rho2 < 1.0
        nz = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
        n = np.stack([a, b, nz], axis=-1)
        d = np.array([0.0, 0.0, -1.0])
    else:
        D = float(distance)
        if D <= 1.0:
            raise InputError("the camera must be outside the ball (distance > 1 ball radius)")
        focal = 1.0 / math.tan(math.asin(1.0 / D))  # silhouette radius 1 <-> tangent cone
        d = np.stack([a / focal, b / focal, -np.ones_like(a)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.array([0.0, 0.0, D])
        bq = d @ o
        disc = bq * bq - (D * D - 1.0)
        inside = disc > 0
        t = -bq - np.sqrt(np.maximum(disc, 0.0))
        n = o + t[..., None] * d
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
    dn = np.sum(d * n, axis=-1, keepdims=True)
    r = d - 2 * dn * n
    r = np.where(inside[..., None], r, 0.0)
    return r, inside


def _ball_points(dirs: np.ndarray, distance: float | None, iterations: int = 12) -> np.ndarray:
    """Point of the unit ball (in ball radii) that reflects each direction toward the camera.

    Orthographic: the normal is the half vector ``normalize(w + z)``. Perspective (camera at
    ``(0, 0, distance)``): fixed-point iteration on the half vector of ``w`` and the direction
    from the point to the camera (converges quickly for distance > 2).
    """
    z = np.array([0.0, 0.0, 1.0])
    n = dirs + z
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    if distance is None:
        return n
    cam = np.array([0.0, 0.0, float(distance)])
    for _ in range(iterations):
        v = cam - n
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        n = dirs + v
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return n


@dataclass
class ProbeMap:
    """An unwrapped light probe.

    Attributes:
        pixels: (H, 2H, 3) linear radiance, equirectangular (``docs/design.md``), masked texels filled.
        valid: (H, 2H) bool, texels the ball sampled reliably (False: filled by inpainting).
        circle: the ball's outline in the photograph.
        info: what was done (mask angles, supersampling, ...), for ``--json``.
    """

    pixels: np.ndarray
    valid: np.ndarray
    circle: Circle
    info: dict = field(default_factory=dict)


def unwrap_mirror_ball(
    pixels: np.ndarray,
    circle: Circle,
    *,
    height: int = 256,
    distance: float | None = None,
    rim_mask_deg: float = 20.0,
    camera_mask_deg: float = 8.0,
    rotation: float = 0.0,
    supersample: int | None = None,
    fill: bool = True,
) -> ProbeMap:
    """Unwrap a mirror-ball photograph to an equirectangular environment map.

    For each texel direction ``w`` of the output map (texel centres of
    :func:`bubblefit.lighting.envmap.texel_directions`, Mitsuba's convention), the ball point that
    reflects ``w`` toward the camera has normal ``n = normalize(w + v)`` (mirror reflection
    law; ``v`` the direction to the camera), which projects to image position
    ``(cx + r n_x, cy - r n_y)``; the photograph is sampled there bilinearly. When one
    texel covers several photograph pixels (a large ball, a small map), ``supersample^2``
    directions spread over the texel are averaged (weighted by ``sin theta``) so that the
    map is box-filtered rather than aliased.

    Masked (``valid = False``) are the directions within ``rim_mask_deg`` of -z, straight
    behind the ball, which the rim shows infinitely compressed (the reflection map is
    singular there: an error of one pixel in the radius moves them by tens of degrees);
    the directions within ``camera_mask_deg`` of +z, where the camera and photographer see
    themselves; and directions whose ball point falls outside the photograph. With ``fill``
    those texels are inpainted from their neighbours in log radiance (:func:`fill_masked`)
    so that the map can light a scene; ``valid`` says which they are.

    Args:
        pixels: (H, W, 3) linear photograph of the ball (one exposure or an HDR merge).
        circle: the ball's outline (:func:`find_ball`).
        height: output map height; its width is ``2 height``.
        distance: camera-to-ball distance in ball radii (perspective) or ``None``
            (orthographic, a ball photographed from far away with a long lens).
        rim_mask_deg: half-angle of the masked cone around -z (degrees).
        camera_mask_deg: half-angle of the masked cone around +z (degrees; 0 keeps it).
        rotation: rotate the map about +y by this many radians (the output direction ``w``
            reads the camera-frame direction ``R_y(rotation) w``), e.g. to align it with a scene.
        supersample: sub-samples per texel side; ``None`` chooses from the ball's size.
        fill: inpaint the masked texels.

    Returns:
        A :class:`ProbeMap` with ``pixels`` (height, 2 height, 3) and ``valid``.
    """
    img = np.asarray(pixels, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) photograph of the ball, got shape {img.shape}")
    if height < 4:
        raise InputError(f"environment map height must be at least 4, got {height}")
    if circle.r < 4:
        raise InputError(f"the mirror ball is too small ({circle.r:.1f} px radius)")
    if distance is not None and not (math.isfinite(distance) and distance > 1.0):
        raise InputError(f"the camera-to-ball distance is in ball radii and must exceed 1 (the camera outside "
                         f"the ball), got {distance:g}")
    H, W = int(height), 2 * int(height)
    texel = math.pi / (H - 1)
    if supersample is None:
        # angular size of one photo pixel at the ball's centre is ~2/r radians
        supersample = int(min(8, max(1, math.ceil(texel / (2.0 / circle.r)))))
    s = int(supersample)
    out, hit = _sample_texels(img, circle, H, s, distance, rotation)
    dirs_c = _rotate_y(texel_directions(H, W), rotation)
    back = np.degrees(np.arccos(np.clip(-dirs_c[..., 2], -1, 1)))
    front = np.degrees(np.arccos(np.clip(dirs_c[..., 2], -1, 1)))
    valid = (back > rim_mask_deg) & hit
    if camera_mask_deg > 0:
        valid &= front > camera_mask_deg
    if fill and not valid.all():
        out = fill_masked(out, valid)
    info = {
        "height": H,
        "width": W,
        "supersample": s,
        "rim_mask_deg": float(rim_mask_deg),
        "camera_mask_deg": float(camera_mask_deg),
        "projection": "orthographic" if distance is None else f"perspective (distance {distance:g} radii)",
        "valid_fraction": float(valid.mean()),
    }
    return ProbeMap(pixels=out, valid=valid, circle=circle, info=info)


def _rotate_y(dirs: np.ndarray, angle: float) -> np.ndarray:
    """Directions rotated by ``angle`` radians about +y (right-handed)."""
    if not angle:
        return dirs
    c, sn = math.cos(angle), math.sin(angle)
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    return np.stack([c * x + sn * z, y, -sn * x + c * z], axis=-1)


def _photo_position(dirs: np.ndarray, circle: Circle, distance: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Continuous image position (``cv2.remap`` convention: pixel centres at integers) of
    the ball point that reflects each direction toward the camera."""
    n = _ball_points(dirs, distance)
    if distance is None:
        px, py = n[..., 0], n[..., 1]
    else:
        focal = 1.0 / math.tan(math.asin(1.0 / distance))
        depth = distance - n[..., 2]
        px, py = focal * n[..., 0] / depth, focal * n[..., 1] / depth
    mx = (circle.cx + circle.r * px - 0.5).astype(np.float32)
    my = (circle.cy - circle.r * py - 0.5).astype(np.float32)
    return mx, my


def _sample_texels(img: np.ndarray, circle: Circle, H: int, s: int, distance: float | None,
                   rotation: float) -> tuple[np.ndarray, np.ndarray]:
    """Box-filtered photo radiance for each texel of an (H, 2H) map, from ``s x s``
    directions per texel weighted by ``sin theta``; returns it with the (H, 2H) mask of
    texels whose ball point lies in the photograph."""
    W = 2 * H
    offs = (np.arange(s) + 0.5) / s - 0.5
    u0 = (np.arange(W) + 0.5) / W
    v0 = np.arange(H) / (H - 1)
    acc = np.zeros((H, W, 3))
    wsum = np.zeros((H, W, 1))
    img32 = img.astype(np.float32)
    ih, iw = img.shape[:2]
    for du in offs:
        for dv in offs:
            phi = 2 * np.pi * (u0 + du / W)[None, :]
            th = np.pi * np.clip(v0 + dv / (H - 1), 0.0, 1.0)[:, None]
            st = np.sin(th)
            dirs = np.stack(np.broadcast_arrays(st * np.sin(phi), np.cos(th), -st * np.cos(phi)), axis=-1)
            mx, my = _photo_position(_rotate_y(dirs, rotation), circle, distance)
            inb = (mx >= -0.5) & (mx <= iw - 0.5) & (my >= -0.5) & (my <= ih - 0.5)
            samp = cv2.remap(img32, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            wgt = np.where(inb, np.maximum(st, 1e-6) * np.ones((1, W)), 0.0)[..., None]
            acc += samp.astype(np.float64) * wgt
            wsum += wgt
    return acc / np.maximum(wsum, 1e-300), wsum[..., 0] > 0


def fill_masked(pixels: np.ndarray, valid: np.ndarray, *, radius: int = 5) -> np.ndarray:
    """Fill invalid texels of an equirectangular map from their valid neighbours.

    Each channel's log radiance is inpainted with the Navier-Stokes method (Bertalmio,
    Bertozzi & Sapiro 2001, "Navier-Stokes, fluid dynamics, and image and video
    inpainting", CVPR; OpenCV ``INPAINT_NS``; OpenCV 5.0's ``INPAINT_TELEA`` returned
    values far outside the neighbours' range on float input) on a copy padded by a quarter of the width on each side
    with the columns that wrap around, so that holes on the map's seam fill seamlessly.

    Args:
        pixels: (H, W, 3) linear map.
        valid: (H, W) bool, texels to keep.

    Returns:
        (H, W, 3) map with the invalid texels replaced.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    if valid.all():
        return pixels.copy()
    if not valid.any():
        return np.zeros_like(pixels)
    h, w = valid.shape
    pad = w // 4
    floor = max(float(np.percentile(pixels[valid], 0.1)), 1e-6) * 0.1
    logp = np.log(np.maximum(pixels, floor)).astype(np.float32)
    logp = np.concatenate([logp[:, -pad:], logp, logp[:, :pad]], axis=1)
    hole = (~valid).astype(np.uint8)
    hole = np.concatenate([hole[:, -pad:], hole, hole[:, :pad]], axis=1)
    out = np.empty_like(logp)
    for c in range(logp.shape[2]):
        out[..., c] = cv2.inpaint(np.ascontiguousarray(logp[..., c]), hole, radius, cv2.INPAINT_NS)
    filled = np.exp(out[:, pad:pad + w].astype(np.float64))
    return np.where(valid[..., None], pixels, filled)
