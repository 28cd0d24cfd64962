"""What validation says about a program: a verdict made of located rejections and warnings.

Kept apart from the checks so that every check module (text, file names,
program structure) produces the same `Rejection`, and the job queue can import
the result types without the checks.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

from gateway.jobs.validation.estimate import Estimate

#: At most this many rejections are listed; the last one then says how many more there were.
MAX_REJECTIONS = 50


@dataclass(frozen=True, slots=True)
class Rejection:
    """One reason to refuse a program, located by 1-based line and column where that applies.

    `rule` is a stable machine-readable id: encoding, binary, character, xon-xoff,
    start-marker, end-marker, forbidden-marker, end-code, line-length, size, empty,
    program-name, file-name, syntax, forbidden-code, and `more` for the summary of
    rejections left out of a long list.
    """

    rule: str
    reason: str
    line: int | None = None
    column: int | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"rule": self.rule, "reason": self.reason, "line": self.line, "column": self.column}


@dataclass(frozen=True, slots=True)
class Verdict:
    """The outcome of validating one program.

    `program` is what will be delivered: the input bytes, unless a rule strips
    something (xon_xoff: strip). `warnings` include the estimate's notes.
    """

    accepted: bool
    rejections: tuple[Rejection, ...]
    warnings: tuple[str, ...]
    program: bytes
    estimate: Estimate | None
    program_name: str | None

    @property
    def reason(self) -> str:
        """Every rejection, one per line: for a reason file or a log line."""
        return "\n".join(r.reason for r in self.rejections)

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly (without the program bytes), for job records."""
        return {
            "accepted": self.accepted,
            "rejections": [r.as_dict() for r in self.rejections],
            "warnings": list(self.warnings),
            "estimate": None if self.estimate is None else self.estimate.as_dict(),
            "program_name": self.program_name,
        }


def capped(rejections: list[Rejection], limit: int = MAX_REJECTIONS) -> tuple[Rejection, ...]:
    """File-level rejections first, then by line and column (column-less last); capped at `limit`."""
    ordered = sorted(rejections, key=lambda r: (r.line or 0, r.column if r.column is not None else 1 << 30))
    if len(ordered) <= limit:
        return tuple(ordered)
    kept, rest = ordered[: limit - 1], ordered[limit - 1 :]
    by_rule = Counter(r.rule for r in rest)
    detail = ", ".join(f"{rule}: {n}" for rule, n in by_rule.most_common())
    return (*kept, Rejection("more", f"and {len(rest)} more rejections ({detail})"))
