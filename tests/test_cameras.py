"""Camera files and camera responses: encodings, RAW, flat fields, calibration, wrong cameras.

References are written here, independently of the package: the scene values a file was
made from, the IEC 61966-2-1 sRGB formula, hand-built PNG chunks and ICC curves, a DNG
written with tifffile from a Bayer mosaic of a known scene, and colour-science's camera
sensitivities and ColorChecker reflectances.
"""

from __future__ import annotations

import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.io.camera_files import PhotoReading, flat_dark, read_photo, read_raw

from helpers import FILM_PHOTO_DISC, film_photo


# ----------------------------------------------------------------------------- helpers


def _png(path, codes16: np.ndarray, chunks: list[tuple[bytes, bytes]]):
    """A 16-bit RGB PNG written by hand (ISO/IEC 15948), with the given ancillary chunks."""
    h, w, _ = codes16.shape

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    raw = b"".join(b"\x00" + codes16[y].astype(">u2").tobytes() for y in range(h))
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
    for kind, body in chunks:
        data += chunk(kind, body)
    data += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    path.write_bytes(data)


def _srgb_encode(lin):
    """IEC 61966-2-1:1999 sec. 5.3, written out here."""
    lin = np.clip(lin, 0, 1)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)


def _scene(h=24, w=32, seed=0):
    """A smooth linear RGB scene in (0.05, 0.9)."""
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    return np.stack([0.1 + 0.7 * x, 0.2 + 0.5 * y, 0.5 + 0.3 * np.sin(2 * x + y)], axis=-1)


def _write_dng(path, mosaic: np.ndarray, black: int, white: int, neutral=(1.0, 1.0, 1.0)):
    """A minimal uncompressed CFA DNG (Adobe DNG 1.4 tags) of an RGGB mosaic."""
    import tifffile

    def srat(vals):
        out = []
        for v in vals:
            out += [int(round(v * 10000)), 10000]
        return out

    def rat(vals):
        out = []
        for v in vals:
            out += [int(round(v * 10000)), 10000]
        return out

    tags = [(50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True),
            (50708, "s", 0, "bubblefit synthetic", True),
            (33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
            (50714, "H", 1, (black,), True), (50717, "H", 1, (white,), True),
            (50721, "2i", 9, srat([1, 0, 0, 0, 1, 0, 0, 0, 1]), True), (50778, "H", 1, (21,), True),
            (50728, "2I", 3, rat(neutral), True)]
    tifffile.imwrite(str(path), mosaic.astype(np.uint16), photometric=32803, subfiletype=0, extratags=tags)


def _mosaic(scene: np.ndarray) -> np.ndarray:
    """RGGB Bayer sampling of an (H, W, 3) scene."""
    h, w, _ = scene.shape
    m = np.empty((h, w))
    m[0::2, 0::2] = scene[0::2, 0::2, 0]
    m[0::2, 1::2] = scene[0::2, 1::2, 1]
    m[1::2, 0::2] = scene[1::2, 0::2, 1]
    m[1::2, 1::2] = scene[1::2, 1::2, 2]
    return m


# ----------------------------------------------------------------------------- encodings


def test_linear_12bit_tiff_in_16bit_container(tmp_path):
    """A 12-bit linear sensor's codes with a pedestal, stored in a 16-bit TIFF: read back
    within half a code of the scene (quantisation 0.5 / (white - black))."""
    import tifffile

    scene = _scene()
    black, white = 64, 4095
    codes = np.round(scene * (white - black) + black).astype(np.uint16)
    tifffile.imwrite(str(tmp_path / "lin.tif"), codes, photometric="rgb")
    img = read_photo(str(tmp_path / "lin.tif"), PhotoReading("linear", black_level=black, white_level=white))
    assert img.encoding.encoding == "linear"
    assert np.max(np.abs(img.pixels - scene)) <= 0.5 / (white - black) + 1e-12
    # auto on a file that states nothing: sRGB assumed, and the record says so
    auto = read_photo(str(tmp_path / "lin.tif"))
    assert auto.encoding.encoding == "srgb" and "assumed" in auto.encoding.reason


def test_png_chunks_decide_auto(tmp_path):
    """gAMA 1.0 -> linear; an sRGB chunk -> the IEC 61966-2-1 decoding; and an encoding that
    contradicts the chunk is refused unless forced."""
    scene = _scene(8, 10)
    lin_codes = np.round(scene * 65535).astype(np.uint16)
    _png(tmp_path / "g1.png", lin_codes, [(b"gAMA", struct.pack(">I", 100000))])
    img = read_photo(str(tmp_path / "g1.png"))
    assert img.encoding.encoding == "linear" and "gAMA" in img.encoding.reason
    assert np.max(np.abs(img.pixels - scene)) <= 0.5 / 65535 + 1e-12

    srgb_codes = np.round(_srgb_encode(scene) * 65535).astype(np.uint16)
    _png(tmp_path / "s.png", srgb_codes, [(b"sRGB", b"\x00")])
    img = read_photo(str(tmp_path / "s.png"))
    assert img.encoding.encoding == "srgb"
    # one code step of the 16-bit encoding is at most 12.92^-1 / 65535 ... (2.4/1.055) / 65535 in linear
    assert np.max(np.abs(img.pixels - scene)) < 2.3 / 65535
    with pytest.raises(InputError, match="contradicts"):
        read_photo(str(tmp_path / "s.png"), PhotoReading("linear"))
    forced = read_photo(str(tmp_path / "s.png"), PhotoReading("linear", force=True))
    assert np.allclose(forced.pixels, srgb_codes / 65535)


def test_icc_linear_curve_in_a_tiff(tmp_path):
    """An ICC profile whose tone curves are the identity (``curv`` with no entries, ICC.1
    sec. 10.6) makes ``auto`` read a TIFF as linear."""
    import tifffile

    tags = [(b"rTRC", b"curv" + b"\x00" * 4 + struct.pack(">I", 0))] * 1
    header = bytearray(128)
    table = struct.pack(">I", len(tags))
    offset = 128 + 4 + 12 * len(tags)
    body = b""
    for sig, data in tags:
        table += struct.pack(">4sII", sig, offset + len(body), len(data))
        body += data
    profile = bytes(header) + table + body
    struct.pack_into(">I", header, 0, len(profile))
    profile = bytes(header) + table + body
    scene = _scene(6, 8)
    tifffile.imwrite(str(tmp_path / "icc.tif"), np.round(scene * 65535).astype(np.uint16), photometric="rgb",
                     iccprofile=profile)
    img = read_photo(str(tmp_path / "icc.tif"))
    assert img.encoding.encoding == "linear" and "ICC" in img.encoding.reason
    assert np.max(np.abs(img.pixels - scene)) <= 0.5 / 65535 + 1e-12


def test_bad_levels_and_float_srgb(tmp_path):
    from bubblefit.io.images import write_image

    with pytest.raises(InputError, match="below"):
        PhotoReading("linear", black_level=5000, white_level=4095)
    with pytest.raises(InputError, match="linear files"):
        PhotoReading("srgb", black_level=10)
    write_image(tmp_path / "f.exr", np.full((4, 4, 3), 0.5), bit_depth=32)
    with pytest.raises(InputError, match="float"):
        read_photo(str(tmp_path / "f.exr"), PhotoReading("srgb"))
    with pytest.raises(InputError, match="exceeds"):
        import tifffile

        tifffile.imwrite(str(tmp_path / "e.tif"), np.zeros((4, 4, 3), np.uint8), photometric="rgb")
        read_photo(str(tmp_path / "e.tif"), PhotoReading("linear", white_level=4095))


# ----------------------------------------------------------------------------- RAW


def test_dng_bayer_mosaic_matches_the_scene(tmp_path):
    """A smooth scene sampled through an RGGB mosaic with a black level, written as a DNG,
    read by LibRaw without white balance: the demosaiced camera RGB equals the scene away
    from the border. Bilinear-class interpolation of a field with second derivative
    ``f''`` over 2 px errs by at most ``f'' * 2^2 / 8``; the scene's largest curvature is
    0.3 * (2/32)^2 per px^2 -> 6e-4; plus 12-bit quantisation 1.2e-4 and LibRaw's 16-bit
    output 8e-6."""
    pytest.importorskip("rawpy")
    scene = _scene(32, 48)
    black, white = 256, 4095
    codes = np.round(_mosaic(scene) * (white - black) + black)
    _write_dng(tmp_path / "s.dng", codes, black, white)
    img = read_photo(str(tmp_path / "s.dng"), PhotoReading(raw_white_balance="none"))
    assert img.encoding.encoding == "raw"
    inner = (slice(4, -4), slice(4, -4))
    err = np.abs(img.pixels[inner] - scene[inner])
    assert np.max(err) < 2e-3, np.max(err)
    info = img.metadata["raw"]
    assert info["black_level_per_channel"][0] == black and info["white_level"] == white
    # ColorMatrix1 = identity (camera RGB = XYZ): LibRaw's camera-to-sRGB matrix is then the
    # inverse of sRGB-to-XYZ with rows normalised to white (dcraw's cam_rgb normalisation)
    import colour

    m = colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ
    expected = np.linalg.inv(m / m.sum(axis=1, keepdims=True))
    assert np.allclose(np.asarray(info["color_matrix"]), expected, atol=0.01)
    # the as-shot white balance (AsShotNeutral 0.5, 1, 0.8): channels scaled by 2, 1, 1.25
    _write_dng(tmp_path / "wb.dng", codes, black, white, neutral=(0.5, 1.0, 0.8))
    wb = read_photo(str(tmp_path / "wb.dng"))
    ratio = np.median(wb.pixels[inner] / np.maximum(img.pixels[inner], 1e-6), axis=(0, 1))
    assert np.allclose(ratio / ratio[1], [2.0, 1.0, 1.25], rtol=0.01), ratio


def test_a_clipped_raw_photosite_is_censored_with_its_block_once(tmp_path):
    """A photosite at the white level, read from a DNG through the Bayer reader, is marked
    alone (its own pixel), and the fit's censoring grows it once by the bilinear demosaic's
    3 x 3 block: every pixel the demosaic fills from it is left out, and no pixel farther
    (a second growth would censor a 5 x 5 block)."""
    pytest.importorskip("rawpy")
    from bubblefit.inverse import saturation_mask

    black, white = 256, 4095
    smooth = _mosaic(_scene(32, 32)) * (white - black) + black
    bright = smooth.copy()
    bright[16, 16] = white  # a red photosite of the RGGB mosaic, clipped
    _write_dng(tmp_path / "smooth.dng", np.round(smooth), black, white)
    _write_dng(tmp_path / "clip.dng", np.round(bright), black, white)
    reading = PhotoReading(raw_white_balance="none")
    base, img = read_photo(str(tmp_path / "smooth.dng"), reading), read_photo(str(tmp_path / "clip.dng"), reading)
    assert np.argwhere(img.saturated).tolist() == [[16, 16]]
    spread = np.any(np.abs(img.pixels - base.pixels) > 1e-6, axis=-1)
    censored = saturation_mask(img.pixels, 2.0, img.saturated)  # the level above every pixel: the reader's mask alone
    assert not np.any(spread & ~censored)
    assert np.argwhere(censored).tolist() == [[r, c] for r in (15, 16, 17) for c in (15, 16, 17)]


def test_unsupported_raw_is_one_line(tmp_path):
    pytest.importorskip("rawpy")
    bad = tmp_path / "x.nef"
    bad.write_bytes(b"not a raw file at all" * 50)
    with pytest.raises(InputError) as exc:
        read_raw(str(bad))
    assert "\n" not in str(exc.value) and "x.nef" in str(exc.value)


def test_raw_without_image_data_is_one_line(tmp_path):
    """A DNG whose photosites all read one value (image data stripped, as in ExifTool's
    test DNG, or a file cut short) is refused in one line instead of read as a black photo;
    a dark frame (the black level plus read noise of a few codes) is read."""
    pytest.importorskip("rawpy")
    black, white = 256, 4095
    _write_dng(tmp_path / "empty.dng", np.zeros((24, 32)), black, white)
    with pytest.raises(InputError, match="holds no image") as exc:
        read_photo(str(tmp_path / "empty.dng"))
    assert "\n" not in str(exc.value)
    noise = np.random.default_rng(0).normal(0.0, 3.0, (24, 32))
    _write_dng(tmp_path / "dark.dng", np.round(black + np.abs(noise)), black, white)
    dark = read_photo(str(tmp_path / "dark.dng"), PhotoReading(raw_white_balance="none"))
    # demosaicing averages photosites: no pixel above the largest |noise| (under 5 sigma of 768 draws)
    assert 0.0 <= dark.pixels.min() and dark.pixels.max() <= 5 * 3.0 / (white - black)


# ----------------------------------------------------------------------------- flat and dark


def test_flat_and_dark_remove_vignetting(tmp_path):
    """photo = scene * V + D and flat = k * V * lamp + D (V a cos^4 vignette, D a fixed
    pattern): the corrected photo is the scene up to one factor per channel."""
    from bubblefit.io.images import write_image

    h, w = 24, 32
    scene = _scene(h, w)
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x - w / 2) ** 2 + (y - h / 2) ** 2) / (w * w)
    vig = (1.0 / (1.0 + r2)) ** 2
    dark = 0.01 + 0.002 * np.random.default_rng(1).random((h, w, 1)) * np.ones(3)
    photo = scene * vig[..., None] + dark
    flat = 0.6 * vig[..., None] * np.array([1.0, 0.9, 0.7]) + dark
    for name, arr in (("p.exr", photo), ("f.exr", flat), ("d.exr", dark)):
        write_image(tmp_path / name, arr, bit_depth=32)
    img = read_photo(str(tmp_path / "p.exr"), PhotoReading(flat=str(tmp_path / "f.exr"), dark=str(tmp_path / "d.exr")))
    gain = np.median(img.pixels / scene, axis=(0, 1))
    assert np.allclose(img.pixels / gain, scene, rtol=2e-6, atol=1e-6)
    with pytest.raises(InputError, match="flat field"):
        flat_dark(photo, flat=flat[:-1], flat_path="f.exr")


