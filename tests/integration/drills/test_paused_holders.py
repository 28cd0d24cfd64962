"""A lease holder paused past its lease (SIGSTOP) cannot act on its machine when it wakes (SIGCONT).

The drill of issue 29 (3 tries in `make test`, 30 in `make soak`: conftest.py's counts): a real
process (tests/shard_holder.py) holds a machine's lease and delivers its jobs with the lease's
fencing token. It is stopped; the test waits until the
database says the lease ran out, another holder takes the machine (a greater token) and a job is
queued for it; the stopped process is continued. It must try to claim the job, be refused by the
database, find its lease lost and stop, with no side effect (no delivery written, the job untouched);
the new holder then claims and delivers the job once.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.records import JobState
from gateway.shards.leases import LeaseTable
from tests.integration.drills.conftest import Report, count

ROOT = Path(__file__).resolve().parents[3]
LEASE = 2.0  # s: long enough that a loaded machine renews in time, short enough for 30 tries


def read_until(proc: subprocess.Popen[str], prefix: str, seen: list[str]) -> str:
    """The holder's lines up to the first that starts with `prefix` (the test's timeout bounds it)."""
    assert proc.stdout is not None
    while True:
        line = proc.stdout.readline()
        assert line, f"the holder ended before saying {prefix!r}: {seen}"
        seen.append(line.strip())
        if line.startswith(prefix):
            return line.strip()


def wait_expired(table: LeaseTable, machine: str, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while any(lease.live for lease in table.leases() if lease.machine == machine):
        assert time.monotonic() < deadline, "the paused holder's lease never expired"
        time.sleep(0.05)


@pytest.mark.timeout(1800)
def test_a_holder_paused_past_its_lease_makes_no_side_effect_when_it_wakes(
    postgres_url: str, tmp_path: Path, drill_report: Report
) -> None:
    tries = count("paused_holders")
    refused = 0
    side_effects = tmp_path / "controller"
    side_effects.mkdir()
    delivered_before: list[str] = []
    with LeaseTable(postgres_url, lease_time=LEASE) as table, PostgresJobQueue(postgres_url) as queue:
        for attempt in range(tries):
            machine = f"laser-{attempt}"
            proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "tests.shard_holder",
                    postgres_url,
                    machine,
                    str(LEASE),
                    str(side_effects),
                ],
                cwd=ROOT,
                stdout=subprocess.PIPE,
                text=True,
            )
            seen: list[str] = []
            try:
                old_token = int(read_until(proc, "holding", seen).split()[1])
                before = queue.receive(machine, "before.nc", 1, f"before-{attempt}")
                queue.accept(before.seq, duplicates="skip", program_size=1, program_sha256=before.sha256)
                read_until(proc, f"delivered {before.id}", seen)  # a live holder does deliver
                read_until(proc, "idle", seen)  # between rounds: no transaction open
                os.kill(proc.pid, signal.SIGSTOP)
                wait_expired(table, machine)
                new = table.acquire(machine, "gw-new")
                assert new is not None and new.token > old_token
                job = queue.receive(machine, "part.nc", 1, f"sha-{attempt}")
                queue.accept(job.seq, duplicates="skip", program_size=1, program_sha256=job.sha256)
                os.kill(proc.pid, signal.SIGCONT)
                read_until(proc, "lost", seen)
                assert proc.wait(timeout=30) == 0
            finally:
                if proc.poll() is None:
                    os.kill(proc.pid, signal.SIGCONT)
                    proc.kill()
                    proc.wait()
            assert any(line.startswith(f"fenced {job.id}") for line in seen), seen  # it did try
            refused += 1
            assert [line for line in seen if line.startswith("delivered")] == [f"delivered {before.id}"]
            delivered_before.append(before.id)
            assert sorted(p.name for p in side_effects.iterdir()) == delivered_before  # none after the pause
            after = queue.get(job.seq)
            assert after.state is JobState.QUEUED and after.attempts == 0
            claimed = queue.start_sending(job.seq, fence=new.fence)  # the new holder delivers it, once
            assert claimed.attempts == 1
            assert queue.delivered(job.seq, "part.nc", fence=new.fence).state is JobState.DELIVERED
            table.release(new)
    after_pause = len(list(side_effects.iterdir())) - len(delivered_before)
    drill_report(
        "paused holders", tries=tries, claims_refused=refused, side_effects_after_the_pause=after_pause
    )
    assert refused == tries and after_pause == 0
