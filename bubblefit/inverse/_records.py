"""The record store of a sequence fit: one JSON per frame and the run's settings.

``OUT_DIR/frames/frame_NNNNNN.json`` holds each finished frame, written at once through
:func:`bubblefit.io.atomic.write_text`, so an interrupted run loses no finished frame;
``OUT_DIR/run.json`` holds the fingerprint of the settings the frames were fitted with
(:func:`bubblefit.inverse._plan.fingerprint`), so that a rerun under other settings (or
without a readable ``run.json`` to tell) never mixes its frames with the earlier ones.
The tables are rebuilt from these records (:mod:`bubblefit.inverse._tables`).
"""

from __future__ import annotations

import json
import math
import os
import socket
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.atomic import json_text, write_text
from ..io.images import write_image
from ._plan import FrameRef

__all__ = ["RECORD_VERSION", "RecordStore", "one_line", "warm_init", "base_record", "result_record",
           "failed_record"]

RECORD_VERSION = 1


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


def one_line(exc: BaseException) -> str:
    """``Type: first line`` of an exception, for a frame's ``message``."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def warm_init(record: dict | None) -> dict | None:
    """The warm start a record offers its next frame: its parameters if it converged."""
    if record and record.get("status") == "ok" and record.get("converged") and record.get("init"):
        return dict(record["init"])
    return None


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def base_record(ref: FrameRef, init) -> dict:
    """The fields every record of ``ref`` has, fitted or failed."""
    return {"version": RECORD_VERSION, "frame": ref.index, "file": ref.label, "time_s": ref.time_s,
            "warm_start": init is not None, "worker": _worker_name()}


def failed_record(ref: FrameRef, reason: str, *, retryable: bool = False) -> dict:
    """The record of a frame that could not be fitted (``retryable``: not the frame's fault,
    e.g. a lost worker, so a rerun always tries again)."""
    rec = {"version": RECORD_VERSION, "frame": ref.index, "file": ref.label, "time_s": ref.time_s,
           "status": "failed", "converged": False, "message": reason, "warm_start": False}
    if retryable:
        rec["retryable"] = True
    return rec


def result_record(base: dict, res, fit_time_s: float) -> dict:
    """A frame's record from its fit result.

    Reads the fit's ``ok``, ``reduced_chi2`` and ``warnings`` with ``getattr`` defaults, so
    it works with fit results that carry them and with those that do not.
    """
    params = _scalar_dict(getattr(res, "params", {}))
    stderr = _scalar_dict(getattr(res, "stderr", {}))
    init_next = getattr(res, "init", None)
    converged = bool(getattr(res, "converged", False))
    rec = dict(
        base,
        status="ok",
        converged=converged,
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
    disc = getattr(res, "disc", None)
    if disc is not None and getattr(res, "disc_stderr", None) is not None:  # refined: the next frame's start
        rec["init"] = dict(rec["init"], disc=[float(v) for v in disc])
    carried = getattr(res, "carried", None)
    if isinstance(carried, dict):  # a map's global parameters, for the next frame to hold
        rec["init"] = dict(rec["init"], carried=carried)
        if carried.get("frames"):
            rec["globals_carried_frames"] = int(carried["frames"])
    fit_ok = getattr(res, "ok", None)
    if fit_ok is not None:
        rec["fit_ok"] = bool(fit_ok)
    chi2 = getattr(res, "reduced_chi2", None)
    if chi2 is not None:
        rec["reduced_chi2"] = _as_float(chi2)
    floor = getattr(res, "chi2_floor", None)
    if floor is not None:
        rec["chi2_floor"] = _as_float(floor)
    model = getattr(res, "model", None)
    if isinstance(model, str):
        rec["model"] = model
    warnings = getattr(res, "warnings", None)
    if warnings:
        rec["warnings"] = [str(w) for w in warnings]
    tmap = getattr(res, "thickness_map", None)
    if tmap is not None:
        rec["_thickness_map"] = np.asarray(tmap, dtype=np.float32)
    return rec


def _read_json(path: Path) -> dict | None:
    try:
        with open(path) as fh:
            data = json.load(fh)
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return data if isinstance(data, dict) else None


class RecordStore:
    """The files of one output folder: ``frames/*.json``, ``maps/``, ``run.json``.

    Parameters
    ----------
    out_dir
        The output folder; it and ``frames/`` are created.

    Raises
    ------
    InputError
        The folder cannot be created.
    """

    def __init__(self, out_dir: str | os.PathLike):
        self.out = Path(out_dir)
        try:
            (self.out / "frames").mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"cannot create output folder {self.out}: {exc.strerror}") from None

    @property
    def run_path(self) -> Path:
        return self.out / "run.json"

    def record_path(self, index: int) -> Path:
        return self.out / "frames" / f"frame_{index:06d}.json"

    def read(self, index: int) -> dict | None:
        """The record of frame ``index``, or None (missing, half-written by something else,
        another version): such a frame is refitted."""
        rec = _read_json(self.record_path(index))
        return rec if rec is not None and rec.get("version") == RECORD_VERSION else None

    def save(self, rec: dict) -> dict:
        """Write a record (and its thickness map, to ``maps/``); returns it as saved."""
        rec = dict(rec)
        tmap = rec.pop("_thickness_map", None)
        if tmap is not None:
            maps = self.out / "maps"
            maps.mkdir(exist_ok=True)
            name = f"frame_{rec['frame']:06d}_thickness.exr"
            write_image(maps / name, tmap, bit_depth=32)
            rec["thickness_map"] = f"maps/{name}"
        write_text(self.record_path(rec["frame"]), json_text(rec, indent=1) + "\n")
        return rec

    def _frame_files(self) -> list[Path]:
        return sorted((self.out / "frames").glob("frame_*.json"))

    def open_run(self, fp: str, n_frames: int, chunk_size: int, options_repr: str, *, force: bool) -> None:
        """Check that this folder's finished frames were fitted with the same settings, then
        record this run's (``run.json``).

        Raises
        ------
        InputError
            Without ``force``: ``run.json`` holds another fingerprint, or it is missing or
            unreadable while ``frames/`` holds finished frames (their settings are unknown).
        """
        if not force:
            prev = _read_json(self.run_path)
            if prev is not None and prev.get("fingerprint") != fp:
                raise InputError(f"{self.out} holds results fitted with other settings or maps; "
                                 "use --force to refit, or another output folder")
            held = self._frame_files()
            if prev is None and held:
                state = "unreadable" if self.run_path.exists() else "missing"
                raise InputError(f"{self.out} holds {len(held)} finished frame(s) but its run.json is {state}, "
                                 "so the settings they were fitted with are unknown; use --force to refit, "
                                 "or another output folder")
        write_text(self.run_path, json_text({"fingerprint": fp, "frames": n_frames, "chunk_size": chunk_size,
                                             "options": options_repr}, indent=1) + "\n")

    def finished(self, frames: list[FrameRef], *, retry_failed: bool) -> dict[int, dict]:
        """The records of frames that need no refit: saved for the same file, and not a
        failure to retry (a lost worker is not the frame's fault: always retried)."""
        done = {}
        for ref in frames:
            rec = self.read(ref.index)
            if rec is None or rec.get("file") != ref.label:
                continue
            if rec.get("status") != "ok" and (retry_failed or rec.get("retryable")):
                continue
            done[ref.index] = rec
        return done
