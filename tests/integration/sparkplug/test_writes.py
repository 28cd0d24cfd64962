"""DCMD writes and commands through the tree's one write path, against the real simulator: accepted ones
reach the controller and show as the next DDATA; refused ones are logged, audited, counted by kind, and
the metric's value is shown again."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gateway.model.audit import AuditEntry
from simulator.machine import MachineState
from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import (
    MACHINE,
    laser_sparkplug,
    sink_rig,
    sparkplug_config,
    start_host,
    typed_mapping,
)
from tests.integration.sparkplug.host import SparkplugHost
from tests.unit.codecs.sparkplug import host as spec
from tests.waiting import wait_until

OPERATOR = {"mqtt_writer_role": "operator"}


def by_target(entries: list[AuditEntry], target: str) -> list[AuditEntry]:
    return [e for e in entries if e.target == target and e.origin == "sparkplug"]


async def test_dcmd_writes_accepted_and_refused(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with laser_sparkplug(tmp_path, sparkplug_config(mosquitto.port), access=OPERATOR) as laser:
        audit: list[AuditEntry] = []
        laser.gateway.tree.audit_sinks.append(audit.append)
        await wait_until(lambda: host.value(MACHINE, "Feed/Override") == 100, message="the override, 100")
        sink = laser.sink

        host.write(MACHINE, "Feed/Override", 50)  # accepted: the controller takes it, read back, DDATA
        await wait_until(lambda: host.value(MACHINE, "Feed/Override") == 50, message="the write's DDATA")
        assert laser.sim.machine.override == 50
        [entry] = by_target(audit, "Feed/Override")
        assert entry.ok and entry.role == "operator" and entry.new == "50"

        mark = host.count()
        host.write(MACHINE, "Feed/Override", 151)  # the mapping's range: 0..150
        await wait_until(lambda: sink.refusals.get("BadOutOfRange") == 1, message="the refusal, counted")
        assert laser.sim.machine.override == 50
        # No reply topic in Sparkplug: the value the metric still holds is its next DDATA.
        await wait_until(
            lambda: any(s.kind == "DDATA" and s.metric("Feed/Override") for s in host.since(mark)),
            message="the metric's value again",
        )
        assert host.value(MACHINE, "Feed/Override") == 50
        refused = by_target(audit, "Feed/Override")[-1]
        assert refused.status == "BadOutOfRange" and refused.new == "151"

        host.write(MACHINE, "Machine/Mode", 1)  # role engineer; MQTT and Sparkplug writers are operators
        host.write(MACHINE, "Axes/X/Position", 5.0)  # read-only
        host.write(MACHINE, "Status/State", "x")  # the gateway's own
        host.write(MACHINE, "Commands/start/Result", "x")  # a command's outcome
        alias = host.alias(MACHINE, "Feed/Override")  # a Double for a UInt16: refused by the codec
        host.send(
            f"spBv1.0/cnc/DCMD/cnc-gateway/{MACHINE}",
            spec.command(spec.write(60.0, spec.DOUBLE, alias=alias)),
        )
        await wait_until(
            lambda: sink.refusals.get("BadNotWritable") == 3 and sink.refusals.get("wrong_datatype") == 1,
            message="every refusal counted",
        )
        assert sink.refusals["BadUserAccessDenied"] == 1
        assert by_target(audit, "Machine/Mode")[-1].status == "BadUserAccessDenied"
        assert by_target(audit, "Axes/X/Position")[-1].status == "BadNotWritable"
        assert by_target(audit, "Feed/Override")[-1].status == "BadTypeMismatch"
        assert laser.sim.machine.override == 50 and laser.sim.machine.mode == 0
        assert dict(sink.refusals) == {
            "BadOutOfRange": 1,
            "BadUserAccessDenied": 1,
            "BadNotWritable": 3,
            "wrong_datatype": 1,
        }
        await wait_until(
            lambda: (
                (host.last("NDATA") or None)
                and host.last("NDATA").metric("Sparkplug/CommandsRefused")  # type: ignore[union-attr]
                and host.last("NDATA").metric("Sparkplug/CommandsRefused").value == 6
            ),  # type: ignore[union-attr]
            message="the node's refusal count",
        )


async def test_dcmd_commands_run_with_their_guards_and_say_how_they_ended(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with laser_sparkplug(tmp_path, sparkplug_config(mosquitto.port), access=OPERATOR) as laser:
        audit: list[AuditEntry] = []
        laser.gateway.tree.audit_sinks.append(audit.append)
        await wait_until(lambda: host.value(MACHINE, "Machine/State") == 0, message="the machine, idle")

        host.write(MACHINE, "Commands/select-program/Execute", "demo.nc")
        await wait_until(
            lambda: "demo.nc" in (host.value(MACHINE, "Commands/select-program/Result") or ""),
            message="select-program's result",
        )
        assert host.value(MACHINE, "Commands/select-program/Result") == "Good: Program/Name is 'demo.nc'"
        assert host.value(MACHINE, "Commands/select-program/Execute") == ""  # at rest again
        host.write(MACHINE, "Commands/start/Execute", True)
        await wait_until(lambda: host.value(MACHINE, "Commands/start/Result"), message="start's result")
        assert host.value(MACHINE, "Commands/start/Result") == "Good: Machine/State is 1 (Running)"
        assert laser.sim.machine.state is MachineState.RUNNING
        assert host.value(MACHINE, "Commands/start/Execute") is False

        host.write(MACHINE, "Commands/start/Execute", True)  # already running: the guard says no
        await wait_until(
            lambda: (host.value(MACHINE, "Commands/start/Result") or "").startswith("BadInvalidState"),
            message="the guard's refusal",
        )
        host.write(MACHINE, "Commands/stop/Execute", False)  # false asks for nothing
        await wait_until(lambda: laser.sink.refusals.get("BadInvalidArgument") == 1, message="false, refused")
        assert laser.sim.machine.state is MachineState.RUNNING
        calls = [(e.target, e.status) for e in audit if e.kind == "call" and e.origin == "sparkplug"]
        assert calls == [
            ("Commands.select-program", "Good"),
            ("Commands.start", "Good"),
            ("Commands.start", "BadInvalidState"),
            ("Commands.stop", "BadInvalidArgument"),
        ]
        assert {e.role for e in audit if e.origin == "sparkplug"} == {"operator"}


async def test_writes_and_commands_the_mapping_does_not_open_are_refused(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    mapping = typed_mapping(writable=False)
    async with sink_rig(tmp_path, mapping, sparkplug_config(mosquitto.port)) as rig:
        audit: list[AuditEntry] = []
        rig.tree.audit_sinks.append(audit.append)
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        override = host.last("DBIRTH", "m1").metric("Feed/Override")  # type: ignore[union-attr]
        assert override is not None and override.properties["readOnly"] == (spec.BOOLEAN, True)
        host.write("m1", "Feed/Override", 10)
        await wait_until(lambda: rig.sink.refusals.get("BadUserAccessDenied") == 1, message="the refusal")
        assert rig.controller.written == []
        [entry] = audit
        assert entry.status == "BadUserAccessDenied" and "mqtt.writable" in entry.reason
        metrics: dict[str, Any] = dict(rig.sink.refusals)
        assert metrics == {"BadUserAccessDenied": 1}
