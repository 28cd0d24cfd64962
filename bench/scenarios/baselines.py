"""The ceilings of the libraries underneath, measured in this run: asyncua and paho → Mosquitto.

* asyncua: a plain server's `write_attribute_value` rate with no subscriber, the
  data-change notifications per second it delivers to one subscribed client
  (queue size 1, 100 ms publishing interval, 10,000 variables, writer flat out),
  and the time to build a hierarchical address space of 10,000 variables.
* paho → Mosquitto → paho: messages per second at the subscriber, QoS 0 and
  QoS 1, 80-byte payloads, publisher flat out.
* the simulator's noise mode: what it sustains with no subscriber, so that the
  mirror figures are known not to be capped by the simulator.
* PublishResponse decoding: data-change notifications per CPU second decoded by
  asyncua's `struct_from_binary` and by the OPC UA source's compiled reader, on the
  same responses captured from the simulator (bench/publish_capture.py); and the
  gateway's OPC UA source alone at 5,000 changes/s, CPU per 1,000 changes with each
  (bench/source_ab.py, alternating windows in one process).

Each rate is the median of `repeats` short windows after a warm-up.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import statistics
import sys
from typing import Any

from bench.context import Context
from bench.procs import Agent, Mosquitto, free_port
from bench.scenarios.common import ids_file

SECTION = "Baselines: the libraries' ceilings"
RAW_VARIABLES = 10_000
NOTIFY_RATES = [10_000, 20_000, 30_000, "max"]  # writer rates; the ceiling is the best notification rate
NOTIFY_RATES_QUICK = [20_000, "max"]
ISSUE = "issue's reference machine"


async def run(ctx: Context) -> None:
    await asyncua_ceiling(ctx)
    await paho_ceiling(ctx)
    await noise_ceiling(ctx)
    await publish_decode(ctx)
    await source_decode(ctx)
    notify, qos0 = ctx.ceilings.get("asyncua_notify"), ctx.ceilings.get("paho_qos0")
    if notify and qos0:
        ctx.ceilings["lower"] = min(notify, qos0)
        ctx.results.add(
            "baseline.lower_ceiling",
            SECTION,
            "lower raw ceiling: min(asyncua notifications, paho QoS 0)",
            ctx.ceilings["lower"],
            "msg/s",
        )


async def asyncua_ceiling(ctx: Context) -> None:
    s, r = ctx.settings, ctx.results
    ctx.log("asyncua: building 10,000 variables, writing flat out")
    server = await Agent.start(
        "raw-opcua",
        "bench.agents.raw_opcua",
        ["--variables", str(RAW_VARIABLES), "--port", str(free_port())],
        ctx.workdir,
    )
    try:
        build = server.ready["build_seconds"]
        ctx.ceilings["asyncua_build_10k"] = build
        r.add(
            "baseline.asyncua.build_10k",
            SECTION,
            "asyncua: build 10,000 variables (hierarchical)",
            build,
            "s",
            baseline=2.0,
            baseline_label=ISSUE,
        )
        rates = []
        await server.ask("burst", seconds=0.5)  # warm-up
        for _ in range(s.repeats):
            answer = await server.ask("burst", seconds=2.0)
            rates.append(answer["writes"] / answer["elapsed"])
        ctx.ceilings["asyncua_writes"] = statistics.median(rates)
        ctx.ceilings["asyncua_rss_10k"] = (await server.ask("snap"))["rss"]
        r.add(
            "baseline.asyncua.writes",
            SECTION,
            "asyncua: write_attribute_value, no subscriber",
            ctx.ceilings["asyncua_writes"],
            "writes/s",
            baseline=217_000,
            baseline_label=ISSUE,
        )
        ids = ids_file(
            ctx.workdir / "raw-ids.txt", server.ready["uri"], [f"v{i:05d}" for i in range(RAW_VARIABLES)]
        )
        sub = await Agent.start(
            "raw-opcua-sub",
            "bench.agents.opcua_sub",
            ["--endpoint", server.ready["endpoint"], "--ids", str(ids)],
            ctx.workdir,
        )
        best: dict[str, float] = {}
        try:
            for rate in NOTIFY_RATES_QUICK if s.quick else NOTIFY_RATES:
                await server.ask("run", rate=rate)
                await asyncio.sleep(s.warmup)
                snaps = [await sub.ask("snap")]
                for _ in range(s.repeats):
                    await asyncio.sleep(s.window / 2)
                    snaps.append(await sub.ask("snap"))
                await server.ask("pause")
                got = statistics.median(
                    (b["count"] - a["count"]) / (b["mono"] - a["mono"]) for a, b in itertools.pairwise(snaps)
                )
                best[str(rate)] = got
                await asyncio.sleep(0.5)
        finally:
            await sub.stop()
        ctx.results.details.setdefault("baselines", {})["asyncua_notify_by_rate"] = best
        ctx.ceilings["asyncua_notify"] = max(best.values())
        r.add(
            "baseline.asyncua.notify",
            SECTION,
            "asyncua: notifications to one client (queue 1, 100 ms, 10k vars, best writer rate)",
            ctx.ceilings["asyncua_notify"],
            "notif/s",
            baseline=22_000,
            baseline_label=ISSUE,
        )
    finally:
        await server.stop()


async def paho_ceiling(ctx: Context) -> None:
    r = ctx.results
    reference = {0: 20_000, 1: 14_000}
    for qos in (0, 1):
        ctx.log(f"paho → Mosquitto → paho, QoS {qos}, 80-byte payloads, flat out")
        rates, latency = await paho_rates(ctx, qos, f"raw-mqtt-q{qos}")
        ctx.ceilings[f"paho_qos{qos}"] = statistics.median(rates)
        ctx.results.details.setdefault("baselines", {})[f"paho_qos{qos}"] = {
            "rates": rates,
            "latency_ms": latency,
        }
        r.add(
            f"baseline.paho.qos{qos}",
            SECTION,
            f"paho → Mosquitto → paho, QoS {qos} (80 B)",
            ctx.ceilings[f"paho_qos{qos}"],
            "msg/s",
            baseline=reference[qos],
            baseline_label=ISSUE,
        )


async def paho_rates(
    ctx: Context, qos: int, name: str, *, check: bool = False, c_sub: bool = False
) -> tuple[list[float], dict[str, Any]]:
    """One paho publisher flat out (bench/agents/paho_pub.py; QoS 1: a window of 200) through a fresh
    Mosquitto to one paho subscriber: msg/s at the subscriber in `repeats` windows, and the latency.
    Also issue 28's ceiling beside the gateway's QoS 1 rate (bench/scenarios/qos1.py), whose subscriber
    checks order and duplicates as it reads (`check`): this one then does the same work per message."""
    s = ctx.settings
    if c_sub:
        return await _paho_c_sub(ctx, qos, name)
    async with Mosquitto(ctx.workdir) as broker:
        sub = await Agent.start(
            f"{name}-sub",
            "bench.agents.mqtt_sub",
            [
                "--port",
                str(broker.port),
                "--topic",
                "raw/#",
                "--qos",
                str(qos),
                *(["--check"] if check else []),
            ],
            ctx.workdir,
        )
        pub = await Agent.start(
            f"{name}-pub",
            "bench.agents.paho_pub",
            ["--port", str(broker.port), "--qos", str(qos)],
            ctx.workdir,
        )
        try:
            step = s.window / 2
            total = s.warmup + s.repeats * step + 0.5
            publishing = asyncio.create_task(pub.ask("run", seconds=total, timeout=total + 30))
            await asyncio.sleep(s.warmup)
            snaps = [await sub.ask("snap")]
            for _ in range(s.repeats):
                await asyncio.sleep(step)
                snaps.append(await sub.ask("snap"))
            await publishing
        finally:
            await pub.stop()
            await sub.stop()
    rates = [(b["count"] - a["count"]) / (b["mono"] - a["mono"]) for a, b in itertools.pairwise(snaps)]
    return rates, snaps[-1]["latency"]


PAHO_TOPICS = 1000  # bench/agents/paho_pub.py's TOPICS: change `seq` goes to raw/t{seq % 1000}


async def _paho_c_sub(ctx: Context, qos: int, name: str) -> tuple[list[float], dict[str, Any]]:
    """paho_rates through mosquitto_sub (bench/agents/c_sub.py) and an unbounded broker queue: the
    rates are distinct changes delivered and checked; the last snap carries `acked` (published per
    second of the publisher's run: its window of 200 and queue of 1,000 are all that is not yet
    acknowledged) and the delivery verdict over everything it published."""
    s = ctx.settings
    async with Mosquitto(ctx.workdir, unbounded=True) as broker:
        sub = await Agent.start(
            f"{name}-csub", "bench.agents.c_sub", ["--port", str(broker.port), "--topic", "raw/#",
                                                  "--qos", str(qos)], ctx.workdir,
        )  # fmt: skip
        pub = await Agent.start(
            f"{name}-pub",
            "bench.agents.paho_pub",
            ["--port", str(broker.port), "--qos", str(qos)],
            ctx.workdir,
        )
        try:
            step = s.window / 2
            total = s.warmup + s.repeats * step + 0.5
            publishing = asyncio.create_task(pub.ask("run", seconds=total, timeout=total + 30))
            await asyncio.sleep(s.warmup)
            snaps = [await sub.ask("snap")]
            for _ in range(s.repeats):
                await asyncio.sleep(step)
                snaps.append(await sub.ask("snap"))
            run = await publishing
            await settle_count(sub)
            published = int(run["published"])
            topics = [f"raw/t{(i + 1) % PAHO_TOPICS:04d}" for i in range(PAHO_TOPICS)]
            verdict = await sub.ask("check", topics=topics, written=published, timeout=120)
            drops = broker.drops()
        finally:
            await pub.stop()
            await sub.stop()
    rates = [(b["distinct"] - a["distinct"]) / (b["mono"] - a["mono"]) for a, b in itertools.pairwise(snaps)]
    last = {
        **snaps[-1],
        "acked": published / float(run["elapsed"]),
        "verdict": verdict,
        "broker_drops": drops,
    }
    return rates, last


async def settle_count(sub: Agent, timeout: float = 120.0) -> None:
    """Until the subscriber has seen nothing new for half a second."""
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


async def noise_ceiling(ctx: Context) -> None:
    """The simulator's noise writer alone: it must not be what limits the mirror figures."""
    s, r = ctx.settings, ctx.results
    ctx.log("simulator noise mode: 10,000 variables, flat out and at 10,000/s")
    sim = await Agent.start(
        "noise-ceiling-sim", "bench.agents.simulator", ["--variables", str(RAW_VARIABLES)], ctx.workdir
    )
    try:
        achieved = {}
        for rate in ("max", 10_000):
            await sim.ask("rate", rate=rate)
            await asyncio.sleep(s.warmup + s.window / 2)
            achieved[rate] = (await sim.ask("snap"))["achieved"]
            await sim.ask("rate", rate=0)
        ctx.ceilings["noise_max"] = achieved["max"]
        r.add(
            "baseline.noise.max",
            SECTION,
            "simulator noise: changes written, flat out, no subscriber",
            achieved["max"],
            "changes/s",
            baseline=ctx.ceilings.get("asyncua_writes"),
            baseline_label="raw asyncua writes",
        )
        r.add(
            "baseline.noise.r10000",
            SECTION,
            "simulator noise: set to 10,000/s, achieved",
            achieved[10_000],
            "changes/s",
            baseline=10_000,
            baseline_label="set rate",
        )
    finally:
        await sim.stop()


