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
- What a warm-started frame reuses (:func:`~._executors.fit_chunk`): only the film's
  thickness changes between the frames of one film, so under ``model = "auto"`` it fits
  the model its predecessor kept when that model explained its photo
  (:func:`~._executors.kept_model`); a frame the kept model does not explain falls back
  to the full fit, and its record says so (``fallback``). Its thickness map is built
  coarse to fine as a single photo's is (a map started from the predecessor's,
  :func:`~bubblefit.inverse._maps.warm_centre`, passed its order hops on:
  ``experiments/results/bench_sequence_maps``). A warm-started map holds the global
  parameters (exposure, light, reflectances, roughness, disc) at the values of the last
  frame that solved them, with that solve's standard errors, fits its map and then the
  drainage profile to the map; it solves them again when its map's misfit over that
  solve's fails an F test (``fit._carried_map_fit``). The first frame of every chunk runs
  the full fit, so the globals are solved at least every ``chunk_size`` frames.
- One chunk is one Dask task. Tasks run on a ``distributed`` cluster: a local one by
  default (one single-threaded worker process per core, so two workers do not fight
  over the same cores) or an existing one (``scheduler="tcp://host:8786"``). A worker
  process keeps JAX's compiled functions between tasks, so only its first frame pays
  the compilation. ``workers=0`` runs everything in the calling process, without Dask.
- Every finished frame is written at once, atomically, as ``OUT_DIR/frames/frame_NNNNNN.json``.
  A rerun reads those files and fits only the frames that have none (``force=True``
  redoes all); it refuses a folder fitted under other settings, or whose ``run.json``
  is missing or unreadable while it holds frames. A frame that fails (unreadable file,
  fit error, lost worker) is recorded with its reason and the others go on.
- At the end the tables ``params.csv`` and ``params.jsonl`` (one row per frame, with
  ``ok`` and ``warnings``; a frame whose roughness or gain jumps away from its
  neighbours is flagged) and the plot ``thickness.png`` (thickness against time) are
  rebuilt from the frame files.

The pieces: :mod:`._plan` (frames, chunks, fingerprint), :mod:`._executors` (the work
of a chunk, in this process or on Dask), :mod:`._records` (the frame files and
``run.json``) and :mod:`._tables` (tables, plot, jump flags); this module joins them
under :class:`SequenceOptions`.

Frames come from image files, folders of images (sorted by name, numbers in natural
order) or a video file read through OpenCV (8-bit BGR, sRGB-encoded: converted to
linear RGB with :func:`bubblefit.io.images.srgb_decode`).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError
from ..io.jaxcache import jax_settings
from ..progress import Progress, stage
from ._executors import DEFAULT_FIT, ChunkTask, DaskExecutor, LocalExecutor
from ._plan import (IMAGE_EXTENSIONS, VIDEO_EXTENSIONS, FrameRef, as_frames, discover_frames, fingerprint,
                    fix_disc, load_frame, plan_chunks)
from ._records import RECORD_VERSION, RecordStore, failed_record, one_line, warm_init
from ._tables import flag_jumps, plot, read_table, row_ok, write_tables
from .fit import FitOptions

__all__ = [
    "FrameRef",
    "SequenceOptions",
    "SequenceResult",
    "discover_frames",
    "load_frame",
    "fit_sequence",
    "read_table",
    "row_ok",
    "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS",
    "RECORD_VERSION",
]


