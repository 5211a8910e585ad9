"""An independent spectral soap-bubble renderer in numpy (imports nothing from bubblefit).

Physics (written from the optics, not from bubblefit's code):

* The bubble is a sphere of radius R carrying a film of index ``n_film`` in air, of local
  thickness d(p) (constant, a drainage profile, or a drainage profile plus a Gaussian bump).
* A film is air | film | air. Its amplitude reflection per polarisation is Airy's sum of
  all the beams, ``r = r01 (1 - e^{2i beta}) / (1 - r01^2 e^{2i beta})`` with
  ``beta = 2 pi n d cos(theta_t) / lambda`` and ``r01`` Fresnel's s or p coefficient; the
  film reflects ``R = |r|^2`` and, lossless and with air on both sides, transmits
  ``T = 1 - R``. The film is parallel-sided, so a transmitted ray keeps its direction.
* A camera ray meets the front film at p1 (incidence theta). Inside a sphere every chord
  meets the film at the same angle theta, and every hit of one ray stays in the plane of
  the ray and the centre, so s and p are the same two eigen-polarisations at every hit
  and are carried separately through the whole path and averaged only at the end.
  Paths summed per ray:
    front reflection       R(p1) L(reflected direction)
    straight through       T(p1) T(p2) B(ray)            (the background)
    k-th internal bounce   T(p1) R(p2) ... R(p_{k+1}) T(p_{k+2}) L(d_k), k = 1..bounces
  with d_k the direction after k internal mirror reflections.
* Every path's spectral factor F(lambda) (averaged over s and p) becomes an RGB factor by
  integrating against the CIE 1931 2 degree observer under an illuminant (D65 or E),
  converting XYZ to linear sRGB (Rec.709) and dividing per channel by the same integral
  of a flat F = 1, so flat 1 gives (1, 1, 1). The RGB factor multiplies the map's RGB
  radiance in the path's direction (the shared docs/design.md contract for RGB maps).
* Environment lookups: equirectangular, u = atan2(x, -z)/(2 pi), v = acos(y)/pi, bilinear
  with column u W - 1/2 (wrapping) and row v (H - 1) (clamped), map rotated about +y by
  ``rotation_deg`` (a world direction w reads the map at R_y(-rotation) w).
* Pixels: 4x4 regular supersamples (box filter), pixel centres at +0.5.
* Sensor: Poisson-Gaussian noise and 8-bit sRGB quantisation (vio.add_noise_and_quantise).

Cameras: ``ortho`` (the disc {cx, cy, r} in pixels fixes the projection; rays along -z)
and ``persp`` (origin, target, up, fov_deg along the width, pixel centres at +0.5, image
right = forward x up). Background ``env`` is the map seen along each camera ray;
``backdrop`` (orthographic only) is a textured backdrop: the map as a perspective camera of
``backdrop_fov_deg`` would see it, seen only by rays that pass straight through the bubble
(reflected and bounced rays see the map itself).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

VERSION = "validation-reference 1.0"


# ---------------------------------------------------------------- spectra and colour
@dataclass
class Spectral:
    lam: np.ndarray          # (N,) nm
    weights: np.ndarray      # (3, N): rgb = weights @ F(lambda), flat F = 1 -> (1, 1, 1)
    illuminant: str


def spectral_setup(illuminant: str = "D65", step: float = 2.0) -> Spectral:
    import colour

    lam = np.arange(380.0, 780.0 + 1e-9, step)
    shape = colour.SpectralShape(380, 780, step)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape).values  # (N, 3)
    if illuminant.upper() == "E":
        s = np.ones_like(lam)
    else:
        s = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape).values
    xyz_to_rgb = np.array([[3.2404542, -1.5371385, -0.4985314],
                           [-0.9692660, 1.8760108, 0.0415560],
                           [0.0556434, -0.2040259, 1.0572252]])      # IEC 61966-2-1 / Rec.709
    w = xyz_to_rgb @ (cmfs * s[:, None]).T                         # (3, N)
    w = w / w.sum(axis=1, keepdims=True)                            # flat 1 -> (1, 1, 1)
    return Spectral(lam=lam, weights=w, illuminant=illuminant)


# ---------------------------------------------------------------- the film
def fresnel_r01(n: float, cos_i: np.ndarray):
    """Amplitude reflection air -> medium n (s, p) and cos of the refracted angle."""
    sin2_t = (1.0 - cos_i ** 2) / n ** 2
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, 1.0))
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return rs, rp, cos_t


def airy_film(n: float, d_nm: np.ndarray, cos_i: np.ndarray, lam: np.ndarray):
    """Film (air | n, thickness d | air) power reflectance per polarisation.

    ``d_nm`` and ``cos_i`` broadcast together to shape S; returns (Rs, Rp), each S + (N,).
    Closed form of Airy's sum with r12 = -r01: R = 2 rho (1 - cos 2b) / (1 + rho^2 - 2 rho cos 2b),
    rho = r01^2, b = 2 pi n d cos_t / lambda. T = 1 - R.
    """
    d_nm, cos_i = np.broadcast_arrays(np.asarray(d_nm, float), np.asarray(cos_i, float))
    rs, rp, cos_t = fresnel_r01(n, cos_i)
    two_beta = (4.0 * np.pi * n) * (d_nm * cos_t)[..., None] / lam
    c = np.cos(two_beta)
    out = []
    for r in (rs, rp):
        rho = (r * r)[..., None]
        out.append(2.0 * rho * (1.0 - c) / (1.0 + rho * rho - 2.0 * rho * c))
    return out[0], out[1]


def incoherent_film(n: float, cos_i: np.ndarray):
    """Thick-film limit per polarisation: 2 R / (1 + R) of a slab's two interfaces."""
    rs, rp, _ = fresnel_r01(n, cos_i)
    return [2 * r * r / (1 + r * r) for r in (rs, rp)]


