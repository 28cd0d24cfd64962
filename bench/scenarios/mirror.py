"""Mirror throughput and latency: N variables changing at a set rate, through the gateway, to subscribers.

One configuration = (N, source, QoS). Source `opcua`: the simulator's noise mode
in its own process, read by the gateway's real OPC UA source driver. Source
`inproc`: the gateway process pushes the changes into `Machine.ingest` itself,
so that the sinks are measured alone. Either way the gateway runs in its own
process, and two subscribers in processes of their own count what arrives: a
paho MQTT subscriber at the configured QoS, and an asyncua client subscribed to
all N variables (queue size 1, 100 ms publishing interval).

For each rate step: set the rate, warm up, count over a fixed window (the
gateway's backlogs sampled every second), then pause the source and let the
pipeline drain. After the last step every variable's last value at both
subscribers is compared with the last value the source wrote.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field
from typing import Any

from bench.context import Context, rate_key, rate_label
from bench.procs import Agent, Meter, Mosquitto
from bench.scenarios.common import (
    GATEWAY_URI,
    expected_last,
    gateway_ids,
    ids_file,
    matches,
    noise_paths,
    noise_topic,
    profile,
    write_gateway,
)
from simulator.noise import NoiseSpec, noise_mapping

MACHINE = "noise"
OPCUA_SUB_INTERVAL = 100.0  # ms, the OPC UA subscriber's publishing interval (queue size 1)
SUSTAINED = 0.95  # a step is sustained when at least this share of what arrives is delivered...
OPCUA_SHARE = 0.8  # ...and the OPC UA subscriber gets this share of what its queue size allows


@dataclass
class Step:
    rate: float
    seconds: float = 0.0
    offered: float = 0.0  # changes/s the source produced
    received: float = 0.0  # changes/s the gateway's tree accepted (into the MQTT hub subscription)
    mqtt: float = 0.0  # changes/s at the MQTT subscriber
    opcua: float = 0.0  # notifications/s at the OPC UA subscriber
    latency: dict[str, Any] = field(default_factory=dict)  # over the whole window
    latency_seconds: list[dict[str, Any]] = field(default_factory=list)  # each second of it
    opcua_latency: dict[str, Any] = field(default_factory=dict)
    cpu: float = 0.0  # gateway CPU, % of one core
    source_cpu: float = 0.0  # the simulator's (opcua source)
    others_cpu: dict[str, float] = field(
        default_factory=dict
    )  # subscribers and broker: who else used the cores
    backlog: list[dict[str, int]] = field(default_factory=list)
    growing: bool = False
    coalesced_opcua: float = 0.0  # /s: intermediate values the OPC UA sink skipped (latest-value mode)
    dropped: int = 0
    gc: dict[str, Any] = field(default_factory=dict)  # the gateway's collector passes in the window
    lagged: int = 0  # changes the source could not produce at the set rate

    @property
    def opcua_expected(self) -> float:
        return min(self.received, self.n_cap)

    n_cap: float = math.inf

    @property
    def p99_median(self) -> float | None:
        """The median of the p99s of the window's seconds: one bad second (another process taking
        the core) does not decide it, as it can the p99 of the whole window, which is beside it."""
        values = sorted(s["p99"] for s in self.latency_seconds if s.get("n", 0) >= 100)
        return values[len(values) // 2] if values else None

    @property
    def sustained(self) -> bool:
        if self.received <= 0 or self.growing or self.mqtt < SUSTAINED * self.received:
            return False
        if math.isfinite(self.rate) and self.received < SUSTAINED * self.offered:
            return False  # the gateway's source did not take what the controller offered
        return self.opcua >= OPCUA_SHARE * self.opcua_expected

    def as_dict(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        out["rate"] = None if math.isinf(self.rate) else self.rate
        out["sustained"] = self.sustained
        out["p99_median"] = self.p99_median
        out["opcua_expected"] = self.opcua_expected
        out["n_cap"] = None if math.isinf(self.n_cap) else self.n_cap
        return out


async def run(ctx: Context) -> None:
    s = ctx.settings
    for source in s.mirror_sources:
        for n in s.mirror_sizes:
            for qos in s.mirror_qos:
                name = f"{source}.qos{qos}.n{n}"
                ctx.log(f"mirror: {source} source, {n:,} variables, MQTT QoS {qos}")
                try:
                    steps, final = await configuration(ctx, source, n, qos)
                except Exception as exc:  # noqa: BLE001 - reported; the other configurations still run
                    ctx.results.errors.append(f"mirror {name}: {type(exc).__name__}: {exc}")
                    ctx.log(f"FAILED: {exc}")
                    continue
                ctx.results.details.setdefault("mirror", {})[name] = {
                    "steps": [st.as_dict() for st in steps],
                    "final": final,
                }
                report(ctx, source, n, qos, steps, final)


async def configuration(ctx: Context, source: str, n: int, qos: int) -> tuple[list[Step], dict[str, Any]]:
    s = ctx.settings
    folder = ctx.workdir / f"mirror-{source}-q{qos}-n{n}"
    spec = NoiseSpec(n)
    agents: list[Agent] = []
    async with Mosquitto(ctx.workdir) as broker:
        try:
            sim: Agent | None = None
            endpoint = "opc.tcp://127.0.0.1:1"  # never contacted: the injector replaces the source
            if source == "opcua":
                sim = await Agent.start(
                    f"sim-{folder.name}", "bench.agents.simulator", ["--variables", str(n)], ctx.workdir
                )
                agents.append(sim)
                endpoint = sim.ready["endpoint"]
            mapping = noise_mapping(spec, endpoint, machine=MACHINE)
            config, gw_endpoint = write_gateway(
                folder, {MACHINE: mapping}, mqtt_port=broker.port, mqtt={"qos": qos}
            )
            gw = await Agent.start(
                f"gw-{folder.name}",
                "bench.agents.gateway",
                ["--config", str(config), *(["--inject"] if sim is None else [])],
                ctx.workdir,
            )
            agents.append(gw)
            if sim is not None:
                await _wait_good(gw, n)
            paths = noise_paths(0, n)
            ids = ids_file(folder / "ids.txt", GATEWAY_URI, gateway_ids(MACHINE, paths))
            mqtt_sub = await Agent.start(
                f"mqtt-sub-{folder.name}", "bench.agents.mqtt_sub",
                ["--port", str(broker.port), "--topic", f"cnc/{MACHINE}/noise/#", "--qos", str(qos)],
                ctx.workdir,
            )  # fmt: skip
            agents.append(mqtt_sub)
            opcua_sub = await Agent.start(
                f"opcua-sub-{folder.name}", "bench.agents.opcua_sub",
                ["--endpoint", gw_endpoint, "--ids", str(ids), "--interval", str(OPCUA_SUB_INTERVAL)],
                ctx.workdir,
            )  # fmt: skip
            agents.append(opcua_sub)
            driver = sim if sim is not None else gw
            broker_meter = Meter(broker.pid) if broker.pid else None
            steps = []
            for rate in s.mirror_rates:
                step = await measure(
                    ctx,
                    driver,
                    gw,
                    mqtt_sub,
                    opcua_sub,
                    rate,
                    n,
                    broker=broker_meter,
                    profile_as=f"{source}-q{qos}-n{n}-{rate_key(rate)}" if s.profile else None,
                )
                steps.append(step)
                ctx.log(
                    f"  {rate_label(rate):>9}: offered {step.offered:8,.0f}/s  in {step.received:8,.0f}/s  "
                    f"mqtt {step.mqtt:8,.0f}/s  opcua {step.opcua:8,.0f}/s  "
                    f"p99 {_ms(step.latency.get('p99'))} ({_ms(step.p99_median)})  "
                    f"cpu {step.cpu:3.0f}% (sim {step.source_cpu:3.0f}%, subs+broker "
                    f"{sum(step.others_cpu.values()):3.0f}%)  {'backlog GROWS' if step.growing else ''}"
                    + (f"  gc {step.gc['passes']} {step.gc['paused_ms']:.0f} ms" if step.gc else "")
                )
                await drain(driver, mqtt_sub)
            final = await final_values(driver, gw, mqtt_sub, opcua_sub, n, source)
            return steps, final
        finally:
            for agent in reversed(agents):
                last = await agent.stop()
                if agent.name.startswith("gw-") and last is not None:
                    ctx.results.details.setdefault("mirror_gateway_peak_rss", {})[folder.name] = last.get(
                        "maxrss"
                    )


async def _wait_good(gw: Agent, n: int, timeout: float = 60.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        snap = await gw.ask("snap")
        machine = snap["machines"][MACHINE]
        if machine["good"] >= n:
            return
        if loop.time() > deadline:
            raise TimeoutError(f"only {machine['good']} of {n} variables Good after {timeout:g} s")
        await asyncio.sleep(0.2)


def _source_written(snap: dict[str, Any]) -> tuple[int, int]:
    """(changes written, changes lagged) from a simulator or an injecting gateway's answer."""
    stats = snap.get("injector", snap)
    return int(stats["written"]), int(stats.get("lagged", 0))


