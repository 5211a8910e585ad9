"""``bubblefit check-capture DIR --protocol NAME``: check a capture against a protocol.

Runs the checks of :func:`bubblefit.capture.protocols.check_capture` and prints a pass/fail table
with reasons; exits 0 when every check passed (warnings allowed), 1 when one failed, and 2
on bad input (missing folder, no images, unknown protocol).
"""

from __future__ import annotations

import json

NAME = "check-capture"


def register(subparsers) -> None:
    from ..capture.protocols import list_protocols

    known = ", ".join(list_protocols()) or "transmission, envmap, bubble"
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
    p.add_argument("folder", metavar="DIR", help="folder holding the capture's images")
    p.add_argument("--protocol", required=True, metavar="NAME", help=f"protocol name ({known}) or spec path")
    p.add_argument("--json", metavar="PATH", help="write the results as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..capture.protocols import check_capture, format_table, load_protocol
    from ..io.images import atomic_path

    spec = load_protocol(args.protocol)
    report = check_capture(args.folder, spec)
    print(format_table(report))
    if args.json:
        with atomic_path(args.json) as tmp:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(report.as_dict(), f, indent=2)
    return 0 if report.passed else 1
