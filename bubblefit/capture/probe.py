"""Light probes: finding a mirror ball, unwrapping it to an environment map, HDR merging.

A mirror ball photographed from the bubble's viewpoint reflects almost the whole sphere of
directions around it (paper sec. 3.2; Miller & Hoffman 1984, "Illumination and reflection
maps"; Debevec 1998, "Rendering synthetic objects into real scenes"). This module turns such
photographs into an equirectangular map in the convention of DESIGN.md:

1. :func:`merge_exposures` merges a bracket of exposures into one linear radiance image
   (Debevec & Malik 1997, or Robertson, Borman & Stevenson 2003), with weights that ignore
   clipped pixels and a fallback for pixels clipped in every exposure (a sun);
   :func:`recover_response` recovers a camera's response with OpenCV when it is unknown.
2. :func:`find_ball` finds the ball's outline (Hough transform, then a sub-pixel
   least-squares circle fit to radial edge positions, Kasa 1976).
3. :func:`unwrap_mirror_ball` maps every texel direction of the output map to the point of
   the ball that reflects it (the mirror reflection law ``r = d - 2 (d.n) n``), samples the
   photograph there, and masks the directions the ball cannot show reliably.

Frames and pixel coordinates
----------------------------
The unwrapped map is expressed in the camera's frame: the camera looks along -z with +y up
in the image, which is the default camera of DESIGN.md, so a map captured from the bubble's
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
from typing import Sequence

import cv2
import numpy as np

from ..lighting.envmap import texel_directions
from ..errors import InputError

__all__ = [
    "Circle",
    "HdrMerge",
    "ProbeMap",
    "find_ball",
    "refine_circle",
    "fit_circle",
    "ball_mask",
    "rim_contrast",
    "mirror_ball_directions",
    "unwrap_mirror_ball",
    "fill_masked",
    "merge_exposures",
    "recover_response",
    "apply_response",
    "exposure_stops",
]


# --------------------------------------------------------------------------------------
# Finding the ball
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Circle:
    """A circle in continuous image coordinates (pixel (i, j) centred at (j + 1/2, i + 1/2)).

    Attributes:
        cx, cy: centre in pixels (x to the right, y down).
        r: radius in pixels.
    """

    cx: float
    cy: float
    r: float

    def as_dict(self) -> dict:
        return {"cx": float(self.cx), "cy": float(self.cy), "r": float(self.r)}


def _luminance(pixels: np.ndarray) -> np.ndarray:
    """Rec. 709 relative luminance of a linear (H, W, 3) image (ITU-R BT.709)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim == 2:
        return pixels
    return pixels[..., 0] * 0.2126 + pixels[..., 1] * 0.7152 + pixels[..., 2] * 0.0722


def _log_image(pixels: np.ndarray) -> np.ndarray:
    """Log luminance scaled to [0, 1], robust to the image's dynamic range.

    Edges of a mirror ball are visible in log luminance whatever the exposure, which makes
    the Hough transform work on HDR merges as well as on single photographs.
    """
    lum = _luminance(pixels)
    pos = lum[lum > 0]
    floor = np.percentile(pos, 1) if pos.size else 1e-6
    floor = max(float(floor), 1e-8)
    log = np.log(np.maximum(lum, floor))
    lo, hi = np.percentile(log, [0.5, 99.5])
    if hi - lo < 1e-9:
        return np.zeros_like(log)
    return np.clip((log - lo) / (hi - lo), 0.0, 1.0)