async def publish_decode(ctx: Context) -> None:
    """asyncua's PublishResponse decoding against the source's compiled reader, same captured bytes."""
    ctx.log("PublishResponse decoding: capturing from the simulator (1,000 noise variables at 5,000/s)")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "bench.publish_capture", str(ctx.workdir / "publish-responses.bin"),
        "--seconds", "2" if ctx.settings.quick else "4", "--noise", "1000", "--rate", "5000", "--measure",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL,
    )  # fmt: skip
    out, _ = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"bench.publish_capture exited with {proc.returncode}")
    found = json.loads(out.decode().strip().splitlines()[-1])
    ctx.results.details.setdefault("baselines", {})["publish_decode"] = found
    ctx.ceilings["asyncua_decode"] = found["asyncua"]
    ctx.results.add(
        "baseline.decode.asyncua",
        SECTION,
        f"asyncua: PublishResponse notifications decoded per CPU second ({found['changes']:,} captured)",
        found["asyncua"],
        "changes/s",
    )
    ctx.results.add(
        "baseline.decode.compiled",
        SECTION,
        f"the source's compiled reader, same responses ({100 * found['fast_share']:.0f} % taken)",
        found["compiled"],
        "changes/s",
        baseline=found["asyncua"],
        baseline_label="asyncua",
    )


async def source_decode(ctx: Context) -> None:
    """The OPC UA source alone at 5,000 changes/s: CPU per 1,000 changes, asyncua's decoding vs the reader."""
    ctx.log("OPC UA source alone, 1,000 variables at 5,000/s: asyncua's decoding and the compiled reader")
    window, rounds = ("2", "2") if ctx.settings.quick else ("4", "3")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "bench.source_ab", "--window", window, "--rounds", rounds,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL,
    )  # fmt: skip
    out, _ = await proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"bench.source_ab exited with {proc.returncode}")
    found = json.loads(out.decode().strip().splitlines()[-1])
    ctx.results.details.setdefault("baselines", {})["source_decode"] = found
    ctx.results.add(
        "baseline.source.cpu_asyncua",
        SECTION,
        "OPC UA source alone @5,000/s, asyncua's decoding: CPU per 1,000 changes",
        found["asyncua"],
        "ms",
    )
    ctx.results.add(
        "baseline.source.cpu_compiled",
        SECTION,
        "OPC UA source alone @5,000/s, compiled reader: CPU per 1,000 changes",
        found["compiled"],
        "ms",
        baseline=found["asyncua"],
        baseline_label="asyncua's decoding",
    )
