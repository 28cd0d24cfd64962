"""Issue 28: MQTT QoS 1 at full speed, every change once and in order, beside paho's raw QoS 1 ceiling.

1. paho's raw QoS 1 ceiling in this run: bench/agents/paho_pub.py (a window of 200 in flight, the
   gateway's default `max_inflight`) through a fresh Mosquitto to the same subscriber as below,
   checking order as it reads (bench/scenarios/baselines.py `paho_rates`).
2. The gateway at QoS 1, N = 10,000 variables, the in-process source (mirror's `inproc`,
   bench/agents/injector.py) flat out but held back while the MQTT sink has BOUND changes on its
   hands, so that it always has more to send and nothing is dropped at the store-and-forward limit:
   the changes/s at the subscriber over a window is the sustained rate. The subscriber
   (bench/agents/mqtt_sub.py `--check`, bench/delivery.py) checks every message: after the steps,
   every change the source wrote must have arrived once (byte-identical redeliveries counted apart)
   and in order per topic, or the rate is not counted as sustained.
3. CPU per 1,000 changes at QoS 1 and at QoS 0, in the same run, at the same offered rate (80 % of
   what QoS 1 sustained flat out, at most 20,000/s) so that neither coalesces nor queues: the gateway
   process's CPU time over the window (all its threads, the injector included as in mirror's
   `inproc`) per 1,000 changes delivered.
4. Broker restarts (the drill's figure as a bench row; the drill itself is
   tests/integration/drills/test_broker_restarts_qos1.py): 1,000 variables at QoS 1, 5,000/s offered,
   Mosquitto with persistence stopped (SIGTERM) and started again 30 times (quick: 3) with a persistent
   subscriber session; changes lost, out of order, redelivered.
"""

from __future__ import annotations

import asyncio
import math
import statistics
import time
from typing import Any

from bench.context import Context, poll
from bench.procs import Agent, Mosquitto
from bench.scenarios.baselines import paho_rates
from bench.scenarios.common import noise_paths, noise_topic, write_gateway
from simulator.noise import NoiseSpec, noise_mapping

SECTION = "MQTT QoS 1 (issue 28): in-process source → MQTT sink → a checking QoS 1 subscriber"
MACHINE = "noise"
N = 10_000
BOUND = 20_000  # changes the injector lets the MQTT sink have on its hands (waiting + in flight)
CPU_SHARE = 0.8  # the CPU step's rate: this share of what QoS 1 sustained flat out...
CPU_RATE_MAX = 20_000.0  # ...at most
RESTART_N = 1000
RESTART_RATE = 5000.0
MAX_INFLIGHT = 200  # the gateway's default mqtt.max_inflight (and paho_pub's window)


async def run(ctx: Context) -> None:
    s = ctx.settings
    details: dict[str, Any] = ctx.results.details.setdefault("qos1", {})
    ctx.log("qos1: paho → Mosquitto → checking subscriber, QoS 1, flat out")
    rates, latency = await paho_rates(ctx, 1, "qos1-paho", check=True)
    details["paho"] = {"rate": statistics.median(rates), "rates": rates, "latency_ms": latency}
    ctx.log(f"  paho QoS 1: {details['paho']['rate']:,.0f} msg/s")

    ctx.log(f"qos1: gateway, {N:,} variables, QoS 1, flat out (held at {BOUND:,} pending), then the CPU step")
    q1 = await configuration(ctx, 1, [math.inf])
    flat = q1["steps"][0]
    cpu_rate = max(1000.0, min(CPU_RATE_MAX, round(CPU_SHARE * flat["delivered"] / 500) * 500))
    details["cpu_rate"] = cpu_rate
    details["qos1"] = q1
    ctx.log(f"qos1: CPU per 1,000 changes at {cpu_rate:,.0f}/s, QoS 1 then QoS 0 (fresh gateways)")
    details["cpu_qos1"] = await configuration(ctx, 1, [cpu_rate])
    details["cpu_qos0"] = await configuration(ctx, 0, [cpu_rate])

    restarts = 3 if s.quick else 30
    ctx.log(f"qos1: {restarts} broker restarts at {RESTART_RATE:,.0f}/s, {RESTART_N:,} variables")
    details["restarts"] = await broker_restarts(ctx, restarts)
    report(ctx, details)