def fit_circle(x: np.ndarray, y: np.ndarray) -> Circle:
    """Least-squares circle through points (Kasa 1976, "A circle fitting procedure and its
    error analysis", IEEE Trans. Instrum. Meas. 25(1)).

    Solves ``x^2 + y^2 + D x + E y + F = 0`` in the least-squares sense.

    Args:
        x, y: (N,) point coordinates, N >= 3, not collinear.

    Returns:
        The fitted :class:`Circle`.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.size < 3:
        raise InputError("cannot fit a circle to fewer than 3 edge points")
    a = np.stack([x, y, np.ones_like(x)], axis=1)
    b = -(x * x + y * y)
    (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = -d / 2, -e / 2
    r2 = cx * cx + cy * cy - f
    if not np.isfinite(r2) or r2 <= 0:
        raise InputError("edge points do not lie on a circle")
    return Circle(float(cx), float(cy), float(math.sqrt(r2)))


def refine_circle(
    pixels: np.ndarray,
    guess: Circle,
    *,
    search: float = 0.15,
    n_rays: int = 360,
    smooth: float = 0.7,
    outermost: bool = False,
    min_inliers: float = 0.0,
) -> Circle:
    """Refine a circle to sub-pixel accuracy from the radial edge profile.

    Along ``n_rays`` rays from the guessed centre, the position of the strongest luminance
    step (linear luminance clipped at its 99th percentile, so that a mixed edge pixel is
    located without the bias a log scale would give and a sun cannot dominate) between ``(1 - search) r`` and ``(1 + search) r`` is located to sub-pixel accuracy
    (parabola through the gradient peak); a circle is fitted to those positions with
    :func:`fit_circle` (Kasa 1976), twice, dropping positions more than 3 robust standard
    deviations (at least 1 px) from the first fit.

    Args:
        pixels: (H, W, 3) or (H, W) linear image.
        guess: a rough circle (e.g. from the Hough transform).
        search: half-width of the search band, as a fraction of the radius.
        n_rays: number of rays.
        smooth: Gaussian blur (pixels) applied before differentiating.
        outermost: take the outermost edge at least half as strong as the ray's strongest
            instead of the strongest (the ball's silhouette is its outermost edge; details
            of the reflection crowd just inside the rim).
        min_inliers: fraction of the rays whose edge must lie within 1 px of the fitted
            circle; below it an :class:`InputError` says no clear edge was found.

    Returns:
        The refined :class:`Circle`.
    """
    lum = _luminance(pixels)
    top = float(np.percentile(lum, 99.0))
    img = (np.clip(lum / top, 0.0, 1.0) if top > 0 else lum).astype(np.float32)
    if smooth > 0:
        img = cv2.GaussianBlur(img, (0, 0), smooth)
    step = 0.25
    radii = np.arange((1 - search) * guess.r, (1 + search) * guess.r + step, step)
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    xs = guess.cx + radii[None, :] * ca - 0.5  # cv2.remap samples pixel centres at integers
    ys = guess.cy + radii[None, :] * sa - 0.5
    h, w = img.shape
    inside = (xs >= 0) & (xs <= w - 1) & (ys >= 0) & (ys <= h - 1)
    prof = cv2.remap(img, xs.astype(np.float32), ys.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    grad = np.abs(np.gradient(prof.astype(np.float64), step, axis=1))
    grad[~inside] = 0.0
    if outermost:
        # the silhouette is the outermost strong edge: take the last local maximum that
        # reaches half of the ray's strongest gradient
        gmax = grad.max(axis=1, keepdims=True)
        peak = np.zeros_like(grad, dtype=bool)
        peak[:, 1:-1] = (grad[:, 1:-1] >= grad[:, :-2]) & (grad[:, 1:-1] > grad[:, 2:])
        peak &= grad >= 0.5 * gmax
        k = np.where(peak.any(axis=1), radii.size - 1 - np.argmax(peak[:, ::-1], axis=1), np.argmax(grad, axis=1))
    else:
        k = np.argmax(grad, axis=1)
    ok = (k > 0) & (k < radii.size - 1) & inside.all(axis=1)
    rows = np.arange(n_rays)
    kc = np.clip(k, 1, radii.size - 2)
    g0, g1, g2 = grad[rows, kc - 1], grad[rows, kc], grad[rows, kc + 1]
    denom = g0 - 2 * g1 + g2
    off = np.where(np.abs(denom) > 1e-12, 0.5 * (g0 - g2) / np.where(denom == 0, 1, denom), 0.0)
    rad = radii[kc] + np.clip(off, -1, 1) * step
    ok &= grad[rows, kc] > 0.2 * np.median(grad[rows, kc][ok]) if ok.any() else ok
    if ok.sum() < max(12, n_rays // 8):
        raise InputError("cannot locate the mirror ball's edge (too little contrast at its rim)")
    px = guess.cx + rad * ca[:, 0]
    py = guess.cy + rad * sa[:, 0]
    circ = fit_circle(px[ok], py[ok])
    for _ in range(2):
        res = np.hypot(px - circ.cx, py - circ.cy) - circ.r
        mad = 1.4826 * np.median(np.abs(res[ok])) if ok.any() else 1.0
        keep = ok & (np.abs(res) < max(3 * mad, 1.0))
        if keep.sum() < max(12, n_rays // 8):
            break
        circ = fit_circle(px[keep], py[keep])
    res = np.hypot(px - circ.cx, py - circ.cy) - circ.r
    inliers = float(np.mean(ok & (np.abs(res) < 1.0)))
    if inliers < min_inliers:
        raise InputError(
            f"no clear mirror-ball edge: only {100 * inliers:.0f}% of the rim lies on one circle "
            "(give the ball's circle with --ball CX,CY,R)"
        )
    return circ


def find_ball(
    pixels: np.ndarray, *, min_radius_frac: float = 0.08, max_side: int = 800, min_contrast: float = 0.05
) -> Circle:
    """Find the mirror ball (the largest clear circle) in a photograph.

    A Hough transform for circles (Yuen et al. 1990, "Comparative study of Hough transform
    methods for circle finding", as implemented by OpenCV's ``HoughCircles``) on the log
    luminance gives a rough circle; :func:`refine_circle` makes it sub-pixel accurate.

    Args:
        pixels: (H, W, 3) linear image (a single exposure or an HDR merge).
        min_radius_frac: smallest ball radius to look for, as a fraction of the shorter side.
        max_side: the Hough transform runs on a copy at most this many pixels wide.
        min_contrast: smallest accepted :func:`rim_contrast` (log luminance step at the rim).

    Returns:
        The ball's :class:`Circle`.

    Raises:
        InputError: no circle was found.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim not in (2, 3) or min(pixels.shape[:2]) < 16:
        raise InputError(f"image too small to hold a mirror ball: {pixels.shape}")
    img = _log_image(pixels)
    h, w = img.shape
    scale = min(1.0, max_side / max(h, w))
    small = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA) \
        if scale < 1 else img
    small8 = np.round(small * 255).astype(np.uint8)
    small8 = cv2.GaussianBlur(small8, (0, 0), 1.5)
    side = min(small8.shape)
    rmin = max(4, int(min_radius_frac * side))
    rmax = int(0.5 * side * 1.05) + 2
    circles = None
    for p2 in (0.9, 0.8, 0.7, 0.6, 0.5):
        circles = cv2.HoughCircles(small8, cv2.HOUGH_GRADIENT_ALT, dp=1.0, minDist=side,
                                   param1=60, param2=p2, minRadius=rmin, maxRadius=rmax)
        if circles is not None and len(circles):
            break
    if circles is None or not len(circles):
        for p2 in (60, 40, 25):
            circles = cv2.HoughCircles(small8, cv2.HOUGH_GRADIENT, dp=1.5, minDist=side,
                                       param1=80, param2=p2, minRadius=rmin, maxRadius=rmax)
            if circles is not None and len(circles):
                break
    if circles is None or not len(circles):
        raise InputError("no mirror ball found in the image (give its circle with --ball CX,CY,R)")
    c = np.asarray(circles).reshape(-1, 3)
    c = c[0]  # OpenCV lists the best-supported circle first
    guess = Circle((c[0] + 0.5) / scale, (c[1] + 0.5) / scale, c[2] / scale)
    circ = refine_circle(pixels, guess)
    # second pass in a narrow band: interior edges near the rim cannot compete; most of
    # the rim must then lie on one circle (noise or clutter does not)
    circ = refine_circle(pixels, circ, search=max(2.0 / circ.r, 0.03), outermost=True, min_inliers=0.5)
    contrast = rim_contrast(pixels, circ)
    if contrast < min_contrast:
        raise InputError(
            f"no mirror ball found: the best circle's rim has {100 * contrast:.1f}% contrast "
            "(give the ball's circle with --ball CX,CY,R)"
        )
    return circ


