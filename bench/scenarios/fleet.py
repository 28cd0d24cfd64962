"""Fleet: 200 machines × 50 variables served by 1, 2 and 4 shards of `cnc-gateway fleet` (issue 29).

One noise simulator process serves all 10,000 variables (a folder per machine, as `scale` does);
the gateway file lists 200 mapping files and says `shard: ${CNC_SHARD}`; `cnc-gateway fleet`
starts the shards as the user would. For each shard count, with a broker of its own (no retained
values left from the run before):

- start-up: from starting `cnc-gateway fleet` until an MQTT subscriber (retained topics, connected
  before) has every variable Good;
- throughput: the simulator flat out; the changes the shards take into their trees per second, summed
  over their `/metrics` (`cnc_gateway_machine_changes_total`), and each shard's CPU and RSS;
- restart: the last shard SIGKILLed; the time until its machines are connected again on its
  `/metrics` (static shards: the supervisor starts it again; no other shard takes them over);
- the gateway's own scaling: the same 200 machines with the in-process source (bench/agents/injector.py,
  `--inject`: no simulator, no OPC UA client) flat out, in 1 process (every machine) and in 2 processes
  (`shard: 1/2` and `2/2`): the changes the processes take into their trees per second, summed; once with
  the OPC UA face alone (the broker elsewhere, as in a plant), once also publishing to a Mosquitto on this
  host (QoS 0), which then takes its share of the two cores. The simulator cannot offer a single shard
  what it can take on two cores; this is the issue's "2 shards vs 1" as the gateway decides it;
- failover: 2 shards with `shard: lease` (LEASE_TIME, leases in a scratch PostgreSQL database), shared
  out 100 and 100; shard 2 SIGKILLed (its supervisor waits a minute before starting it again); the time
  until shard 1's `/metrics` has all 200 machines connected.

The 1-shard run is the baseline of the others, from the same run. On a 2-core machine the simulator,
the broker and the subscriber share the cores with the shards: the ratios say what sharding buys there.
"""

from __future__ import annotations

import asyncio
import re
import signal
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

import psutil
import yaml

from bench.context import Context
from bench.procs import ROOT, Agent, Mosquitto, child_env, listener_ports
from bench.scenarios.common import write_gateway
from bench.scenarios.queue import database  # a scratch PostgreSQL database, dropped afterwards
from simulator.noise import NoiseSpec, noise_mapping, split_machines

SECTION = "Fleet: 200 machines × 50 variables over shards of `cnc-gateway fleet` (issue 29)"
MACHINES, PER_MACHINE = 200, 50
SHARDS = (1, 2, 4)
START_LIMIT = 180.0  # s: a start-up slower than this is a failure of the run, not a figure
LEASE_TIME = 5.0  # s: the failover run's lease


def _metrics(port: int) -> str:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2) as answer:
            return str(answer.read().decode())
    except OSError:
        return ""


CHANGES = re.compile(r"^cnc_gateway_machine_changes_total\{[^}]*\} (\S+)$", re.MULTILINE)
CONNECTED = re.compile(r"^cnc_gateway_machine_connected\{[^}]*\} 1\.0$", re.MULTILINE)


def _shard_process(supervisor: int, k: int) -> psutil.Process:
    """Shard K's process among the supervisor's children (by the environment the supervisor gave it)."""
    for child in psutil.Process(supervisor).children():
        if child.environ().get("CNC_SHARD_INDEX") == str(k):
            return child
    raise RuntimeError(f"no shard {k} among the fleet's processes")


def _changes(text: str) -> float:
    return sum(float(v) for v in CHANGES.findall(text))


def _connected(text: str) -> int:
    return len(CONNECTED.findall(text))


