"""How a file's code values map to linear radiance.

The sRGB transfer function and its slope (IEC 61966-2-1), what a file states about its
encoding (a PNG's ``sRGB``, ``gAMA`` and ``iCCP`` chunks, an embedded ICC profile's red
tone curve, OpenImageIO's ``oiio:ColorSpace``), the reading a command asks for
(:class:`PhotoReading`) and the encoding decided for one file (:func:`decide_encoding`,
:func:`decode_codes`; :mod:`bubblefit.io.camera_files` states the rules). Both readers,
:mod:`bubblefit.io.images` and :mod:`bubblefit.io.camera_files`, take their encodings from
here.
"""

from __future__ import annotations

import os
import struct
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError

__all__ = ["srgb_decode", "srgb_encode", "srgb_slope", "ENCODINGS", "PhotoReading", "EncodingChoice",
           "decide_encoding", "decode_codes"]


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


#: The encodings a command accepts (``--encoding``).
ENCODINGS = ("auto", "srgb", "linear")

#: Float formats, linear by definition.
_FLOAT_EXTENSIONS = frozenset({".exr", ".hdr", ".pfm"})


@dataclass(frozen=True)
class PhotoReading:
    """How to turn a camera's file into linear RGB (the ``--encoding`` family of options).

    Attributes
    ----------
    encoding : str
        ``auto``, ``srgb`` or ``linear`` (:data:`ENCODINGS`).
    black_level, white_level : float or None
        Code values of a linear integer file's zero and full scale (defaults 0 and the
        container's maximum, 255 or 65535).
    force : bool
        Use ``encoding`` even where the file's metadata states another.
    raw_white_balance : str
        ``camera`` (the as-shot multipliers) or ``none`` (raw channel gains) for RAW files.
    raw_colour : str
        ``camera`` (linear camera RGB) or ``srgb`` (through the camera's colour matrix).
    flat, dark : str or None
        Paths of a flat-field photo and a dark frame (:func:`flat_dark`).
    """

    encoding: str = "auto"
    black_level: float | None = None
    white_level: float | None = None
    force: bool = False
    raw_white_balance: str = "camera"
    raw_colour: str = "camera"
    flat: str | None = None
    dark: str | None = None

    def __post_init__(self):
        if self.encoding not in ENCODINGS:
            raise InputError(f"--encoding must be one of {', '.join(ENCODINGS)}, got {self.encoding!r}")
        if self.raw_white_balance not in ("camera", "none"):
            raise InputError(f"--raw-white-balance must be camera or none, got {self.raw_white_balance!r}")
        if self.raw_colour not in ("camera", "srgb"):
            raise InputError(f"--raw-colour must be camera or srgb, got {self.raw_colour!r}")
        for name, v in (("--black-level", self.black_level), ("--white-level", self.white_level)):
            if v is not None and not (np.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be a finite code value >= 0, got {v}")
        if self.black_level is not None and self.white_level is not None and self.black_level >= self.white_level:
            raise InputError(f"--black-level {self.black_level:g} must lie below --white-level {self.white_level:g}")
        if (self.black_level is not None or self.white_level is not None) and self.encoding == "srgb":
            raise InputError("--black-level and --white-level apply to linear files, not to --encoding srgb")

    @property
    def plain(self) -> bool:
        """True when nothing differs from a plain read (auto encoding, no levels, flat nor dark)."""
        return self == PhotoReading()


@dataclass(frozen=True)
class EncodingChoice:
    """The encoding used for one file and why (recorded in the commands' JSON)."""

    encoding: str       # "srgb", "linear" or "raw"
    reason: str
    black_level: float = 0.0
    white_level: float = 1.0

    def to_json(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------- metadata


def _png_chunks(path: str) -> dict:
    """The colour chunks of a PNG before its image data: ``sRGB`` (rendering intent),
    ``gAMA`` (gamma x 100000) and ``iCCP`` (the decompressed ICC profile), per the PNG
    specification (ISO/IEC 15948:2004, sec. 11.3.3)."""
    import zlib

    out = {}
    try:
        with open(path, "rb") as fh:
            if fh.read(8) != b"\x89PNG\r\n\x1a\n":
                return out
            while True:
                head = fh.read(8)
                if len(head) < 8:
                    break
                length, kind = struct.unpack(">I4s", head)
                if kind in (b"IDAT", b"IEND") or length > 1 << 24:
                    break
                body = fh.read(length)
                fh.read(4)  # CRC
                if kind == b"sRGB":
                    out["sRGB"] = True
                elif kind == b"gAMA" and length == 4:
                    out["gAMA"] = struct.unpack(">I", body)[0] / 100000.0
                elif kind == b"iCCP":
                    name_end = body.find(b"\x00")
                    try:
                        out["iCCP"] = zlib.decompress(body[name_end + 2:])
                    except zlib.error:
                        pass
    except OSError:
        pass
    return out


def _icc_trc(profile: bytes):
    """The red tone curve of an ICC profile as a function of encoded values in [0, 1], or
    None when the profile has none (ICC.1:2010, sec. 7.3 tag table, 10.6 ``curv``, 10.18
    ``para`` with its five function types)."""
    if len(profile) < 132:
        return None
    count = struct.unpack(">I", profile[128:132])[0]
    for i in range(min(count, 200)):
        sig, off, size = struct.unpack(">4sII", profile[132 + 12 * i: 144 + 12 * i])
        if sig not in (b"rTRC", b"kTRC", b"gTRC"):
            continue
        body = profile[off: off + size]
        kind = body[:4]
        if kind == b"curv":
            n = struct.unpack(">I", body[8:12])[0]
            if n == 0:
                return lambda x: x
            if n == 1:
                g = struct.unpack(">H", body[12:14])[0] / 256.0
                return lambda x, g=g: x**g
            table = np.frombuffer(body[12: 12 + 2 * n], dtype=">u2").astype(np.float64) / 65535.0
            return lambda x, t=table: np.interp(x, np.linspace(0, 1, len(t)), t)
        if kind == b"para":
            ftype = struct.unpack(">H", body[8:10])[0]
            nparam = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}.get(ftype)
            if nparam is None:
                return None
            p = [struct.unpack(">i", body[12 + 4 * k: 16 + 4 * k])[0] / 65536.0 for k in range(nparam)]
            g, a, b, c, d, e, f = (p + [0.0] * 7)[:7] if ftype else (p[0], 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            if ftype == 1:
                return lambda x: np.where(x >= -b / a, (a * x + b) ** g, 0.0)
            if ftype == 2:
                return lambda x: np.where(x >= -b / a, (a * x + b) ** g + c, c)
            if ftype == 3:
                return lambda x: np.where(x >= d, (a * x + b) ** g, c * x)
            if ftype == 4:
                return lambda x: np.where(x >= d, (a * x + b) ** g + e, c * x + f)
            return lambda x: x**g
    return None


def _classify_curve(curve) -> str | None:
    """``linear`` or ``srgb`` when a decoding curve is within 0.01 of either at the
    quartiles of the encoded range, else None (a transfer bubblefit does not decode)."""
    x = np.array([0.25, 0.5, 0.75])
    y = np.asarray(curve(x), dtype=np.float64)
    if np.max(np.abs(y - x)) < 0.01:
        return "linear"
    if np.max(np.abs(y - srgb_decode(x))) < 0.01:
        return "srgb"
    return None


def _stated_encoding(path: str, metadata: dict) -> tuple[str | None, str]:
    """``(encoding or None, what the file states)`` from an integer file's metadata."""
    ext = os.path.splitext(path)[1].lower()
    icc = metadata.get("ICCProfile")
    if ext == ".png":
        chunks = _png_chunks(path)
        if chunks.get("sRGB"):
            return "srgb", "its PNG sRGB chunk"
        icc = chunks.get("iCCP", icc)
        if "gAMA" in chunks and not icc:
            g = 1.0 / chunks["gAMA"] if chunks["gAMA"] > 0 else float("inf")
            if abs(g - 1.0) < 0.02:
                return "linear", "its PNG gAMA chunk (gamma 1.0)"
            if abs(g - 2.2) < 0.1:
                return "srgb", f"its PNG gAMA chunk (gamma {g:.2f}, read as sRGB)"
            return "unknown", f"its PNG gAMA chunk (gamma {g:.2f})"
    if icc is not None and len(bytes(icc)) >= 132:
        curve = _icc_trc(bytes(icc))
        if curve is not None:
            kind = _classify_curve(curve)
            return (kind or "unknown"), "its ICC profile's tone curve"
    cs = str(metadata.get("oiio:ColorSpace", "")).lower()
    # OpenImageIO names every PNG and JPEG sRGB when the file says nothing; its colour space
    # is a statement only for other formats (TIFF, PNM, ...).
    if cs and ext not in (".png", ".jpg", ".jpeg"):
        if cs.startswith("lin") or "linear" in cs:
            return "linear", f"its colour space {metadata['oiio:ColorSpace']!r}"
        if "srgb" in cs:
            return "srgb", f"its colour space {metadata['oiio:ColorSpace']!r}"
    return None, ""


def decide_encoding(path: str, metadata: dict, bit_depth: int, reading: PhotoReading) -> EncodingChoice:
    """The encoding of one file under ``reading`` (module docstring), with the reason.

    Raises
    ------
    InputError
        The requested encoding contradicts the file's stated one (without ``force``), the
        file states a transfer bubblefit does not decode, or the levels do not fit the file.
    """
    ext = os.path.splitext(path)[1].lower()
    if bit_depth == 32:
        if reading.encoding == "srgb" and not reading.force:
            raise InputError(f"{path} holds float values, which are linear; --encoding srgb contradicts it "
                             "(add --force-encoding to decode it as sRGB anyway)")
        if reading.black_level is not None or reading.white_level is not None:
            raise InputError("--black-level and --white-level apply to integer files, "
                             f"{path} holds float values")
        if reading.encoding == "srgb":
            return EncodingChoice("srgb", "forced by --encoding srgb --force-encoding")
        why = "float file (linear)" if reading.encoding == "auto" else "--encoding linear"
        return EncodingChoice("linear", f"{why}{' (' + ext + ')' if ext in _FLOAT_EXTENSIONS else ''}")
    maxcode = 255.0 if bit_depth == 8 else 65535.0
    stated, source = _stated_encoding(path, metadata)
    if reading.encoding == "auto":
        if stated == "unknown":
            raise InputError(f"{path}: {source} is neither sRGB nor linear; convert the file or say "
                             "--encoding srgb|linear --force-encoding")
        if stated is None:
            enc, why = ("linear", "--black-level/--white-level given") if (
                reading.black_level is not None or reading.white_level is not None) else (
                "srgb", "the file states no encoding: sRGB assumed (--encoding linear for a linear camera file)")
        else:
            enc, why = stated, f"stated by {source}"
    else:
        enc = reading.encoding
        if stated in ("srgb", "linear") and stated != enc and not reading.force:
            raise InputError(f"--encoding {enc} contradicts {path}: {source} says {stated} "
                             "(add --force-encoding to use it anyway)")
        why = f"--encoding {enc}" + (f" (the file: {stated} by {source})" if stated else "")
    if enc == "srgb":
        if reading.black_level is not None or reading.white_level is not None:
            raise InputError(f"--black-level and --white-level apply to linear files; {path} is read as sRGB ({why})")
        return EncodingChoice("srgb", why, 0.0, maxcode)
    black = 0.0 if reading.black_level is None else float(reading.black_level)
    white = maxcode if reading.white_level is None else float(reading.white_level)
    if white > maxcode:
        raise InputError(f"--white-level {white:g} exceeds the largest code of {path}'s {bit_depth}-bit values "
                         f"({maxcode:g})")
    if black >= white:
        raise InputError(f"--black-level {black:g} must lie below the white level {white:g}")
    return EncodingChoice("linear", why, black, white)


def decode_codes(data: np.ndarray, choice: EncodingChoice, bit_depth: int, dtype=np.float64):
    """``(pixels, saturated)`` of integer code values under ``choice``: sRGB through
    IEC 61966-2-1's decoding, linear as ``(V - black) / (white - black)`` (negative values
    below the black level are kept: they are noise about zero). Saturated: any channel at
    or above the white level. One table entry per code value, so the decoded photo is the
    only full-size float array."""
    maxcode = 255 if bit_depth == 8 else 65535
    codes = np.arange(maxcode + 1, dtype=np.float64)
    if choice.encoding == "srgb":
        table = srgb_decode(codes / maxcode)
        white = maxcode
    else:
        table = (codes - choice.black_level) / (choice.white_level - choice.black_level)
        white = choice.white_level
    saturated = np.any(data >= white, axis=2)
    return table.astype(dtype)[data], saturated
