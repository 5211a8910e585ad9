"""Edge evidence for circles: gradients, their noise, Hough voting and rim support.

A pixel on a circle's outline has its intensity gradient along the circle's radius, so
the centre lies on the gradient line at distance r (Kimme, Ballard & Sklansky 1975,
"Finding circles by an array of accumulators", Comm. ACM 18(2)). Each strong-gradient
pixel casts one vote per radius at both points of its gradient line; a circle's votes
grow with its circumference, so the accumulator is divided by it. See ``docs/design.md``,
"Light probes".
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["LOG_NOISE_FLOOR", "gradients", "gradient_noise", "hough_circles", "rim_support"]

# Immerkaer 1996 ("Fast noise variance estimation", CVIU 64(2)): this Laplacian-difference
# mask cancels image structure up to second order and gives white noise of std sigma a
# response of std 6 sigma.
_IMMERKAER = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)

# Smallest pixel noise assumed, in log luminance: the quantisation of one 8-bit sRGB code
# at mid-grey (d ln L = 2.4 dV / (V + 0.055) at V = 0.5, dV = 1/255; std = step / sqrt(12)),
# so that a noise-free render is judged like the photograph it stands for.
LOG_NOISE_FLOOR = 2.4 / 255 / 0.555 / np.sqrt(12.0)


def gradients(img: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-smoothed (``sigma`` pixels) image gradient ``(d/dx, d/dy)`` per pixel (Sobel)."""
    g = cv2.GaussianBlur(np.asarray(img, np.float32), (0, 0), sigma) if sigma > 0 else np.asarray(img, np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return gx, gy


def gradient_noise(img: np.ndarray, sigma: float) -> float:
    """Standard deviation that pixel noise alone gives one component of :func:`gradients`.

    The pixel noise of the log-luminance image ``img`` is Immerkaer's estimate with a
    median (robust to edges and texture), ``median |I * M| / (0.6745 * 6)``, at least
    :data:`LOG_NOISE_FLOOR`; its gain through the smoothed Sobel filter is measured once on
    unit white noise.

    References
    ----------
    Immerkaer 1996, "Fast noise variance estimation", CVIU 64(2), 300-302.
    """
    img = np.asarray(img, np.float32)
    pixel = LOG_NOISE_FLOOR
    if min(img.shape) >= 3:
        resp = cv2.filter2D(img, cv2.CV_32F, _IMMERKAER)[1:-1, 1:-1]
        pixel = max(pixel, float(np.median(np.abs(resp))) / (0.6745 * 6.0))
    unit = np.random.default_rng(0).standard_normal((128, 128)).astype(np.float32)
    gain = float(np.std(gradients(unit, sigma)[0][8:-8, 8:-8]))
    return pixel * gain


def hough_circles(gx: np.ndarray, gy: np.ndarray, r_min: int, r_max: int, *, count: int = 10,
                  edge_fraction: float = 0.15) -> list[tuple[float, float, float]]:
    """The ``count`` best-supported circles ``(cx, cy, r)`` in pixels, best first.

    Parameters
    ----------
    gx, gy
        (H, W) image gradient.
    r_min, r_max
        Radii searched, in pixels (integer steps).
    count
        Number of candidates overall, plus ``max(2, count // 4)`` from each quarter of the
        radius range; each suppresses the others whose centre lies within ``max(3, 0.3 r)``
        pixels of its own.
    edge_fraction
        Fraction of the pixels, those with the strongest gradient, that vote. Every vote
        weighs one, so a faint rim counts as much as a bright one.

    Returns
    -------
    list of (cx, cy, r)
        Centres in continuous coordinates (pixel (i, j) centred at (j + 1/2, i + 1/2)).
        Ranked by votes per unit circumference times ``sqrt(r)``: the ball is the largest
        clear circle, not the most crowded small one.

    References
    ----------
    Kimme, Ballard & Sklansky 1975, Comm. ACM 18(2), 120-122.
    """
    h, w = gx.shape
    mag = np.hypot(gx, gy)
    thr = max(float(np.quantile(mag, 1.0 - edge_fraction)), 1e-12)
    ys, xs = np.nonzero(mag > thr)
    radii = np.arange(int(r_min), int(r_max) + 1)
    if ys.size == 0 or radii.size == 0:
        return []
    m = mag[ys, xs]
    ux, uy = gx[ys, xs] / m, gy[ys, xs] / m
    nr = radii.size
    acc = np.zeros(h * w * nr)
    ri = np.arange(nr)[None, :]
    for sign in (1.0, -1.0):
        cx = np.rint(xs[:, None] + sign * ux[:, None] * radii[None, :]).astype(np.int64)
        cy = np.rint(ys[:, None] + sign * uy[:, None] * radii[None, :]).astype(np.int64)
        ok = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
        idx = (cy * w + cx) * nr + ri
        acc += np.bincount(idx[ok], minlength=h * w * nr)
    acc = acc.reshape(h, w, nr).astype(np.float32)
    for k in range(0, nr, 256):  # OpenCV filters at most 512 channels at once
        acc[..., k:k + 256] = cv2.GaussianBlur(np.ascontiguousarray(acc[..., k:k + 256]), (0, 0), 1.0) \
            .reshape(h, w, -1)
    score = acc / (2 * np.pi * radii[None, None, :]) * np.sqrt(radii)[None, None, :]
    out: list[tuple[float, float, float]] = []
    _take_peaks(score, radii, count, out)
    # and the best few of each quarter of the radius range, so that a crowd of small
    # circles (a busy backdrop) cannot hide a large one
    for part in np.array_split(np.arange(nr), 4):
        if part.size:
            _take_peaks(score[..., part].copy(), radii[part], max(2, count // 4), out)
    return out


def _take_peaks(score: np.ndarray, radii: np.ndarray, count: int, out: list) -> None:
    """Append the ``count`` highest peaks of ``score`` (H, W, R) to ``out``, each clearing
    the centres within ``max(3, 0.3 r)`` of itself, skipping circles already in ``out``."""
    h, w = score.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(count):
        i = int(np.argmax(score))
        y, x, k = np.unravel_index(i, score.shape)
        if score[y, x, k] <= 0:
            break
        c = (x + 0.5, y + 0.5, float(radii[k]))
        if not any(abs(c[0] - o[0]) < 1 and abs(c[1] - o[1]) < 1 and abs(c[2] - o[2]) < 1 for o in out):
            out.append(c)
        score[np.hypot(xx - x, yy - y) < max(3.0, 0.3 * radii[k])] = 0.0


def rim_support(gx: np.ndarray, gy: np.ndarray, noise: float, circle: Circle, *, n_rays: int = 360,
                band: float = 1.0, min_snr: float = 4.0) -> float:
    """Fraction of the rim where the image has a sharp edge lying on ``circle``.

    Along each of ``n_rays`` rays, within ``band`` pixels of the circle, the strongest
    gradient counts as rim evidence when it is radial (its radial component at least 0.85
    of its length: an outline's gradient is normal to it) and at least ``min_snr`` times the
    gradient that pixel noise alone gives (:func:`gradient_noise`).
    Pure noise scores near 0; a ball whose outline is visible all round near 1. It does not
    depend on the rim's contrast, only on its being clear of the noise and on one circle.

    Parameters
    ----------
    gx, gy
        (H, W) gradient of the log luminance.
    noise
        Standard deviation of one gradient component from pixel noise.
    circle
        The circle to judge (anything with ``cx``, ``cy``, ``r``); rays leaving the image count as no evidence.

    Returns
    -------
    float
        Fraction of the rays, in [0, 1].
    """
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    ca, sa = np.cos(ang)[:, None], np.sin(ang)[:, None]
    dr = np.arange(-band, band + 1e-9, 0.5)[None, :]
    xs = (circle.cx + (circle.r + dr) * ca - 0.5).astype(np.float32)
    ys = (circle.cy + (circle.r + dr) * sa - 0.5).astype(np.float32)
    h, w = gx.shape
    inside = ((xs >= 0) & (xs <= w - 1) & (ys >= 0) & (ys <= h - 1)).all(axis=1)
    sx = cv2.remap(gx, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    sy = cv2.remap(gy, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    radial = np.abs(sx * ca + sy * sa)
    k = np.argmax(radial, axis=1)
    rows = np.arange(n_rays)
    peak = radial[rows, k]
    hit = (peak > min_snr * noise) & (peak > 0.85 * np.hypot(sx, sy)[rows, k]) & inside
    return float(np.mean(hit))
