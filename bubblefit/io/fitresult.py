"""Reading a fit result: the JSON that ``bubblefit fit --json`` writes, and the paths it names.

``bubblefit export`` and ``bubblefit report`` start from such a file; both read it here,
so that a file that is not a fit result, or one whose named file is missing, gets the
same one clear line.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import InputError

__all__ = ["FIT_KEYS", "read_fit_result", "named_path"]

#: Keys every fit result has (docs/design.md, "Command line", ``bubblefit fit``).
FIT_KEYS = ("params", "stderr", "converged", "ok", "thickness", "model")


def read_fit_result(path: str | os.PathLike) -> dict:
    """The fit result at ``path`` as a dict; :class:`InputError` when it is missing,
    unreadable, not JSON, or lacks any of :data:`FIT_KEYS`."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"fit result {path} does not exist") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path} is not a fit result: {type(exc).__name__}: {exc}") from None
    missing = [k for k in FIT_KEYS if not isinstance(data, dict) or k not in data]
    if missing or not isinstance(data["params"], dict):
        raise InputError(f"{path} is not a fit result of `bubblefit fit --json` (it lacks "
                         f"{', '.join(missing) or 'a params table'})")
    return data


def named_path(value: str | None, result: str | os.PathLike, what: str, *, must_exist: bool = True) -> str | None:
    """A path the fit result names: as given when it exists (or is absolute), else relative
    to the result's folder; None for none. :class:`InputError` when it must exist and does not."""
    if not value:
        return None
    p = Path(value)
    if not p.exists() and not p.is_absolute():
        p = Path(result).resolve().parent / p
    if must_exist and not p.is_file():
        raise InputError(f"the {what} {value} named by the fit result {result} does not exist")
    return str(p)
