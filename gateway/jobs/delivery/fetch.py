"""A job's program from the job queue's database, for a job whose program is not in this process's spool
(another shard's inbox took it in: docs/scaling.md, "Programs where every shard reads them").

The program is written into the spool where the transport reads it (spool/<id>.program), through a
temporary file beside it, a chunk at a time, and kept only if its size and SHA-256 are those validation
gave the job: bytes changed in the database are never sent. What goes wrong is a DeliveryError, as a
transport's would be: permanent (the job FAILED, its stored copy left in the database for an operator)
when the database holds no program or another one than was validated; transient (retried with backoff)
when the database cannot be read.
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from gateway.errors import DeliveryError, JobError, JobStoreError
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.records import Job

log = logging.getLogger("gateway.jobs.delivery")

# Runs blocking file and database work off the event loop (JobThreads.work).
Work = Callable[..., Awaitable[Any]]


class ProgramFetch:
    """`await fetch(job, path)`: the job's stored program, checked, as the file `path`."""

    def __init__(self, queue: JobStore, work: Work) -> None:
        self.queue = queue
        self.work = work

    async def __call__(self, job: Job, path: Path) -> None:
        await self.work(self.fetch, job, path)

    def fetch(self, job: Job, path: Path) -> None:
        """Blocking: the program into `path`, or DeliveryError (and nothing at `path`)."""
        temp = path.with_name(f"{path.name}.fetching")
        digest = hashlib.sha256()
        size = 0
        try:
            with temp.open("wb") as f:
                for chunk in self.queue.program_chunks(job.seq):
                    digest.update(chunk)
                    size += len(chunk)
                    f.write(chunk)
                f.flush()
                os.fsync(f.fileno())
        except JobStoreError as exc:  # the database is away: try again later
            temp.unlink(missing_ok=True)
            raise DeliveryError(f"the program cannot be read from the job queue: {exc}") from None
        except JobError as exc:
            temp.unlink(missing_ok=True)
            raise DeliveryError(f"not in the spool, and {exc}", permanent=True) from None
        except OSError as exc:
            temp.unlink(missing_ok=True)
            raise DeliveryError(f"cannot write {temp}: {exc.strerror or exc}") from None
        found = digest.hexdigest()
        if size != job.program_size or found != job.program_sha256:
            temp.unlink(missing_ok=True)
            raise DeliveryError(
                f"the program read back from the job queue is not the one validated ({size} bytes, SHA-256"
                f" {found}; validated: {job.program_size} bytes, {job.program_sha256}): not sent; the"
                f" job queue keeps it (cnc-gateway jobs retry {job.id} once it is put right)",
                permanent=True,
            )
        os.replace(temp, path)
        log.info(
            "%s: %s's program read from the job queue (%d bytes, SHA-256 checked)", job.machine, job.id, size
        )
