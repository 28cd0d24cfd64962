"""Jobs as the queue stores them: the states, the transitions allowed between them, the records. Pure.

RECEIVED -> VALIDATED -> QUEUED -> SENDING -> DELIVERED
     \\-> REJECTED    \\-> REJECTED  \\-> CANCELLED  \\-> QUEUED (retry later) | FAILED
FAILED / CANCELLED -> QUEUED (retry from the CLI)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from enum import Enum
from typing import Any

from gateway.errors import JobError


class JobState(str, Enum):
    RECEIVED = "RECEIVED"
    VALIDATED = "VALIDATED"
    QUEUED = "QUEUED"
    SENDING = "SENDING"
    DELIVERED = "DELIVERED"
    REJECTED = "REJECTED"
    FAILED = "FAILED"
    CANCELLED = "CANCELLED"

    def __str__(self) -> str:
        return self.value


S = JobState
TERMINAL = frozenset({S.DELIVERED, S.REJECTED, S.FAILED, S.CANCELLED})
ALLOWED: dict[JobState, frozenset[JobState]] = {
    S.RECEIVED: frozenset({S.VALIDATED, S.REJECTED, S.CANCELLED}),
    S.VALIDATED: frozenset({S.QUEUED, S.REJECTED, S.CANCELLED}),
    S.QUEUED: frozenset({S.SENDING, S.CANCELLED}),
    S.SENDING: frozenset({S.DELIVERED, S.QUEUED, S.FAILED}),
    S.FAILED: frozenset({S.QUEUED}),
    S.CANCELLED: frozenset({S.QUEUED}),
    S.REJECTED: frozenset(),
    S.DELIVERED: frozenset(),
}


def job_id(seq: int) -> str:
    return f"J{seq:06d}"


def parse_job_id(text: str) -> int:
    """'J000042', 'j42' or '42' -> 42; JobError otherwise."""
    raw = text.strip()
    digits = raw[1:] if raw[:1] in ("J", "j") else raw
    if not digits.isdigit() or int(digits) <= 0:
        raise JobError(f"{text!r} is not a job id (like J000042)")
    return int(digits)


def iso_utc(clock: float) -> str:
    return datetime.fromtimestamp(clock, UTC).isoformat(timespec="milliseconds")


def parse_ts(text: str | None) -> datetime | None:
    return datetime.fromisoformat(text) if text else None


@dataclass(frozen=True, slots=True)
class Job:
    """One job as stored. `received_at`/`updated_at` are UTC; `estimate` is the validator's dict."""

    seq: int
    machine: str
    filename: str
    user: str
    origin: str
    size: int
    sha256: str
    priority: int
    state: JobState
    reason: str
    attempts: int
    next_attempt_at: float | None
    received_at: datetime
    updated_at: datetime
    program_name: str | None
    program_size: int | None
    program_sha256: str | None
    estimate: dict[str, Any] | None
    warnings: tuple[str, ...]
    delivered_name: str | None
    delivered_at: datetime | None
    rev: int

    @property
    def id(self) -> str:
        return job_id(self.seq)

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly record, as MQTT and `jobs show --json` present it."""
        out = asdict(self)
        out.pop("rev")
        out["id"] = self.id
        out["state"] = self.state.value
        out["warnings"] = list(self.warnings)
        for key in ("received_at", "updated_at", "delivered_at"):
            value = out[key]
            out[key] = value.isoformat() if value is not None else None
        return out


@dataclass(frozen=True, slots=True)
class Transition:
    id: int
    seq: int
    machine: str
    state: JobState
    previous: JobState | None
    reason: str
    ts: datetime

    @property
    def job_id(self) -> str:
        return job_id(self.seq)
