"""The peer: the gateway against a hand-built Node-RED flow, one after the other, on the same load.

The most common alternative to the gateway is a Node-RED flow: node-red-contrib-opcua
subscribing to the controller, feeding an `mqtt out` node (bench/nodered.py builds
it: the OpcUa-Client in its multiple-subscribe mode at a 10-ms publishing
interval). Each party gets the same setup, fresh: the simulator in noise mode with
N = 1,000 variables (bench.agents.simulator), a private Mosquitto, and a paho
subscriber (bench.agents.mqtt_sub) that counts messages and measures latency from
the source timestamp in each JSON payload. MQTT QoS 0, retained, JSON, for both.
The gateway runs as the mirror scenario runs it (its own process, OPC UA source,
the real driver), but without an OPC UA client on its server, since Node-RED
serves none.

Steps: 5,000 and 15,000 changes/s and flat out. Per step: messages/s delivered,
CPU per 1,000 messages (the process's CPU time over the window / messages
delivered in it), latency p50/p99 over the window, the highest RSS sampled in it; for
the gateway also where that latency accrued (`where`: the age at its ingest and at its
MQTT write, bench/agents/ages.py, and the bytes unread in the subscriber's socket).
Node-RED's figures are the baseline of the gateway's (ratio = gateway / Node-RED).

node-red-contrib-opcua creates its subscription with a lifetime of 30 publishing
intervals (300 ms at 10 ms): when Node-RED falls that far behind, the server
(asyncua) ends the subscription and the flow delivers nothing more until it is
redeployed. The scenario counts such expiries from the simulator's log, starts
Node-RED again if its subscription does not outlive start-up, restarts it before a
step if it expired since, measures a step in which it expired once more after a
restart, and the step's note says so.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import shutil
import time
from collections.abc import Awaitable, Callable
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from bench.agents.protocol import percentiles
from bench.context import Context, rate_key, rate_label
from bench.nodered import NodeRed, flow, installed_versions
from bench.procs import Agent, BenchError, Meter, Mosquitto
from bench.scenarios.common import expected_last, matches, noise_paths, noise_topic, write_gateway
from bench.scenarios.mirror import drain
from simulator.noise import NoiseSpec, noise_mapping

N = 1000
QOS = 0
INTERVAL_MS = 10.0  # Node-RED's publishing interval (and its items' sampling interval)
QUEUE_SIZE = 1  # the monitored items' queue at the controller, for both parties
PUBLISH_REQUESTS = 4  # the gateway's Publish requests at the controller (driver.publish_requests), as
# Node-RED runs in its fastest setting: flat out, the simulator's publishing is the limit, not the gateway
MACHINE = "noise"
SIM_NAMESPACE = 2  # simulator/README.md: urn:cnc-simulator:plc is namespace index 2
EXPIRED = (
    "has expired"  # asyncua's log line when a subscription outlived its lifetime without publish requests
)
PARTIES = {"gateway": "cnc-gateway", "nodered": "Node-RED"}


@dataclass
class PeerStep:
    rate: float
    offered: float = 0.0  # changes/s the simulator wrote
    delivered: float = 0.0  # messages/s at the MQTT subscriber
    cpu: float = 0.0  # the party's CPU, % of one core
    cpu_per_1000: float | None = None  # ms of CPU per 1,000 messages delivered
    latency: dict[str, Any] = field(default_factory=dict)  # p50/p99/max/n over the window, ms
    rss: float = 0.0  # bytes, the highest sample in the window
    source_cpu: float = 0.0
    # Where the age accrued (the gateway only): p50/p99/max ms at the source's ingest and at the MQTT write,
    # and the bytes (and, by the mean message size and the delivered rate, ms) unread at the subscriber
    ages: dict[str, Any] = field(default_factory=dict)
    # Flat out: the same window's latency (p50/p99/max/n, ms) at a C subscriber (mosquitto_sub) beside the
    # Python one, which falls behind there (its unread socket adds age after the party has sent)
    latency_c: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["rate"] = None if math.isinf(self.rate) else self.rate
        return out


class Party:
    """One of the two: how to start it (returning its pid) and stop it, and the topics it publishes."""

    def __init__(
        self,
        name: str,
        prefix: str,
        topics: list[str],
        start: Callable[[], Awaitable[int]],
        stop: Callable[[], Awaitable[None]],
        alive: Callable[[], None] = lambda: None,
        ages: Callable[[], Awaitable[dict[str, Any]]] | None = None,
    ) -> None:
        self.name, self.prefix, self.topics = name, prefix, topics
        self.start, self.stop, self.alive = start, stop, alive
        self.ages = ages  # the ages at ingest and write since the last call (bench/agents/ages.py)


async def run(ctx: Context) -> None:
    versions = (
        installed_versions()
    )  # before anything starts: a clear error when make bench did not install it
    ctx.log(
        f"peer: Node-RED {versions['node-red']}, "
        f"node-red-contrib-opcua {versions['node-red-contrib-opcua']}, "
        f"Node.js {versions['node']}; N = {N:,}, MQTT QoS {QOS} JSON"
    )
    details: dict[str, Any] = {
        "versions": versions,
        "variables": N,
        "qos": QOS,
        "interval_ms": INTERVAL_MS,
        "queue_size": QUEUE_SIZE,
        "parties": {},
    }
    ctx.results.details["peer"] = details
    for name, label in PARTIES.items():
        ctx.log(f"{label}:")
        try:
            details["parties"][name] = await run_party(ctx, name)
        except Exception as exc:  # noqa: BLE001 - reported; the other party's figures still count
            ctx.results.errors.append(f"peer {name}: {type(exc).__name__}: {exc}")
            ctx.log(f"  FAILED: {exc}")
    report(ctx, details)


async def run_party(ctx: Context, name: str) -> dict[str, Any]:
    s = ctx.settings
    folder = ctx.workdir / f"peer-{name}"
    folder.mkdir(parents=True)
    out: dict[str, Any] = {"steps": [], "restarts": 0}
    async with Mosquitto(ctx.workdir) as broker, contextlib.AsyncExitStack() as stack:
        sim = await Agent.start(
            f"peer-sim-{name}", "bench.agents.simulator", ["--variables", str(N)], ctx.workdir
        )
        stack.push_async_callback(sim.stop)
        party = (
            _gateway(ctx, folder, sim, broker.port)
            if name == "gateway"
            else _nodered(folder, sim, broker.port)
        )
        sub = await Agent.start(
            f"peer-mqtt-sub-{name}",
            "bench.agents.mqtt_sub",
            ["--port", str(broker.port), "--topic", f"{party.prefix}#", "--qos", str(QOS)],
            ctx.workdir,
        )
        stack.push_async_callback(sub.stop)
        stack.push_async_callback(party.stop)
        started = time.monotonic()
        meter = Meter(await _start(party, sub, sim))
        out["ready_seconds"] = round(time.monotonic() - started, 2)
        ctx.log(f"  all {N:,} variables at the MQTT subscriber after {out['ready_seconds']:.1f} s")
        restart = False
        for rate in s.peer_rates:
            notes: list[str] = []
            for attempt in (1, 2):
                if restart:
                    if attempt == 1:
                        notes.append("restarted before the step (its subscription had expired)")
                    out["restarts"] += 1
                    await party.stop()
                    meter = Meter(await _start(party, sub, sim))
                seen_expired = _expired(sim)
                step = await measure(ctx, sim, sub, meter, party, rate, broker.port)
                expired = _expired(sim) > seen_expired
                dead = expired or (step.offered > 0 and step.delivered == 0)
                restart = dead and name == "nodered"  # the gateway's driver resubscribes by itself
                if not dead:
                    break
                what = "its subscription expired in" if expired else "it delivered nothing in"
                if not restart or attempt == 2:
                    notes.append(f"{what} the step")
                    break
                notes.append(f"{what} a first try; restarted and measured again")
                await drain(sim, sub)
            step.notes = notes
            out["steps"].append(step.as_dict())
            ctx.log(
                f"  {rate_label(rate):>9}: offered {step.offered:8,.0f}/s  "
                f"delivered {step.delivered:8,.0f} msg/s  "
                f"cpu {step.cpu:3.0f}% ({_num(step.cpu_per_1000)} ms/1,000 msgs)  p50/p99 "
                f"{_num(step.latency.get('p50'))}/{_num(step.latency.get('p99'))} ms  "
                f"rss {step.rss / 1e6:4.0f} MB"
                f"  (sim {step.source_cpu:3.0f}%)" + (f"  [{'; '.join(step.notes)}]" if step.notes else "")
            )
            if step.latency_c:
                c = step.latency_c
                ctx.log(
                    f"{'':>13}at a C subscriber (mosquitto_sub) in the same window: p50/p99 "
                    f"{_num(c.get('p50'))}/{_num(c.get('p99'))} ms over {c.get('n', 0):,} messages"
                )
            if step.ages:
                ctx.log(f"{'':>13}{where(step)}")
            await drain(sim, sub)
            restart = restart or (name == "nodered" and _expired(sim) > seen_expired)  # in the pause
        # Node-RED with an expired subscription will not catch up (the gateway's driver resubscribes by
        # itself)
        last_expired = seen_expired
        out["final"] = await final_values(
            sim, sub, party, gave_up=lambda: name == "nodered" and _expired(sim) > last_expired
        )
        out["expired"] = _expired(sim)
        ctx.log(
            f"  last values right at MQTT: {out['final']['match']:,} of {N:,} "
            f"(after {out['final']['settled_after']:.1f} s); subscriptions expired: {out['expired']}"
        )
    return out


def _gateway(ctx: Context, folder: Path, sim: Agent, broker_port: int) -> Party:
    # Queue size 1 at the controller, as Node-RED's monitored item group has (bench/nodered.py) and as the
    # gateway's own default is: the same subscription. With the mirror's 10, a gateway that falls behind
    # is handed up to ten old values per variable to decode, and the age of what it sends starts there.
    mapping = noise_mapping(
        NoiseSpec(N),
        sim.ready["endpoint"],
        machine=MACHINE,
        queue_size=QUEUE_SIZE,
        publish_requests=PUBLISH_REQUESTS,
    )
    config, _ = write_gateway(folder, {MACHINE: mapping}, mqtt_port=broker_port, mqtt={"qos": QOS})
    topics = [noise_topic(MACHINE, p) for p in noise_paths(0, N)]
    agent: list[Agent] = []

    async def start() -> int:
        agent[:] = [
            await Agent.start(
                "peer-gateway", "bench.agents.gateway", ["--config", str(config), "--ages"], ctx.workdir
            )
        ]
        return agent[0].pid

    async def stop() -> None:
        for a in agent:
            await a.stop()
        agent.clear()

    async def ages() -> dict[str, Any]:
        return await agent[0].ask("ages")

    return Party("gateway", f"cnc/{MACHINE}/noise/", topics, start, stop, ages=ages)


def _nodered(folder: Path, sim: Agent, broker_port: int) -> Party:
    spec = NoiseSpec(N)
    ids = [f"ns={SIM_NAMESPACE};s={spec.node_id(i)}" for i in range(N)]
    prefix = "peer/noise/"
    nodes = flow(
        sim.ready["endpoint"], ids, broker_port, interval_ms=INTERVAL_MS, qos=QOS, topic_prefix=prefix
    )
    # bench/nodered.py's function node: the part of the node id after its last ':' with '.' → '/'
    topics = [prefix + spec.node_id(i).rsplit(":", 1)[1].replace(".", "/", 1) for i in range(N)]
    running: list[NodeRed] = []
    starts = [0]

    async def start() -> int:
        starts[0] += 1
        red = NodeRed(folder / f"node-red-{starts[0]}", nodes)  # a restart starts from a clean user directory
        red.folder.mkdir(parents=True)
        running[:] = [await red.__aenter__()]
        return red.pid

    async def stop() -> None:
        for red in running:
            await red.__aexit__(None, None, None)
        running.clear()

    def alive() -> None:
        for red in running:
            red.check()

    return Party("nodered", prefix, topics, start, stop, alive)


async def _start(party: Party, sub: Agent, sim: Agent, tries: int = 3) -> int:
    """Start the party and wait until it has published every topic; for Node-RED, also until its
    subscription has outlived start-up (on a loaded machine it can expire in the first second)."""
    for _ in range(tries):
        expired = _expired(sim)
        pid = await _publishing(party, sub)
        if party.name != "nodered":
            return pid
        await asyncio.sleep(1.0)
        if _expired(sim) == expired:
            return pid
        await party.stop()
    raise BenchError(f"{PARTIES[party.name]}'s subscription expired during start-up {tries} times")


async def _publishing(party: Party, sub: Agent, timeout: float = 120.0) -> int:
    """Start the party; wait until it has published every topic (initial values count) since it started."""
    before = (await sub.ask("snap"))["count"]
    pid = await party.start()
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        party.alive()
        count = (await sub.ask("snap"))["count"]
        if count - before >= N:
            last = (await sub.ask("values"))["last"]
            missing = [t for t in party.topics if t not in last]
            if not missing:
                return pid
        if loop.time() > deadline:
            raise BenchError(
                f"{PARTIES[party.name]} published {count - before} messages in {timeout:g} s, "
                f"not every one of the {N:,} variables"
            )
        await asyncio.sleep(0.2)


def _expired(sim: Agent) -> int:
    try:
        return sim.log.read_text(errors="replace").count(EXPIRED)
    except OSError:
        return 0


async def measure(
    ctx: Context, sim: Agent, sub: Agent, meter: Meter, party: Party, rate: float, broker_port: int
) -> PeerStep:
    s = ctx.settings
    await sim.ask("rate", rate="max" if math.isinf(rate) else rate)
    await asyncio.sleep(s.warmup)
    step = PeerStep(rate)
    if party.ages is not None:
        await party.ages()  # from here
    c_sub = await CSubscriber.start(ctx.workdir, broker_port, party.prefix) if math.isinf(rate) else None
    src0, sub0 = await sim.ask("snap"), await sub.ask("mark")
    cpu0, t0 = meter.cpu(), time.monotonic()
    rss = [meter.rss()]
    end = t0 + s.window
    while (left := end - time.monotonic()) > 0:
        await asyncio.sleep(min(1.0, left))
        party.alive()
        rss.append(meter.rss())
    src1, sub1 = await sim.ask("snap"), await sub.ask("snap")
    cpu1, t1 = meter.cpu(), time.monotonic()
    rss.append(meter.rss())
    if c_sub is not None:
        step.latency_c = await c_sub.stop()
    step.offered = (src1["written"] - src0["written"]) / (src1["mono"] - src0["mono"])
    step.source_cpu = 100.0 * (src1["cpu"] - src0["cpu"]) / (src1["mono"] - src0["mono"])
    step.delivered = (sub1["count"] - sub0["count"]) / (sub1["mono"] - sub0["mono"])
    cpu_rate = (cpu1 - cpu0) / (t1 - t0)  # CPU seconds per second
    step.cpu = 100.0 * cpu_rate
    step.cpu_per_1000 = 1e6 * cpu_rate / step.delivered if step.delivered > 0 else None
    step.latency = sub1["window"]
    step.rss = max(rss)
    if party.ages is not None:
        ages = await party.ages()
        backlog = dict(sub1["backlog"])
        count = sub1["count"] - sub0["count"]
        if count > 0 and step.delivered > 0 and backlog.get("p99") is not None:
            size = (sub1["bytes"] - sub0["bytes"]) / count + 4  # + the PUBLISH header
            backlog["p99_ms"] = 1000.0 * backlog["p99"] / size / step.delivered
        step.ages = {"ingest": ages["ingest"], "write": ages["write"], "subscriber_backlog": backlog}
    return step


async def final_values(
    sim: Agent, sub: Agent, party: Party, *, gave_up: Callable[[], bool], timeout: float = 30.0
) -> dict[str, Any]:
    """After the last step: does every topic end at the last value the simulator wrote to its variable?
    Polled until it does, or the deadline passes, or the party's subscription has expired (a second later)."""
    written = int((await sim.ask("snap"))["written"])
    expected = expected_last(written, N)
    loop = asyncio.get_running_loop()
    started = loop.time()
    expired_at: float | None = None
    while True:
        last = (await sub.ask("values"))["last"]
        match = matches([last.get(t) for t in party.topics], expected)
        now = loop.time()
        if expired_at is None and gave_up():
            expired_at = now
        if match == N or now - started > timeout or (expired_at is not None and now - expired_at >= 1.0):
            break
        await asyncio.sleep(0.5)
    return {
        "written": written,
        "match": match,
        "variables": N,
        "settled_after": round(loop.time() - started, 1),
    }


