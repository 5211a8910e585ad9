"""What a camera's file holds: its encoding (sRGB or linear), RAW sensor data, flat fields
and dark frames.

A thickness from colour is only as good as the linear values it starts from. This module
decides how the code values of an integer file map to linear radiance, reads RAW files
without any tone curve, and removes a dark frame and a flat field:

- **Encodings** (:func:`~bubblefit.io.encoding.decide_encoding`,
  :func:`~bubblefit.io.encoding.decode_codes`, in :mod:`bubblefit.io.encoding`). ``auto`` reads what the
  file says: float files (EXR, HDR, PFM, float TIFF) are linear; a PNG's ``sRGB``,
  ``gAMA`` and ``iCCP`` chunks, an embedded ICC profile's red tone curve (``rTRC``, ICC.1:2010
  sec. 10.6 ``curv`` and 10.18 ``para``) and OpenImageIO's ``oiio:ColorSpace`` (when the
  file stated it) decide integer files; a file that says nothing is sRGB (IEC 61966-2-1),
  and the record says it was assumed. ``linear`` maps code ``V`` to
  ``(V - black) / (white - black)``, so a 12-bit sensor's values in 16-bit containers are
  read with ``white = 4095`` (and a dark pedestal with ``black``). An encoding that
  contradicts what the file states is refused unless forced.
- **RAW** (:func:`read_raw`): LibRaw through ``rawpy``: the black level of each CFA
  channel subtracted, scaled by the white level, no gamma, no automatic brightening, the
  camera's as-shot white balance or none, demosaiced to linear *camera* RGB (or, asked for,
  to linear sRGB through the camera's colour matrix); the matrices are recorded.
- **Dark frame and flat field** (:func:`flat_dark`): ``(photo - dark) / flat_n`` with
  ``flat_n = (flat - dark) / median(flat - dark)`` per channel: vignetting and the lamp's
  unevenness divided out without changing the photo's colour balance.

:class:`~bubblefit.io.encoding.PhotoReading` holds these settings (one record from the command line to every
reader); :func:`read_photo` is the one entry point of the commands.
"""

from __future__ import annotations

import os
from dataclasses import asdict

import numpy as np

from ..errors import InputError
from .encoding import ENCODINGS, EncodingChoice, PhotoReading, decide_encoding, decode_codes

__all__ = [
    "RAW_EXTENSIONS",
    "PhotoReading",
    "is_raw",
    "read_raw",
    "flat_dark",
    "read_photo",
]

#: File extensions read as RAW sensor data through LibRaw (the formats LibRaw 0.21 reads
#: that cameras write; a file LibRaw does not know is refused in one line).
RAW_EXTENSIONS = frozenset({
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf", ".rw2",
    ".pef", ".srw", ".3fr", ".iiq", ".erf", ".kdc", ".mrw", ".x3f", ".mos", ".rwl",
})


# --------------------------------------------------------------------------- RAW


def is_raw(path: str) -> bool:
    """Whether ``path`` names a RAW file (by its extension, :data:`RAW_EXTENSIONS`)."""
    return os.path.splitext(str(path))[1].lower() in RAW_EXTENSIONS


