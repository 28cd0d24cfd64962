"""Anonymous OPC UA clients of a gateway run from a mapping alone (no gateway file, so no users) only read:
every door that changes the machine (writes, commands, Programs, alarm acknowledgement) answers
BadUserAccessDenied and the controller keeps its value. Only a gateway file opens writes to them
(`access: {anonymous: operator}`, or `access: {enabled: false}`), and start-up then warns, saying which
role they get, on which endpoints, and what they may change (issue 12)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.app import Gateway
from gateway.audit.store import AuditStore, audit_path
from gateway.config.loader import Config, load
from gateway.settings.access import AccessConfig
from simulator.machine import MachineState
from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
MACHINE = "laser-sim"
WRITE = ua.AccessLevel.CurrentWrite.mask
DENIED = "BadUserAccessDenied"
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)


@dataclass
class Rig:
    gateway: Gateway
    sim: Simulator
    endpoint: str
    state_dir: Path

    def node(self, client: Client, path: str) -> Any:
        return client.get_node(f"ns=2;s={MACHINE}/{path}")


def environ(sim_port: int) -> dict[str, str]:
    return {"LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}", "LASER_SIM_COPYDATA_PORT": "0"}


def from_mapping_alone(tmp_path: Path, sim_port: int, gw_port: int) -> Config:
    """`cnc-gateway run mappings/laser-sim.yaml`: every default, free ports instead of the default ones."""
    config = load([ROOT / "mappings" / "laser-sim.yaml"], environ=environ(sim_port))
    gw = config.gateway
    assert gw.users == [] and gw.access == AccessConfig()  # what a new user gets
    gw = gw.model_copy(
        update={
            "opcua": gw.opcua.model_copy(update={"endpoint": f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"}),
            "inbox": gw.inbox.model_copy(update={"port": free_port()}),
            "state_dir": str(tmp_path / "state"),
        }
    )
    return Config(gw, config.machines, tmp_path, config.files)


def from_gateway_file(tmp_path: Path, sim_port: int, gw_port: int, access: str) -> Config:
    """A gateway file that lists the mapping and says `access`: still no users."""
    path = tmp_path / "gateway.yaml"
    path.write_text(
        f"opcua: {{endpoint: 'opc.tcp://127.0.0.1:{gw_port}/cnc-gateway'}}\n"
        f"state_dir: {tmp_path / 'state'}\ninbox: {{port: {free_port()}}}\n"
        f"machines: [{ROOT / 'mappings' / 'laser-sim.yaml'}]\naccess: {access}\n"
    )
    return load([path], environ=environ(sim_port))


def to_simulator_store(config: Config, ftp_port: int) -> Config:
    """The mapping's program store is the simulator's FTP (port 2122 in the file; a free one here)."""
    [mapping] = config.machines
    assert mapping.jobs is not None
    controller = mapping.jobs.controller.model_copy(update={"port": ftp_port})
    jobs = mapping.jobs.model_copy(update={"controller": controller})
    return Config(config.gateway, (mapping.model_copy(update={"jobs": jobs}),), config.base_dir, config.files)


@asynccontextmanager
async def running(tmp_path: Path, access: str | None = None) -> AsyncIterator[Rig]:
    sim_port, ftp_port, gw_port = free_port(), free_port(), free_port()
    if access is None:
        config = from_mapping_alone(tmp_path, sim_port, gw_port)
    else:
        config = from_gateway_file(tmp_path, sim_port, gw_port, access)
    config = to_simulator_store(config, ftp_port)
    store = tmp_path / "store"
    async with (
        Simulator(opcua_port=sim_port, ftp_port=ftp_port, speed=20.0, store=store) as sim,
        Gateway(config) as gw,
    ):
        task = asyncio.create_task(gw.run(), name="test:gateway")
        try:
            machine = gw.tree.machines[MACHINE]
            await wait_until(
                lambda: machine.nodes["Feed/Override"].sample.good,
                timeout=15,
                message="the gateway mirroring the simulator",
            )
            yield Rig(gw, sim, config.gateway.opcua.endpoint, config.state_dir)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def status_of(coro: Any) -> str:
    try:
        await coro
    except ua.UaStatusCodeError as exc:
        return type(exc).__name__
    return "Good"


class Alarms:
    def __init__(self) -> None:
        self.received: list[Any] = []

    def event_notification(self, event: Any) -> None:
        if event.EventType == ua.NodeId(ua.ObjectIds.AlarmConditionType):
            self.received.append(event)


def override(value: int) -> ua.Variant:
    return ua.Variant(value, ua.VariantType.UInt16)


def opened(caplog: pytest.LogCaptureFixture) -> list[str]:
    """What start-up warned anonymous clients may change."""
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and "anonymous clients" in r.getMessage()
    ]


async def test_without_a_gateway_file_anonymous_clients_change_nothing(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    async with running(tmp_path) as rig:
        sim = rig.sim.machine
        async with Client(rig.endpoint, timeout=5) as client:  # anonymous, on the None endpoint
            level = await rig.node(client, "Feed/Override").read_attribute(ua.AttributeIds.UserAccessLevel)
            assert not level.Value.Value & WRITE  # its client greys the write out beforehand

            assert await status_of(rig.node(client, "Feed/Override").write_value(override(50))) == DENIED
            assert await status_of(rig.node(client, "Control/Start").write_value(ua.Variant(True))) == DENIED
            commands, programs = rig.node(client, "Commands"), rig.node(client, "Programs")
            assert await status_of(commands.call_method("2:start")) == DENIED
            assert (
                await status_of(
                    programs.call_method("2:Delete", ua.Variant("demo.nc", ua.VariantType.String))
                )
                == DENIED
            )
            assert await status_of(programs.call_method("2:List")) == "Good"  # reading stays open

            # An alarm raised on the machine itself: anonymous clients see it, and may not acknowledge it.
            alarms = Alarms()
            subscription = await client.create_subscription(20, alarms)
            await subscription.subscribe_alarms_and_conditions(
                ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType
            )
            sim.select_program("soft-limit.nc")
            sim.start()
            await wait_until(lambda: alarms.received, timeout=15, message="the soft-limit alarm event")
            event = alarms.received[-1]
            assert (
                await status_of(
                    client.get_node(event.NodeId).call_method(
                        ACK,
                        ua.Variant(event.EventId, ua.VariantType.ByteString),
                        ua.Variant(ua.LocalizedText("me"), ua.VariantType.LocalizedText),
                    )
                )
                == DENIED
            )

        # The controller kept its values: nothing anonymous reached it.
        assert (
            sim.override == 100
            and rig.gateway.tree.machines[MACHINE].nodes["Feed/Override"].sample.value == 100
        )
        assert sim.store.exists("demo.nc") and sim.state is MachineState.ALARM
        await rig.gateway.audit.flush()
        rows = [r.entry for r in AuditStore(audit_path(rig.state_dir)).query(machine=MACHINE, limit=100)]

    refused = {(e.target, e.user, e.role, e.status) for e in rows}
    for target in ("Feed/Override", "Control/Start", "Commands.start", "Programs.Delete", "Alarms/1001#1"):
        assert (target, None, "viewer", DENIED) in refused, (target, refused)
    assert opened(caplog) == []
    assert any(
        "anonymous clients on" in r.getMessage() and "change nothing" in r.getMessage()
        for r in caplog.records
    ), "start-up says anonymous clients only read"


async def test_a_gateway_file_that_gives_anonymous_clients_operator_opens_those_writes_and_warns(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    async with running(tmp_path, "{anonymous: operator}") as rig:
        [warning] = opened(caplog)
        assert f"on {rig.endpoint} (every endpoint: None, Basic256Sha256_SignAndEncrypt" in warning
        assert "access.anonymous gives them role 'operator'" in warning
        assert "laser-sim: write " in warning and "Feed/Override" in warning and "Control/Start" in warning
        assert "call Commands.start" in warning and "acknowledge alarms" in warning
        assert "Machine/Mode" not in warning  # an engineer's variable stays closed to them
        async with Client(rig.endpoint, timeout=5) as client:
            assert await status_of(rig.node(client, "Feed/Override").write_value(override(50))) == "Good"
            mode = ua.Variant(1, ua.VariantType.Int16)
            assert await status_of(rig.node(client, "Machine/Mode").write_value(mode)) == DENIED
        await wait_until(
            lambda: rig.sim.machine.override == 50, timeout=10, message="the override on the controller"
        )


async def test_access_enabled_false_opens_everything_and_warns(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    async with running(tmp_path, "{enabled: false}") as rig:
        [warning] = opened(caplog)
        assert "access.enabled is false: no role is checked" in warning and "Machine/Mode" in warning
        async with Client(rig.endpoint, timeout=5) as client:
            mode = ua.Variant(1, ua.VariantType.Int16)
            assert await status_of(rig.node(client, "Machine/Mode").write_value(mode)) == "Good"
        await wait_until(lambda: rig.sim.machine.mode == 1, timeout=10, message="the mode on the controller")
