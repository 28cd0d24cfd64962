"""Serial DNC (issues 14 and 22): the gateway's job service and serial lines against simulated device servers.

Two processes: bench/agents/dnc_sim.py runs the simulator's DNC faces (raw TCP device servers, each with
its own machine), bench/agents/dnc_gateway.py the gateway's job service with its serial lines, built from
mappings as the README has a user write them: on a `7bit` device server (as a Moxa NPort or Lantronix set
7E2 is, the simulator's default: its UART does the parity) the defaults, on a `transparent` 8-bit port
`software_parity: true`. The controller's 256-byte buffer is told truthfully to the gateway (`buffer:
256`). The controller's side does the measuring: when characters reached it, what came after each of its
DC3s, when its machine waited for data, and its overruns: its buffer has the levels of a Fanuc's 256-byte
one (DC3 at 224, DC1 at 64) with room behind them, and each time it holds more than 256 bytes counts one
overrun (alarm 087 on a real one, which would end the run at the first).

"The estimate" is the gateway's run-time estimate of a program (gateway/codecs/dnc/runtime.py,
`block_times` with the line's `rapid`, default 10,000 mm/min): a machine at 8x consumes the program 8
times faster than it says. The simulated machines run at a feed override of 100 x that factor, on
programs of feed moves at F600 (so that 8x, 4,800 mm/min, stays below the simulator's rapid) paced so
that each machine really consumes a set number of characters a second.

* Load: a program (1 MB; quick 40 KB) at 115,200 baud 7E2, as the share of the line rate the controller
  received (characters over the time from its first to its last character), beside the same framed
  bytes written with one raw pyserial call, and the line rate itself.
* After DC3, once through each kind of device server: characters sent after each of the controller's
  DC3s, p99 and max, over a drip (5 MB through each, 10 MB in all, about 13 minutes each; quick 40 KB)
  at 115,200 baud, real time, whose machine cuts at half the estimate (6,400 characters a second, 61 %
  of the line; the estimate says more than the line carries), so that the buffer fills and DC3/DC1
  cycle. "Sent after" is timed: the controller notes when each
  DC3 and the DC1 after it left (CLOCK_MONOTONIC, which both processes share; a stamp just before and
  just after each send), the gateway's process when it wrote each piece to the device server's socket,
  and the characters written after the DC3's send returned and before the DC1's began are the ones sent
  after the DC3 (beside them, as an upper bound, those between the outer stamps). Beside it, from the
  controller's side alone: the characters that reached the device server after its DC3 (including what
  was sent before it but read late by a busy simulator), what the controller received after it (adding
  what the device server already held), its overruns, and the DC3s the job's record reports.
* One line, machines at 0.5x, 1x, 1.5x and 8x the estimate, 19,200 baud, each really consuming 60 % of
  the line (1,047 characters a second; 64 bytes after a DC1 last 61 ms, more than the simulator's own
  wake-up delays on a loaded machine, so that a starvation is the gateway's doing): starvation events
  and seconds, overruns, and how long the program took against its nominal time (60 s; quick 8 s). A
  gateway that sends only what its model says was consumed takes up to 8 times as long: a run is stopped
  at three times its nominal time plus 20 s and reported unfinished.
* Fleet: 20 machines drip-fed at once at 38,400 baud (real time), at 0.5x to 8x the estimate (a
  geometric spread), each really consuming 1,000 characters a second (29 % of its line: with 20 faces in
  one simulator process its wake-ups lag more), the 20 lines sharing one device server's uplink of 1.2
  times what they consume together: starvation events and seconds, overruns, and the CPU of the
  gateway's process (the job service and its 20 serial lines, no sinks).
* Restart (issue 14): a drip restarted at a line near the end of its program (header, modal state, that
  line on): from the command to the first byte at the device server, median and max of a few.

A/B (`python -m bench.run --only dnc --dnc-gateway before=PATH --dnc-gateway after=.`): the whole
scenario once per checkout, each with fresh agents, the gateway agent importing that checkout's gateway/;
figures and targets carry the label.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.agents.protocol import percentiles
from bench.context import Context
from bench.gcode_gen import laser_program, paced_program
from bench.procs import ROOT, Agent

SECTION = "Serial DNC: the gateway's serial lines → simulated device servers"
BAUD = 115_200
SINGLE_BAUD = 19_200
FLEET_BAUD = 38_400
BITS_PER_CHAR = 11  # 7E2: start, 7 data, parity, 2 stop
LINK_SHARE = 1.2  # the fleet's shared link, relative to what its machines really consume together
TOLD = 256  # the controller's buffer, told truthfully to the gateway
#: The simulated controller's buffer: a 256-byte one's levels, with room behind them to count overruns.
LEVELS = {"buffer": 16384, "high": 224, "low": 64, "overrun_at": TOLD}
KINDS = ("7bit", "transparent")
FACTORS = (0.5, 1.0, 1.5, 8.0)
SINGLE_SHARE = 0.6  # of the line, what a single line's machine really consumes
FLEET_RATE = 1000.0  # characters per second each fleet machine really consumes
AFTER_DC3_FACTOR = 0.5  # the after-DC3 drips' machine, relative to the estimate
AFTER_DC3_RATE = 6400.0  # characters per second it consumes (61 % of 115,200 baud)


def line_rate(baud: float) -> float:
    return baud / BITS_PER_CHAR


def drip_program(size: int, *, number: int, move: float, feed: int, pad: int) -> bytes:
    """Feed moves back and forth along X, each `move` mm at `feed` mm/min, padded with a comment to make
    each block about `pad` bytes: the machine's cutting pace in bytes/s is about pad / (move / feed * 60)."""
    head = f"%\nO{number:04d} (BENCH DRIP)\nG21 G90 G17\nG0 X100 Y100\n".encode()
    out = [head]
    length = len(head)
    x, sign = 100.0, 1.0
    filler = "P" * max(0, pad - 32)
    while length < size:
        x += sign * move
        if not 50.0 < x < 2500.0:
            sign = -sign
        block = f"G1 X{x:.3f} Y100 F{feed} ({filler})\n".encode()
        out.append(block)
        length += len(block)
    out.append(b"M30\n%\n")
    return b"".join(out)