def read_raw(path: str, reading: PhotoReading = PhotoReading(), dtype=np.float64):
    """A RAW file as linear RGB: the sensor's values unpacked by LibRaw (``rawpy``).

    For a Bayer sensor (a 2x2 colour filter pattern) every step is done here, so that the
    values stay exactly linear: each photosite's black level (per CFA channel) subtracted
    and the result divided by ``white - black`` (Adobe DNG Specification 1.6, ch. 5,
    "Mapping Raw Values to Linear Reference Values"), the camera's as-shot white-balance
    multipliers (``reading.raw_white_balance == "camera"``, normalised to green) or none,
    then bilinear demosaicing (each missing colour the mean of its nearest same-colour
    neighbours; sampled values kept: Ramanath et al., "Demosaicking methods for Bayer color
    arrays", J. Electron. Imaging 11(3), 2002, sec. 3.1), and the camera's orientation. The
    result is linear *camera* RGB, or, with ``raw_colour == "srgb"``, linear sRGB through
    LibRaw's camera-to-sRGB matrix (``rgb_cam``, from the camera's XYZ matrix). Other
    sensors (X-Trans, Foveon, ...) go through LibRaw's own processing with ``gamma=(1, 1)``
    and no automatic brightening: linear, but scaled by LibRaw (a global factor, which a
    fit's exposure absorbs).

    Returns
    -------
    Image
        ``encoding`` records the choice; ``metadata["raw"]`` the black and white levels, the
        as-shot multipliers, ``rgb_xyz_matrix`` (XYZ to camera) and ``color_matrix``
        (camera to sRGB).

    References
    ----------
    LibRaw 0.21 API (``raw_image``, ``raw_colors``, ``black_level_per_channel``,
    ``white_level``, ``camera_whitebalance``, ``rgb_xyz_matrix``, ``color_matrix``).
    """
    from .images import Image

    try:
        import rawpy
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError(f"cannot read RAW file {path}: the rawpy package is not installed") from None
    if not os.path.isfile(path):
        raise InputError(f"image not found: {path}")
    if reading.encoding == "srgb":
        raise InputError(f"{path} is a RAW file, which is linear; --encoding srgb contradicts it")
    if reading.black_level is not None or reading.white_level is not None:
        raise InputError(f"{path} is a RAW file: its black and white levels come from the file "
                         "(--black-level/--white-level are for linear TIFF/PNG files)")
    try:
        raw = rawpy.imread(str(path))  # LibRaw takes a plain str, not a subclass (the CLI's path types)
    except rawpy.LibRawFileUnsupportedError:
        raise InputError(f"cannot read RAW file {path}: LibRaw {'.'.join(map(str, rawpy.libraw_version))} does "
                         "not support this camera or format (convert it to DNG)") from None
    except (rawpy.LibRawError, OSError) as exc:
        raise InputError(f"cannot read RAW file {path}: {type(exc).__name__}: {exc}") from None
    with raw:
        try:
            sites = np.asarray(raw.raw_image_visible)
            if sites.size == 0 or int(sites.min()) == int(sites.max()):
                raise InputError(f"RAW file {path} holds no image: every photosite reads "
                                 f"{int(sites.max()) if sites.size else 'nothing'} (its image data stripped or "
                                 "the file cut short; a real exposure, even a dark frame, has noise)")
            desc = raw.color_desc.decode(errors="replace")
            wb = np.asarray(raw.camera_whitebalance, dtype=np.float64)
            info = {
                "camera_white_balance": wb.tolist(),
                "black_level_per_channel": [float(v) for v in raw.black_level_per_channel],
                "white_level": float(raw.white_level),
                "rgb_xyz_matrix": np.asarray(raw.rgb_xyz_matrix, float)[:3].tolist(),
                "color_matrix": np.asarray(raw.color_matrix, float)[:, :3].tolist(),
                "color_desc": desc,
                "raw_colour": reading.raw_colour,
                "raw_white_balance": reading.raw_white_balance,
            }
            pattern = raw.raw_pattern
            bayer = pattern is not None and np.shape(pattern) == (2, 2) and len(set(desc[:3])) == 3
            if bayer:
                pixels, saturated, share = _develop_bayer(raw, desc, wb, reading)
                info["photosite_share"] = share
                how = "bilinear demosaic here"
                flip = int(raw.sizes.flip)
            else:
                out = raw.postprocess(
                    gamma=(1, 1), no_auto_bright=True, output_bps=16, user_flip=0,
                    output_color=rawpy.ColorSpace.raw if reading.raw_colour == "camera" else rawpy.ColorSpace.sRGB,
                    **(dict(use_camera_wb=True) if reading.raw_white_balance == "camera"
                       else dict(use_camera_wb=False, user_wb=[1.0, 1.0, 1.0, 1.0])))
                pixels = np.asarray(out, np.float64) / 65535.0
                saturated = np.any(out >= 65535, axis=2)
                how, flip = "LibRaw's demosaic, scaled by LibRaw", 0
        except rawpy.LibRawError as exc:
            raise InputError(f"cannot decode RAW file {path}: {type(exc).__name__}: {exc}") from None
    pixels, saturated = _orient(pixels, flip), _orient(saturated, flip)
    why = (f"RAW through LibRaw: black level subtracted, no gamma, {reading.raw_white_balance} white balance, "
           f"{how}, {'camera RGB' if reading.raw_colour == 'camera' else 'linear sRGB via the camera matrix'}")
    return Image(pixels=pixels.astype(dtype), path=path, bit_depth=16, linear_file=True, saturated=saturated,
                 metadata={"raw": info}, encoding=EncodingChoice("raw", why, 0.0, 1.0))


def _develop_bayer(raw, desc: str, wb: np.ndarray, reading: PhotoReading):
    """``(pixels, saturated, share)`` of a Bayer sensor: levels, white balance, bilinear
    demosaic, and the colour matrix when asked (:func:`read_raw`); ``saturated`` marks the
    pixels whose own photosite reached the white level (a fit grows it by the demosaic's
    block, :data:`bubblefit.inverse._observation.CLIP_NEIGHBOURS`); ``share`` is the fraction
    of the photosites that measure each of R, G, B (1/4, 1/2, 1/4 for a Bayer mosaic): an
    average over ``n`` demosaiced pixels holds the noise of ``share * n`` photosites only."""
    from scipy.ndimage import convolve

    vals = np.asarray(raw.raw_image_visible, dtype=np.float64)
    cfa = np.asarray(raw.raw_colors_visible)
    black = np.asarray(raw.black_level_per_channel, dtype=np.float64)[cfa]
    white = float(raw.white_level)
    norm = (vals - black) / (white - black)
    channel = np.array(["RGB".index(c) if c in "RGB" else 1 for c in desc[:4].ljust(4, "G")])[cfa]
    if reading.raw_white_balance == "camera":
        gains = np.where(wb > 0, wb, wb[1])  # LibRaw leaves the second green's multiplier at 0
        norm = norm * (gains / gains[1])[cfa]
    kernel = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]])
    out = np.empty(vals.shape + (3,))
    for c in range(3):
        mask = (channel == c).astype(np.float64)
        num = convolve(norm * mask, kernel, mode="mirror")
        den = convolve(mask, kernel, mode="mirror")
        out[..., c] = np.where(mask > 0, norm, num / np.maximum(den, 1e-12))
    saturated = vals >= white
    if reading.raw_colour == "srgb":
        out = out @ np.asarray(raw.color_matrix, np.float64)[:, :3].T
    share = [float(np.mean(channel == c)) for c in range(3)]
    return out, saturated, share


