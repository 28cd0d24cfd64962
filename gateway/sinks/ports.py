"""What the console needs from the rest of the gateway, as Protocols that app.py wires in.

The web sink reads the tree directly (like every sink) and writes and calls
through `Machine.write_node`/`Machine.call_method`. Everything else reaches it
through these ports, implemented elsewhere and handed in by gateway/app.py, so
that this package imports nothing of the job queue, the alarms, the audit store
or the OPC UA server:

| port | implemented by |
|---|---|
| `JobsPort` | `gateway.jobs.queue_port.QueuePort` (the same inbox staging, validation and queue as FTP) |
| `AlarmsPort` | `gateway.alarms.service.AlarmService` (the managers' role checks and audit) |
| `AuditPort` | `gateway.audit.trail.AuditTrail` (reads the audit table) |
| `TrustPort` | `gateway.sinks.opcua.security.TrustList` (the OPC UA server's pki folders) |
| `GatewayPort` | `gateway.app.Gateway` (diagnostics, readiness) |

Records cross as JSON-ready mappings, so that neither side needs the other's classes.
Refusals are the RequestErrors of gateway/errors.py (NotFound, InvalidState, …).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Protocol

from gateway.model.audit import AuditEntry
from gateway.model.context import WriteContext

Record = Mapping[str, Any]


class SubmitReply(Protocol):
    """The job service's answer to a submission (the FTP inbox gets the same one as its reply)."""

    @property
    def ok(self) -> bool: ...

    @property
    def message(self) -> str: ...

    @property
    def job_id(self) -> str | None: ...


class JobsPort(Protocol):
    @property
    def job_machines(self) -> Collection[str]: ...

    @property
    def max_upload(self) -> int: ...

    def staging_file(self) -> Path:
        """A fresh file name in the inbox's staging folder, for an upload as it streams in."""
        ...

    async def submit_file(
        self,
        machine: str,
        filename: str,
        path: Path,
        *,
        size: int,
        sha256: str,
        user: str,
        origin: str,
        priority: int = 0,
    ) -> SubmitReply:
        """Validate and queue the program at `path` (the service takes the file over)."""
        ...

    async def list_jobs(
        self, *, machine: str | None, states: Sequence[str], limit: int
    ) -> Sequence[Record]: ...

    async def show_job(self, job_id: str) -> Record:
        """The job's record with `history` (its transitions); NotFound if there is none."""
        ...

    async def retry_job(self, job_id: str, by: str) -> Record: ...

    async def cancel_job(self, job_id: str, by: str) -> Record: ...

    async def prioritize_job(self, job_id: str, priority: int) -> Record: ...

    async def job_counts(self) -> dict[str, dict[str, int]]:
        """Jobs per machine and state (for /metrics)."""
        ...


class AlarmsPort(Protocol):
    @property
    def alarm_machines(self) -> Collection[str]: ...

    def active_alarms(self, machine: str | None = None) -> Sequence[Record]:
        """The occurrences still listed (active, or waiting for an acknowledgement or confirmation)."""
        ...

    async def alarm_history(self, machine: str | None, limit: int) -> Sequence[Record]: ...

    def acknowledge_role(self, machine: str) -> str | None: ...

    async def acknowledge_alarm(
        self, machine: str, occurrence: int, ctx: WriteContext, comment: str
    ) -> Record: ...

    async def confirm_alarm(
        self, machine: str, occurrence: int, ctx: WriteContext, comment: str
    ) -> Record: ...


class AuditPort(Protocol):
    async def query_audit(
        self,
        *,
        machine: str | None = None,
        user: str | None = None,
        origin: str | None = None,
        kind: str | None = None,
        since: datetime | None = None,
        limit: int = 100,
    ) -> list[AuditEntry]: ...


class TrustPort(Protocol):
    def certificates(self) -> Sequence[Record]:
        """Every certificate in trusted/ and rejected/: name, state, subject, thumbprint, URIs, validity."""
        ...

    def trust(self, name: str) -> Record:
        """Move a certificate from rejected/ to trusted/; NotFound if there is none of that name."""
        ...

    def reject(self, name: str) -> Record:
        """Move a certificate from trusted/ to rejected/."""
        ...


class GatewayPort(Protocol):
    def diagnostics(self) -> Mapping[str, Any]:
        """gateway/diagnostics.py's snapshot: hub backlogs, sinks' queues and drops, machines, GC."""
        ...

    def not_ready(self) -> list[str]:
        """What keeps the gateway from being ready (empty: ready)."""
        ...


@dataclass(frozen=True, slots=True)
class Ports:
    gateway: GatewayPort
    jobs: JobsPort | None = None
    alarms: AlarmsPort | None = None
    audit: AuditPort | None = None
    trust: TrustPort | None = None