def where(step: PeerStep | dict[str, Any]) -> str:
    """Where the age of the delivered values accrued: before the gateway, inside it, after it."""
    ages = step.ages if isinstance(step, PeerStep) else step.get("ages") or {}
    latency = step.latency if isinstance(step, PeerStep) else step.get("latency") or {}
    if not ages:
        return ""
    ingest, write, backlog = ages["ingest"], ages["write"], ages["subscriber_backlog"]

    def pair(d: dict[str, Any]) -> str:
        return f"{_num(d.get('p50'))}/{_num(d.get('p99'))} ms"

    return (
        f"age p50/p99 at the gateway's ingest {pair(ingest)}, at its MQTT write {pair(write)}, "
        f"at the subscriber {pair(latency)}; unread in the subscriber's socket p99 "
        f"{(backlog.get('p99') or 0) / 1e3:,.0f} kB (~{_num(backlog.get('p99_ms'))} ms of messages)"
    )


def _num(value: float | None) -> str:
    return "—" if value is None else f"{value:,.1f}"


def section(details: dict[str, Any]) -> str:
    v = details.get("versions", {})
    return (
        f"Peer: cnc-gateway vs Node-RED {v.get('node-red', '?')} + node-red-contrib-opcua "
        f"{v.get('node-red-contrib-opcua', '?')} (multiple subscribe, {INTERVAL_MS:g} ms), "
        f"same load, N={N:,}, MQTT QoS {QOS} JSON"
    )


