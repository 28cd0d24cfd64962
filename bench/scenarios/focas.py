"""FOCAS (issue 25): 20 Fanucs x 50 items at a 100 ms poll, and a 1 MB program download against FTP.

- Polling: 20 simulated Fanucs (bench/agents/focas_faces.py, their own process) and 20 FocasSources in
  this process, on one event loop as in the gateway, each mapping 50 items of every kind (status,
  positions, feed, program, macros, PMC, a parameter, the alarm list) at 100 ms. Figures over the
  window: the share of poll cycles that started on time (not after their slot, i.e. the previous cycle
  had not overrun), round trips per cycle relative to one per item, and this process's CPU (the
  gateway's side only: the faces are another process).
- Program transfer: one simulator with both faces; a 1 MB program delivered by the FOCAS transport and
  by the FTP transport into the same store, each checked by size, median of 3.
"""

from __future__ import annotations

import asyncio
import hashlib
import statistics
import time
from typing import Any

import psutil

from bench.context import Context
from bench.procs import Agent
from gateway.config.mapping import MachineMapping
from gateway.model.tree import VariableTree
from gateway.sources.focas.source import FocasSource
from gateway.transports.base import Program
from gateway.transports.focas.config import ControllerFocas
from gateway.transports.focas.transport import FocasTransport
from gateway.transports.ftp.config import ControllerFtp
from gateway.transports.ftp.transport import FtpTransport

SECTION = "FOCAS: 20 Fanucs x 50 items at 100 ms, program download"
MACHINES = 20
ITEMS = 50
INTERVAL = 100  # ms


def items() -> list[dict[str, Any]]:
    """50 items as a shop maps them: status, positions, feed and program, parts, macros, PMC, alarms."""
    out: list[dict[str, Any]] = [
        {"path": f"Status2/{f}", "source": f"status.{f}", "type": "Int16"}
        for f in ("mode", "run", "motion", "mstb", "emergency", "alarm", "edit")
    ]
    for kind in ("absolute", "machine", "relative", "distance"):
        out += [
            {"path": f"Axes/{a}/{kind}", "source": f"position.{kind}[{a}]", "type": "Double"} for a in "XYZ"
        ]
    out += [
        {"path": "Feed/Rate", "source": "feed.actual", "type": "Double"},
        {"path": "Feed/Override", "source": "feed.override", "type": "Int32"},
        {"path": "Spindle/Speed", "source": "spindle.actual", "type": "Double"},
        {"path": "Spindle/Override", "source": "spindle.override", "type": "Int32"},
        {"path": "Program/Number", "source": "program.number", "type": "Int32"},
        {"path": "Program/Name", "source": "program.name", "type": "String"},
        {"path": "Program/Sequence", "source": "program.sequence", "type": "Int32"},
        {"path": "Program/Block", "source": "program.block", "type": "String"},
        {"path": "Parts/Count", "source": "parts.count", "type": "Int32"},
        {"path": "Parts/Required", "source": "parts.required", "type": "Int32"},
        {"path": "Params/P6711", "source": "param:6711", "type": "Int32"},
        {"path": "Diag/ServoErrorX", "source": "diag:300[X]", "type": "Int32"},
        {"path": "Alarms2/Status", "source": "alarm.status", "type": "Int32"},
        {"path": "Alarms2/Numbers", "source": "alarms.number", "type": "Int32[]"},
        {"path": "Alarms2/Messages", "source": "alarms.message", "type": "String[]"},
    ]
    out += [{"path": f"Macros/M{n}", "source": f"#{n}", "type": "Double"} for n in range(500, 510)]
    out += [{"path": f"PMC/R{n}", "source": f"pmc:R{n}", "type": "Byte"} for n in range(100, 106)]
    assert len(out) == ITEMS, len(out)
    return out


def mapping(name: str, port: int) -> MachineMapping:
    return MachineMapping.model_validate({
        "machine": name,
        "driver": {"type": "focas", "host": "127.0.0.1", "port": port, "sessions": 2, "timeout": 5},
        "defaults": {"sampling_interval": INTERVAL},
        "variables": items(),
    })  # fmt: skip


async def run(ctx: Context) -> None:
    details: dict[str, Any] = {}
    ctx.results.details["focas"] = details
    await _polling(ctx, details)
    await _download(ctx, details)


