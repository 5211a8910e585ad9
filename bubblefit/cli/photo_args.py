"""The options of every command that reads a camera's photo: its encoding, levels, RAW
development, dark frame and flat field (:mod:`bubblefit.io.camera_files`).

Imported while the parsers are built: nothing heavy at module level.
"""

from __future__ import annotations

__all__ = ["add_photo_options", "photo_reading"]


def add_photo_options(parser, *, flat: bool = True) -> None:
    """``--encoding``, ``--black-level``, ``--white-level``, ``--force-encoding``,
    ``--raw-white-balance``, ``--raw-colour`` and (with ``flat``) ``--flat``, ``--dark``."""
    from .common import input_file

    g = parser.add_argument_group("camera files (docs/cameras.md)")
    g.add_argument("--encoding", choices=("auto", "srgb", "linear"), default="auto",
                   help="how integer files encode light: auto (EXR/HDR/RAW linear; PNG/TIFF/JPEG from their "
                        "metadata, else sRGB), srgb, or linear [auto]")
    g.add_argument("--black-level", type=float, default=None, metavar="CODE",
                   help="code value of zero light in a linear integer file [0]")
    g.add_argument("--white-level", type=float, default=None, metavar="CODE",
                   help="code value of full scale in a linear integer file, e.g. 4095 for 12-bit data in "
                        "16-bit TIFFs [the container's maximum]")
    g.add_argument("--force-encoding", action="store_true",
                   help="use --encoding even where the file's metadata states another")
    g.add_argument("--raw-white-balance", choices=("camera", "none"), default="camera",
                   help="RAW files: the camera's as-shot white balance, or none [camera]")
    g.add_argument("--raw-colour", choices=("camera", "srgb"), default="camera",
                   help="RAW files: linear camera RGB (fit with the camera's response), or linear sRGB through "
                        "the camera's colour matrix [camera]")
    if flat:
        g.add_argument("--flat", metavar="FLAT", default=None, type=input_file,
                       help="flat-field photo (same camera, lens and light, no subject): divides out vignetting "
                            "and the light's unevenness")
        g.add_argument("--dark", metavar="DARK", default=None, type=input_file,
                       help="dark frame (same exposure, lens capped): subtracted from the photos and the flat")


def photo_reading(args):
    """The :class:`~bubblefit.io.camera_files.PhotoReading` of :func:`add_photo_options`' flags
    (one-line errors for contradictory values)."""
    from ..io.camera_files import PhotoReading

    return PhotoReading(encoding=args.encoding, black_level=args.black_level, white_level=args.white_level,
                        force=bool(args.force_encoding), raw_white_balance=args.raw_white_balance,
                        raw_colour=args.raw_colour, flat=getattr(args, "flat", None),
                        dark=getattr(args, "dark", None))
