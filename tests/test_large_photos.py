"""Large photos: read exactly, and analysed in memory bounded by the fit's size.

An 8-bit file is decoded through a table of its 256 code values (IEC 61966-2-1 sRGB), which
must equal the arithmetic decoding of every code; the fit's analysis frame of a large photo
(crop to the bubble, block mean, noise per block) is built band by band, so its peak
allocation stays near the size of the frame it returns, not the photo's.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from bubblefit.inverse import analysis_frame
from bubblefit.inverse import FitOptions
from bubblefit.io.images import read_image, srgb_decode, write_image
from helpers import block_average, sensor_sigma


def _srgb_to_linear(v):
    # IEC 61966-2-1, written out here independently of the package
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def test_every_8bit_code_decodes_exactly(tmp_path):
    codes = np.arange(256, dtype=np.float64) / 255
    lin = _srgb_to_linear(codes)
    img = np.repeat(lin[None, :, None], 3, axis=2)  # 1 x 256 ramp, every code once
    path = tmp_path / "ramp.png"
    write_image(path, img)
    for dtype in (np.float64, np.float32):
        got = read_image(path, dtype=dtype)
        assert got.pixels.dtype == dtype
        np.testing.assert_allclose(got.pixels[0, :, 0], lin, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(got.pixels[0, :, 1], srgb_decode(codes), rtol=1e-6, atol=1e-9)
        assert got.saturated[0, -1] and not got.saturated[0, :-1].any()


def test_analysis_frame_memory_is_bounded_by_the_frame():
    H, W, disc = 3000, 4000, (2000.0, 1500.0, 1200.0)
    xx = np.arange(W, dtype=np.float32)[None, :]  # a row and a column, broadcast
    yy = np.arange(H, dtype=np.float32)[:, None]
    photo = np.stack(np.broadcast_arrays(0.3 + 1e-4 * xx, 0.2 + 1e-4 * yy, 0.5 + np.sin(0.01 * xx * yy) * 0.1),
                     axis=-1)
    del yy, xx
    opts = FitOptions()
    sat = np.zeros((H, W), bool)
    tracemalloc.start()
    try:
        frame = analysis_frame(photo, photo, sat, disc, opts)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    outputs = frame.photo.nbytes + frame.background.nbytes + frame.sigma.nbytes + frame.bg_sigma.nbytes
    assert max(frame.photo.shape[:2]) <= opts.sizes.analysis
    crop64 = (2 * 1.15 * disc[2]) ** 2 * 3 * 8  # the crop alone, in float64
    assert peak < 2.5 * outputs and peak < crop64, (peak / 2**20, outputs / 2**20)
    # the band-by-band result is the block mean of the crop, and its noise per block
    k, x0, y0 = frame.k, frame.x0, frame.y0
    h, w = frame.photo.shape[:2]
    crop = photo[y0:y0 + h * k, x0:x0 + w * k].astype(np.float64)
    # references written in tests/helpers.py: the k x k block mean, and the sensor's noise
    # (read, shot, one 8-bit code through the sRGB slope) averaged over a block of k^2 pixels
    np.testing.assert_allclose(frame.photo, block_average(crop, k), rtol=1e-12)
    # the noise's reference on the first and last 16 block rows (the bands built first and last)
    for rows in (slice(0, 16), slice(h - 16, h)):
        part = crop[rows.start * k:rows.stop * k]
        var = sensor_sigma(part, opts.noise.read, opts.noise.shot, opts.noise.bits) ** 2
        np.testing.assert_allclose(frame.sigma[rows], np.sqrt(block_average(var, k) / k**2), rtol=1e-9)
    # the background photo's noise, the same way (here the background is the photo itself)
    np.testing.assert_allclose(frame.bg_sigma, frame.sigma, rtol=1e-12)
    cx, cy, r = frame.disc
    assert abs(x0 + cx * k - disc[0]) < 1e-9 and abs(r * k - disc[2]) < 1e-9
