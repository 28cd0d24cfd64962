"""Web console: the machines page's server time, the mirror with live pages open, and source → DOM latency.

One gateway in this process, 20 machines × 500 noise variables, its OPC UA server and the web sink as
configured by a gateway file; no controller: the benchmark feeds each machine's tree itself
(`Machine.ingest`, the source's own entry), so the figures are the gateway's, not a driver's.

- **Machines page, server time**: the handler of `/` (the tree read, the template rendered) for all
  20 × 500 variables, median and p95 of repeated renders; beside it, the floor: one pass reading every
  variable's sample (the least any page about all of them must do).
- **The mirror with pages open**: one machine's 500 variables changed flat out for a window, with no
  page open and with 5 live-socket clients in another process, each subscribed exactly as the machine
  page is (every variable of the machine, plus job and alarm events), alternately; the ratio of the
  changes the tree takes in per CPU second of the gateway's process (the wall-clock ratio beside it: on
  two cores shared with other work it also measures that work). Socket clients, not five Chromiums:
  five browsers would share this machine's two cores with the gateway and measure the browsers.
- **Browser latency**: Debian's Chromium (Playwright) on the machine page while 5,000 changes/s go into
  that machine; one of its variables carries the time it was ingested (ms since the epoch) and a
  MutationObserver in the page records, at each update of that cell, now - that time. p50/p99, and how
  many updates a second that one variable got.
"""

from __future__ import annotations

import asyncio
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from bench.context import Context
from bench.procs import ROOT
from bench.scenarios.common import write_gateway
from simulator.noise import NoiseSpec, noise_mapping
from tests.waiting import free_port

SECTION = "Web console: pages, live updates, browsers"
MACHINES, PER = 20, 500
CLIENTS = 5
LATENCY_RATE = 5000.0
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip


async def run(ctx: Context) -> None:
    from gateway.app import Gateway
    from gateway.config.loader import load
    from gateway.sinks.web.http import HttpRequest
    from gateway.sinks.web.sessions import Caller

    s, r = ctx.settings, ctx.results
    folder = ctx.workdir / "web"
    spec = NoiseSpec(MACHINES * PER)
    dead = f"opc.tcp://127.0.0.1:{free_port()}"  # nothing listens: the benchmark feeds the tree itself
    mappings = {
        f"m{k:02d}": noise_mapping(spec, dead, machine=f"m{k:02d}", first=k * PER, count=PER)
        for k in range(MACHINES)
    }
    path, _ = write_gateway(folder, mappings, mqtt_port=None)
    http_port = free_port()
    doc = yaml.safe_load(path.read_text())
    doc["http"] = {"host": "127.0.0.1", "port": http_port}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    url = f"http://127.0.0.1:{http_port}/"
    details: dict[str, Any] = {"machines": MACHINES, "per_machine": PER}
    r.details["web"] = details

    gw = Gateway(load([path]))
    gw.sources.clear()  # no controller: no reconnect loop turning the variables Bad under the benchmark
    async with gw:
        task = asyncio.create_task(gw.run(), name="bench:gateway")
        try:
            tree = gw.tree
            now = time.time()
            for machine in tree.machines.values():
                ts = _ts(now)
                for i, node in enumerate(machine.mapped):
                    machine.ingest(node, float(i), ts)
            web = gw.sink("web")

            # 1. the machines page
            req = HttpRequest("GET", "/", {}, {}, {}, "127.0.0.1")
            caller = Caller(None, "viewer", "anonymous")
            pages = web.pages  # type: ignore[attr-defined]
            times, size = [], 0
            for _ in range(5 if s.quick else 30):
                t0 = time.perf_counter()
                response = await pages.machines(req, caller)
                times.append((time.perf_counter() - t0) * 1000)
                size = len(response.body)
            floor = []
            for _ in range(5 if s.quick else 30):
                t0 = time.perf_counter()
                sum(1 for n in tree.nodes() if n.sample.good)
                floor.append((time.perf_counter() - t0) * 1000)
            page = {"p50": statistics.median(times), "p95": _pct(times, 95), "bytes": size}
            details["machines_page_ms"] = page
            r.add(
                "web.machines_page", SECTION, f"machines page server time, {MACHINES} × {PER} (p50)",
                page["p50"], "ms", baseline=statistics.median(floor),
                baseline_label="one pass over every sample",
                note=f"p95 {page['p95']:.1f} ms, {size:,} bytes",
            )  # fmt: skip
            ctx.log(f"machines page: p50 {page['p50']:.1f} ms, p95 {page['p95']:.1f} ms ({size:,} bytes)")

            # 2. the mirror's changes/s with 5 live clients, against none
            busy = tree.machines["m00"]
            rounds = 1 if s.quick else max(2, s.repeats)
            none, watched, received = [], [], []
            for _ in range(rounds):
                none.append(await _flat_out(busy, s.window))
                clients = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "bench.agents.web_clients", url, "m00", str(CLIENTS),
                    cwd=ROOT, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE,
                )  # fmt: skip
                assert clients.stdout is not None and clients.stdin is not None
                busy.ingest(next(iter(busy.mapped)), -1.0, _ts(time.time()))  # something for the first batch
                line = await asyncio.wait_for(clients.stdout.readline(), 30)
                if line.strip() != b"ready":
                    raise RuntimeError(f"web clients did not start: {line!r}")
                watched.append(await _flat_out(busy, s.window))
                clients.stdin.close()
                out, _ = await asyncio.wait_for(clients.communicate(), 30)
                received.append(json.loads(out.decode().strip().splitlines()[-1]))
            # Judged per CPU second of the gateway: on two shared cores the wall-clock rate also counts
            # whatever else runs (the clients' process, other work on the machine); both are kept.
            alone, shown = statistics.median(c for _, c in none), statistics.median(c for _, c in watched)
            wall_alone, wall_shown = (
                statistics.median(w for w, _ in none),
                statistics.median(w for w, _ in watched),
            )
            ratio, wall_ratio = shown / alone, wall_shown / wall_alone
            details["mirror"] = {
                "none": none, "clients": watched, "received": received,
                "ratio": ratio, "wall_ratio": wall_ratio,
            }  # fmt: skip
            r.add(
                "web.mirror_ratio", SECTION,
                f"mirror changes per CPU-s with {CLIENTS} machine pages open / none",
                ratio, "×", note=f"{shown:,.0f} vs {alone:,.0f} per CPU-s; wall clock {wall_shown:,.0f}/s vs "
                f"{wall_alone:,.0f}/s = {wall_ratio:.2f} (flat out, one machine's {PER} variables, "
                f"{CLIENTS} socket clients in another process)",
            )  # fmt: skip
            r.add("web.mirror_none", SECTION, "mirror changes/s, no page open (flat out, wall clock)",
                  wall_alone, "changes/s")  # fmt: skip
            ctx.log(f"mirror: {alone:,.0f} alone, {shown:,.0f} with {CLIENTS} pages per CPU-s: {ratio:.3f} "
                    f"(wall clock {wall_alone:,.0f}/s vs {wall_shown:,.0f}/s: {wall_ratio:.3f})")  # fmt: skip

            # 3. source -> DOM in Chromium at 5,000 changes/s
            latency = await _browser_latency(url, busy, s.window * (2 if s.quick else 3))
            details["browser"] = latency
            if latency:
                r.add(
                    "web.browser_p99", SECTION,
                    f"source → DOM in Chromium at {LATENCY_RATE:,.0f} changes/s (p99)",
                    latency["p99"], "ms", note=f"p50 {latency['p50']:.0f} ms, {latency['n']} samples, "
                    f"{latency['per_second']:.1f} updates/s of the sampled variable",
                )  # fmt: skip
                ctx.log(f"browser: p50 {latency['p50']:.0f} ms, p99 {latency['p99']:.0f} ms, "
                        f"{latency['per_second']:.1f} updates/s")  # fmt: skip
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def _ts(epoch: float) -> Any:
    from datetime import UTC, datetime

    return datetime.fromtimestamp(epoch, UTC)


