"""End to end, as a SCADA engineer meets it: simulator → gateway → a real OPC UA client over TCP.

The gateway runs the shipped mappings/laser-sim.yaml (pointed at a simulator on a
free port); the client browses, subscribes, writes, and watches the mirror go Bad
when the simulator stops and Good again when it comes back.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from asyncua import ua

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig
from gateway.config.loader import Config, load_mapping
from gateway.settings.access import AccessConfig
from gateway.sinks.opcua.config import OpcUaServerConfig
from simulator.runner import Simulator
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
MACHINE = "laser-sim"


@dataclass
class Rig:
    gateway: Gateway
    client: Client
    sim_ports: tuple[int, int]
    store: Path
    sim: Simulator | None

    def node(self, path: str) -> Any:
        return self.client.get_node(f"ns=2;s={MACHINE}/{path}")

    async def read(self, path: str) -> ua.DataValue:
        return await self.node(path).read_data_value(raise_on_bad_status=False)

    async def start_simulator(self) -> None:
        self.sim = Simulator(
            opcua_port=self.sim_ports[0], ftp_port=self.sim_ports[1], speed=20.0, store=self.store
        )
        await self.sim.__aenter__()

    async def stop_simulator(self) -> None:
        assert self.sim is not None
        await self.sim.__aexit__(None, None, None)
        self.sim = None


def gateway_config(tmp_path: Path, sim_port: int, gw_port: int, mapping_text: str | None = None) -> Config:
    mapping_file = ROOT / "mappings" / "laser-sim.yaml"
    if mapping_text is not None:
        mapping_file = tmp_path / "laser-sim.yaml"
        mapping_file.write_text(mapping_text)
    mapping = load_mapping(
        mapping_file,
        environ={"LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}", "LASER_SIM_COPYDATA_PORT": "0"},
    )
    driver = mapping.driver.model_copy(
        update={
            "watchdog_interval": 0.5,
            "reconnect": mapping.driver.reconnect.model_copy(update={"initial": 0.2, "max": 1.0}),
        }
    )
    mapping = mapping.model_copy(update={"driver": driver})
    gateway = GatewayConfig(
        opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"),
        state_dir=str(tmp_path / "state"),
        inbox=InboxConfig(port=free_port()),
        access=AccessConfig(anonymous="operator"),  # the client writes anonymously: the gateway file opens it
    )
    return Config(gateway, (mapping,), tmp_path, (mapping_file,))


@pytest.fixture
async def rig(tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[Rig]:
    import asyncio

    sim_ports = (free_port(), free_port())
    gw_port = free_port()
    mapping_text = getattr(request, "param", None)
    config = gateway_config(tmp_path, sim_ports[0], gw_port, mapping_text)
    store = tmp_path / "store"
    store.mkdir()
    async with Gateway(config) as gw:
        run = asyncio.create_task(gw.run(), name="gateway")
        client = Client(f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway", timeout=5)
        await client.connect()
        rig = Rig(gw, client, sim_ports, store, None)
        try:
            await rig.start_simulator()
            yield rig
        finally:
            await client.disconnect()
            if rig.sim is not None:
                await rig.stop_simulator()
            run.cancel()
            await asyncio.gather(run, return_exceptions=True)


async def good(rig: Rig, path: str) -> bool:
    dv = await rig.read(path)
    return dv.StatusCode is None or dv.StatusCode.is_good()


async def test_client_browses_the_machine_tree(rig: Rig) -> None:
    objects = rig.client.nodes.objects
    x = await objects.get_child(["2:Machines", f"2:{MACHINE}", "2:Axes", "2:X", "2:Position"])
    assert x.nodeid == rig.node("Axes/X/Position").nodeid
    assert (await x.read_description()).Text == "Actual X position"
    assert await x.read_data_type() == ua.NodeId(ua.ObjectIds.Double)
    units = await (await x.get_child("0:EngineeringUnits")).read_value()
    assert units.DisplayName.Text == "mm"
    override = await objects.get_child(["2:Machines", f"2:{MACHINE}", "2:Feed", "2:Override"])
    rng = await (await override.get_child("0:EURange")).read_value()
    assert (rng.Low, rng.High) == (0, 150)
    access = await override.read_attribute(ua.AttributeIds.AccessLevel)
    assert access.Value.Value & ua.AccessLevel.CurrentWrite.mask
    status = await objects.get_child(["2:Machines", f"2:{MACHINE}", "2:Status"])
    assert await status.read_node_class() == ua.NodeClass.Object


async def test_positions_move_with_controller_timestamps_while_a_program_runs(rig: Rig) -> None:
    await wait_until(lambda: good(rig, "Axes/X/Position"), timeout=10, message="X position Good")
    await rig.node("Control/SelectProgram").write_value(ua.Variant("demo.nc", ua.VariantType.String))
    await rig.node("Control/Start").write_value(ua.Variant(True, ua.VariantType.Boolean))
    first = await rig.read("Axes/X/Position")

    async def moved() -> bool:
        now = await rig.read("Axes/X/Position")
        return now.Value.Value != first.Value.Value

    await wait_until(moved, timeout=15, message="X to move")
    dv = await rig.read("Program/Block")
    assert dv.SourceTimestamp is not None and dv.StatusCode.is_good()
    assert (await rig.read("Program/Name")).Value.Value == "demo.nc"
    assert (await rig.read("Machine/StateText")).Value.Value == "Running"


async def test_feed_override_write_reaches_the_simulator(rig: Rig) -> None:
    await wait_until(lambda: good(rig, "Feed/Override"), timeout=10, message="override Good")
    await rig.node("Feed/Override").write_value(ua.Variant(50, ua.VariantType.UInt16))
    assert rig.sim is not None
    await wait_until(lambda: rig.sim.machine.override == 50, timeout=5, message="simulator override 50")

    async def mirrored() -> bool:
        return (await rig.read("Feed/Override")).Value.Value == 50

    await wait_until(mirrored, timeout=5, message="gateway shows the new override")


async def test_a_client_reads_back_what_it_just_wrote(rig: Rig) -> None:
    """Read-your-writes: an HMI that checks a write by reading the variable at once sees the new value,
    not the old one for the 20-100 ms until the controller's own notification would bring it."""
    await wait_until(lambda: good(rig, "Feed/Override"), timeout=10, message="override Good")
    before = (await rig.read("Feed/Override")).Value.Value
    values = [v for v in (50, 75, 120, 10, 150, 0, 99, 100, 33, 66, 140, 5) if v != before]
    for value in values:
        await rig.node("Feed/Override").write_value(ua.Variant(value, ua.VariantType.UInt16))
        dv = await rig.read("Feed/Override")
        assert (dv.Value.Value, dv.StatusCode.is_good()) == (value, True)
    assert rig.sim is not None and rig.sim.machine.override == values[-1]