def report(ctx: Context, details: dict[str, Any]) -> None:
    r = ctx.results
    sec = section(details)
    parties = details["parties"]
    gateway, nodered = parties.get("gateway", {}), parties.get("nodered", {})
    peer_steps = {st["rate"]: st for st in nodered.get("steps", [])}
    rates = [st["rate"] for st in gateway.get("steps", [])] or list(peer_steps)
    gw_steps = {st["rate"]: st for st in gateway.get("steps", [])}
    for rate_or_none in rates:
        st, other = gw_steps.get(rate_or_none, {}), peer_steps.get(rate_or_none, {})
        rate = math.inf if rate_or_none is None else rate_or_none
        key, what = f"peer.{rate_key(rate)}", f"@{rate_label(rate)}"
        notes = [f"source wrote {st.get('offered', 0):,.0f}/s vs {other.get('offered', 0):,.0f}/s"]
        notes += [
            f"{who}: {'; '.join(step['notes'])}"
            for who, step in (("gateway", st), ("Node-RED", other))
            if step.get("notes")
        ]
        r.add(
            f"{key}.delivered",
            sec,
            f"{what}: MQTT delivered",
            st.get("delivered"),
            "msgs/s",
            baseline=other.get("delivered"),
            baseline_label="Node-RED",
            note="; ".join(notes),
        )
        r.add(
            f"{key}.cpu_per_1000",
            sec,
            f"{what}: CPU per 1,000 msgs",
            st.get("cpu_per_1000"),
            "ms",
            baseline=other.get("cpu_per_1000"),
            baseline_label="Node-RED",
            note=f"{st.get('cpu', 0):.0f} % vs {other.get('cpu', 0):.0f} % of a core",
        )
        for q in ("p50", "p99"):
            r.add(
                f"{key}.{q}",
                sec,
                f"{what}: latency {q}",
                (st.get("latency") or {}).get(q),
                "ms",
                baseline=(other.get("latency") or {}).get(q),
                baseline_label="Node-RED",
            )
        r.add(
            f"{key}.rss",
            sec,
            f"{what}: RSS",
            st["rss"] / 1e6 if st.get("rss") else None,
            "MB",
            baseline=other["rss"] / 1e6 if other.get("rss") else None,
            baseline_label="Node-RED",
        )
    r.add(
        "peer.final",
        sec,
        "last values right at MQTT after the last step",
        _final(gateway),
        "vars",
        baseline=_final(nodered),
        baseline_label="Node-RED",
        note=f"of {N:,}; subscriptions expired: gateway {gateway.get('expired', '—')}, Node-RED "
        f"{nodered.get('expired', '—')} (Node-RED restarted {nodered.get('restarts', 0)}×)",
    )


