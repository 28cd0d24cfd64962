"""PLCs and auxiliaries (issue 26): the Modbus TCP and S7 drivers beside their libraries' raw clients.

Modbus: 20 devices of 500 holding registers each (bench/agents/modbus_devices.py, the simulator's
Modbus face, its own process; 50 registers of each device change every 100 ms), mapped as 100 float32
and 300 uint16 variables per device (8,000 variables, 10,000 registers). The gateway side is the real
driver (`ModbusSource`, one per device, feeding one variable tree) in this process; the baseline is
pymodbus' AsyncModbusTcpClient, one per device, reading the same requests (the driver's plan) on the
same schedule, in this process too, in windows alternating with the driver's. Per window: poll cycles
achieved against those configured, registers read per second, changes per second into the tree, the
CPU of this process. At the configured 100 ms, and flat out (10 ms, the driver's shortest interval).

S7: 5 PLCs (bench/agents/s7_plcs.py, python-snap7's server, its own process), each with a DB of 200 REALs
and 200 INTs (2,000 variables; a tenth change every 100 ms), read by the real driver (`S7Source`) at
100 ms and flat out, beside snap7's AsyncClient reading the same items (`read_area`, one request per
item as that client reads; the driver's plan has one item a request here too, the block being
contiguous and larger than a PDU's item) and decoding every variable with snap7.util.
"""

from __future__ import annotations

import asyncio
import statistics
import time
from typing import Any

from bench.context import Context
from bench.procs import Agent
from gateway.codecs.modbus.planner import Request, plan
from gateway.config.mapping import MachineMapping
from gateway.model.tree import VariableTree
from gateway.sources.modbus.config import ModbusDriver
from gateway.sources.modbus.source import ModbusSource

SECTION = "PLCs: Modbus TCP and S7 drivers beside their libraries' raw clients"
DEVICES = 20
REGISTERS = 500
FLOATS = 100  # float32 at 0-199, then uint16 at 200-499
CHANGE = 50  # registers changed per device every 100 ms


def modbus_mapping(index: int, port: int, interval: float) -> MachineMapping:
    variables = [
        {"path": f"F/f{i:03d}", "source": f"holding:{2 * i}", "type": "Float"} for i in range(FLOATS)
    ]
    variables += [
        {"path": f"U/u{i:03d}", "source": f"holding:{a}", "type": "UInt16"}
        for i, a in enumerate(range(2 * FLOATS, REGISTERS))
    ]
    return MachineMapping.model_validate({
        "machine": f"dev-{index:02d}",
        "driver": {"type": "modbus", "host": "127.0.0.1", "port": port, "timeout": 2},
        "defaults": {"sampling_interval": interval},
        "variables": variables,
    })  # fmt: skip


def _plan(mapping: MachineMapping) -> list[Request[int]]:
    driver = mapping.driver
    assert isinstance(driver, ModbusDriver)
    variables = mapping.variables
    entries = [(i, v.source, v.raw_type, mapping.sampling_interval(v)) for i, v in enumerate(variables)]
    groups = driver.polling_groups(entries)
    return [r for fields in groups.values() for r in plan(fields, driver.limits)]


async def _gateway_window(ctx: Context, mappings: list[MachineMapping], interval: float) -> dict[str, Any]:
    tree = VariableTree([m.definition() for m in mappings])
    sources = [ModbusSource(tree.machines[m.machine], m) for m in mappings]
    tasks = [asyncio.create_task(s.run(), name=f"modbus:{s.machine.name}") for s in sources]
    try:
        await asyncio.sleep(ctx.settings.warmup)

        def counters() -> tuple[int, int, int, float, float]:
            cycles = sum(g.cycles for s in sources for g in s.groups)
            registers = sum(s.registers for s in sources)
            changes = sum(m.changes for m in tree.machines.values())
            return cycles, registers, changes, time.process_time(), time.monotonic()

        c0, r0, ch0, cpu0, t0 = counters()
        overruns0 = sum(g.overruns for s in sources for g in s.groups)
        await asyncio.sleep(ctx.settings.window)
        c1, r1, ch1, cpu1, t1 = counters()
        elapsed = t1 - t0
        requests = sum(len(g.reads) for s in sources for g in s.groups)
        variables = sum(len(m.variables) for m in mappings)
        return {
            "cycles_ratio": (c1 - c0) / (len(sources) * elapsed / (interval / 1000.0)),
            "registers_per_s": (r1 - r0) / elapsed,
            "changes_per_s": (ch1 - ch0) / elapsed,
            "cpu": (cpu1 - cpu0) / elapsed,
            "overruns": sum(g.overruns for s in sources for g in s.groups) - overruns0,
            "requests_per_variable": requests / variables,
            "requests_per_cycle": requests,
            "connected": sum(1 for s in sources if s.machine.status.is_connected),
        }
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for source in sources:
            await source.__aexit__(None, None, None)


