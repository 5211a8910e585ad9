"""The camera-view flags of ``fit``, ``fit-sequence`` and ``calibrate``: the field of view
as a user knows it (``docs/camera-view.md``)."""

from __future__ import annotations


def add_view_options(p) -> None:
    """``--fov DEG``, ``--focal-length MM`` with ``--sensor-width MM``, ``--focal-length-35mm MM``."""
    g = p.add_argument_group("camera view (default: the photo's EXIF, else orthographic with the error bars "
                             "widened by what a 50 mm lens would change)")
    g.add_argument("--fov", type=float, metavar="DEG",
                   help="the camera's angle of view across the photo's width, degrees (0: orthographic, parallel rays)")
    g.add_argument("--focal-length", type=float, metavar="MM", help="the lens's focal length, mm (with --sensor-width)")
    g.add_argument("--sensor-width", type=float, metavar="MM", help="the sensor's width, mm (with --focal-length)")
    g.add_argument("--focal-length-35mm", type=float, metavar="MM",
                   help="the focal length in 35 mm terms (as phones report it), mm")


def view_from_args(args, metadata: dict | None, width: int, height: int):
    """The :class:`~bubblefit.capture.view.View` of :func:`add_view_options`' flags, else the
    photo's EXIF (``metadata``), else an assumed orthographic view."""
    from ..capture.view import resolve_view

    return resolve_view(fov_deg=args.fov, focal_length_mm=args.focal_length, sensor_width_mm=args.sensor_width,
                        focal_length_35mm=args.focal_length_35mm, metadata=metadata, width=width, height=height)


def check_view_args(args) -> None:
    """Refuse conflicting or incomplete view flags before any photo is read."""
    view_from_args(args, None, 100, 100)


__all__ = ["add_view_options", "view_from_args", "check_view_args", "sequence_view"]


def sequence_view(args, frames):
    """The view of a sequence's frames: the flags, else the first frame's EXIF (a video's
    frames carry none)."""
    from ..inverse import load_frame
    from ..io.images import read_image

    first = frames[0]
    if first.video_frame is None:
        img = read_image(first.source)
        meta, (h, w) = img.metadata, img.pixels.shape[:2]
    else:
        meta, (h, w) = None, load_frame(first).shape[:2]
    return view_from_args(args, meta, w, h)

