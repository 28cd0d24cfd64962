"""Serial DNC (issue 14): the gateway's serial delivery transport against simulated device servers.

Two processes: bench/agents/dnc_sim.py runs the simulator's DNC faces (raw TCP device servers, each with
its own machine), bench/agents/dnc_gateway.py the gateway's serial transport (pyserial in a thread per
line, as in the gateway). The controller's side does the measuring: when characters reached it, what
came after each of its DC3s, when its machine waited for data.

* Load: a program (1 MB; quick 40 KB) at 115,200 baud 7E2, as the share of the line rate the controller
  received (characters over the time from its first to its last character), beside the same framed
  bytes written with one raw pyserial call, and the line rate itself.
* DC3 overrun: characters sent after each of the controller's DC3s, p99 and max, over a drip-feed (10 MB,
  about 40 minutes on a loaded machine; quick 40 KB) at 115,200 baud, real time, whose machine cuts
  slower than the line, so that the buffer fills and DC3/DC1 cycle (the controller's levels are a
  256-byte buffer's, with room behind them, so that an overrun is counted rather than ending the run with
  alarm 087). "Sent after" is timed: the controller notes when each DC3 and the DC1 after it left
  (CLOCK_MONOTONIC, which both processes share; a stamp just before and just after each send), the
  transport's process when it made each write, and the characters written after the DC3's send
  returned and before the DC1's began are the ones sent after the DC3 (beside them, as an upper bound,
  those between the outer stamps: a simulator descheduled between a stamp and its send widens that).
  Beside it, from the controller's side alone: the characters that reached the device server after its
  DC3 (those include what the sender wrote before the DC3 but the simulator read late: on a loaded
  machine its wake-ups lag), and what the controller received after its DC3, which adds what the device
  server already held.
* Fleet: 20 machines drip-fed at once at 38,400 baud (real time), each cutting at its program's pace
  (slower than the line) with a 4 KB receive buffer, the 20 lines sharing one device server's uplink of
  1.2 times what they cut together (their lines could carry 1.7 times): the gateway's drip scheduler
  shares it (gateway/jobs/dnc/fleet.py). Starvation events and their seconds, and the CPU of the
  gateway's process (20 serial transports, no queue and no sinks).
* Restart: a drip restarted at a line near the end of its program (header, modal state, that line on):
  from the command to the first byte at the device server, median and max of a few.
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from bench.agents.protocol import percentiles
from bench.context import Context
from bench.procs import Agent

SECTION = "Serial DNC: the gateway's serial transport → simulated device servers"
BAUD = 115_200
FLEET_BAUD = 38_400
BITS_PER_CHAR = 11  # 7E2: start, 7 data, parity, 2 stop
LINK_SHARE = 1.2  # the fleet's shared link, relative to what its machines cut together


def line_rate(baud: float) -> float:
    return baud / BITS_PER_CHAR


def drip_program(size: int, *, number: int, move: float, feed: int, pad: int) -> bytes:
    """Feed moves back and forth along X, each `move` mm at `feed` mm/min, padded with a comment to make
    each block about `pad` bytes: the machine's cutting pace in bytes/s is about pad / (move / feed * 60)."""
    head = f"%\nO{number:04d} (BENCH DRIP)\nG21 G90 G17\nG0 X100 Y100\n".encode()
    out = [head]
    length = len(head)
    x, sign, i = 100.0, 1.0, 0
    filler = "P" * max(0, pad - 32)
    while length < size:
        x += sign * move
        if not 50.0 < x < 2500.0:
            sign = -sign
        block = f"G1 X{x:.3f} Y100 F{feed} ({filler})\n".encode()
        out.append(block)
        length += len(block)
        i += 1
    out.append(b"M30\n%\n")
    return b"".join(out)