@dataclass(frozen=True)
class SequenceOptions:
    """How a sequence is cut, where it runs and what a rerun reuses (the fit itself is
    :class:`bubblefit.inverse.fit.FitOptions`).

    Attributes
    ----------
    scheduler
        None: start a local Dask cluster; ``"tcp://host:8786"``: use that cluster; a
        ``distributed.Client``: use it. Ignored when ``workers == 0``.
    workers
        Local cluster size (default: one per core); ``0`` fits in this process without
        Dask; with an existing cluster, use at most this many of its workers.
    chunk_size
        Frames per task (a warm-start chain). Bigger chunks warm-start more frames;
        smaller ones spread better over many workers.
    force
        Refit frames already finished (and accept a folder whose settings are unknown).
    retry_failed
        Refit frames recorded as failed (frames lost with a worker are always refitted;
        unreadable frames and fits that raised only with this flag).
    maps
        Write each frame's thickness map (when the fit gives one).
    fps
        Frames per second for the time axis (see :func:`discover_frames`).
    progress
        Show a progress bar (frames per second, time left) on a terminal.
    fit_function
        ``"module:name"`` of the per-frame fit (importable on the workers), called as
        ``fit(photo, env, options=, background=, init=, scene=)``.
    warm_start
        Start each frame from its predecessor (False: global search everywhere, for
        frames that are not a continuous film).
    batch
        Frames fitted together in one vmapped solve within a task, once a chunk has two
        warm-started results (:func:`bubblefit.inverse.fit.fit_batch`). 1 (the default)
        fits frame after frame, which is faster on CPUs (``experiments/bench_sequence.py``:
        batches of 2-8 ran at 0.5-0.7x the frames per second on 2 cores); larger batches
        are for accelerators, where one small frame does not fill the device.
    """

    scheduler: Any = None
    workers: int | None = None
    chunk_size: int = 8
    force: bool = False
    retry_failed: bool = False
    maps: bool = False
    fps: float | None = None
    progress: bool = True
    fit_function: str = DEFAULT_FIT
    warm_start: bool = True
    batch: int = 1

    def __post_init__(self):
        if self.chunk_size < 1:
            raise InputError(f"chunk size must be at least 1, got {self.chunk_size}")
        if self.batch < 1:
            raise InputError(f"batch must be at least 1, got {self.batch}")
        if self.workers is not None and self.workers < 0:
            raise InputError(f"workers must be 0 (this process) or more, got {self.workers}")


