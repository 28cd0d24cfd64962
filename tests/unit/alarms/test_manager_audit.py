"""Acknowledge and Confirm go to the audit trail like writes and calls: who, role, which alarm, the
comment and the result, refusals (role, already acknowledged, ended alarm, a sink's own check) included."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from gateway.alarms.manager import AlarmManager, AlreadyAcknowledged, UnknownAlarm
from gateway.alarms.service import AlarmService
from gateway.errors import AccessDenied, WriteError
from gateway.model.audit import AuditEntry
from gateway.model.context import WriteContext
from gateway.model.tree import VariableTree
from tests.trees import MappedTree
from tests.unit.alarms.test_manager import T0, mapping

ROLES = ("viewer", "operator", "engineer", "admin")


class Rig:
    def __init__(self, tree: VariableTree, manager: AlarmManager) -> None:
        self.tree = tree
        self.manager = manager
        self.entries: list[AuditEntry] = []
        tree.audit_sinks.append(self.entries.append)

    async def alarm(self, *alarms: tuple[int, str, int]) -> int:
        """The controller reports this list; the newest occurrence's number."""
        machine = self.tree.machines["m"]
        nodes = machine.nodes
        machine.ingest(nodes["A/Ids"], [a[0] for a in alarms], T0)
        machine.ingest(nodes["A/Texts"], [a[1] for a in alarms], T0)
        machine.ingest(nodes["A/Classes"], [a[2] for a in alarms], T0)
        await self.manager.apply(self.manager.source.read())
        return max(self.manager.records, default=0)


@pytest.fixture
async def rig(tmp_path: Path) -> AsyncIterator[Rig]:
    tree = MappedTree([mapping(confirm=True)])
    tree.access.configure(ROLES, enabled=True)
    async with AlarmService(tree, tree.mappings, tmp_path) as service:
        yield Rig(tree, service.managers["m"])


async def test_acknowledge_and_confirm_are_audited_with_user_role_alarm_and_comment(rig: Rig) -> None:
    occ = await rig.alarm((1001, "Soft limit", 3))
    await rig.manager.acknowledge(occ, WriteContext("opcua", "olga", "operator"), "seen it")
    await rig.manager.confirm(occ, WriteContext("opcua", "erik", "engineer"), "fixed")
    ack, confirm = rig.entries
    assert (ack.kind, ack.machine, ack.target, ack.origin, ack.user, ack.role) == (
        "acknowledge",
        "m",
        f"Alarms/1001#{occ}",
        "opcua",
        "olga",
        "operator",
    )
    assert (ack.new, ack.status, ack.reason, ack.old) == ('["seen it"]', "Good", "", None)
    assert (confirm.kind, confirm.target, confirm.user, confirm.new, confirm.ok) == (
        "confirm",
        f"Alarms/1001#{occ}",
        "erik",
        '["fixed"]',
        True,
    )
    assert ack.describe().startswith(
        f'acknowledge m/Alarms/1001#{occ}("seen it") by olga via opcua, operator: ok'
    )


async def test_refusals_are_audited_with_their_status_and_reason(rig: Rig) -> None:
    occ = await rig.alarm((1001, "Soft limit", 3))
    with pytest.raises(AccessDenied):
        await rig.manager.acknowledge(occ, WriteContext("opcua", "vera", "viewer"), "let me")
    denied = rig.entries[-1]
    assert (denied.kind, denied.user, denied.role, denied.status) == (
        "acknowledge",
        "vera",
        "viewer",
        "BadUserAccessDenied",
    )
    assert "may not acknowledge alarms" in denied.reason and denied.new == '["let me"]'

    def refuse() -> None:
        raise WriteError("not one of ours", status="BadEventIdUnknown")

    with pytest.raises(WriteError):
        await rig.manager.acknowledge(occ, WriteContext("opcua", "olga", "operator"), check=refuse)
    assert (rig.entries[-1].status, rig.entries[-1].reason) == ("BadEventIdUnknown", "not one of ours")
    assert not rig.manager.records[occ].acked  # the sink's check refused it before anything was recorded

    await rig.manager.acknowledge(occ, WriteContext("opcua", "olga", "operator"))
    with pytest.raises(AlreadyAcknowledged):
        await rig.manager.acknowledge(occ, WriteContext("opcua", "otto", "operator"))
    assert rig.entries[-1].status == "BadConditionBranchAlreadyAcked" and rig.entries[-1].user == "otto"
    with pytest.raises(UnknownAlarm):
        await rig.manager.confirm(occ + 100, WriteContext("opcua", "olga", "operator"))
    assert (rig.entries[-1].kind, rig.entries[-1].target, rig.entries[-1].status) == (
        "confirm",
        f"Alarms/#{occ + 100}",
        "BadNodeIdUnknown",
    )
    assert [e.status for e in rig.entries].count("Good") == 1
