"""Fitting a sequence of frames (a draining bubble filmed for minutes), locally or on Dask.

A physicist films a bubble while its film drains; every frame is one fit of
:func:`bubblefit.inverse.fit.fit_photo`. The thickness changes slowly from frame to frame, so
each frame starts from its neighbour's result (a *warm start*, ``init=``) and the global
thickness search runs only for the first frame of a chunk or where the warm start fails.

How the work is cut and where it runs:

- Frames are cut into *chunks* of ``chunk_size`` contiguous frames, at fixed boundaries
  (frame ``k`` belongs to chunk ``k // chunk_size``) so the numbers never depend on how
  many workers ran them, nor on whether a run was interrupted and resumed. Inside a
  chunk the frames are fitted one after the other, each warm-started from the last
  successful frame before it in the chunk; the first frame of a chunk runs the global
  search.
- One chunk is one Dask task. Tasks run on a ``distributed`` cluster: a local one by
  default (one single-threaded worker process per core, so two workers do not fight
  over the same cores) or an existing one (``scheduler="tcp://host:8786"``). A worker
  process keeps JAX's compiled functions between tasks, so only its first frame pays
  the compilation. ``workers=0`` runs everything in the calling process, without Dask.
- Every finished frame is written at once, atomically, as ``OUT_DIR/frames/frame_NNNNNN.json``.
  A rerun reads those files and fits only the frames that have none (``force=True``
  redoes all). A frame that fails (unreadable file, fit error, lost worker) is recorded
  with its reason and the others go on.
- At the end the tables ``params.csv`` and ``params.jsonl`` (one row per frame) and the
  plot ``thickness.png`` (thickness against time) are rebuilt from the frame files.

Frames come from image files, folders of images (sorted by name, numbers in natural
order) or a video file read through OpenCV (8-bit BGR, sRGB-encoded: converted to
linear RGB with :func:`bubblefit.io.images.srgb_decode`).
"""

from __future__ import annotations

import csv
import glob
import hashlib
import io
import json
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError

__all__ = [
    "FrameRef",
    "SequenceResult",
    "discover_frames",
    "load_frame",
    "fit_sequence",
    "read_table",
    "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS",
]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr", ".pfm", ".bmp")
VIDEO_EXTENSIONS = (".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv", ".mjpeg", ".mj2")

# Leading columns of params.csv (docs/design.md, "Command line"); more follow them.
LEADING_COLUMNS = ("frame", "file", "converged", "thickness_nm", "thickness_nm_stderr", "t", "roughness", "exposure")
# Columns describing the frame and its fit, after the parameters and their errors.
TRAILING_COLUMNS = ("time_s", "status", "message", "warm_start", "iterations", "residual_rms", "fit_time_s",
                    "worker")

RECORD_VERSION = 1


# ----------------------------------------------------------------------------------------
# Frames: where they come from and how they are read
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameRef:
    """One frame of a sequence.

    Attributes:
        index: position in the sequence (0-based); the frame's row in the tables.
        source: the image file, or the video file it is read from.
        time_s: the frame's time in seconds from the first frame.
        video_frame: the frame's number in the video, or None for an image file.
    """

    index: int
    source: str
    time_s: float
    video_frame: int | None = None

    @property
    def label(self) -> str:
        """What the tables show in their ``file`` column (``video.mp4#12`` for a video frame)."""
        return self.source if self.video_frame is None else f"{self.source}#{self.video_frame}"


def _natural_key(name: str):
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", name)]


def _is_video(path: str) -> bool:
    return Path(path).suffix.lower() in VIDEO_EXTENSIONS


