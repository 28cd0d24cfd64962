"""Issue 27: what the umati view costs at scale, start-up and memory, with against without, same run.

20 machines × 500 noise variables from one simulator (the scale scenario's load), the gateway started
as `cnc-gateway run` twice per round, alternately: each mapping as the scale scenario writes it, then
the same with a `umati:` section (identification constants, a channel, a laser working unit, the active
program, bound to the machine's Status/ variables and one noise variable each: a MachineTool per
machine). Measured as the scale scenario does: process start → every variable Good at an MQTT
subscriber; RSS once settled with an OPC UA client subscribed to all 10,000. The NodeSets come from
their cache (gateway/shims/asyncua_nodesets.py) as on every start but the first: a first start that
writes it is run before the rounds and not counted.
"""

from __future__ import annotations

import asyncio
import signal
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from bench.context import Context
from bench.procs import ROOT, Agent, Meter, Mosquitto, child_env
from bench.scenarios.common import GATEWAY_URI, gateway_ids, ids_file, noise_paths, write_gateway
from simulator.noise import NoiseSpec, noise_mapping, split_machines

SECTION = "umati view (issue 27): 20 machines as MachineTools, start-up and RSS against the same run without"

STATES = "{connected: Running, connecting: Initializing, disconnected: Aborted}"


def umati_section(machine: str, first_path: str) -> str:
    """The `umati:` section of one noise machine (YAML text)."""
    return f"""
umati:
  identification:
    Manufacturer: bench
    SerialNumber: {machine}
    ProductInstanceUri: urn:bench:{machine}
    Model: noise machine
  channels:
    - name: Channel1
      state: {{variable: Status/State, values: {{connected: Active, connecting: Reset, disconnected: Reset}}}}
      mode: Automatic
      feed_override: {{variable: {first_path}}}
  laser:
    controller_is_on: {{variable: Status/Connected}}
    laser_state:
      variable: Status/State
      values: {{connected: Ready, connecting: Undefined, disconnected: Error}}
  program:
    name: noise
    state: {{variable: Status/State, values: {STATES}}}
"""


async def _one(ctx: Context, sim: Agent, label: str, with_umati: bool, index: int) -> dict[str, Any]:
    """One gateway start with a broker of its own (no retained topics of the start before)."""
    async with Mosquitto(ctx.workdir) as broker:
        return await _measure(ctx, sim, broker, label, with_umati, index)


async def _measure(
    ctx: Context, sim: Agent, broker: Mosquitto, label: str, with_umati: bool, index: int
) -> dict[str, Any]:
    s = ctx.settings
    machines, per = s.scale_machines, s.scale_per_machine
    total = machines * per
    spec = NoiseSpec(total)
    folder = ctx.workdir / f"umati-{label}-{index}"
    mappings = {}
    for k, (first, count) in enumerate(split_machines(spec, machines)):
        name = f"m{k:02d}"
        text = noise_mapping(
            spec,
            sim.ready["endpoint"],
            machine=name,
            first=first,
            count=count,
            publishing_interval=100,
            queue_size=1,
        )
        if with_umati:
            text += umati_section(name, noise_paths(first, 1)[0])
        mappings[name] = text
    config, endpoint = write_gateway(folder, mappings, mqtt_port=broker.port)
    topic = "cnc/+/noise/#"
    sub = await Agent.start(
        f"umati-mqtt-{label}-{index}",
        "bench.agents.mqtt_sub",
        ["--port", str(broker.port), "--topic", topic, "--qos", "1", "--expect", str(total)],
        ctx.workdir,
    )
    agents = [sub]
    log = (ctx.workdir / f"umati-gateway-{label}.log").open("ab")
    exe = Path(sys.executable).with_name("cnc-gateway")
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "gateway.cli.main"]
    started = time.time()
    proc = await asyncio.create_subprocess_exec(
        *command, "run", str(config), stdout=log, stderr=log, env=child_env(), cwd=str(ROOT)
    )
    out: dict[str, Any] = {}
    try:
        meter = Meter(proc.pid)
        deadline = time.monotonic() + 120
        while True:
            snap = await sub.ask("snap")
            if snap["all_good_at"] is not None:
                break
            if proc.returncode is not None or time.monotonic() > deadline:
                raise RuntimeError(
                    f"umati {label}: only {snap['good']} of {total} Good (see the gateway log)"
                )
            await asyncio.sleep(0.05)
        out["startup"] = snap["all_good_at"] - started
        paths = [p for k in range(machines) for p in gateway_ids(f"m{k:02d}", noise_paths(k * per, per))]
        ids = ids_file(folder / "ids.txt", GATEWAY_URI, paths)
        opcua = await Agent.start(
            f"umati-opcua-{label}-{index}",
            "bench.agents.opcua_sub",
            ["--endpoint", endpoint, "--ids", str(ids)],
            ctx.workdir,
        )
        agents.append(opcua)
        await asyncio.sleep(1.0)
        out["opcua_good"] = (await opcua.ask("snap"))["good"]
        await asyncio.sleep(max(1.0, s.scale_phase / 2))
        out["rss"] = meter.rss()
    finally:
        if proc.returncode is None:
            proc.send_signal(signal.SIGTERM)
            try:
                async with asyncio.timeout(10):
                    await proc.wait()
            except TimeoutError:
                proc.kill()
                await proc.wait()
        for agent in reversed(agents):
            await agent.stop()
    ctx.log(f"  {label:>7}: start-up {out['startup']:.2f} s, RSS {out['rss'] / 1e6:.0f} MB")
    return out


async def run(ctx: Context) -> None:
    s, r = ctx.settings, ctx.results
    total = s.scale_machines * s.scale_per_machine
    rounds = 1 if s.quick else 3
    ctx.log(f"umati: {s.scale_machines} machines × {s.scale_per_machine} variables, {rounds} round(s)")
    details: dict[str, Any] = {"machines": s.scale_machines, "per_machine": s.scale_per_machine, "runs": []}
    r.details["umati"] = details
    sim = await Agent.start("umati-sim", "bench.agents.simulator", ["--variables", str(total)], ctx.workdir)
    try:
        await _one(ctx, sim, "warm-up", True, 0)  # writes the NodeSets' cache if there is none
        for index in range(1, rounds + 1):
            for label, with_umati in (("without", False), ("with", True)):
                run_ = await _one(ctx, sim, label, with_umati, index)
                details["runs"].append({"label": label, **run_})
    finally:
        await sim.stop()
    for key in ("startup", "rss"):
        for label in ("without", "with"):
            values = [run_[key] for run_ in details["runs"] if run_["label"] == label]
            details[f"{key}_{label}"] = statistics.median(values) if values else None
    tag = f"{s.scale_machines} × {s.scale_per_machine}"
    without, with_ = details.get("startup_without"), details.get("startup_with")
    r.add(
        "umati.startup", SECTION, f"{tag}: start-up with the umati view (median of {rounds})", with_, "s",
        baseline=without, baseline_label="the same without",
    )  # fmt: skip
    rss_without, rss_with = details.get("rss_without"), details.get("rss_with")
    r.add(
        "umati.rss", SECTION, f"{tag}: RSS once settled with the umati view (median of {rounds})",
        rss_with / 1e6 if rss_with else None, "MB",
        baseline=rss_without / 1e6 if rss_without else None, baseline_label="the same without",
    )  # fmt: skip