async def run(ctx: Context) -> None:
    quick = ctx.settings.quick
    folder = ctx.workdir / "dnc"
    folder.mkdir(parents=True, exist_ok=True)
    sim = await Agent.start("dnc-sim", "bench.agents.dnc_sim", [], ctx.workdir)
    gw = await Agent.start("dnc-gateway", "bench.agents.dnc_gateway", ["--workdir", str(folder)], ctx.workdir)
    details: dict[str, Any] = {}
    ctx.results.details["dnc"] = details
    try:
        await _load(ctx, sim, gw, folder, details, size=40_000 if quick else 1_000_000)
        await _overrun(ctx, sim, gw, folder, details, size=40_000 if quick else 10_000_000)
        await _fleet(ctx, sim, gw, folder, details, seconds=6.0 if quick else 60.0)
        await _restart(ctx, sim, gw, folder, details, repeats=3 if quick else 5)
    finally:
        await gw.stop()
        await sim.stop()


async def _load(
    ctx: Context, sim: Agent, gw: Agent, folder: Path, details: dict[str, Any], *, size: int
) -> None:
    from bench.gcode_gen import laser_program

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
        out[who] = {
            "share": share,
            "chars": chars,
            "seconds": answer["seconds"],
            "loaded": face["last_loaded"],
        }
        ctx.log(f"load {who}: {chars:,} chars, {share or 0:.1%} of the line rate ({answer['seconds']:.1f} s)")
    details["load"] = out
    ctx.results.add(
        "dnc.load.share",
        SECTION,
        f"load mode, {out['size'] / 1e6:.2f} MB at 115,200 baud 7E2: share of the line rate",
        _pct(out["gateway"]["share"]),
        "%",
        baseline=_pct(out["raw"]["share"]),
        baseline_label="raw pyserial write, same bytes",
        note=f"line rate {rate:,.0f} chars/s",
    )