def _video_info(path: str) -> tuple[int, float]:
    """(frame count, frames per second) of a video file, through OpenCV."""
    import cv2

    cap = cv2.VideoCapture(path)
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

    Args:
        inputs: image files, folders (their image files, sorted naturally by name),
            video files (every frame, through OpenCV) or glob patterns, in any mix.
        fps: frames per second, which gives each frame's ``time_s``. None: a video's own
            rate, and 1 frame per second for image files (``time_s`` = frame number).

    Returns:
        A list of :class:`FrameRef`, indices 0..N-1.

    Raises:
        InputError: nothing matched, a path does not exist, a folder holds no images,
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
        import cv2

        if self.path != path or self.cap is None:
            self.close()
            self.cap = cv2.VideoCapture(path)
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

    Raises:
        InputError: the file is missing, truncated or not an image.
    """
    from ..io.images import read_image, srgb_decode

    if ref.video_frame is None:
        return read_image(ref.source).pixels
    bgr = _VIDEO.read(ref.source, ref.video_frame)
    if bgr.ndim == 2:
        bgr = np.repeat(bgr[:, :, None], 3, axis=2)
    maxcode = 65535.0 if bgr.dtype == np.uint16 else 255.0
    rgb = bgr[:, :, 2::-1].astype(np.float64) / maxcode
    return srgb_decode(rgb)


# ----------------------------------------------------------------------------------------
# The work of one chunk (runs in a worker process, or in this one)
# ----------------------------------------------------------------------------------------

_WORKER_READY = False


def _worker_setup(jax_setup: dict) -> None:
    """Once per process: the client's JAX settings (compilation cache, float64)."""
    global _WORKER_READY
    if _WORKER_READY:
        return
    import jax

    cache = jax_setup.get("cache_dir")
    if cache:
        try:
            jax.config.update("jax_compilation_cache_dir", cache)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
        except Exception:  # a cache that cannot be used only costs time
            pass
    if jax_setup.get("enable_x64") is not None:
        jax.config.update("jax_enable_x64", bool(jax_setup["enable_x64"]))
    _WORKER_READY = True


def _client_jax_setup() -> dict:
    """The calling process's JAX settings that workers should share."""
    import jax

    out = {"enable_x64": bool(jax.config.jax_enable_x64)}
    try:
        out["cache_dir"] = jax.config.jax_compilation_cache_dir
    except AttributeError:
        out["cache_dir"] = None
    if not out["cache_dir"]:
        out["cache_dir"] = os.environ.get("BUBBLEFIT_CACHE_DIR") or os.path.join(
            os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "bubblefit", "jax")
    return out


def _as_float(x) -> float:
    try:
        return float(np.asarray(x).reshape(-1)[0]) if np.asarray(x).size == 1 else float("nan")
    except (TypeError, ValueError):
        return float("nan")


def _scalar_dict(d) -> dict:
    """Parameters as plain floats (JSON-safe); non-scalar entries are left out."""
    out = {}
    for k, v in dict(d or {}).items():
        a = np.asarray(v)
        if a.size == 1 and a.dtype.kind in "fiub":
            out[str(k)] = float(a.reshape(-1)[0])
    return out


def _warm_init(record: dict | None) -> dict | None:
    """The warm start a record offers its next frame: its parameters if it converged."""
    if record and record.get("status") == "ok" and record.get("converged") and record.get("init"):
        return dict(record["init"])
    return None


def _worker_name() -> str:
    import socket

    return f"{socket.gethostname()}:{os.getpid()}"


def _base_record(ref: FrameRef, init) -> dict:
    return {"version": RECORD_VERSION, "frame": ref.index, "file": ref.label, "time_s": ref.time_s,
            "warm_start": init is not None, "worker": _worker_name()}


def _result_record(base: dict, res, fit_time_s: float) -> dict:
    """A frame's record from its fit result."""
    params = _scalar_dict(getattr(res, "params", {}))
    stderr = _scalar_dict(getattr(res, "stderr", {}))
    init_next = getattr(res, "init", None)
    rec = dict(
        base,
        status="ok",
        converged=bool(getattr(res, "converged", False)),
        message=str(getattr(res, "message", "") or ""),
        iterations=int(getattr(res, "iterations", 0) or 0),
        residual_rms=_as_float(getattr(res, "residual_rms", float("nan"))),
        fit_time_s=fit_time_s,
        params=params,
        stderr=stderr,
        init=_scalar_dict(init_next) if isinstance(init_next, dict) else params,
    )
    if not all(math.isfinite(v) for v in params.values()):
        rec["converged"] = False
    tmap = getattr(res, "thickness_map", None)
    if tmap is not None:
        rec["_thickness_map"] = np.asarray(tmap, dtype=np.float32)
    return rec


def _read_frame(ref: FrameRef, base: dict, t0: float):
    """``(photo, None)``, or ``(None, failed record)`` for a frame that cannot be read."""
    try:
        return load_frame(ref), None
    except Exception as exc:  # unreadable frame: record and go on
        return None, dict(base, status="failed", converged=False, warm_start=False,
                          message=f"cannot read frame: {_one_line(exc)}", fit_time_s=time.perf_counter() - t0)