async def run(ctx: Context) -> None:
    runs: dict[str, Any] = {}
    ctx.results.details["dnc"] = {"runs": runs}
    for label, source in ctx.settings.dnc_gateways:
        await _run_one(ctx, label, source, runs)


async def _run_one(ctx: Context, label: str, source: str | None, runs: dict[str, Any]) -> None:
    quick = ctx.settings.quick
    folder = ctx.workdir / (f"dnc-{label}" if label else "dnc")
    folder.mkdir(parents=True, exist_ok=True)
    args = ["--workdir", str(folder)]
    if source is not None:
        args += ["--gateway-source", str(Path(source).resolve())]
    sim = await Agent.start(f"dnc-sim{'-' + label if label else ''}", "bench.agents.dnc_sim", [], ctx.workdir)
    name = f"dnc-gateway{'-' + label if label else ''}"
    try:
        gw = await Agent.start(name, "bench.agents.dnc_gateway", args, ctx.workdir)
    except BaseException:
        await sim.stop()
        raise
    details: dict[str, Any] = {
        "label": label,
        "gateway": gw.ready.get("gateway"),
        "commit": gw.ready.get("commit"),
        "this_checkout": str(ROOT),
    }
    runs[label] = details
    run = Run(ctx, sim, gw, folder, details, label, gw.ready.get("commit") or "")
    run.log(f"gateway from {details['gateway']} ({details['commit'] or 'no git'})")
    try:
        parts = set(ctx.settings.dnc_parts) or {"load", "after_dc3", "single", "fleet", "restart"}
        if "load" in parts:
            await _load(run, size=40_000 if quick else 1_000_000)
        if "after_dc3" in parts:
            details["after_dc3"] = {}
            for kind in KINDS:
                await _after_dc3(run, kind, size=40_000 if quick else 5_000_000)
        if "single" in parts:
            details["single"] = {}
            for factor in FACTORS:
                await _single(run, factor, seconds=8.0 if quick else 60.0)
        if "fleet" in parts:
            await _fleet(run, seconds=10.0 if quick else 60.0)
        if "restart" in parts:
            await _restart(run, repeats=3 if quick else 5)
    finally:
        await gw.stop()
        await sim.stop()