async def _raw_window(
    ctx: Context, ports: list[int], plans: list[list[Request[int]]], interval: float
) -> dict[str, Any]:
    from pymodbus.client import AsyncModbusTcpClient

    period = interval / 1000.0
    counts = {"cycles": 0, "registers": 0}
    clients = [
        AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0, reconnect_delay=0)
        for port in ports
    ]

    async def poll(client: AsyncModbusTcpClient, requests: list[Request[int]]) -> None:
        me = asyncio.current_task()
        assert me is not None
        await client.connect()
        due = time.monotonic()
        while True:
            delay = due - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            for r in requests:
                response = await client.read_holding_registers(r.start, count=r.count, device_id=1)
                counts["registers"] += len(response.registers)
                if me.cancelling():  # pymodbus' wait_for drops a cancel that meets an answer (Python 3.11)
                    raise asyncio.CancelledError
            counts["cycles"] += 1
            due = max(due + period, time.monotonic() - period)

    tasks = [asyncio.create_task(poll(c, p)) for c, p in zip(clients, plans, strict=True)]
    try:
        await asyncio.sleep(ctx.settings.warmup)
        c0, r0, cpu0, t0 = counts["cycles"], counts["registers"], time.process_time(), time.monotonic()
        await asyncio.sleep(ctx.settings.window)
        c1, r1, cpu1, t1 = counts["cycles"], counts["registers"], time.process_time(), time.monotonic()
        elapsed = t1 - t0
        return {
            "cycles_ratio": (c1 - c0) / (len(clients) * elapsed / period),
            "registers_per_s": (r1 - r0) / elapsed,
            "cpu": (cpu1 - cpu0) / elapsed,
        }
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for client in clients:
            client.close()


def _median(windows: list[dict[str, Any]], key: str) -> float | None:
    values = [w[key] for w in windows if w.get(key) is not None]
    return statistics.median(values) if values else None


async def run(ctx: Context) -> None:
    details: dict[str, Any] = ctx.results.details.setdefault("plc", {})
    await _modbus(ctx, details)
    await _s7(ctx, details)


PLCS = 5
REALS = 200
INTS = 200


def s7_mapping(index: int, port: int, interval: float) -> MachineMapping:
    variables = [{"path": f"R/r{i:03d}", "source": f"DB1.DBD{4 * i}", "type": "Float"} for i in range(REALS)]
    variables += [
        {"path": f"I/i{i:03d}", "source": f"DB1.DBW{4 * REALS + 2 * i}", "type": "Int16"} for i in range(INTS)
    ]
    return MachineMapping.model_validate({
        "machine": f"plc-{index}",
        "driver": {"type": "s7", "host": "127.0.0.1", "port": port, "timeout": 2},
        "defaults": {"sampling_interval": interval},
        "variables": variables,
    })  # fmt: skip


