"""Sparkplug B beside the JSON topics (issue 15): the same changes through each sink, in the same run.

1. Throughput and latency: N noise variables pushed in-process into the tree (the sinks alone, as
   mirror's `inproc`), first through the MQTT JSON sink (QoS 0) to a paho subscriber, then through
   the Sparkplug sink to a Sparkplug host in its own process (protobuf decoding, alias → name from the
   births); the same steps for both. A change counts at the host when its metric arrives in a DDATA;
   latency is receipt time minus the metric's timestamp (the source time, in ms, as the JSON `ts`).
2. Rebirth: 20 machines × 500 variables (every one with a value); the host publishes an NCMD
   `Node Control/Rebirth` and times until the NBIRTH and all 20 DBIRTHs are in.
3. Broker restarts: changes stream at 1,000/s while the broker is stopped and started again; the host
   counts gaps in `seq` within each session (a session: an NBIRTH with a new bdSeq).
"""

from __future__ import annotations

import asyncio
import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Any

from bench.context import Context, poll, rate_key, rate_label
from bench.procs import Agent, Mosquitto
from bench.scenarios.common import expected_last, matches, noise_paths, noise_topic, write_gateway
from simulator.noise import NoiseSpec, noise_mapping, split_machines

SECTION = "Sparkplug B beside the JSON sink (in-process source, each sink alone, same steps)"
MACHINE = "noise"
GROUP, EDGE = "cnc", "cnc-gateway"
REBIRTHS = 5  # rebirth requests timed; the median is the figure
SUSTAINED = 0.95