# ----------------------------------------------------------------------------- films read as photos

#: A flat film's scene (Newton's rings, 128x128 pixels) of the validation set.
_GAP_SCENE = (Path(__file__).resolve().parent.parent / "experiments" / "validation" / "data"
              / "film_newton_bk7_na010" / "scene.toml")


def _film_args(tmp_path, photo, *flags):
    """``fit PHOTO --scene`` (a flat film's scene) parsed as the command line parses it."""
    from bubblefit.cli import build_parser

    return build_parser().parse_args(["fit", str(photo), "--scene", str(_GAP_SCENE), *map(str, flags)])


def test_film_photo_read_as_every_camera_file(tmp_path):
    """A flat film's photo goes through the camera-file reader of every other command: a
    DNG is developed by LibRaw (not its TIFF thumbnail or first IFD), a 12-bit linear TIFF
    takes --encoding and its levels, and the JSON record says how the file was read. The
    reference is :func:`read_photo` itself on the same flags (the same values exactly)."""
    import tifffile

    from bubblefit.cli.fit_planar import read_film_photo

    pytest.importorskip("rawpy")
    scene = _scene(128, 128)
    black, white = 256, 4095
    _write_dng(tmp_path / "f.dng", np.round(_mosaic(scene) * (white - black) + black), black, white)
    photo, record = read_film_photo(_film_args(tmp_path, tmp_path / "f.dng", "--raw-white-balance", "none"))
    assert record["encoding"] == "raw"
    ref = read_photo(str(tmp_path / "f.dng"), PhotoReading(raw_white_balance="none"))
    assert np.array_equal(photo.pixels, ref.pixels)
    black, white = 64, 4095
    tifffile.imwrite(str(tmp_path / "lin.tif"), np.round(scene * (white - black) + black).astype(np.uint16),
                     photometric="rgb")
    photo, record = read_film_photo(_film_args(tmp_path, tmp_path / "lin.tif", "--encoding", "linear",
                                               "--black-level", black, "--white-level", white))
    assert record["encoding"] == "linear"
    assert np.max(np.abs(photo.pixels - scene)) <= 0.5 / (white - black) + 1e-12


def test_film_fit_flat_of_another_size_exits_2(tmp_path):
    """``fit --scene FILM.toml --flat`` reads the flat field (it was not ignored): one of
    another size is refused in one line, exit 2, nothing written."""
    from bubblefit.io.images import write_image

    write_image(tmp_path / "p.exr", np.full((128, 128, 3), 0.5), bit_depth=32)
    write_image(tmp_path / "f.exr", np.full((64, 128, 3), 0.5), bit_depth=32)
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(tmp_path / "p.exr"),
                           "--scene", str(_GAP_SCENE),
                           "--flat", str(tmp_path / "f.exr"), "--json", str(tmp_path / "o.json")],
                          capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "flat field" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "o.json").exists()


