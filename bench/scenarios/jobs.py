"""Jobs: programs from the FTP inbox to the simulator's FTP program store.

* Latency: `jobs_small` programs of 100 KB, one after another. Each is uploaded to
  the inbox under a temporary name (`O1001.nc.part`) and committed by the rename;
  the latency runs from just before the RNTO to the job's DELIVERED time in the
  gateway's queue (its own record, millisecond resolution). The time the file
  appeared on the store under its final name is kept beside it.
* Throughput: one 50 MB program, from the first byte of the upload to DELIVERED,
  compared with a raw copy of the same file between the same two kinds of
  servers in the same run: an aioftp client uploads it to a plain aioftp server
  in another process, which then uploads it to the simulator's store with an
  aioftp client (bench/agents/ftp_relay.py). Raw copies and the gateway's runs
  alternate (`repeats` of the gateway's, one more raw copy); the medians count.
"""

from __future__ import annotations

import asyncio
import sqlite3
import statistics
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import aioftp

from bench.agents.protocol import percentiles
from bench.context import Context
from bench.gcode_gen import laser_program
from bench.procs import Agent
from bench.scenarios.common import write_gateway
from gateway.auth.passwords import hash_password
from gateway.config.validation import ValidationRules
from gateway.jobs.validation.pipeline import validate_program

SECTION = "Jobs: FTP inbox → validation → queue → simulator's FTP store"
MACHINE = "laser"
USER, PASSWORD = "bench", "bench-password"
STORE_USER, STORE_PASSWORD = "cnc", "simulator"


def mapping(endpoint: str, ftp_port: int) -> str:
    return f"""
machine: {MACHINE}
driver: {{endpoint: "{endpoint}"}}
variables:
  - {{path: Noise/V0, source: "nsu=urn:cnc-simulator:plc;s=::Noise:g000.v00000", type: Double}}
jobs:
  controller: {{host: 127.0.0.1, port: {ftp_port}, user: {STORE_USER}, password: {STORE_PASSWORD},
               folder: /DATA/Programs, timeout: 30}}
  validation: {{dialect: laser-sim}}
  retry: {{initial: 0.2, max: 1, factor: 2}}
"""