def rim_contrast(pixels: np.ndarray, circle: Circle, *, offset: float = 2.0, n_rays: int = 180) -> float:
    """Median over the rim of ``|log L(r + offset) - log L(r - offset)|`` (luminance just
    outside vs. just inside the circle): how clearly the circle separates two regions.
    A mirror ball shows tens of percent; noise or a flat wall shows a fraction of one."""
    lum = np.maximum(_luminance(pixels), 1e-8).astype(np.float32)
    lum = cv2.GaussianBlur(lum, (0, 0), 0.7)
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    vals = []
    for rr in (circle.r + offset, max(circle.r - offset, 1.0)):
        xs = (circle.cx + rr * np.cos(ang) - 0.5).astype(np.float32)[None, :]
        ys = (circle.cy + rr * np.sin(ang) - 0.5).astype(np.float32)[None, :]
        vals.append(cv2.remap(lum, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0])
    return float(np.median(np.abs(np.log(vals[0] / vals[1]))))


def ball_mask(shape: tuple[int, int], circle: Circle, *, shrink: float = 0.0) -> np.ndarray:
    """Pixels whose centres lie inside ``circle`` (radius reduced by ``shrink`` pixels).

    Returns:
        (H, W) bool mask.
    """
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    return np.hypot(xx + 0.5 - circle.cx, yy + 0.5 - circle.cy) < circle.r - shrink


