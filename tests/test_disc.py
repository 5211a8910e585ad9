"""Disc detection (:func:`bubblefit.capture.disc.find_disc`) on images made here.

The bubbles are drawn by numpy code in this file, not by bubblefit's renderer: a disc
whose inside is the background dimmed by the two films' transmission plus a reflection
that brightens toward the rim as Schlick's approximation of Fresnel reflectance, 4x4
supersampled (antialiased rim), optionally blurred, with Poisson-Gaussian noise and
8-bit sRGB quantisation. Backgrounds are a crop of a real HDR map (the shipped
courtyard, read with OpenImageIO) or a bright procedural texture. Independent photos
rendered by Blender Cycles, Mitsuba 3 and a separate reference renderer are checked
when the validation set is present.
"""

from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage as ndi

from bubblefit.capture.disc import Disc, find_disc

SS = 4  # supersampling per axis


def _srgb_quantise(lin: np.ndarray) -> np.ndarray:
    """Linear -> 8-bit sRGB codes -> linear (IEC 61966-2-1), written out here."""
    x = np.clip(lin, 0, 1)
    enc = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    codes = np.round(enc * 255) / 255
    return np.where(codes <= 0.04045, codes / 12.92, ((codes + 0.055) / 1.055) ** 2.4)


def _noisy(lin: np.ndarray, rng, full_well: float = 3000.0, read: float = 3.0) -> np.ndarray:
    e = rng.poisson(np.clip(lin, 0, None) * full_well) + rng.normal(0, read, lin.shape)
    return _srgb_quantise(e / full_well)


def _texture(h: int, w: int, rng, bright: bool = True) -> np.ndarray:
    """A bright, busy procedural background: smoothed noise at three scales, with edges."""
    out = np.zeros((h, w, 3))
    for s, a in ((1.5, 0.25), (4.0, 0.35), (12.0, 0.4)):
        f = ndi.gaussian_filter(rng.normal(size=(h, w, 3)), (s, s, 0))
        out += a * f / f.std()
    out += 0.5 * (ndi.gaussian_filter(rng.normal(size=(h, w)), 6)[..., None] > 0)  # sharp-edged blobs
    out = 0.25 + 0.12 * out
    return np.clip(out + (0.35 if bright else 0.0), 0.02, 0.95)


def _map_crop(pixels: np.ndarray, h: int, w: int, row: int, col: int) -> np.ndarray:
    """A crop of an HDR map scaled so that its 95th percentile is 0.7 (a bright photo)."""
    crop = pixels[row : row + h, col : col + w, :3].astype(np.float64)
    return np.clip(crop * (0.7 / max(np.percentile(crop, 95), 1e-6)), 0, 1.5)


def _bubble(bg: np.ndarray, refl: np.ndarray, cx: float, cy: float, r: float, *, blur: float = 0.0,
            dim_sector: tuple[float, float] | None = None, ss: int = SS) -> np.ndarray:
    """The photo with the bubble: per sub-pixel, T^2 bg + 4 R sin^2(phase/2) refl inside.

    R is Schlick's Fresnel approximation for n = 1.4 (R0 = 0.028), T = 1 - R, the
    interference factor that of a 400 nm film at 610, 550 and 465 nm (paper, eqs. 8-10);
    ``refl`` is the reflected scene. ``dim_sector`` (start, end) angles in radians where the
    reflection is black and the transmission is replaced by the background (a rim that
    barely differs from its surroundings). ``ss`` sub-pixels per axis.
    """
    h, w = bg.shape[:2]
    up = lambda a: np.repeat(np.repeat(a, ss, 0), ss, 1)  # noqa: E731
    # sub-pixel centres as a row and a column (broadcast against each other below)
    x = (np.arange(w * ss)[None, :] + 0.5) / ss
    y = (np.arange(h * ss)[:, None] + 0.5) / ss
    rho = np.hypot(x - cx, y - cy) / r
    inside = rho < 1
    cos = np.sqrt(np.clip(1 - rho * rho, 0, 1))
    R = 0.028 + (1 - 0.028) * (1 - cos) ** 5
    T = (1 - R) ** 2
    # two-beam interference of a 400 nm film (n = 1.4) at three wavelengths: the colours
    cos_t = np.sqrt(1 - (1 - cos * cos) / 1.4**2)
    tint = np.stack([np.sin(2 * np.pi * 1.4 * 400.0 * cos_t / lam) ** 2 for lam in (610.0, 550.0, 465.0)], axis=-1)
    bgu, reflu = up(bg), up(refl)
    img = np.where(inside[..., None], T[..., None] * bgu + 4 * R[..., None] * tint * reflu, bgu)
    if dim_sector is not None:
        ang = np.arctan2(y - cy, x - cx) % (2 * np.pi)
        sector = inside & (ang >= dim_sector[0]) & (ang < dim_sector[1]) & (rho > 0.8)
        img[sector] = 0.97 * bgu[sector]
    img = img.reshape(h, ss, w, ss, 3).mean(axis=(1, 3))
    if blur > 0:
        img = ndi.gaussian_filter(img, (blur, blur, 0))
    return img