@pytest.mark.slow
def test_fit_flat_of_another_size_exits_2(tmp_path):
    from bubblefit.io.images import write_image

    write_image(tmp_path / "p.exr", np.full((16, 16, 3), 0.5), bit_depth=32)
    write_image(tmp_path / "f.exr", np.full((8, 16, 3), 0.5), bit_depth=32)
    env = tmp_path / "env.exr"
    write_image(env, np.full((8, 16, 3), 1.0), bit_depth=32)
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(tmp_path / "p.exr"), "--envmap", str(env),
                           "--flat", str(tmp_path / "f.exr"), "--json", str(tmp_path / "o.json")],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "flat field" in proc.stderr
    assert not (tmp_path / "o.json").exists()


# ----------------------------------------------------------------------------- end to end

DISC = FILM_PHOTO_DISC
NIKON = "Nikon 5100 (NPL)"  # measured raw sensitivities shipped with colour-science


def _fit_cli(tmp_path, name, photo, background, envfile, *flags):
    import json

    from bubblefit.cli import main

    out = tmp_path / f"{name}.json"
    rc = main(["fit", str(photo), "--background", str(background), "--envmap", str(envfile), "--model", "paper",
               "--disc", ",".join(map(str, DISC)), "--t", "0.968", "--fov", "0", "--json", str(out), *map(str, flags)])
    assert rc == 0
    return json.loads(out.read_text())


@pytest.mark.slow
def test_linear_tiff_and_dng_fit_as_the_exr(small_courtyard, tmp_path):
    """One noisy linear photo stored three ways: float EXR, 12-bit linear codes with a black
    level in a 16-bit TIFF, and an RGGB mosaic in a DNG. The TIFF's quantisation (1/4031 of
    full scale) is far below the noise, so it fits to the EXR's thickness within a tenth of
    its standard error; the DNG keeps one channel in three per pixel and interpolates the
    rest, so it agrees within three combined standard errors. All within 5 nm of the truth."""
    import tifffile

    from bubblefit.io.images import write_image

    truth = 700.0
    photo, bg = film_photo(__import__("bubblefit").lighting.envmap.EnvMap.from_array(small_courtyard), truth, 3,
                           quantised=False)
    envfile = tmp_path / "env.exr"
    write_image(envfile, small_courtyard, bit_depth=32)
    black, white = 64, 4095
    for name, arr in (("photo", photo), ("bg", bg)):
        write_image(tmp_path / f"{name}.exr", arr, bit_depth=32)
        codes = np.clip(np.round(arr * (white - black) + black), 0, white)
        tifffile.imwrite(str(tmp_path / f"{name}.tif"), codes.astype(np.uint16), photometric="rgb")
        _write_dng(tmp_path / f"{name}.dng", _mosaic(codes), black, white)
    exr = _fit_cli(tmp_path, "exr", tmp_path / "photo.exr", tmp_path / "bg.exr", envfile)
    tif = _fit_cli(tmp_path, "tif", tmp_path / "photo.tif", tmp_path / "bg.tif", envfile,
                   "--encoding", "linear", "--black-level", black, "--white-level", white)
    dng = _fit_cli(tmp_path, "dng", tmp_path / "photo.dng", tmp_path / "bg.dng", envfile,
                   "--raw-white-balance", "none")
    d = {k: (r["params"]["thickness_nm"], r["stderr"]["thickness_nm"]) for k, r in
         (("exr", exr), ("tif", tif), ("dng", dng))}
    assert tif["photo_reading"]["encoding"] == "linear" and dng["photo_reading"]["encoding"] == "raw"
    assert dng["photo_reading"]["raw"]["photosite_share"] == [0.25, 0.5, 0.25]
    # the right camera: every file's colours pass the colour check and every fit is ok
    assert all(r["ok"] and r["colour_check"]["consistent"] for r in (exr, tif, dng)), [
        (r["colour_check"], r["warnings"]) for r in (exr, tif, dng)]
    assert abs(d["tif"][0] - d["exr"][0]) < 0.1 * d["exr"][1] + 0.05, d
    assert abs(d["dng"][0] - d["exr"][0]) < 3 * np.hypot(d["exr"][1], d["dng"][1]) + 0.5, d
    assert all(abs(v[0] - truth) < 5.0 for v in d.values()), d


# ----------------------------------------------------------------------------- calibration

_LAM = np.arange(380.0, 781.0)


def _sensitivities(name):
    """A colour-science camera's raw sensitivities (L, 3) on the 1 nm grid, zero outside."""
    import colour

    ms = colour.MSDS_CAMERA_SENSITIVITIES[name]
    return np.stack([np.interp(_LAM, ms.wavelengths, ms.values[:, c], left=0, right=0) for c in range(3)], axis=1)


def _airy(d, n=1.33):
    """Normal-incidence Airy reflectance of a free film (Born & Wolf sec. 7.6.1), written out."""
    r = (1 - n) / (1 + n)
    f = 4 * r * r / (1 - r * r) ** 2
    s2 = np.sin(2 * np.pi * n * np.asarray(d, float)[:, None] / _LAM) ** 2
    return f * s2 / (1 + f * s2)


def _film_samples(camera, thickness, noise, seed):
    """Linear RGB of a film at each thickness under illuminant E, with relative noise."""
    rng = np.random.default_rng(seed)
    y = _airy(thickness) @ _sensitivities(camera)
    return y * (1 + noise * rng.normal(size=y.shape))


def test_film_calibration_predicts_film_colours():
    """A draining film's colours (0-2000 nm, 0.5 % noise) seen by the Nikon: the fitted
    response predicts the colours of 80 thicknesses it was not given within 4 noise
    standard deviations (2 %) of each channel's range at worst, and its residual is the noise."""
    from bubblefit.capture.camera_calibration import fit_response

    d = np.linspace(0.0, 2000.0, 81)
    cal = fit_response([("film", _airy(d), _film_samples(NIKON, d, 0.005, 0))])
    assert np.all(cal.residual_rel < 0.01), cal.residual_rel
    assert np.all(cal.stderr >= 0) and np.all(np.median(cal.stderr, axis=0) < 0.05)
    held = np.linspace(12.5, 1987.5, 80)
    resp = np.stack([np.interp(_LAM, cal.wavelengths, cal.response[:, c]) for c in range(3)], axis=1)
    pred, true = _airy(held) @ resp, _airy(held) @ _sensitivities(NIKON)
    pred = pred * (true * pred).sum(0) / (pred * pred).sum(0)  # each channel's free scale
    err = np.abs(pred - true).max(0) / true.max(0)
    assert np.all(err < 0.02), err


def test_chart_calibration_states_its_errors(tmp_path):
    """The ColorChecker's 24 patches seen by the Nikon under E (0.5 % noise) calibrate a
    response whose stated errors, propagated to the colours of films of 50-2000 nm
    (``response_error``), cover what it gets wrong against the true sensitivities. One draw
    of an honest response error moves all film colours of a channel together (a few
    effective modes), so the RMS of their z is below sqrt(chi2_4(0.999) / 4) = 2.3; the
    development cameras' measured shortfall is up to 1.3x (experiments/chart_calibration_error.py):
    3 allowed. Errors that left the smoothing's bias out read 3.6-7.4 here."""
    from bubblefit.capture.camera_calibration import chart_reflectances, fit_response
    from bubblefit.inverse.response_error import response_error

    _, refl = chart_reflectances()
    rgb = refl @ _sensitivities(NIKON) * (1 + 0.005 * np.random.default_rng(0).normal(size=(24, 3)))
    path = tmp_path / "chart.csv"
    path.write_text(fit_response([("chart", refl, rgb)]).csv_text())
    held = np.linspace(50.0, 2000.0, 40)
    truth = _airy(held) @ _sensitivities(NIKON)
    truth = truth / _sensitivities(NIKON).sum(axis=0)
    err = response_error(str(path), "E", 1.33)
    pred = _airy(held) @ err.density / err.density.sum(axis=0)
    sd = np.sqrt(np.sum(err.jacobian(pred, None, held, np.ones_like(held)) ** 2, axis=-1))
    rms_z = np.sqrt(np.mean(((pred - truth) / sd) ** 2, axis=0))
    assert np.all(rms_z < 3.0), rms_z


