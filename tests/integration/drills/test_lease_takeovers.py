"""Drill: failover by lease. A shard of `cnc-gateway fleet` (`shard: lease`) SIGKILLed again and again.

Issue 29's shard-kill drill with takeover (3 kills in `make test`, 30 in `make soak`), with real processes:
the fleet supervisor and its two `cnc-gateway run` shards, a simulator fleet of four laser cutters, one
PostgreSQL database for the queue and the leases (a 2-s lease), Mosquitto with the MQTT face and a
Sparkplug edge node per shard, and a Sparkplug host that reads with a decoder written from the
specification. Each round: the two shards serve two machines each (rebalanced); a program for one of
shard 2's machines goes into shard 1's inbox; shard 2 is SIGKILLed; shard 1 takes its machines over (each
connected on shard 1's /metrics: the failover time is measured from the kill to the last of them); a
program for a dead shard's machine goes in while it is down; the supervisor starts shard 2 again (after
5 s) and the machines are shared out again.

At the end: every job DELIVERED, each program uploaded to its machine's store once and byte for byte; no
machine's retained MQTT status ever said `standby` (a shard publishes nothing of a machine it does not
serve, so its Bad values never overwrote the serving shard's); after each kill the survivor's edge node
sent a DBIRTH for each of the dead shard's machines; no value a standby shard marked Bad (`served by another
shard`) reached the broker; no traceback.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import statistics
import time
import urllib.request
from collections import Counter
from pathlib import Path

import pytest

from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.records import JobState
from simulator.fleet import SimulatorFleet
from tests.fleet_rig import Fleet, write_fleet
from tests.integration.drills.conftest import Report, count
from tests.integration.jobs.conftest import PASSWORD_HASH, USER, Renames, in_thread, inbox_stor, program
from tests.integration.mqtt.conftest import Mosquitto, Recorder
from tests.integration.sparkplug.host import SparkplugHost
from tests.waiting import free_port, wait_until

LEASE = 2.0
S = JobState


def serving(port: int) -> set[str]:
    """The machines a shard serves and is connected to, from its /metrics (empty while it is down)."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2) as answer:
            text = answer.read().decode()
    except OSError:
        return set()
    return set(re.findall(r'cnc_gateway_machine_connected\{machine="([^"]+)"\} 1\.0', text))


@pytest.mark.timeout(1800)
async def test_a_killed_shards_machines_are_taken_over_by_lease_and_its_jobs_delivered_once(
    tmp_path: Path, postgres_url: str, renames: Renames, mosquitto: Mosquitto, drill_report: Report
) -> None:
    kills = count("lease_takeovers")
    http, opcua, inbox = free_port(), free_port(), free_port()
    sent: dict[str, bytes] = {}
    failovers: list[float] = []
    mqtt = Recorder(mosquitto.port, topics=["cnc/#"]).start()
    host = SparkplugHost(mosquitto.port).start()
    try:
        async with SimulatorFleet(4, store_root=tmp_path / "stores", tick=0.1) as sims:
            names = [p.name for p in sims.write_mappings(tmp_path)]
            machines = {p.stem for p in (tmp_path / n for n in names)}
            ports = {"HTTP_PORT": http, "OPCUA_PORT": opcua, "INBOX_PORT": inbox}
            accounts = f"[{{user: {USER}, password_hash: '{PASSWORD_HASH}'}}]"
            fleet_file = write_fleet(
                tmp_path, names, ports, shard="lease", restart="{initial: 5, max: 5}",
                inbox=f"{{host: 127.0.0.1, port: '${{INBOX_PORT}}', accounts: {accounts}}}",
                gateway=(
                    f"queue: {postgres_url}\nlease_time: {LEASE}\n"
                    f"mqtt: {{host: 127.0.0.1, port: {mosquitto.port}}}\n"
                    "sparkplug: {edge_node_id: 'gw-${CNC_SHARD_INDEX}'}\n"
                ),
            )  # fmt: skip

            async def upload(machine: str, name: str) -> None:
                data = program(name, lines=40)
                reply = await in_thread(inbox_stor, inbox, machine, name, data)
                assert reply.startswith("226 J") and f"queued for {machine}" in reply, reply
                sent[name] = data

            def shared_out() -> bool:
                one, two = serving(http), serving(http + 1)
                return len(one) == 2 and len(two) == 2 and one | two == machines

            async with Fleet(fleet_file) as fleet:
                for k in range(kills):
                    await wait_until(shared_out, timeout=90, interval=0.2,
                                     message=f"round {k + 1}: two machines on each shard")  # fmt: skip
                    theirs = sorted(serving(http + 1))
                    await upload(theirs[0], f"k{k}-before.nc")
                    mark = len(host.messages)
                    os.kill(fleet.starts(2)[-1], signal.SIGKILL)
                    killed = time.monotonic()
                    await wait_until(lambda: serving(http) == machines, timeout=60, interval=0.05,
                                     message=f"round {k + 1}: shard 1 serving every machine")  # fmt: skip
                    failovers.append(time.monotonic() - killed)
                    await upload(theirs[1], f"k{k}-while-down.nc")
                    host.wait(
                        lambda: {s.device for s in host.since(mark) if s.kind == "DBIRTH"  # noqa: B023
                                 and "/gw-1/" in s.topic} >= set(theirs),  # noqa: B023
                        timeout=30, message=f"round {k + 1}: gw-1's DBIRTHs of {theirs}",
                    )  # fmt: skip
                    await wait_until(lambda: len(fleet.starts(2)) > k + 1, timeout=60,  # noqa: B023
                                     message=f"round {k + 1}: shard 2 started again")  # fmt: skip

                def all_delivered() -> bool:
                    with PostgresJobQueue(postgres_url) as queue:
                        jobs = queue.list(limit=1000)
                    return len(jobs) == len(sent) and all(j.state is S.DELIVERED for j in jobs)

                await wait_until(all_delivered, timeout=120, interval=0.5, message="every job DELIVERED")
                fleet.proc.send_signal(signal.SIGTERM)
                assert await asyncio.wait_for(fleet.proc.wait(), 30) == 0
            landed = {p.name: p.read_bytes() for p in (tmp_path / "stores").glob("*/DATA/Programs/*.nc")}
    finally:
        mqtt.stop()
        host.stop()
    completed = Counter(renames.targets)
    twice = sorted(name for name, n in completed.items() if n > 1)
    wrong = sorted(name for name, data in sent.items() if landed.get(name) != data)
    statuses = [m for m in mqtt.messages if re.fullmatch(r"cnc/laser-\d+/status", m.topic)]
    states = Counter(json.loads(m.payload).get("state") for m in statuses)
    standby_values = [m.topic for m in mqtt.messages if b"another shard" in m.payload]
    drill_report(
        "lease takeovers",
        kills=kills,
        lease_time=LEASE,
        failover_median=round(statistics.median(failovers), 2),
        failover_max=round(max(failovers), 2),
        jobs=len(sent),
        duplicates=len(twice),
        wrong_or_missing=len(wrong),
        status_states=dict(states),
    )
    assert twice == [], f"programs uploaded twice: {twice}"
    assert wrong == [], f"programs missing or changed on the stores: {wrong}"
    assert states["connected"] > 0, states
    assert states["standby"] == 0, f"a standby shard published a machine's status: {states}"
    assert standby_values == [], f"a standby shard published its Bad values: {standby_values[:5]}"
    log = "".join(fleet.err)
    assert "Traceback" not in log, log[-3000:]
