"""Planning a sequence fit: which frames, in which chunks, under which fingerprint.

Frames come from image files, folders of images (sorted by name, numbers in natural
order), glob patterns or a video file read through OpenCV (8-bit BGR, sRGB-encoded:
converted to linear RGB with :func:`bubblefit.io.images.srgb_decode`). Frames are cut into
chunks of ``chunk_size`` contiguous frames at fixed boundaries (frame ``k`` belongs to
chunk ``k // chunk_size``), so the numbers never depend on how many workers ran them nor
on whether a run was interrupted and resumed. The fingerprint of what decides the numbers
(fit options, maps, scene) guards a resumed run against other settings. See
:mod:`bubblefit.inverse.sequence` and docs/design.md ("Command line", ``fit-sequence``).
"""

from __future__ import annotations

import glob
import hashlib
import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ..errors import InputError
from ..io.images import read_image, srgb_decode
from ._observation import block_mean, noise_sigma, resolve_disc, saturation_mask
from ._pair import PairCheck, judge_pair

__all__ = ["FrameRef", "discover_frames", "load_frame", "as_frames", "plan_chunks", "fingerprint", "fix_disc",
           "check_disc_pair", "IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS"]


IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr", ".pfm", ".bmp")
VIDEO_EXTENSIONS = (".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv", ".mjpeg", ".mj2")


@dataclass(frozen=True)
class FrameRef:
    """One frame of a sequence.

    Attributes
    ----------
    index
        position in the sequence (0-based); the frame's row in the tables.
    source
        the image file, or the video file it is read from.
    time_s
        the frame's time in seconds from the first frame.
    video_frame
        the frame's number in the video, or None for an image file.
    reading
        how an image file is decoded (:class:`bubblefit.io.camera_files.PhotoReading`;
        None: as :func:`bubblefit.io.images.read_image` decides).
    """

    index: int
    source: str
    time_s: float
    video_frame: int | None = None
    reading: object = None

    @property
    def label(self) -> str:
        """What the tables show in their ``file`` column (``video.mp4#12`` for a video frame)."""
        return self.source if self.video_frame is None else f"{self.source}#{self.video_frame}"


def _natural_key(name: str):
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", name)]


def _is_video(path: str) -> bool:
    return Path(path).suffix.lower() in VIDEO_EXTENSIONS


def _open_video(path: str):
    """``cv2.VideoCapture`` of a file, with FFmpeg's own log silenced: a file OpenCV cannot
    decode gives bubblefit's one line, not FFmpeg's (OpenCV reads the level when it opens)."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    return cv2.VideoCapture(path)


def _video_info(path: str) -> tuple[int, float]:
    """(frame count, frames per second) of a video file, through OpenCV."""
    cap = _open_video(path)
    if not cap.isOpened():
        raise InputError(f"cannot open video {path} (OpenCV could not decode it)")
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if n <= 0:  # some containers do not say: count by reading
            n = 0
            while cap.grab():
                n += 1
    finally:
        cap.release()
    if n <= 0:
        raise InputError(f"video {path} has no frames")
    return n, fps


def discover_frames(inputs: Sequence[str | os.PathLike] | str | os.PathLike, *, fps: float | None = None) -> list[FrameRef]:
    """The frames named by ``inputs``, in order.

    Parameters
    ----------
    inputs
        image files, folders (their image files, sorted naturally by name),
        video files (every frame, through OpenCV) or glob patterns, in any mix.
    fps
        frames per second, which gives each frame's ``time_s``. None: a video's own
        rate, and 1 frame per second for image files (``time_s`` = frame number).

    Returns
    -------
    list of FrameRef
        Indices 0..N-1.

    Raises
    ------
    InputError
        nothing matched, a path does not exist, a folder holds no images,
        a video cannot be opened, or ``fps`` is not positive.
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if fps is not None and not (fps > 0 and math.isfinite(fps)):
        raise InputError(f"--fps must be a positive number, got {fps}")
    items: list[tuple[str, int | None, float | None]] = []  # (source, video frame, native fps)
    for raw in inputs:
        path = str(raw)
        if not os.path.exists(path) and any(c in path for c in "*?["):
            matched = sorted(glob.glob(path), key=_natural_key)
            if not matched:
                raise InputError(f"no file matches {path}")
            paths = matched
        elif not os.path.exists(path):
            raise InputError(f"frame not found: {path}")
        else:
            paths = [path]
        for p in paths:
            if os.path.isdir(p):
                names = sorted((n for n in os.listdir(p) if Path(n).suffix.lower() in IMAGE_EXTENSIONS
                                and not n.startswith(".")), key=_natural_key)
                if not names:
                    raise InputError(f"folder {p} holds no image files ({', '.join(IMAGE_EXTENSIONS)})")
                items.extend((os.path.join(p, n), None, None) for n in names)
            elif _is_video(p):
                n, native = _video_info(p)
                items.extend((p, k, native) for k in range(n))
            else:
                items.append((p, None, None))
    if not items:
        raise InputError("no frames given")
    frames = []
    for i, (src, vf, native) in enumerate(items):
        rate = fps or (native if native and native > 0 else 1.0)
        frames.append(FrameRef(i, os.path.abspath(src), i / rate, vf))
    return frames