def test_calibration_under_a_lamp_is_the_camera():
    """Film colours seen by the Nikon under illuminant A (colour-science's tabulated SPD,
    applied here in numpy) calibrated with the lamp named: the CSV's response is the
    camera's own sensitivity (each channel's peak 1): its rows' RMS error is under 5 % of
    the peak (the stated errors there are 1.5-3.5 %, and the rows' z have unit RMS), where
    the sensitivity divided by the lamp once more is 9-13 % off."""
    import colour

    from bubblefit.capture.camera_calibration import fit_response

    lamp = np.interp(_LAM, colour.SDS_ILLUMINANTS["A"].wavelengths, colour.SDS_ILLUMINANTS["A"].values)
    d = np.linspace(0.0, 2000.0, 81)
    sens = _sensitivities(NIKON)
    rgb = _airy(d) @ (sens * lamp[:, None]) * (1 + 0.005 * np.random.default_rng(2).normal(size=(81, 3)))
    cal = fit_response([("film", _airy(d), rgb)], "A")
    true = np.stack([np.interp(cal.wavelengths, _LAM, sens[:, c]) for c in range(3)], axis=1)
    true = true / true.max(axis=0)
    rms = np.sqrt(np.mean((cal.response - true) ** 2, axis=0))
    assert np.all(rms < 0.05), rms
    assert np.all(np.sqrt(np.mean(((cal.response - true) / cal.stderr) ** 2, axis=0)) < 2.0)


@pytest.mark.slow
def test_calibrate_camera_cli_and_bad_input(tmp_path):
    from bubblefit.capture.camera_calibration import chart_reflectances
    from bubblefit.optics.spectral import response_functions

    d = np.linspace(0.0, 2000.0, 61)
    y = _film_samples(NIKON, d, 0.005, 1)
    film = tmp_path / "film.csv"
    film.write_text("thickness_nm,r,g,b\n" + "\n".join(f"{t},{a},{b},{c}" for t, (a, b, c) in zip(d, y)))
    out = tmp_path / "resp.csv"
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "calibrate-camera", "--film", str(film), "-o", str(out),
                           "--json", str(tmp_path / "c.json")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    resp = response_functions(str(out))  # what --camera-response reads
    assert resp.shape[1] == 3 and np.all(resp.max(axis=0) > 0.99)
    names, refl = chart_reflectances()
    values = tmp_path / "chart.csv"
    values.write_text("\n".join(",".join(map(str, v)) for v in (refl @ _sensitivities(NIKON))[:20]))
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "calibrate-camera", "--chart-values", str(values),
                           "-o", str(tmp_path / "c2.csv")], capture_output=True, text=True)
    assert proc.returncode == 2 and "24 patches" in proc.stderr and proc.stderr.count("\n") == 1
    assert not (tmp_path / "c2.csv").exists()


def _chart_image(values, patch=50, gap=12, margin=40, rng=None):
    """A synthetic ColorChecker photo (linear): 24 square patches of ``values`` in 4 rows of
    6, on a black frame inside a grey surround, with 0.2 % read noise."""
    h, w = 4 * patch + 5 * gap + 2 * margin, 6 * patch + 7 * gap + 2 * margin
    img = np.full((h, w, 3), 0.6 * values.max())
    img[margin:h - margin, margin:w - margin] = 0.02 * values.max()
    for i, v in enumerate(values):
        r, c = divmod(i, 6)
        y0, x0 = margin + gap + r * (patch + gap), margin + gap + c * (patch + gap)
        img[y0:y0 + patch, x0:x0 + patch] = v
    rng = rng or np.random.default_rng(0)
    return img + 0.002 * values.max() * rng.normal(size=img.shape)


@pytest.mark.slow
def test_chart_found_in_a_photo():
    """The 24 patches of a synthetic chart photographed by the Nikon under E (reflectances
    times sensitivities, numpy), found by colour-checker-detection, upright and upside
    down: each patch's value within 1 % of the chart's brightest (the noise averages over
    hundreds of pixels; the detector samples the patch's centre); a photo without a chart
    is refused in one line."""
    pytest.importorskip("colour_checker_detection")
    from bubblefit.capture.camera_calibration import chart_reflectances, detect_chart

    _, refl = chart_reflectances()
    truth = refl @ _sensitivities(NIKON)
    img = _chart_image(truth)
    for photo in (img, img[::-1, ::-1]):
        found = detect_chart(photo)
        assert np.max(np.abs(found - truth)) < 0.01 * truth.max(), np.abs(found - truth).max() / truth.max()
    with pytest.raises(InputError, match="found 0 ColorChecker"):
        detect_chart(np.full((200, 300, 3), 0.3) + 0.01 * np.random.default_rng(1).normal(size=(200, 300, 3)))


def test_calibrated_response_names_its_lamp(tmp_path):
    """A response CSV from calibrate-camera says which lamp it was fitted under: the fit
    takes it when no illuminant is stated; one fitted under E already holds the lamp, so
    another stated illuminant is refused in one line; one fitted under a named lamp (the
    camera alone) may be used under another."""
    from bubblefit.capture.camera_calibration import fit_response
    from bubblefit.inverse import calibrated_illuminant
    from bubblefit.optics.spectral import response_functions

    d = np.linspace(0.0, 2000.0, 41)
    product = tmp_path / "e.csv"
    product.write_text(fit_response([("film", _airy(d), _film_samples(NIKON, d, 0.005, 0))]).csv_text())
    assert calibrated_illuminant(str(product), "D65", stated=False) == "E"
    assert calibrated_illuminant(str(product), "E", stated=True) == "E"
    with pytest.raises(InputError, match="already holds the lamp") as exc:
        calibrated_illuminant(str(product), "D65", stated=True)
    assert "\n" not in str(exc.value)
    camera = tmp_path / "a.csv"
    camera.write_text(fit_response([("film", _airy(d), _film_samples(NIKON, d, 0.005, 0))], "A").csv_text())
    assert calibrated_illuminant(str(camera), "D65", stated=False) == "A"
    assert calibrated_illuminant(str(camera), "D65", stated=True) == "D65"
    assert calibrated_illuminant(NIKON, "D65", stated=False) == "D65"  # a named camera says nothing
    assert response_functions(str(product)).shape[1] == 3  # the comment line does not disturb the reader


@pytest.mark.slow
def test_film_calibrated_camera_reads_films(small_courtyard, tmp_path):
    """The camera is never told: a draining film's linear colours (0-2000 nm, 61
    thicknesses, 0.5 % noise) seen by the Nikon D5100 under illuminant E calibrate a
    response with ``bubblefit calibrate-camera``; 48 px photos of 300, 1000 and 1500 nm
    films rendered with the Nikon's own sensitivities (noise, 8-bit sRGB codes) are fitted
    with ``--camera-response`` that CSV and no illuminant (the CSV's E is taken): each
    within 5 nm of the truth, so in the right order, and ok. The same CSV with
    ``--illuminant D65`` is refused with exit status 2. The fits start from roughness 0.04
    (as experiments/calibrated_camera.py): from the default start the 300 nm film settles
    at 514 nm with the calibrated CSV and with the Nikon's own response alike (a search
    matter, not the camera's; the colour check then reads 48 and the fit is not ok)."""
    from bubblefit.cli import main
    from bubblefit.io.images import write_image
    from bubblefit.lighting.envmap import EnvMap

    d = np.linspace(0.0, 2000.0, 61)
    y = _film_samples(NIKON, d, 0.005, 1)
    film = tmp_path / "film.csv"
    film.write_text("thickness_nm,r,g,b\n" + "\n".join(f"{t},{a},{b},{c}" for t, (a, b, c) in zip(d, y)))
    cal = tmp_path / "camera.csv"
    assert main(["calibrate-camera", "--film", str(film), "-o", str(cal)]) == 0
    env = EnvMap.from_array(small_courtyard)
    envfile = tmp_path / "env.exr"
    write_image(envfile, small_courtyard, bit_depth=32)
    for k, truth in enumerate((300.0, 1000.0, 1500.0)):
        photo, bg = film_photo(env, truth, 31 + k, NIKON, "E")
        write_image(tmp_path / f"p{k}.exr", photo, bit_depth=32)
        write_image(tmp_path / f"b{k}.exr", bg, bit_depth=32)
        r = _fit_cli(tmp_path, f"f{k}", tmp_path / f"p{k}.exr", tmp_path / f"b{k}.exr", envfile,
                     "--camera-response", cal, "--set", "roughness=0.04")
        assert abs(r["params"]["thickness_nm"] - truth) < 5.0, (truth, r["params"], r["warnings"])
        assert r["ok"] and r["colour_check"]["consistent"], (truth, r["colour_check"], r["warnings"])
    out = tmp_path / "refused.json"
    rc = main(["fit", str(tmp_path / "p0.exr"), "--background", str(tmp_path / "b0.exr"), "--envmap", str(envfile),
               "--disc", ",".join(map(str, DISC)), "--fov", "0", "--camera-response", str(cal), "--illuminant", "D65",
               "--json", str(out)])
    assert rc == 2 and not out.exists()


