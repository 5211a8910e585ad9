"""The ``bubblefit`` command line (DESIGN.md, "Command line").

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to a function taking
the parsed arguments and returning an exit status. Errors of type
:class:`bubblefit.errors.BubblefitError` are printed as one line on stderr.
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
    "fit",
    "fit_sequence",
    "fit_spectrum",
    "demo",
)


def _setup_jax() -> None:
    """Persistent compilation cache, so a second CLI call starts fast."""
    cache = os.environ.get("BUBBLEFIT_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "bubblefit", "jax"
    )
    try:
        os.makedirs(cache, exist_ok=True)
        import jax

        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    except Exception:  # a read-only home must not stop the program
        pass


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
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def _one_line(text: str) -> str:
    """The first non-empty line of a message (decoders sometimes return several)."""
    lines = [ln.strip() for ln in str(text).strip().splitlines() if ln.strip()]
    return lines[0] if lines else "unknown error"


def main(argv: list[str] | None = None) -> int:
    """Run one sub-command; every failure becomes one line on stderr and a non-zero exit.

    ``BubblefitError`` (bad input, failed computation) prints ``bubblefit: error: ...`` and
    exits with its code (2 for bad input). Any other exception is a bug or an unforeseen
    input: it prints ``bubblefit: internal error: <type>: <message>`` and exits 1, unless
    the environment sets ``BUBBLEFIT_DEBUG=1``, which re-raises it with its traceback.
    """
    from ..errors import BubblefitError

    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_jax()
    try:
        return int(args.func(args) or 0)
    except BubblefitError as exc:
        print(f"bubblefit: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("bubblefit: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print("bubblefit: error: out of memory (try a smaller image or fewer spectral samples)", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence of the CLI contract
        if os.environ.get("BUBBLEFIT_DEBUG", "") not in ("", "0"):
            raise
        print(f"bubblefit: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(rerun with BUBBLEFIT_DEBUG=1 for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