async def configuration(ctx: Context, qos: int, rates: list[float]) -> dict[str, Any]:
    """A fresh broker, gateway and checking subscriber; one window per rate; then the verdict."""
    s = ctx.settings
    tag = f"q{qos}-{'max' if math.isinf(rates[0]) else int(rates[0])}"
    folder = ctx.workdir / f"qos1-{tag}"
    mapping = noise_mapping(NoiseSpec(N), "opc.tcp://127.0.0.1:1", machine=MACHINE)
    topics = [noise_topic(MACHINE, p) for p in noise_paths(0, N)]
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir) as broker:
        try:
            config, _ = write_gateway(folder, {MACHINE: mapping}, mqtt_port=broker.port, mqtt={"qos": qos})
            gw = await Agent.start(
                f"gw-qos1-{tag}", "bench.agents.gateway",
                ["--config", str(config), "--inject", "--inject-bound", str(BOUND)], ctx.workdir,
            )  # fmt: skip
            agents.append(gw)
            sub = await Agent.start(
                f"sub-qos1-{tag}", "bench.agents.mqtt_sub",
                ["--port", str(broker.port), "--topic", f"cnc/{MACHINE}/noise/#", "--qos", str(qos),
                 "--check"],
                ctx.workdir,
            )  # fmt: skip
            agents.append(sub)
            await poll(lambda: _online(gw), timeout=30, what="the MQTT sink online")
            steps = []
            for rate in rates:
                step = await window(ctx, gw, sub, rate)
                steps.append(step)
                ctx.log(
                    f"  QoS {qos} @{'max' if math.isinf(rate) else f'{rate:,.0f}/s'}: offered "
                    f"{step['offered']:,.0f}/s, delivered {step['delivered']:,.0f}/s, gateway CPU "
                    f"{step['cpu']:.0f}% ({step['cpu_ms_per_1000']:.1f} ms/1,000), subscriber CPU "
                    f"{step['sub_cpu']:.0f}%"
                )
                await gw.ask("rate", rate=0)
                await _settle(gw, sub)
            written = int((await gw.ask("snap"))["injector"]["written"])
            verdict = await sub.ask("check", topics=topics, written=written, timeout=120)
            return {"qos": qos, "steps": steps, "verdict": _plain(verdict), "seconds": s.window}
        finally:
            for agent in reversed(agents):
                await agent.stop()


async def window(ctx: Context, gw: Agent, sub: Agent, rate: float) -> dict[str, Any]:
    s = ctx.settings
    await gw.ask("rate", rate="max" if math.isinf(rate) else rate)
    await asyncio.sleep(s.warmup)
    g0, m0 = await gw.ask("snap"), await sub.ask("snap")
    await asyncio.sleep(s.window)
    g1, m1 = await gw.ask("snap"), await sub.ask("snap")
    seconds = g1["mono"] - g0["mono"]
    delivered = m1["distinct"] - m0["distinct"]
    cpu = g1["cpu"] - g0["cpu"]
    return {
        "rate": None if math.isinf(rate) else rate,
        "offered": (g1["injector"]["written"] - g0["injector"]["written"]) / seconds,
        "delivered": delivered / (m1["mono"] - m0["mono"]),
        "redelivered": m1["redelivered"] - m0["redelivered"],
        "cpu": 100.0 * cpu / seconds,
        "cpu_ms_per_1000": 1e6 * cpu / delivered if delivered else math.nan,
        "sub_cpu": 100.0 * (m1["cpu"] - m0["cpu"]) / (m1["mono"] - m0["mono"]),
        "pending": [_pending(g0), _pending(g1)],
    }


def _pending(snap: dict[str, Any]) -> int:
    """Changes on the MQTT sink's hands: waiting in its hub subscription, its backlog, in flight."""
    sink = snap["sinks"].get("mqtt", {})
    waiting = int(snap["hub"].get("mqtt", {}).get("backlog", 0))
    return waiting + int(sink.get("backlog", 0)) + int(sink.get("in_flight", 0))


async def _online(gw: Agent) -> bool:
    return bool((await gw.ask("snap"))["sinks"].get("mqtt", {}).get("online"))


async def _settle(gw: Agent, sub: Agent, timeout: float = 120.0) -> None:
    """The source paused: wait until the sink has nothing on its hands and the subscriber has seen
    nothing new for half a second (what is still missing then, the verdict counts)."""
    await poll(lambda: _drained(gw), timeout=timeout, interval=0.1, what="the MQTT sink to drain")
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    last, since = -1, loop.time()
    while loop.time() < deadline:
        count = int((await sub.ask("snap"))["count"])
        if count != last:
            last, since = count, loop.time()
        elif loop.time() - since >= 0.5:
            return
        await asyncio.sleep(0.1)


async def _drained(gw: Agent) -> bool:
    return _pending(await gw.ask("snap")) == 0


def _plain(answer: dict[str, Any]) -> dict[str, Any]:
    """An agent's answer without its process figures."""
    return {k: v for k, v in answer.items() if k not in ("ok", "cpu", "rss", "maxrss", "wall", "mono")}


