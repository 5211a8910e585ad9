"""The ``bubblefit`` command line (docs/design.md, "Command line").

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to a function taking
the parsed arguments and returning an exit status. Errors of type
:class:`bubblefit.errors.BubblefitError` are printed as one line on stderr.

Start-up: building the parsers imports the command modules, which import nothing heavy
at module level (JAX, OpenImageIO, colour-science, OpenCV, Dask, SciPy and Matplotlib are
imported inside each command's ``run``), so ``--help``, ``--version`` and argument errors
answer at once. JAX's compilation cache and quiet logs are set up through environment
variables (:func:`bubblefit.io.jaxcache.jax_setup`) before any command imports JAX.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Sub-command modules, in the order ``--help`` lists them.
COMMANDS = (
    "render",
    "chart",
    "envmap",
    "check_capture",
    "calibrate",
    "calibrate_camera",
    "fit",
    "fit_sequence",
    "fit_spectrum",
    "demo",
    "export",
    "report",
)


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit 2), like every
    other error of the command line; ``--help`` shows the usage."""

    def error(self, message):  # noqa: D102
        self.exit(2, f"bubblefit: error: {_one_line(message)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="bubblefit",
        description="Render soap bubbles and measure them from photographs.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"bubblefit {__version__}")
    parser.add_argument("--max-megapixels", type=float, default=None, metavar="N",
                        help="largest image read, in millions of pixels (default 150; checked from the "
                             "file's header before decoding)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def _one_line(text: str) -> str:
    """The first non-empty line of a message (decoders sometimes return several)."""
    lines = [ln.strip() for ln in str(text).strip().splitlines() if ln.strip()]
    return lines[0] if lines else "unknown error"


#: Commands whose process :func:`main` ends itself once their outputs are written
#: (:func:`_end_process`), when it was called as the process's entry (no ``argv``).
ENDED_AT_ONCE = ("fit", "render")


def main(argv: list[str] | None = None) -> int:
    """Run one sub-command; every failure becomes one line on stderr and a non-zero exit.

    ``BubblefitError`` (bad input, failed computation) prints ``bubblefit: error: ...`` and
    exits with its code (2 for bad input). Any other exception is a bug or an unforeseen
    input: it prints ``bubblefit: internal error: <type>: <message>`` and exits 1, unless
    the environment sets ``BUBBLEFIT_DEBUG=1``, which re-raises it with its traceback.
    Called without ``argv`` (the ``bubblefit`` script, ``python -m bubblefit``), a command
    of :data:`ENDED_AT_ONCE` ends the process itself (:func:`_end_process`).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    rc = _run(parser, args)
    if argv is None and args.command in ENDED_AT_ONCE:
        _end_process(rc)
    return rc


def _end_process(rc: int) -> None:
    """End the process with status ``rc`` without the interpreter's finalisation, which
    frees every program, array and module one by one: 0.66-0.77 s of CPU after a warm fit
    of docs/speed.md's 320x320 photo, against 0.07-0.09 s ended this way
    (docs/speed-profile.md, "The command ends its process itself"). What the exit would still do
    is done first: the store's compile threads finish and store their programs
    (:func:`~bubblefit.io.executables.wait_for_compiles`), the ``atexit`` handlers run
    (temporary folders, weak-reference finalizers) and stdout and stderr are flushed. A
    process with another thread still running is left to the interpreter (returns)."""
    import atexit
    import threading

    from ..io.executables import wait_for_compiles

    wait_for_compiles()
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        return
    _flush()
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if run_exit_handlers is None:  # an interpreter without it: the usual exit
        return
    run_exit_handlers()
    _flush()
    os._exit(rc)


def _flush() -> None:
    """Flush stdout and stderr (a reader that has gone is not an error here)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


def _run(parser, args) -> int:
    """:func:`main`'s command ``args`` run, with its errors as exit statuses."""
    from ..errors import BubblefitError
    from ..io.atomic import remove_temporaries
    from ..io.jaxcache import jax_setup

    if args.max_megapixels is not None:
        if not (args.max_megapixels > 0 and args.max_megapixels < 1e6):
            parser.error(f"--max-megapixels must be a positive number of millions of pixels, got {args.max_megapixels:g}")
        os.environ["BUBBLEFIT_MAX_PIXELS"] = str(int(args.max_megapixels * 1e6))  # workers inherit it
    _one_line_warnings()
    jax_setup()
    previous = _terminate_as_exit()
    try:
        return int(args.func(args) or 0)
    except BubblefitError as exc:
        print(f"bubblefit: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        remove_temporaries()
        print("bubblefit: interrupted", file=sys.stderr)
        return 130
    except SystemExit:
        remove_temporaries()
        raise
    except BrokenPipeError:  # ``bubblefit ... | head``: the reader has gone; nothing more to say
        _quiet_stdout()
        return 141
    except MemoryError:
        print("bubblefit: error: out of memory (try a smaller image or fewer spectral samples)", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence of the CLI contract
        if os.environ.get("BUBBLEFIT_DEBUG", "") not in ("", "0"):
            raise
        print(f"bubblefit: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(rerun with BUBBLEFIT_DEBUG=1 for a traceback)", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            import signal

            signal.signal(signal.SIGTERM, previous)


def _one_line_warnings() -> None:
    """Warnings as one ``bubblefit: warning: ...`` line each (no source line); NumPy's
    floating-point RuntimeWarnings (overflow in an intermediate of a refused input) are
    not shown: every result they could affect is checked and reported by the command."""
    import warnings

    warnings.filterwarnings("ignore", category=RuntimeWarning)

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"bubblefit: warning: {_one_line(message)}", file=file or sys.stderr)

    warnings.showwarning = show


def _terminate_as_exit():
    """SIGTERM (``kill``, a job scheduler's time limit) ends the command as an exception
    does: context managers run, so half-written outputs are removed (exit 143). Returns
    the handler it replaced (None where none was set)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None

    def terminate(signum, frame):
        raise SystemExit(128 + signum)

    try:
        return signal.signal(signal.SIGTERM, terminate)
    except (ValueError, OSError):  # not the main thread of the main interpreter
        return None


def _quiet_stdout() -> None:
    """Point stdout at /dev/null once its reader has gone, so that the interpreter's final
    flush does not print a second BrokenPipeError."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