@dataclass
class Run:
    """One run of the scenario (one per --dnc-gateway): its agents, folder and details, and its label in
    figure keys, sections and log lines (nothing when there is one run)."""

    ctx: Context
    sim: Agent
    gw: Agent
    folder: Path
    details: dict[str, Any]
    label: str = ""
    commit: str = ""

    @property
    def key(self) -> str:
        return f"dnc.{self.label}." if self.label else "dnc."

    @property
    def section(self) -> str:
        return f"{SECTION} [{self.label}: {self.commit}]" if self.label else SECTION

    def log(self, text: str) -> None:
        self.ctx.log(f"[{self.label}] {text}" if self.label else text)

    def add(self, key: str, label: str, value: float | None, unit: str, **more: Any) -> None:
        self.ctx.results.add(self.key + key, self.section, label, value, unit, **more)


async def _load(run: Run, *, size: int) -> None:
    sim, gw, folder, details = run.sim, run.gw, run.folder, run.details
    path = folder / "load.nc"
    path.write_bytes(laser_program(size, number=4711))
    rate = line_rate(BAUD)
    out: dict[str, Any] = {"size": path.stat().st_size, "line_rate": rate}
    for who, cmd in (("gateway", "load"), ("raw", "raw")):
        (url,) = (await sim.ask("setup", count=1, baud=BAUD, mode="load"))["urls"]
        answer = await gw.ask(cmd, url=url, baud=BAUD, program=str(path), timeout=size / rate * 3 + 60)
        face = await _settled(sim, lambda f: f["programs_loaded"] >= 1, timeout=size / rate + 30)
        chars, first, last = face["rx_chars"], face["rx_first"], face["rx_last"]
        share = (chars - 1) / (last - first) / rate if chars > 1 and last > first else None
        seconds = answer["seconds"]
        out[who] = {"share": share, "chars": chars, "seconds": seconds, "loaded": face["last_loaded"]}
        run.log(f"load {who}: {chars:,} chars, {share or 0:.1%} of the line rate ({answer['seconds']:.1f} s)")
    details["load"] = out
    run.add(
        "load.share",
        f"load mode, {out['size'] / 1e6:.2f} MB at 115,200 baud 7E2: share of the line rate",
        _pct(out["gateway"]["share"]),
        "%",
        baseline=_pct(out["raw"]["share"]),
        baseline_label="raw pyserial write, same bytes",
        note=f"line rate {rate:,.0f} chars/s; a 7-bit device server, the mapping's defaults",
    )