def _pending(snap: dict[str, Any]) -> dict[str, int]:
    hub, sinks = snap["hub"], snap["sinks"]
    mqtt = hub.get("mqtt", {})
    sink = sinks.get("mqtt", {})
    return {
        "mqtt": int(mqtt.get("backlog", 0)) + int(sink.get("backlog", 0)) + int(sink.get("in_flight", 0)),
        "opcua": int(hub.get("opcua", {}).get("backlog", 0)),
    }


def _hub_in(snap: dict[str, Any]) -> int:
    """Changes pushed into the MQTT sink's hub subscription so far (taken + waiting + collapsed)."""
    sub = snap["hub"].get("mqtt", {})
    return int(sub.get("delivered", 0)) + int(sub.get("backlog", 0)) + int(sub.get("coalesced", 0))


async def measure(
    ctx: Context,
    driver: Agent,
    gw: Agent,
    mqtt_sub: Agent,
    opcua_sub: Agent,
    rate: float,
    n: int,
    *,
    profile_as: str | None = None,
    broker: Meter | None = None,
) -> Step:
    s = ctx.settings
    await driver.ask("rate", rate="max" if math.isinf(rate) else rate)
    await asyncio.sleep(s.warmup)
    step = Step(rate, n_cap=n * 1000.0 / OPCUA_SUB_INTERVAL)
    src0 = await driver.ask("snap")
    gw0, m0, o0 = await gw.ask("snap"), await mqtt_sub.ask("mark"), await opcua_sub.ask("snap")
    broker0 = broker.cpu() if broker is not None else 0.0
    step.backlog.append(_pending(gw0))
    profiling = None
    if profile_as is not None:
        profiling = asyncio.create_task(profile(gw.pid, s.window, ctx.workdir / f"profile-{profile_as}"))
    loop = asyncio.get_running_loop()
    end = loop.time() + s.window
    while loop.time() < end - 0.5:
        await asyncio.sleep(min(1.0, max(0.0, end - loop.time())))
        step.backlog.append(_pending(await gw.ask("snap")))
        step.latency_seconds.append((await mqtt_sub.ask("snap"))["latency"])
    await asyncio.sleep(max(0.0, end - loop.time()))
    src1 = await driver.ask("snap")
    gw1, m1, o1 = await gw.ask("snap"), await mqtt_sub.ask("snap"), await opcua_sub.ask("snap")
    broker1 = broker.cpu() if broker is not None else 0.0
    step.backlog.append(_pending(gw1))
    if profiling is not None:
        ctx.profiles[profile_as or ""] = await profiling
    seconds = gw1["mono"] - gw0["mono"]
    step.seconds = seconds
    (w0, l0), (w1, l1) = _source_written(src0), _source_written(src1)
    step.offered = (w1 - w0) / (src1["mono"] - src0["mono"])
    step.lagged = l1 - l0
    step.received = (_hub_in(gw1) - _hub_in(gw0)) / seconds
    step.mqtt = (m1["count"] - m0["count"]) / (m1["mono"] - m0["mono"])
    step.opcua = (o1["count"] - o0["count"]) / (o1["mono"] - o0["mono"])
    step.latency = m1["window"]
    step.latency_seconds.append(m1["latency"])
    step.opcua_latency = o1["latency"]
    step.cpu = 100.0 * (gw1["cpu"] - gw0["cpu"]) / seconds
    if driver is not gw:
        step.source_cpu = 100.0 * (src1["cpu"] - src0["cpu"]) / (src1["mono"] - src0["mono"])
    step.others_cpu = {
        "mqtt_subscriber": 100.0 * (m1["cpu"] - m0["cpu"]) / (m1["mono"] - m0["mono"]),
        "opcua_subscriber": 100.0 * (o1["cpu"] - o0["cpu"]) / (o1["mono"] - o0["mono"]),
    }
    if broker is not None:
        step.others_cpu["mosquitto"] = 100.0 * (broker1 - broker0) / seconds
    opc0, opc1 = gw0["hub"].get("opcua", {}), gw1["hub"].get("opcua", {})
    step.coalesced_opcua = (opc1.get("coalesced", 0) - opc0.get("coalesced", 0)) / seconds
    step.dropped = int(gw1["sinks"].get("mqtt", {}).get("dropped", 0))
    g0, g1 = gw0.get("gc", {}), gw1.get("gc", {})
    if g1.get("installed"):
        step.gc = {
            "passes": [b - a for a, b in zip(g0["count"], g1["count"], strict=True)],
            "paused_ms": round(sum(g1["total_ms"]) - sum(g0["total_ms"]), 1),
            "longest_gen2_ms": g1["longest_ms"][2],
        }
    received_total = step.received * seconds
    growth = step.backlog[-1]["mqtt"] - step.backlog[0]["mqtt"]
    step.growing = growth > max(500.0, 0.05 * received_total)
    return step


