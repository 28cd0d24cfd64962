"""The SHDR driver over real TCP: the gateway on the simulator's adapter, a silent adapter, junk on the line.

The gateway runs mappings/laser-sim-shdr.yaml against a simulator whose SHDR face listens
on a free port: values arrive converted to their types, alarms arrive as conditions and
become the gateway's alarms, an adapter that goes away turns every value Bad (and they
come back with it). A fake adapter that stops answering PINGs is dropped; one that sends
the whole bad-input corpus is read to its end, every bad line counted, none fatal.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.config.mapping import MachineMapping
from gateway.sinks.mtconnect.config import AgentConfig
from simulator.alarms import soft_limit
from simulator.runner import Simulator
from tests.unit.codecs.mtconnect.test_corpus import cases
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
MACHINE = "laser-shdr"


def shdr_mapping(port: int, **driver: Any) -> MachineMapping:
    mapping = load_mapping(
        ROOT / "mappings" / "laser-sim-shdr.yaml", environ={"LASER_SIM_SHDR_PORT": str(port)}
    )
    settings = {"reconnect": {"initial": 0.1, "max": 0.5, "factor": 2}, **driver}
    return mapping.model_copy(
        update={"driver": mapping.driver.model_validate({**mapping.driver.model_dump(), **settings})}
    )


def gateway_config(tmp_path: Path, mapping: MachineMapping, *, agent: bool = False) -> Config:
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway", "security": ["None"]},
            "state_dir": str(tmp_path / "state"),
            "inbox": {"enabled": False},
        }
    )
    if agent:
        gateway = gateway.model_copy(update={"mtconnect": AgentConfig(host="127.0.0.1", port=0)})
    return Config(gateway, (mapping,), tmp_path)


@asynccontextmanager
async def running(config: Config) -> AsyncIterator[Gateway]:
    async with Gateway(config) as gw:
        task = asyncio.create_task(gw.run(), name="gateway")
        try:
            yield gw
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def value(gw: Gateway, path: str) -> Any:
    sample = gw.tree.find(MACHINE, path).sample
    return sample.value if sample.good else None


async def test_the_gateway_reads_the_simulators_adapter_values_alarms_and_outages(tmp_path: Path) -> None:
    sim_args = {
        "opcua_port": 0,
        "ftp_port": 0,
        "speed": 20.0,
        "loop_program": "demo.nc",
        "store": tmp_path / "store",
    }
    sim = Simulator(shdr_port=0, **sim_args)  # type: ignore[arg-type]
    await sim.__aenter__()
    assert sim.shdr is not None
    port = sim.shdr.port
    try:
        async with running(gateway_config(tmp_path, shdr_mapping(port))) as gw:
            machine = gw.tree.machines[MACHINE]
            await wait_until(lambda: machine.status.is_connected, timeout=10, message="connected")
            await wait_until(lambda: value(gw, "Machine/Execution") == "ACTIVE", message="running")
            await wait_until(lambda: isinstance(value(gw, "Axes/X/Position"), float), message="positions")
            assert value(gw, "Program/Name") == "demo.nc"
            assert value(gw, "Laser/On") in (True, False)
            assert value(gw, "EmergencyStop") == "ARMED"
            assert value(gw, "Controller/System") == []
            # an alarm on the machine: a FAULT condition, then one of the gateway's alarms
            sim.machine.raise_alarm(soft_limit("X", "+", 12))
            await wait_until(lambda: value(gw, "Controller/System"), message="the condition")
            assert value(gw, "Controller/System")[0].startswith("FAULT|1001|3||")
            assert gw.alarms is not None
            manager = gw.alarms.managers[MACHINE]
            await wait_until(
                lambda: [r.id for r in manager.records.values() if r.active] == ["1001"], message="alarm"
            )
            record = next(r for r in manager.records.values() if r.active)
            assert record.severity == 700 and "Soft limit X+" in record.text
            sim.machine.reset()
            await wait_until(lambda: not any(r.active for r in manager.records.values()), message="cleared")
            # the adapter goes away: every value Bad, with the reason; back with it
            await sim.__aexit__(None, None, None)
            await wait_until(lambda: not machine.status.is_connected, message="lost")
            node = gw.tree.find(MACHINE, "Axes/X/Position")
            await wait_until(lambda: node.sample.status == "BadNotConnected", message="Bad")
            sim = Simulator(shdr_port=port, **sim_args)  # type: ignore[arg-type]
            await sim.__aenter__()
            await wait_until(lambda: node.sample.good, timeout=10, message="Good again")
            assert machine.status.reconnects >= 1
    finally:
        await sim.__aexit__(None, None, None)


@asynccontextmanager
async def fake_adapter(
    serve: Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]],
) -> AsyncIterator[int]:
    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    try:
        yield server.sockets[0].getsockname()[1]
    finally:
        server.close()


async def test_an_adapter_that_stops_answering_pings_is_dropped(tmp_path: Path) -> None:
    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert await reader.readline() == b"* PING\n"
        writer.write(b"* PONG 200\n|Xact|12.5\n")  # a 200 ms period, then silence (a hung adapter)
        await asyncio.sleep(30)

    async with fake_adapter(serve) as port, running(gateway_config(tmp_path, shdr_mapping(port))) as gw:
        machine = gw.tree.machines[MACHINE]
        node = gw.tree.find(MACHINE, "Axes/X/Position")
        await wait_until(lambda: node.sample.good and node.sample.value == 12.5, message="the value")
        await wait_until(lambda: node.sample.status == "BadNotConnected", timeout=3, message="dropped")
        assert "heartbeat" in machine.status.last_error


async def test_the_bad_input_corpus_over_tcp_is_counted_and_reading_goes_on(tmp_path: Path) -> None:
    corpus = [c for c in cases("shdr.yaml") if "max_line" not in c]  # the driver reads with the default limit
    wire = b""
    for n, case in enumerate(corpus):
        data = bytes.fromhex(case["hex"]) if "hex" in case else case["text"].encode("utf-8")
        data += case.get("then", "").encode("utf-8") * case.get("repeat", 1 if "then" in case else 0)
        data += case.get("end", "").encode("utf-8")
        wire += data + f"|sentinel|{n}\n".encode()
    expected = sum(len(case["junk"]) for case in corpus)

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await reader.readline()
        writer.write(b"* PONG 10000\n")
        for start in range(0, len(wire), 1000):  # in pieces, as a network delivers it
            writer.write(wire[start : start + 1000])
            await writer.drain()
        await asyncio.sleep(30)

    base = shdr_mapping(1)
    extra = [
        {"path": "Corpus/Sentinel", "source": "sentinel", "type": "String"},
        {"path": "Corpus/Message", "source": "msg", "type": "String",
         "mtconnect": {"category": "EVENT", "type": "MESSAGE"}},
        {"path": "Corpus/Vibration", "source": "vib", "type": "Double[]",
         "mtconnect": {"category": "SAMPLE", "type": "DISPLACEMENT", "representation": "TIME_SERIES"}},
    ]  # fmt: skip
    data = base.model_dump(by_alias=True, exclude_none=True)
    data["variables"] = [v for v in data["variables"] if v["source"] != "system"]
    data["variables"].append({"path": "Corpus/System", "source": "system", "type": "String[]",
                              "mtconnect": {"category": "CONDITION", "type": "SYSTEM"}})  # fmt: skip
    data["variables"] += extra
    async with fake_adapter(serve) as port:
        data["driver"]["port"] = port
        mapping = MachineMapping.model_validate(data)
        async with running(gateway_config(tmp_path, mapping)) as gw:
            source = gw.sources[0]
            last = str(len(corpus) - 1)
            await wait_until(
                lambda: value(gw, "Corpus/Sentinel") == last, timeout=20, message="the last sentinel"
            )
            assert source.junk == expected  # type: ignore[attr-defined]
            assert gw.tree.machines[MACHINE].status.is_connected
