"""MkDocs hooks of the bubblefit documentation site.

- The figures under ``experiments/figures/`` and the validation plots under
  ``experiments/validation/results/`` are added to the site as ``figures/NAME.png`` and
  ``figures/validation/NAME.png``, so the pages show the pictures the experiments wrote
  without a second copy in ``docs/``.
- ``<!-- bubblefit-help: all -->`` in a page becomes the ``--help`` text of every
  ``bubblefit`` command (``<!-- bubblefit-help: NAME -->`` of one), taken from the
  parser itself at build time, so the command-line page cannot drift from the code.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
FIGURES = {"experiments/figures": "figures", "experiments/validation/results": "figures/validation"}
HELP = re.compile(r"<!--\s*bubblefit-help:\s*([\w-]+)\s*-->")
WIDTH = "90"  # columns argparse wraps the help texts to


def on_files(files, config):
    """Add the experiments' PNG figures to the site."""
    for src, dest in FIGURES.items():
        for png in sorted((ROOT / src).glob("*.png")):
            files.append(File.generated(config, f"{dest}/{png.name}", abs_src_path=str(png)))
    return files


def _subparsers():
    os.environ["COLUMNS"] = WIDTH
    from bubblefit.cli import build_parser

    parser = build_parser()
    action = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return parser, action.choices


def _block(text: str) -> str:
    return "```text\n" + text.rstrip() + "\n```\n"


def _help(match: re.Match) -> str:
    parser, commands = _subparsers()
    name = match.group(1)
    if name == "main":
        return _block(parser.format_help())
    if name == "all":
        return "\n".join(f"### bubblefit {cmd}\n\n" + _block(sub.format_help()) for cmd, sub in commands.items())
    if name not in commands:
        raise ValueError(f"bubblefit has no command {name!r} (page marker {match.group(0)})")
    return _block(commands[name].format_help())


def on_page_markdown(markdown, page, config, files):
    """Expand the command line's help markers."""
    return HELP.sub(_help, markdown)
