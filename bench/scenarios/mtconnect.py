"""MTConnect (issue 17): the agent's /current and streaming, the SHDR source, what streaming costs the mirror.

Four measurements, each beside a ceiling measured in the same run:

- `/current` for 20 machines x 500 data items (the laser profile grown with filler items):
  server time per request (p50 of wall clock and of CPU), 5 % of the items changing between
  requests; the ceiling is joining the same 10,000 pre-rendered observations alone;
- `/sample` streaming to one HTTP client (its own process): observations/s it receives while
  the tree changes as fast as the gateway takes it; the ceiling is the codec rendering the
  same stream without HTTP;
- the SHDR source: changes/s into the tree from one adapter process sending as fast as it
  can (1,000 keys); the ceiling is the SHDR reader parsing the same bytes alone;
- the mirror's changes/s into the agent (tree -> hub -> agent buffer) while 5 streaming
  clients follow it (`interval=100`, as dashboards do), relative to none.

Everything on the gateway side runs in this process, on one event loop, as in the gateway.
"""

from __future__ import annotations

import asyncio
import random
import statistics
import time
from collections.abc import Awaitable, Callable
from datetime import UTC, datetime
from typing import Any

from bench.context import Context
from bench.procs import Agent
from gateway.codecs.mtconnect.documents import streams_xml
from gateway.codecs.mtconnect.shdr import ShdrReader
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping
from gateway.model.sample import utcnow
from gateway.model.tree import VariableTree
from gateway.sinks.mtconnect.agent import Agent as MTAgent
from gateway.sinks.mtconnect.profile import build_profile
from gateway.sinks.mtconnect.sink import MTConnectSink
from gateway.sources.mtconnect.shdr_source import ShdrSource
from tests.mtconnect_shop import shop

SECTION = "MTConnect: the agent (HTTP) and the SHDR source"
FOLLOW = "interval=100&count=10000&heartbeat=1000"  # how a dashboard follows an agent: a chunk per 100 ms
T = datetime(2024, 5, 1, tzinfo=UTC)


def _doubles(tree: VariableTree) -> list[Any]:
    return [n for n in tree.nodes() if not n.internal and str(n.type) == "Double"]


async def run(ctx: Context) -> None:
    s, r = ctx.settings, ctx.results
    details: dict[str, Any] = {}
    r.details["mtconnect"] = details
    await _current(ctx, details, rounds=20 if s.quick else 60)
    await _streaming(ctx, details, s.window)
    await _shdr(ctx, details, s.window)
    await _mirror(ctx, details, s.window)


# --- /current -------------------------------------------------------------------------------------