def _check(d: Disc, cx: float, cy: float, r: float, tol: float = 1.5) -> None:
    assert d.found, d.reason
    assert abs(d.cx - cx) < tol and abs(d.cy - cy) < tol, (d, cx, cy)
    assert abs(d.r - r) < tol, (d, r)


CASES = [
    # (name, h, w, cx, cy, r, blur, dim_sector)
    ("centred_sharp", 160, 160, 80.0, 80.0, 50.0, 0.0, None),
    ("offcentre_blurred", 144, 192, 121.3, 62.7, 38.4, 1.5, None),
    ("large_near_edge", 160, 160, 70.2, 88.9, 66.0, 0.7, None),
    ("dim_rim_quarter", 160, 176, 90.6, 77.1, 52.3, 0.0, (0.3, 0.3 + np.pi / 2)),
    ("small", 120, 120, 47.5, 66.3, 14.2, 0.0, None),
]


@pytest.mark.parametrize("bg_kind", ["map", "texture"])
@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_finds_disc_with_background(case, bg_kind, courtyard_pixels):
    name, h, w, cx, cy, r, blur, sector = case
    rng = np.random.default_rng(zlib.crc32(f"{name}-{bg_kind}".encode()))
    if bg_kind == "map":
        bg = _map_crop(courtyard_pixels, h, w, 150, 300)
        refl = _map_crop(courtyard_pixels, h, w, 40, 620)[::-1]
    else:
        bg, refl = _texture(h, w, rng), _texture(h, w, rng)[::-1]
    photo = _noisy(_bubble(bg, refl, cx, cy, r, blur=blur, dim_sector=sector), rng)
    background = _noisy(ndi.gaussian_filter(bg, (blur, blur, 0)) if blur else bg, rng)
    d = find_disc(photo, background)
    _check(d, cx, cy, r)
    assert d.contrast > 4 and d.support >= 0.5
    assert d.to_json() == {"cx": round(d.cx, 3), "cy": round(d.cy, 3), "r": round(d.r, 3)}


@pytest.mark.parametrize("case", CASES[:3], ids=[c[0] for c in CASES[:3]])
def test_finds_disc_without_background(case):
    """Without a background photo: a bubble before a dim textured scene, lit from the front
    (its reflection of a bright scene outlines the rim, as in a studio or at night)."""
    name, h, w, cx, cy, r, blur, sector = case
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    bg = 0.3 * _texture(h, w, rng, bright=False)
    refl = _texture(h, w, rng)[::-1]
    photo = _noisy(_bubble(bg, refl, cx, cy, r, blur=blur, dim_sector=sector), rng)
    _check(find_disc(photo), cx, cy, r)


LARGE = [
    # (name, h, w, cx, cy, r, with a background photo): photos whose Hough search runs on
    # a copy (HOUGH_SIZE); without a background photo radii below a twentieth of the
    # photo's short side are not searched, so the small bubble has one.
    ("large_bubble", 480, 640, 352.3, 230.6, 171.2, True),
    ("large_bubble", 480, 640, 352.3, 230.6, 171.2, False),
    ("small_bubble", 480, 640, 505.1, 118.4, 16.3, True),
]


@pytest.mark.parametrize("case", LARGE, ids=[f"{c[0]}-{'with' if c[-1] else 'without'}_background" for c in LARGE])
def test_large_photos(case):
    """A 640x480 photo: the Hough transform searches a 267x200 copy, the rim is found on
    the full-resolution evidence, as precisely as on the small photos."""
    name, h, w, cx, cy, r, background = case
    rng = np.random.default_rng(zlib.crc32(f"{name}-{background}".encode()))
    bg = _texture(h, w, rng) if background else 0.3 * _texture(h, w, rng, bright=False)
    refl = _texture(h, w, rng)[::-1]
    photo = _noisy(_bubble(bg, refl, cx, cy, r, ss=2), rng)
    d = find_disc(photo, _noisy(bg, rng) if background else None)
    _check(d, cx, cy, r)


def test_invisible_rim_without_background_is_not_a_false_disc(courtyard_pixels):
    """A rim that reflects what lies behind it hardly shows: no disc rather than a wrong one."""
    rng = np.random.default_rng(7)
    bg = _map_crop(courtyard_pixels, 160, 160, 150, 300)
    photo = _noisy(_bubble(bg, bg[::-1], 80.0, 80.0, 50.0), rng)
    d = find_disc(photo)
    if d.found:
        _check(d, 80.0, 80.0, 50.0)


