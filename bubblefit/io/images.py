"""Image input and output through OpenImageIO, with sRGB transfer through colour-science.

Conventions (docs/design.md): images in memory are ``float`` arrays of shape (H, W, 3) holding
linear radiance. 8- and 16-bit files (PNG, JPEG, TIFF) are sRGB-encoded unless told
otherwise; EXR and HDR files, and float TIFFs, are linear. Writers are atomic: they write
to a temporary file beside the target and rename it, so a failed run never leaves a
half-written file nor destroys an existing one.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..errors import InputError, OutputError
from .atomic import atomic_path, preview_path

__all__ = [
    "Image",
    "read_image",
    "write_image",
    "write_preview",
    "srgb_decode",
    "srgb_encode",
    "srgb_slope",
    "atomic_path",
    "preview_path",
]

_LINEAR_EXTENSIONS = {".exr", ".hdr", ".pfm"}


def _first_line(text: str) -> str:
    """The first non-empty line of a (possibly multi-line) library message."""
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[0] if lines else ""


def srgb_decode(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear: ``V / 12.92`` up to 0.04045, else
    ``((V + 0.055) / 1.055)^2.4`` (IEC 61966-2-1:1999, sec. 5.2)."""
    v = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def srgb_encode(values: np.ndarray) -> np.ndarray:
    """Linear values to sRGB-encoded values in [0, 1]: ``12.92 L`` up to 0.0031308, else
    ``1.055 L^(1/2.4) - 0.055`` (IEC 61966-2-1:1999, sec. 5.3)."""
    lin = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)