# ----------------------------------------------------------------------------- wrong camera


@pytest.mark.slow
@pytest.mark.parametrize("thickness,told,right", [(600.0, "srgb", False), (1500.0, "srgb", False),
                                                  (1300.0, "Sigma SDMerill (NPL)", False), (1300.0, NIKON, True)])
def test_a_wrong_camera_is_not_ok(small_courtyard, thickness, told, right):
    """Photos rendered with the Nikon's sensitivities under illuminant E (8-bit sRGB codes),
    fitted with the response they were taken with (consistent, ok, the thickness within
    10 nm) and with another (sRGB/D65, the Sigma): not ok, with the one warning that names
    the camera response and what to do. The 1500 nm film read as sRGB is the hardest case
    measured (experiments/colour_check_null.py: pale colours, a hue error under 1 %)."""
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.inverse import starts
    from bubblefit.lighting.envmap import EnvMap

    env = EnvMap.from_array(small_courtyard)
    photo, bg = film_photo(env, thickness, int(thickness), NIKON, "E")
    r = fit_photo(photo, env, background=bg, options=FitOptions(
        disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=told, view=ORTHOGRAPHIC,
        illuminant="D65" if told == "srgb" else "E"))
    check = r.to_json()["colour_check"]
    assert check is not None and check["consistent"] is right, check
    assert r.ok is right, (r.ok, r.warnings)
    if right:
        assert abs(r.params["thickness_nm"] - thickness) < 10.0, (r.params, r.warnings)
    else:
        said = [w for w in r.warnings if "camera response" in w]
        assert len(said) == 1 and "calibrate-camera" in said[0] and "--encoding" in said[0], r.warnings


@pytest.mark.slow
def test_another_cameras_film_calibration_is_not_ok(small_courtyard):
    """A 1500 nm film photographed by the Sigma SD Merrill (8-bit, seed 35) and fitted with
    the Nikon D5100's film-calibrated CSV (experiments/calibrated_camera.py's: 81
    thicknesses 0-2000 nm, 0.5 % noise, its generator seeded 5 and drawn for the chart's 24
    patches first) reads about 1656 nm, 0.7 of a fringe off and no order error, with a
    1.5 nm error bar. Its hue error turns with the optical path, which a 6 x 6 cell of this
    disc spans a fringe of: the colour check's parts split by the path
    (``colour_check.PATH_BIN``) and its path bins pooled over the film see it, and the fit
    is not ok with the camera's warning (docs/cameras.md: 95 of 100 noise draws of this
    photo flagged, 15 with the cells alone; this draw among them, flagged by both
    partitions, each near 1.08 of its threshold)."""
    import tempfile

    from bubblefit.capture.camera_calibration import fit_response
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.lighting.envmap import EnvMap

    rng = np.random.default_rng(5)
    rng.normal(size=(24, 3))  # the chart's noise, drawn first there
    spectra = _airy(np.linspace(0.0, 2000.0, 81))
    y = spectra @ _sensitivities(NIKON)
    y = y * (1 + 0.005 * rng.normal(size=y.shape))
    env = EnvMap.from_array(small_courtyard)
    photo, bg = film_photo(env, 1500.0, 35, "Sigma SDMerill (NPL)", "E")
    with tempfile.TemporaryDirectory() as tmp:
        path = f"{tmp}/film.csv"
        with open(path, "w") as fh:
            fh.write(fit_response([("film", spectra, y)]).csv_text())
        r = fit_photo(photo, env, background=bg, options=FitOptions(
            disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=path,
            illuminant="E", view=ORTHOGRAPHIC))
    check = r.colour_check
    assert abs(r.params["thickness_nm"] - 1500.0) > 10 * r.stderr["thickness_nm"], (r.params, r.stderr)
    assert not r.ok and not check["consistent"], (check, r.warnings)
    assert any("camera response" in w and "calibrate-camera" in w for w in r.warnings), r.warnings


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["decide", "warn"])
def test_a_wrong_camera_on_a_draining_film(small_courtyard, mode):
    """A draining film (200 nm at the top to 1500 nm at the bottom) photographed by the
    Nikon under illuminant E (8-bit), fitted as sRGB/D65 with the drainage profile: the
    colour check fails it (measured 6.7 against 1.64 on this photo,
    experiments/colour_check_null.py), and the fit is not ok with the camera's warning;
    with ``JudgeSettings(colour_check="warn")`` the same warning is there, marked as a
    warning only, and the record says it did not decide."""
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import JudgeSettings, starts
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.lighting.envmap import EnvMap

    env = EnvMap.from_array(small_courtyard)
    photo, bg = film_photo(env, (200.0, 1500.0, 1.0), 51, NIKON, "E")
    r = fit_photo(photo, env, background=bg, options=FitOptions(
        disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response="srgb", view=ORTHOGRAPHIC,
        illuminant="D65", thickness="drainage", judge=JudgeSettings(colour_check=mode)))
    check = r.to_json()["colour_check"]
    assert check is not None and not check["consistent"] and check["decides"] is (mode == "decide"), check
    said = [w for w in r.warnings if "camera response" in w]
    assert len(said) == 1 and "calibrate-camera" in said[0], r.warnings
    assert ("warning only" in said[0]) is (mode == "warn"), said
    if mode == "decide":
        assert not r.ok


def _smooth_colours(h=48, w=48):
    y, x = np.mgrid[0:h, 0:w]
    mask = (x - w / 2) ** 2 + (y - h / 2) ** 2 < (0.42 * w) ** 2
    truth = np.stack([0.3 + 0.2 * np.sin(x / 7), 0.35 + 0.15 * np.cos(y / 9), 0.25 + 0.1 * np.sin((x + y) / 11)], -1)
    return truth, mask


def test_colour_check_null_law():
    """The statistic's law when the render is right and the noise is the stated one:
    Gaussian noise whose standard deviation differs between the channels (2, 6, 12 per
    mille: the chromatic plane is far from isotropic) on ~25 px cells, no model floor.
    Each cell's two chromatic components, whitened by their exact covariance, are two
    standard normals, so the statistic per degree of freedom averages 1 (its standard
    deviation over 300 photos is sqrt(2 / 64) / sqrt(300) = 0.01; tolerance 0.05) and the
    check fails on a photo at the false-alarm rate 1e-3 (0.3 of 300 expected; at most 2)."""
    from bubblefit.inverse.colour_check import colour_check

    truth, mask = _smooth_colours()
    sigma = np.array([0.002, 0.006, 0.012]) * np.ones_like(truth)
    values, fails = [], 0
    for seed in range(300):
        photo = truth + sigma * np.random.default_rng(seed).normal(size=truth.shape)
        c = colour_check(photo, truth, mask, sigma, floor=0.0, chroma_floor=0.0)
        values.append(c.chi2_per_dof)
        fails += not c.consistent
    assert abs(np.mean(values) - 1.0) < 0.05, np.mean(values)
    assert fails <= 2, fails


def test_colour_check_sees_hue_not_brightness_noise_or_glints():
    """On a disc of smoothly varying colours with noise (1 % of the signal): a render whose
    brightness is off by 5 % is consistent (the test looks at hue only), one whose hue is
    off by 2 % in one channel is not; noise twice the stated one is measured from the
    photo's own scatter (noise_scale ~ 4) and raises no alarm, and neither do a few glint
    pixels (outliers of the fit's model-error floor, left out as the verdict's split does)."""
    from bubblefit.inverse.colour_check import colour_check

    truth, mask = _smooth_colours()
    sigma = 0.01 * truth
    for seed in range(5):
        rng = np.random.default_rng(seed)
        photo = truth + sigma * rng.normal(size=truth.shape)
        assert colour_check(photo, truth * 1.05, mask, sigma).consistent
        hue = colour_check(photo, truth * np.array([1.02, 1.0, 1.0]), mask, sigma)
        assert not hue.consistent and 0.004 < hue.chroma_rms < 0.02, hue
        loud = truth + 2 * sigma * rng.normal(size=truth.shape)
        c = colour_check(loud, truth, mask, sigma)
        assert c.consistent and 3.0 < c.noise_scale < 5.0, c
        glint = photo.copy()
        glint[20:22, 20:22] += np.array([0.6, 0.3, 0.0])
        assert colour_check(glint, truth, mask, sigma, model_error=0.03).consistent