async def _after_dc3(run: Run, kind: str, *, size: int) -> None:
    sim, gw, folder, details = run.sim, run.gw, run.folder, run.details
    path = folder / f"after-dc3-{kind}.nc"
    # 64-byte blocks the machine cuts at half the estimate, 6,400 bytes/s (61 % of the line's pace): the
    # estimate (12,800 bytes/s) is more than the line carries, so the buffer fills and DC3/DC1 cycle.
    path.write_bytes(paced_program(size, factor=AFTER_DC3_FACTOR, rate=AFTER_DC3_RATE, pad=64, number=42))
    setup = {
        "count": 1,
        "baud": BAUD,
        "mode": "drip",
        "device_server": kind,
        "overrides": round(100 * AFTER_DC3_FACTOR),
        **LEVELS,
    }
    (url,) = (await sim.ask("setup", **setup))["urls"]
    timeout = size / AFTER_DC3_RATE * 3 + 120
    answer = await gw.ask(
        "drip",
        urls=[url],
        kinds=[kind],
        baud=BAUD,
        programs=[str(path)],
        buffer=TOLD,
        record=True,
        deadline=timeout,
        timeout=timeout + 60,
    )
    await _settled(sim, lambda f: f["machine"] != "RUNNING", timeout=60)
    stats = await sim.ask("stats")
    [face] = stats["faces"]
    arrived, got, flight = face["sent_after_dc3"], face["after_dc3"], face["in_flight_at_dc3"]
    # Certainly after the DC3 and before the DC1: from just after the DC3's send to just before the DC1's;
    # at most: from just before the one to just after the other (a descheduled simulator widens the gap).
    certain = [[h[1], h[2]] for h in face["holds"]]
    widest = [[h[0], h[3]] for h in face["holds"]]
    timed = await gw.ask("sent_after", holds=certain, timeout=120)
    sent = percentiles([float(n) for n in timed["counts"]])
    upper = percentiles([float(n) for n in (await gw.ask("sent_after", holds=widest, timeout=120))["counts"]])
    # Where the largest in-flight figures came from: what the gateway wrote in the 50 and 200 ms before
    # those DC3s, against what the line carries in that time (a writer ahead of the line, or a late DC3).
    each, all_holds = face.get("in_flight_each") or [], face["holds"]
    top = sorted(range(min(len(each), len(all_holds))), key=lambda i: -each[i])[:5]
    windows = [[all_holds[i][1] - w, all_holds[i][1]] for i in top for w in (0.05, 0.2)]
    written = (await gw.ask("sent_after", holds=windows, timeout=120))["counts"] if windows else []
    largest = [
        {"in_flight": each[i], "written_50ms": written[2 * k], "written_200ms": written[2 * k + 1]}
        for k, i in enumerate(top)
    ]
    [job] = answer["jobs"].values()
    out = {
        "kind": kind,
        "size": path.stat().st_size,
        "seconds": answer["seconds"],
        "sent_after_dc3": sent,
        "sent_after_dc3_at_most": upper,
        "arrived_after_dc3": arrived,
        "writes": timed["writes"],
        "received_after_dc3": got,
        "in_flight_at_dc3": flight,
        "largest_in_flight": largest,
        "line_chars_50ms": round(line_rate(BAUD) * 0.05),
        "loop_lag_ms": stats.get("loop_lag_ms"),
        "dc3_sent": face["dc3_sent"],
        "dc3_reported": job["dc3"],
        "overruns": face["overruns"],
        "overruns_late_dc3": face.get("overruns_late_dc3", 0),
        "overruns_bunched": face.get("overruns_bunched", 0),
        "bunched_reads": face.get("bunched_reads", 0),
        "overruns_on_time": face["overruns"]
        - face.get("overruns_late_dc3", 0)
        - face.get("overruns_bunched", 0),
        "dc3_late_ms": face.get("dc3_late_ms"),
        "dc3_late_beyond_headroom": face.get("dc3_late_beyond_headroom", 0),
        "highest": face["highest"],
        "failures": answer["failures"],
        "unfinished": answer["unfinished"],
        "starvations": face["starvations"],
        "rx_chars": face["rx_chars"],
        "parity_errors": face["parity_errors"],
    }
    details["after_dc3"][kind] = out
    run.log(
        f"after DC3, {kind} device server: {face['dc3_sent']:,} DC3s in {answer['seconds']:.0f} s "
        f"(the job's record: {job['dc3']} DC3); sent after DC3 p50 {sent['p50']} p99 {sent['p99']} max "
        f"{sent['max']} ({timed['writes']:,} writes; the stamps' widest span: p99 {upper['p99']} max "
        f"{upper['max']}); reached the device server after DC3 p99 {arrived['p99']} max {arrived['max']}; "
        f"received after DC3 p99 {got['p99']} max {got['max']}; overruns {face['overruns']:,} (highest "
        f"level {face['highest']:,}); failures {answer['failures']}"
    )
    lag = stats.get("loop_lag_ms") or {}
    run.log(
        "  largest in flight at a DC3 (written by the gateway in the 50 / 200 ms before it; the line "
        f"carries {out['line_chars_50ms']} in 50 ms): "
        + ", ".join(f"{x['in_flight']} ({x['written_50ms']} / {x['written_200ms']})" for x in largest)
        + f"; the simulator's loop late p99 {lag.get('p99', 0):.1f} ms, max {lag.get('max', 0):.1f} ms, "
        f"over 20 ms {lag.get('over_20_ms')} times, over 40 ms {lag.get('over_40_ms')}; DC3s later than the "
        f"headroom's line time after their level: {out['dc3_late_beyond_headroom']}, overruns after such a "
        f"late DC3: {out['overruns_late_dc3']} of {face['overruns']}; reads from TCP larger than the "
        f"headroom (the loop reading late): {out['bunched_reads']}, overruns after one: "
        f"{out['overruns_bunched']}"
    )
    note = f"{out['size'] / 1e6:.2f} MB drip at 115,200 baud, {sent['n']:,} DC3s, a {kind} device server"
    key = f"dc3.{kind}."
    run.add(
        key + "p99",
        f"characters sent after the controller's DC3, p99 ({kind})",
        sent["p99"],
        "chars",
        note=note,
    )
    run.add(
        key + "max",
        f"characters sent after the controller's DC3, max ({kind})",
        sent["max"],
        "chars",
        note=f"p50 {sent['p50']}; with the simulator's stamps' widest span, p99 {upper['p99']} max "
        f"{upper['max']}",
    )
    run.add(
        key + "received_p99",
        f"characters the controller received after its DC3, p99 ({kind})",
        got["p99"],
        "chars",
        note=f"max {got['max']}; reached the device server after it p99 "
        f"{arrived['p99']} max {arrived['max']} (the controller's counts: a busy simulator's lateness adds)",
    )
    run.add(
        key + "overruns",
        f"buffer overruns (alarm 087) over the drip ({kind})",
        face["overruns"],
        "",
        note=f"the buffer's highest level {face['highest']:,} of 256; the job's record: {job['dc3']} DC3 "
        f"of {face['dc3_sent']:,} sent",
    )


