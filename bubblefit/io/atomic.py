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

A writer may report success on a short write (a full disk seen only when the file is
closed, or not at all): a ``check`` given to :class:`atomic_path` reads the temporary file
back before it replaces anything (:func:`write_bytes` compares its size with the bytes
given; image writers re-read the image), and a file that fails the check is removed.

A command's outputs land as a set (:func:`output_set`): inside it, each completed file waits
as its temporary file, and all are renamed together once every one is complete; an
exception or an interrupt (``KeyboardInterrupt``, ``SystemExit``) anywhere removes them all,
so the earlier outputs stay as they were, side by side. Temporary files still open when the
process is interrupted are removed by :func:`remove_temporaries` (the command line calls it).
"""

from __future__ import annotations

import errno
import json
import math
import os
import stat
import contextlib
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

from ..errors import OutputError

__all__ = ["atomic_path", "preview_path", "write_text", "write_bytes", "write_json", "json_text", "json_default",
           "os_reason", "output_set", "remove_temporaries", "check_png"]

#: Temporary files created and not yet renamed or removed (for :func:`remove_temporaries`).
_PENDING: set[str] = set()
_STATE = threading.local()
_PENDING_LOCK = threading.Lock()


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


def _remove_quietly(path: str | None) -> None:
    if path is None:
        return
    try:
        os.remove(path)
    except OSError:
        pass
    with _PENDING_LOCK:
        _PENDING.discard(path)


def remove_temporaries() -> None:
    """Remove every temporary file this process created and has not renamed (an interrupted
    command's half-written outputs); the targets stay as they were."""
    with _PENDING_LOCK:
        pending = list(_PENDING)
    for tmp in pending:
        _remove_quietly(tmp)


def _finish(tmp: str, final: Path, shown: Path) -> None:
    """fsync ``tmp``, give it the permissions of the file it replaces, rename it over
    ``final`` and fsync the folder; on any failure or interrupt ``tmp`` is removed."""
    try:
        _fsync_path(tmp)
        os.chmod(tmp, _new_file_mode(final))
        os.replace(tmp, final)
    except OSError as err:
        _remove_quietly(tmp)
        raise OutputError(f"cannot write {shown}: {os_reason(err)}") from None
    except BaseException:
        _remove_quietly(tmp)
        raise
    with _PENDING_LOCK:
        _PENDING.discard(tmp)
    try:
        _fsync_path(final.parent, directory=True)
    except OSError:
        pass  # the file is complete and in place; only its durability is unconfirmed


@contextlib.contextmanager
def output_set():
    """Context in which this thread's completed outputs (:class:`atomic_path`) wait as their
    temporary files and are renamed together at its end, once every one is complete; an
    exception or interrupt removes them all (the earlier files stay as a set)."""
    outer = getattr(_STATE, "waiting", None)
    waiting: list[tuple[str, Path, Path]] = []
    _STATE.waiting = waiting
    try:
        yield
    except BaseException:
        for tmp, _, _ in waiting:
            _remove_quietly(tmp)
        raise
    finally:
        _STATE.waiting = outer
    if outer is not None:  # nested: the outer set renames them
        outer.extend(waiting)
        return
    for i, (tmp, final, shown) in enumerate(waiting):
        try:
            _finish(tmp, final, shown)
        except BaseException:
            for rest, _, _ in waiting[i + 1:]:
                _remove_quietly(rest)
            raise


class atomic_path:
    """Context manager yielding the path to write, which replaces ``target`` on success.

    ``with atomic_path("out.exr") as tmp: writer(tmp)``. On success the temporary file is
    checked (``check(tmp)``, when given: it raises :class:`OutputError` for a short or
    unreadable file), fsync'd and renamed over the target (at the end of the enclosing
    :func:`output_set`, if any); on any exception or interrupt it is removed and the
    target is left as it was. An ``OSError`` raised by the writer (or by the rename)
    becomes one :class:`~bubblefit.errors.OutputError` line naming the target. A
    non-regular target (e.g. ``/dev/null``) is yielded itself and written in place.

    Raises
    ------
    OutputError
        The folder is missing or not writable, the target is a folder, or a write, the
        check, the fsync or the rename failed.
    """

    def __init__(self, target: str | os.PathLike, check: Callable[[str], None] | None = None):
        self.target = Path(target)
        self.check = check
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
        with _PENDING_LOCK:  # registered before it exists: an interrupt cannot slip between
            try:
                fd, tmp = tempfile.mkstemp(prefix=f".{real.stem}.", suffix=real.suffix or ".tmp", dir=folder)
            except OSError as exc:
                raise OutputError(f"cannot write {shown}: {os_reason(exc)}") from None
            _PENDING.add(tmp)
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
            if self.check is not None:
                self.check(self.tmp)
        except OSError as err:
            _remove_quietly(self.tmp)
            raise OutputError(f"cannot write {self.target}: {os_reason(err)}") from None
        except BaseException:
            _remove_quietly(self.tmp)
            raise
        waiting = getattr(_STATE, "waiting", None)
        if waiting is not None:
            waiting.append((self.tmp, self.final, self.target))
            return False
        _finish(self.tmp, self.final, self.target)
        return False


#: The last 12 bytes of every complete PNG file: the IEND chunk (length 0, type, CRC)
#: (ISO/IEC 15948:2004, sec. 11.2.5).
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def check_png(tmp: str) -> None:
    """An :class:`atomic_path` check for PNG writers (matplotlib): the file ends with the
    IEND chunk, so it was written to its last byte.

    References
    ----------
    ISO/IEC 15948:2004 (PNG), sec. 11.2.5: IEND is the last chunk.
    """
    with open(tmp, "rb") as fh:
        size = fh.seek(0, os.SEEK_END)
        fh.seek(max(size - len(PNG_END), 0))
        if size < 8 + len(PNG_END) or fh.read() != PNG_END:
            raise OutputError(f"the PNG written has no end chunk ({size} bytes; disk full?)")


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` through :class:`atomic_path`, checked to the last byte
    (the file's size on disk after the close is ``len(data)``)."""
    def check(tmp: str) -> None:
        size = os.stat(tmp).st_size
        if size != len(data):
            raise OutputError(f"cannot write {path}: {size} of {len(data)} bytes written (disk full?)")

    with atomic_path(path, check=check) as tmp:
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