def test_colour_check_type_b_offset():
    """A nuisance's Type B offset ``s_b`` (the model's render with the nuisance's other
    choice less its own) joins each part's floor as ``s_b s_b^T``. A photo whose hue differs
    from the render by exactly that offset (2 % more red: 0.004-0.02 of chroma, which fails
    alone, as above), in either sign, is then consistent: by Sherman-Morrison a part's
    statistic along ``s_b`` is ``(s_b^T C^-1 s_b) / (1 + s_b^T C^-1 s_b) < 1`` and the
    component across it keeps the null law, about 1 per degree of freedom in all. Twice
    the offset is not (about 4 along it: 2.5 per degree of freedom, over the limit near
    1.5). A zero offset leaves the statistic as it was; several sources add their outer
    products."""
    from bubblefit.inverse.colour_check import colour_check

    truth, mask = _smooth_colours()
    sigma = 0.01 * truth
    shift = truth * np.array([0.02, 0.0, 0.0])
    for seed in range(5):
        noise = sigma * np.random.default_rng(seed).normal(size=truth.shape)
        for sign in (1.0, -1.0):
            photo = truth + sign * shift + noise
            alone = colour_check(photo, truth, mask, sigma)
            held = colour_check(photo, truth, mask, sigma, offset=shift)
            assert not alone.consistent and held.consistent, (alone, held)
            # the offset measured as the residual is: their RMS agree within the noise of a
            # ~25 px mean (0.01 / 5 of the brightness)
            assert abs(held.offset_rms - alone.chroma_rms) < 0.002, (held.offset_rms, alone.chroma_rms)
        far = colour_check(truth + 2 * shift + noise, truth, mask, sigma, offset=shift)
        assert not far.consistent, far
        # independent sources stack, each its own outer product: a second source across the
        # first (more green) lets the photo hold both offsets; a zero source changes nothing
        green = truth * np.array([0.0, 0.02, 0.0])
        both = truth + shift + green + noise
        assert not colour_check(both, truth, mask, sigma, offset=shift).consistent
        assert colour_check(both, truth, mask, sigma, offset=np.stack([shift, green])).consistent
        two = colour_check(far_photo := truth + 2 * shift + noise, truth, mask, sigma,
                           offset=np.stack([shift, np.zeros_like(shift)]))
        assert two.chi2_per_dof == colour_check(far_photo, truth, mask, sigma, offset=shift).chi2_per_dof
        same = colour_check(truth + noise, truth, mask, sigma, offset=np.zeros_like(truth))
        plain = colour_check(truth + noise, truth, mask, sigma)
        assert same.chi2_per_dof == plain.chi2_per_dof and same.offset_rms == 0.0 and plain.offset_rms is None


def test_colour_check_noise_shared_by_neighbours():
    """Noise drawn once per 2 x 2 block of pixels holds, in a mean over n pixels, the noise
    of about n/4 independent ones, while each pixel's scatter is the stated sigma: taken as
    independent pixels the statistic would read about 4 per degree of freedom. Neighbouring
    pixels then differ less than independent ones (0.3 of the prediction, under the check's
    0.6), so the check measures the blocks' variance from the photo (noise_scale ~ 3: the
    cells' planes take part of it)
    and the statistic stays about 1 (200 photos: mean 1.07, 2 % false alarms; here 40
    photos, mean within 0.15 of 1 and at most 3 false alarms, 0.8 expected)."""
    from bubblefit.inverse.colour_check import colour_check

    truth, mask = _smooth_colours()
    sigma = 0.01 * np.ones_like(truth)
    values, scales, fails = [], [], 0
    for seed in range(40):
        block = 0.01 * np.random.default_rng(seed).normal(size=(24, 24, 3))
        c = colour_check(truth + np.kron(block, np.ones((2, 2, 1))), truth, mask, sigma, floor=0.0, chroma_floor=0.0)
        values.append(c.chi2_per_dof)
        scales.append(c.noise_scale)
        fails += not c.consistent
    assert abs(np.mean(values) - 1.0) < 0.15 and fails <= 3, (np.mean(values), fails)
    assert 2.0 < np.mean(scales) < 5.0, np.mean(scales)


def _thick_film_path(h=48, w=48, thickness=1500.0, n=1.33):
    """The optical path ``2 n d cos t`` (nm) over :func:`_smooth_colours`' disc of a constant
    film seen orthographically (``sin(theta_i) = r / R``; Snell: ``sin t = sin(theta_i) / n``)."""
    y, x = np.mgrid[0:h, 0:w]
    s2 = np.clip(((x - w / 2) ** 2 + (y - h / 2) ** 2) / (0.42 * w) ** 2, 0.0, 1.0)
    return 2.0 * n * thickness * np.sqrt(1.0 - s2 / n**2)


def test_colour_check_cells_follow_the_optical_path():
    """A hue error that turns with the film's optical path (period 500 nm, as a response's
    error at 500 nm does) over a 1500 nm film's disc, whose path changes by up to ~100 nm
    per pixel: the 6 x 6 grid's outer cells each span a fringe and average it towards
    zero, the cells split by the path (``PATH_BIN``, 95 nm: each part keeps at least
    sinc(95 / 500) = 0.94 of it) keep it. Its amplitude, one noise sigma per pixel, gives
    a non-centrality (the statistic less its degrees of freedom) of up to 0.94^2 N
    (N ~ 1390 pixels; at least half of N asserted: parts under 4 pixels are left out, and
    the estimate's deviation is ~70) over about 2 x 150 degrees of freedom, a statistic
    over 3 times the threshold on every draw, and more than twice what the grid's 32
    cells keep (only its central cells, where the path changes slowly, hold the error). The right render with the path split follows the chi^2 law (parts of 4 or
    more pixels, each mean whitened by its exact covariance): mean 1 within 0.05 (its
    deviation over 100 photos ~0.01) and at most 2 false alarms in 100 (0.1 expected)."""
    from bubblefit.inverse.colour_check import PATH_BIN, colour_check

    assert PATH_BIN == 95.0
    truth, mask = _smooth_colours()
    path = _thick_film_path()
    sigma = np.array([0.004, 0.004, 0.004]) * np.ones_like(truth)
    u = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)           # two directions orthogonal to grey
    v = np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0)
    turn = 2 * np.pi * path / 500.0
    error = 0.004 * (np.cos(turn)[..., None] * u + np.sin(turn)[..., None] * v)
    values, fails = [], 0
    for seed in range(100):
        noise = sigma * np.random.default_rng(seed).normal(size=truth.shape)
        c = colour_check(truth + noise, truth, mask, sigma, floor=0.0, chroma_floor=0.0, path=path)
        values.append(c.chi2_per_dof)
        fails += not c.consistent
        if seed < 5:
            split = colour_check(truth + error + noise, truth, mask, sigma, floor=0.0, chroma_floor=0.0, path=path)
            grid = colour_check(truth + error + noise, truth, mask, sigma, floor=0.0, chroma_floor=0.0)
            assert not split.consistent and split.chi2_per_dof > 3.0 * split.threshold_per_dof, split
            kept = [(c.chi2_per_dof - 1.0) * 2 * c.cells for c in (split, grid)]  # non-centralities
            assert kept[0] > 0.5 * mask.sum() and kept[0] > 2.0 * kept[1], (kept, split, grid)
    assert abs(np.mean(values) - 1.0) < 0.05, np.mean(values)
    assert fails <= 2, fails


def test_the_verdict_splits_the_cells_by_the_fitted_films_path():
    """``judge_colours`` given the fitted film (a 1500 nm thickness, n 1.33) splits the
    check's cells by its optical path at each pixel's cosine, as :func:`colour_check` does
    given that path (the same parts, the same statistic), so a hue error that turns with
    the path is caught by every caller that states its film (the fit with a stated
    response and the fit that frees it); without the film the cells are not split."""
    from bubblefit.inverse.colour_check import INNER_COS, colour_check, judge_colours

    truth, mask = _smooth_colours()
    h, w = mask.shape
    y, x = np.mgrid[0:h, 0:w]
    cos = np.sqrt(1.0 - np.clip(((x - w / 2) ** 2 + (y - h / 2) ** 2) / (0.42 * w) ** 2, 0.0, 1.0))
    path = _thick_film_path()
    sigma = 0.004 * np.ones_like(truth)
    turn = 2 * np.pi * path / 500.0
    u, v = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0), np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0)
    photo = truth + 0.004 * (np.cos(turn)[..., None] * u + np.sin(turn)[..., None] * v)
    photo = photo + sigma * np.random.default_rng(3).normal(size=truth.shape)
    ok, warnings, record = judge_colours(True, [], photo, truth, mask, cos, sigma, thickness=1500.0, n_film=1.33)
    direct = colour_check(photo, truth, mask & (cos > INNER_COS), sigma, path=path, pooled=True)
    assert record["cells"] == direct.cells and record["chi2_per_dof"] == pytest.approx(direct.chi2_per_dof, rel=1e-6)
    assert record["partition"] == direct.partition
    assert not ok and not record["consistent"], record
    _, _, unsplit = judge_colours(True, [], photo, truth, mask, cos, sigma)
    split = colour_check(photo, truth, mask & (cos > INNER_COS), sigma, path=path)
    assert unsplit["partition"] == "cells" and unsplit["cells"] < split.cells, (unsplit, split)