async def _s7_gateway_window(ctx: Context, mappings: list[MachineMapping], interval: float) -> dict[str, Any]:
    from gateway.sources.s7.source import S7Source

    tree = VariableTree([m.definition() for m in mappings])
    sources = [S7Source(tree.machines[m.machine], m) for m in mappings]
    tasks = [asyncio.create_task(s.run(), name=f"s7:{s.machine.name}") for s in sources]
    try:
        await asyncio.sleep(ctx.settings.warmup)

        def counters() -> tuple[int, int, int, float, float]:
            cycles = sum(g.cycles for s in sources for g in s.groups)
            return (cycles, sum(s.values for s in sources), sum(m.changes for m in tree.machines.values()),
                    time.process_time(), time.monotonic())  # fmt: skip

        c0, v0, ch0, cpu0, t0 = counters()
        await asyncio.sleep(ctx.settings.window)
        c1, v1, ch1, cpu1, t1 = counters()
        elapsed = t1 - t0
        return {
            "cycles_ratio": (c1 - c0) / (len(sources) * elapsed / (interval / 1000.0)),
            "variables_per_s": (v1 - v0) / elapsed,
            "changes_per_s": (ch1 - ch0) / elapsed,
            "cpu": (cpu1 - cpu0) / elapsed,
            "requests_per_cycle": sum(len(g.reads) for s in sources for g in s.groups),
            "pdu": [s.link.pdu_size for s in sources],
        }
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for source in sources:
            await source.__aexit__(None, None, None)


async def _s7_raw_window(ctx: Context, ports: list[int], interval: float) -> dict[str, Any]:
    import snap7
    from snap7.type import Area
    from snap7.util import get_int, get_real

    from gateway.codecs.s7.pdu import max_item

    period = interval / 1000.0
    counts = {"cycles": 0, "variables": 0}
    size = 4 * REALS + 2 * INTS

    async def poll(port: int) -> None:
        me = asyncio.current_task()
        assert me is not None
        client = snap7.AsyncClient()
        await client.connect("127.0.0.1", 0, 1, port)
        chunk = max_item(client.pdu_length) // 4 * 4
        try:
            due = time.monotonic()
            while True:
                delay = due - time.monotonic()
                if delay > 0:
                    await asyncio.sleep(delay)
                data = bytearray()
                for start in range(0, size, chunk):
                    data += await client.read_area(Area.DB, 1, start, min(chunk, size - start))
                    if me.cancelling():  # snap7's wait_for drops a cancel that meets an answer (Python 3.11)
                        raise asyncio.CancelledError
                values = [get_real(data, 4 * i) for i in range(REALS)]
                values += [get_int(data, 4 * REALS + 2 * i) for i in range(INTS)]
                counts["variables"] += len(values)
                counts["cycles"] += 1
                due = max(due + period, time.monotonic() - period)
        finally:
            await client.disconnect()

    tasks = [asyncio.create_task(poll(port)) for port in ports]
    try:
        await asyncio.sleep(ctx.settings.warmup)
        c0, v0, cpu0, t0 = counts["cycles"], counts["variables"], time.process_time(), time.monotonic()
        await asyncio.sleep(ctx.settings.window)
        c1, v1, cpu1, t1 = counts["cycles"], counts["variables"], time.process_time(), time.monotonic()
        elapsed = t1 - t0
        return {
            "cycles_ratio": (c1 - c0) / (len(ports) * elapsed / period),
            "variables_per_s": (v1 - v0) / elapsed,
            "cpu": (cpu1 - cpu0) / elapsed,
        }
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def _s7(ctx: Context, details: dict[str, Any]) -> None:
    plcs = await Agent.start(
        "s7-plcs", "bench.agents.s7_plcs", ["--plcs", str(PLCS), "--reals", str(REALS), "--ints", str(INTS)],
        ctx.workdir,
    )  # fmt: skip
    ports: list[int] = plcs.ready["ports"]
    result: dict[str, Any] = {"plcs": PLCS, "variables": PLCS * (REALS + INTS)}
    details["s7"] = result
    rounds = 1 if ctx.settings.quick else 2
    try:
        for interval in (100.0, 10.0):
            mappings = [s7_mapping(i, port, interval) for i, port in enumerate(ports)]
            gateway: list[dict[str, Any]] = []
            raw: list[dict[str, Any]] = []
            for _ in range(rounds):
                gateway.append(await _s7_gateway_window(ctx, mappings, interval))
                raw.append(await _s7_raw_window(ctx, ports, interval))
            step: dict[str, Any] = {
                key: {"gateway": _median(gateway, key), "raw": _median(raw, key)}
                for key in ("cycles_ratio", "variables_per_s", "cpu")
            }
            step["changes_per_s"] = _median(gateway, "changes_per_s")
            step["requests_per_cycle"] = gateway[0]["requests_per_cycle"]
            step["pdu"] = gateway[0]["pdu"]
            step["windows"] = {"gateway": gateway, "raw": raw}
            result[f"{interval:g}ms"] = step
            label = "100 ms" if interval == 100 else "flat out (10 ms)"
            g, b = step["variables_per_s"]["gateway"], step["variables_per_s"]["raw"]
            cycles, cpu = step["cycles_ratio"], step["cpu"]
            note = (
                f"cycles {cycles['gateway'] or 0:.1%} (raw {cycles['raw'] or 0:.1%}), "
                f"CPU {cpu['gateway'] or 0:.0%} (raw {cpu['raw'] or 0:.0%}), "
                f"{step['changes_per_s'] or 0:,.0f} changes/s into the tree"
            )
            ctx.results.add(
                f"plc.s7.{interval:g}ms.variables_s", SECTION,
                f"S7: variables read/s, 5 PLCs x 400, poll {label}", g, "var/s",
                baseline=b, baseline_label="snap7's AsyncClient, same items, same schedule", note=note,
            )  # fmt: skip
            ctx.log(f"s7 {label}: gateway {g or 0:,.0f} var/s, raw {b or 0:,.0f} var/s; {note}")
        result["variables_per_s"] = result["100ms"]["variables_per_s"]
        result["flat_variables_per_s"] = result["10ms"]["variables_per_s"]
    finally:
        await plcs.stop()


