"""The tables of a sequence fit: ``params.csv``, ``params.jsonl`` and ``thickness.png``.

One row per frame, rebuilt from the frame records at the end of every run. The leading
columns are those of docs/design.md ("Command line"): ``frame,file,converged,
thickness_nm,thickness_nm_stderr,t,roughness,exposure``; the other parameters, their
standard errors and the fit's own fields follow. A row is ``ok`` only when the frame was
fitted, converged, the fit itself says ``ok`` (where it reports it) and no parameter
jumps away from its neighbours (:func:`flag_jumps`); its ``warnings`` say why not.
"""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import atomic_path, json_text, write_text

__all__ = ["LEADING_COLUMNS", "TRAILING_COLUMNS", "JUMP_SIGMA", "JUMP_FLOOR", "JUMP_PARAMETERS", "flag_jumps",
           "row_ok", "write_tables", "read_table", "plot"]

# Leading columns of params.csv (docs/design.md, "Command line"); more follow them.
LEADING_COLUMNS = ("frame", "file", "converged", "thickness_nm", "thickness_nm_stderr", "t", "roughness", "exposure")
# Columns describing the frame and its fit, after the parameters and their errors.
TRAILING_COLUMNS = ("time_s", "ok", "status", "message", "warnings", "warm_start", "iterations", "residual_rms",
                    "reduced_chi2", "fit_time_s", "worker")
_RECORD_FIELDS = ("frame", "file", "converged", "status", "message", "warm_start", "iterations", "residual_rms",
                  "reduced_chi2", "fit_time_s", "worker", "time_s")

#: Parameters whose jump away from the neighbouring frames flags a frame: the film's
#: roughness and the camera gain (exposure) do not change from one frame to the next.
JUMP_PARAMETERS = ("roughness", "exposure")
#: A jump is flagged beyond this many standard deviations of the expected change.
JUMP_SIGMA = 5.0
#: Relative change always tolerated between neighbours (model error, not noise), in log units.
JUMP_FLOOR = 0.05
#: Neighbours on each side (nearest valid frames) that give the reference value of a frame.
JUMP_NEIGHBOURS = 2


def row_ok(rec: dict) -> bool:
    """True when a frame's result is trusted: fitted, converged, the fit's own ``ok``
    (when the fit reports one) and not flagged by :func:`flag_jumps`."""
    return (rec.get("status") == "ok" and bool(rec.get("converged")) and rec.get("fit_ok", True) is not False
            and not rec.get("jumps"))


def _log_values(records: list[dict], name: str) -> tuple[np.ndarray, np.ndarray]:
    """(log value, its standard error) of a positive parameter per record; NaN where absent."""
    y = np.full(len(records), np.nan)
    e = np.full(len(records), np.nan)
    for i, r in enumerate(records):
        v = r.get("params", {}).get(name) if r.get("status") == "ok" and r.get("converged") else None
        if v is not None and math.isfinite(v) and v > 0:
            y[i] = math.log(v)
            s = r.get("stderr", {}).get(name)
            e[i] = s / v if s is not None and math.isfinite(s) else 0.0
    return y, e


def _jumps_of(y: np.ndarray, e: np.ndarray) -> list[tuple[int, float, float]]:
    """(index, log jump, its sigma) of the values that jump away from their neighbours.

    Each valid value is compared with the median of its ``2 JUMP_NEIGHBOURS`` nearest
    valid neighbours (both sides, or one side at the ends of the sequence). The expected
    change combines the value's own standard error, the sequence's frame-to-frame scatter
    (1.4826 MAD of consecutive differences over sqrt 2, robust to the jumps themselves)
    and :data:`JUMP_FLOOR`.
    """
    idx = np.flatnonzero(np.isfinite(y))
    if len(idx) < 3:
        return []
    vals = y[idx]
    diffs = np.diff(vals)
    scatter = 1.4826 * float(np.median(np.abs(diffs - np.median(diffs)))) / math.sqrt(2.0)
    out = []
    order = np.arange(len(idx))
    for k, i in enumerate(idx):
        # the nearest valid frames, 2 x JUMP_NEIGHBOURS of them (one side only at the ends):
        # their median tolerates one outlier among them
        others = order[order != k]
        near = vals[others[np.argsort(np.abs(others - k), kind="stable")[: 2 * JUMP_NEIGHBOURS]]]
        if len(near) < 3:
            continue
        jump = float(vals[k] - np.median(near))
        sigma = math.sqrt(float(e[i]) ** 2 + scatter ** 2 + JUMP_FLOOR ** 2)
        if abs(jump) > JUMP_SIGMA * sigma:
            out.append((int(i), jump, sigma))
    return out