async def run(ctx: Context) -> None:
    s, r = ctx.settings, ctx.results
    folder = ctx.workdir / "jobs"
    store = folder / "store"
    details: dict[str, Any] = {"small_count": s.jobs_small, "large_size": s.jobs_large_size}
    r.details["jobs"] = details
    ctx.log(
        f"jobs: generating {s.jobs_small} programs of {s.jobs_small_size:,} B "
        f"and one of {s.jobs_large_size:,} B"
    )
    small = [laser_program(s.jobs_small_size, seed=k + 1, number=2000 + k) for k in range(s.jobs_small + 1)]
    large_file = folder / "R9999.nc"  # the raw copies' name; the gateway gets O9999.nc, O9998.nc, ...
    folder.mkdir(parents=True, exist_ok=True)
    large_file.write_bytes(laser_program(s.jobs_large_size, seed=9999, number=9999))
    details["large_size"] = large_file.stat().st_size
    agents: list[Agent] = []
    try:
        sim = await Agent.start(
            "jobs-sim", "bench.agents.simulator", ["--variables", "1", "--store", str(store)], ctx.workdir
        )
        agents.append(sim)
        inbox = {"accounts": [{"user": USER, "password_hash": hash_password(PASSWORD, n=2**10)}]}
        config, _ = write_gateway(
            folder / "gateway",
            {MACHINE: mapping(sim.ready["endpoint"], sim.ready["ftp_port"])},
            mqtt_port=None,
            inbox=inbox,
        )
        inbox_port = _inbox_port(config)
        gw = await Agent.start("jobs-gateway", "bench.agents.gateway", ["--config", str(config)], ctx.workdir)
        agents.append(gw)
        programs = store / "DATA" / "Programs"
        queue = folder / "gateway" / "state" / "jobs" / "queue.sqlite3"
        relay = await Agent.start(
            "jobs-relay", "bench.agents.ftp_relay", ["--root", str(folder / "relay")], ctx.workdir
        )
        agents.append(relay)

        # --- latency: 100 KB, one at a time ---------------------------------------------------------
        commits: dict[str, float] = {}
        appeared: dict[str, float] = {}
        replies: dict[str, float] = {}
        async with aioftp.Client.context("127.0.0.1", inbox_port, USER, PASSWORD) as client:
            for k, data in enumerate(small):
                name = f"O{2000 + k}.nc"
                async with client.upload_stream(f"/{MACHINE}/{name}.part") as stream:
                    await stream.write(data)
                commits[name] = time.time()
                await client.rename(f"/{MACHINE}/{name}.part", f"/{MACHINE}/{name}")
                replies[name] = time.time()
                appeared[name] = await _arrival(programs / name, len(data))
        delivered = await _delivered(queue, list(commits), timeout=30)
        names = list(commits)[1:]  # the first one warms up both sides
        latencies = [1000.0 * (delivered[n] - commits[n]) for n in names if n in delivered]
        details["small"] = {
            "latency_ms": percentiles(latencies),
            "store_ms": percentiles([1000.0 * (appeared[n] - commits[n]) for n in names]),
            "reply_ms": percentiles([1000.0 * (replies[n] - commits[n]) for n in names]),
            "delivered": len(latencies),
        }
        details["small_p50"] = details["small"]["latency_ms"]["p50"]
        details["small_p99"] = details["small"]["latency_ms"]["p99"]
        ctx.log(
            f"  100 KB: p50 {details['small_p50']:.0f} ms, p99 {details['small_p99']:.0f} ms "
            f"({len(latencies)} delivered)"
        )

        # --- a raw transfer of one small program: the floor of the latency -------------------------
        raw_small = []
        for k in range(5):
            raw_small.append(await _raw_copy(relay, folder / f"R{k}.nc", small[0], sim.ready["ftp_port"]))
        details["raw_small_ms"] = 1000.0 * statistics.median(raw_small)

        # --- throughput: the large program against the raw copy, interleaved -----------------------
        # Both figures swing by a third from run to run on a shared 2-core machine: `repeats` rounds of
        # each (a different first line each time, so that no job is a duplicate), medians compared.
        raw = [await _raw_copy(relay, large_file, None, sim.ready["ftp_port"])]
        ctx.log(f"  raw aioftp copy of {details['large_size'] / 1e6:.0f} MB: {raw[0]:.2f} s")
        original = large_file.read_bytes()
        runs: list[dict[str, Any]] = []
        for k in range(s.repeats):
            name = f"O{9999 - k}.nc"
            variant = folder / name
            variant.write_bytes(original.replace(b"(BENCH SHEET", f"(BENCH RUN {k % 10}".encode(), 1))
            started = time.time()
            async with aioftp.Client.context("127.0.0.1", inbox_port, USER, PASSWORD) as client:
                await client.upload(variant, f"/{MACHINE}/{name}.part", write_into=True)
                uploaded = time.time()
                await client.rename(f"/{MACHINE}/{name}.part", f"/{MACHINE}/{name}")
                replied = time.time()
            await _arrival(programs / name, details["large_size"], timeout=600)
            done = (await _delivered(queue, [name], timeout=60))[name]
            runs.append(
                {
                    "seconds": done - started,
                    "upload": uploaded - started,
                    "rename_reply": replied - uploaded,
                    **_transitions(queue, name, started),
                }
            )
            ctx.log(f"  gateway: {runs[-1]['seconds']:.2f} s {runs[-1]}")
            raw.append(await _raw_copy(relay, large_file, None, sim.ready["ftp_port"]))
            ctx.log(f"  raw aioftp copy: {raw[-1]:.2f} s")
        details["large_runs"] = runs
        details["large_seconds"] = statistics.median(run["seconds"] for run in runs)
        details["large_breakdown"] = sorted(runs, key=lambda run: run["seconds"])[len(runs) // 2]
        details["raw_runs"] = raw
        details["raw_seconds"] = statistics.median(raw)
    finally:
        for agent in reversed(agents):
            await agent.stop()
    details["validation"] = _validation(ctx, large_file)
    r.add(
        "jobs.small.p50",
        SECTION,
        f"{s.jobs_small_size // 1000} KB job, RNTO → DELIVERED, p50",
        details.get("small_p50"),
        "ms",
        baseline=details.get("raw_small_ms"),
        baseline_label="raw aioftp copy",
    )
    r.add(
        "jobs.small.p99",
        SECTION,
        f"{s.jobs_small_size // 1000} KB job, RNTO → DELIVERED, p99",
        details.get("small_p99"),
        "ms",
        baseline=details.get("raw_small_ms"),
        baseline_label="raw aioftp copy",
    )
    large = details.get("large_seconds")
    size = (details.get("large_size") or 0) / 1e6
    r.add(
        "jobs.large.seconds",
        SECTION,
        f"{size:.0f} MB job, first byte → DELIVERED",
        large,
        "s",
        baseline=details.get("raw_seconds"),
        baseline_label="raw aioftp copy",
    )
    if large and details.get("raw_seconds"):
        r.add(
            "jobs.large.throughput",
            SECTION,
            f"{size:.0f} MB job throughput",
            size / large,
            "MB/s",
            baseline=size / details["raw_seconds"],
            baseline_label="raw aioftp copy",
        )
    validation = details["validation"]
    r.add(
        "jobs.validation.throughput",
        SECTION,
        f"G-code validation of the {size:.0f} MB program (laser-sim rules)",
        validation["mb_per_s"],
        "MB/s",
        baseline=size / details["raw_seconds"] if details.get("raw_seconds") else None,
        baseline_label="raw aioftp copy",
        note=f"{validation['cpu_seconds']:.1f} s CPU",
    )


def _validation(ctx: Context, path: Path) -> dict[str, Any]:
    """The validator alone on the large program, in this process: its speed, and with --profile where
    its time goes (pyinstrument)."""
    rules = ValidationRules.model_validate({"dialect": "laser-sim"})
    data = path.read_bytes()
    started = time.process_time()
    verdict = validate_program(data, path.name, rules)
    seconds = time.process_time() - started
    out: dict[str, Any] = {
        "accepted": verdict.accepted,
        "cpu_seconds": seconds,
        "mb_per_s": len(data) / seconds / 1e6,
    }
    if ctx.settings.profile:
        from pyinstrument import Profiler

        profiler = Profiler(interval=0.005)
        profiler.start()
        validate_program(data, path.name, rules)
        profiler.stop()
        text = profiler.output_text(unicode=False, color=False)
        (ctx.workdir / "profile-validation.txt").write_text(text)
        out["profile"] = text.splitlines()[:60]
        ctx.profiles["validation"] = {"pyinstrument": out["profile"]}
    return out


def _inbox_port(config: Path) -> int:
    import yaml

    return int(yaml.safe_load(config.read_text())["inbox"]["port"])


async def _arrival(path: Path, size: int, timeout: float = 30.0) -> float:
    """When `path` exists with `size` bytes (polled every 2 ms)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            if path.stat().st_size == size:
                return time.time()
        except FileNotFoundError:
            pass
        if time.monotonic() > deadline:
            raise TimeoutError(f"{path.name} did not arrive on the store within {timeout:g} s")
        await asyncio.sleep(0.002)


def _read(queue: Path, sql: str, params: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
    db = sqlite3.connect(f"file:{queue}?mode=ro", uri=True, timeout=5)
    db.row_factory = sqlite3.Row
    try:
        return db.execute(sql, params).fetchall()
    finally:
        db.close()


async def _delivered(queue: Path, names: list[str], timeout: float) -> dict[str, float]:
    """DELIVERED times (epoch seconds) of the jobs with these file names, from the gateway's queue."""
    deadline = time.monotonic() + timeout
    while True:
        rows = _read(queue, "SELECT filename, state, delivered_at FROM jobs")
        found = {
            row["filename"]: datetime.fromisoformat(row["delivered_at"]).timestamp()
            for row in rows
            if row["state"] == "DELIVERED" and row["delivered_at"]
        }
        if all(n in found for n in names) or time.monotonic() > deadline:
            return found
        await asyncio.sleep(0.1)


def _transitions(queue: Path, name: str, started: float) -> dict[str, float]:
    rows = _read(
        queue,
        "SELECT t.state, t.ts FROM transitions t JOIN jobs j ON j.seq = t.seq "
        "WHERE j.filename = ? ORDER BY t.id",
        (name,),
    )
    return {row["state"]: round(datetime.fromisoformat(row["ts"]).timestamp() - started, 3) for row in rows}


async def _raw_copy(relay: Agent, path: Path, data: bytes | None, store_port: int) -> float:
    """Client → relay's aioftp server, then relay → store: seconds for both."""
    if data is not None:
        path.write_bytes(data)
    started = time.perf_counter()
    async with aioftp.Client.context("127.0.0.1", relay.ready["port"], "bench", "bench") as client:
        await client.upload(path, path.name, write_into=True)
    await relay.ask(
        "relay",
        name=path.name,
        port=store_port,
        user=STORE_USER,
        password=STORE_PASSWORD,
        folder="/DATA/Programs",
        timeout=300,
    )
    return time.perf_counter() - started
