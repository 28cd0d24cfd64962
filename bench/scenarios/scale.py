"""Scale: 20 machines × 500 variables = 10,000, from one simulator process serving all of them.

The gateway is started the way a user starts it, `cnc-gateway run gateway.yaml`,
as a process of its own. Measured: the time from starting that process until an
MQTT subscriber (retained topics, connected before the start) has seen every
variable with Good quality; the resident memory once settled (an OPC UA client
subscribed to every variable, as SCADA would be); and the gateway's CPU while
nothing changes, and while every variable changes once (1 Hz) and ten times
(10 Hz) a second. Each machine has its own mapping file and its own OPC UA
session to the simulator (100 ms publishing, queue size 1, as the shipped
laser-sim mapping has).
"""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from pathlib import Path

from bench.context import Context
from bench.procs import ROOT, Agent, Meter, Mosquitto, child_env
from bench.scenarios.common import GATEWAY_URI, gateway_ids, ids_file, noise_paths, write_gateway
from gateway.shims.asyncua_ns0 import cache_file, default_cache_dir
from simulator.noise import NoiseSpec, noise_mapping, split_machines

SECTION = "Scale: machines × variables from one simulator, gateway started as `cnc-gateway run`"


async def run(ctx: Context) -> None:
    s, r = ctx.settings, ctx.results
    machines, per = s.scale_machines, s.scale_per_machine
    total = machines * per
    ctx.log(f"scale: {machines} machines × {per} variables = {total:,}")
    folder = ctx.workdir / "scale"
    spec = NoiseSpec(total)
    details: dict[str, object] = {"machines": machines, "per_machine": per, "variables": total}
    ctx.results.details["scale"] = details
    async with Mosquitto(ctx.workdir) as broker:
        sim = await Agent.start(
            "scale-sim", "bench.agents.simulator", ["--variables", str(total)], ctx.workdir
        )
        agents = [sim]
        proc = None
        try:
            mappings = {
                f"m{k:02d}": noise_mapping(
                    spec,
                    sim.ready["endpoint"],
                    machine=f"m{k:02d}",
                    first=first,
                    count=count,
                    publishing_interval=100,
                    queue_size=1,
                )
                for k, (first, count) in enumerate(split_machines(spec, machines))
            }
            config, gw_endpoint = write_gateway(folder, mappings, mqtt_port=broker.port)
            sub = await Agent.start(
                "scale-mqtt-sub",
                "bench.agents.mqtt_sub",
                [
                    "--port",
                    str(broker.port),
                    "--topic",
                    "cnc/+/noise/#",
                    "--qos",
                    "1",
                    "--expect",
                    str(total),
                ],
                ctx.workdir,
            )
            agents.append(sub)
            # The standard namespace's cache (gateway/shims/asyncua_ns0.py) that the gateway will find: a
            # start with it is every start but the first of this asyncua on this machine.
            folder_of_cache = default_cache_dir()
            details["ns0_cache"] = folder_of_cache is not None and cache_file(folder_of_cache).is_file()
            log = (ctx.workdir / "scale-gateway.log").open("ab")
            exe = Path(sys.executable).with_name("cnc-gateway")
            command = [str(exe)] if exe.exists() else [sys.executable, "-m", "gateway.cli.main"]
            started = time.time()
            proc = await asyncio.create_subprocess_exec(
                *command, "run", str(config), stdout=log, stderr=log, env=child_env(), cwd=str(ROOT)
            )
            meter = Meter(proc.pid)
            deadline = time.monotonic() + 120
            while True:
                snap = await sub.ask("snap")
                if snap["all_good_at"] is not None:
                    break
                if proc.returncode is not None or time.monotonic() > deadline:
                    raise RuntimeError(
                        f"only {snap['good']} of {total} variables Good "
                        f"(see {ctx.workdir / 'scale-gateway.log'})"
                    )
                meter.rss()
                await asyncio.sleep(0.05)
            startup = snap["all_good_at"] - started
            details["startup"] = startup
            ctx.log(f"  all {total:,} Good at MQTT after {startup:.2f} s")
            paths = [p for k in range(machines) for p in gateway_ids(f"m{k:02d}", noise_paths(k * per, per))]
            ids = ids_file(folder / "ids.txt", GATEWAY_URI, paths)
            opcua = await Agent.start(
                "scale-opcua-sub",
                "bench.agents.opcua_sub",
                ["--endpoint", gw_endpoint, "--ids", str(ids)],
                ctx.workdir,
            )
            agents.append(opcua)
            await asyncio.sleep(1.0)
            details["opcua_good"] = (await opcua.ask("snap"))["good"]
            await asyncio.sleep(max(1.0, s.scale_phase / 2))
            details["rss"] = meter.rss()
            phases = {}
            for label, rate in (("idle", 0), ("1 Hz", total), ("10 Hz", total * 10)):
                await sim.ask("rate", rate=rate)
                await asyncio.sleep(1.0)
                c0, t0, m0, n0 = meter.cpu(), time.monotonic(), await sub.ask("snap"), await sim.ask("snap")
                await asyncio.sleep(s.scale_phase)
                c1, t1, m1, n1 = meter.cpu(), time.monotonic(), await sub.ask("snap"), await sim.ask("snap")
                meter.rss()
                phases[label] = {
                    "cpu": 100.0 * (c1 - c0) / (t1 - t0),
                    "offered": (n1["written"] - n0["written"]) / (n1["mono"] - n0["mono"]),
                    "mqtt": (m1["count"] - m0["count"]) / (m1["mono"] - m0["mono"]),
                    "set": rate,
                }
                ctx.log(
                    f"  {label:>5}: gateway CPU {phases[label]['cpu']:5.1f} %, source wrote "
                    f"{phases[label]['offered']:8,.0f}/s, MQTT got {phases[label]['mqtt']:8,.0f}/s"
                )
            await sim.ask("rate", rate=0)
            details["phases"] = phases
            details["peak_rss"] = meter.peak_rss
        finally:
            if proc is not None and proc.returncode is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    async with asyncio.timeout(10):
                        await proc.wait()
                except TimeoutError:
                    proc.kill()
                    await proc.wait()
            for agent in reversed(agents):
                await agent.stop()
    tag = f"{machines} × {per}"
    r.add(
        "scale.startup",
        SECTION,
        f"{tag}: process start → every variable Good (MQTT)",
        details.get("startup"),
        "s",
        baseline=ctx.ceilings.get("asyncua_build_10k"),
        baseline_label="raw asyncua build of 10k vars",
        note="standard namespace from its cache"
        if details.get("ns0_cache")
        else "first start: cache written",
    )
    r.add(
        "scale.opcua_good",
        SECTION,
        f"{tag}: Good at an OPC UA subscriber after start-up",
        details.get("opcua_good"),
        "vars",
        baseline=total,
        baseline_label="variables",
    )
    rss = details.get("rss")
    raw_rss = ctx.ceilings.get("asyncua_rss_10k")
    r.add(
        "scale.rss",
        SECTION,
        f"{tag}: gateway RSS once settled",
        rss / 1e6 if rss else None,
        "MB",
        baseline=raw_rss / 1e6 if raw_rss else None,
        baseline_label="raw asyncua server, 10k vars",
    )
    for label, phase in (details.get("phases") or {}).items():
        r.add(
            f"scale.cpu.{label.replace(' ', '')}",
            SECTION,
            f"{tag}: gateway CPU, {label}",
            phase["cpu"],
            "%",
            note=f"source {phase['offered']:,.0f}/s, MQTT {phase['mqtt']:,.0f}/s" if phase["set"] else "",
        )