# ---------------------------------------------------------------- thickness fields
@dataclass
class Thickness:
    """Film thickness (nm) on the unit sphere: ``kind`` constant | drainage | bump."""
    kind: str = "constant"
    value_nm: float = 500.0
    top_nm: float = 150.0
    bottom_nm: float = 900.0
    exponent: float = 1.0
    bump_nm: float = 40.0
    bump_center: tuple = (0.25, 0.2, 0.9465)   # a unit vector on the front (camera side, +z)
    bump_sigma: float = 0.15                    # Gaussian sigma, in radii (chord distance)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """q: (..., 3) points on the unit sphere (relative to the centre, over R)."""
        if self.kind == "constant":
            return np.full(q.shape[:-1], float(self.value_nm))
        y = np.clip(q[..., 1], -1.0, 1.0)
        d = self.top_nm + (self.bottom_nm - self.top_nm) * ((1.0 - y) / 2.0) ** self.exponent
        if self.kind == "bump":
            c = np.asarray(self.bump_center, float)
            c = c / np.linalg.norm(c)
            dist2 = ((q - c) ** 2).sum(axis=-1)
            d = d + self.bump_nm * np.exp(-dist2 / (2 * self.bump_sigma ** 2))
        elif self.kind != "drainage":
            raise ValueError(self.kind)
        return d

    def describe(self) -> dict:
        if self.kind == "constant":
            return {"profile": "constant", "thickness_nm": self.value_nm}
        out = {"profile": "drainage" if self.kind == "drainage" else "drainage+bump",
               "top_nm": self.top_nm, "bottom_nm": self.bottom_nm, "exponent": self.exponent,
               "formula": "d = top + (bottom - top) ((1 - y)/2)^exponent, y = height over radius"}
        if self.kind == "bump":
            c = np.asarray(self.bump_center, float)
            out.update(bump_nm=self.bump_nm, bump_center_unit=(c / np.linalg.norm(c)).tolist(),
                       bump_sigma_radii=self.bump_sigma,
                       bump_formula="+ bump_nm exp(-|q - c|^2 / (2 sigma^2)), q, c on the unit sphere")
        return out


# ---------------------------------------------------------------- environment map
def env_lookup(env: np.ndarray, d: np.ndarray, rotation_deg: float = 0.0) -> np.ndarray:
    """Bilinear lookup (docs/design.md convention) of directions d (..., 3)."""
    if rotation_deg:
        a = -math.radians(rotation_deg)         # the map is turned by +rotation: read at R_y(-rot) w
        c, s = math.cos(a), math.sin(a)
        x, y, z = d[..., 0], d[..., 1], d[..., 2]
        d = np.stack([c * x + s * z, y, -s * x + c * z], axis=-1)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    h, w, _ = env.shape
    u = np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)
    u = u - np.floor(u)
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    x = u * w - 0.5
    yy = v * (h - 1)
    x0 = np.floor(x)
    y0 = np.clip(np.floor(yy), 0, h - 2)
    fx = (x - x0)[..., None]
    fy = np.clip(yy - y0, 0, 1)[..., None]
    x0 = x0.astype(int) % w
    x1 = (x0 + 1) % w
    y0 = y0.astype(int)
    y1 = np.minimum(y0 + 1, h - 1)
    top = env[y0, x0] * (1 - fx) + env[y0, x1] * fx
    bot = env[y1, x0] * (1 - fx) + env[y1, x1] * fx
    return top * (1 - fy) + bot * fy