class _VideoReader:
    """Reads frames of one video, sequentially when it can (seeking is slow and inexact)."""

    def __init__(self):
        self.path = None
        self.cap = None
        self.next_frame = 0

    def read(self, path: str, k: int) -> np.ndarray:
        if self.path != path or self.cap is None:
            self.close()
            self.cap = _open_video(path)
            if not self.cap.isOpened():
                self.cap = None
                raise InputError(f"cannot open video {path}")
            self.path, self.next_frame = path, 0
        if k != self.next_frame:
            if k > self.next_frame and k - self.next_frame < 64:
                while self.next_frame < k:  # grab forward: exact, unlike seeking
                    if not self.cap.grab():
                        raise InputError(f"video {path} ends before frame {k}")
                    self.next_frame += 1
            else:
                self.cap.set(cv2.CAP_PROP_POS_FRAMES, k)
                self.next_frame = k
        ok, bgr = self.cap.read()
        if not ok or bgr is None:
            self.next_frame = -1
            raise InputError(f"cannot read frame {k} of video {path}")
        self.next_frame = k + 1
        return bgr

    def close(self):
        if self.cap is not None:
            self.cap.release()
        self.cap, self.path = None, None


_VIDEO = _VideoReader()


def load_frame(ref: FrameRef) -> np.ndarray:
    """The pixels of one frame as a linear (H, W, 3) float64 array.

    Image files go through :func:`bubblefit.io.images.read_image`. A video frame is 8-bit
    BGR from OpenCV: it is reordered to RGB, scaled to [0, 1] and decoded from sRGB to
    linear (:func:`bubblefit.io.images.srgb_decode`); 16-bit video frames are scaled by 65535.

    Raises
    ------
    InputError
        the file is missing, truncated or not an image.
    """
    if ref.video_frame is None:
        if ref.reading is not None:
            from ..io.camera_files import read_photo

            return read_photo(ref.source, ref.reading, what="frame").pixels
        return read_image(ref.source).pixels
    bgr = _VIDEO.read(ref.source, ref.video_frame)
    if bgr.ndim == 2:
        bgr = np.repeat(bgr[:, :, None], 3, axis=2)
    maxcode = 65535.0 if bgr.dtype == np.uint16 else 255.0
    rgb = bgr[:, :, 2::-1].astype(np.float64) / maxcode
    return srgb_decode(rgb)


def fingerprint(options, env, background, scene) -> str:
    """A short hash of what decides the numbers (options, maps, scene): a rerun must match it."""
    h = hashlib.sha1()
    h.update(repr(options).encode())
    for arr in (getattr(env, "pixels", None), background):
        if arr is not None:
            a = np.ascontiguousarray(np.asarray(arr, dtype=np.float32))
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    if scene is not None:
        h.update(repr(getattr(scene, "data", scene)).encode())
    return h.hexdigest()[:16]