async def _single(run: Run, factor: float, *, seconds: float) -> None:
    sim, gw, folder, details = run.sim, run.gw, run.folder, run.details
    rate = SINGLE_SHARE * line_rate(SINGLE_BAUD)
    path = folder / f"single-{factor:g}x.nc"
    path.write_bytes(paced_program(int(rate * seconds), factor=factor, rate=rate, pad=48, number=300))
    override = round(100 * factor)
    setup = {"count": 1, "baud": SINGLE_BAUD, "mode": "drip", "overrides": override, **LEVELS}
    (url,) = (await sim.ask("setup", **setup))["urls"]
    deadline = 3 * seconds + 20
    answer = await gw.ask(
        "drip",
        urls=[url],
        baud=SINGLE_BAUD,
        programs=[str(path)],
        buffer=TOLD,
        deadline=deadline,
        timeout=deadline + 60,
    )
    await _settled(sim, lambda f: f["machine"] != "RUNNING", timeout=60)
    [face] = (await sim.ask("stats"))["faces"]
    took = answer["seconds"]
    out = {
        "factor": factor,
        "override": override,
        "rate": rate,
        "nominal_seconds": seconds,
        "seconds": took,
        "unfinished": bool(answer["unfinished"]),
        "starvations": face["starvations"],
        "starved_seconds": face["starved_seconds"],
        "overruns": face["overruns"],
        "dc3_sent": face["dc3_sent"],
        "failures": answer["failures"],
    }
    details["single"][f"{factor:g}"] = out
    end = "stopped unfinished" if out["unfinished"] else "ended"
    run.log(
        f"one line, machine at {factor:g}x the estimate ({rate:,.0f} chars/s): "
        f"{face['starvations']} starvations ({face['starved_seconds']:.2f} s), {face['overruns']} overruns, "
        f"{end} after {took:.1f} s of a nominal {seconds:g} s; failures {answer['failures']}"
    )
    run.add(
        f"single.{factor:g}x.starvations",
        f"one line, machine at {factor:g}x the estimate: starvation events",
        face["starvations"],
        "",
        note=f"{face['starved_seconds']:.2f} s starved, {face['overruns']} overruns; the program took "
        f"{took:.1f} s of a nominal {seconds:g} s{' (stopped unfinished)' if out['unfinished'] else ''}; "
        f"{SINGLE_BAUD:,} baud, {rate:,.0f} chars/s consumed",
    )


