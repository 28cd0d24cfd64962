"""The FOCAS driver over real TCP against the simulator's FOCAS face: values, alarms, writes, outages.

The gateway runs mappings/fanuc-sim.yaml: positions, status, program, macros, PMC, parameters arrive
typed; an alarm on the machine becomes one of the gateway's alarms; writes of macros and PMC data go
to the control and are read back; commands select and start a program; a control that goes away
turns every value Bad, and they come back with it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.errors import ControllerRefused, OutOfRange
from gateway.model.context import WriteContext
from simulator.alarms import soft_limit
from tests.integration.focas.conftest import MACHINE, fanuc_mapping, gateway_config, running, simulator, value
from tests.waiting import wait_until

CTX = WriteContext("test", "tester", "admin")


async def test_the_gateway_reads_values_alarms_and_survives_an_outage(tmp_path: Path) -> None:
    sim = simulator(tmp_path, speed=20.0, loop_program="demo.nc")
    await sim.__aenter__()
    assert sim.focas is not None
    port = sim.focas.port
    try:
        async with running(gateway_config(tmp_path, fanuc_mapping(port))) as gw:
            machine = gw.tree.machines[MACHINE]
            await wait_until(lambda: machine.status.is_connected, timeout=10, message="connected")
            await wait_until(lambda: value(gw, "Machine/Run") == 3, message="running (STRT)")
            await wait_until(lambda: isinstance(value(gw, "Axes/X/Position"), float), message="positions")
            assert value(gw, "Controller/Series") == "G4A1"
            assert value(gw, "Controller/Type") == "31"
            assert value(gw, "Program/Name") == "demo.nc"
            assert value(gw, "Machine/Mode") == 1  # MEM
            assert value(gw, "Spindle/Override") == 100
            assert value(gw, "Feed/Override") == 100
            assert len(value(gw, "Axes/Relative")) == 3
            await wait_until(lambda: value(gw, "PMC/Automatic") is True, message="F0.7 while running")
            assert value(gw, "ActiveAlarms/Numbers") == []
            # an alarm on the machine becomes one of the gateway's alarms
            sim.machine.raise_alarm(soft_limit("X", "+", 12))
            await wait_until(lambda: value(gw, "ActiveAlarms/Numbers") == [1001], message="the alarm list")
            assert value(gw, "ActiveAlarms/Types") == [4]  # OT: overtravel
            assert "Soft limit X+" in value(gw, "ActiveAlarms/Messages")[0]
            assert gw.alarms is not None
            manager = gw.alarms.managers[MACHINE]
            await wait_until(
                lambda: [r.id for r in manager.records.values() if r.active] == ["1001"], message="alarm"
            )
            record = next(r for r in manager.records.values() if r.active)
            assert record.severity == 700
            # reset through the PMC (ERS, as a ladder takes it): the alarm clears
            await machine.write("PMC/ExternalReset", True, CTX)
            await wait_until(lambda: not any(r.active for r in manager.records.values()), message="cleared")
            # the control goes away: every value Bad, with the reason; back with it
            await sim.__aexit__(None, None, None)
            await wait_until(lambda: not machine.status.is_connected, message="lost")
            node = gw.tree.find(MACHINE, "Axes/X/Position")
            await wait_until(lambda: node.sample.status == "BadNotConnected", message="Bad")
            sim = simulator(tmp_path, port, speed=20.0)
            await sim.__aenter__()
            await wait_until(lambda: node.sample.good, timeout=10, message="Good again")
            assert machine.status.reconnects >= 1
    finally:
        await sim.__aexit__(None, None, None)


async def test_writes_go_to_the_control_and_are_read_back(tmp_path: Path) -> None:
    async with (
        simulator(tmp_path) as sim,
        running(gateway_config(tmp_path, fanuc_mapping(sim.focas.port))) as gw,
    ):  # type: ignore[union-attr]
        machine = gw.tree.machines[MACHINE]
        await wait_until(lambda: machine.status.is_connected, timeout=10, message="connected")
        await wait_until(lambda: value(gw, "Macros/M500") is not None, message="macros")
        await machine.write("Macros/M500", 12.345, CTX)
        assert value(gw, "Macros/M500") == 12.345  # read back before the write was answered
        assert sim.focas is not None and sim.focas.cnc.macros[500] == 12.345
        await machine.write("PMC/D2204", -1234, CTX)
        assert value(gw, "PMC/D2204") == -1234
        assert sim.focas.cnc.pmc["D"][2204:2206] == (-1234).to_bytes(2, "little", signed=True)
        await machine.write("PMC/R100", 7, CTX)
        assert value(gw, "PMC/R100") == 7
        await machine.write("Parts/Required", 40, CTX)
        assert value(gw, "Parts/Required") == 40
        # the control refuses what it does not hold: its reason comes back
        with pytest.raises(ControllerRefused, match="EW_DATA"):
            await machine.write("Program/Select", "no-such-program.nc", CTX)
        # select and start through the commands
        await machine.write("Program/Select", "demo.nc", CTX)
        await wait_until(lambda: value(gw, "Program/Name") == "demo.nc", message="selected")
        await machine.write("Program/Start", True, CTX)
        await wait_until(lambda: value(gw, "Machine/Run") == 3, message="started")
        assert sim.machine.program.name == "demo.nc"
        # a macro write the control refuses (a system variable) names the code
        with pytest.raises(OutOfRange):
            await machine.write("Macros/M501", 1e12, CTX)


async def test_commands_select_start_and_reset_a_fanuc_with_their_guards(tmp_path: Path) -> None:
    """mappings/fanuc-sim.yaml's commands: select-program, start (cnc_start), reset (ERS through the PMC),
    each refused by its guard where the machine's state does not allow it."""
    from gateway.errors import InvalidState

    ctx = WriteContext("test", role="operator")
    async with (
        simulator(tmp_path) as sim,
        running(gateway_config(tmp_path, fanuc_mapping(sim.focas.port))) as gw,
    ):  # type: ignore[union-attr]
        machine = gw.tree.machines[MACHINE]
        await wait_until(lambda: value(gw, "Machine/Run") == 0, timeout=10, message="connected, reset state")
        methods = machine.methods
        await machine.call_method(methods[("Commands", "select-program")], ["soft-limit.nc"], ctx)
        assert sim.machine.program.name == "soft-limit.nc"
        await machine.call_method(methods[("Commands", "start")], [], ctx)
        await wait_until(
            lambda: value(gw, "ActiveAlarms/Numbers") == [1001], timeout=15, message="the soft-limit alarm"
        )
        await wait_until(lambda: value(gw, "Machine/Run") == 1, message="STOP after the alarm")
        await machine.call_method(
            methods[("Commands", "reset")], [], ctx
        )  # ERS: done when Machine/Alarm is 0
        assert not sim.machine.alarms
        sim.machine.select_program("demo.nc")
        sim.machine.start()
        await wait_until(lambda: value(gw, "Machine/Run") == 3, message="running")
        with pytest.raises(
            InvalidState, match="Machine/Run is 3"
        ):  # select-program's guard: not while running
            await machine.call_method(methods[("Commands", "select-program")], ["soft-limit.nc"], ctx)
        assert sim.machine.program.name == "demo.nc"