def check_disc_pair(photo, background, disc, opts) -> PairCheck | None:
    """:func:`~bubblefit.inverse._pair.judge_pair` of a photo and its background photo around an orthographic disc
    ``(cx, cy, r)`` in pixels, before any fit is set up (``fit-sequence`` checks its first
    frame so): the pair block-averaged to at most ``opts.sizes.analysis`` pixels (``opts``:
    a :class:`~bubblefit.inverse._options.FitOptions`), its noise and clipped pixels as a
    fit's (:func:`~bubblefit.inverse._observation.noise_sigma`,
    :func:`~bubblefit.inverse._observation.saturation_mask`). None without a background
    photo; raises :class:`InputError` with the refusal."""
    if background is None or disc is None:
        return None
    k = max(1, math.ceil(max(photo.shape[:2]) / opts.sizes.analysis))
    clip = opts.noise.saturation
    sat = saturation_mask(np.asarray(photo), clip, None) | saturation_mask(np.asarray(background), clip, None)
    p, b = (block_mean(np.asarray(photo, np.float64), k), block_mean(np.asarray(background, np.float64), k))
    h, w = p.shape[:2]
    sat = sat[: h * k, : w * k].reshape(h, k, w, k).any(axis=(1, 3)) if k > 1 else sat
    sig = lambda a: noise_sigma(a, opts.noise.read, opts.noise.shot, opts.noise.bits) / k
    cx, cy, r = (float(v) / k for v in disc)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    rho = np.hypot(xx - cx, yy - cy) / r
    usable = ~sat & np.all(np.isfinite(p) & np.isfinite(b), axis=-1)
    check = judge_pair(p, b, sig(p), sig(b), usable, rho < 1.0, np.sqrt(np.clip(1.0 - rho**2, 0.0, 1.0)))
    why = check.refusal()
    if why is not None:
        raise InputError(why)
    return check


def fix_disc(options, frames: list[FrameRef], background, scene):
    """Options with the bubble's disc fixed for the whole sequence.

    Without a disc, :func:`bubblefit.inverse.fit.fit_photo` detects one per photo; a disc that
    moves by a fraction of a pixel changes the static camera and recompiles the fit for
    every frame. A filmed bubble stays put, so the disc is resolved once, on the first
    readable frame, as a fit of that frame resolves it (a calibration's disc checked
    against it, else the one found: :func:`~bubblefit.inverse._observation.resolve_disc`), held as
    every frame's start and refined in each fit as ``fit`` refines it; one frame is then
    fitted as ``bubblefit fit`` fits it (give ``FitOptions.disc`` for a bubble that moves).
    That frame and the background photo are checked as a pair before any fit
    (:func:`check_disc_pair`: swapped, or of another view).
    """
    if not hasattr(options, "disc") or options.disc is not None:
        return options
    if scene is not None and (scene.table("camera").get("type", "orthographic") == "perspective"
                              or "disc" in scene.table("camera")):
        return options
    for ref in frames[:10]:
        try:
            photo = load_frame(ref)
        except InputError:
            continue
        try:  # the disc a fit of this frame would start from (a calibration's, checked, or the one found)
            disc, _ = resolve_disc(photo, background, options)
        except InputError as exc:
            raise InputError(f"cannot find the bubble in frame {ref.index} ({ref.label}): {exc}; give its disc") \
                from None
        check_disc_pair(photo, background, disc, options)  # swapped or of another view: refused before any fit
        # held as every frame's start and refined in each, as a fit refines a disc it was not given
        return replace(options, disc=tuple(round(float(v), 2) for v in disc),
                       fit_disc=True if options.fit_disc is None else options.fit_disc)
    raise InputError("none of the first frames can be read")


def as_frames(frames, fps: float | None = None) -> list[FrameRef]:
    """:class:`FrameRef` s as given, or those :func:`discover_frames` finds for paths.

    Raises
    ------
    InputError
        No frames.
    """
    if isinstance(frames, (str, os.PathLike)) or (frames and not isinstance(frames[0], FrameRef)):
        frames = discover_frames(frames, fps=fps)
    frames = list(frames)
    if not frames:
        raise InputError("no frames given")
    return frames


Chunk = list[tuple[FrameRef, dict | None]]


def plan_chunks(frames: list[FrameRef], chunk_size: int, done: dict[int, dict]) -> list[Chunk]:
    """The chunks that still have work: fixed boundaries (frame ``k`` in chunk ``k // chunk_size``),
    each cut after its last pending frame, every frame paired with its finished record (or None).

    Finished frames inside a chunk stay in it: they pass their result on as a warm start.
    """
    chunks = []
    for start in range(0, len(frames), chunk_size):
        part = frames[start:start + chunk_size]
        if any(r.index not in done for r in part):
            last = max(i for i, r in enumerate(part) if r.index not in done)
            chunks.append([(r, done.get(r.index)) for r in part[: last + 1]])
    return chunks
