"""Independent renderer of flat films and gaps (numpy + colour-science; imports nothing from bubblefit).

Physics, written from the optics for this validation set:

* A layer of index n1 and thickness d between a medium n0 (the light's side) and n2.
  Amplitude reflection per polarisation from Airy's sum of all the beams, in complex
  form: ``r = (r01 + r12 e^{2 i b}) / (1 + r01 r12 e^{2 i b})``, ``b = 2 pi n1 d cos t1 / lambda``,
  Fresnel's s and p coefficients at each face; ``R = |r|^2``, s and p averaged (the lamp
  is unpolarised).
* Media: BK7 from the SCHOTT Sellmeier data sheet, water from Daimon & Masumura's (2007)
  Sellmeier formula at 20 C (a different law from the one bubblefit ships), air = 1.
* Coaxial light through an objective of numerical aperture NA: the reflectance averaged
  over the illumination cone with weight cos(theta) dOmega, i.e. uniform in
  u = sin^2(theta_air) over [0, NA^2], taken with 64 midpoint nodes; the light enters the
  medium above through a parallel face (n0 sin t0 = sin t_air).
* Area light: a Lambertian rectangle of radiance 1; a pixel of a pinhole camera sees the
  panel's radiance times R at its ray's incidence angle when the ray's mirror direction
  off the film plane hits the panel, else black.
* Colour: the spectrum R(lambda) S(lambda) (S the lamp: D65 from colour-science, or a
  black body from Planck's law) integrated against the CIE 1931 2 degree observer every 1
  nm over 380-780 nm, XYZ -> linear sRGB (IEC 61966-2-1), divided per channel by the same
  integral of R = 1 (the camera white-balanced to the lamp).
* Sensor: Poisson-Gaussian noise and 8-bit sRGB quantisation (vio.add_noise_and_quantise).
"""

from __future__ import annotations

import numpy as np

VERSION = "validation-films 1.0"

XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])


def colour_weights(lamp: str, step: float = 1.0):
    """(lam (N,), weights (3, N)) with rgb = weights @ R(lambda) and R = 1 -> (1, 1, 1)."""
    import colour

    lam = np.arange(380.0, 780.0 + 1e-9, step)
    shape = colour.SpectralShape(380, 780, step)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape).values
    if lamp.upper().endswith("K"):
        t = float(lamp[:-1])
        s = np.asarray(colour.sd_blackbody(t, shape).values)
    else:
        s = colour.SDS_ILLUMINANTS[lamp].copy().align(shape).values
    w = XYZ_TO_SRGB @ (cmfs * s[:, None]).T
    return lam, w / w.sum(axis=1, keepdims=True)


def index(medium, lam):
    """Refractive index of a named medium at lam (nm)."""
    if isinstance(medium, (int, float)):
        return np.full_like(lam, float(medium))
    l2 = (lam / 1000.0) ** 2  # um^2
    if medium == "air":
        return np.ones_like(lam)
    if medium == "bk7":
        b, c = (1.03961212, 0.231792344, 1.01046945), (0.00600069867, 0.0200179144, 103.560653)
    elif medium == "water":   # Daimon & Masumura 2007, 20 C, four-term Sellmeier
        b, c = (5.684027565e-1, 1.726177391e-1, 2.086189578e-2, 1.130748688e-1), \
               (5.101829712e-3, 1.821153936e-2, 2.620722293e-2, 1.069792721e1)
    else:
        raise ValueError(medium)
    n2 = 1.0 + sum(bi * l2 / (l2 - ci) for bi, ci in zip(b, c))
    return np.sqrt(n2)


def stack_reflectance(d_nm, lam, n0, n1, n2, sin2_air):
    """Unpolarised R of n0 | n1 (d) | n2; d_nm (...,), sin2_air scalar or (...,); returns (..., N)."""
    d = np.asarray(d_nm, float)[..., None]
    s2 = np.asarray(sin2_air, float)
    s2 = s2[..., None] if s2.ndim else s2
    c = [np.sqrt((1 - s2 / n ** 2).astype(complex)) for n in (n0, n1, n2)]
    rs01 = (n0 * c[0] - n1 * c[1]) / (n0 * c[0] + n1 * c[1])
    rs12 = (n1 * c[1] - n2 * c[2]) / (n1 * c[1] + n2 * c[2])
    rp01 = (n1 * c[0] - n0 * c[1]) / (n1 * c[0] + n0 * c[1])
    rp12 = (n2 * c[1] - n1 * c[2]) / (n2 * c[1] + n1 * c[2])
    e = np.exp(2j * (2 * np.pi * n1 * d * c[1] / lam))
    out = 0.0
    for a, b in ((rs01, rs12), (rp01, rp12)):
        out = out + 0.5 * np.abs((a + b * e) / (1 + a * b * e)) ** 2
    return out


