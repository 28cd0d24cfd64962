"""Job state, shown everywhere the tree is: per-machine `Jobs/...` variables and job events.

The variables are gateway-owned (internal) variables, so the OPC UA sink shows
them under the machine's `Jobs` object and MQTT as topics, with no job-specific
code in any sink. Events go on the tree's event bus:

- `jobs/<job-id>` (retained): the job's whole record, with its progress;
- `jobs/events`: one event per state change, in order.

Retained records would pile up on the broker, one per job ever uploaded. Only
the machine's `mqtt_retained_jobs` most recently ended jobs keep theirs: when
one more ends, the oldest ended job's record is withdrawn (an empty retained
message). Jobs that ended before this run are only known if the service hands
them to `ended_before`.

Everything is derived from the queue (which the CLI may change from another
process), so the service only has to say "something changed" and call `sync`.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from typing import Any

from gateway.config.jobs import JobsConfig
from gateway.jobs.queue.records import TERMINAL
from gateway.jobs.queue.store import Job, JobState, Transition
from gateway.model.events import Event
from gateway.model.tree import Machine, VariableNode, VariableTree

NEVER = datetime(1601, 1, 1, tzinfo=UTC)
PROGRESS_EVERY = 0.5  # s between progress events of one job


def describe(job: Job | None) -> str:
    return f"{job.id} {job.filename}" if job is not None else ""


class JobVariables:
    """One machine's `Jobs/...` variables."""

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        add = machine.add_internal
        self.queue_length = add("Jobs/QueueLength", "UInt32", "Jobs waiting for delivery or being sent", 0)
        self.current = add(
            "Jobs/Current", "String", "The job being sent to the controller: id and file name", ""
        )
        self.progress = add("Jobs/Progress", "Double", "Share of the current job sent, in percent", 0.0)
        self.last_delivered = add(
            "Jobs/LastDelivered", "String", "The last job delivered: id and file name", ""
        )
        self.last_delivered_at = add(
            "Jobs/LastDeliveredAt", "DateTime", "When the last job was delivered", NEVER
        )
        self.last_failed = add(
            "Jobs/LastFailed", "String", "The last job that failed (dead letter): id and file name", ""
        )
        self.last_failed_reason = add("Jobs/LastFailedReason", "String", "Why the last failed job failed", "")
        self.last_rejected = add(
            "Jobs/LastRejected", "String", "The last job refused by validation: id and file name", ""
        )
        self.last_rejected_reason = add("Jobs/LastRejectedReason", "String", "Why it was refused", "")
        self.failed_count = add("Jobs/FailedCount", "UInt32", "FAILED jobs waiting for a retry or cancel", 0)
        self.block = add(
            "Jobs/Block",
            "Int32",
            "Drip-feed: the program line the controller is estimated to run (0: none)",
            0,
        )
        self.lead = add(
            "Jobs/LeadSeconds",
            "Double",
            "Drip-feed: seconds of cutting estimated in the controller's buffer",
            0.0,
        )
        self.remaining = add(
            "Jobs/RemainingSeconds", "Double", "Drip-feed: estimated run time left, in seconds", 0.0
        )
        self.held = add(
            "Jobs/Held",
            "String",
            "Why nothing is being sent now: DC3, waiting for DC1, paused (or empty)",
            "",
        )
        self.estimate = add(
            "Jobs/LastEstimatedSeconds",
            "Double",
            "Estimated run time of the last job delivered, in seconds",
            0.0,
        )

    def set(self, node: VariableNode, value: Any) -> None:
        self.machine.set_internal(node, value)


