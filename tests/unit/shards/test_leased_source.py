"""LeasedSource (`shard: lease`): a machine's source runs only while this process holds its lease.

With a real LeaseHolder on PostgreSQL and a source of the test's own (it counts its runs and writes):
the machine is on standby until the lease arrives (status, Served, ServiceLevel, values BadOutOfService,
not `served` for the faces); served while held; a write on standby is refused, audited, and never reaches
the source; a lease taken by another holder stops the source and puts the machine back on standby.
"""

from __future__ import annotations

import asyncio
import contextlib
from datetime import UTC, datetime
from typing import Any, Self

import pytest

from gateway.config.mapping import MachineMapping
from gateway.errors import ControllerUnavailable
from gateway.model.audit import AuditEntry
from gateway.model.context import WriteContext
from gateway.model.sample import ReadBack
from gateway.model.status import STANDBY_STATUS
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.shards.holder import LeaseHolder
from gateway.shards.leases import LeaseTable
from gateway.sources.leased import SERVED_LEVEL, STANDBY_LEVEL, LeasedSource
from tests.waiting import wait_until

LEASE = 2.0


class CountingSource:
    """A controller that is always there: connects when run, one value, takes every write."""

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self.runs = 0
        self.running = False
        self.writes: list[Any] = []

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None

    async def run(self) -> None:
        self.runs += 1
        self.running = True
        try:
            self.machine.status.connected()
            self.machine.ingest(self.machine.nodes["Feed"], 42.0, datetime.now(UTC))
            await asyncio.Event().wait()
        finally:
            self.running = False
            self.machine.status.disconnected("stopped")

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        self.writes.append(raw)
        return None


def one_machine() -> VariableTree:
    mapping = MachineMapping.model_validate(
        {
            "machine": "laser",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
            "variables": [{"path": "Feed", "source": "s", "type": "Double", "access": "readwrite"}],
        }
    )
    tree = VariableTree([mapping.definition()])
    tree.access.configure(["viewer", "operator"], enabled=False)
    return tree


@pytest.fixture
def audited() -> list[AuditEntry]:
    return []


async def test_the_source_runs_only_while_the_lease_is_held(
    postgres_url: str, audited: list[AuditEntry]
) -> None:
    tree = one_machine()
    tree.audit_sinks.append(audited.append)
    machine = tree.machines["laser"]
    inner = CountingSource(machine)
    with LeaseTable(postgres_url, lease_time=60) as other:  # another shard holds the machine first
        other.join("other")
        theirs = other.acquire("laser", "other")
        assert theirs is not None
        holder = LeaseHolder(postgres_url, "us", ["laser"], lease_time=LEASE)
        source = LeasedSource(inner, holder)
        async with holder, source, asyncio.TaskGroup() as group:
            keeping = group.create_task(holder.run(), name="test:leases")
            running = group.create_task(source.run(), name="test:leased-source")
            await asyncio.sleep(0)
            # Standby: what every face reads of it.
            assert not machine.served and "laser" in tree.standby
            assert machine.status.state == "standby" and not machine.status.is_connected
            assert machine.nodes["Status/Served"].sample.value is False
            assert machine.nodes["Status/ServiceLevel"].sample.value == STANDBY_LEVEL
            assert machine.nodes["Feed"].sample.status == STANDBY_STATUS
            assert inner.runs == 0
            with pytest.raises(ControllerUnavailable, match="served by another shard"):
                await machine.write("Feed", 10.0, WriteContext("opcua", user="olga"))
            assert inner.writes == [] and "another shard" in audited[-1].reason

            other.release(theirs)  # the other shard stops cleanly: ours at the holder's next round
            other.leave("other")
            await wait_until(lambda: inner.running, timeout=10, message="the source started on the lease")
            assert machine.served and machine.nodes["Status/ServiceLevel"].sample.value == SERVED_LEVEL
            assert machine.nodes["Status/Served"].sample.value is True
            assert machine.nodes["Feed"].sample.good and machine.status.is_connected
            await machine.write("Feed", 10.0, WriteContext("opcua", user="olga"))
            assert inner.writes == [10.0]

            # Taken away: the holder is told at its next renewal (refused) and the source stops.
            await asyncio.to_thread(_steal, postgres_url)
            await wait_until(lambda: not inner.running, timeout=10, message="the source stopped")
            assert not machine.served and machine.status.state == "standby"
            assert machine.nodes["Feed"].sample.status == STANDBY_STATUS
            assert inner.runs == 1
            for task in (keeping, running):
                task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.gather(keeping, running)


def _steal(url: str) -> None:
    """Another shard takes the machine as a takeover does once a lease ran out (here: forced at once)."""
    import psycopg

    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("UPDATE shard_leases SET expires_at = now() WHERE machine = 'laser'")
    with LeaseTable(url, lease_time=LEASE) as table:
        table.join("thief")
        assert table.acquire("laser", "thief") is not None