def fleet_factors(count: int) -> list[float]:
    """0.5x to 8x the estimate, a geometric spread over `count` machines."""
    return [0.5 * 16 ** (i / (count - 1)) for i in range(count)]


async def _fleet(run: Run, *, seconds: float) -> None:
    sim, gw, folder, details = run.sim, run.gw, run.folder, run.details
    count = 20
    factors = fleet_factors(count)
    overrides = [round(100 * f) for f in factors]
    paths = []
    for i, override in enumerate(overrides):
        path = folder / f"fleet-{i:02d}.nc"
        size = int(FLEET_RATE * seconds)
        data = paced_program(size, factor=override / 100, rate=FLEET_RATE, pad=48, number=100 + i)
        path.write_bytes(data)
        paths.append(str(path))
    setup = {"count": count, "baud": FLEET_BAUD, "mode": "drip", "overrides": overrides, **LEVELS}
    urls = (await sim.ask("setup", **setup))["urls"]
    # The 20 lines share one device server's uplink of 1.2 times what the machines really consume together
    # (the lines could carry 3.5 times as much): the scheduler shares it.
    link = {"name": "nport", "capacity": round(LINK_SHARE * count * FLEET_RATE)}
    deadline = 3 * seconds + 20
    answer = await gw.ask(
        "drip",
        urls=urls,
        baud=FLEET_BAUD,
        programs=paths,
        buffer=TOLD,
        link=link,
        deadline=deadline,
        timeout=deadline + 60,
    )
    await _settled_all(sim, lambda f: f["machine"] != "RUNNING", timeout=60)
    faces = (await sim.ask("stats"))["faces"]
    events = sum(f["starvations"] for f in faces)
    starved = sum(f["starved_seconds"] for f in faces)
    overruns = sum(f["overruns"] for f in faces)
    chars = sum(f["rx_chars"] for f in faces)
    cpu = answer["cpu_share"]
    # A gateway that starves its machines also sends less: its CPU per 1,000 characters the controllers
    # received puts two gateways side by side on the same work.
    per_1000 = cpu * answer["seconds"] / chars * 1e6 if cpu is not None and chars else None
    details["fleet"] = {
        "machines": count,
        "baud": FLEET_BAUD,
        "factors": factors,
        "rate": FLEET_RATE,
        "link_capacity": link["capacity"],
        "nominal_seconds": seconds,
        "seconds": answer["seconds"],
        "unfinished": answer["unfinished"],
        "starvations": events,
        "starved_seconds": starved,
        "overruns": overruns,
        "cpu_share": cpu,
        "chars": chars,
        "cpu_ms_per_1000_chars": per_1000,
        "failures": answer["failures"],
        "per_machine": [
            {"override": o, **{k: f[k] for k in ("starvations", "starved_seconds", "rx_chars", "overruns")}}
            for o, f in zip(overrides, faces, strict=True)
        ],
    }
    run.log(
        f"fleet: {count} × {FLEET_BAUD} baud at 0.5x-8x the estimate, {answer['seconds']:.0f} s "
        f"(nominal {seconds:g} s; unfinished {len(answer['unfinished'])}): {events} starvations "
        f"({starved:.2f} s), {overruns} overruns, gateway CPU {cpu or 0:.0%} of a core "
        f"({per_1000 or 0:.2f} ms per 1,000 of the {chars:,} characters received), failures "
        f"{len(answer['failures'])}"
    )
    note = (
        f"{count} machines × {FLEET_BAUD:,} baud at 0.5x-8x the estimate, each consuming {FLEET_RATE:,.0f} "
        f"chars/s, sharing a {link['capacity']:,} chars/s link; {answer['seconds']:.0f} s of a nominal "
        f"{seconds:g} s, {len(answer['unfinished'])} unfinished"
    )
    run.add("fleet.starvations", "fleet drip: starvation events", events, "", note=note)
    run.add(
        "fleet.starved_seconds",
        "fleet drip: seconds starved (all machines)",
        starved,
        "s",
        note=f"{overruns} overruns",
    )
    run.add(
        "fleet.cpu",
        "fleet drip: the gateway's CPU, share of one core",
        _pct(cpu),
        "%",
        note=f"the process running the job service and its 20 serial lines (no sinks); "
        f"{per_1000 or 0:.2f} ms of CPU per 1,000 of the {chars:,} characters the controllers received",
    )


