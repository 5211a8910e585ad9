"""The report of a capture check: one row per check, and its plain-text table.

See ``docs/design.md``, "Capture protocols".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

__all__ = ["Status", "PASS", "FAIL", "WARN", "SKIP", "CheckResult", "CaptureReport", "format_table"]

Status = Literal["PASS", "FAIL", "WARN", "SKIP"]

PASS: Status = "PASS"
FAIL: Status = "FAIL"
WARN: Status = "WARN"
SKIP: Status = "SKIP"


@dataclass
class CheckResult:
    """One row of the report: ``check`` name, ``status`` (PASS/FAIL/WARN/SKIP), ``reason``."""

    check: str
    status: str
    reason: str

    def as_dict(self) -> dict:
        return {"check": self.check, "status": self.status, "reason": self.reason}


@dataclass
class CaptureReport:
    """All check results of one capture folder.

    Attributes:
        protocol: the protocol's name.
        folder: the folder checked.
        results: the :class:`CheckResult` rows, in the order they ran.
        files: role -> list of file names matched.
        measurements: numbers measured on the way (shift in pixels, stops, ...).
    """

    protocol: str
    folder: str
    results: list[CheckResult] = field(default_factory=list)
    files: dict = field(default_factory=dict)
    measurements: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """True when no check failed (warnings do not fail a capture)."""
        return not any(r.status == FAIL for r in self.results)

    def failed(self) -> list[CheckResult]:
        return [r for r in self.results if r.status == FAIL]

    def add(self, check: str, status: str, reason: str) -> None:
        self.results.append(CheckResult(check, status, reason))

    def as_dict(self) -> dict:
        return {
            "protocol": self.protocol,
            "folder": self.folder,
            "passed": self.passed,
            "results": [r.as_dict() for r in self.results],
            "files": self.files,
            "measurements": self.measurements,
        }


def format_table(report: CaptureReport) -> str:
    """The report as a plain-text table: check, status, reason; then a verdict line."""
    rows = [(r.check, r.status, r.reason) for r in report.results]
    w0 = max([len("check")] + [len(r[0]) for r in rows])
    lines = [f"capture {report.folder} against protocol {report.protocol!r}", "",
             f"{'check':<{w0}}  status  reason"]
    lines.append(f"{'-' * w0}  ------  {'-' * 40}")
    for c, s, why in rows:
        lines.append(f"{c:<{w0}}  {s:<6}  {why}")
    n_fail = len(report.failed())
    lines.append("")
    lines.append("PASS" if report.passed else f"FAIL: {n_fail} check(s) failed")
    return "\n".join(lines)