async def drain(driver: Agent, mqtt_sub: Agent, timeout: float = 20.0) -> None:
    """Pause the source; wait until the MQTT subscriber has seen nothing new for half a second."""
    await driver.ask("rate", rate=0)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    last, since = -1, loop.time()
    while loop.time() < deadline:
        count = (await mqtt_sub.ask("snap"))["count"]
        if count != last:
            last, since = count, loop.time()
        elif loop.time() - since >= 0.5:
            return
        await asyncio.sleep(0.1)


async def final_values(
    driver: Agent, gw: Agent, mqtt_sub: Agent, opcua_sub: Agent, n: int, source: str, timeout: float = 60.0
) -> dict[str, Any]:
    """After the last step: does every variable end at the source's last value, at both subscribers?

    Polled until both subscribers have every last value or the deadline passes: after a
    flat-out step the gateway may still be working off a backlog, or resynchronising after
    its driver gave up on a controller too busy to answer, and what counts is that it gets
    there. The time it took is reported beside the counts.
    """
    written, _ = _source_written(await driver.ask("snap"))
    expected = expected_last(written, n)
    topics = [noise_topic(MACHINE, p) for p in noise_paths(0, n)]
    loop = asyncio.get_running_loop()
    started = loop.time()
    while True:
        await asyncio.sleep(0.5)  # at least the OPC UA subscriber's publishing interval
        mqtt_last = (await mqtt_sub.ask("values"))["last"]
        opcua_last = (await opcua_sub.ask("values"))["last"]
        mqtt_match = matches([mqtt_last.get(t) for t in topics], expected)
        opcua_match = matches(opcua_last, expected)
        if (mqtt_match == n and opcua_match == n) or loop.time() - started > timeout:
            break
    snap = await gw.ask("snap")
    return {
        "written": written,
        "mqtt_match": mqtt_match,
        "opcua_match": opcua_match,
        "variables": n,
        "settled_after": round(loop.time() - started, 1),
        "dropped": snap["sinks"].get("mqtt", {}).get("dropped", 0),
        "discarded": snap["sinks"].get("mqtt", {}).get("discarded", 0),
    }