class JobPublisher:
    def __init__(self, tree: VariableTree, machines: Mapping[str, JobsConfig]) -> None:
        self.tree = tree
        self.vars = {name: JobVariables(tree.machines[name]) for name in machines}
        self._progress_at: dict[int, float] = {}
        # Per machine: how many ended jobs keep a retained record, and those that do (seq -> id),
        # oldest first.
        self.keep = {name: jobs.mqtt_retained_jobs for name, jobs in machines.items()}
        self._ended: dict[str, OrderedDict[int, str]] = {name: OrderedDict() for name in self.vars}

    def summary(
        self,
        machine: str,
        *,
        waiting: int,
        failed: int,
        current: Job | None,
        delivered: Job | None,
        failed_job: Job | None,
        rejected: Job | None,
    ) -> None:
        """The machine's variables from the queue's point of view."""
        v = self.vars[machine]
        v.set(v.queue_length, waiting)
        v.set(v.failed_count, failed)
        v.set(v.current, describe(current))
        if current is None:
            v.set(v.progress, 0.0)
            v.set(v.block, 0)
            v.set(v.lead, 0.0)
            v.set(v.remaining, 0.0)
            v.set(v.held, "")
        if delivered is not None:
            v.set(v.last_delivered, describe(delivered))
            v.set(v.last_delivered_at, delivered.delivered_at or delivered.updated_at)
            seconds = (delivered.estimate or {}).get("seconds")
            v.set(v.estimate, float(seconds) if isinstance(seconds, (int, float)) else 0.0)
        if failed_job is not None:
            v.set(v.last_failed, describe(failed_job))
            v.set(v.last_failed_reason, failed_job.reason)
        if rejected is not None:
            v.set(v.last_rejected, describe(rejected))
            v.set(v.last_rejected_reason, rejected.reason)

    def job(self, job: Job, progress: float | None = None, detail: Mapping[str, Any] | None = None) -> None:
        """The job's retained record (with a drip-feed's block, lead and time left while it is sent)."""
        record = job.as_dict()
        if progress is None:
            progress = 100.0 if job.state is JobState.DELIVERED else 0.0
        record["progress"] = round(progress, 1)
        if detail is not None:
            record.update(detail)
        self.tree.events.publish(Event(job.machine, f"jobs/{job.id}", record, retain=True))
        self._retire(job)

    def ended_before(self, jobs: Iterable[Job]) -> None:
        """Ended jobs whose records a previous run may have left retained, oldest first (at start-up)."""
        for job in jobs:
            self._retire(job)

    def _retire(self, job: Job) -> None:
        """Track which ended jobs keep a retained record; withdraw the oldest beyond the machine's limit."""
        ended = self._ended.get(job.machine)
        if ended is None:
            return
        if job.state not in TERMINAL:  # running again (a retry): its record is live, not an ended one
            ended.pop(job.seq, None)
            return
        ended.setdefault(job.seq, job.id)  # a job republished while ended keeps its place
        while len(ended) > self.keep[job.machine]:
            _, old = ended.popitem(last=False)
            self.tree.events.publish(Event(job.machine, f"jobs/{old}", None, retain=True))

    def transition(self, t: Transition, job: Job | None) -> None:
        payload: dict[str, Any] = {
            "job": t.job_id,
            "state": t.state.value,
            "previous": t.previous.value if t.previous is not None else None,
            "reason": t.reason,
        }
        if job is not None:
            payload["filename"] = job.filename
            payload["user"] = job.user
        self.tree.events.publish(Event(t.machine, "jobs/events", payload, ts=t.ts))

    def progress(self, job: Job, sent: int, total: int, detail: Mapping[str, Any] | None = None) -> None:
        """Bytes sent so far, at most every PROGRESS_EVERY seconds per job (and always the last)."""
        percent = min(100.0, 100.0 * sent / total) if total else 100.0
        now = time.monotonic()
        if sent < total and now - self._progress_at.get(job.seq, 0.0) < PROGRESS_EVERY:
            return
        self._progress_at[job.seq] = now
        v = self.vars.get(job.machine)
        if v is not None:
            v.set(v.progress, round(percent, 1))
            if detail is not None:
                v.set(v.block, detail.get("block") or 0)
                v.set(v.lead, detail.get("lead") or 0.0)
                v.set(v.remaining, detail.get("remaining") or 0.0)
                v.set(v.held, detail.get("held") or "")
        self.job(job, percent, detail)

    def forget(self, job: Job) -> None:
        self._progress_at.pop(job.seq, None)
