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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bubblefit",
        description="Render soap bubbles and measure them from photographs.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from ..errors import BubblefitError

    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_jax()
    try:
        return int(args.func(args) or 0)
    except BubblefitError as exc:
        print(f"bubblefit: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("bubblefit: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print("bubblefit: error: out of memory (try a smaller image or fewer spectral samples)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
