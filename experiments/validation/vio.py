"""Small image helpers shared by the validation scripts (no bubblefit import).

Works in both virtual environments (the project's and the renderers'): it needs only
numpy and OpenImageIO. sRGB transfer functions are the IEC 61966-2-1 ones, written out.
"""

from __future__ import annotations

import json
import os

import numpy as np
import OpenImageIO as oiio


def read_image(path: str) -> np.ndarray:
    """Float (H, W, C) array; 8/16-bit files are returned as codes / max (still sRGB-encoded)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise OSError(f"cannot read {path}: {oiio.geterror()}")
    spec = inp.spec()
    data = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    inp.close()
    return np.asarray(data, dtype=np.float64).reshape(spec.height, spec.width, spec.nchannels)


def write_exr(path: str, img: np.ndarray, half: bool = False) -> None:
    img = np.ascontiguousarray(np.asarray(img, dtype=np.float32))
    if img.ndim == 2:
        img = img[:, :, None]
    h, w, c = img.shape
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(img)
    out.close()


def srgb_encode(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def write_png8(path: str, linear: np.ndarray, codes: np.ndarray | None = None) -> np.ndarray:
    """Write linear RGB as an 8-bit sRGB PNG (or the given uint8 codes); returns the codes."""
    if codes is None:
        codes = np.round(srgb_encode(linear) * 255.0).astype(np.uint8)
    codes = np.ascontiguousarray(codes)
    h, w, c = codes.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(codes)
    out.close()
    return codes


def add_noise_and_quantise(linear: np.ndarray, rng: np.random.Generator, full_well: float = 4000.0,
                           read_noise: float = 3.0) -> np.ndarray:
    """Poisson-Gaussian sensor noise and 8-bit sRGB quantisation.

    A linear value 1.0 collects ``full_well`` photo-electrons (shot noise is Poisson in
    electrons), read noise is Gaussian with ``read_noise`` electrons RMS; the result is clipped to
    [0, 1], sRGB-encoded and rounded to 8 bits. Returns uint8 codes.
    """
    e = rng.poisson(np.clip(linear, 0, None) * full_well).astype(np.float64)
    e += rng.normal(0.0, read_noise, size=e.shape)
    lin = np.clip(e / full_well, 0.0, 1.0)
    return np.round(srgb_encode(lin) * 255.0).astype(np.uint8)


def box_downsample_envmap(env: np.ndarray, factor: int) -> np.ndarray:
    """Power-preserving box downsample of an equirectangular map by an integer factor.

    Each output texel is the solid-angle weighted mean of its factor x factor block (row
    weights sin(theta) at the source row centres), so the total power sum(L dOmega) of the
    map is kept to the accuracy of that quadrature.
    """
    h, w, c = env.shape
    assert h % factor == 0 and w % factor == 0
    theta = np.pi * (np.arange(h) + 0.5) / h
    wt = np.sin(theta)[:, None, None]
    num = (env * wt).reshape(h // factor, factor, w // factor, factor, c).sum(axis=(1, 3))
    den = np.broadcast_to(wt, (h, w, 1)).reshape(h // factor, factor, w // factor, factor, 1).sum(axis=(1, 3))
    return num / den


def save_json(path: str, obj) -> None:
    with open(path, "w") as fh:
        json.dump(obj, fh, indent=2, sort_keys=False, default=float)
        fh.write("\n")


HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "data")
ENVMAPS = os.path.join(DATA, "envmaps")
