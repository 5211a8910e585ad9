"""``bubblefit check-capture DIR --protocol NAME``: check a capture against a protocol.

Runs the checks of :func:`bubblefit.capture.protocols.check_capture` and prints a pass/fail table
with reasons; exits 0 when every check passed (warnings allowed), 1 when one failed, and 2
on bad input (missing folder, no images, unknown protocol).
"""

from __future__ import annotations

from pathlib import Path

NAME = "check-capture"


def _protocol_names() -> list[str]:
    """Names of the shipped protocol specs, found without importing :mod:`bubblefit.capture`
    (the same folder as :func:`bubblefit.capture.protocols.protocols_dir`: ``capture_protocols/``
    beside the package), so that ``--help`` stays fast."""
    folder = Path(__file__).resolve().parents[2] / "capture_protocols"
    return sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []


def register(subparsers) -> None:
    from .common import input_file, output_file

    known = ", ".join(_protocol_names()) or "transmission, envmap, bubble"
    p = subparsers.add_parser(
        NAME,
        help="check a capture folder against a protocol of capture_protocols/",
        description=(
            "Read the images of DIR and their EXIF metadata and check what the protocol "
            "requires (files present, sizes, locked exposure and white balance, "
            "registration, no saturation inside the bubble or ball, bracket span). "
            f"Protocols: {known}; or the path of a .toml spec. Exits 1 if a check fails."
        ),
    )
    p.add_argument("folder", metavar="DIR", type=input_file, help="folder holding the capture's images")
    p.add_argument("--protocol", required=True, metavar="NAME", help=f"protocol name ({known}) or spec path")
    p.add_argument("--json", metavar="PATH", type=output_file, help="write the results as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..capture.protocols import check_capture, format_table, load_protocol
    from .common import folder_files, guard_args, write_json

    guard_args(args, inputs=folder_files(args.folder) + [Path(args.protocol)])
    spec = load_protocol(args.protocol)
    report = check_capture(args.folder, spec)
    print(format_table(report))
    if args.json:
        write_json(args.json, report.as_dict())
    return 0 if report.passed else 1
