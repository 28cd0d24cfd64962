"""Simulated serial DNC controllers for the DNC benchmark: N of the simulator's DNC faces (simulator/dnc),
each a raw TCP device server with its own machine, stepped like the simulator's runner steps its one.

Commands: `setup` (count, baud, mode, speed, buffer, high, low, overrun_at, load_rate, device_server,
overrides): start N faces, answer their URLs; `device_server` (7bit or transparent) and `overrides` (the
machines' feed overrides in %, one per face or one for all) may be lists; `mark`: forget first/last
receive times; `stats`: per face the controller's counters, the characters after each DC3, the first
and last receive time (CLOCK_MONOTONIC, which every process shares), the machine's starvations and the
seconds it spent starved, and its overruns; `teardown`.

Overruns: a Fanuc's 256-byte buffer raises alarm 087 at its first overrun and the run would stop there.
Here the buffer (`buffer`) has room behind the levels a 256-byte one has (DC3 at `high`, DC1 at `low`),
and each time its level goes beyond `overrun_at` (256) counts one overrun: what 087 would have been.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from bench.agents.protocol import percentiles, serve, setup_logging
from gateway.codecs.dnc import DC3, LineSettings
from simulator.dnc.controller import DncSpec, Mode
from simulator.dnc.face import DncFace
from simulator.dnc.links import Link
from simulator.dnc.uart import DeviceServer
from simulator.machine import Machine
from simulator.store import MemoryStore

TICK = 0.01  # s between machine steps, as the simulator's runner
LAG_PROBE = 0.002  # s: the sleep whose overshoot measures the event loop's lateness


@dataclass
class Timed:
    first: float | None = None  # the device server's first and last receive (TCP)
    last: float | None = None
    chars: int = 0
    rx_first: float | None = None  # the controller's: when its character count first and last moved
    rx_last: float | None = None
    rx_seen: int = 0


class TimedFace(DncFace):
    """A DNC face that notes when data first and last came in (the controller's view of a transfer), and
    per DC3 of the controller: how many characters the device server already held (sent before the DC3,
    still on their way), and how many reached the device server after it, until the DC1 (sent after it:
    what the sender's reaction time costs)."""

    timed: Timed
    overrun_at: int | None = None
    overruns: int = 0  # times the buffer's level went beyond overrun_at (alarm 087 on a real controller)
    # Of those, the overruns of episodes whose DC3 left late: later after the level was reached (the line's
    # own clock) than the headroom between the DC3 level and overrun_at takes the line to fill. Such a DC3
    # overruns the buffer whatever the sender does; a controller's UART and firmware raise it on time, a
    # simulator whose event loop is late does not (bench/README.md, scenario dnc).
    overruns_late_dc3: int = 0
    # And those of episodes in which the device server took more than that headroom from TCP in one read:
    # the gateway writes a few characters at a time, so such a read is the simulator's loop reading late
    # (the kernel held what came meanwhile) and its line then carries a burst it would have carried over
    # the time the loop slept, the machine cutting meanwhile.
    overruns_bunched: int = 0
    bunched_reads: int = 0
    _largest_read: int = 0  # since the last DC1
    dc3_late: list[float]  # s after the level was reached, per DC3
    highest: int = 0  # the buffer's highest level
    in_flight: list[int]
    sent_after: list[int]
    # Per DC3, CLOCK_MONOTONIC: [just before and just after the DC3 was handed to the socket, just before and
    # just after the DC1 after it (inf until then)]. A busy simulator can be descheduled between a stamp
    # and the send, so each moment is known to lie between its two stamps.
    holds: list[list[float]]
    _after: int | None

    def watch_dc3(self) -> None:
        self.in_flight, self.sent_after, self.holds, self._after = [], [], [], None
        self.dc3_late = []
        controller = self.controller
        send_flow = controller._send_flow

        def watched(char: int) -> None:
            now = time.monotonic()
            send_flow(char)
            sent = time.monotonic()
            if char == DC3:
                self.dc3_late.append(max(0.0, now - controller._rx_free_at))  # the level's char arrived then
                if not self.holds or self.holds[-1][3] != math.inf:
                    self.holds.append([now, sent, math.inf, math.inf])
                self.in_flight.append(len(controller.wire))
                if self._after is not None:
                    self.sent_after.append(self._after)
                self._after = 0
            else:
                self._largest_read = 0
                if self.holds and self.holds[-1][3] == math.inf:
                    self.holds[-1][2:] = [now, sent]
                if self._after is not None:
                    self.sent_after.append(self._after)
                    self._after = None

        controller._send_flow = watched  # type: ignore[method-assign]

    def watch_level(self, overrun_at: int | None) -> None:
        """Count the overruns of a buffer of `overrun_at` bytes (the controller's own `_buffer` appends)."""
        self.overrun_at, self.overruns, self.highest = overrun_at, 0, 0
        self.overruns_late_dc3 = self.overruns_bunched = self.bunched_reads = self._largest_read = 0
        controller = self.controller
        headroom = (overrun_at - controller.spec.high) / controller.rate if overrun_at is not None else 0.0
        buffer = controller._buffer

        def watched(chars: bytes) -> None:
            before = len(controller.rx)
            buffer(chars)
            level = len(controller.rx)
            self.highest = max(self.highest, level)
            if self.overrun_at is not None and before <= self.overrun_at < level:
                self.overruns += 1
                if self.dc3_late and self.dc3_late[-1] > headroom:
                    self.overruns_late_dc3 += 1
                elif self._largest_read > self.overrun_at - controller.spec.high:
                    self.overruns_bunched += 1

        controller._buffer = watched  # type: ignore[method-assign]

    def link_data(self, link: Link, data: bytes) -> None:
        now = time.monotonic()
        t = self.timed
        if t.first is None:
            t.first = now
        t.last = now
        t.chars += len(data)
        self._largest_read = max(self._largest_read, len(data))
        if self.overrun_at is not None and len(data) > self.overrun_at - self.controller.spec.high:
            self.bunched_reads += 1
        if self._after is not None:
            self._after += len(data)
        super().link_data(link, data)


@dataclass
class Fleet:
    faces: list[TimedFace] = field(default_factory=list)
    starved: list[float] = field(default_factory=list)
    stack: contextlib.AsyncExitStack | None = None
    ticker: asyncio.Task[None] | None = None
    prober: asyncio.Task[None] | None = None
    speed: float = 1.0
    lags: list[float] = field(default_factory=list)  # s: how late the loop woke a 2 ms sleep, per sleep


async def main() -> None:
    fleet = Fleet()

    async def tick() -> None:
        last = time.monotonic()
        while True:
            await asyncio.sleep(TICK)
            now = time.monotonic()
            dt = now - last
            last = now
            for i, face in enumerate(fleet.faces):
                t = face.timed
                rx = face.controller.stats.rx_chars
                if rx != t.rx_seen:
                    t.rx_seen = rx
                    t.rx_last = now
                    if t.rx_first is None:
                        t.rx_first = now
                machine = face.machine
                if machine.waiting_for_data:
                    fleet.starved[i] += dt
                machine.step(dt * fleet.speed)

    async def probe() -> None:
        """The event loop's lateness, which is the faces' (a late loop raises a DC3 late)."""
        while True:
            before = time.monotonic()
            await asyncio.sleep(LAG_PROBE)
            fleet.lags.append(time.monotonic() - before - LAG_PROBE)

    async def setup(request: dict[str, Any]) -> dict[str, Any]:
        await teardown({})
        count = int(request["count"])
        speed = float(request.get("speed", 1.0))
        line = LineSettings(baud=int(request["baud"]))
        kinds = _each(request.get("device_server", DeviceServer.SEVEN_BIT.value), count)
        overrides = _each(request.get("overrides"), count)
        spec = DncSpec(
            line=line,
            mode=Mode(request.get("mode", "load")),
            buffer_size=int(request.get("buffer", 256)),
            high_water=request.get("high"),
            low_water=request.get("low"),
            load_rate=request.get("load_rate"),
            max_program=int(request.get("max_program", 16 * 1024 * 1024)),
        )
        stack = contextlib.AsyncExitStack()
        await stack.__aenter__()
        fleet.stack, fleet.speed = stack, speed
        fleet.faces, fleet.starved = [], []
        for kind, override in zip(kinds, overrides, strict=True):
            face = TimedFace(
                spec, Machine(MemoryStore()), MemoryStore(), tcp_port=0, speed=speed,
                device_server=DeviceServer(kind), override=None if override is None else int(override),
            )  # fmt: skip
            face.timed = Timed()
            face.watch_dc3()
            face.watch_level(request.get("overrun_at"))
            face.controller.episodes = deque()  # every DC3 episode, not the last 10,000
            await stack.enter_async_context(face)
            fleet.faces.append(face)
            fleet.starved.append(0.0)
        fleet.ticker = asyncio.create_task(tick(), name="dnc-sim:tick")
        fleet.lags = []
        fleet.prober = asyncio.create_task(probe(), name="dnc-sim:lag")
        return {"urls": [f.socket_url for f in fleet.faces]}

    def mark(_request: dict[str, Any]) -> dict[str, Any]:
        for i, face in enumerate(fleet.faces):
            face.timed = Timed(rx_seen=face.controller.stats.rx_chars)
            face.overruns = face.highest = face.overruns_late_dc3 = face.overruns_bunched = 0
            face.bunched_reads = 0
            face.dc3_late.clear()
            fleet.starved[i] = 0.0
            face.machine.starvations = 0
            face.controller.episodes.clear()
            face.in_flight.clear()
            face.sent_after.clear()
            face.holds.clear()
        fleet.lags = []
        return {}

    def stats(_request: dict[str, Any]) -> dict[str, Any]:
        out = []
        for i, face in enumerate(fleet.faces):
            s = face.stats()
            episodes = s.pop("after_dc3_episodes")
            out.append(
                {
                    **s,
                    "after_dc3": percentiles([float(e) for e in episodes]),
                    "episodes": len(episodes),
                    "in_flight_at_dc3": percentiles([float(n) for n in face.in_flight]),
                    "in_flight_each": list(face.in_flight),
                    "sent_after_dc3": percentiles([float(n) for n in face.sent_after]),
                    "holds": [[t if t != math.inf else None for t in hold] for hold in face.holds],
                    "first": face.timed.first,
                    "last": face.timed.last,
                    "chars": face.timed.chars,
                    "rx_first": face.timed.rx_first,
                    "rx_last": face.timed.rx_last,
                    "starved_seconds": fleet.starved[i],
                    "machine": face.machine.state.name,
                    "overruns": face.overruns,
                    "overruns_late_dc3": face.overruns_late_dc3,
                    "overruns_bunched": face.overruns_bunched,
                    "bunched_reads": face.bunched_reads,
                    "dc3_late_ms": percentiles([late * 1000.0 for late in face.dc3_late]),
                    "dc3_late_beyond_headroom": sum(
                        1
                        for late in face.dc3_late
                        if face.overrun_at is not None
                        and late > (face.overrun_at - face.controller.spec.high) / face.controller.rate
                    ),
                    "highest": face.highest,
                }
            )
        lags = [lag * 1000.0 for lag in fleet.lags]
        late = {f"over_{ms}_ms": sum(1 for lag in lags if lag > ms) for ms in (10, 20, 40)}
        return {"faces": out, "loop_lag_ms": {**percentiles(lags), **late}}

    async def teardown(_request: dict[str, Any]) -> dict[str, Any]:
        for task in (fleet.ticker, fleet.prober):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        fleet.ticker = fleet.prober = None
        if fleet.stack is not None:
            await fleet.stack.aclose()
            fleet.stack = None
        fleet.faces = []
        return {}

    try:
        await serve({"setup": setup, "mark": mark, "stats": stats, "teardown": teardown})
    finally:
        await teardown({})


def _each(value: Any, count: int) -> list[Any]:
    """One value per face: a list as it is, anything else repeated."""
    if isinstance(value, list):
        if len(value) != count:
            raise ValueError(f"{len(value)} values for {count} faces")
        return value
    return [value] * count


if __name__ == "__main__":
    argparse.ArgumentParser().parse_args()
    setup_logging()
    asyncio.run(main())
