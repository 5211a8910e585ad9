"""Progress reporting for long work: a one-line bar on a terminal, silent otherwise."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "status"]


def status(message: str, *, stream=None) -> None:
    """Print a short status line on stderr when it is a terminal (or always with BUBBLEFIT_VERBOSE)."""
    import os

    stream = stream or sys.stderr
    if stream.isatty() or os.environ.get("BUBBLEFIT_VERBOSE"):
        print(message, file=stream, flush=True)


class Progress:
    """``with Progress(total, "fitting") as bar: bar.update()`` — rate and time left on stderr."""

    def __init__(self, total: int, label: str = "", *, stream=None, unit: str = "it"):
        import os

        self.total = max(int(total), 1)
        self.label = label
        self.unit = unit
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() or bool(os.environ.get("BUBBLEFIT_VERBOSE"))
        self.done = 0
        self.start = time.perf_counter()

    def __enter__(self):
        self._draw()
        return self

    def update(self, n: int = 1, note: str = "") -> None:
        self.done = min(self.done + n, self.total)
        self._draw(note)

    def _draw(self, note: str = "") -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        rate = self.done / elapsed if elapsed > 0 and self.done else 0.0
        left = (self.total - self.done) / rate if rate > 0 else float("nan")
        width = 24
        fill = int(width * self.done / self.total)
        eta = f"{left:5.0f}s left" if left == left else "  ...   "
        line = (f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
                f"{rate:5.2f} {self.unit}/s {eta} {note}")
        self.stream.write(line[:160])
        self.stream.flush()

    def __exit__(self, *exc):
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
        return False