async def _polling(ctx: Context, details: dict[str, Any]) -> None:
    s, r = ctx.settings, ctx.results
    args = ["--count", str(MACHINES), "--store", str(ctx.workdir / "faces-store")]
    faces = await Agent.start("focas-faces", "bench.agents.focas_faces", args, ctx.workdir)
    try:
        ports = faces.ready["ports"]
        mappings = tuple(mapping(f"fanuc-{i:02d}", port) for i, port in enumerate(ports))
        tree = VariableTree([m.definition() for m in mappings])
        sources = [FocasSource(tree.machines[m.machine], m) for m in mappings]
        tasks = []
        for source in sources:
            await source.__aenter__()
            tasks.append(asyncio.create_task(source.run()))
        await asyncio.sleep(s.warmup + 1.0)
        groups = [g for src in sources for g in src.groups]
        cycles0 = sum(g.cycles for g in groups)
        late0 = sum(g.late for g in groups)
        requests0 = sum(src.requests for src in sources)
        proc = psutil.Process()
        cpu0, t0 = sum(proc.cpu_times()[:2]), time.monotonic()
        await asyncio.sleep(s.window * 2)
        cpu1, t1 = sum(proc.cpu_times()[:2]), time.monotonic()
        cycles = sum(g.cycles for g in groups) - cycles0
        late = sum(g.late for g in groups) - late0
        requests = sum(src.requests for src in sources) - requests0
        good = all(n.sample.good for n in tree.nodes() if not n.internal)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for source in sources:
            await source.__aexit__(None, None, None)
    finally:
        await faces.stop()
    wall = t1 - t0
    expected = MACHINES * wall / (INTERVAL / 1000)
    on_time = (cycles - late) / cycles if cycles else None
    per_cycle = requests / cycles if cycles else None
    cpu = (cpu1 - cpu0) / wall * 100
    details.update(
        cycles=cycles, late=late, expected_cycles=round(expected), requests=requests, on_time=on_time,
        requests_per_cycle=per_cycle, relative=per_cycle / ITEMS if per_cycle else None, cpu_pct=cpu,
        all_good=good, window_s=round(wall, 1),
    )  # fmt: skip
    r.add(
        "focas.on_time", SECTION, "poll cycles on time (20 x 50 items, 100 ms)",
        100 * on_time if on_time else None, "%",
        note=f"{cycles} cycles of {expected:.0f} due, {late} late; every value Good: {good}",
    )  # fmt: skip
    r.add("focas.requests_per_cycle", SECTION, "round trips per cycle (50 items)", per_cycle, "requests",
          baseline=ITEMS, baseline_label="one request per item")  # fmt: skip
    r.add("focas.cpu", SECTION, "gateway CPU for that load", cpu, "% of a core")
    print(
        f"  polling: {cycles} cycles ({late} late) in {wall:.1f} s, "
        f"{per_cycle or 0:.2f} round trips a cycle, CPU {cpu:.1f} %",
        flush=True,
    )


async def _download(ctx: Context, details: dict[str, Any]) -> None:
    from simulator.runner import Simulator

    text = b"%\n(BENCH)\n" + b"G1 X1234.567 Y987.654 F12000\nG1 X10 Y10\n" * 24_000 + b"M30\n%\n"
    spool = ctx.workdir / "bench-1mb.nc"
    spool.write_bytes(text)
    program = Program("bench-1mb.nc", spool, len(text), hashlib.sha256(text).hexdigest())
    focas_s: list[float] = []
    ftp_s: list[float] = []
    async with Simulator(opcua_port=0, ftp_port=0, focas_port=0, store=ctx.workdir / "sim-store") as sim:
        assert sim.focas is not None
        focas = FocasTransport(ControllerFocas(type="focas", host="127.0.0.1", port=sim.focas.port))
        ftp = FtpTransport(ControllerFtp(host="127.0.0.1", port=sim.ftp_port, user=sim.ftp_user,
                                         password=sim.ftp_password))  # type: ignore[arg-type]  # fmt: skip
        for _ in range(3):
            for transport, times in ((focas, focas_s), (ftp, ftp_s)):
                t0 = time.perf_counter()
                await transport.deliver(program, lambda p: None)
                times.append(time.perf_counter() - t0)
    f, t = statistics.median(focas_s), statistics.median(ftp_s)
    details.update(download_bytes=len(text), focas_s=f, ftp_s=t, ratio=f / t)
    label = f"{len(text) / 1e6:.1f} MB program download over FOCAS"
    ctx.results.add(
        "focas.download", SECTION, label, f, "s", baseline=t, baseline_label="FTP to the same store",
        note=f"ratio {f / t:.2f}",
    )  # fmt: skip
    print(f"  download: FOCAS {f:.3f} s, FTP {t:.3f} s (x{f / t:.2f})", flush=True)