@dataclass
class Step:
    rate: float
    offered: float = 0.0  # changes/s the injector wrote
    delivered: float = 0.0  # changes/s at the subscriber (JSON messages, or DDATA metrics)
    messages: float = 0.0  # MQTT messages/s at the subscriber
    latency: dict[str, Any] = field(default_factory=dict)
    latency_seconds: list[dict[str, Any]] = field(default_factory=list)
    cpu: float = 0.0

    @property
    def p99_median(self) -> float | None:
        values = sorted(s["p99"] for s in self.latency_seconds if s.get("n", 0) >= 100)
        return values[len(values) // 2] if values else None

    @property
    def sustained(self) -> bool:
        return self.offered > 0 and self.delivered >= SUSTAINED * self.offered

    def as_dict(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        out["rate"] = None if math.isinf(self.rate) else self.rate
        out["p99_median"] = self.p99_median
        out["sustained"] = self.sustained
        return out


async def run(ctx: Context) -> None:
    details: dict[str, Any] = {}
    ctx.results.details["sparkplug"] = details
    n = 1000
    for face in ("json", "sparkplug"):
        ctx.log(f"sparkplug: {face} sink, {n:,} variables, in-process source")
        steps, final = await throughput(ctx, face, n)
        details[face] = {"steps": [st.as_dict() for st in steps], "final": final}
    report_throughput(ctx, details, n)
    machines, per = 20, 500
    ctx.log(f"sparkplug: rebirth of {machines} machines × {per} variables")
    details["rebirth"] = await rebirth(ctx, machines, per)
    report_rebirth(ctx, details["rebirth"])
    restarts = 3 if ctx.settings.quick else 30
    ctx.log(f"sparkplug: {restarts} broker restarts while changes stream")
    details["restarts"] = await broker_restarts(ctx, restarts)
    report_restarts(ctx, details["restarts"])


def sparkplug_section(port: int, name: str) -> dict[str, Any]:
    return {
        "sparkplug": {"group_id": GROUP, "edge_node_id": EDGE, "broker": {"port": port, "client_id": name}}
    }


async def throughput(ctx: Context, face: str, n: int) -> tuple[list[Step], dict[str, Any]]:
    folder = ctx.workdir / f"sparkplug-{face}-n{n}"
    mapping = noise_mapping(NoiseSpec(n), "opc.tcp://127.0.0.1:1", machine=MACHINE)
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir) as broker:
        try:
            if face == "json":
                config, _ = write_gateway(folder, {MACHINE: mapping}, mqtt_port=broker.port, mqtt={"qos": 0})
            else:
                config, _ = write_gateway(
                    folder,
                    {MACHINE: mapping},
                    mqtt_port=None,
                    extra=sparkplug_section(broker.port, f"bench-{folder.name}"),
                )
            gw = await Agent.start(
                f"gw-{folder.name}",
                "bench.agents.gateway",
                ["--config", str(config), "--inject"],
                ctx.workdir,
            )
            agents.append(gw)
            if face == "json":
                sub = await Agent.start(
                    f"sub-{folder.name}",
                    "bench.agents.mqtt_sub",
                    ["--port", str(broker.port), "--topic", f"cnc/{MACHINE}/noise/#", "--qos", "0"],
                    ctx.workdir,
                )
            else:
                sub = await Agent.start(
                    f"host-{folder.name}",
                    "bench.agents.sparkplug_host",
                    ["--port", str(broker.port)],
                    ctx.workdir,
                )
                await poll(lambda: _born(gw), timeout=30, what="the Sparkplug births")
            agents.append(sub)
            steps = []
            for rate in sparkplug_rates(ctx):
                step = await measure(ctx, gw, sub, rate)
                steps.append(step)
                p99 = f"{_ms(step.latency.get('p99'))} ({_ms(step.p99_median)})"
                ctx.log(
                    f"  {rate_label(rate):>9}: offered {step.offered:8,.0f}/s"
                    f"  delivered {step.delivered:8,.0f}/s"
                    f"  in {step.messages:7,.0f} msgs/s  p99 {p99}  cpu {step.cpu:3.0f}%"
                )
                await drain(gw, sub)
            final = await final_values(gw, sub, face, n)
            return steps, final
        finally:
            for agent in reversed(agents):
                await agent.stop()


def sparkplug_rates(ctx: Context) -> list[float]:
    return [5000.0, math.inf] if ctx.settings.quick else [1000.0, 5000.0, 10000.0, math.inf]


async def _born(gw: Agent) -> bool:
    snap = await gw.ask("snap")
    return bool(snap["sinks"].get("sparkplug", {}).get("online"))


async def measure(ctx: Context, gw: Agent, sub: Agent, rate: float) -> Step:
    s = ctx.settings
    await gw.ask("rate", rate="max" if math.isinf(rate) else rate)
    await asyncio.sleep(s.warmup)
    step = Step(rate)
    g0, m0 = await gw.ask("snap"), await sub.ask("mark")
    loop = asyncio.get_running_loop()
    end = loop.time() + s.window
    while loop.time() < end - 0.5:
        await asyncio.sleep(min(1.0, max(0.0, end - loop.time())))
        step.latency_seconds.append((await sub.ask("snap"))["latency"])
    await asyncio.sleep(max(0.0, end - loop.time()))
    g1, m1 = await gw.ask("snap"), await sub.ask("snap")
    seconds = g1["mono"] - g0["mono"]
    step.offered = (g1["injector"]["written"] - g0["injector"]["written"]) / seconds
    elapsed = m1["mono"] - m0["mono"]
    step.delivered = (m1["count"] - m0["count"]) / elapsed
    step.messages = (m1.get("messages", m1["count"]) - m0.get("messages", m0["count"])) / elapsed
    step.latency = m1["window"]
    step.latency_seconds.append(m1["latency"])
    step.cpu = 100.0 * (g1["cpu"] - g0["cpu"]) / seconds
    return step


async def drain(gw: Agent, sub: Agent, timeout: float = 20.0) -> None:
    """Pause the source; wait until the subscriber has seen nothing new for half a second."""
    await gw.ask("rate", rate=0)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    last, since = -1, loop.time()
    while loop.time() < deadline:
        count = (await sub.ask("snap"))["count"]
        if count != last:
            last, since = count, loop.time()
        elif loop.time() - since >= 0.5:
            return
        await asyncio.sleep(0.1)


async def final_values(gw: Agent, sub: Agent, face: str, n: int, timeout: float = 30.0) -> dict[str, Any]:
    """After the last step: does every variable end at the injector's last value at the subscriber?"""
    written = int((await gw.ask("snap"))["injector"]["written"])
    expected = expected_last(written, n)
    paths = noise_paths(0, n)
    keys = [noise_topic(MACHINE, p) for p in paths] if face == "json" else paths
    loop = asyncio.get_running_loop()
    started = loop.time()
    while True:
        last = (await sub.ask("values"))["last"]
        matched = matches([last.get(k) for k in keys], expected)
        if matched == n or loop.time() - started > timeout:
            break
        await asyncio.sleep(0.5)
    return {
        "written": written,
        "match": matched,
        "variables": n,
        "settled_after": round(loop.time() - started, 1),
    }


async def rebirth(ctx: Context, machines: int, per: int) -> dict[str, Any]:
    folder = ctx.workdir / "sparkplug-rebirth"
    spec = NoiseSpec(machines * per)
    mappings = {
        f"m{k:02d}": noise_mapping(
            spec, "opc.tcp://127.0.0.1:1", machine=f"m{k:02d}", first=first, count=count
        )
        for k, (first, count) in enumerate(split_machines(spec, machines))
    }
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir) as broker:
        try:
            config, _ = write_gateway(
                folder, mappings, mqtt_port=None, extra=sparkplug_section(broker.port, "bench-rebirth")
            )
            gw = await Agent.start(
                "gw-rebirth",
                "bench.agents.gateway",
                ["--config", str(config), "--inject"],
                ctx.workdir,
                timeout=180,
            )
            agents.append(gw)
            host = await Agent.start(
                "host-rebirth",
                "bench.agents.sparkplug_host",
                ["--port", str(broker.port), "--devices", str(machines)],
                ctx.workdir,
            )
            agents.append(host)
            await poll(lambda: _born(gw), timeout=60, what="the Sparkplug births")
            total = machines * per
            await gw.ask("rate", rate=20000)  # every variable gets a value: births carry 10,000 of them
            await poll(lambda: _written(gw, total), timeout=60, what="a value for every variable")
            await gw.ask("rate", rate=0)
            await asyncio.sleep(1.0)
            seconds = []
            for _ in range(REBIRTHS):
                answer = await host.ask("rebirth", timeout=90)
                if answer.get("seconds") is not None:
                    seconds.append(float(answer["seconds"]))
                await asyncio.sleep(0.5)
            snap = await host.ask("snap")
            return {
                "machines": machines,
                "per_machine": per,
                "seconds": seconds,
                "median": statistics.median(seconds) if seconds else None,
                "max": max(seconds, default=None),
                "seq_gaps": snap["seq_gaps"],
            }
        finally:
            for agent in reversed(agents):
                await agent.stop()