async def _modbus(ctx: Context, details: dict[str, Any]) -> None:
    devices = await Agent.start(
        "modbus-devices", "bench.agents.modbus_devices",
        ["--devices", str(DEVICES), "--registers", str(REGISTERS), "--change", str(CHANGE)], ctx.workdir,
    )  # fmt: skip
    ports: list[int] = devices.ready["ports"]
    result: dict[str, Any] = {"devices": DEVICES, "registers": DEVICES * REGISTERS}
    details["modbus"] = result
    rounds = 1 if ctx.settings.quick else 2
    try:
        for interval in (100.0, 10.0):
            mappings = [modbus_mapping(i, port, interval) for i, port in enumerate(ports)]
            plans = [_plan(m) for m in mappings]
            gateway: list[dict[str, Any]] = []
            raw: list[dict[str, Any]] = []
            for _ in range(rounds):
                gateway.append(await _gateway_window(ctx, mappings, interval))
                raw.append(await _raw_window(ctx, ports, plans, interval))
            step = {
                key: {"gateway": _median(gateway, key), "raw": _median(raw, key)}
                for key in ("cycles_ratio", "registers_per_s", "cpu")
            }
            step["changes_per_s"] = _median(gateway, "changes_per_s")
            step["requests_per_variable"] = gateway[0]["requests_per_variable"]
            step["requests_per_cycle"] = gateway[0]["requests_per_cycle"]
            step["overruns"] = [w["overruns"] for w in gateway]
            step["windows"] = {"gateway": gateway, "raw": raw}
            result[f"{interval:g}ms"] = step
            label = "100 ms" if interval == 100 else "flat out (10 ms)"
            g, b = step["registers_per_s"]["gateway"], step["registers_per_s"]["raw"]
            cycles, cpu = step["cycles_ratio"], step["cpu"]
            note = (
                f"cycles {cycles['gateway'] or 0:.1%} (raw {cycles['raw'] or 0:.1%}), "
                f"CPU {cpu['gateway'] or 0:.0%} (raw {cpu['raw'] or 0:.0%}), "
                f"{step['changes_per_s'] or 0:,.0f} changes/s into the tree"
            )
            ctx.results.add(
                f"plc.modbus.{interval:g}ms.registers_s", SECTION,
                f"Modbus: registers read/s, 20 devices x 500, poll {label}", g, "reg/s",
                baseline=b, baseline_label="pymodbus' raw client, same requests, same schedule", note=note,
            )  # fmt: skip
            ctx.log(f"modbus {label}: gateway {g or 0:,.0f} reg/s, raw {b or 0:,.0f} reg/s; {note}")
        result["device_process"] = await devices.ask("snap")
    finally:
        await devices.stop()