def _pct(values: list[float], p: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(len(ordered) * p / 100))]


async def _flat_out(machine: Any, seconds: float) -> tuple[float, float]:
    """Changes the tree takes in, ingesting as fast as the loop lets us (yielding every 100): per second
    of wall time, and per second of this process's CPU time (what the gateway does on cores of its own)."""
    nodes = list(machine.mapped)
    count, value = len(nodes), 0.0
    done = 0
    end = time.perf_counter() + seconds
    start = time.perf_counter()
    cpu = time.process_time()
    while time.perf_counter() < end:
        ts = _ts(time.time())
        for i in range(100):
            value += 1.0
            machine.ingest(nodes[(done + i) % count], value, ts)
        done += 100
        await asyncio.sleep(0)
    return done / (time.perf_counter() - start), done / max(time.process_time() - cpu, 1e-6)


async def _browser_latency(url: str, machine: Any, seconds: float) -> dict[str, Any] | None:
    if not await asyncio.to_thread(Path(CHROMIUM).exists):
        return None
    from playwright.async_api import async_playwright

    nodes = list(machine.mapped)
    probe, others = nodes[0], nodes[1:]
    cell = f'tr[data-var="{machine.name}/{probe.path}"] .v'
    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = await browser.new_page()
            await page.goto(f"{url}machines/{machine.name}")
            await page.wait_for_selector("#live-state.on")
            await page.evaluate(
                """(selector) => {
                    window.__lat = [];
                    const el = document.querySelector(selector);
                    new MutationObserver(() => {
                        const v = Number(el.textContent);
                        if (v > 1e12) window.__lat.push([Date.now(), Date.now() - v]);
                    }).observe(el, {childList: true, characterData: true, subtree: true});
                }""",
                cell,
            )
            per_tick, tick = int(LATENCY_RATE / 100), 0.01
            end = time.monotonic() + seconds
            k = 0
            next_at = time.monotonic()
            while time.monotonic() < end:
                ts = _ts(time.time())
                machine.ingest(probe, float(int(time.time() * 1000)), ts)
                for _ in range(per_tick - 1):
                    k += 1
                    machine.ingest(others[k % len(others)], float(k), ts)
                next_at += tick
                await asyncio.sleep(max(0.0, next_at - time.monotonic()))
            samples = await page.evaluate("window.__lat")
        finally:
            await browser.close()
    if not samples:
        return None
    lat = [float(d) for _, d in samples]
    span = (samples[-1][0] - samples[0][0]) / 1000 or 1.0
    return {
        "n": len(lat),
        "p50": statistics.median(lat),
        "p99": _pct(lat, 99),
        "max": max(lat),
        "per_second": len(lat) / span,
    }