async def broker_restarts(ctx: Context, restarts: int) -> dict[str, Any]:
    """The drill's figure: changes lost over `restarts` broker restarts, QoS 1, 5,000/s offered."""
    folder = ctx.workdir / "qos1-restarts"
    mapping = noise_mapping(NoiseSpec(RESTART_N), "opc.tcp://127.0.0.1:1", machine=MACHINE)
    topics = [noise_topic(MACHINE, p) for p in noise_paths(0, RESTART_N)]
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir, persistence=True) as broker:
        try:
            config, _ = write_gateway(
                folder, {MACHINE: mapping}, mqtt_port=broker.port,
                mqtt={"qos": 1, "reconnect": {"initial": 0.05, "max": 0.5}},
            )  # fmt: skip
            gw = await Agent.start(
                "gw-qos1-restarts", "bench.agents.gateway", ["--config", str(config), "--inject"], ctx.workdir
            )
            agents.append(gw)
            sub = await Agent.start(
                "sub-qos1-restarts", "bench.agents.mqtt_sub",
                ["--port", str(broker.port), "--topic", f"cnc/{MACHINE}/noise/#", "--qos", "1", "--check",
                 "--persistent", "--client-id", "bench-qos1-historian"],
                ctx.workdir,
            )  # fmt: skip
            agents.append(sub)
            await poll(lambda: _online(gw), timeout=30, what="the MQTT sink online")
            await gw.ask("rate", rate=RESTART_RATE)
            started = time.monotonic()
            for cycle in range(restarts):
                mark = int((await sub.ask("snap"))["distinct"])
                await poll(lambda m=mark: _distinct(sub, m + int(RESTART_RATE / 2)), timeout=30,  # type: ignore[misc]
                           what=f"changes delivered before restart {cycle + 1}")  # fmt: skip
                written = int((await gw.ask("snap"))["injector"]["written"])
                await broker.stop()
                await poll(lambda: _offline(gw), timeout=10, what="the sink to notice")
                await poll(lambda w=written: _written(gw, w + int(RESTART_RATE)), timeout=15,  # type: ignore[misc]
                           what="a second of changes while the broker is away")  # fmt: skip
                await broker.start()
                await poll(lambda: _online(gw), timeout=30, what=f"reconnect {cycle + 1}")
            await gw.ask("rate", rate=0)
            streamed = time.monotonic() - started
            await _settle(gw, sub)
            snap = await gw.ask("snap")
            written = int(snap["injector"]["written"])
            got = await sub.ask("snap")
            verdict = await sub.ask("check", topics=topics, written=written, timeout=120)
            return {
                "restarts": restarts,
                "variables": RESTART_N,
                "offered": RESTART_RATE,
                "achieved": written / streamed,
                "verdict": _plain(verdict),
                "dropped": snap["sinks"].get("mqtt", {}).get("dropped", 0),
                "resumed": got["resumed"],
                # The gateway's re-sends (without DUP at the subscriber) are bounded by its window per
                # restart; the broker's (DUP set) are Mosquitto's and only reported.
                "redelivery_bound": restarts * MAX_INFLIGHT,
                "seconds": round(time.monotonic() - started, 1),
            }
        finally:
            for agent in reversed(agents):
                await agent.stop()


async def _distinct(sub: Agent, at_least: int) -> bool:
    return int((await sub.ask("snap"))["distinct"]) >= at_least


async def _written(gw: Agent, at_least: int) -> bool:
    return int((await gw.ask("snap"))["injector"]["written"]) >= at_least


async def _offline(gw: Agent) -> bool:
    return not (await gw.ask("snap"))["sinks"].get("mqtt", {}).get("online")


# --- the figures ----------------------------------------------------------------------------------


def report(ctx: Context, d: dict[str, Any]) -> None:
    r = ctx.results
    paho = d["paho"]["rate"]
    flat = d["qos1"]["steps"][0]
    v = d["qos1"]["verdict"]
    r.add(
        "qos1.n10000.max.delivered", SECTION, f"N={N:,} QoS 1 flat out: delivered, every change checked",
        flat["delivered"], "changes/s", baseline=paho, baseline_label="paho QoS 1 ceiling, same subscriber",
        note=f"missing {v['missing']}, out of order {v['out_of_order']}, duplicates {v['duplicates']}, "
        f"redelivered {v['redelivered']}; gateway CPU {flat['cpu']:.0f}%, subscriber {flat['sub_cpu']:.0f}%",
    )  # fmt: skip
    rate = d["cpu_rate"]
    q1, q0 = d["cpu_qos1"]["steps"][0], d["cpu_qos0"]["steps"][0]
    r.add(
        "qos1.cpu_per_1000", SECTION, f"N={N:,} @{rate:,.0f}/s: gateway CPU per 1,000 changes, QoS 1",
        q1["cpu_ms_per_1000"], "ms", baseline=q0["cpu_ms_per_1000"], baseline_label="QoS 0, same rate",
        note=f"delivered {q1['delivered']:,.0f}/s vs {q0['delivered']:,.0f}/s",
    )  # fmt: skip
    rs = d["restarts"]
    rv = rs["verdict"]
    r.add(
        "qos1.restarts.missing", SECTION,
        f"{rs['restarts']} broker restarts, QoS 1 @{rs['offered']:,.0f}/s: changes lost",
        rv["missing"], "changes", baseline=rv["written"], baseline_label="written",
        note=f"out of order {rv['out_of_order']}, duplicates {rv['duplicates']}, redelivered by the gateway "
        f"{rv['redelivered'] - rv['redelivered_dup']} (bound {rs['redelivery_bound']}), by the broker "
        f"{rv['redelivered_dup']}, dropped {rs['dropped']}, achieved {rs['achieved']:,.0f}/s",
    )  # fmt: skip
