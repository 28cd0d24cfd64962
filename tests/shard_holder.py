"""A minimal shard for the paused-holder drill: hold one machine's lease and deliver its jobs, fenced.

    python -m tests.shard_holder URL MACHINE LEASE_TIME OUT_DIR

Loop: claim the machine's next job with the lease's fencing token; when the claim succeeds, "deliver"
it (write OUT_DIR/<job id>, the side effect the drill counts) and record the delivery, fenced too;
then renew the lease. Each step is printed as a line, so the test knows where the process stands:
`holding TOKEN`, `idle` (between rounds, outside any transaction), `fenced JOB` (a claim the
database refused), `delivered JOB`, `lost` (the renewal failed: it stops).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from gateway.errors import JobError, StaleFence
from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.records import JobState
from gateway.shards.leases import LeaseTable


def main(url: str, machine: str, lease_time: float, out: Path) -> None:
    holder = f"holder-{machine}-{time.monotonic_ns()}"
    with LeaseTable(url, lease_time=lease_time) as table, PostgresJobQueue(url) as queue:
        lease = None
        while lease is None:
            lease = table.acquire(machine, holder)
            if lease is None:
                time.sleep(lease_time / 10)
        print(f"holding {lease.token}", flush=True)
        while True:
            job = queue.head(machine)
            if job is not None and job.state is JobState.QUEUED:
                try:
                    queue.start_sending(job.seq, fence=lease.fence)
                except JobError as exc:
                    print(f"fenced {job.id}: {exc}", flush=True)
                else:
                    (out / job.id).write_text(f"{holder} {lease.token}\n")  # the side effect
                    queue.delivered(job.seq, job.filename, fence=lease.fence)
                    print(f"delivered {job.id}", flush=True)
            try:
                lease = table.renew(lease)
            except StaleFence:
                print("lost", flush=True)
                return
            print("idle", flush=True)
            time.sleep(lease_time / 10)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], float(sys.argv[3]), Path(sys.argv[4]))