def _fit_one(ref: FrameRef, env, options, init, background, scene, fit_fn) -> dict:
    """Fit one frame; a failure becomes a record with its reason, never an exception."""
    t0 = time.perf_counter()
    base = _base_record(ref, init)
    photo, failed = _read_frame(ref, base, t0)
    if failed:
        return failed
    try:
        res = fit_fn(photo, env, options=options, background=background, init=init, scene=scene)
    except Exception as exc:  # a fit that raises fails this frame only
        return dict(base, status="failed", converged=False, message=f"fit failed: {_one_line(exc)}",
                    fit_time_s=time.perf_counter() - t0)
    return _result_record(base, res, time.perf_counter() - t0)


def _fit_batch(refs: list[FrameRef], env, options, init, previous, background, scene) -> list[dict]:
    """Fit consecutive frames together (:func:`bubblefit.inverse.fit.fit_batch`); one record each.
    If the batched fit raises, the frames are fitted one by one instead."""
    from .fit import fit_batch, fit_photo

    t0 = time.perf_counter()
    bases = [_base_record(r, init) for r in refs]
    read = [_read_frame(r, b, t0) for r, b in zip(refs, bases)]
    good = [k for k, (photo, _) in enumerate(read) if photo is not None]
    recs = [failed for _, failed in read]
    try:
        results = fit_batch([read[k][0] for k in good], env, options=options, background=background, init=init,
                            previous=previous, scene=scene)
    except Exception:  # fall back to single fits, which record their own failures
        return [recs[k] or _fit_one(refs[k], env, options, init, background, scene, fit_photo)
                for k in range(len(refs))]
    share = (time.perf_counter() - t0) / max(len(good), 1)
    for k, res in zip(good, results):
        recs[k] = dict(_result_record(bases[k], res, share), batch=len(good))
    return recs


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def _fit_chunk(todo: list[tuple[FrameRef, dict | None]], env, options, background, scene, jax_setup: dict,
               want_maps: bool, fit_function: str = "bubblefit.inverse.fit:fit_photo", warm_start: bool = True,
               init: dict | None = None, batch: int = 1) -> list[dict]:
    """Fit the pending frames of one chunk, in order, each warm-started from the last success.

    Args:
        todo: the chunk's frames in order, each with its finished record (None: to fit).
            Finished frames are not refitted; they only pass their result on as a warm start.
        env: the environment map (:class:`~bubblefit.lighting.envmap.EnvMap`).
        options: :class:`bubblefit.inverse.fit.FitOptions`.
        background, scene: passed on to :func:`bubblefit.inverse.fit.fit_photo`.
        jax_setup: the client's JAX settings (compilation cache, float64).
        want_maps: keep each frame's thickness map (else it is dropped here, in the worker).
        fit_function: ``"module:name"`` of the fit, called like :func:`bubblefit.inverse.fit.fit_photo`.
        warm_start: False: every frame runs the global search (independent frames).
        init: warm start of the chunk's first frame (the previous chunk's last result), or None.
        batch: once two frames have warm-started results, fit up to this many following
            frames together (:func:`bubblefit.inverse.fit.fit_batch`, default fit function only).

    Returns:
        One record (dict) per frame fitted, in order.
    """
    _worker_setup(jax_setup)
    fit_photo = _resolve(fit_function)
    batched = batch > 1 and warm_start and fit_function == "bubblefit.inverse.fit:fit_photo"

    out = []
    warm, prev = init, None

    def keep(rec):
        nonlocal warm, prev
        nxt = _warm_init(rec)
        if nxt is not None:
            prev, warm = warm, nxt

    i = 0
    while i < len(todo):
        ref, done = todo[i]
        if done is not None:
            keep(done)
            i += 1
            continue
        group = []
        if batched and warm is not None and prev is not None:
            while i + len(group) < len(todo) and len(group) < batch and todo[i + len(group)][1] is None:
                group.append(todo[i + len(group)][0])
        if len(group) >= 2:
            recs = _fit_batch(group, env, options, warm, prev, background, scene)
        else:
            recs = [_fit_one(ref, env, options, warm if warm_start else None, background, scene, fit_photo)]
        for rec in recs:
            if not want_maps:
                rec.pop("_thickness_map", None)
            out.append(rec)
            keep(rec)
        i += len(recs)
    return out


def _resolve(target: str):
    import importlib

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name or "fit_photo")


# ----------------------------------------------------------------------------------------
# Records on disk
# ----------------------------------------------------------------------------------------


def _json_default(o):
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"cannot write {type(o).__name__} as JSON")


def _write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file, fsync'd, then renamed over it."""
    from ..io.images import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())


def _record_path(out_dir: Path, index: int) -> Path:
    return out_dir / "frames" / f"frame_{index:06d}.json"