def _orient(arr: np.ndarray, flip: int) -> np.ndarray:
    """The image as the camera was held: LibRaw's ``flip`` 3 (180 degrees), 5 (90 degrees
    counter-clockwise), 6 (90 degrees clockwise); 0 as stored."""
    if flip == 3:
        return arr[::-1, ::-1]
    if flip == 5:
        return np.rot90(arr, 1)
    if flip == 6:
        return np.rot90(arr, -1)
    return arr


# --------------------------------------------------------------------------- flat and dark


def flat_dark(pixels: np.ndarray, *, flat: np.ndarray | None = None, dark: np.ndarray | None = None,
              what: str = "photo", flat_path: str = "", dark_path: str = "") -> np.ndarray:
    """``(pixels - dark) / flat_n``, ``flat_n = (flat - dark) / median_c(flat - dark)``.

    The standard flat-field correction of a linear detector (e.g. Howell, *Handbook of
    CCD Astronomy*, 2nd ed., sec. 4.5): the dark frame removes the offset and fixed-pattern
    signal, the flat divides out the optics' vignetting and the light's unevenness. Each
    channel of the flat is normalised by its own median so the photo's colour balance is
    kept. Flat values at or below 1e-3 of the median (dead or unlit pixels) become NaN-free
    by leaving those pixels uncorrected.

    Raises
    ------
    InputError
        A frame of another size than the photo, or a flat with no positive channel.
    """
    h, w = pixels.shape[:2]
    out = np.asarray(pixels)
    for arr, name, p in ((dark, "dark frame", dark_path), (flat, "flat field", flat_path)):
        if arr is not None and arr.shape[:2] != (h, w):
            raise InputError(f"the {name} {p} is {arr.shape[1]}x{arr.shape[0]}, the {what} is {w}x{h}")
    if dark is not None:
        out = out - dark.astype(out.dtype)
    if flat is not None:
        f = flat.astype(np.float64) - (dark if dark is not None else 0.0)
        med = np.median(f.reshape(-1, 3), axis=0)
        if np.any(~(med > 0)):
            raise InputError(f"the flat field {flat_path} has a channel without light (median <= 0 after the dark)")
        fn = f / med
        fn = np.where(fn > 1e-3, fn, 1.0)
        out = (out / fn).astype(pixels.dtype)
    return out


# --------------------------------------------------------------------------- the entry point


def read_photo(path: str, reading: PhotoReading | None = None, *, dtype=np.float64, what: str = "photo"):
    """Read a camera's file as linear RGB under ``reading``: RAW through :func:`read_raw`,
    anything else through :func:`bubblefit.io.images.read_image` with the encoding decided
    by :func:`decide_encoding`; then the dark frame and flat field (:func:`flat_dark`).
    The returned :class:`~bubblefit.io.images.Image` carries ``encoding`` (an
    :class:`EncodingChoice`) and ``reading_record()`` for the JSON."""
    from .images import read_image

    reading = reading or PhotoReading()
    core = PhotoReading(**{**asdict(reading), "flat": None, "dark": None})
    img = read_raw(path, core, dtype) if is_raw(path) else read_image(path, encoding=core, dtype=dtype)
    if reading.flat or reading.dark:
        dark = read_photo(reading.dark, core, dtype=np.float64, what="dark frame").pixels if reading.dark else None
        flat = read_photo(reading.flat, core, dtype=np.float64, what="flat field").pixels if reading.flat else None
        img.pixels = flat_dark(img.pixels, flat=flat, dark=dark, what=f"{what} {path}",
                               flat_path=reading.flat or "", dark_path=reading.dark or "")
        img.metadata["bubblefit:corrections"] = {"flat": reading.flat, "dark": reading.dark}
    return img


def reading_record(img) -> dict:
    """The JSON record of how a photo was read: its encoding and reason, levels, RAW details
    and flat/dark corrections (what :func:`read_photo` attached)."""
    choice = getattr(img, "encoding", None)
    rec = choice.to_json() if choice is not None else {"encoding": "linear" if img.linear_file else "srgb",
                                                        "reason": "read without a stated encoding"}
    raw = img.metadata.get("raw") if isinstance(img.metadata, dict) else None
    if raw:
        rec["raw"] = raw
    corr = img.metadata.get("bubblefit:corrections") if isinstance(img.metadata, dict) else None
    if corr:
        rec.update({k: v for k, v in corr.items() if v})
    return rec