def _write_fleet(
    folder: Path, mappings: dict[str, str], shards: int, mqtt_port: int, lease: str | None = None
) -> Path:
    """The gateway and fleet files; `lease`: a PostgreSQL URL, for `shard: lease` on it."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in mappings.items():
        (folder / f"{name}.yaml").write_text(text, encoding="utf-8")
    gateway: dict[str, Any] = {
        "machines": [f"{name}.yaml" for name in mappings],
        "shard": "${CNC_SHARD}",
        "state_dir": "${CNC_STATE_DIR}",
        "log_level": "warning",
        "opcua": {"endpoint": "opc.tcp://127.0.0.1:${OPCUA_PORT}/cnc-gateway", "security": ["None"]},
        "http": {"host": "127.0.0.1", "port": "${HTTP_PORT}"},
        "mqtt": {"port": mqtt_port, "client_id": "bench-fleet-${OPCUA_PORT}"},  # one per shard
    }
    if lease is not None:
        gateway.update(shard="lease", queue=lease, lease_time=LEASE_TIME)
    (folder / "gateway.yaml").write_text(yaml.safe_dump(gateway, sort_keys=False), encoding="utf-8")
    base = listener_ports(2 * shards)
    fleet = {
        "gateway": "gateway.yaml",
        "shards": shards,
        "ports": {"OPCUA_PORT": base, "HTTP_PORT": base + shards},  # shard K: base + K - 1
        "state_dir": "state",
        "restart": {"initial": 60, "max": 60} if lease else {"initial": 0.2, "max": 1},
    }
    path = folder / "fleet.yaml"
    path.write_text(yaml.safe_dump(fleet, sort_keys=False), encoding="utf-8")
    return path


async def _one(ctx: Context, sim: Agent, mappings: dict[str, str], shards: int) -> dict[str, Any]:
    total = MACHINES * PER_MACHINE
    out: dict[str, Any] = {"shards": shards}
    async with Mosquitto(ctx.workdir) as broker:
        fleet_file = _write_fleet(ctx.workdir / f"fleet-{shards}", mappings, shards, broker.port)
        http = int(yaml.safe_load(fleet_file.read_text())["ports"]["HTTP_PORT"])
        sub = await Agent.start(
            f"fleet-{shards}-mqtt-sub",
            "bench.agents.mqtt_sub",
            ["--port", str(broker.port), "--topic", "cnc/+/noise/#", "--expect", str(total)],
            ctx.workdir,
        )
        log = (ctx.workdir / f"fleet-{shards}.log").open("ab")
        await sim.ask("rate", rate=0)
        started = time.time()
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "gateway.cli.main", "fleet", str(fleet_file),
            stdout=log, stderr=log, env=child_env(), cwd=str(ROOT),
        )  # fmt: skip
        try:
            deadline = time.monotonic() + START_LIMIT
            while True:
                snap = await sub.ask("snap")
                if snap["all_good_at"] is not None:
                    break
                if proc.returncode is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"{shards} shard(s): only {snap['good']} of {total} Good")
                await asyncio.sleep(0.1)
            out["startup"] = snap["all_good_at"] - started
            ctx.log(f"  {shards} shard(s): all {total:,} Good at MQTT after {out['startup']:.2f} s")
            ports = [http + k for k in range(shards)]
            workers = sorted(psutil.Process(proc.pid).children(), key=lambda p: p.create_time())
            await sim.ask("rate", rate="max")
            await asyncio.sleep(ctx.settings.warmup)
            c0 = [w.cpu_times() for w in workers]
            m0, t0 = sum(_changes(_metrics(p)) for p in ports), time.monotonic()
            s0 = await sim.ask("snap")
            await asyncio.sleep(ctx.settings.window)
            m1, t1 = sum(_changes(_metrics(p)) for p in ports), time.monotonic()
            s1 = await sim.ask("snap")
            c1 = [w.cpu_times() for w in workers]
            await sim.ask("rate", rate=0)
            out["changes"] = (m1 - m0) / (t1 - t0)
            out["offered"] = (s1["written"] - s0["written"]) / (s1["mono"] - s0["mono"])
            out["cpu"] = [
                100.0 * ((b.user + b.system) - (a.user + a.system)) / (t1 - t0)
                for a, b in zip(c0, c1, strict=True)
            ]
            out["rss"] = [w.memory_info().rss for w in workers]
            ctx.log(
                f"  {shards} shard(s), simulator flat out ({out['offered']:,.0f}/s written): "
                f"{out['changes']:,.0f} changes/s into the trees; CPU per shard "
                + ", ".join(f"{c:.0f} %" for c in out["cpu"])
                + "; RSS per shard "
                + ", ".join(f"{r / 1e6:.0f} MB" for r in out["rss"])
            )
            if shards > 1:
                last = ports[-1]
                expected = _connected(_metrics(last))
                victim = _shard_process(proc.pid, shards)
                killed = time.monotonic()
                victim.send_signal(signal.SIGKILL)
                # Polled, as an operator's dashboard would: /metrics is all a shard says about its machines.
                while _connected(_metrics(last)) > 0 and time.monotonic() - killed < 5:  # noqa: ASYNC110
                    await asyncio.sleep(0.02)
                while _connected(_metrics(last)) < expected:
                    if time.monotonic() - killed > START_LIMIT:
                        raise RuntimeError(f"{shards} shards: the killed shard's machines never came back")
                    await asyncio.sleep(0.05)
                out["restart"] = time.monotonic() - killed
                ctx.log(f"  shard {shards}/{shards} SIGKILLed: its {expected} machines connected again "
                        f"after {out['restart']:.2f} s (started again by the supervisor)")  # fmt: skip
        finally:
            if proc.returncode is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    async with asyncio.timeout(30):
                        await proc.wait()
                except TimeoutError:
                    proc.kill()
                    await proc.wait()
            await sub.stop()
    return out


async def _injected(ctx: Context, mappings: dict[str, str], shards: int, *, mqtt: bool) -> dict[str, Any]:
    """`shards` gateway processes over the 200 machines, each fed flat out by its own injector; with `mqtt`,
    each also publishes to one Mosquitto on this host (which then takes its share of the two cores)."""
    agents: list[Agent] = []
    tag = f"{shards}-{'mqtt' if mqtt else 'opcua'}"
    async with Mosquitto(ctx.workdir) as broker:
        try:
            for k in range(1, shards + 1):
                folder = ctx.workdir / f"fleet-inject-{tag}-{k}"
                extra = {"shard": f"{k}/{shards}", "http": None}
                port = broker.port if mqtt else None
                config, _ = write_gateway(folder, mappings, mqtt_port=port, extra=extra)
                agents.append(await Agent.start(
                    f"fleet-inject-{tag}-{k}", "bench.agents.gateway",
                    ["--config", str(config), "--inject"], ctx.workdir,
                ))  # fmt: skip
            for agent in agents:
                await agent.ask("rate", rate="max")
            await asyncio.sleep(ctx.settings.warmup)
            before = [await a.ask("snap") for a in agents]
            t0 = time.monotonic()
            c0 = [psutil.Process(a.proc.pid).cpu_times() for a in agents]
            await asyncio.sleep(ctx.settings.window)
            after = [await a.ask("snap") for a in agents]
            c1 = [psutil.Process(a.proc.pid).cpu_times() for a in agents]
            seconds = time.monotonic() - t0
            for agent in agents:
                await agent.ask("rate", rate=0)
        finally:
            for agent in reversed(agents):
                await agent.stop()
    rates = [
        (b["injector"]["written"] - a["injector"]["written"]) / seconds
        for a, b in zip(before, after, strict=True)
    ]
    cpu = [100.0 * ((b.user + b.system) - (a.user + a.system)) / seconds for a, b in zip(c0, c1, strict=True)]
    out = {"shards": shards, "mqtt": mqtt, "changes": sum(rates), "per_shard": rates, "cpu": cpu}
    each = ", ".join(f"{r:,.0f}/s at {c:.0f} %" for r, c in zip(rates, cpu, strict=True))
    faces = "OPC UA and MQTT to a broker on this host" if mqtt else "OPC UA"
    ctx.log(f"  in-process source, {shards} process(es) flat out, {faces}: {out['changes']:,.0f} changes/s "
            f"({each})")  # fmt: skip
    return out


async def _failover(ctx: Context, mappings: dict[str, str]) -> dict[str, Any]:
    """Two lease-served shards; the second SIGKILLed; until the first has every machine connected."""
    out: dict[str, Any] = {"lease_time": LEASE_TIME}
    with database() as url:
        async with Mosquitto(ctx.workdir) as broker:
            fleet_file = _write_fleet(ctx.workdir / "fleet-lease", mappings, 2, broker.port, lease=url)
            http = int(yaml.safe_load(fleet_file.read_text())["ports"]["HTTP_PORT"])
            log = (ctx.workdir / "fleet-lease.log").open("ab")
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gateway.cli.main", "fleet", str(fleet_file),
                stdout=log, stderr=log, env=child_env(), cwd=str(ROOT),
            )  # fmt: skip
            try:
                deadline = time.monotonic() + START_LIMIT
                half = MACHINES // 2
                while (_connected(_metrics(http)), _connected(_metrics(http + 1))) != (half, half):
                    if proc.returncode is not None or time.monotonic() > deadline:
                        raise RuntimeError("lease: the two shards never shared the machines out")
                    await asyncio.sleep(0.1)
                victim = _shard_process(proc.pid, 2)
                killed = time.monotonic()
                victim.send_signal(signal.SIGKILL)
                while _connected(_metrics(http)) < MACHINES:
                    if time.monotonic() - killed > START_LIMIT:
                        raise RuntimeError("lease: shard 1 never took shard 2's machines over")
                    await asyncio.sleep(0.05)
                out["failover"] = time.monotonic() - killed
                ctx.log(f"  lease {LEASE_TIME:g} s: shard 2/2 SIGKILLed; shard 1 serves all {MACHINES} "
                        f"machines after {out['failover']:.2f} s")  # fmt: skip
            finally:
                if proc.returncode is None:
                    proc.send_signal(signal.SIGTERM)
                    try:
                        async with asyncio.timeout(30):
                            await proc.wait()
                    except TimeoutError:
                        proc.kill()
                        await proc.wait()
    return out


async def run(ctx: Context) -> None:
    total = MACHINES * PER_MACHINE
    ctx.log(f"fleet: {MACHINES} machines × {PER_MACHINE} variables = {total:,}, shards {SHARDS}")
    spec = NoiseSpec(total)
    sim = await Agent.start("fleet-sim", "bench.agents.simulator", ["--variables", str(total)], ctx.workdir)
    runs: dict[int, dict[str, Any]] = {}
    try:
        mappings = {
            f"m{k:03d}": noise_mapping(
                spec, sim.ready["endpoint"], machine=f"m{k:03d}", first=first, count=count,
                publishing_interval=100, queue_size=1,
            )
            for k, (first, count) in enumerate(split_machines(spec, MACHINES))
        }  # fmt: skip
        for shards in SHARDS:
            runs[shards] = await _one(ctx, sim, mappings, shards)
        lease = await _failover(ctx, mappings)
    finally:
        await sim.stop()
    injected = {n: await _injected(ctx, mappings, n, mqtt=False) for n in (1, 2)}
    with_broker = {n: await _injected(ctx, mappings, n, mqtt=True) for n in (1, 2)}
    ctx.results.details["fleet"] = {
        "machines": MACHINES, "per_machine": PER_MACHINE, "runs": runs, "lease": lease,
        "injected": injected, "injected_mqtt": with_broker,
    }  # fmt: skip
    for key, label, table in (
        ("opcua", "OPC UA", injected),
        ("mqtt", "OPC UA + MQTT, broker here", with_broker),
    ):
        for n, data in table.items():
            ctx.results.add(
                f"fleet.injected.{key}.{n}", SECTION,
                f"{n} process(es), in-process source flat out ({label}): changes/s",
                data["changes"], "changes/s",
                baseline=table[1]["changes"] if n > 1 else None, baseline_label="1 process",
                note="CPU per process " + ", ".join(f"{c:.0f} %" for c in data["cpu"]),
            )  # fmt: skip
    ctx.results.add(
        "fleet.failover.2", SECTION, f"2 lease shards: kill → all {MACHINES} machines served by the other",
        lease["failover"], "s", note=f"lease_time {LEASE_TIME:g} s",
    )  # fmt: skip
    one = runs.get(1, {})
    for shards, data in runs.items():
        ctx.results.add(
            f"fleet.startup.{shards}", SECTION, f"{shards} shard(s): start → every variable Good (MQTT)",
            data.get("startup"), "s",
            baseline=one.get("startup") if shards > 1 else None, baseline_label="1 shard",
        )  # fmt: skip
        ctx.results.add(
            f"fleet.changes.{shards}", SECTION, f"{shards} shard(s): changes/s into the trees, flat out",
            data.get("changes"), "changes/s",
            baseline=one.get("changes") if shards > 1 else None, baseline_label="1 shard",
            note=f"offered {data.get('offered', 0):,.0f}/s; CPU per shard "
            + ", ".join(f"{c:.0f} %" for c in data.get("cpu", [])),
        )  # fmt: skip
        if "restart" in data:
            ctx.results.add(
                f"fleet.restart.{shards}", SECTION, f"{shards} shards: a killed shard's machines back",
                data["restart"], "s", note="static shards: the supervisor starts it again",
            )  # fmt: skip