async def _written(gw: Agent, total: int) -> bool:
    return int((await gw.ask("snap"))["injector"]["written"]) >= total


async def broker_restarts(ctx: Context, restarts: int) -> dict[str, Any]:
    folder = ctx.workdir / "sparkplug-restarts"
    n = 1000
    mapping = noise_mapping(NoiseSpec(n), "opc.tcp://127.0.0.1:1", machine=MACHINE)
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir) as broker:
        try:
            section = sparkplug_section(broker.port, "bench-restarts")
            section["sparkplug"]["broker"]["reconnect"] = {"initial": 0.05, "max": 0.5}
            config, _ = write_gateway(folder, {MACHINE: mapping}, mqtt_port=None, extra=section)
            gw = await Agent.start(
                "gw-restarts", "bench.agents.gateway", ["--config", str(config), "--inject"], ctx.workdir
            )
            agents.append(gw)
            host = await Agent.start(
                "host-restarts", "bench.agents.sparkplug_host", ["--port", str(broker.port)], ctx.workdir
            )
            agents.append(host)
            await poll(lambda: _born(gw), timeout=30, what="the Sparkplug births")
            await gw.ask("rate", rate=1000)
            started = time.monotonic()
            for cycle in range(restarts):
                sessions = (await host.ask("snap"))["sessions"]
                await asyncio.sleep(0.5)
                await broker.restart()
                await poll(
                    lambda s=sessions: _sessions(host, s + 1),
                    timeout=30,  # type: ignore[misc]
                    what=f"the host's session after restart {cycle + 1}",
                )
            await asyncio.sleep(0.5)
            await gw.ask("rate", rate=0)
            snap = await host.ask("snap")
            return {
                "restarts": restarts,
                "sessions": snap["sessions"],
                "seq_gaps": snap["seq_gaps"],
                "messages": snap["messages"],
                "historical": snap["historical"],
                "seconds": round(time.monotonic() - started, 1),
            }
        finally:
            for agent in reversed(agents):
                await agent.stop()