@pytest.mark.parametrize(
    ("path", "variant", "code"),
    [
        ("Axes/X/Position", ua.Variant(1.0, ua.VariantType.Double), "BadNotWritable"),
        ("Feed/Override", ua.Variant(151, ua.VariantType.UInt16), "BadOutOfRange"),
        ("Feed/Override", ua.Variant(50.0, ua.VariantType.Double), "BadTypeMismatch"),
        ("Status/Connected", ua.Variant(False, ua.VariantType.Boolean), "BadNotWritable"),
    ],
)
async def test_refused_writes_get_their_status_and_never_reach_the_controller(
    rig: Rig, path: str, variant: ua.Variant, code: str
) -> None:
    await wait_until(lambda: good(rig, "Feed/Override"), timeout=10, message="override Good")
    assert rig.sim is not None
    before = rig.sim.machine.override
    with pytest.raises(ua.UaStatusCodeError) as info:
        await rig.node(path).write_value(variant)
    assert type(info.value).__name__ == code
    assert rig.sim.machine.override == before


async def test_controller_outage_turns_values_bad_and_back_good(rig: Rig) -> None:
    await wait_until(lambda: good(rig, "Axes/X/Position"), timeout=10, message="X position Good")
    await rig.stop_simulator()

    async def bad() -> bool:
        dv = await rig.read("Axes/X/Position")
        return dv.StatusCode is not None and dv.StatusCode.is_bad()

    await wait_until(bad, timeout=5, message="X position Bad after the simulator stopped")
    assert (await rig.read("Status/Connected")).Value.Value is False
    assert (await rig.read("Status/State")).Value.Value == "disconnected"
    assert (await rig.read("Status/LastError")).Value.Value
    await rig.start_simulator()
    await wait_until(lambda: good(rig, "Axes/X/Position"), timeout=10, message="X position Good again")
    assert (await rig.read("Status/Connected")).Value.Value is True
    assert (await rig.read("Status/ReconnectCount")).Value.Value == 1


def with_extra_variable(entry: dict[str, str]) -> str:
    data = yaml.safe_load((ROOT / "mappings" / "laser-sim.yaml").read_text())
    data["variables"].append(entry)
    return yaml.safe_dump(data, sort_keys=False)


MISSING_NODE = with_extra_variable(
    {"path": "Extra/Missing", "source": "ns=2;s=::AsGlobalPV:gNoSuchThing", "type": "Double"}
)


@pytest.mark.parametrize("rig", [MISSING_NODE], indirect=True)
async def test_a_mapped_node_missing_on_the_controller_is_bad_alone(rig: Rig) -> None:
    await wait_until(lambda: good(rig, "Axes/X/Position"), timeout=10, message="X position Good")

    async def unknown() -> bool:
        dv = await rig.read("Extra/Missing")
        return dv.StatusCode is not None and dv.StatusCode.value == ua.StatusCodes.BadNodeIdUnknown

    await wait_until(unknown, timeout=5, message="Extra/Missing BadNodeIdUnknown")
    assert await good(rig, "Feed/Rate")