def _final(party: dict[str, Any]) -> float | None:
    final = party.get("final")
    return None if final is None else float(final["match"])


class CSubscriber:
    """mosquitto_sub for one window, writing each message's receipt time (`%U`, the wall clock with
    nanoseconds) and payload to a file; afterwards, the latency of each from its payload's `ts`, as the
    Python subscriber computes it. Retained messages (stale) are not printed (`-R`)."""

    def __init__(self, proc: asyncio.subprocess.Process, path: Path) -> None:
        self.proc, self.path = proc, path

    @classmethod
    async def start(cls, workdir: Path, port: int, prefix: str) -> CSubscriber:
        exe = shutil.which("mosquitto_sub")
        if exe is None:
            raise BenchError("mosquitto_sub is not installed (make system-deps installs mosquitto-clients)")
        path = workdir / f"mosquitto-sub-{time.monotonic_ns()}.txt"
        with path.open("wb") as out:
            proc = await asyncio.create_subprocess_exec(
                exe, "-h", "127.0.0.1", "-p", str(port), "-t", f"{prefix}#", "-q", "0", "-R",
                "-F", "%U %p", stdout=out, stderr=asyncio.subprocess.DEVNULL,
            )  # fmt: skip
        return cls(proc, path)

    async def stop(self) -> dict[str, Any]:
        with contextlib.suppress(ProcessLookupError):
            self.proc.terminate()
        await self.proc.wait()
        return await asyncio.to_thread(c_latencies, self.path)


def c_latencies(path: Path) -> dict[str, Any]:
    seconds: dict[str, float] = {}
    out: list[float] = []
    with path.open("rb") as lines:
        for line in lines:
            stamp, _, payload = line.partition(b" ")
            t = payload.find(b'"ts":"')
            if t < 0:
                continue
            ts = payload[t + 6 : t + 30].decode("ascii", "replace")
            head = ts[:19]
            base = seconds.get(head)
            if base is None:
                try:
                    base = datetime.fromisoformat(head + "+00:00").timestamp()
                except ValueError:
                    continue
                seconds[head] = base
            try:
                out.append((float(stamp) - base - int(ts[20:23]) / 1000.0) * 1000.0)
            except ValueError:
                continue
    path.unlink(missing_ok=True)
    return percentiles(out)