def flag_jumps(records: list[dict]) -> list[dict]:
    """Records with the frames whose roughness or gain jumps away from their neighbours flagged.

    A soap film's roughness and the camera's gain stay put from one frame to the next;
    a frame whose fit lands far from its neighbours' (a wrong interference order, a
    reflection, a frame of another scene) gets ``jumps`` (the parameters), a warning in
    words and ``ok`` false. The records given are not changed; flagged ones are copied.
    """
    out = list(records)
    for name in JUMP_PARAMETERS:
        y, e = _log_values(out, name)
        for i, jump, sigma in _jumps_of(y, e):
            rec = dict(out[i])
            ratio = math.exp(jump)
            rec["jumps"] = list(rec.get("jumps", [])) + [name]
            rec["warnings"] = list(rec.get("warnings", [])) + [
                f"{name} jumps away from the neighbouring frames (x{ratio:.3g}, {abs(jump) / sigma:.1f} sigma)"]
            out[i] = rec
    return out


def _columns(records: list[dict]) -> list[str]:
    names: list[str] = []
    for r in records:
        for k in r.get("params", {}):
            if k not in names:
                names.append(k)
    lead = list(LEADING_COLUMNS)
    others = sorted(k for k in names if k not in lead)
    errs = [f"{k}_stderr" for k in ("t", "roughness", "exposure", *others)
            if any(k in r.get("stderr", {}) for r in records)]
    return lead + others + errs + list(TRAILING_COLUMNS)


def _row(rec: dict, columns: list[str]) -> dict:
    row = {}
    p, e = rec.get("params", {}), rec.get("stderr", {})
    for c in columns:
        if c == "ok":
            row[c] = row_ok(rec)
        elif c == "warnings":
            row[c] = "; ".join(rec.get("warnings", [])) or None
        elif c in _RECORD_FIELDS:
            row[c] = rec.get(c)
        elif c.endswith("_stderr"):
            row[c] = e.get(c[: -len("_stderr")])
        else:
            row[c] = p.get(c)
    return row


def _csv_value(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_tables(out_dir: Path, records: list[dict]) -> tuple[Path, Path]:
    """``params.csv`` and ``params.jsonl``: one row per record, the columns of :func:`_columns`."""
    columns = _columns(records)
    rows = [_row(r, columns) for r in records]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_csv_value(row[c]) for c in columns])
    csv_path, jsonl_path = out_dir / "params.csv", out_dir / "params.jsonl"
    write_text(csv_path, buf.getvalue())
    lines = [json_text({c: row[c] for c in columns}, indent=None, allow_nan=False) for row in rows]
    write_text(jsonl_path, "\n".join(lines) + ("\n" if lines else ""))
    return csv_path, jsonl_path


def read_table(path: str | os.PathLike) -> list[dict]:
    """Read ``params.csv`` back: one dict per frame, numbers as floats, empty cells as None."""
    out = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            parsed: dict[str, Any] = {}
            for k, v in row.items():
                if v == "":
                    parsed[k] = None
                elif k in ("file", "status", "message", "worker", "warnings"):
                    parsed[k] = v
                elif v in ("true", "false"):
                    parsed[k] = v == "true"
                else:
                    try:
                        parsed[k] = int(v) if k in ("frame", "iterations") else float(v)
                    except ValueError:
                        parsed[k] = v
            out.append(parsed)
    return out


def plot(out_dir: Path, records: list[dict]) -> Path | None:
    """Thickness (with its standard error) against time, to ``OUT_DIR/thickness.png``."""
    import matplotlib

    matplotlib.use("Agg")  # before pyplot, and only when a plot is drawn (no display needed)
    import matplotlib.pyplot as plt

    from ._parameters import THICKNESSES

    keys = [k for k in THICKNESSES
            if any(k in r.get("params", {}) for r in records)]
    if not keys:
        return None
    fig, ax = plt.subplots(figsize=(7, 4), dpi=120)
    for k in keys:
        ok = [r for r in records if r.get("status") == "ok" and k in r.get("params", {})]
        for conv, style in ((True, "o"), (False, "x")):
            sel = [r for r in ok if bool(r.get("converged")) == conv]
            if not sel:
                continue
            t = [r["time_s"] for r in sel]
            y = [r["params"][k] for r in sel]
            err = [r.get("stderr", {}).get(k, float("nan")) for r in sel]
            err = [e if e == e else 0.0 for e in err]
            label = k.replace("_nm", "").replace("_", " ") + ("" if conv else " (not converged)")
            ax.errorbar(t, y, yerr=err, fmt=style, ms=3, lw=0.8, capsize=1.5, label=label)
    failed = [r["time_s"] for r in records if r.get("status") != "ok"]
    if failed:
        ax.plot(failed, [ax.get_ylim()[0]] * len(failed), "|", color="red", ms=10, label="failed frames")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("film thickness (nm)")
    ax.set_title(f"{len(records)} frames")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out_dir / "thickness.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


