"""The Haas MDC driver over real TCP against the simulator's MDC face (mappings/haas-sim.yaml).

Q-command values arrive typed (times in seconds, Q500's three fields, Q600 variables); a ?E write goes
to the control and is read back; a second client polling the same control (whose answers the control
sends to both, as a Haas does) does not confuse the gateway, which counts them as unsolicited; a
third connection is refused by the control; the control going away turns every value Bad.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gateway.codecs.haas_mdc.protocol import Query
from gateway.config.loader import load_mapping
from gateway.errors import SourceError
from gateway.model.context import WriteContext
from gateway.sources.haas_mdc.connection import MdcConnection
from gateway.sources.haas_mdc.source import HaasMdcSource
from tests.integration.focas.conftest import ROOT, gateway_config, running, value
from tests.waiting import wait_until

MACHINE = "haas-sim"
CTX = WriteContext("test", "tester", "admin")


def haas_mapping(port: int):  # type: ignore[no-untyped-def]
    mapping = load_mapping(ROOT / "mappings" / "haas-sim.yaml", environ={"HAAS_SIM_PORT": str(port)})
    driver = mapping.driver.model_validate(
        {**mapping.driver.model_dump(), "reconnect": {"initial": 0.1, "max": 0.5}}
    )
    return mapping.model_copy(update={"driver": driver})


async def test_the_gateway_reads_and_writes_a_haas_and_tolerates_another_client(tmp_path: Path) -> None:
    from simulator.runner import Simulator

    sim = Simulator(opcua_port=0, ftp_port=0, haas_port=0, store=tmp_path / "store")
    await sim.__aenter__()
    assert sim.haas is not None
    port = sim.haas.port
    other = MdcConnection("127.0.0.1", port, 2.0)
    try:
        async with running(gateway_config(tmp_path, haas_mapping(port))) as gw:
            machine = gw.tree.machines[MACHINE]
            await wait_until(lambda: machine.status.is_connected, timeout=10, message="connected")
            await wait_until(lambda: value(gw, "Program/Status", MACHINE) == "IDLE", message="Q500")
            assert value(gw, "Controller/Serial", MACHINE) == "1234567"
            assert value(gw, "Machine/Mode", MACHINE) == "MEM"
            await wait_until(lambda: isinstance(value(gw, "Times/PowerOn", MACHINE), int), message="Q300")
            assert value(gw, "Axes/X/Position", MACHINE) == 0.0
            # a ?E write, read back before it is answered
            await machine.write("Macros/V10500", 2.75, CTX)
            assert value(gw, "Macros/V10500", MACHINE) == 2.75 and sim.haas.macros[10500] == 2.75
            # another client on the control's second connection: its answers reach the gateway too
            await other.open()
            source = next(s for s in gw.sources if isinstance(s, HaasMdcSource))
            assert source.connection is not None
            before = source.connection.unsolicited
            for _ in range(20):
                assert (await other.ask(Query(102))).fields == ("LASER-SIM",)
                assert (await other.ask(Query(600, 5022))).label == "MACRO"
            await wait_until(lambda: source.connection is not None and source.connection.unsolicited > before,
                             message="unsolicited answers counted")  # fmt: skip
            cycles = source.cycles
            await wait_until(lambda: source.cycles > cycles + 3, message="polling goes on")
            assert machine.status.is_connected and value(gw, "Controller/Model", MACHINE) == "LASER-SIM"
            # a third connection: the control takes two
            third = MdcConnection("127.0.0.1", port, 1.0)
            await third.open()
            with pytest.raises(SourceError):
                await third.ask(Query(100))
            assert sim.haas.refused == 1
            # a running program: Q500 answers STATUS, BUSY; the program and parts are then unavailable
            sim.machine.select_program("demo.nc")
            sim.machine.start()
            await wait_until(lambda: value(gw, "Program/Status", MACHINE) == "BUSY", message="BUSY")
            node = gw.tree.find(MACHINE, "Parts/Count")
            await wait_until(lambda: node.sample.status == "BadDataUnavailable", message="parts unavailable")
            # the control goes away
            await sim.__aexit__(None, None, None)
            x = gw.tree.find(MACHINE, "Axes/X/Position")
            await wait_until(lambda: x.sample.status == "BadNotConnected", message="Bad")
            await asyncio.sleep(0)
    finally:
        other.close()
        await sim.__aexit__(None, None, None)