async def _overrun(
    ctx: Context, sim: Agent, gw: Agent, folder: Path, details: dict[str, Any], *, size: int
) -> None:
    path = folder / "overrun.nc"
    # 64-byte blocks of 1 mm at 6,000 mm/min: 10 ms of cutting each, 6,400 bytes/s, 61 % of the line's pace
    path.write_bytes(drip_program(size, number=42, move=1.0, feed=6000, pad=64))
    # A Fanuc-like 256-byte buffer's levels (DC3 at 224, DC1 at 64), with room behind them so that an
    # overrun is counted instead of stopping the run with alarm 087
    setup = {"count": 1, "baud": BAUD, "mode": "drip", "buffer": 16384, "high": 224, "low": 64}
    (url,) = (await sim.ask("setup", **setup))["urls"]
    timeout = size / 6400 * 3 + 120
    # The gateway is told the controller holds 16 KB: its scheduler then leaves the regulating to DC3/DC1,
    # as with a controller whose buffer is not known, so that every one of the many DC3s tests its reaction
    # (told 256 bytes, it would keep the buffer below the DC3 level most of the time).
    answer = await gw.ask(
        "drip", urls=[url], baud=BAUD, programs=[str(path)], timeout=timeout, record=True, buffer=16384
    )
    [face] = (await sim.ask("stats"))["faces"]
    arrived, got, flight = face["sent_after_dc3"], face["after_dc3"], face["in_flight_at_dc3"]
    # Certainly after the DC3 and before the DC1: from just after the DC3's send to just before the DC1's;
    # at most: from just before the one to just after the other (a descheduled simulator widens the gap).
    certain = [[h[1], h[2]] for h in face["holds"]]
    widest = [[h[0], h[3]] for h in face["holds"]]
    timed = await gw.ask("sent_after", holds=certain, timeout=120)
    sent = percentiles([float(n) for n in timed["counts"]])
    upper = percentiles([float(n) for n in (await gw.ask("sent_after", holds=widest, timeout=120))["counts"]])
    seconds = answer["seconds"]
    details["overrun"] = {
        "size": path.stat().st_size,
        "seconds": seconds,
        "sent_after_dc3": sent,
        "sent_after_dc3_at_most": upper,
        "arrived_after_dc3": arrived,
        "writes": timed["writes"],
        "received_after_dc3": got,
        "in_flight_at_dc3": flight,
        "dc3_sent": face["dc3_sent"],
        "over_256": face["overflows"],
        "failures": answer["failures"],
        "starvations": face["starvations"],
        "rx_chars": face["rx_chars"],
    }
    ctx.log(
        f"overrun: {face['dc3_sent']:,} DC3s in {seconds:.0f} s; sent after DC3 p50 {sent['p50']} "
        f"p99 {sent['p99']} "
        f"max {sent['max']} ({timed['writes']:,} writes; counting the simulator's stamps' widest span: p99 "
        f"{upper['p99']} max {upper['max']}); reached the device server after DC3 p99 "
        f"{arrived['p99']} max {arrived['max']}; in the device server at DC3 p50 {flight['p50']} max "
        f"{flight['max']}; the "
        f"controller received after DC3 p99 {got['p99']} max {got['max']}; failures {answer['failures']}"
    )
    note = f"{path.stat().st_size / 1e6:.2f} MB drip at 115,200 baud, {sent['n']:,} DC3s"
    ctx.results.add(
        "dnc.dc3.p99",
        SECTION,
        "characters sent after the controller's DC3, p99",
        sent["p99"],
        "chars",
        note=note,
    )
    ctx.results.add(
        "dnc.dc3.max",
        SECTION,
        "characters sent after the controller's DC3, max",
        sent["max"],
        "chars",
        note=f"written between the DC3 leaving the controller and its DC1 (timed); p50 {sent['p50']}; "
        f"with the simulator's stamps' widest span, p99 {upper['p99']} max {upper['max']}",
    )
    ctx.results.add(
        "dnc.dc3.arrived_p99",
        SECTION,
        "characters that reached the device server after the controller's DC3, p99",
        arrived["p99"],
        "chars",
        note=f"the controller's count alone: includes what was sent before the DC3 and read late; max "
        f"{arrived['max']}",
    )
    ctx.results.add(
        "dnc.dc3.received_p99",
        SECTION,
        "characters the controller received after its DC3, p99",
        got["p99"],
        "chars",
        note=f"with those already in the device server at the DC3 (p99 {flight['p99']}): the simulator's "
        "own lateness on a loaded machine counts here; max " + str(got["max"]),
    )