def srgb_slope(encoded: np.ndarray) -> np.ndarray:
    """``dL/dV`` of :func:`srgb_decode` at the encoded values ``V`` (the size in linear units
    of one step of the encoded value)."""
    v = np.clip(np.asarray(encoded, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((v + 0.055) / 1.055) ** 1.4)


@dataclass
class Image:
    """A linear RGB image with what its file said about it.

    Attributes:
        pixels: (H, W, 3) linear radiance (float64 unless read otherwise).
        path: where it was read from.
        bit_depth: 8, 16 or 32 (float) as stored in the file.
        linear_file: True when the file held linear values (EXR, HDR, float TIFF).
        saturated: (H, W) bool, pixels where any channel reached the file's maximum
            code value (meaningful for integer files only).
        metadata: the file's attributes (EXIF and others) as a dict of strings/numbers.
        alpha_dropped: True when an alpha channel was present and ignored.
        was_gray: True when the file had one channel that was replicated to three.
    """

    pixels: np.ndarray
    path: str = ""
    bit_depth: int = 32
    linear_file: bool = True
    saturated: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    alpha_dropped: bool = False
    was_gray: bool = False
    #: How the values were decoded (:class:`bubblefit.io.camera_files.EncodingChoice`).
    encoding: object = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape[0], self.pixels.shape[1]


def _undecodable_as_input_error(func):
    """OpenImageIO returns some strings of a corrupt file (error messages, attribute names)
    as bytes that are not UTF-8; the Python binding then raises UnicodeDecodeError. That is
    a damaged file, i.e. bad input: report it as one :class:`InputError` line."""
    import functools

    @functools.wraps(func)
    def wrapper(path, *args, **kwargs):
        try:
            return func(path, *args, **kwargs)
        except UnicodeDecodeError:
            raise InputError(f"cannot read image {path}: corrupt file (undecodable header or metadata)") from None

    return wrapper


@_undecodable_as_input_error
def read_image(path: str | os.PathLike, *, linear: bool | None = None, dtype=np.float64,
               encoding=None) -> Image:
    """Read an image file as linear RGB.

    Args:
        path: any format OpenImageIO reads (EXR, HDR, PNG, JPEG, TIFF, ...).
        linear: force the interpretation of integer files (True: already linear,
            False: sRGB). ``None`` decides from the file: integer data are sRGB unless
            the file's colour space attribute says linear; float data are linear.
        dtype: of the pixels (float64, or float32 for large photos read by the fit,
            whose arithmetic is float32: half the memory).
        encoding: a :class:`~bubblefit.io.camera_files.PhotoReading` (or one of its
            encodings, ``"auto"``, ``"srgb"``, ``"linear"``): how the values map to linear,
            decided by :func:`~bubblefit.io.camera_files.decide_encoding`; ``linear``, when
            given, is the same as ``"linear"``/``"srgb"`` forced.

    Raises:
        InputError: the file is missing, unreadable, truncated, has no pixels, has an
            unusable channel count, or holds NaN/Inf values.
    """
    path = str(path)
    if not os.path.exists(path):
        raise InputError(f"image not found: {path}")
    if os.path.isdir(path):
        raise InputError(f"expected an image file, got a folder: {path}")
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot read image {path}: {_first_line(oiio.geterror()) or 'unknown format'}")
    try:
        spec = inp.spec()
        if spec.width <= 0 or spec.height <= 0:
            raise InputError(f"image {path} has no pixels")
        fmt = spec.format.basetype
        if fmt in (oiio.UINT8, oiio.INT8):
            bit_depth, native = 8, oiio.UINT8
        elif fmt in (oiio.UINT16, oiio.INT16):
            bit_depth, native = 16, oiio.UINT16
        else:
            bit_depth, native = 32, oiio.FLOAT
        data = inp.read_image(0, 0, 0, spec.nchannels, native)
        metadata = {}
        for attrib in spec.extra_attribs:
            try:
                metadata[attrib.name] = attrib.value
            except Exception:  # attributes of exotic types are not needed
                pass
        err = inp.geterror()
    finally:
        inp.close()
    if data is None or (isinstance(data, np.ndarray) and data.size == 0):
        raise InputError(f"cannot read pixels of {path}: {_first_line(err) or 'truncated or corrupt file'}")
    if err and "corrupt" in err.lower():
        raise InputError(f"cannot read pixels of {path}: {_first_line(err)}")
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[:, :, None]
    nch = data.shape[2]
    alpha_dropped = False
    was_gray = False
    if nch == 1 or nch == 2:
        was_gray = True
        alpha_dropped = nch == 2
        data = np.repeat(data[:, :, :1], 3, axis=2)
    elif nch >= 4:
        alpha_dropped = True
        data = data[:, :, :3]
    elif nch != 3:
        raise InputError(f"image {path} has {nch} channels; expected 1 (gray), 3 (RGB) or 4 (RGBA)")

    from .camera_files import PhotoReading, decide_encoding, decode_codes

    if linear is not None:
        reading = PhotoReading("linear" if linear else "srgb", force=True)
    elif isinstance(encoding, PhotoReading):
        reading = encoding
    else:
        reading = PhotoReading(encoding or "auto")
    choice = decide_encoding(path, metadata, bit_depth, reading)
    is_linear = choice.encoding == "linear"
    if bit_depth in (8, 16):
        pixels, saturated = decode_codes(data, choice, bit_depth, dtype)
    else:
        pixels = data.astype(dtype)
        saturated = np.zeros(pixels.shape[:2], dtype=bool)
        if not is_linear:
            pixels = srgb_decode(pixels)
    if bit_depth == 32 and not np.all(np.isfinite(pixels)):
        bad = int(np.sum(~np.isfinite(pixels).all(axis=2)))
        raise InputError(f"image {path} has {bad} pixel(s) with NaN or Inf values")
    return Image(
        pixels=pixels,
        path=path,
        bit_depth=bit_depth,
        linear_file=bool(is_linear),
        saturated=saturated,
        metadata=metadata,
        alpha_dropped=alpha_dropped,
        was_gray=was_gray,
        encoding=choice,
    )


def write_image(path: str | os.PathLike, pixels: np.ndarray, *, bit_depth: int | None = None) -> None:
    """Write a linear image atomically.

    EXR/HDR files get linear float (half for EXR unless ``bit_depth=32``); PNG, JPEG and
    TIFF files get sRGB-encoded 8-bit (or 16-bit with ``bit_depth=16``) values.
    NaN pixels (e.g. outside the bubble in a thickness map) are kept in float files and
    written as 0 in integer files.
    """
    path = Path(path)
    pixels = np.asarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    h, w, c = pixels.shape
    ext = path.suffix.lower()
    if ext in _LINEAR_EXTENSIONS or (ext in (".tif", ".tiff") and bit_depth == 32):
        fmt = oiio.HALF if (ext == ".exr" and bit_depth != 32) else oiio.FLOAT
        if ext == ".hdr":
            fmt = oiio.FLOAT
        data = pixels
    else:
        depth = bit_depth or 8
        if depth not in (8, 16):
            raise InputError(f"cannot write {path}: {depth}-bit integer output is not supported")
        maxcode = 255 if depth == 8 else 65535
        enc = srgb_encode(np.nan_to_num(pixels, nan=0.0))
        data = np.round(enc * maxcode).astype(np.uint8 if depth == 8 else np.uint16)
        fmt = oiio.UINT8 if depth == 8 else oiio.UINT16
    spec = oiio.ImageSpec(w, h, c, fmt)
    if ext in (".jpg", ".jpeg"):
        spec.attribute("Compression", "jpeg:95")
    with atomic_path(path) as tmp:
        _write_oiio(tmp, path, spec, np.ascontiguousarray(data))


def _write_oiio(tmp: str, shown: os.PathLike, spec, data: np.ndarray) -> None:
    """Write ``data`` to ``tmp`` with OpenImageIO, checking the open, the pixels and the
    close: OpenImageIO reports a failed write (e.g. a full disk) through the return values
    and ``has_error``/``geterror()`` of the ImageOutput, not by raising."""
    out = oiio.ImageOutput.create(tmp)
    if out is None:
        raise OutputError(f"cannot write {shown}: {_first_line(oiio.geterror()) or 'unsupported format'}")
    opened = False
    try:
        opened = bool(out.open(tmp, spec))
        ok = opened and bool(out.write_image(data))
    finally:
        closed = bool(out.close()) if opened else False
    if not (ok and closed) or bool(out.has_error):
        raise OutputError(f"cannot write {shown}: {_oiio_reason(out.geterror(), tmp, shown, data.nbytes)}")


def _oiio_reason(message: str, tmp: str, shown: os.PathLike, nbytes: int) -> str:
    """The reason of a failed OpenImageIO write in one line: a full disk in plain words
    (OpenImageIO only says that the output failed), else its message, naming the target
    rather than the temporary file."""
    try:
        st = os.statvfs(os.path.dirname(os.path.abspath(tmp)))
        if st.f_bavail * st.f_frsize < max(nbytes, 1) // 2 + 4096:
            return "no space left on device"
    except OSError:
        pass
    return (_first_line(message) or "the image writer failed").replace(tmp, str(shown))


def write_preview(path: str | os.PathLike, pixels: np.ndarray, *, exposure: float = 1.0) -> None:
    """Write an 8-bit sRGB PNG preview of a linear image (values clipped to [0, 1])."""
    write_image(path, np.asarray(pixels) * exposure)
