"""Image input and output through OpenImageIO, with sRGB transfer through colour-science.

Conventions (docs/design.md): images in memory are ``float`` arrays of shape (H, W, 3) holding
linear radiance. 8- and 16-bit files (PNG, JPEG, TIFF) are sRGB-encoded unless told
otherwise; EXR and HDR files, and float TIFFs, are linear. Writers are atomic: they write
to a temporary file beside the target and rename it, so a failed run never leaves a
half-written file nor destroys an existing one.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..errors import InputError, OutputError
from .atomic import atomic_path, preview_path
from .encoding import PhotoReading, decide_encoding, decode_codes, srgb_decode, srgb_encode, srgb_slope

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
    "ImageWarning",
    "MAX_PIXELS",
]

_LINEAR_EXTENSIONS = {".exr", ".hdr", ".pfm"}

#: Largest image read, in pixels (width x height from the header, checked before any pixel
#: is decoded): 150 million holds the largest camera sensors sold (102 MP) and a 16K
#: equirectangular map (16384 x 8192 = 134 M); a 30000x30000 PNG (900 M pixels in 2.6 MB)
#: would need 22 GB as float64. ``bubblefit --max-megapixels N`` (or the environment's
#: ``BUBBLEFIT_MAX_PIXELS``) raises it.
MAX_PIXELS = 150_000_000


class ImageWarning(UserWarning):
    """Something about an input image that the result depends on (alpha, clipping): the
    command line prints it as one ``bubblefit: warning:`` line."""


def max_pixels() -> int:
    """The pixel limit in force: ``$BUBBLEFIT_MAX_PIXELS`` if set, else :data:`MAX_PIXELS`."""
    try:
        return int(float(os.environ.get("BUBBLEFIT_MAX_PIXELS", "")))
    except ValueError:
        return MAX_PIXELS


def _check_declared_size(path: str, spec) -> None:
    """Refuse, from the header alone, an image with more pixels than :func:`max_pixels` or
    with more than one subimage-sized plane of channels than RGBA can use."""
    pixels = int(spec.width) * int(spec.height) * max(int(spec.depth), 1)
    limit = max_pixels()
    if pixels > limit:
        raise InputError(f"image {path} is {spec.width}x{spec.height} ({pixels / 1e6:.0f} megapixels), above the "
                         f"limit of {limit / 1e6:.0f}; raise it with bubblefit --max-megapixels N")
    if spec.nchannels > 16:
        raise InputError(f"image {path} declares {spec.nchannels} channels; expected 1 to 4")


def _reader_config():
    """OpenImageIO's open options: alpha left unassociated, as PNG and TIFF store it
    (OpenImageIO otherwise multiplies the colour by alpha while reading)."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    return config


#: Markers of JPEG: start of scan and end of image (ITU-T T.81, table B.1).
_JPEG_SOS, _JPEG_EOI = b"\xff\xda", b"\xff\xd9"


def _check_file_end(path: str, fmt: str) -> None:
    """Refuse a JPEG or PNG file that stops before its end marker (a truncated copy or
    download). A JPEG decoder fills the missing rows and reports success or a warning; the
    file must hold an end-of-image marker after its last start of scan. A PNG must hold
    its IEND chunk near the end (trailing bytes after it are tolerated).

    References
    ----------
    ITU-T T.81 (JPEG), annex B.2: EOI ends the compressed image data.
    ISO/IEC 15948:2004 (PNG), sec. 11.2.5: IEND is the last chunk.
    """
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            if fmt == "jpeg":
                data = fh.read()  # the limit on pixels bounds a JPEG's bytes only loosely; read once
                sos = data.rfind(_JPEG_SOS)
                complete = sos >= 0 and data.find(_JPEG_EOI, sos + 2) >= 0
            elif fmt == "png":
                fh.seek(max(size - 4096, 0))
                complete = b"IEND" in fh.read()
            else:
                return
    except OSError:
        return  # the decoder has read it; its own errors are reported
    if not complete:
        raise InputError(f"cannot read pixels of {path}: the file is truncated (no end marker)")


@contextlib.contextmanager
def _native_stderr_filtered():
    """Context in which what C libraries print on file descriptor 2 is held back and passed
    on afterwards without libpng's own ``libpng error:``/``libpng warning:`` lines (the
    same error reaches the caller through OpenImageIO, as one line)."""
    import sys
    import tempfile

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            text = held.read().decode("utf-8", "replace")
            kept = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("libpng ")]
            if kept:
                print("\n".join(kept), file=sys.stderr)