async def _fleet(
    ctx: Context, sim: Agent, gw: Agent, folder: Path, details: dict[str, Any], *, seconds: float
) -> None:
    count = 20
    rate = line_rate(FLEET_BAUD)
    # 42-byte blocks of 1 mm at 3,000 mm/min: 20 ms of cutting each, 2,100 bytes/s, 60 % of the line
    pace = 42 / (1.0 / 3000 * 60)
    paths = []
    for i in range(count):
        path = folder / f"fleet-{i:02d}.nc"
        path.write_bytes(drip_program(int(pace * seconds), number=100 + i, move=1.0, feed=3000, pad=48))
        paths.append(str(path))
    # a 4 KB receive buffer (DC3 at 3.5 KB, DC1 at 1 KB: half a second of cutting): a 256-byte one's DC1
    # at 64 bytes leaves 18 ms at 38,400 baud, less than the simulator's own wake-up delays on a loaded
    # machine, which would count as starvations of the gateway's making
    setup = {"count": count, "baud": FLEET_BAUD, "mode": "drip", "buffer": 4096, "high": 3584, "low": 1024}
    urls = (await sim.ask("setup", **setup))["urls"]
    # The 20 lines share one device server's uplink, configured at 1.2 times what the machines cut together
    # (less than the lines could carry together): the scheduler shares it, earliest dry first.
    link = {"name": "nport", "capacity": round(LINK_SHARE * count * pace)}
    answer = await gw.ask(
        "drip",
        urls=urls,
        baud=FLEET_BAUD,
        programs=paths,
        timeout=seconds * 5 + 120,
        buffer=setup["high"],
        link=link,
    )
    faces = (await sim.ask("stats"))["faces"]
    events = sum(f["starvations"] for f in faces)
    starved = sum(f["starved_seconds"] for f in faces)
    cpu = answer["cpu_share"]
    details["fleet"] = {
        "machines": count,
        "baud": FLEET_BAUD,
        "line_rate": rate,
        "cutting_pace": pace,
        "link_capacity": link["capacity"],
        "seconds": answer["seconds"],
        "starvations": events,
        "starved_seconds": starved,
        "cpu_share": cpu,
        "failures": answer["failures"],
        "per_machine": [
            {k: f[k] for k in ("starvations", "starved_seconds", "rx_chars", "overflows")} for f in faces
        ],
    }
    ctx.log(
        f"fleet: {count} × {FLEET_BAUD} baud, {answer['seconds']:.0f} s: {events} starvations "
        f"({starved:.2f} s), gateway CPU {cpu:.0%} of a core, failures {answer['failures']}"
    )
    note = (
        f"{count} machines × {FLEET_BAUD:,} baud, {answer['seconds']:.0f} s, "
        f"cutting at {pace / rate:.0%} of the line, sharing a {link['capacity']:,} chars/s link"
    )
    ctx.results.add("dnc.fleet.starvations", SECTION, "fleet drip: starvation events", events, "", note=note)
    ctx.results.add(
        "dnc.fleet.starved_seconds", SECTION, "fleet drip: seconds starved (all machines)", starved, "s"
    )
    ctx.results.add(
        "dnc.fleet.cpu",
        SECTION,
        "fleet drip: the gateway transport's CPU, share of one core",
        _pct(cpu),
        "%",
        note="the process running the 20 serial transports (no queue, no sinks)",
    )


async def _restart(
    ctx: Context, sim: Agent, gw: Agent, folder: Path, details: dict[str, Any], *, repeats: int
) -> None:
    path = folder / "restart.nc"
    data = drip_program(
        1_000_000 if not ctx.settings.quick else 200_000, number=77, move=0.6, feed=6000, pad=64
    )
    path.write_bytes(data)
    lines = data.count(b"\n")
    line = lines - 20  # a tool broke near the end: header, modal state, and the last few blocks
    (url,) = (await sim.ask("setup", count=1, baud=BAUD, mode="drip"))["urls"]
    delays = []
    for _ in range(repeats):
        # The controller ready again: the machine has finished the blocks it holds from the last restart
        # (the first move of a restart, a rapid back to that line's position, can take seconds).
        await _settled(sim, lambda f: f["machine"] == "IDLE", timeout=120)
        await sim.ask("mark")
        answer = await gw.ask(
            "restart", url=url, baud=BAUD, program=str(path), line=line, repeats=1, timeout=120
        )
        [face] = (await sim.ask("stats"))["faces"]
        if face["first"] is not None:
            delays.append(face["first"] - answer["commands"][0])
    details["restart"] = {"program_bytes": len(data), "line": line, "delays": delays}
    median = statistics.median(delays) if delays else None
    ctx.log(
        f"restart at line {line:,} of {lines:,}: command to first byte "
        f"{', '.join(f'{d:.3f}' for d in delays)} s"
    )
    ctx.results.add(
        "dnc.restart.first_byte",
        SECTION,
        "drip restart at block N: command to first byte, median",
        median,
        "s",
        note=f"{len(data) / 1e6:.1f} MB program, line {line:,}; max {max(delays) if delays else 0:.3f} s",
    )


async def _settled(sim: Agent, done: Any, *, timeout: float) -> dict[str, Any]:
    import asyncio

    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        [face] = (await sim.ask("stats"))["faces"]
        if done(face):
            return face
        if loop.time() > deadline:
            raise TimeoutError(f"the simulated controller did not finish within {timeout:g} s: {face}")
        await asyncio.sleep(0.2)


def _pct(share: float | None) -> float | None:
    return None if share is None else share * 100.0