@dataclass
class SequenceResult:
    """What :func:`fit_sequence` did.

    Attributes
    ----------
    out_dir
        the output folder.
    records
        one dict per frame, in order (``status`` "ok" or "failed", ``params``,
        ``stderr``, ``converged``, ``message``, ``time_s``, ...), as in ``frames/``.
    fitted
        frames fitted by this call.
    skipped
        frames found finished on disk.
    failed
        frames recorded as failed (this call or before).
    elapsed_s
        wall time of the fitting (cluster start excluded); fps = fitted / elapsed_s.
    setup_s
        time to start (or connect to) the cluster and send it the data.
    workers
        how many worker processes took part (0: this process).
    table, jsonl, plot
        paths of ``params.csv``, ``params.jsonl``, ``thickness.png``.
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


class _Run:
    """The records of one call as they arrive: saved at once, kept for the tables."""

    def __init__(self, store: RecordStore, want_maps: bool, on_record: Callable[[dict], None] | None, bar):
        self.store, self.want_maps, self.on_record, self.bar = store, want_maps, on_record, bar
        self.fresh: dict[int, dict] = {}
        self.fitted: set[int] = set()

    def accept(self, rec: dict, refit: bool = True) -> None:
        if refit:
            self.fitted.add(rec["frame"])
        saved = self.store.save(rec)
        self.fresh[rec["frame"]] = saved
        if self.on_record is not None:
            self.on_record(saved)

    def failed_chunk(self, chunk, reason: str) -> None:
        for ref, d in chunk:
            if d is None and ref.index not in self.fresh:
                self.accept(failed_record(ref, reason, retryable=True))
        if self.bar:
            self.bar.update(sum(1 for _, d in chunk if d is None))

    def run(self, executor, chunks) -> None:
        """Submit every chunk and accept its records as the chunks finish."""
        futures = {executor.submit(chunk): chunk for chunk in chunks}
        for f in executor.completed(futures):
            chunk = futures[f]
            try:
                recs = f.result()
            except Exception as exc:  # lost worker, unpicklable result, ...
                if executor.workers == 0:
                    raise
                self.failed_chunk(chunk, f"task failed: {one_line(exc)}")
                continue
            for rec in recs:
                self.accept(rec)
                if self.bar:
                    self.bar.update(1, _note(rec))


def fit_sequence(
    frames: Sequence[FrameRef] | Sequence[str | os.PathLike] | str | os.PathLike,
    env,
    out_dir: str | os.PathLike,
    options: FitOptions | None = None,
    sequence: SequenceOptions | None = None,
    *,
    background: np.ndarray | None = None,
    scene=None,
    on_record: Callable[[dict], None] | None = None,
) -> SequenceResult:
    """Fit every frame of a sequence and write the tables, resumably.

    Parameters
    ----------
    frames
        :class:`FrameRef` s, or paths (files, folders, videos, globs) for :func:`discover_frames`.
    env
        The environment map (:class:`~bubblefit.lighting.envmap.EnvMap`).
    out_dir
        Output folder (created). Holds ``frames/`` (one JSON per finished frame),
        ``params.csv``, ``params.jsonl``, ``thickness.png``, ``run.json`` and, with
        ``maps``, ``maps/frame_NNNNNN_thickness.exr``.
    options
        :class:`bubblefit.inverse.fit.FitOptions` of every frame (default: its defaults).
    sequence
        :class:`SequenceOptions`: chunks, workers, resume, maps (default: its defaults).
    background, scene
        Passed to every :func:`bubblefit.inverse.fit.fit_photo` call.
    on_record
        Called with each new record as it is saved (for tests and tools).

    Returns
    -------
    SequenceResult

    Raises
    ------
    InputError
        Bad frames or options, an unreachable scheduler, or an output folder holding the
        results of a run with other settings, or frames without a readable ``run.json``
        (use ``force``).
    """
    seq = sequence or SequenceOptions()
    options = options or FitOptions()
    frames = as_frames(frames, seq.fps)
    store = RecordStore(out_dir)
    with stage("finding the bubble's disc"):
        options = fix_disc(options, frames, background, scene)
    key = (options, seq.fit_function, bool(seq.warm_start)) + ((int(seq.batch),) if seq.batch > 1 else ())
    fp = fingerprint(key, env, background, scene)
    store.open_run(fp, len(frames), seq.chunk_size, repr(options), force=seq.force)
    done = {} if seq.force else store.finished(frames, retry_failed=seq.retry_failed)
    chunks = plan_chunks(frames, seq.chunk_size, done)
    pending = sum(1 for c in chunks for _, d in c if d is None)

    task = ChunkTask(env, options, background, scene, jax_settings(), bool(seq.maps), seq.fit_function,
                     bool(seq.warm_start), int(seq.batch))
    bar = Progress(pending, "fitting frames", unit="frames") if seq.progress else None
    run = _Run(store, bool(seq.maps), on_record, bar)
    t_setup = time.perf_counter()
    executor = LocalExecutor(task)
    if chunks and seq.workers != 0:
        with stage("starting the Dask workers"):
            executor = DaskExecutor(task, seq.scheduler, seq.workers)
    try:
        setup_s = time.perf_counter() - t_setup
        t0 = time.perf_counter()
        with bar if bar else _nullctx():
            run.run(executor, chunks)
        if seq.warm_start and seq.chunk_size < len(frames):
            _repair_seams(frames, seq.chunk_size, done, run.fresh, executor.submit, run.accept)
        elapsed = time.perf_counter() - t0
    finally:
        executor.close()
    with stage("writing the tables"):
        return _finish(store, frames, done, run, elapsed, setup_s, executor.workers)


def _finish(store: RecordStore, frames, done, run: _Run, elapsed: float, setup_s: float,
            workers: int) -> SequenceResult:
    """The tables and plot from every frame's record, jumps flagged, and the result."""
    records = []
    for ref in frames:
        rec = run.fresh.get(ref.index) or done.get(ref.index)
        if rec is None:
            rec = {"frame": ref.index, "file": ref.label, "time_s": ref.time_s, "status": "failed",
                   "converged": False, "message": "not fitted"}
        records.append(rec)
    records = flag_jumps(records)
    table, jsonl = write_tables(store.out, records)
    fig = plot(store.out, records)
    n_failed = sum(1 for r in records if r.get("status") != "ok")
    skipped = sum(1 for i in done if i not in run.fitted)
    return SequenceResult(out_dir=store.out, records=records, fitted=len(run.fitted), skipped=skipped,
                          failed=n_failed, elapsed_s=elapsed, setup_s=setup_s, workers=workers, table=table,
                          jsonl=jsonl, plot=fig)


SEAM_TOLERANCE = 1.05


def _repair_seams(frames, chunk_size, done, fresh, submit, accept):
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
            if warm_init(rec(ref)):
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

    checks = {c: submit([(first_ok(parts[c])[0], None)], warm_init(last_ok(parts[c - 1])))
              for c in range(1, len(parts)) if needs_check(c)}
    repaired = set()
    for c in sorted(checks):
        if not needs_check(c):
            continue
        ref, first = first_ok(parts[c])
        prev = last_ok(parts[c - 1])
        check = checks[c] if c - 1 not in repaired else submit([(ref, None)], warm_init(prev))
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
                recs = submit(todo, warm_init(prev)).result()
            except Exception:
                continue
            for r in recs:
                accept(dict(r, seam="repaired"))
            repaired.add(c)
        else:
            accept(dict(first, seam_checked=True), False)


def _note(rec: dict) -> str:
    d = rec.get("params", {}).get("thickness_nm")
    return f"frame {rec['frame']}: " + (f"{d:.0f} nm" if d is not None else rec.get("status", ""))


class _nullctx:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False