def _read_record(path: Path) -> dict | None:
    try:
        with open(path) as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None  # missing or half-written by something else: refit
    return rec if isinstance(rec, dict) and rec.get("version") == RECORD_VERSION else None


def _save_record(out_dir: Path, rec: dict) -> None:
    rec = dict(rec)
    tmap = rec.pop("_thickness_map", None)
    if tmap is not None:
        from ..io.images import write_image

        maps = out_dir / "maps"
        maps.mkdir(exist_ok=True)
        name = f"frame_{rec['frame']:06d}_thickness.exr"
        write_image(maps / name, tmap, bit_depth=32)
        rec["thickness_map"] = f"maps/{name}"
    _write_text_atomic(_record_path(out_dir, rec["frame"]),
                       json.dumps(rec, indent=1, default=_json_default, allow_nan=True) + "\n")


def _fingerprint(options, env, background, scene) -> str:
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


# ----------------------------------------------------------------------------------------
# Tables and plot
# ----------------------------------------------------------------------------------------


def _columns(records: list[dict]) -> list[str]:
    names: list[str] = []
    for r in records:
        for k in r.get("params", {}):
            if k not in names:
                names.append(k)
    lead = list(LEADING_COLUMNS)
    others = sorted(k for k in names if k not in lead)
    errs = [f"{k}_stderr" for k in ("t", "roughness", "exposure", *others)
            if any(k in r.get("stderr", {}) for r in records)]
    return lead + others + errs + list(TRAILING_COLUMNS)


def _row(rec: dict, columns: list[str]) -> dict:
    row = {}
    p, e = rec.get("params", {}), rec.get("stderr", {})
    for c in columns:
        if c in ("frame", "file", "converged", "status", "message", "warm_start", "iterations", "residual_rms",
                 "fit_time_s", "worker", "time_s"):
            row[c] = rec.get(c)
        elif c.endswith("_stderr"):
            row[c] = e.get(c[: -len("_stderr")])
        else:
            row[c] = p.get(c)
    return row


def _csv_value(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _jsonl_value(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _write_tables(out_dir: Path, records: list[dict]) -> tuple[Path, Path]:
    columns = _columns(records)
    rows = [_row(r, columns) for r in records]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_csv_value(row[c]) for c in columns])
    csv_path, jsonl_path = out_dir / "params.csv", out_dir / "params.jsonl"
    _write_text_atomic(csv_path, buf.getvalue())
    lines = [json.dumps({c: _jsonl_value(row[c]) for c in columns}, default=_json_default) for row in rows]
    _write_text_atomic(jsonl_path, "\n".join(lines) + ("\n" if lines else ""))
    return csv_path, jsonl_path


def read_table(path: str | os.PathLike) -> list[dict]:
    """Read ``params.csv`` back: one dict per frame, numbers as floats, empty cells as None."""
    out = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            parsed: dict[str, Any] = {}
            for k, v in row.items():
                if v == "":
                    parsed[k] = None
                elif k in ("file", "status", "message", "worker"):
                    parsed[k] = v
                elif v in ("true", "false"):
                    parsed[k] = v == "true"
                else:
                    try:
                        parsed[k] = int(v) if k in ("frame", "iterations") else float(v)
                    except ValueError:
                        parsed[k] = v
            out.append(parsed)
    return out


