"""One write path for every output: temporary file, checked writes, fsync, rename.

Every file bubblefit writes (images, previews, JSON, CSV, plots, sequence records) goes
through :class:`atomic_path`, so that a failed run (full disk, missing folder, a writer
that reports an error, an interrupt) leaves the earlier file byte-identical and no
temporary file behind, and the user reads one line, e.g. ``cannot write out.exr: no
space left on device`` (docs/design.md, "Command line": nothing lost).

How a regular file (or a new one) is written:

1. a temporary file is created in the target's own folder (same file system, so the
   final rename is atomic), hidden (``.<stem>.<random><suffix>``) and with the target's
   suffix, so that format-guessing writers (OpenImageIO, matplotlib) pick the right one;
2. the caller writes it; any ``OSError`` becomes an :class:`~bubblefit.errors.OutputError`;
3. the temporary file is flushed to disk (``fsync``), given the permissions of the file
   it replaces (or those of a new file: ``0666`` less the umask), renamed over the
   target, and the folder is fsync'd so the rename itself survives a crash.

A symbolic link is followed: the file it points to is replaced and the link stays. A
target that exists and is not a regular file (a character device such as
``/dev/null``, a FIFO, a socket) is written in place, never renamed over.
"""

from __future__ import annotations

import errno
import json
import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

from ..errors import OutputError

__all__ = ["atomic_path", "preview_path", "write_text", "write_bytes", "write_json", "json_text", "json_default",
           "os_reason"]


def os_reason(exc: OSError) -> str:
    """The reason of an ``OSError`` in lower case, as the one-line messages print it
    (``"no space left on device"``)."""
    text = exc.strerror or (errno.errorcode.get(exc.errno or 0) if exc.errno else None) or str(exc)
    return text[:1].lower() + text[1:] if text else "unknown error"


def _is_special(path: Path) -> bool:
    """True for an existing target that is not a regular file (device, FIFO, socket)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


def _new_file_mode(existing: Path) -> int:
    """The permissions of the file being replaced, or those of a new file (0666 less the umask)."""
    try:
        return stat.S_IMODE(os.stat(existing).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_path(path: str | Path, *, directory: bool = False) -> None:
    """Flush a file (or a folder's entries) to disk; folders that refuse fsync are skipped."""
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    except OSError as exc:
        if not directory or exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def _remove_quietly(path: str) -> None:
    try:
        os.remove(path)
    except OSError:
        pass


class atomic_path:
    """Context manager yielding the path to write, which replaces ``target`` on success.

    ``with atomic_path("out.exr") as tmp: writer(tmp)``. On success the temporary file is
    fsync'd and renamed over the target; on any exception it is removed and the target is
    left as it was. An ``OSError`` raised by the writer (or by the rename) becomes one
    :class:`~bubblefit.errors.OutputError` line naming the target. A non-regular target
    (e.g. ``/dev/null``) is yielded itself and written in place.

    Raises
    ------
    OutputError
        The folder is missing or not writable, the target is a folder, or a write,
        the fsync or the rename failed.
    """

    def __init__(self, target: str | os.PathLike):
        self.target = Path(target)
        self.tmp: str | None = None
        self.in_place = False

    def __enter__(self) -> str:
        shown = self.target
        real = Path(os.path.realpath(self.target))  # a link is followed, and stays a link
        if real.is_dir():
            raise OutputError(f"cannot write {shown}: it is a folder")
        if _is_special(real):
            self.in_place, self.final = True, real
            return str(real)
        folder = real.parent
        if not folder.is_dir():
            raise OutputError(f"cannot write {shown}: folder {self.target.parent} does not exist")
        if not os.access(folder, os.W_OK):
            raise OutputError(f"cannot write {shown}: folder {self.target.parent} is not writable")
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{real.stem}.", suffix=real.suffix or ".tmp", dir=folder)
        except OSError as exc:
            raise OutputError(f"cannot write {shown}: {os_reason(exc)}") from None
        os.close(fd)
        self.tmp, self.final = tmp, real
        return tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        if self.in_place:
            if isinstance(exc, OSError):
                raise OutputError(f"cannot write {self.target}: {os_reason(exc)}") from None
            return False
        if exc_type is not None:
            _remove_quietly(self.tmp)
            if isinstance(exc, OSError):
                raise OutputError(f"cannot write {self.target}: {os_reason(exc)}") from None
            return False
        try:
            _fsync_path(self.tmp)
            os.chmod(self.tmp, _new_file_mode(self.final))
            os.replace(self.tmp, self.final)
        except OSError as err:
            _remove_quietly(self.tmp)
            raise OutputError(f"cannot write {self.target}: {os_reason(err)}") from None
        try:
            _fsync_path(self.final.parent, directory=True)
        except OSError:
            pass  # the file is complete and in place; only its durability is unconfirmed
        return False


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through :class:`atomic_path`."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` through :class:`atomic_path`."""
    write_bytes(path, text.encode("utf-8"))


def json_default(o: Any):
    """JSON form of the NumPy and JAX values results hold (scalars, arrays, booleans)."""
    if hasattr(o, "tolist") and hasattr(o, "dtype"):  # numpy (and jax) arrays and scalars
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    if isinstance(o, os.PathLike):
        return os.fspath(o)
    raise TypeError(f"cannot write {type(o).__name__} as JSON")


def _finite_or_none(value):
    """Non-finite floats as ``null``, recursively (strict JSON has no NaN nor Infinity)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value


def json_text(data: Any, *, indent: int | None = 2, allow_nan: bool = True) -> str:
    """``data`` as JSON text (NumPy values converted). ``allow_nan=False`` writes NaN and
    infinities as ``null`` (strict JSON, for JSON-lines tables)."""
    if not allow_nan:
        data = _finite_or_none(json.loads(json.dumps(data, default=json_default, allow_nan=True)))
    return json.dumps(data, indent=indent, default=json_default, allow_nan=allow_nan)


def write_json(path: str | os.PathLike, data: Any, *, indent: int | None = 2) -> None:
    """Write ``data`` as JSON (NumPy values converted, NaN kept as ``NaN``) through
    :class:`atomic_path`; the text is built first, so an unwritable value leaves no file."""
    write_text(path, json_text(data, indent=indent) + "\n")


def preview_path(image_path: str | os.PathLike) -> Path:
    """The sRGB PNG preview written beside an image output: same name, ``.png`` suffix
    (``X_preview.png`` when the output is itself ``X.png``)."""
    p = Path(image_path)
    return p.with_suffix(".png") if p.suffix.lower() != ".png" else p.with_name(p.stem + "_preview.png")