async def _sessions(host: Agent, at_least: int) -> bool:
    return int((await host.ask("snap"))["sessions"]) >= at_least


# --- the figures ----------------------------------------------------------------------------------


def report_throughput(ctx: Context, details: dict[str, Any], n: int) -> None:
    r = ctx.results
    json_steps = {st["rate"]: st for st in details["json"]["steps"]}
    for st in details["sparkplug"]["steps"]:
        rate = math.inf if st["rate"] is None else st["rate"]
        base = json_steps.get(st["rate"], {})
        key = f"sparkplug.n{n}.{rate_key(rate)}"
        what = f"N={n:,} @{rate_label(rate)}"
        r.add(
            f"{key}.delivered",
            SECTION,
            f"{what}: Sparkplug host, changes",
            st["delivered"],
            "changes/s",
            baseline=base.get("delivered"),
            baseline_label="JSON subscriber",
            note=f"in {st['messages']:,.0f} DDATA/s; {'sustained' if st['sustained'] else 'NOT sustained'}",
        )
        r.add(
            f"{key}.p99",
            SECTION,
            f"{what}: Sparkplug latency p99",
            st["latency"].get("p99"),
            "ms",
            baseline=(base.get("latency") or {}).get("p99"),
            baseline_label="JSON",
        )
        r.add(
            f"{key}.p99_median",
            SECTION,
            f"{what}: Sparkplug p99, median of 1-s windows",
            st["p99_median"],
            "ms",
            baseline=base.get("p99_median"),
            baseline_label="JSON",
        )
        r.add(
            f"{key}.cpu",
            SECTION,
            f"{what}: gateway CPU with Sparkplug",
            st["cpu"],
            "%",
            baseline=base.get("cpu"),
            baseline_label="with JSON",
        )
    for face in ("json", "sparkplug"):
        final = details[face]["final"]
        r.add(
            f"sparkplug.n{n}.final_{face}",
            SECTION,
            f"N={n:,}: last values right ({face})",
            final["match"],
            "vars",
            baseline=final["variables"],
            baseline_label="variables",
        )


def report_rebirth(ctx: Context, data: dict[str, Any]) -> None:
    tag = f"{data['machines']} machines × {data['per_machine']}"
    ctx.results.add(
        "sparkplug.rebirth.median",
        SECTION,
        f"rebirth, NCMD → NBIRTH + every DBIRTH ({tag}), median",
        data["median"],
        "s",
        note=f"{len(data['seconds'])} requests, max {_s(data['max'])}",
    )
    ctx.log(f"  rebirth: median {_s(data['median'])}, max {_s(data['max'])} over {len(data['seconds'])}")


def report_restarts(ctx: Context, data: dict[str, Any]) -> None:
    ctx.results.add(
        "sparkplug.restarts.seq_gaps",
        SECTION,
        f"seq gaps over {data['restarts']} broker restarts",
        data["seq_gaps"],
        "gaps",
        note=f"{data['sessions']} sessions, {data['messages']:,} messages",
    )
    ctx.log(f"  restarts: {data['restarts']}, sessions {data['sessions']}, seq gaps {data['seq_gaps']}")


def _ms(value: float | None) -> str:
    return "—" if value is None else f"{value:.0f} ms"


def _s(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f} s"