async def _current(ctx: Context, details: dict[str, Any], rounds: int) -> None:
    config = shop(20, 500, buffer_size=131_072)
    assert config.gateway.mtconnect is not None
    tree = VariableTree(config.definitions())
    profile = build_profile(tree, config.mappings, config.gateway.mtconnect)
    agent = MTAgent(profile, config.gateway.mtconnect)
    agent.start([*profile.bindings, *profile.connected])
    sub = tree.hub.subscribe("bench", every_change=True, limit=1 << 20)
    nodes = _doubles(tree)
    rng = random.Random(17)
    for machine in tree.machines.values():
        for node in machine.mapped:
            machine.ingest(node, 1.0 if str(node.type) == "Double" else node.type.default(), T)
        machine.status.connected()
    agent.feed(sub.take())
    wall: list[float] = []
    cpu: list[float] = []
    raw: list[float] = []
    size = 0
    for _ in range(rounds):
        for node in rng.sample(nodes, len(nodes) // 20):
            node.machine.ingest(node, rng.random(), utcnow())
        agent.feed(sub.take())
        w0, c0 = time.perf_counter(), time.process_time()
        body = agent.answer("/current").body
        wall.append((time.perf_counter() - w0) * 1000)
        cpu.append((time.process_time() - c0) * 1000)
        size = len(body)
        entries, _ = agent.buffer.current()
        w0 = time.perf_counter()
        "".join(e.xml for e in entries)
        raw.append((time.perf_counter() - w0) * 1000)
        await asyncio.sleep(0)
    sub.close()
    p50, p50_cpu, floor = statistics.median(wall), statistics.median(cpu), statistics.median(raw)
    details["current"] = {
        "items": len(agent.catalog.items), "bytes": size, "p50_ms": p50, "p50_cpu_ms": p50_cpu,
        "p99_ms": sorted(wall)[int(0.99 * (len(wall) - 1))], "join_floor_ms": floor,
    }  # fmt: skip
    ctx.results.add(
        "mtconnect.current_ms", SECTION, "/current, 20 x 500 data items, p50 server time", p50, "ms",
        baseline=floor, baseline_label="joining the pre-rendered observations alone",
        note=f"CPU p50 {p50_cpu:.1f} ms; {size / 1e6:.1f} MB",
    )  # fmt: skip
    ctx.log(f"mtconnect /current: p50 {p50:.1f} ms (CPU {p50_cpu:.1f} ms), join floor {floor:.1f} ms")


# --- streaming --------------------------------------------------------------------------------------


async def _producer(tree: VariableTree, stop: asyncio.Event, batch: int = 500) -> None:
    nodes = _doubles(tree)
    value = 0.0
    while not stop.is_set():
        now = utcnow()
        for node in nodes[:batch] if len(nodes) >= batch else nodes:
            value += 1.0
            node.machine.ingest(node, value, now)
        nodes = nodes[batch:] + nodes[:batch]
        await asyncio.sleep(0)


async def _with_sink(config: Config, body: Callable[[VariableTree, MTConnectSink], Awaitable[None]]) -> None:
    assert config.gateway.mtconnect is not None
    tree = VariableTree(config.definitions())
    sink = MTConnectSink(tree, config.gateway.mtconnect, config.mappings, config.state_dir)
    async with sink:
        task = asyncio.create_task(sink.run())
        try:
            for machine in tree.machines.values():
                machine.status.connected()
            await body(tree, sink)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def _streaming(ctx: Context, details: dict[str, Any], window: float) -> None:
    config = shop(1, 1000, buffer_size=131_072, state_dir=ctx.workdir / "mtconnect-stream")
    result: dict[str, Any] = {}

    async def body(tree: VariableTree, sink: MTConnectSink) -> None:
        client = await Agent.start("mtconnect-client", "bench.agents.mtconnect_client",
                                   ["--url", sink.url, "--streams", "1"], ctx.workdir)  # fmt: skip
        stop = asyncio.Event()
        producer = asyncio.create_task(_producer(tree, stop))
        try:
            await asyncio.sleep(ctx.settings.warmup)
            a = await client.ask("snap")
            t0 = time.monotonic()
            await asyncio.sleep(window)
            b = await client.ask("snap")
            elapsed = time.monotonic() - t0
            result["received_per_s"] = (b["observations"] - a["observations"]) / elapsed
            result["errors"] = b["errors"]
        finally:
            stop.set()
            await producer
            await client.stop()
        # the ceiling: the same buffer rendered in chunks of 10,000 without HTTP
        buffer = sink.agent.buffer
        start = buffer.first_sequence
        rendered, t0 = 0, time.perf_counter()
        while rendered < 200_000 and start < buffer.next_sequence:
            chunk = buffer.sample(None, from_=start, count=10_000)
            streams_xml(sink.agent.catalog, chunk.entries, chunk.window, sink.agent.info()).encode()
            rendered += len(chunk.entries)
            start = chunk.window.next_sequence
        result["render_per_s"] = rendered / (time.perf_counter() - t0)

    await _with_sink(config, body)
    details["streaming"] = result
    ctx.results.add("mtconnect.stream_obs_s", SECTION, "/sample streaming to one HTTP client",
                    result.get("received_per_s"), "obs/s", baseline=result.get("render_per_s"),
                    baseline_label="rendering the same chunks without HTTP",
                    note=f"stream errors {result.get('errors')}")  # fmt: skip
    ctx.log(f"mtconnect streaming: {result.get('received_per_s', 0):,.0f} obs/s at the client "
            f"(render ceiling {result.get('render_per_s', 0):,.0f}/s)")  # fmt: skip


# --- SHDR source ------------------------------------------------------------------------------------


def _shdr_mapping(port: int, keys: int) -> MachineMapping:
    return MachineMapping.model_validate({
        "machine": "adapter",
        "driver": {"type": "shdr", "host": "127.0.0.1", "port": port},
        "variables": [{"path": f"K/k{n:05d}", "source": f"k{n:05d}", "type": "Double"} for n in range(keys)],
    })  # fmt: skip


async def _shdr(ctx: Context, details: dict[str, Any], window: float) -> None:
    keys = 1000
    adapter = await Agent.start(
        "shdr-adapter", "bench.agents.shdr_adapter", ["--keys", str(keys)], ctx.workdir
    )
    mapping = _shdr_mapping(int(adapter.ready["port"]), keys)
    tree = VariableTree([mapping.definition()])
    result: dict[str, Any] = {}
    try:
        async with ShdrSource(tree.machines["adapter"], mapping) as source:
            task = asyncio.create_task(source.run())
            try:
                await asyncio.sleep(ctx.settings.warmup)
                a, t0 = source.changes, time.monotonic()
                await asyncio.sleep(window)
                result["changes_per_s"] = (source.changes - a) / (time.monotonic() - t0)
                result["junk"] = source.junk
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
    finally:
        await adapter.stop()
    # the ceiling: the reader alone on the same kind of lines
    lines = "".join("|" + "|".join(f"k{(i * 10 + j) % keys:05d}|{i * 10 + j}" for j in range(10)) + "\n"
                    for i in range(20_000)).encode()  # fmt: skip
    reader, t0 = ShdrReader(), time.perf_counter()
    events = sum(len(reader.feed(lines[k : k + 65536], T)) for k in range(0, len(lines), 65536))
    result["reader_per_s"] = events / (time.perf_counter() - t0)
    details["shdr"] = result
    ctx.results.add("mtconnect.shdr_changes_s", SECTION, "SHDR source: changes/s into the tree (one adapter)",
                    result.get("changes_per_s"), "changes/s", baseline=result["reader_per_s"],
                    baseline_label="the SHDR reader alone on the same lines")  # fmt: skip
    ctx.log(f"mtconnect SHDR: {result.get('changes_per_s', 0):,.0f} changes/s "
            f"(reader alone {result['reader_per_s']:,.0f}/s)")  # fmt: skip


# --- the mirror with streams ------------------------------------------------------------------------


async def _mirror(ctx: Context, details: dict[str, Any], window: float) -> None:
    """Windows with no client and with 5 streaming clients, alternated (the machine's other load moves)."""
    result: dict[str, Any] = {}
    rates: dict[int, list[float]] = {0: [], 5: []}
    cpu_rates: dict[int, list[float]] = {0: [], 5: []}  # per CPU second of this process (the gateway's side)
    rounds = 2 if ctx.settings.quick else 3
    config = shop(1, 1000, buffer_size=131_072, state_dir=ctx.workdir / "mtconnect-mirror")

    async def body(tree: VariableTree, sink: MTConnectSink) -> None:
        stop = asyncio.Event()
        producer = asyncio.create_task(_producer(tree, stop))
        try:
            for _ in range(rounds):
                for clients in (0, 5):
                    agent = None
                    if clients:
                        args = ["--url", sink.url, "--streams", str(clients), "--query", FOLLOW]
                        agent = await Agent.start("mtconnect-clients", "bench.agents.mtconnect_client", args,
                                                  ctx.workdir)  # fmt: skip
                    try:
                        await asyncio.sleep(ctx.settings.warmup)
                        a, t0, c0 = sink.agent.buffer.next_sequence, time.monotonic(), time.process_time()
                        await asyncio.sleep(window)
                        done = sink.agent.buffer.next_sequence - a
                        rates[clients].append(done / (time.monotonic() - t0))
                        cpu_rates[clients].append(done / max(time.process_time() - c0, 1e-6))
                        if agent is not None:
                            snap = await agent.ask("snap")
                            result["client_snap"] = {
                                k: snap[k] for k in ("observations", "errors", "dropped")
                            }
                    finally:
                        if agent is not None:
                            await agent.stop()
            result["parts"] = {"sent": sink.server.parts_sent, "shared": sink.server.parts_shared}
        finally:
            stop.set()
            await producer

    await _with_sink(config, body)
    none, five = statistics.median(rates[0]), statistics.median(rates[5])
    result.update(clients_0=none, clients_5=five, windows=rates, ratio=five / none if none else None)
    # Per CPU second of this process as well (the web scenario's measure): on two shared cores the wall-clock
    # rate also counts the clients' own process (it parses every part) and whatever else runs.
    cpu_none, cpu_five = statistics.median(cpu_rates[0]), statistics.median(cpu_rates[5])
    result.update(cpu_clients_0=cpu_none, cpu_clients_5=cpu_five, cpu_windows=cpu_rates,
                  cpu_ratio=cpu_five / cpu_none if cpu_none else None)  # fmt: skip
    details["mirror"] = result
    ctx.results.add(
        "mtconnect.mirror_5_streams", SECTION, "mirror changes/s with 5 streaming clients", five, "changes/s",
        baseline=none, baseline_label="the same with no client (median of windows)",
    )  # fmt: skip
    ctx.results.add(
        "mtconnect.mirror_5_streams_cpu", SECTION, "mirror changes per CPU-s with 5 streaming clients",
        cpu_five, "changes/CPU-s", baseline=cpu_none,
        baseline_label="the same with no client (median of windows)",
    )  # fmt: skip
    ctx.log(f"mtconnect mirror: {five:,.0f}/s with 5 streams, {none:,.0f}/s without "
            f"(ratio {result['ratio'] or 0:.2f}; windows {rates}; parts {result.get('parts')}); per CPU-s "
            f"{cpu_five:,.0f} vs {cpu_none:,.0f} (ratio {result['cpu_ratio'] or 0:.2f})")  # fmt: skip
