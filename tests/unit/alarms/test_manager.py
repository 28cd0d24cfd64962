"""The alarm manager's state machine, over a real tree and a real store: raise, clear, occurrences,
acknowledge and confirm (with roles), a controller that drops, and what the event bus carries."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from gateway.alarms.manager import AlarmManager, AlreadyAcknowledged, AlreadyConfirmed, UnknownAlarm
from gateway.alarms.records import AlarmChange, Kind, Quality
from gateway.alarms.service import AlarmService
from gateway.config.mapping import MachineMapping
from gateway.errors import AccessDenied, InvalidState
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableTree
from tests.trees import MappedTree
from tests.waiting import wait_until

T0 = datetime(2026, 5, 6, 7, 0, 0, tzinfo=UTC)
OPERATOR = WriteContext("test", "olga", "operator")


def mapping(confirm: bool = False) -> MachineMapping:
    return MachineMapping.model_validate(
        {
            "machine": "m",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
            "variables": [
                {"path": "A/Ids", "source": "ns=2;s=ids", "type": "UInt32[]"},
                {"path": "A/Texts", "source": "ns=2;s=texts", "type": "String[]"},
                {"path": "A/Classes", "source": "ns=2;s=classes", "type": "UInt16[]"},
            ],
            "alarms": {
                "source": {"ids": "A/Ids", "texts": "A/Texts", "severities": "A/Classes"},
                "severity": {1: 100, 3: 700},
                "confirm": confirm,
            },
        }
    )


class Rig:
    def __init__(self, tree: VariableTree, service: AlarmService) -> None:
        self.tree = tree
        self.service = service
        self.machine: Machine = tree.machines["m"]
        self.manager: AlarmManager = service.managers["m"]
        self.changes: list[AlarmChange] = []
        self.events = tree.events.subscribe("test")
        self.clock = T0

    def controller(self, *alarms: tuple[int, str, int]) -> None:
        """The controller reports this active list (all three arrays in one go)."""
        self.clock += timedelta(seconds=1)
        nodes = self.machine.nodes
        self.machine.ingest(nodes["A/Ids"], [a[0] for a in alarms], self.clock)
        self.machine.ingest(nodes["A/Texts"], [a[1] for a in alarms], self.clock)
        self.machine.ingest(nodes["A/Classes"], [a[2] for a in alarms], self.clock)

    async def look(self) -> None:
        await self.manager.apply(self.manager.source.read())

    def bus(self, channel: str) -> list[Any]:
        return [e.payload for e in self.events.take() if e.channel == channel]


@pytest.fixture
async def rig(tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[Rig]:
    tree = MappedTree([mapping(getattr(request, "param", False))])
    async with AlarmService(tree, tree.mappings, tmp_path) as service:
        r = Rig(tree, service)

        async def listen(change: AlarmChange) -> None:
            r.changes.append(change)

        r.manager.listen(listen)
        yield r


async def test_raise_and_clear_with_severity_mapped_and_times_from_the_controller(rig: Rig) -> None:
    rig.controller((1001, "Soft limit X+", 3), (5, "Info", 9))
    await rig.look()
    raised = [c for c in rig.changes if c.kind is Kind.RAISED]
    assert [(c.record.id, c.record.severity, c.record.raised_at) for c in raised] == [
        ("1001", 700, rig.clock),
        ("5", 500, rig.clock),  # class 9 is not mapped: default_severity
    ]
    events = rig.bus("alarms/events")
    assert [(e["event"], e["id"]) for e in events if e["event"] == "raised"] == [
        ("raised", "1001"),
        ("raised", "5"),
    ]
    rig.controller((5, "Info", 9))
    await rig.look()
    cleared = rig.changes[-1]
    assert (
        cleared.kind is Kind.CLEARED
        and cleared.record.id == "1001"
        and cleared.record.cleared_at == rig.clock
    )
    assert cleared.retained  # not acknowledged yet
    active = rig.bus("alarms/active")[-1]
    assert [(a["id"], a["active"]) for a in active] == [("1001", False), ("5", True)]


async def test_the_same_id_again_after_clearing_is_a_new_occurrence(rig: Rig) -> None:
    rig.controller((1001, "Soft limit", 3))
    await rig.look()
    first = rig.changes[-1].record.occurrence
    rig.controller()
    await rig.look()
    rig.controller((1001, "Soft limit", 3))
    await rig.look()
    second = rig.changes[-1]
    assert second.kind is Kind.RAISED and second.record.occurrence != first
    assert {r.occurrence for r in rig.manager.retained()} == {first, second.record.occurrence}


async def test_acknowledge_once_with_user_and_comment_then_the_cleared_alarm_ends(rig: Rig) -> None:
    rig.controller((1001, "Soft limit", 3))
    await rig.look()
    occ = rig.changes[-1].record.occurrence
    acked = await rig.manager.acknowledge(occ, OPERATOR, "seen it")
    assert acked.acked_by == "olga" and acked.ack_comment == "seen it"
    with pytest.raises(AlreadyAcknowledged):
        await rig.manager.acknowledge(occ, OPERATOR)
    [event] = [e for e in rig.bus("alarms/events") if e["event"] == "acknowledged"]
    assert event["user"] == "olga" and event["comment"] == "seen it" and event["acked"] is True
    rig.controller()
    await rig.look()
    assert rig.changes[-1].kind is Kind.CLEARED and not rig.changes[-1].retained
    assert rig.manager.retained() == []
    assert rig.bus("alarms/active")[-1] == []
    with pytest.raises(UnknownAlarm):
        await rig.manager.acknowledge(occ, OPERATOR)
    [past] = rig.service.store.history("m")
    assert past.acked and not past.active


@pytest.mark.parametrize("rig", [True], indirect=True)
async def test_with_confirmation_required_the_alarm_stays_until_confirmed(rig: Rig) -> None:
    rig.controller((1001, "Soft limit", 3))
    await rig.look()
    occ = rig.changes[-1].record.occurrence
    with pytest.raises(InvalidState, match="acknowledged first"):
        await rig.manager.confirm(occ, OPERATOR)
    await rig.manager.acknowledge(occ, OPERATOR)
    rig.controller()
    await rig.look()
    assert rig.changes[-1].retained
    confirmed = await rig.manager.confirm(occ, OPERATOR, "fixed the fixture")
    assert confirmed.confirmed_by == "olga" and not rig.changes[-1].retained
    with pytest.raises(UnknownAlarm):
        await rig.manager.confirm(occ, OPERATOR)


async def test_a_confirmed_alarm_cannot_be_confirmed_again(rig: Rig) -> None:
    rig.controller((1001, "Soft limit", 3))
    await rig.look()
    occ = rig.changes[-1].record.occurrence
    await rig.manager.acknowledge(occ, OPERATOR)
    await rig.manager.confirm(occ, OPERATOR)  # still active, so still listed
    with pytest.raises(AlreadyConfirmed):
        await rig.manager.confirm(occ, OPERATOR)


async def test_acknowledging_needs_the_role_while_access_control_is_on(rig: Rig) -> None:
    rig.controller((1001, "Soft limit", 3))
    await rig.look()
    occ = rig.changes[-1].record.occurrence
    rig.tree.access.configure(("viewer", "operator", "engineer", "admin"), enabled=True)
    with pytest.raises(AccessDenied, match="acknowledge alarms"):
        await rig.manager.acknowledge(occ, WriteContext("opcua", "vic", "viewer"))
    with pytest.raises(AccessDenied):
        await rig.manager.acknowledge(occ, WriteContext("opcua", None, None))
    assert (await rig.manager.acknowledge(occ, WriteContext("opcua", "eve", "engineer"))).acked_by == "eve"


async def test_a_controller_that_drops_clears_nothing_and_reconnecting_reconciles(rig: Rig) -> None:
    rig.controller((1001, "Soft limit", 3), (2001, "Program error", 3))
    await rig.look()
    rig.machine.invalidate("BadNotConnected", "connection lost")
    await rig.look()
    quality = [c for c in rig.changes if c.kind is Kind.QUALITY]
    assert len(quality) == 2 and all(c.record.quality is Quality.UNCERTAIN for c in quality)
    assert all(r.active for r in rig.manager.retained())
    assert {a["quality"] for a in rig.bus("alarms/active")[-1]} == {"uncertain"}
    rig.changes.clear()
    rig.controller((2001, "Program error", 3))  # back: 1001 went away meanwhile
    await rig.look()
    kinds = [(c.kind, c.record.id) for c in rig.changes]
    assert (Kind.CLEARED, "1001") in kinds and (Kind.QUALITY, "2001") in kinds
    assert all(r.quality is Quality.GOOD for r in rig.manager.retained())


@pytest.mark.parametrize("database", ["sqlite", "postgresql"])
async def test_a_restart_picks_up_the_retained_occurrences_with_their_acknowledgement(
    tmp_path: Path, database: str, request: pytest.FixtureRequest
) -> None:
    """Also with the history in PostgreSQL, where the second service stands for the shard that serves the
    machine next (another state directory, the same database)."""
    url = request.getfixturevalue("postgres_url") if database == "postgresql" else None
    first_dir, next_dir = (tmp_path / "one", tmp_path / "two") if url else (tmp_path, tmp_path)
    tree = MappedTree([mapping()])
    async with AlarmService(tree, tree.mappings, first_dir, url) as service:
        rig = Rig(tree, service)
        rig.controller((1001, "Soft limit", 3))
        await rig.look()
        [record] = rig.manager.retained()
        await rig.manager.acknowledge(record.occurrence, OPERATOR, "seen")
    tree = MappedTree([mapping()])
    async with AlarmService(tree, tree.mappings, next_dir, url) as service:
        [again] = service.managers["m"].retained()
        assert again.occurrence == record.occurrence and again.acked_by == "olga"
        assert again.quality is Quality.UNCERTAIN  # until the controller's list is read again
        rig = Rig(tree, service)
        rig.controller((1001, "Soft limit", 3))
        await rig.look()
        [still] = rig.manager.retained()
        assert still.occurrence == record.occurrence and still.quality is Quality.GOOD and still.acked


async def test_the_running_manager_follows_the_hub_and_waits_for_arrays_that_lag(rig: Rig) -> None:
    task = asyncio.create_task(rig.manager.run())
    try:
        nodes = rig.machine.nodes
        await wait_until(lambda: any(s.name == "alarms:m" for s in rig.tree.hub.subscriptions))
        [sub] = [s for s in rig.tree.hub.subscriptions if s.name == "alarms:m"]
        rig.controller()  # an empty list, all three arrays Good
        await wait_until(lambda: sub.backlog == 0 and rig.manager.quality is Quality.GOOD)
        rig.machine.ingest(nodes["A/Ids"], [1001], T0)  # the texts and classes arrive a little later
        await wait_until(lambda: sub.backlog == 0, message="the manager to take the ids alone")
        rig.machine.ingest(nodes["A/Texts"], ["Soft limit"], T0)
        rig.machine.ingest(nodes["A/Classes"], [3], T0)
        await wait_until(lambda: any(c.kind is Kind.RAISED for c in rig.changes), timeout=5)
        raised = [c for c in rig.changes if c.kind is Kind.RAISED]
        assert [(c.record.text, c.record.severity) for c in raised] == [("Soft limit", 700)]
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


async def test_a_takeover_replaces_the_alarms_with_those_another_shard_left(
    tmp_path: Path, postgres_url: str
) -> None:
    """shard: lease. Shard B loaded the history at its start; shard A served the machine meanwhile (cleared
    and acknowledged one occurrence, raised another). When the machine's lease reaches B (`Status/Served`
    turns true under its running manager), B holds what A left: its listeners hear of each difference,
    the retained list is published again, the event stream repeats nothing."""
    tree_a, tree_b = MappedTree([mapping()]), MappedTree([mapping()])
    async with AlarmService(tree_a, tree_a.mappings, tmp_path / "a", postgres_url) as shard_a:
        a = Rig(tree_a, shard_a)
        a.controller((1001, "Soft limit", 3))
        await a.look()
        [first] = a.manager.retained()
        async with AlarmService(tree_b, tree_b.mappings, tmp_path / "b", postgres_url) as shard_b:
            b = Rig(tree_b, shard_b)
            assert [r.occurrence for r in b.manager.retained()] == [first.occurrence]  # loaded at its start

            async def listen(change: AlarmChange) -> None:
                b.changes.append(change)

            b.manager.listen(listen)
            served = b.machine.add_internal("Status/Served", "Boolean", "leased", False)
            running = asyncio.create_task(b.manager.run())
            try:
                await wait_until(lambda: any(s.name == "alarms:m" for s in tree_b.hub.subscriptions))
                a.controller((2001, "Door open", 1))  # on A: 1001 cleared, 2001 raised
                await a.look()
                await a.manager.acknowledge(first.occurrence, OPERATOR, "seen")
                [second] = a.manager.retained()
                b.events.take()
                b.machine.set_internal(served, True)  # the lease arrives at B
                await wait_until(lambda: [r.occurrence for r in b.manager.retained()] == [second.occurrence],
                                 timeout=10, message="B holding what A left")  # fmt: skip
            finally:
                running.cancel()
                await asyncio.gather(running, return_exceptions=True)
            kinds = [(c.kind, c.record.occurrence) for c in b.changes]
            assert kinds == [(Kind.CLEARED, first.occurrence), (Kind.RAISED, second.occurrence)]
            cleared = b.changes[0].record
            assert cleared.acked_by == "olga" and not cleared.active and not b.changes[0].retained
            published = b.events.take()
            assert [e for e in published if e.channel == "alarms/events"] == []  # A published those
            active = [e.payload for e in published if e.channel == "alarms/active"]
            assert active and [r["occurrence"] for r in active[-1]] == [second.occurrence]