def _decoder_error(path: str, err: str) -> None:
    """Refuse an image whose decoder reported any error while reading the pixels (a
    truncated or damaged file: "Premature end of JPEG file", "hit end of file", "missing
    or corrupted" scanlines), not only messages that say "corrupt"."""
    if err and err.strip():
        raise InputError(f"cannot read pixels of {path}: truncated or damaged file ({_first_line(err)})")


def _alpha_checked(path: str, data: np.ndarray, alpha_channel: int, maxcode: float) -> None:
    """Warn when the alpha channel that is dropped is not opaque everywhere: the colour is
    used as the file stores it (unassociated), not multiplied by alpha."""
    if alpha_channel < 0 or alpha_channel >= data.shape[2]:
        return
    alpha = data[:, :, alpha_channel]
    if np.any(alpha < maxcode):
        share = float(np.mean(alpha < maxcode))
        import warnings

        warnings.warn(f"{path} has an alpha channel that is not opaque in {100 * share:.1f} % of the pixels; "
                      "its colour is used as stored and alpha is ignored", ImageWarning, stacklevel=3)


def _first_line(text: str) -> str:
    """The first non-empty line of a (possibly multi-line) library message."""
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[0] if lines else ""


@dataclass
class Image:
    """A linear RGB image with what its file said about it.

    Attributes:
        pixels: (H, W, 3) linear radiance (float64 unless read otherwise).
        path: where it was read from.
        bit_depth: 8, 16 or 32 (float) as stored in the file.
        linear_file: True when the file held linear values (EXR, HDR, float TIFF).
        saturated: (H, W) bool, pixels where any channel reached the file's maximum
            code value, or, in a Bayer RAW file, whose own photosite reached the white
            level (meaningful for integer and RAW files only).
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
    #: How the values were decoded (:class:`bubblefit.io.encoding.EncodingChoice`).
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


def _check_path(path: str) -> None:
    """Refuse, in one line, a path that is missing, a folder, or not UTF-8 (OpenImageIO's open needs UTF-8)."""
    if not os.path.exists(path):
        raise InputError(f"image not found: {path}")
    if os.path.isdir(path):
        raise InputError(f"expected an image file, got a folder: {path}")
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raise InputError(f"cannot read image {path.encode('utf-8', 'surrogateescape').decode('utf-8', 'replace')}: "
                         "the path is not UTF-8 (rename it)") from None


def _decode_file(path: str) -> tuple[np.ndarray, int, dict, int]:
    """(codes (H, W, C) in the file's own type, bit depth 8/16/32, metadata, the alpha
    channel's index or -1) through OpenImageIO, with the declared size checked before
    decoding and a truncated file refused (the decoder's error, the file's end marker)."""
    inp = oiio.ImageInput.open(path, _reader_config())
    if inp is None:
        raise InputError(f"cannot read image {path}: {_first_line(oiio.geterror()) or 'unknown format'}")
    try:
        spec = inp.spec()
        if spec.width <= 0 or spec.height <= 0:
            raise InputError(f"image {path} has no pixels")
        _check_declared_size(path, spec)
        file_format = inp.format_name()
        fmt = spec.format.basetype
        if fmt in (oiio.UINT8, oiio.INT8):
            bit_depth, native = 8, oiio.UINT8
        elif fmt in (oiio.UINT16, oiio.INT16):
            bit_depth, native = 16, oiio.UINT16
        else:
            bit_depth, native = 32, oiio.FLOAT
        with _native_stderr_filtered():
            data = inp.read_image(0, 0, 0, spec.nchannels, native)
        metadata = {}
        for attrib in spec.extra_attribs:
            try:
                metadata[attrib.name] = attrib.value
            except Exception:  # attributes of exotic types are not needed
                pass
        err = inp.geterror()
        alpha_channel = spec.alpha_channel
    finally:
        inp.close()
    if data is None or (isinstance(data, np.ndarray) and data.size == 0):
        raise InputError(f"cannot read pixels of {path}: {_first_line(err) or 'truncated or corrupt file'}")
    _decoder_error(path, err)
    _check_file_end(path, file_format)
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[:, :, None]
    return data, bit_depth, metadata, alpha_channel


def _rgb_channels(path: str, data: np.ndarray, bit_depth: int, alpha_channel: int) -> tuple[np.ndarray, bool, bool]:
    """(RGB codes, whether an alpha channel was dropped, whether the file was grey): grey
    repeated to RGB, alpha checked (:func:`_alpha_checked`) and dropped."""
    nch = data.shape[2]
    full = 255 if bit_depth == 8 else 65535 if bit_depth == 16 else 1.0
    if nch in (1, 2):
        if nch == 2:
            _alpha_checked(path, data, 1, full)
        return np.repeat(data[:, :, :1], 3, axis=2), nch == 2, True
    if nch >= 4:
        _alpha_checked(path, data, alpha_channel if alpha_channel >= 0 else 3, full)
        return data[:, :, :3], True, False
    if nch != 3:
        raise InputError(f"image {path} has {nch} channels; expected 1 (gray), 3 (RGB) or 4 (RGBA)")
    return data, False, False


@_undecodable_as_input_error
def read_image(path: str | os.PathLike, *, linear: bool | None = None, dtype=np.float64,
               allow_nan: bool = False, encoding=None) -> Image:
    """Read an image file as linear RGB.

    Args:
        path: any format OpenImageIO reads (EXR, HDR, PNG, JPEG, TIFF, ...).
        linear: force the interpretation of integer files (True: already linear,
            False: sRGB). ``None`` decides from the file: integer data are sRGB unless
            the file's colour space attribute says linear; float data are linear.
        dtype: of the pixels (float64, or float32 for large photos read by the fit,
            whose arithmetic is float32: half the memory).
        allow_nan: keep NaN pixels of a float file (a thickness map is NaN off the bubble).
        encoding: a :class:`~bubblefit.io.encoding.PhotoReading` (or one of its
            encodings, ``"auto"``, ``"srgb"``, ``"linear"``): how the values map to linear,
            decided by :func:`~bubblefit.io.encoding.decide_encoding`; ``linear``, when
            given, is the same as ``"linear"``/``"srgb"`` forced.

    Raises:
        InputError: the file is missing, unreadable, truncated, has no pixels, has an
            unusable channel count, or holds NaN/Inf values.

    Examples
    --------
    A linear grey written as an 8-bit sRGB PNG reads back linear, within the 8-bit step:

    >>> import os, tempfile
    >>> import numpy as np
    >>> import bubblefit as bf
    >>> path = os.path.join(tempfile.mkdtemp(), "grey.png")
    >>> bf.write_image(path, np.full((4, 6, 3), 0.5))
    >>> image = bf.read_image(path)
    >>> image.pixels.shape, round(float(image.pixels[0, 0, 0]), 4)
    ((4, 6, 3), 0.5029)
    """
    path = str(path)
    _check_path(path)
    data, bit_depth, metadata, alpha_channel = _decode_file(path)
    data, alpha_dropped, was_gray = _rgb_channels(path, data, bit_depth, alpha_channel)

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
    if bit_depth == 32 and not np.all(np.isfinite(pixels) | (allow_nan & np.isnan(pixels))):
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

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> import bubblefit as bf
    >>> path = os.path.join(tempfile.mkdtemp(), "ramp.exr")
    >>> bf.write_image(path, np.linspace(0.0, 4.0, 8 * 3).reshape(1, 8, 3), bit_depth=32)
    >>> float(bf.read_image(path).pixels.max())        # float EXR: values above 1 are kept
    4.0
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
    if ext in (".tif", ".tiff"):  # no EXIF to write; libtiff's empty EXIF directory is reported as a failed write
        spec.attribute("tiff:write_exif", 0)
    with atomic_path(path, check=lambda tmp: _check_written(tmp, path, spec)) as tmp:
        _write_oiio(tmp, path, spec, np.ascontiguousarray(data))


def _check_written(tmp: str, shown: os.PathLike, spec) -> None:
    """Read the image just written back whole, so that a writer that reported success on a
    short write (a full disk seen by no return value) never replaces a good file: the
    header must give the size written and every pixel must decode."""
    inp = oiio.ImageInput.open(tmp)
    if inp is None:
        oiio.geterror()  # taken, so that OpenImageIO does not print it at exit
        raise OutputError(f"cannot write {shown}: the written file does not read back (disk full?)")
    try:
        got = inp.spec()
        data = inp.read_image(0, 0, 0, got.nchannels, oiio.FLOAT) \
            if (got.width, got.height, got.nchannels) == (spec.width, spec.height, spec.nchannels) else None
        err = inp.geterror()
    finally:
        inp.close()
    if data is None or np.asarray(data).size != spec.width * spec.height * spec.nchannels or err:
        raise OutputError(f"cannot write {shown}: the written file does not read back whole (disk full?)")


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