def _ms(value: float | None) -> str:
    return "—" if value is None else f"{value:.0f} ms"


SECTION = {
    "opcua": "Mirror: simulator over OPC UA → gateway → MQTT + OPC UA subscribers",
    "inproc": "Sinks alone: in-process source → gateway sinks → MQTT + OPC UA subscribers",
}


def report(ctx: Context, source: str, n: int, qos: int, steps: list[Step], final: dict[str, Any]) -> None:
    r = ctx.results
    section = SECTION[source]
    base = f"mirror.{source}.qos{qos}.n{n}"
    tag = f"N={n:,} QoS {qos}"
    for st in steps:
        key = f"{base}.{rate_key(st.rate)}"
        what = f"{tag} @{rate_label(st.rate)}"
        r.add(
            f"{key}.mqtt_rate",
            section,
            f"{what}: MQTT delivered",
            st.mqtt,
            "changes/s",
            baseline=st.received,
            baseline_label="into the gateway",
            note="sustained" if st.sustained else "NOT sustained",
        )
        if math.isfinite(st.rate):
            r.add(
                f"{key}.received",
                section,
                f"{what}: into the gateway",
                st.received,
                "changes/s",
                baseline=st.offered,
                baseline_label="source wrote",
            )
        else:
            r.add(
                f"{key}.received",
                section,
                f"{what}: into the gateway",
                st.received,
                "changes/s",
                baseline=st.offered,
                baseline_label="source wrote flat out",
            )
        r.add(
            f"{key}.opcua_rate",
            section,
            f"{what}: OPC UA notifications",
            st.opcua,
            "notif/s",
            baseline=st.opcua_expected,
            baseline_label="queue-1 limit",
        )
        r.add(f"{key}.p50", section, f"{what}: latency p50", st.latency.get("p50"), "ms")
        r.add(f"{key}.p99", section, f"{what}: latency p99", st.latency.get("p99"), "ms")
        r.add(
            f"{key}.p99_median", section, f"{what}: latency p99, median of 1-s windows", st.p99_median, "ms"
        )
        r.add(f"{key}.max", section, f"{what}: latency max", st.latency.get("max"), "ms")
        r.add(
            f"{key}.cpu",
            section,
            f"{what}: gateway CPU",
            st.cpu,
            "%",
            note=f"backlog {st.backlog[0]['mqtt']}→{st.backlog[-1]['mqtt']}"
            + (" GROWS" if st.growing else ""),
        )
    peak = ctx.results.details.get("mirror_gateway_peak_rss", {}).get(f"mirror-{source}-q{qos}-n{n}")
    r.add(f"{base}.peak_rss", section, f"{tag}: gateway peak RSS", peak / 1e6 if peak else None, "MB")
    r.add(
        f"{base}.final_mqtt",
        section,
        f"{tag}: last values right at MQTT",
        final["mqtt_match"],
        "vars",
        baseline=final["variables"],
        baseline_label="variables",
        note=f"after {final['settled_after']:.1f} s" if final.get("settled_after") is not None else "",
    )
    r.add(
        f"{base}.final_opcua",
        section,
        f"{tag}: last values right at OPC UA",
        final["opcua_match"],
        "vars",
        baseline=final["variables"],
        baseline_label="variables",
    )