def test_colour_check_pools_each_path_over_the_film():
    """``pooled``: a constant film's hue error is a function of its optical path alone, so
    the path's bins pooled over the whole film keep it (each bin of 95 nm keeps at least
    sinc(95 / 500) = 0.94 of an error of period 500 nm) and hold it in about 2 x 15
    degrees of freedom (the 1500 nm film's path spans ~1360 nm) instead of the ~2 x 150
    of the grid's cells split by path. An error of 0.35 noise sigma per pixel over
    N ~ 1280 pixels has a non-centrality of up to 0.94^2 0.35^2 N ~ 140: against 30
    degrees of freedom (threshold ~2.1 per degree at 5e-4) the pooled statistic reads
    ~5.7 per degree, against 300 (threshold ~1.3) the split ~1.5; so the pooled partition
    is reported, over twice its threshold, and the check fails on every draw. The right
    render: the union of the two partitions, each at half the false-alarm rate, fails at
    most at the rate 1e-3 (0.1 of 100 expected; at most 2)."""
    from bubblefit.inverse.colour_check import colour_check

    truth, mask = _smooth_colours()
    path = _thick_film_path()
    sigma = 0.004 * np.ones_like(truth)
    u, v = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0), np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0)
    turn = 2 * np.pi * path / 500.0
    error = 0.35 * 0.004 * (np.cos(turn)[..., None] * u + np.sin(turn)[..., None] * v)
    fails = 0
    for seed in range(100):
        noise = sigma * np.random.default_rng(seed).normal(size=truth.shape)
        fails += not colour_check(truth + noise, truth, mask, sigma, floor=0.0, chroma_floor=0.0, path=path,
                                  pooled=True).consistent
        if seed < 5:
            c = colour_check(truth + error + noise, truth, mask, sigma, floor=0.0, chroma_floor=0.0, path=path,
                             pooled=True)
            assert not c.consistent and c.partition == "path" and c.chi2_per_dof > 2.0 * c.threshold_per_dof, c
            assert 10 <= c.cells <= 20, c
    assert fails <= 2, fails


def _draining_film_colours(camera: str, lamp: str | None = None, n: int = 64):
    """Closed-form colours of a draining film seen by a measured camera, written here
    independently of the package: the Airy reflectance of a free film in air at normal
    incidence (index 1.33), ``R = F sin^2(delta/2) / (1 + F sin^2(delta/2))`` with
    ``delta = 4 pi n d / lambda`` and ``F = 4 r^2 / (1 - r^2)^2``, times colour-science's
    camera sensitivities (and a CIE lamp's spectrum) over 400-700 nm, each channel's
    white 1. Returns ``(colours(top, bottom), mask)``: a function giving the (n, n, 3)
    image of a film thinning linearly from ``top`` nm at the disc's top to ``bottom``
    nm at its bottom, and the disc (radius 0.42 n)."""
    import colour

    lam = np.arange(400.0, 701.0, 5.0)
    msds = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    sens = np.stack([np.interp(lam, msds.wavelengths, msds.values[:, c]) for c in range(3)], axis=1)
    if lamp is not None:
        sd = colour.SDS_ILLUMINANTS[lamp]
        sens = sens * np.interp(lam, sd.wavelengths, sd.values)[:, None]
    depth = np.arange(0.0, 2500.0, 1.0)
    r = (1.33 - 1) / (1.33 + 1)
    f = 4 * r**2 / (1 - r**2) ** 2
    s2 = np.sin(2 * np.pi * 1.33 * depth[:, None] / lam) ** 2
    table = (f * s2 / (1 + f * s2)) @ sens / sens.sum(axis=0)
    y, x = np.mgrid[0:n, 0:n]
    radius = 0.42 * n
    mask = (x - n / 2 + 0.5) ** 2 + (y - n / 2 + 0.5) ** 2 < radius**2
    height = np.clip((y - (n / 2 - radius)) / (2 * radius), 0.0, 1.0)

    def colours(top, bottom):
        return table[np.round(top + (bottom - top) * height).astype(int)]

    return colours, mask


def test_colour_check_wrong_lamp_on_a_draining_film():
    """A 64 px draining film (200 -> 1500 nm) photographed by the Nikon D5100 under
    illuminant E (read and shot noise), and the same film rendered as if lit by CIE A (a
    halogen lamp: the stated response Nikon x A), its profile and a gain per channel fitted
    to the photo by least squares (more freedom than a fit's exposure): its reduced chi^2
    with the fit's 3 % model-error floor is about 1.3, within the verdict's 3, but its hues
    follow the thickness, and the colour check fails it (20 noise draws: statistic at least
    2.7, mean 3.4, threshold 1.64); the noise scale from neighbouring pixels stays near 1 (the hue error
    cancels in their differences). The right render passes every draw (at most 1.03)."""
    from bubblefit.inverse.colour_check import colour_check

    right, mask = _draining_film_colours("Nikon 5100 (NPL)")
    wrong, _ = _draining_film_colours("Nikon 5100 (NPL)", "A")
    clean = 3.0 * right(200.0, 1500.0) + 0.05
    sigma = np.sqrt(0.003**2 + 1e-4 * clean)
    for seed in range(10):
        photo = clean + sigma * np.random.default_rng(seed).normal(size=clean.shape)
        good = colour_check(photo, clean, mask, sigma)
        assert good.consistent and good.noise_scale < 1.2, good
        best = None
        for top in np.arange(150.0, 251.0, 5.0):
            for bottom in np.arange(1450.0, 1551.0, 5.0):
                base, seen = wrong(top, bottom)[mask], photo[mask] - 0.05
                gain = (base * seen).sum(axis=0) / (base * base).sum(axis=0)
                chi2 = np.sum((base * gain - seen) ** 2 / (sigma[mask] ** 2 + (0.03 * photo[mask]) ** 2))
                if best is None or chi2 < best[0]:
                    best = (chi2, top, bottom, gain)
        chi2, top, bottom, gain = best
        assert chi2 / (3 * mask.sum()) < 3.0, best  # the chi^2 alone would pass it
        bad = colour_check(photo, wrong(top, bottom) * gain + 0.05, mask, sigma)
        assert not bad.consistent and bad.noise_scale < 1.2, bad


def test_colour_check_decides_or_warns():
    """``judge_colours`` with ``decide`` (``JudgeSettings.colour_check = "decide"``, the
    default) makes a fit with inconsistent hues not ok; with ``decide`` False
    (``"warn"``) it keeps ``ok`` and adds the same reason, marked as a warning only; both
    record the test and whether it decided. A consistent photo keeps ``ok`` either way."""
    from bubblefit.inverse import JudgeSettings
    from bubblefit.inverse.colour_check import judge_colours

    assert JudgeSettings().colour_check == "decide"
    with pytest.raises(ValueError):
        JudgeSettings(colour_check="ignore")
    truth, mask = _smooth_colours()
    sigma = 0.01 * truth
    photo = truth + sigma * np.random.default_rng(0).normal(size=truth.shape)
    cos = np.ones(mask.shape)
    hue = truth * np.array([1.02, 1.0, 1.0])
    ok, warnings, record = judge_colours(True, [], photo, hue, mask, cos, sigma)
    assert not ok and len(warnings) == 1 and "camera response" in warnings[0] and record["decides"], warnings
    ok, warnings, record = judge_colours(True, [], photo, hue, mask, cos, sigma, decide=False)
    assert ok and len(warnings) == 1 and "warning only" in warnings[0], warnings
    assert not record["consistent"] and not record["decides"]
    for decide in (True, False):
        ok, warnings, record = judge_colours(True, [], photo, truth, mask, cos, sigma, decide=decide)
        assert ok and warnings == [] and record["consistent"], (warnings, record)