def test_known_noise_sigma_gives_the_same_disc(courtyard_pixels):
    """With the noise given (linear sigma per pixel) the disc agrees with the estimate."""
    rng = np.random.default_rng(3)
    h = w = 128
    bg = _map_crop(courtyard_pixels, h, w, 150, 300)
    refl = _map_crop(courtyard_pixels, h, w, 40, 620)[::-1]
    clean = _bubble(bg, refl, 61.2, 66.8, 40.5)
    sigma = np.sqrt(clean / 3000.0 + (3.0 / 3000.0) ** 2)
    photo = np.clip(clean + rng.normal(size=clean.shape) * sigma, 0, None)
    background = np.clip(bg + rng.normal(size=bg.shape) * np.sqrt(bg / 3000.0), 0, None)
    _check(find_disc(photo, background, sigma=sigma), 61.2, 66.8, 40.5)


def test_no_bubble_with_background_is_not_found(courtyard_pixels):
    """The background photographed twice: the photo matches it within its noise."""
    rng = np.random.default_rng(5)
    bg = _map_crop(courtyard_pixels, 160, 160, 150, 300)
    d = find_disc(_noisy(bg, rng), _noisy(bg, rng))
    assert not d.found and d.reason
    assert np.isnan(d.cx) and np.isnan(d.r)


def test_something_not_round_is_not_a_bubble(courtyard_pixels):
    """A square object that differs from the background is changed, but not round."""
    rng = np.random.default_rng(6)
    bg = _map_crop(courtyard_pixels, 160, 160, 150, 300)
    photo = bg.copy()
    photo[40:110, 50:120] = 0.6 * photo[40:110, 50:120] + 0.2
    d = find_disc(_noisy(photo, rng), _noisy(bg, rng))
    assert not d.found
    assert "round" in d.reason


@pytest.mark.parametrize("film", [0.8, 1.0])
def test_an_edge_inside_a_faint_bubble_is_not_its_outline(film):
    """A bubble over a dark sky whose film changes the photo by ``film`` times the pixel
    noise per channel (its rim's jump stays below the support's bar), with a bright round
    reflection inside it, tangent to its outline at the bottom (0.6 of its radius). The
    reflection's edge is a round, fully supported circle 0.4 r = 15 px off the outline; it
    must not be declared found, since the film goes on beyond it: the detector returns the
    outline (within 1.5 px, its accuracy on the photos above) or refuses."""
    rng = np.random.default_rng(11)
    n, sigma, sky = 96, 0.01, 0.04
    cx, cy, r = 48.3, 47.4, 38.4
    x = (np.arange(n * SS)[None, :] + 0.5) / SS
    y = (np.arange(n * SS)[:, None] + 0.5) / SS
    film_px = np.hypot(x - cx, y - cy) < r
    lamp = film_px & (np.hypot(x - cx, y - (cy + 0.4 * r)) < 0.6 * r)
    clean = (sky + sigma * (film * film_px + 8.0 * lamp)).reshape(n, SS, n, SS).mean(axis=(1, 3))
    photo = clean[..., None] + rng.normal(0.0, sigma, (n, n, 3))
    background = sky + rng.normal(0.0, sigma, (n, n, 3))
    d = find_disc(photo, background, sigma=np.full((n, n), sigma))
    if d.found:
        _check(d, cx, cy, r)
    else:
        assert d.reason and np.isnan(d.r)


def test_tiny_and_flat_images_are_not_found():
    assert not find_disc(np.full((8, 8, 3), 0.5)).found
    rng = np.random.default_rng(1)
    flat = _noisy(np.full((96, 96, 3), 0.4), rng)
    assert not find_disc(flat).found


# --------------------------------------------------------------------------------------
# Independent photos (Blender Cycles, Mitsuba 3, a separate reference renderer)
# --------------------------------------------------------------------------------------

VALIDATION = Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data"
# the bubbles of the validation set (its flat films and gaps have no disc: the reference
# renderer's are named film_*, the other renderers' say kind = "film" in their truth)
_CASES = sorted(p.parent.name for p in VALIDATION.glob("*/truth.json")  # shipped with the repository
                if not p.parent.name.startswith("film_") and json.loads(p.read_text()).get("kind") != "film")


def _truth(case: str) -> dict:
    return json.loads((VALIDATION / case / "truth.json").read_text())


_STUDIO = pytest.mark.xfail(strict=True, reason=(
    "dark studio map: the outer 2 px of the film are black on black over half the rim, so the visible change "
    "ends inside the silhouette; find_disc refuses it as not round enough"))


@pytest.mark.parametrize("case", [pytest.param(c, marks=_STUDIO) if "studio" in c else c for c in _CASES])
def test_independent_photos_with_background(case):
    from bubblefit.io.images import read_image

    folder = VALIDATION / case
    truth = _truth(case)
    photo, back = ("photo.png", "background.png") if (folder / "photo.png").exists() else ("after.png", "before.png")
    d = find_disc(read_image(folder / photo).pixels, read_image(folder / back).pixels)
    if truth.get("kind") == "negative" and "nobubble" in case:
        assert not d.found
        return
    t = truth["disc"]
    _check(d, t["cx"], t["cy"], t["r"])