# ---------------------------------------------------------------- cameras
@dataclass
class Camera:
    kind: str                 # "ortho" | "persp"
    width: int
    height: int
    disc: tuple = None        # ortho: (cx, cy, r) pixels of the unit... sphere of radius R at centre
    origin: tuple = (0.0, 0.0, 4.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0

    def rays(self, px: np.ndarray, py: np.ndarray, center, radius):
        """Rays through image positions (px right, py down, continuous pixel units)."""
        if self.kind == "ortho":
            cx, cy, r = self.disc
            x = center[0] + (px - cx) / r * radius
            y = center[1] - (py - cy) / r * radius
            o = np.stack([x, y, np.full_like(x, center[2] + 10.0 * radius)], axis=-1)
            d = np.broadcast_to(np.array([0.0, 0.0, -1.0]), o.shape).copy()
            return o, d
        o = np.asarray(self.origin, float)
        f = np.asarray(self.target, float) - o
        f /= np.linalg.norm(f)
        right = np.cross(f, np.asarray(self.up, float))
        right /= np.linalg.norm(right)
        up = np.cross(right, f)
        tx = math.tan(math.radians(self.fov_deg) / 2)
        sx = (2 * px / self.width - 1) * tx
        sy = (1 - 2 * py / self.height) * tx * self.height / self.width
        d = f + sx[..., None] * right + sy[..., None] * up
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.broadcast_to(o, d.shape).copy(), d

    def describe(self) -> dict:
        if self.kind == "ortho":
            return {"type": "orthographic", "width": self.width, "height": self.height,
                    "disc": list(self.disc)}
        return {"type": "perspective", "width": self.width, "height": self.height,
                "origin": list(self.origin), "target": list(self.target), "up": list(self.up),
                "fov_deg": self.fov_deg, "fov_axis": "width"}

    def disc_pixels(self, center, radius):
        """The sphere's outline centre and radius in pixels (exact for a sphere on the optical
        axis; for an off-axis sphere in perspective the outline is an ellipse and this gives
        the projected centre and the mean radius)."""
        if self.kind == "ortho":
            return tuple(float(x) for x in self.disc)
        o = np.asarray(self.origin, float)
        c = np.asarray(center, float)
        dist = np.linalg.norm(c - o)
        alpha = math.asin(radius / dist)
        fpx = (self.width / 2) / math.tan(math.radians(self.fov_deg) / 2)
        f = np.asarray(self.target, float) - o
        f /= np.linalg.norm(f)
        right = np.cross(f, np.asarray(self.up, float))
        right /= np.linalg.norm(right)
        up = np.cross(right, f)
        v = c - o
        zc = v @ f
        cx = self.width / 2 + fpx * (v @ right) / zc
        cy = self.height / 2 - fpx * (v @ up) / zc
        # mean outline radius: tangent-cone half angle alpha about the centre direction
        beta = math.acos(np.clip(zc / dist, -1, 1))
        r_a = fpx * 0.5 * (math.tan(beta + alpha) - math.tan(beta - alpha))
        r_b = fpx * math.tan(alpha) / math.cos(beta) if beta > 1e-9 else fpx * math.tan(alpha)
        return float(cx), float(cy), float(0.5 * (r_a + r_b)) if beta > 1e-9 else float(fpx * math.tan(alpha))


# ---------------------------------------------------------------- the renderer
@dataclass
class Bubble:
    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0
    n_film: float = 1.4
    thickness: Thickness = field(default_factory=Thickness)
    interference: bool = True       # False: incoherent thick-film limit


def _intersect(o, d, c, R):
    oc = o - c
    b = (oc * d).sum(-1)
    cc = (oc * oc).sum(-1) - R * R
    disc = b * b - cc
    hit = disc > 0
    sq = np.sqrt(np.where(hit, disc, 0.0))
    return hit, -b - sq


def render(camera: Camera, bubble: Bubble | None, env: np.ndarray, spectral: Spectral, *,
           rotation_deg: float = 0.0, background: str = "env", backdrop_fov_deg: float = 50.0,
           bounces: int = 8, ss: int = 4, chunk: int = 8192):
    """Linear RGB image (H, W, 3) of the scene; ``bubble=None`` renders the background alone.

    Returns (image, thickness_map) with the front film's thickness at pixel centres (NaN off
    the bubble), or None for no bubble.
    """
    H, W = camera.height, camera.width
    off = (np.arange(ss) + 0.5) / ss
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    px = np.broadcast_to(jj[..., None, None] + off[None, None, None, :], (H, W, ss, ss)).reshape(-1)
    py = np.broadcast_to(ii[..., None, None] + off[None, None, :, None], (H, W, ss, ss)).reshape(-1)
    o, d = camera.rays(px, py, np.asarray(bubble.center if bubble else (0, 0, 0), float),
                       bubble.radius if bubble else 1.0)

    def backdrop(px_, py_, d_):
        if background == "env" or camera.kind == "persp":
            return env_lookup(env, d_, rotation_deg)
        t = math.tan(math.radians(backdrop_fov_deg) / 2)
        bx = (2 * px_ / W - 1) * t
        by = (1 - 2 * py_ / H) * t * H / W
        bd = np.stack([bx, by, -np.ones_like(bx)], axis=-1)
        return env_lookup(env, bd, rotation_deg)

    out = np.zeros((px.size, 3))
    if bubble is None:
        out = backdrop(px, py, d)
        return out.reshape(H, W, ss * ss, 3).mean(axis=2), None

    c = np.asarray(bubble.center, float)
    R = float(bubble.radius)
    hit, s1 = _intersect(o, d, c, R)
    miss = ~hit
    out[miss] = backdrop(px[miss], py[miss], d[miss])
    idx = np.nonzero(hit)[0]
    wts = spectral.weights
    lam = spectral.lam
    for k0 in range(0, idx.size, chunk):
        sel = idx[k0:k0 + chunk]
        dd = d[sel]
        p = o[sel] + s1[sel, None] * dd
        n1 = (p - c) / R
        cos_i = np.clip(-(dd * n1).sum(-1), 0.0, 1.0)

        def film(q):
            if bubble.interference:
                return airy_film(bubble.n_film, bubble.thickness((q - c) / R), cos_i, lam)
            rs, rp = incoherent_film(bubble.n_film, cos_i)
            return rs[:, None] * np.ones_like(lam), rp[:, None] * np.ones_like(lam)

        # front reflection
        Rf = film(p)
        refl = dd - 2 * (dd * n1).sum(-1, keepdims=True) * n1
        col = ((0.5 * (Rf[0] + Rf[1])) @ wts.T) * env_lookup(env, refl, rotation_deg)
        # inside: carry T(p1) per polarisation
        carry = [1.0 - Rf[0], 1.0 - Rf[1]]
        chord = (2 * R * cos_i)[:, None]
        q = p + chord * dd                  # rear hit
        dirn = dd.copy()
        # straight through the rear film: the background
        Rq = film(q)
        through = 0.5 * (carry[0] * (1 - Rq[0]) + carry[1] * (1 - Rq[1]))
        col += (through @ wts.T) * backdrop(px[sel], py[sel], dd)
        for _ in range(bounces):
            nq = (q - c) / R
            dirn = dirn - 2 * (dirn * nq).sum(-1, keepdims=True) * nq
            carry = [carry[0] * Rq[0], carry[1] * Rq[1]]
            q = q + chord * dirn
            Rq = film(q)
            esc = 0.5 * (carry[0] * (1 - Rq[0]) + carry[1] * (1 - Rq[1]))
            col += (esc @ wts.T) * env_lookup(env, dirn, rotation_deg)
        out[sel] = col
    img = out.reshape(H, W, ss * ss, 3).mean(axis=2)

    # front film thickness at pixel centres
    pcx, pcy = jj.reshape(-1) + 0.5, ii.reshape(-1) + 0.5
    o2, d2 = camera.rays(pcx.astype(float), pcy.astype(float), c, R)
    h2, s2 = _intersect(o2, d2, c, R)
    tmap = np.full(H * W, np.nan)
    p2 = o2[h2] + s2[h2, None] * d2[h2]
    tmap[h2] = bubble.thickness((p2 - c) / R)
    return img, tmap.reshape(H, W)


def t_incoherent_normal(n: float) -> float:
    """Per-interface transmission of the thick-film limit at normal incidence: sqrt(1 - 2R/(1+R))."""
    r = ((n - 1) / (n + 1)) ** 2
    return math.sqrt(1 - 2 * r / (1 + r))
