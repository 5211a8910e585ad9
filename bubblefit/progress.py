"""Progress of long work on stderr: named stages with elapsed time, and a bar for loops.

Shown only when stderr is a terminal (or ``BUBBLEFIT_VERBOSE`` is set), so that scripts,
pipes and logs see nothing but results; ``BUBBLEFIT_QUIET=1`` (or :func:`set_enabled`)
silences it everywhere. Library code marks its stages and stays pure otherwise::

    from bubblefit.progress import stage

    with stage("global thickness search"):
        ...

On a terminal each stage is one line, ``[  2.4 s] global thickness search ... 1.9 s``,
the bracket holding the time since the process started (what the user has waited);
nested stages are indented. :class:`Progress` draws a bar for loops of known length
(frames of a sequence). docs/design.md, "Command line": long work shows progress.
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from typing import Iterator, TextIO

__all__ = ["Progress", "stage", "status", "enabled", "set_enabled", "elapsed"]

_START = time.perf_counter()  # about when the process started: the clock the user sees
_FORCED: bool | None = None
_DEPTH = 0
_BARS = 0  # bars being drawn: stages inside them (each frame's fit) stay quiet


def elapsed() -> float:
    """Seconds since bubblefit was imported (about the process's start)."""
    return time.perf_counter() - _START


def set_enabled(value: bool | None) -> None:
    """Force progress on (True) or off (False); ``None`` goes back to the automatic rule."""
    global _FORCED
    _FORCED = value


def enabled(stream: TextIO | None = None) -> bool:
    """Whether progress is shown on ``stream`` (default stderr): a terminal, or ``BUBBLEFIT_VERBOSE``,
    never with ``BUBBLEFIT_QUIET``."""
    if _FORCED is not None:
        return _FORCED
    if os.environ.get("BUBBLEFIT_QUIET", "") not in ("", "0"):
        return False
    stream = stream or sys.stderr
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):
        tty = False
    return tty or os.environ.get("BUBBLEFIT_VERBOSE", "") not in ("", "0")


def status(message: str, *, stream: TextIO | None = None) -> None:
    """Print a short status line on stderr when progress is shown (see :func:`enabled`)."""
    stream = stream or sys.stderr
    if enabled(stream):
        print(f"[{elapsed():6.1f} s] {message}", file=stream, flush=True)


@contextmanager
def stage(name: str, *, stream: TextIO | None = None) -> Iterator[None]:
    """Mark a stage of long work: its name when it starts, its duration when it ends.

    The hook the fit, render and sequence code call around their steps (finding the disc,
    search, refinement, uncertainty, writing). It costs nothing when progress is hidden,
    and it never swallows an exception: a failed stage is marked ``failed``.
    """
    global _DEPTH
    stream = stream or sys.stderr
    show = enabled(stream)
    t0 = time.perf_counter()
    indent = "  " * _DEPTH
    if show:
        print(f"[{elapsed():6.1f} s] {indent}{name} ...", file=stream, flush=True)
    _DEPTH += 1
    try:
        yield
    except BaseException:
        if show:
            print(f"[{elapsed():6.1f} s] {indent}{name} failed after {time.perf_counter() - t0:.1f} s",
                  file=stream, flush=True)
        raise
    finally:
        _DEPTH -= 1
    if show and time.perf_counter() - t0 >= 0.05:
        print(f"[{elapsed():6.1f} s] {indent}{name} done in {time.perf_counter() - t0:.1f} s",
              file=stream, flush=True)


class Progress:
    """``with Progress(total, "fitting") as bar: bar.update()``: a bar with rate and time left on stderr.

    Drawn in place on one line, only when progress is shown (see :func:`enabled`).
    """

    def __init__(self, total: int, label: str = "", *, stream: TextIO | None = None, unit: str = "it"):
        self.total = max(int(total), 1)
        self.label = label
        self.unit = unit
        self.stream = stream or sys.stderr
        self.enabled = enabled(self.stream)
        self.done = 0
        self.start = time.perf_counter()

    def __enter__(self):
        global _BARS
        _BARS += 1
        self._draw()
        return self

    def update(self, n: int = 1, note: str = "") -> None:
        self.done = min(self.done + n, self.total)
        self._draw(note)

    def _draw(self, note: str = "") -> None:
        if not self.enabled:
            return
        spent = time.perf_counter() - self.start
        rate = self.done / spent if spent > 0 and self.done else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        width = 24
        fill = int(width * self.done / self.total)
        eta = f"{left:5.0f}s left" if left == left else "  ...   "
        line = (f"\r[{elapsed():6.1f} s] {self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
                f"{rate:5.2f} {self.unit}/s {eta} {note}")
        self.stream.write(line[:160].ljust(100))
        self.stream.flush()

    def __exit__(self, *exc):
        global _BARS
        _BARS -= 1
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
        return False