def coaxial_rgb(d_nm, lamp, media, na, nodes=64):
    """Linear RGB (..., 3) of thickness d under coaxial light of numerical aperture na."""
    lam, w = colour_weights(lamp)
    n0, n1, n2 = (index(m, lam) for m in media)
    u = (np.arange(nodes) + 0.5) / nodes * na * na
    spec = sum(stack_reflectance(d_nm, lam, n0, n1, n2, uk) for uk in u) / nodes
    return spec @ w.T


def newton_case(size=128, pixel_um=9.0, radius_mm=100.0, na=0.1, center=(61.3, 66.8), h0_nm=0.0,
                lamp="3200K", media=("bk7", "air", "bk7"), sub=16, table_step_nm=0.1):
    """Gap (H, W) nm at the pixel centres and RGB (H, W, 3) of a lens of radius R on a plate
    under coaxial light, each pixel the mean over its square of ``sub`` x ``sub`` points
    (midpoints of equal sub-squares: a camera's pixel collects the light of its whole area).

    The colour depends on the gap alone, so it is computed once on a grid of gaps every
    ``table_step_nm`` (:func:`coaxial_rgb`) and read at each point by linear
    interpolation: the fringe of the shortest wavelength spans 190 nm of gap, and a 0.1 nm
    step leaves an interpolation error under (2 pi 0.1 / 190)^2 / 8 = 1.4e-6 of its amplitude."""
    R = radius_mm * 1000.0

    def gap(x, y):
        r_um = pixel_um * np.hypot(x - center[0], y - center[1])
        return 1000.0 * (R - np.sqrt(R * R - r_um ** 2)) + h0_nm

    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    h = gap(xx, yy)
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    corner = float(np.max(gap(np.array([0.0, size, 0.0, size]), np.array([0.0, 0.0, size, size]))))
    grid = np.arange(min(h0_nm, 0.0), corner + 2 * table_step_nm, table_step_nm)
    table = np.concatenate([coaxial_rgb(grid[i:i + 2000], lamp, media, na) for i in range(0, len(grid), 2000)])
    rgb = np.zeros((size, size, 3))
    for oy in offs:
        for ox in offs:
            hs = gap(xx + ox, yy + oy)
            rgb += np.stack([np.interp(hs, grid, table[:, c]) for c in range(3)], axis=-1)
    return h, rgb / (sub * sub)


def drainage_area_case(size=128, top_nm=120.0, bottom_nm=1100.0, exponent=1.3, lamp="D65", n_film="water",
                       cam_dist=0.6, fov_deg=30.0, film_half=0.09, panel_z=0.7, panel_half=0.5):
    """A vertical film in the plane z = 0 (normal +z), thickness growing downwards,
    seen by a pinhole camera at (0, 0, cam_dist) looking at -z, lit by a panel at z =
    panel_z behind the camera (facing -z, half-size panel_half). Returns (d (H, W) nm,
    NaN off the film, rgb (H, W, 3), cos_i (H, W))."""
    lam, w = colour_weights(lamp)
    n1 = index(n_film, lam)
    one = np.ones_like(lam)
    t = np.tan(np.radians(fov_deg) / 2)
    j, i = np.mgrid[0:size, 0:size] + 0.5
    x = (2 * i / size - 1) * t
    y = (1 - 2 * j / size) * t
    dirs = np.stack([x, y, -np.ones_like(x)], -1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    tt = cam_dist / -dirs[..., 2]
    px, py = tt * dirs[..., 0], tt * dirs[..., 1]
    on = (np.abs(px) <= film_half) & (np.abs(py) <= film_half)
    mirror = dirs * np.array([1, 1, -1])
    s = panel_z / mirror[..., 2]
    qx, qy = px + s * mirror[..., 0], py + s * mirror[..., 1]
    lit = (np.abs(qx) <= panel_half) & (np.abs(qy) <= panel_half)
    mask = on & lit
    frac = np.clip((film_half - py) / (2 * film_half), 0, 1)   # 0 at the top edge, 1 at the bottom
    d = top_nm + (bottom_nm - top_nm) * frac ** exponent
    cos_i = -dirs[..., 2]
    spec = stack_reflectance(d, lam, one, n1, one, 1 - cos_i ** 2)
    rgb = np.where(mask[..., None], spec @ w.T, 0.0)
    return np.where(mask, d, np.nan), rgb, cos_i
