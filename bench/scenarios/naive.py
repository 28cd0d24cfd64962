"""The naive bridge under the same load as the gateway: simulator noise, N = 1,000, same rates.

Measured like the mirror (bench/scenarios/mirror.py): changes/s at an MQTT QoS 1
subscriber and at an OPC UA subscriber on the bridge's own server, latency, CPU.
The gateway's figure it is compared with is the mirror's flat-out step for the
same N over OPC UA at QoS 1 (QoS 0 when only that was run, which the table says).
"""

from __future__ import annotations

import asyncio
import math
from typing import Any

from bench.context import Context, rate_key, rate_label
from bench.procs import Agent, Mosquitto, free_port
from bench.scenarios.common import ids_file
from bench.scenarios.mirror import OPCUA_SUB_INTERVAL

SECTION = "Naive bridge (asyncua subscription → node.write_value + paho wait_for_publish), same load"
N = 1000


async def run(ctx: Context) -> None:
    s, r = ctx.settings, ctx.results
    folder = ctx.workdir / "naive"
    folder.mkdir()
    agents: list[Agent] = []
    steps: list[dict[str, Any]] = []
    async with Mosquitto(ctx.workdir) as broker:
        try:
            sim = await Agent.start(
                "naive-sim", "bench.agents.simulator", ["--variables", str(N)], ctx.workdir
            )
            agents.append(sim)
            source_ids = ids_file(
                folder / "source.txt",
                "urn:cnc-simulator:plc",
                [f"::Noise:g{i // 200:03d}.v{i:05d}" for i in range(N)],
            )
            bridge = await Agent.start(
                "naive-bridge", "bench.agents.naive_bridge",
                ["--source", sim.ready["endpoint"], "--ids", str(source_ids), "--port", str(free_port()),
                 "--mqtt-port", str(broker.port)], ctx.workdir,
            )  # fmt: skip
            agents.append(bridge)
            mirror_ids = ids_file(folder / "mirror.txt", bridge.ready["uri"], [f"v{i:05d}" for i in range(N)])
            mqtt_sub = await Agent.start(
                "naive-mqtt-sub",
                "bench.agents.mqtt_sub",
                ["--port", str(broker.port), "--topic", "naive/#", "--qos", "1"],
                ctx.workdir,
            )
            agents.append(mqtt_sub)
            opcua_sub = await Agent.start(
                "naive-opcua-sub", "bench.agents.opcua_sub",
                ["--endpoint", bridge.ready["endpoint"], "--ids", str(mirror_ids),
                 "--interval", str(OPCUA_SUB_INTERVAL)],
                ctx.workdir,
            )  # fmt: skip
            agents.append(opcua_sub)
            for rate in s.naive_rates:
                step = await measure(ctx, sim, bridge, mqtt_sub, opcua_sub, rate)
                steps.append(step)
                ctx.log(
                    f"  {rate_label(rate):>9}: offered {step['offered']:8,.0f}/s  "
                    f"mqtt {step['mqtt']:8,.0f}/s  opcua {step['opcua']:8,.0f}/s  "
                    f"p99 {step['latency'].get('p99') or 0:.0f} ms  "
                    f"cpu {step['cpu']:.0f}%"
                )
                await sim.ask("rate", rate=0)
                await asyncio.sleep(1.0)
        finally:
            for agent in reversed(agents):
                await agent.stop()
    for step in steps:
        key = f"naive.{rate_key(step['rate'])}"
        what = f"N={N:,} @{rate_label(step['rate'])}"
        r.add(
            f"{key}.mqtt_rate",
            SECTION,
            f"{what}: MQTT delivered",
            step["mqtt"],
            "changes/s",
            baseline=step["offered"],
            baseline_label="source wrote",
        )
        r.add(f"{key}.opcua_rate", SECTION, f"{what}: OPC UA notifications", step["opcua"], "notif/s")
        r.add(f"{key}.p99", SECTION, f"{what}: latency p99", step["latency"].get("p99"), "ms")
        r.add(f"{key}.cpu", SECTION, f"{what}: bridge CPU", step["cpu"], "%")
    naive_rate = max((st["mqtt"] for st in steps), default=None)
    gateway_rate, qos = _gateway_rate(ctx)
    ctx.results.details["naive"] = {
        "steps": [{**st, "rate": None if math.isinf(st["rate"]) else st["rate"]} for st in steps],
        "naive_rate": naive_rate,
        "gateway_rate": gateway_rate,
        "gateway_qos": qos,
    }
    if naive_rate:
        r.add(
            "naive.vs_gateway",
            SECTION,
            f"gateway flat out (N={N:,}, MQTT QoS {qos}) vs naive bridge flat out",
            gateway_rate,
            "changes/s",
            baseline=naive_rate,
            baseline_label="naive bridge",
        )


def _gateway_rate(ctx: Context) -> tuple[float | None, int | None]:
    mirror = ctx.results.details.get("mirror", {})
    for qos in (1, 0):
        data = mirror.get(f"opcua.qos{qos}.n{N}")
        if data:
            rates = [st["mqtt"] for st in data["steps"]]
            return (max(rates) if rates else None), qos
    return None, None


async def measure(
    ctx: Context, sim: Agent, bridge: Agent, mqtt_sub: Agent, opcua_sub: Agent, rate: float
) -> dict[str, Any]:
    s = ctx.settings
    await sim.ask("rate", rate="max" if math.isinf(rate) else rate)
    await asyncio.sleep(s.warmup)
    a = [await x.ask("snap") for x in (sim, bridge, mqtt_sub, opcua_sub)]
    await asyncio.sleep(s.window)
    b = [await x.ask("snap") for x in (sim, bridge, mqtt_sub, opcua_sub)]

    def per_s(i: int, key: str) -> float:
        return (b[i][key] - a[i][key]) / (b[i]["mono"] - a[i]["mono"])

    return {
        "rate": rate,
        "offered": per_s(0, "written"),
        "handled": per_s(1, "handled"),
        "mqtt": per_s(2, "count"),
        "opcua": per_s(3, "count"),
        "latency": b[2]["latency"],
        "cpu": 100.0 * per_s(1, "cpu"),
    }
