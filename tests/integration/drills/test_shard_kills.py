"""Drill: a shard of `cnc-gateway fleet` SIGKILLed again and again while the fleet takes in and delivers jobs.

Issue 29's shard-kill drill for static shards (3 kills in `make test`, 30 in `make soak`), with real
processes: the fleet supervisor and its two `cnc-gateway run` shards, a simulator fleet of two laser
cutters, one PostgreSQL job queue. Each round a program for shard 2's machine goes into shard 1's inbox,
shard 2 is killed at a random moment (the seed is printed; `CNC_DRILL_SEED` replays it), possibly mid-
delivery; while it is down another program for its machine and one for shard 1's go in through shard 1.
The supervisor starts shard 2 again. At the end every job is DELIVERED, each program reached its machine's
store once (one completed upload: the store's RNTO log) and byte for byte, and no shard logged a traceback.
What static shards cannot do, and this drill does not ask: serve a dead shard's machines from another shard
before it is back (lease-served machines, docs/scaling.md).
"""

from __future__ import annotations

import asyncio
import os
import random
import signal
import socket
from collections import Counter
from pathlib import Path

import pytest

from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.records import JobState
from simulator.fleet import SimulatorFleet
from tests.fleet_rig import Fleet, write_fleet
from tests.integration.drills.conftest import Report, count
from tests.integration.jobs.conftest import PASSWORD_HASH, USER, Renames, in_thread, inbox_stor, program
from tests.waiting import free_port, wait_until

S = JobState


def listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    except OSError:
        return False
    return True


@pytest.mark.timeout(1800)
async def test_jobs_are_delivered_once_while_a_shard_is_killed_again_and_again(
    tmp_path: Path, postgres_url: str, renames: Renames, drill_report: Report
) -> None:
    kills = count("shard_kills")
    seed = int(os.environ.get("CNC_DRILL_SEED") or random.randrange(2**31))
    rng = random.Random(seed)
    http, opcua, inbox = free_port(), free_port(), free_port()
    sent: dict[str, bytes] = {}  # program name -> bytes, every one the inbox accepted
    async with SimulatorFleet(2, store_root=tmp_path / "stores", tick=0.1) as sims:
        names = [p.name for p in sims.write_mappings(tmp_path)]
        ports = {"HTTP_PORT": http, "OPCUA_PORT": opcua, "INBOX_PORT": inbox}
        accounts = f"[{{user: {USER}, password_hash: '{PASSWORD_HASH}'}}]"
        fleet_file = write_fleet(
            tmp_path, names, ports,
            inbox=f"{{host: 127.0.0.1, port: '${{INBOX_PORT}}', accounts: {accounts}}}",
            gateway=f"queue: {postgres_url}\n",
        )  # fmt: skip

        async def upload(machine: str, name: str) -> None:
            data = program(name, lines=rng.randrange(3, 400))
            reply = await in_thread(inbox_stor, inbox, machine, name, data)
            assert reply.startswith("226 J") and f"queued for {machine}" in reply, reply
            sent[name] = data

        mid_delivery = 0
        async with Fleet(fleet_file) as fleet:
            await wait_until(lambda: fleet.said("every shard started"), timeout=60, message="every shard up")
            await wait_until(lambda: listening(inbox), timeout=60, message="shard 1's inbox")
            for k in range(kills):
                await upload("laser-002", f"k{k}-before.nc")
                await asyncio.sleep(rng.uniform(0.0, 0.6))  # the kill lands anywhere in the job's way
                with PostgresJobQueue(postgres_url) as queue:
                    sending = any(j.state is S.SENDING for j in queue.list(limit=1000))
                mid_delivery += sending
                os.kill(fleet.starts(2)[-1], signal.SIGKILL)
                await upload("laser-002", f"k{k}-while-down.nc")  # shard 1 takes it for the dead shard
                await upload("laser-001", f"k{k}-other.nc")  # shard 1's own machine goes on
                await wait_until(lambda: len(fleet.starts(2)) > k + 1, timeout=30,  # noqa: B023 - read at once
                                 message=f"kill {k + 1}: shard 2 started again")  # fmt: skip

            def all_delivered() -> bool:
                with PostgresJobQueue(postgres_url) as queue:
                    jobs = queue.list(limit=1000)
                return len(jobs) == len(sent) and all(j.state is S.DELIVERED for j in jobs)

            await wait_until(all_delivered, timeout=120, interval=0.5, message="every job DELIVERED")
            fleet.proc.send_signal(signal.SIGTERM)
            assert await asyncio.wait_for(fleet.proc.wait(), 30) == 0
        stores = tmp_path / "stores"
        landed = {p.name: p.read_bytes() for p in stores.glob("*/DATA/Programs/*.nc")}
    completed = Counter(renames.targets)
    twice = sorted(name for name, n in completed.items() if n > 1)
    wrong = sorted(name for name, data in sent.items() if landed.get(name) != data)
    drill_report(
        "shard kills",
        seed=seed,
        kills=kills,
        jobs=len(sent),
        delivered=len(sent) - len(wrong),
        duplicates=len(twice),
        wrong_or_missing=len(wrong),
        caught_mid_delivery=mid_delivery,
    )
    assert twice == [], f"seed {seed}: programs uploaded twice: {twice}"
    assert wrong == [], f"seed {seed}: programs missing or changed on the stores: {wrong}"
    assert set(completed) >= set(sent), f"seed {seed}: uploads completed {completed}"
    log = "".join(fleet.err)
    assert "Traceback" not in log, log[-3000:]