# --------------------------------------------------------------------------------------
# Unwrapping
# --------------------------------------------------------------------------------------


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
        pixels: (H, 2H, 3) linear radiance, equirectangular (DESIGN.md), masked texels filled.
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
    H, W = int(height), 2 * int(height)
    texel = math.pi / (H - 1)
    if supersample is None:
        # angular size of one photo pixel at the ball's centre is ~2/r radians
        supersample = int(min(8, max(1, math.ceil(texel / (2.0 / circle.r)))))
    s = int(supersample)
    offs = (np.arange(s) + 0.5) / s - 0.5
    u0 = (np.arange(W) + 0.5) / W
    v0 = np.arange(H) / (H - 1)
    acc = np.zeros((H, W, 3))
    wsum = np.zeros((H, W, 1))
    hit_any = np.zeros((H, W), dtype=bool)
    img32 = img.astype(np.float32)
    ih, iw = img.shape[:2]
    for du in offs:
        for dv in offs:
            u = u0 + du / W
            v = np.clip(v0 + dv / (H - 1), 0.0, 1.0)
            phi = 2 * np.pi * u[None, :]
            th = np.pi * v[:, None]
            st = np.sin(th)
            dirs = np.stack(np.broadcast_arrays(st * np.sin(phi), np.cos(th), -st * np.cos(phi)), axis=-1)
            if rotation:
                c, sn = math.cos(rotation), math.sin(rotation)
                x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
                dirs = np.stack([c * x + sn * z, y, -sn * x + c * z], axis=-1)
            n = _ball_points(dirs, distance)
            if distance is None:
                px, py = n[..., 0], n[..., 1]
            else:
                focal = 1.0 / math.tan(math.asin(1.0 / distance))
                depth = distance - n[..., 2]
                px, py = focal * n[..., 0] / depth, focal * n[..., 1] / depth
            mx = (circle.cx + circle.r * px - 0.5).astype(np.float32)
            my = (circle.cy - circle.r * py - 0.5).astype(np.float32)
            inb = (mx >= -0.5) & (mx <= iw - 0.5) & (my >= -0.5) & (my <= ih - 0.5)
            samp = cv2.remap(img32, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            wgt = np.maximum(st, 1e-6) * np.ones((1, W))
            wgt = np.where(inb, wgt, 0.0)[..., None]
            acc += samp.astype(np.float64) * wgt
            wsum += wgt
            hit_any |= inb
    out = acc / np.maximum(wsum, 1e-300)
    dirs_c = texel_directions(H, W)
    if rotation:
        c, sn = math.cos(rotation), math.sin(rotation)
        x, y, z = dirs_c[..., 0], dirs_c[..., 1], dirs_c[..., 2]
        dirs_c = np.stack([c * x + sn * z, y, -sn * x + c * z], axis=-1)
    back = np.degrees(np.arccos(np.clip(-dirs_c[..., 2], -1, 1)))
    front = np.degrees(np.arccos(np.clip(dirs_c[..., 2], -1, 1)))
    valid = (back > rim_mask_deg) & hit_any & (wsum[..., 0] > 0)
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


# --------------------------------------------------------------------------------------
# HDR merge
# --------------------------------------------------------------------------------------


def exposure_stops(times: Sequence[float]) -> float:
    """Span of a bracket in stops: ``log2(max time / min time)``."""
    t = np.asarray(times, dtype=np.float64)
    return float(np.log2(t.max() / t.min())) if t.size else 0.0


def recover_response(codes: Sequence[np.ndarray], times: Sequence[float], *, method: str = "debevec",
                     samples: int = 200, smoothness: float = 10.0) -> np.ndarray:
    """Recover a camera's response curve from a bracket of 8-bit exposures (OpenCV).

    ``method="debevec"``: Debevec & Malik 1997, "Recovering high dynamic range radiance maps
    from photographs" (SIGGRAPH), the least-squares solve of their eq. (3) with a smoothness
    term (``cv2.createCalibrateDebevec``). ``method="robertson"``: Robertson, Borman &
    Stevenson 2003, "Estimation-theoretic approach to dynamic range enhancement using
    multiple exposures", J. Electronic Imaging 12(2) (``cv2.createCalibrateRobertson``).

    Args:
        codes: exposures as (H, W, 3) uint8 arrays (the camera's code values, RGB order).
        times: exposure times in seconds, one per exposure.
        method: "debevec" or "robertson".

    Returns:
        (256, 3) float64: relative linear exposure for each code value and channel, made
        monotone and scaled so that the codes 250-255 average 1 (a recovered curve is
        defined only up to scale).
    """
    if len(codes) < 2:
        raise InputError("recovering a response curve needs at least two exposures")
    imgs = []
    for c in codes:
        c = np.asarray(c)
        if c.dtype != np.uint8 or c.ndim != 3 or c.shape[2] != 3:
            raise InputError("response recovery needs 8-bit RGB exposures")
        imgs.append(np.ascontiguousarray(c[..., ::-1]))  # OpenCV works in BGR
    t = np.asarray(times, dtype=np.float32)
    if method == "debevec":
        cal = cv2.createCalibrateDebevec(samples=samples, lambda_=smoothness, random=False)
    elif method == "robertson":
        cal = cv2.createCalibrateRobertson()
    else:
        raise InputError(f"unknown response recovery method {method!r} (debevec, robertson)")
    resp = np.asarray(cal.process(imgs, t), dtype=np.float64).reshape(256, 3)[:, ::-1]
    resp = np.maximum.accumulate(np.maximum(resp, 0.0), axis=0)  # monotone, non-negative
    top = resp[250:].mean()
    return resp / top if top > 0 else resp


def apply_response(codes: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Linearise 8-bit code values with a (256, 3) response table: out[..., c] = response[code, c]."""
    codes = np.asarray(codes)
    return np.stack([response[codes[..., c], c] for c in range(3)], axis=-1)


@dataclass
class HdrMerge:
    """A merged HDR image.

    Attributes:
        radiance: (H, W, 3) linear radiance, in units of (pixel value) / (exposure time).
        clipped: (H, W) bool, pixels clipped in every exposure: there the value is the
            darkest exposure's (a lower bound).
        underexposed: (H, W) bool, pixels below the noise floor in every exposure.
        used: (H, W) int, number of exposures that contributed to each pixel.
    """

    radiance: np.ndarray
    clipped: np.ndarray
    underexposed: np.ndarray
    used: np.ndarray


def merge_exposures(
    images: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    saturated: Sequence[np.ndarray | None] | None = None,
    method: str = "robertson",
    clip_level: float = 0.98,
    noise_floor: float | None = None,
) -> HdrMerge:
    """Merge a bracket of linearised exposures into one radiance image.

    Each exposure j gives a radiance estimate ``x_ij / t_j`` where it is neither clipped nor
    lost in noise. ``method="robertson"`` combines them with the maximum-likelihood estimator
    of Robertson, Borman & Stevenson 2003 (J. Electronic Imaging 12(2), eq. 12 with unit
    weights): ``E_i = sum_j w_ij t_j x_ij / sum_j w_ij t_j^2``, which trusts long exposures
    most (their relative quantisation and noise are smallest). ``method="debevec"`` averages
    log radiance with Debevec & Malik 1997's hat weights (their eq. 6), the hat measured on
    the sRGB-encoded value.

    Clipping. A clipped pixel says only "at least 1 / t_j"; any weight it gets pulls a sun
    (clipped in all exposures but the darkest) below its radiance. OpenCV's triangle weights
    are small but not zero at code 255; with OpenCV 5.0 and the sRGB response given,
    ``cv2.createMergeDebevec`` nevertheless recovered such a sun within 0.3% on our
    synthetic 12-stop brackets, but it needs 8-bit input, a 256-entry response and cannot
    report which pixels were clipped everywhere. Here a pixel gets weight 0 in an exposure
    where any channel reaches ``clip_level`` (linear) or where the file flagged it
    saturated, so the sun comes only from the exposures that did not clip it; this works
    for 8-bit, 16-bit and float inputs alike. A pixel clipped in *every* exposure falls back to the darkest
    exposure's value (a lower bound) and is reported in ``clipped``; one below
    ``noise_floor`` in every exposure falls back to the longest exposure and is reported in
    ``underexposed``.

    Args:
        images: exposures as (H, W, 3) linear arrays in [0, 1] (response already applied,
            e.g. by :func:`bubblefit.io.images.read_image` or :func:`apply_response`).
        times: exposure time of each image, seconds (only ratios matter).
        saturated: optional (H, W) bool masks of clipped pixels, one per image.
        method: "robertson" (default) or "debevec".
        clip_level: linear value at or above which a channel counts as clipped.
        noise_floor: linear value below which an exposure's pixel (robertson: all its
            channels; debevec: that channel) is not trusted. Default 1e-3 for robertson,
            whose ``t_j^2`` weights already discount short exposures, and 2e-2 for debevec,
            whose log average amplifies the quantisation error of small values (measured on
            8-bit sRGB brackets 2 stops apart: max error 16% with 1e-3, 3% with 2e-2).

    Returns:
        An :class:`HdrMerge`.
    """
    if len(images) == 0:
        raise InputError("no exposures to merge")
    if len(times) != len(images):
        raise InputError(f"{len(images)} exposures but {len(times)} exposure times")
    t = np.asarray(times, dtype=np.float64)
    if not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise InputError(f"exposure times must be positive, got {list(times)}")
    shape = np.shape(images[0])
    for im in images:
        if np.shape(im) != shape:
            raise InputError(f"exposures differ in size: {shape[:2]} and {np.shape(im)[:2]}")
    if len(shape) != 3 or shape[2] != 3:
        raise InputError(f"exposures must be (H, W, 3), got {shape}")
    if method not in ("robertson", "debevec"):
        raise InputError(f"unknown merge method {method!r} (robertson, debevec)")
    if saturated is None:
        saturated = [None] * len(images)
    if noise_floor is None:
        noise_floor = 1e-3 if method == "robertson" else 2e-2
    h, w = shape[:2]
    num = np.zeros((h, w, 3))
    den = np.zeros((h, w, 1 if method == "robertson" else 3))
    used = np.zeros((h, w), dtype=np.int32)
    order = np.argsort(t)
    for j, (im, tj) in enumerate(zip(images, t)):
        x = np.clip(np.asarray(im, dtype=np.float64), 0.0, None)
        clip = np.any(x >= clip_level, axis=-1)
        if saturated[j] is not None:
            clip |= np.asarray(saturated[j], dtype=bool)
        ok = ~clip & (np.max(x, axis=-1) >= noise_floor)
        if method == "robertson":
            wj = ok[..., None] * 1.0
            num += wj * tj * x
            den += wj * tj * tj
        else:
            z = np.clip(x, 0.0, 1.0)
            zenc = np.where(z <= 0.0031308, 12.92 * z, 1.055 * np.power(z, 1 / 2.4) - 0.055)
            hat = np.minimum(zenc, 1.0 - zenc)
            wj = ok[..., None] * hat * (x >= noise_floor)
            num += wj * (np.log(np.maximum(x, 1e-12)) - math.log(tj))
            den += wj
        used += ok
    none = used == 0
    if method == "robertson":
        rad = num / np.maximum(den, 1e-300)
    else:
        rad = np.exp(num / np.maximum(den, 1e-300))
    # Fallbacks where no exposure was trusted: the longest exposure that is not clipped
    # (the pixel is dark everywhere), else the darkest exposure (clipped everywhere).
    fallback = None
    unclipped_any = np.zeros((h, w), dtype=bool)
    for j in order:
        x = np.clip(np.asarray(images[j], dtype=np.float64), 0.0, None)
        clip = np.any(x >= clip_level, axis=-1)
        if saturated[j] is not None:
            clip |= np.asarray(saturated[j], dtype=bool)
        est = x / t[j]
        if fallback is None:
            fallback = est
        else:
            fallback = np.where(~clip[..., None], est, fallback)
        unclipped_any |= ~clip
    clipped_all = none & ~unclipped_any
    under_all = none & unclipped_any
    rad = np.where(none[..., None] | (den <= 0), fallback, rad)
    return HdrMerge(radiance=rad, clipped=clipped_all, underexposed=under_all, used=used)
