"""Alarm Acknowledge and Confirm over OPC UA reach the audit table like writes and calls: a viewer's
acknowledgement is refused and audited as denied, an operator's is carried out and audited with its
comment, and `cnc-gateway audit list` shows both."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.audit.store import AuditStore, audit_path
from gateway.cli.main import main as cli
from simulator.machine import MachineState
from tests.integration.laser_rig import Events
from tests.integration.security.conftest import MACHINE, secure_gateway
from tests.waiting import wait_until

ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)


async def call(client: Any, method: ua.NodeId, event: Any, comment: str) -> str:
    """Acknowledge or Confirm `event`'s condition; the status name."""
    try:
        await client.get_node(event.NodeId).call_method(
            method,
            ua.Variant(event.EventId, ua.VariantType.ByteString),
            ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
        )
    except ua.UaStatusCodeError as exc:
        return type(exc).__name__
    return "Good"


async def test_acknowledge_and_confirm_over_opcua_are_audited_whether_allowed_or_denied(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async with secure_gateway(tmp_path) as rig:
        assert rig.sim is not None
        await wait_until(
            lambda: rig.machine.nodes["Machine/State"].sample.good, timeout=15, message="state Good"
        )
        otto, vera = rig.client("otto"), rig.client("vera")
        async with otto, vera:
            seen = Events()
            sub = await otto.create_subscription(20, seen)
            await sub.subscribe_alarms_and_conditions(
                ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType
            )
            commands = otto.get_node(f"ns=2;s={MACHINE}/Commands")
            await commands.call_method("2:select-program", ua.Variant("soft-limit.nc", ua.VariantType.String))
            await commands.call_method("2:start")
            await wait_until(lambda: rig.sim.machine.state is MachineState.ALARM, timeout=15, message="Alarm")
            await wait_until(seen.alarms, timeout=10, message="the alarm event")
            raised = seen.alarms()[0]

            assert await call(vera, ACK, raised, "viewer tries") == "BadUserAccessDenied"
            assert await call(otto, ACK, raised, "operator saw it") == "Good"
            await wait_until(lambda: len(seen.alarms()) >= 2, message="the acknowledge event")
            assert await call(vera, CONFIRM, seen.alarms()[-1], "viewer again") == "BadUserAccessDenied"
            assert await call(otto, CONFIRM, seen.alarms()[-1], "fixed") == "Good"
        await rig.gateway.audit.flush()
        rows = [r.entry for r in AuditStore(audit_path(rig.state_dir)).query(machine=MACHINE, limit=1000)]

    occurrence = raised.NodeId.Identifier.rsplit("/", 1)[-1]
    target = f"Alarms/1001#{occurrence}"
    alarm_rows = [e for e in rows if e.kind in ("acknowledge", "confirm")]
    assert [(e.kind, e.user, e.role, e.target, e.origin, e.status) for e in reversed(alarm_rows)] == [
        ("acknowledge", "vera", "viewer", target, "opcua", "BadUserAccessDenied"),
        ("acknowledge", "otto", "operator", target, "opcua", "Good"),
        ("confirm", "vera", "viewer", target, "opcua", "BadUserAccessDenied"),
        ("confirm", "otto", "operator", target, "opcua", "Good"),
    ]
    denied, acked = alarm_rows[-1], alarm_rows[-2]
    assert denied.new == '["viewer tries"]' and "role 'viewer' may not acknowledge alarms" in denied.reason
    assert acked.new == '["operator saw it"]' and acked.reason == ""

    assert cli(["audit", "list", "--state-dir", str(rig.state_dir)]) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if target in line]
    assert any(
        "acknowledge" in line and "otto" in line and '"operator saw it"' in line and " ok " in line
        for line in lines
    ), lines
    assert any(
        "acknowledge" in line and "vera" in line and "BadUserAccessDenied" in line for line in lines
    ), lines