def _plot(out_dir: Path, records: list[dict]) -> Path | None:
    """Thickness (with its standard error) against time, to ``OUT_DIR/thickness.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io.images import atomic_path

    keys = [k for k in ("thickness_nm", "top_nm", "bottom_nm")
            if any(k in r.get("params", {}) for r in records)]
    if not keys:
        return None
    fig, ax = plt.subplots(figsize=(7, 4), dpi=120)
    for k in keys:
        ok = [r for r in records if r.get("status") == "ok" and k in r.get("params", {})]
        for conv, style in ((True, "o"), (False, "x")):
            sel = [r for r in ok if bool(r.get("converged")) == conv]
            if not sel:
                continue
            t = [r["time_s"] for r in sel]
            y = [r["params"][k] for r in sel]
            err = [r.get("stderr", {}).get(k, float("nan")) for r in sel]
            err = [e if e == e else 0.0 for e in err]
            label = k.replace("_nm", "").replace("_", " ") + ("" if conv else " (not converged)")
            ax.errorbar(t, y, yerr=err, fmt=style, ms=3, lw=0.8, capsize=1.5, label=label)
    failed = [r["time_s"] for r in records if r.get("status") != "ok"]
    if failed:
        ax.plot(failed, [ax.get_ylim()[0]] * len(failed), "|", color="red", ms=10, label="failed frames")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("film thickness (nm)")
    ax.set_title(f"{len(records)} frames")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out_dir / "thickness.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------------------
# Orchestration
# ----------------------------------------------------------------------------------------


@dataclass
class SequenceResult:
    """What :func:`fit_sequence` did.

    Attributes:
        out_dir: the output folder.
        records: one dict per frame, in order (``status`` "ok" or "failed", ``params``,
            ``stderr``, ``converged``, ``message``, ``time_s``, ...), as in ``frames/``.
        fitted: frames fitted by this call; skipped: frames found finished on disk.
        failed: frames recorded as failed (this call or before).
        elapsed_s: wall time of the fitting (cluster start excluded); fps = fitted / elapsed_s.
        setup_s: time to start (or connect to) the cluster and send it the data.
        workers: how many worker processes took part (0: this process).
        table, jsonl, plot: paths of ``params.csv``, ``params.jsonl``, ``thickness.png``.
    """

    out_dir: Path
    records: list[dict]
    fitted: int
    skipped: int
    failed: int
    elapsed_s: float
    setup_s: float
    workers: int
    table: Path
    jsonl: Path
    plot: Path | None = None
    extra: dict = field(default_factory=dict)

    @property
    def fps(self) -> float:
        return self.fitted / self.elapsed_s if self.elapsed_s > 0 else float("nan")

    def column(self, name: str) -> np.ndarray:
        """One parameter (or ``<name>_stderr``, ``time_s``) for every frame; NaN where failed."""
        out = []
        for r in self.records:
            if name in ("time_s", "frame", "residual_rms", "fit_time_s"):
                v = r.get(name)
            elif name.endswith("_stderr"):
                v = r.get("stderr", {}).get(name[: -len("_stderr")])
            else:
                v = r.get("params", {}).get(name)
            out.append(float("nan") if v is None else float(v))
        return np.asarray(out)


def _local_env() -> dict:
    """Environment of local worker processes: one thread each for XLA and BLAS."""
    flags = os.environ.get("XLA_FLAGS", "")
    extra = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    return {
        "XLA_FLAGS": f"{flags} {extra}".strip(),
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "XLA_PYTHON_CLIENT_PREALLOCATE": "false",
    }


def _start_client(scheduler, workers: int | None):
    """(client, cluster or None, worker addresses to use) for a scheduler spec."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:  # pragma: no cover - dask is a dependency
        raise InputError("Dask is not installed: pip install 'dask[distributed]' (or use --workers 0)") from None
    cluster = None
    if scheduler is None:
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               env=_local_env(), silence_logs=40)
        client = Client(cluster)
    elif isinstance(scheduler, str):
        try:
            client = Client(scheduler, timeout=30)
        except (OSError, TimeoutError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {_one_line(exc)}") from None
    else:
        client = scheduler  # an existing distributed.Client
    addrs = sorted(client.scheduler_info(n_workers=-1)["workers"]) if _takes_n_workers(client) else \
        sorted(client.scheduler_info()["workers"])
    if not addrs:
        client.wait_for_workers(1, timeout=60)
        addrs = sorted(client.scheduler_info()["workers"])
    if scheduler is not None and workers:
        addrs = addrs[:workers]
    return client, cluster, addrs


def _takes_n_workers(client) -> bool:
    import inspect

    try:
        return "n_workers" in inspect.signature(client.scheduler_info).parameters
    except (TypeError, ValueError):
        return False


def fit_sequence(
    frames: Sequence[FrameRef] | Sequence[str | os.PathLike] | str | os.PathLike,
    env,
    out_dir: str | os.PathLike,
    options=None,
    *,
    background: np.ndarray | None = None,
    scene=None,
    scheduler=None,
    workers: int | None = None,
    chunk_size: int = 8,
    force: bool = False,
    retry_failed: bool = False,
    maps: bool = False,
    fps: float | None = None,
    progress: bool = True,
    on_record: Callable[[dict], None] | None = None,
    fit_function: str = "bubblefit.inverse.fit:fit_photo",
    warm_start: bool = True,
    batch: int = 1,
) -> SequenceResult:
    """Fit every frame of a sequence and write the tables, resumably.

    Args:
        frames: :class:`FrameRef` s, or paths (files, folders, videos, globs) for
            :func:`discover_frames`.
        env: the environment map (:class:`~bubblefit.lighting.envmap.EnvMap`).
        out_dir: output folder (created). Holds ``frames/`` (one JSON per finished frame),
            ``params.csv``, ``params.jsonl``, ``thickness.png``, ``run.json`` and, with
            ``maps``, ``maps/frame_NNNNNN_thickness.exr``.
        options: :class:`bubblefit.inverse.fit.FitOptions` (default: its defaults).
        background, scene: passed to every :func:`bubblefit.inverse.fit.fit_photo` call.
        scheduler: None: start a local Dask cluster; ``"tcp://host:8786"``: use that
            cluster; a ``distributed.Client``: use it. Ignored when ``workers == 0``.
        workers: local cluster size (default: one per core); ``0`` fits in this process
            without Dask; with an existing cluster, use at most this many of its workers.
        chunk_size: frames per task (a warm-start chain). Bigger chunks warm-start more
            frames; smaller ones spread better over many workers.
        force: refit frames already finished. retry_failed: refit frames recorded as failed
            (frames lost with a worker are always refitted; unreadable frames and fits that
            raised only with this flag).
        maps: write each frame's thickness map (when the fit gives one).
        fps: frames per second for the time axis (see :func:`discover_frames`).
        progress: show a progress bar (frames per second, time left) on a terminal.
        on_record: called with each new record as it is saved (for tests and tools).
        fit_function: ``"module:name"`` of the per-frame fit (importable on the workers),
            called as ``fit(photo, env, options=, background=, init=, scene=)``.
        warm_start: start each frame from its predecessor (False: global search everywhere,
            for frames that are not a continuous film).
        batch: frames fitted together in one vmapped solve within a task, once a chunk has
            two warm-started results (:func:`bubblefit.inverse.fit.fit_batch`). 1 (the default)
            fits frame after frame, which is faster on CPUs (``experiments/bench_sequence.py``:
            batches of 2-8 ran at 0.5-0.7x the frames per second on 2 cores); larger
            batches are for accelerators, where one small frame does not fill the device.

    Returns:
        A :class:`SequenceResult`.

    Raises:
        InputError: bad frames or options, an unreachable scheduler, or an output folder
            holding the results of a run with other settings (use ``force``).
    """
    from ..progress import Progress

    if chunk_size < 1:
        raise InputError(f"chunk size must be at least 1, got {chunk_size}")
    if batch < 1:
        raise InputError(f"batch must be at least 1, got {batch}")
    if workers is not None and workers < 0:
        raise InputError(f"workers must be 0 (this process) or more, got {workers}")
    if options is None:
        from .fit import FitOptions

        options = FitOptions()
    if isinstance(frames, (str, os.PathLike)) or (frames and not isinstance(frames[0], FrameRef)):
        frames = discover_frames(frames, fps=fps)
    frames = list(frames)
    if not frames:
        raise InputError("no frames given")
    out = Path(out_dir)
    try:
        (out / "frames").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output folder {out}: {exc.strerror}") from None

    options = _fix_disc(options, frames, background, scene)

    # -- what is already done --------------------------------------------------------------
    fp = _fingerprint((options, fit_function, bool(warm_start)) + ((int(batch),) if batch > 1 else ()), env,
                      background, scene)
    run_path = out / "run.json"
    if run_path.exists() and not force:
        prev = _read_json(run_path)
        if prev and prev.get("fingerprint") != fp:
            raise InputError(f"{out} holds results fitted with other settings or maps; "
                             "use --force to refit, or another output folder")
    _write_text_atomic(run_path, json.dumps({"fingerprint": fp, "frames": len(frames), "chunk_size": chunk_size,
                                              "options": repr(options)}, indent=1) + "\n")
    done: dict[int, dict] = {}
    if not force:
        for ref in frames:
            rec = _read_record(_record_path(out, ref.index))
            if rec is None or rec.get("file") != ref.label:
                continue
            if rec.get("status") != "ok" and (retry_failed or rec.get("retryable")):
                continue  # a lost worker is not the frame's fault: always retried
            done[ref.index] = rec
    skipped = len(done)

    # -- chunks: fixed boundaries, pending frames only ---------------------------------------
    chunks = []
    for start in range(0, len(frames), chunk_size):
        part = frames[start:start + chunk_size]
        if any(r.index not in done for r in part):
            last = max(i for i, r in enumerate(part) if r.index not in done)
            chunks.append([(r, done.get(r.index)) for r in part[: last + 1]])
    pending = sum(1 for c in chunks for r, d in c if d is None)

    jax_setup = _client_jax_setup()
    want_maps = bool(maps)
    fresh: dict[int, dict] = {}
    n_workers_used = 0
    t_setup = time.perf_counter()
    setup_s = 0.0
    elapsed = 0.0

    fitted: set[int] = set()

    def accept(rec: dict, refit: bool = True):
        if refit:
            fitted.add(rec["frame"])
        _save_record(out, rec)
        rec = {k: v for k, v in rec.items() if k != "_thickness_map"}
        if want_maps and _record_path(out, rec["frame"]).exists():
            saved = _read_record(_record_path(out, rec["frame"]))
            if saved and "thickness_map" in saved:
                rec["thickness_map"] = saved["thickness_map"]
        fresh[rec["frame"]] = rec
        if on_record is not None:
            on_record(rec)

    def failed_chunk(chunk, reason: str):
        for ref, d in chunk:
            if d is None and ref.index not in fresh:
                accept({"version": RECORD_VERSION, "frame": ref.index, "file": ref.label, "time_s": ref.time_s,
                        "status": "failed", "converged": False, "message": reason, "warm_start": False,
                        "retryable": True})

    bar = Progress(pending, "fitting frames", unit="frames") if progress else None
    client = cluster = None
    if chunks and workers != 0:
        client, cluster, addrs = _start_client(scheduler, workers)
        n_workers_used = len(addrs)
    submitted = []
    try:
        if client is not None:
            env_f = client.scatter(env, broadcast=True, workers=addrs, hash=False)
            bg_f = client.scatter(background, broadcast=True, workers=addrs, hash=False) if background is not None \
                else None
            token = hashlib.sha1(f"{fp}{time.time()}{os.getpid()}".encode()).hexdigest()[:10]
        setup_s = time.perf_counter() - t_setup
        t0 = time.perf_counter()

        def submit(todo, init=None):
            """Fit a chunk: a Dask future, or (in this process) a lazy call run by ``.result()``."""
            if client is None:
                return _Lazy(_fit_chunk, todo, env, options, background, scene, jax_setup, want_maps, fit_function,
                             warm_start, init, batch)
            f = client.submit(_fit_chunk, todo, env_f, options, bg_f, scene, jax_setup, want_maps, fit_function,
                              warm_start, init, batch, key=f"bubblefit-chunk-{todo[0][0].index}-{len(submitted)}-{token}",
                              workers=addrs, allow_other_workers=False, pure=False)
            submitted.append(f)
            return f

        futures = {submit(chunk): chunk for chunk in chunks}
        with bar if bar else _nullctx():
            if client is None:
                order = list(futures)
            else:
                from distributed import as_completed

                order = as_completed(list(futures))
            for f in order:
                chunk = futures[f]
                try:
                    recs = f.result()
                except Exception as exc:  # lost worker, unpicklable result, ...
                    if client is None:
                        raise
                    failed_chunk(chunk, f"task failed: {_one_line(exc)}")
                    if bar:
                        bar.update(sum(1 for _, d in chunk if d is None))
                    continue
                for rec in recs:
                    accept(rec)
                    if bar:
                        bar.update(1, _note(rec))
        if warm_start and chunk_size < len(frames):
            _repair_seams(frames, chunk_size, done, fresh, submit, accept, out)
        elapsed = time.perf_counter() - t0
    finally:
        for f in submitted:
            if not f.done():
                f.cancel()
        if cluster is not None:
            client.close()
            cluster.close()
        elif isinstance(scheduler, str) and client is not None:
            client.close()

    # -- tables from the frame files ----------------------------------------------------------
    records = []
    for ref in frames:
        rec = fresh.get(ref.index) or done.get(ref.index)
        if rec is None:
            rec = {"frame": ref.index, "file": ref.label, "time_s": ref.time_s, "status": "failed",
                   "converged": False, "message": "not fitted"}
        records.append(rec)
    table, jsonl = _write_tables(out, records)
    plot = _plot(out, records)
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    skipped = sum(1 for i in done if i not in fitted)
    return SequenceResult(out_dir=out, records=records, fitted=len(fitted), skipped=skipped, failed=n_failed,
                          elapsed_s=elapsed, setup_s=setup_s, workers=n_workers_used, table=table, jsonl=jsonl,
                          plot=plot)


class _Lazy:
    """A call run when its ``result()`` is asked for (the in-process stand-in for a future)."""

    def __init__(self, fn, *args):
        self.fn, self.args, self._done = fn, args, False

    def result(self):
        if not self._done:
            self.value, self._done = self.fn(*self.args), True
        return self.value

    def done(self) -> bool:
        return True  # nothing to cancel

    def cancel(self):
        pass


#: A chunk's global-search result is replaced by the warm start from the previous chunk
#: when that lands on another thickness and fits no worse than this factor in RMS residual.
SEAM_TOLERANCE = 1.05


def _repair_seams(frames, chunk_size, done, fresh, submit, accept, out):
    """Join the warm-start chains of neighbouring chunks.

    The first frame of a chunk runs the global thickness search, which can land on a
    neighbouring interference order (the colours repeat every ~lambda / (2 n) of thickness).
    The film changes slowly, so each chunk's first frame is also fitted warm-started from
    the previous chunk's last converged frame; where that gives another thickness and a
    residual no worse than :data:`SEAM_TOLERANCE` times the global one, the whole chunk is
    refitted from it. Seams are visited in order (a repaired chunk passes its new last
    frame on), so the result does not depend on the number of workers. A first frame that
    was checked is marked ``seam_checked`` so a rerun does not check it again.
    """
    parts = [frames[s:s + chunk_size] for s in range(0, len(frames), chunk_size)]

    def rec(ref):
        return fresh.get(ref.index) or done.get(ref.index)

    def last_ok(part):
        for ref in reversed(part):
            if _warm_init(rec(ref)):
                return rec(ref)
        return None

    def first_ok(part):
        for ref in part:
            r = rec(ref)
            if r and r.get("status") == "ok":
                return ref, r
        return None, None

    def needs_check(c):
        ref, first = first_ok(parts[c])
        return ref is not None and last_ok(parts[c - 1]) is not None and not first.get("warm_start") \
            and not first.get("seam_checked")

    checks = {c: submit([(first_ok(parts[c])[0], None)], _warm_init(last_ok(parts[c - 1])))
              for c in range(1, len(parts)) if needs_check(c)}
    repaired = set()
    for c in sorted(checks):
        if not needs_check(c):
            continue
        ref, first = first_ok(parts[c])
        prev = last_ok(parts[c - 1])
        check = checks[c] if c - 1 not in repaired else submit([(ref, None)], _warm_init(prev))
        try:
            warm = check.result()[0]
        except Exception:  # a lost worker: leave the chunk as it is
            continue
        d_warm = warm.get("params", {}).get("thickness_nm", warm.get("params", {}).get("top_nm"))
        d_glob = first.get("params", {}).get("thickness_nm", first.get("params", {}).get("top_nm"))
        better = (warm.get("status") == "ok" and warm.get("converged") and d_warm is not None and d_glob is not None
                  and abs(d_warm - d_glob) > 2.0
                  and warm.get("residual_rms", math.inf) <= SEAM_TOLERANCE * first.get("residual_rms", math.inf))
        if better:
            todo = [(r, None if (rec(r) or {}).get("status") == "ok" else rec(r)) for r in parts[c]]
            try:
                recs = submit(todo, _warm_init(prev)).result()
            except Exception:
                continue
            for r in recs:
                accept(dict(r, seam="repaired"))
            repaired.add(c)
        else:
            accept(dict(first, seam_checked=True), False)


def _fix_disc(options, frames: list[FrameRef], background, scene):
    """Options with the bubble's disc fixed for the whole sequence.

    Without a disc, :func:`bubblefit.inverse.fit.fit_photo` detects one per photo; a disc that
    moves by a fraction of a pixel changes the static camera and recompiles the fit for
    every frame. A filmed bubble stays put, so the disc is detected once, on the first
    readable frame, and held (give ``FitOptions.disc`` for a bubble that moves).
    """
    if not hasattr(options, "disc") or options.disc is not None:
        return options
    if scene is not None and (scene.table("camera").get("type", "orthographic") == "perspective"
                              or "disc" in scene.table("camera")):
        return options
    from dataclasses import replace

    from .fit import detect_disc

    for ref in frames[:10]:
        try:
            photo = load_frame(ref)
        except InputError:
            continue
        try:
            disc = detect_disc(photo, background)
        except InputError as exc:
            raise InputError(f"cannot find the bubble in frame {ref.index} ({ref.label}): {exc}; give its disc") \
                from None
        return replace(options, disc=tuple(round(float(v), 2) for v in disc))
    raise InputError("none of the first frames can be read")


def _note(rec: dict) -> str:
    d = rec.get("params", {}).get("thickness_nm")
    return f"frame {rec['frame']}: " + (f"{d:.0f} nm" if d is not None else rec.get("status", ""))


def _read_json(path: Path) -> dict | None:
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


class _nullctx:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False
