"""Issue 28: MQTT QoS 1 at full speed, every change once and in order, beside paho's raw QoS 1 ceiling.

1. paho's raw QoS 1 ceiling in this run: bench/agents/paho_pub.py (a window of 200 in flight, the
   gateway's `max_inflight` before issue 28; it now ships 4,000) through a fresh Mosquitto to the same
   subscriber as below, checking order as it reads (bench/scenarios/baselines.py `paho_rates`).
2. The gateway at QoS 1, N = 10,000 variables, the in-process source (mirror's `inproc`,
   bench/agents/injector.py) flat out but held back while the MQTT sink has BOUND changes on its
   hands, so that it always has more to send and nothing is dropped at the store-and-forward limit:
   once the sink has that many (the source is held), the changes/s at the subscriber over a window is
   the sustained rate. 1 and 2 alternate three times (quick: once); the medians are compared, since
   on a shared machine either moves by 30 % from minute to minute. Offered above delivered in such a
   window means the broker's queue for the subscriber grew ("NOT sustained": the subscriber, not the
   gateway, set the pace). The subscriber is Mosquitto's C `mosquitto_sub` (bench/agents/c_sub.py
   feeds its lines to bench/delivery.py): the paho one (bench/agents/mqtt_sub.py `--check`) read
   10-16k/s and so set the pace for the gateway and paho alike. It checks every message: after the
   steps, every change the source wrote must have arrived once (byte-identical redeliveries counted
   apart) and in order per topic, or the rate is not counted as sustained. paho's changes are checked
   the same way. The broker of these steps has no queue limit (bench/procs.py `unbounded`), so that it
   never drops what it acknowledged; its "dropped" notices are counted (`broker_drops`, must be 0).
3. CPU per 1,000 changes at QoS 1 and at QoS 0, in the same run, on fresh gateways at the same
   offered rate, 5,000/s (the drill's), which both must sustain (alternately, three times; medians):
   the gateway process's CPU time over the window (all its threads, the injector included as in
   mirror's `inproc`) per 1,000 changes delivered. Not at a share of the flat-out rate: today's QoS 1
   delivered 14k/s flat out from a full backlog but fell behind at 11.5k/s paced, and a sink that
   falls behind works in large batches, which made its CPU per change look lower than QoS 0's in
   small ones (0.65 x).
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
from bench.scenarios.common import noise_paths, noise_topic, profile, write_gateway
from gateway.sinks.mqtt.config import MqttConfig
from simulator.noise import NoiseSpec, noise_mapping

SECTION = "MQTT QoS 1 (issue 28): in-process source → MQTT sink → a checking QoS 1 subscriber"
MACHINE = "noise"
N = 10_000
BOUND = 20_000  # changes the injector lets the MQTT sink have on its hands (waiting + in flight)
CPU_RATE = 5000.0  # the CPU step's offered rate, at both QoS
ROUNDS = 3  # paho's ceiling and the gateway flat out, alternately (quick: once)
SUSTAINED = 0.95  # a window is sustained when this share of the offer was delivered, and nothing piled up
RESTART_N = 1000
RESTART_RATE = 5000.0
MAX_INFLIGHT = MqttConfig().max_inflight  # the gateway's window as shipped: its re-sends per restart at most


async def run(ctx: Context) -> None:
    s = ctx.settings
    details: dict[str, Any] = ctx.results.details.setdefault("qos1", {})
    # paho and the gateway alternately, `rounds` times: on a shared machine either moves by 30 % from
    # minute to minute, and the medians of interleaved measurements are what compares.
    rounds = 1 if s.quick else ROUNDS
    paho: list[float] = []
    paho_runs: list[dict[str, Any]] = []
    flat: list[dict[str, Any]] = []
    for i in range(rounds):
        ctx.log(f"qos1 ({i + 1}/{rounds}): paho → Mosquitto → checking subscriber, QoS 1, flat out")
        rates, last = await paho_rates(ctx, 1, f"qos1-paho-{i}", check=True, c_sub=True)
        paho.extend(rates)
        paho_runs.append(last)
        ctx.log(
            f"  paho QoS 1: acked {last['acked']:,.0f}/s, delivered and checked "
            f"{statistics.median(rates):,.0f}/s, passed {last['verdict']['passed']}, "
            f"missing {last['verdict']['missing']}, broker drops {last['broker_drops']}"
        )
        what = f"gateway, {N:,} variables, QoS 1, flat out (held at {BOUND:,} pending)"
        ctx.log(f"qos1 ({i + 1}/{rounds}): {what}")
        flat.append(await configuration(ctx, 1, [math.inf], name=f"max-{i}"))
    details["paho"] = {
        "rate": statistics.median(paho),
        "rates": paho,
        "acked": statistics.median(r["acked"] for r in paho_runs),
        "passed": all(r["verdict"]["passed"] for r in paho_runs),
        "verdicts": [r["verdict"] for r in paho_runs],
        "broker_drops": sum(r["broker_drops"] for r in paho_runs),
        "subscriber": "mosquitto_sub",
    }
    details["qos1"] = _merged(flat)
    cpu_rate = CPU_RATE
    details["cpu_rate"] = cpu_rate
    cpu: dict[int, list[dict[str, Any]]] = {1: [], 0: []}
    for i in range(rounds):
        ctx.log(f"qos1 ({i + 1}/{rounds}): CPU per 1,000 changes at {cpu_rate:,.0f}/s, QoS 1 then QoS 0")
        for qos in (1, 0):
            cpu[qos].append(await configuration(ctx, qos, [cpu_rate], name=f"{int(cpu_rate)}-{i}"))
    details["cpu_qos1"] = _merged(cpu[1], key="cpu_ms_per_1000")
    details["cpu_qos0"] = _merged(cpu[0], key="cpu_ms_per_1000")

    restarts = 3 if s.quick else 30
    ctx.log(f"qos1: {restarts} broker restarts at {RESTART_RATE:,.0f}/s, {RESTART_N:,} variables")
    details["restarts"] = await broker_restarts(ctx, restarts)
    report(ctx, details)


def _merged(runs: list[dict[str, Any]], key: str = "delivered") -> dict[str, Any]:
    """Several runs of one configuration as one: the window with the median `key` (its sustained flag
    true only if every run's was), every verdict's counts summed."""
    steps = [run["steps"][0] for run in runs]
    middle = dict(sorted(steps, key=lambda st: st[key])[len(steps) // 2])
    middle["sustained"] = all(st["sustained"] for st in steps)
    verdict = dict(runs[0]["verdict"])
    for run in runs[1:]:
        for count, value in run["verdict"].items():
            if isinstance(value, int) and not isinstance(value, bool):
                verdict[count] += value
    verdict["passed"] = all(run["verdict"]["passed"] for run in runs)
    values = [st[key] for st in steps]
    return {"qos": runs[0]["qos"], "steps": [middle], "verdict": verdict, "rounds": runs, key: values}


async def configuration(ctx: Context, qos: int, rates: list[float], *, name: str = "") -> dict[str, Any]:
    """A fresh broker, gateway and checking subscriber; one window per rate; then the verdict."""
    s = ctx.settings
    tag = f"q{qos}-{name or int(rates[0])}"
    folder = ctx.workdir / f"qos1-{tag}"
    mapping = noise_mapping(NoiseSpec(N), "opc.tcp://127.0.0.1:1", machine=MACHINE)
    topics = [noise_topic(MACHINE, p) for p in noise_paths(0, N)]
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir, unbounded=True) as broker:
        try:
            config, _ = write_gateway(folder, {MACHINE: mapping}, mqtt_port=broker.port, mqtt={"qos": qos})
            gw = await Agent.start(
                f"gw-qos1-{tag}", "bench.agents.gateway",
                ["--config", str(config), "--inject", "--inject-bound", str(BOUND)], ctx.workdir,
            )  # fmt: skip
            agents.append(gw)
            sub = await Agent.start(  # Mosquitto's C subscriber: not the bound (module docstring)
                f"sub-qos1-{tag}", "bench.agents.c_sub",
                ["--port", str(broker.port), "--topic", f"cnc/{MACHINE}/noise/#", "--qos", str(qos)],
                ctx.workdir,
            )  # fmt: skip
            agents.append(sub)
            await poll(lambda: _online(gw), timeout=30, what="the MQTT sink online")
            steps = []
            for rate in rates:
                as_ = f"qos1-{tag}" if s.profile and not math.isinf(rate) else None
                step = await window(ctx, gw, sub, rate, profile_as=as_)
                steps.append(step)
                ctx.log(
                    f"  QoS {qos} @{'max' if math.isinf(rate) else f'{rate:,.0f}/s'}"
                    f"{'' if step['sustained'] else ' (NOT sustained)'}: offered "
                    f"{step['offered']:,.0f}/s, acknowledged {step['acked']:,.0f}/s, "
                    f"delivered {step['delivered']:,.0f}/s, gateway CPU "
                    f"{step['cpu']:.0f}% ({step['cpu_ms_per_1000']:.1f} ms/1,000), subscriber CPU "
                    f"{step['sub_cpu']:.0f}%"
                )
                await gw.ask("rate", rate=0)
                await _settle(gw, sub)
            written = int((await gw.ask("snap"))["injector"]["written"])
            verdict = await sub.ask("check", topics=topics, written=written, timeout=120)
            plain = {**_plain(verdict), "broker_drops": broker.drops()}
            return {"qos": qos, "steps": steps, "verdict": plain, "seconds": s.window}
        finally:
            for agent in reversed(agents):
                await agent.stop()


async def window(
    ctx: Context, gw: Agent, sub: Agent, rate: float, *, profile_as: str | None = None
) -> dict[str, Any]:
    """One rate: warm up, then count over a window (with `--profile`, py-spy samples the gateway)."""
    s = ctx.settings
    await gw.ask("rate", rate="max" if math.isinf(rate) else rate)
    if math.isinf(rate):  # flat out: count once the sink has its BOUND on its hands and holds the source
        await poll(lambda: _filled(gw), timeout=60, interval=0.1, what="the MQTT sink's hands full")
    await asyncio.sleep(s.warmup)
    g0, m0 = await gw.ask("snap"), await sub.ask("snap")
    profiling = None
    if profile_as is not None:
        profiling = asyncio.create_task(profile(gw.pid, s.window, ctx.workdir / f"profile-{profile_as}"))
    await asyncio.sleep(s.window)
    g1, m1 = await gw.ask("snap"), await sub.ask("snap")
    if profiling is not None:
        ctx.profiles[profile_as or ""] = await profiling
    seconds = g1["mono"] - g0["mono"]
    delivered = m1["distinct"] - m0["distinct"]
    cpu = g1["cpu"] - g0["cpu"]
    offered = (g1["injector"]["written"] - g0["injector"]["written"]) / seconds
    rate_in = delivered / (m1["mono"] - m0["mono"])
    piled = _pending(g1) - _pending(g0)
    return {
        "rate": None if math.isinf(rate) else rate,
        "offered": offered,
        "acked": offered - piled / seconds,  # what left the gateway's hands (the broker acknowledged)
        "delivered": rate_in,
        "sustained": rate_in >= SUSTAINED * offered and piled <= max(500.0, 0.05 * delivered),
        "redelivered": m1["redelivered"] - m0["redelivered"],
        "cpu": 100.0 * cpu / seconds,
        "cpu_ms_per_1000": 1e6 * cpu / delivered if delivered else math.nan,
        "sub_cpu": 100.0
        * (m1["cpu"] - m0["cpu"] + m1.get("c_cpu", 0) - m0.get("c_cpu", 0))
        / (m1["mono"] - m0["mono"]),
        "pending": [_pending(g0), _pending(g1)],
    }


def _pending(snap: dict[str, Any]) -> int:
    """Changes on the MQTT sink's hands: waiting in its hub subscription, its backlog, in flight."""
    sink = snap["sinks"].get("mqtt", {})
    waiting = int(snap["hub"].get("mqtt", {}).get("backlog", 0))
    return waiting + int(sink.get("backlog", 0)) + int(sink.get("in_flight", 0))


async def _filled(gw: Agent) -> bool:
    return _pending(await gw.ask("snap")) >= 0.9 * BOUND


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
        flat["delivered"], "changes/s", baseline=paho,
        baseline_label="paho QoS 1 ceiling, same subscriber (mosquitto_sub)",
        note=f"paho acked at the broker {d['paho']['acked']:,.0f}/s; broker drops {v['broker_drops']}; "
        f"missing {v['missing']}, out of order {v['out_of_order']}, duplicates {v['duplicates']}, "
        f"redelivered {v['redelivered']}; acknowledged by the broker {flat['acked']:,.0f}/s; gateway CPU "
        f"{flat['cpu']:.0f}%, subscriber {flat['sub_cpu']:.0f}%; "
        f"median of {len(d['qos1']['delivered'])}: " + ", ".join(f"{x:,.0f}" for x in d["qos1"]["delivered"]),
    )  # fmt: skip
    rate = d["cpu_rate"]
    q1, q0 = d["cpu_qos1"]["steps"][0], d["cpu_qos0"]["steps"][0]
    r.add(
        "qos1.cpu_per_1000", SECTION, f"N={N:,} @{rate:,.0f}/s: gateway CPU per 1,000 changes, QoS 1",
        q1["cpu_ms_per_1000"], "ms", baseline=q0["cpu_ms_per_1000"], baseline_label="QoS 0, same rate",
        note=f"medians of {len(d['cpu_qos1']['cpu_ms_per_1000'])}; delivered {q1['delivered']:,.0f}/s vs "
        f"{q0['delivered']:,.0f}/s"
        + ("" if q1["sustained"] and q0["sustained"] else "; NOT sustained at both: not comparable"),
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
