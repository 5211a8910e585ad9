"""Export a fitted bubble to other renderers (``bubblefit export``).

:func:`load_fit` turns a fit result into a :class:`FittedBubble` (the one record every
format reads); :func:`export_bubble` writes it as ``gltf`` (glTF 2.0 with
``KHR_materials_iridescence``), ``blender`` (a Cycles scene script, Blender >= 4.2),
``openpbr`` (an OpenPBR Surface in MaterialX) or ``mitsuba`` (a Mitsuba 3 scene), with
``export.json`` (the record) and ``export_log.txt`` (the files and, in words, what the
format cannot express of the fit).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .record import ExportCamera, FittedBubble, Thickness, load_fit

__all__ = ["FORMATS", "ExportResult", "export_bubble", "load_fit", "FittedBubble", "ExportCamera", "Thickness"]

#: Format name -> (module, writer, the file a user opens).
FORMATS = {
    "gltf": ("gltf", "write_gltf", "bubble.gltf"),
    "blender": ("blender", "write_blender", "bubble_blender.py"),
    "openpbr": ("openpbr", "write_openpbr", "bubble.mtlx"),
    "mitsuba": ("mitsuba", "write_mitsuba", "bubble_mitsuba.xml"),
}


@dataclass(frozen=True)
class ExportResult:
    """What an export wrote: the main file, every file, and the notes of its log."""

    format: str
    main: Path
    files: list
    notes: list
    log: Path


def planned_files(fmt: str, out: Path) -> list[Path]:
    """The main files an export writes (before any work: for the command's output guard)."""
    return [out / FORMATS[fmt][2], out / "export.json", out / "export_log.txt"]


def export_bubble(bubble: FittedBubble, fmt: str, out: str | Path) -> ExportResult:
    """Write ``bubble`` in format ``fmt`` into the folder ``out`` (created if missing)."""
    import importlib

    from ..errors import InputError
    from ..io.atomic import write_json
    from .assets import write_log

    if fmt not in FORMATS:
        raise InputError(f"unknown export format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if fmt == "gltf":
        try:
            import pygltflib  # noqa: F401  (before anything is written)
        except ImportError:
            raise InputError("the glTF export needs pygltflib (pip install 'bubblefit[export]')") from None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    module, writer, main = FORMATS[fmt]
    files, notes = getattr(importlib.import_module(f"{__name__}.{module}"), writer)(bubble, out)
    notes = list(bubble.notes) + list(notes)
    record = bubble.summary()
    record.update(format=fmt, files=[Path(f).name for f in files], limitations=notes)
    write_json(out / "export.json", record)
    lines = [f"bubblefit export --to {fmt}: {bubble.source}",
             f"fit: {bubble.model} model, {bubble.thickness.kind} thickness, ok {'yes' if bubble.ok else 'NO'}",
             "files:"] + [f"  {Path(f).name}" for f in files] + ["  export.json", "what the format cannot express:"]
    lines += [f"  - {n}" for n in notes]
    log = write_log(out, "export_log.txt", lines)
    return ExportResult(fmt, out / main, [Path(f) for f in files] + [out / "export.json", log], notes, log)
