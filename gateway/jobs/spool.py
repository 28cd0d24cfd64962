"""Where job files live between arrival and delivery: the spool under `<state>/jobs/spool/`."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from gateway.errors import JobError
from gateway.jobs.queue.store import Job, parse_job_id


class Spool:
    """Where job files live between arrival and delivery (and after it, for machines that answer remote
    requests from the queue: `keep` delivered programs per machine)."""

    def __init__(self, root: Path, keep: Mapping[str, int] | None = None) -> None:
        self.root = root
        self.keep = dict(keep or {})

    def kept(self, job: Job) -> Path:
        return self.root / "delivered" / job.machine / f"{job.id}.program"

    def delivered(self, job: Job) -> None:
        """The job was delivered: keep its program for remote requests where the machine wants that."""
        keep = self.keep.get(job.machine, 0)
        program = self.program(job)
        if keep <= 0 or not program.is_file():
            self.discard(job)
            return
        folder = self.kept(job).parent
        folder.mkdir(parents=True, exist_ok=True)
        os.replace(program, self.kept(job))
        self.received(job).unlink(missing_ok=True)
        kept = sorted(folder.glob("J*.program"), key=lambda p: _kept_seq(p.stem))
        for old in kept[: max(0, len(kept) - keep)]:
            old.unlink(missing_ok=True)

    def received(self, job: Job) -> Path:
        return self.root / f"{job.id}.received"

    def program(self, job: Job) -> Path:
        return self.root / f"{job.id}.program"

    def discard(self, job: Job) -> None:
        self.received(job).unlink(missing_ok=True)
        self.program(job).unlink(missing_ok=True)


def queue_path(state_dir: Path) -> Path:
    return state_dir / "jobs" / "queue.sqlite3"


def _kept_seq(stem: str) -> int:
    try:
        return parse_job_id(stem)
    except JobError:
        return -1