async def _restart(run: Run, *, repeats: int) -> None:
    sim, gw, folder, details = run.sim, run.gw, run.folder, run.details
    path = folder / "restart.nc"
    data = drip_program(
        1_000_000 if not run.ctx.settings.quick else 200_000, number=77, move=0.6, feed=6000, pad=64
    )
    path.write_bytes(data)
    lines = data.count(b"\n")
    line = lines - 20  # a tool broke near the end: header, modal state, and the last few blocks
    (url,) = (await sim.ask("setup", count=1, baud=BAUD, mode="drip", **LEVELS))["urls"]
    delays = []
    for _ in range(repeats):
        # The controller ready again: the machine has finished the blocks it holds from the last restart
        # (the first move of a restart, a rapid back to that line's position, can take seconds).
        await _settled(sim, lambda f: f["machine"] != "RUNNING", timeout=120)
        await sim.ask("mark")
        answer = await gw.ask(
            "restart", url=url, baud=BAUD, program=str(path), line=line, repeats=1, timeout=120
        )
        [face] = (await sim.ask("stats"))["faces"]
        if face["first"] is not None:
            delays.append(face["first"] - answer["commands"][0])
    details["restart"] = {"program_bytes": len(data), "line": line, "delays": delays}
    median = statistics.median(delays) if delays else None
    run.log(
        f"restart at line {line:,} of {lines:,}: command to first byte "
        f"{', '.join(f'{d:.3f}' for d in delays)} s"
    )
    run.add(
        "restart.first_byte",
        "drip restart at block N: command to first byte, median",
        median,
        "s",
        note=f"{len(data) / 1e6:.1f} MB program, line {line:,}; max {max(delays) if delays else 0:.3f} s",
    )


async def _settled(sim: Agent, done: Any, *, timeout: float) -> dict[str, Any]:
    faces = await _settled_all(sim, done, timeout=timeout)
    return faces[0]


async def _settled_all(sim: Agent, done: Any, *, timeout: float) -> list[dict[str, Any]]:
    import asyncio

    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        faces: list[dict[str, Any]] = (await sim.ask("stats"))["faces"]
        if all(done(f) for f in faces):
            return faces
        if loop.time() > deadline:
            raise TimeoutError(f"the simulated controllers did not settle within {timeout:g} s: {faces[:2]}")
        await asyncio.sleep(0.2)


def _pct(share: float | None) -> float | None:
    return None if share is None else share * 100.0
