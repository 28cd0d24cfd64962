"""MQTT writes act with the machine's MQTT writers' role: a viewer's /set of Feed/Override is refused with
BadUserAccessDenied on /set/result, an operator's is carried out; both are in the audit table."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.audit.store import AuditStore, audit_path
from gateway.sinks.mqtt.config import MachineMqtt
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.integration.security.conftest import MACHINE, secure_gateway
from tests.waiting import wait_until

OVERRIDE = f"cnc/{MACHINE}/feed/override"


@pytest.mark.parametrize(("role", "accepted"), [("viewer", False), ("operator", True)])
async def test_the_machines_mqtt_writers_role_decides(
    role: str, accepted: bool, mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=[f"{OVERRIDE}/#", OVERRIDE])
    async with secure_gateway(
        tmp_path,
        gateway={"mqtt": mqtt_config(mosquitto.port)},
        mapping={"mqtt": MachineMqtt(writable=True, writer_role=role)},
    ) as rig:
        await wait_until(
            lambda: (rec.last_json(OVERRIDE) or {}).get("value") == 100,
            timeout=20,
            message="the override on MQTT",
        )
        rec.publish(f"{OVERRIDE}/set", b'{"value": 55}')
        result = await wait_until(
            lambda: rec.last_json(f"{OVERRIDE}/set/result"), message="the write's answer"
        )
        assert rig.sim is not None
        if accepted:
            assert result == {"ok": True}
            await wait_until(
                lambda: rig.sim.machine.override == 55, timeout=5, message="the simulator's override"
            )
        else:
            assert result["ok"] is False and result["status"] == "BadUserAccessDenied"
            assert f"role {role!r} may not write {MACHINE}/Feed/Override" in result["error"]
            assert rig.sim.machine.override == 100
        await rig.gateway.audit.flush()
        [entry] = [r.entry for r in AuditStore(audit_path(rig.state_dir)).query(machine=MACHINE)]
    assert (entry.origin, entry.role, entry.user, entry.target, entry.new) == (
        "mqtt",
        role,
        None,
        "Feed/Override",
        "55",
    )
    assert entry.status == ("Good" if accepted else "BadUserAccessDenied")