def test_colour_check_option_of_fit_and_fit_sequence(tmp_path, capsys):
    """``--colour-check warn`` reaches ``FitOptions.judge.colour_check`` for ``fit`` and
    ``fit-sequence``; the default decides; another word is refused by the parser (exit 2,
    one line naming the choices)."""
    from bubblefit.cli import build_parser
    from bubblefit.cli.fit import build_fit_options

    photo, env = tmp_path / "p.png", tmp_path / "e.exr"
    for f in (photo, env):
        f.write_bytes(b"x")
    for command in (["fit", str(photo)], ["fit-sequence", str(photo), "-o", str(tmp_path / "frames")]):
        for extra, want in (([], "decide"), (["--colour-check", "warn"], "warn")):
            args = build_parser().parse_args([*command, "--envmap", str(env), *extra])
            assert build_fit_options(args, None, 8, None).judge.colour_check == want
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["fit", str(photo), "--envmap", str(env), "--colour-check", "ignore"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "decide" in err[0] and "warn" in err[0], err


def _bilinear(mosaic):
    """Bilinear demosaic of an RGGB mosaic written here: each missing colour the weighted
    mean of its nearest photosites of that colour (kernel 1-2-1 x 1-2-1, normalised)."""
    from scipy.ndimage import convolve

    h, w = mosaic.shape
    where = np.zeros((h, w, 3), bool)
    where[0::2, 0::2, 0] = where[0::2, 1::2, 1] = where[1::2, 0::2, 1] = where[1::2, 1::2, 2] = True
    k = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]])
    out = np.empty((h, w, 3))
    for c in range(3):
        m = where[..., c].astype(float)
        out[..., c] = np.where(where[..., c], mosaic, convolve(mosaic * m, k, mode="mirror") /
                               convolve(m, k, mode="mirror"))
    return out


def test_colour_check_demosaiced_noise():
    """A demosaiced photo's channel mean over n pixels holds the noise of about n/4 red,
    n/2 green and n/4 blue photosites: the photosite noise divided by sqrt(share) bounds
    the noise of a cell's mean from above (the interpolation spreads the photosites at a
    cell's edge over its neighbours' pixels too, which averages them further), so the
    statistic per degree of freedom is at most 1 (60 photos: standard deviation 0.023;
    tolerance 0.05) and not far below (over 0.6 on these ~5 px cells); taken as
    independent pixels it is about twice as large ((4 + 2) / 2 times less the spread)."""
    from bubblefit.inverse.colour_check import colour_check

    truth, mask = _smooth_colours()
    clean = _bilinear(_mosaic(truth))  # the interpolation of the scene itself is not noise
    sigma = 0.01 * np.ones_like(truth)
    share = np.array([0.25, 0.5, 0.25])
    right, naive = [], []
    for seed in range(60):
        noise = 0.01 * np.random.default_rng(seed).normal(size=truth.shape[:2])
        photo = _bilinear(_mosaic(truth) + noise)
        right.append(colour_check(photo, clean, mask, sigma / np.sqrt(share), floor=0, chroma_floor=0).chi2_per_dof)
        naive.append(colour_check(photo, clean, mask, sigma, floor=0, chroma_floor=0).chi2_per_dof)
    assert 0.6 < np.mean(right) < 1.05, np.mean(right)
    assert np.mean(naive) > 2.0 * np.mean(right), (np.mean(naive), np.mean(right))


def test_sequence_frames_carry_the_reading(tmp_path):
    """fit-sequence's frames are read with the command's encoding (a linear 12-bit TIFF)."""
    import tifffile

    from bubblefit.inverse import FrameRef, load_frame

    scene = _scene()
    tifffile.imwrite(str(tmp_path / "f.tif"), np.round(scene * 4095).astype(np.uint16), photometric="rgb")
    ref = FrameRef(0, str(tmp_path / "f.tif"), 0.0, reading=PhotoReading("linear", white_level=4095))
    assert np.max(np.abs(load_frame(ref) - scene)) <= 0.5 / 4095 + 1e-12
    plain = load_frame(FrameRef(0, str(tmp_path / "f.tif"), 0.0))  # no reading: sRGB assumed, 16-bit codes
    assert np.max(np.abs(plain - scene)) > 0.1


def test_patch_means_and_their_errors():
    """Patch means of a photo of uniform squares with noise: each within 4 sigma / sqrt(n);
    a patch over the edge or over clipped pixels is refused."""
    from bubblefit.capture.camera_calibration import patch_means

    rng = np.random.default_rng(2)
    values = rng.uniform(0.05, 0.8, (4, 3))
    img = np.zeros((40, 40, 3))
    centres = [(10, 10), (30, 10), (10, 30), (30, 30)]
    for (cx, cy), v in zip(centres, values):
        img[cy - 8:cy + 9, cx - 8:cx + 9] = v
    img += rng.normal(0, 0.01, img.shape)
    got = patch_means(img, [(cx, cy, 5) for cx, cy in centres])
    assert np.all(np.abs(got - values) < 4 * 0.01 / np.sqrt(121))
    with pytest.raises(InputError, match="inside"):
        patch_means(img, [(38, 10, 5)])
    sat = np.zeros((40, 40), bool)
    sat[10, 10] = True
    with pytest.raises(InputError, match="clipped"):
        patch_means(img, [(10, 10, 5)], sat)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [35, 36])
def test_pale_thick_film_found_in_its_order(small_courtyard, seed):
    """A constant 1500 nm film (Nikon D5100 under E, 8-bit codes) fitted with the Nikon's
    own response: on these two noise draws the search grid's two lowest minima are the
    orders above (about 1730 and 1950 nm) and the film's own order is its third; refined,
    the film's order has the lowest chi^2 by about 400, so the search must refine more than
    two candidates. Within 5 nm (standard error about 1.1 nm, the model-error floor aside)
    and ok."""
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.lighting.envmap import EnvMap

    env = EnvMap.from_array(small_courtyard)
    photo, bg = film_photo(env, 1500.0, seed, NIKON, "E")
    r = fit_photo(photo, env, background=bg, options=FitOptions(
        disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=NIKON, illuminant="E",
        view=ORTHOGRAPHIC))
    assert abs(r.params["thickness_nm"] - 1500.0) < 5.0, (r.params, r.warnings)
    assert r.ok, r.warnings


@pytest.mark.slow
def test_chart_calibrated_order_test(small_courtyard):
    """The ColorChecker's patches seen by the Nikon under E (0.5 % noise) calibrate a CSV
    whose errors are wide on thick films. A 1300 nm photo rendered with the Nikon's own
    sensitivities is fitted with it by the global search, and warm-started one order up
    (1524 nm). The colour check cannot tell the orders apart with these errors; the order
    test (the search's candidates compared with the CSV's errors marginalised,
    bubblefit.inverse.order_check) must: a fit is ok only within 3 standard errors of the
    truth, and the warm start one order up is not ok, with the line that names the order
    the photo prefers."""
    from bubblefit.capture.camera_calibration import chart_reflectances, fit_response
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse import starts
    from bubblefit.inverse.fit import FitOptions, fit_photo
    from bubblefit.lighting.envmap import EnvMap
    import tempfile

    _, refl = chart_reflectances()
    rgb = refl @ _sensitivities(NIKON) * (1 + 0.005 * np.random.default_rng(0).normal(size=(24, 3)))
    env = EnvMap.from_array(small_courtyard)
    photo, bg = film_photo(env, 1300.0, 34, NIKON, "E")
    with tempfile.TemporaryDirectory() as tmp:
        path = f"{tmp}/chart.csv"
        with open(path, "w") as fh:
            fh.write(fit_response([("chart", refl, rgb)]).csv_text())
        opts = FitOptions(disc=DISC, parameters=starts(t=0.968, roughness=0.04), model="paper", camera_response=path,
                          illuminant="E", view=ORTHOGRAPHIC)
        searched = fit_photo(photo, env, background=bg, options=opts)
        warm = fit_photo(photo, env, background=bg, options=opts, init=dict(searched.params, thickness_nm=1524.0))
    for fit in (searched, warm):
        assert fit.order_check is not None
        if fit.ok:
            assert abs(fit.params["thickness_nm"] - 1300.0) < 3 * fit.stderr["thickness_nm"], fit.params
    assert abs(warm.params["thickness_nm"] - 1300.0) > 150.0  # the warm start stayed an order up
    assert not warm.ok and not warm.order_check["determined"], warm.order_check
    assert any("admits the neighbouring order" in w for w in warm.warnings), warm.warnings
