"""Drip-feed scheduling for many machines: who is served next, and with how many bytes (pure).

The network-DNC patent's idea: size each transmission by the run time of the
G-code it carries (t = s / v per block), so that every machine has data before
it runs dry. The line whose buffer will run dry first is served first (earliest
dry first); lines that share a device server or uplink with a configured capacity
share it by that rule.

Work-conserving. A line whose controller does flow control (DC1/DC3, or RTS/CTS)
is never held back for the model's sake: whenever its line and its link are free
it is served, and the controller's DC3 says when its buffer is full. The model
only decides the order when lines compete for a shared link. Only a line without
any flow control (`flow_control=False`) is fed by the model alone: never more
than its buffer has room for, filled to `target` seconds of cutting.

The scheduler keeps a model of each controller: the blocks granted, when each
arrives (the chunk's last byte, at the slower of the line and the link), and
when each finishes executing (in order, each starting when it has arrived and
its predecessor is done, at the line's learned `speed` times the estimate). From it:

- `ahead(key, now)`: seconds of cutting the controller holds;
- `buffered(key, now)`: bytes it holds not yet executed (never more than its
  buffer: bytes sent beyond what the model had room for, with no DC3, prove the
  machine ran faster, and the oldest count as executed);
- `next_grant(now)`: one chunk for the most urgent eligible line;
- `wake_at(now)`: when calling again may give something.

The controller is the authority. The caller tells `start(key, now)` when the
machine starts executing, `dc3(key, now, written)` at its DC3 and `dc1(key, now,
written)` at its DC1 (`written`: bytes written to the line so far). A DC1 puts the
model right (the controller is down to its DC1 level, `low_level`) and, from one
DC1 to the next, teaches the line's speed: the run time the estimate gave the bytes
the controller took over the cycle, over the cycle's real length. A machine faster
than its estimate (feed override, rapids faster than the mapping's `rapid`) is
learned at once: the cycle can only underestimate it (a machine that waited for
data took less). A slower one is learned gradually, and only from cycles whose
filling was not held up by other lines. Time is whatever monotonic clock the
caller uses, in seconds.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from gateway.codecs.dnc.framing import WireProgram

#: Bounds of a learned speed (the machine's pace over the estimate's).
MIN_SPEED = 1 / 16
MAX_SPEED = 64.0
#: How far one cycle moves a speed down (up moves at once).
SLOWER_WEIGHT = 0.25
#: A cycle whose filling went at this share of the line's rate or more was held up by nothing.
UNHINDERED = 0.8
#: The smallest grant a line with flow control gets when the model thinks its buffer full.
PROBE = 32
#: Seconds of idle time a line or a link may make up for (see `_grant`).
SLACK = 0.005


@dataclass(frozen=True, slots=True)
class BlockCost:
    """One block on the wire: its bytes (line end included) and its run time in seconds."""

    size: int
    seconds: float


def program_costs(wire: WireProgram, times: Mapping[int, float]) -> tuple[BlockCost, ...]:
    """The cost of each block of a framed program; leader and opening `%` go with the first block,
    the closing `%` with the last. `times` maps source lines to seconds (runtime.block_times)."""
    if not wire.starts:
        return (BlockCost(len(wire.data), 0.0),) if wire.data else ()
    ends = (*wire.starts[1:], len(wire.data))
    costs = []
    for index, (start, end, number) in enumerate(zip(wire.starts, ends, wire.numbers, strict=True)):
        begin = 0 if index == 0 else start
        costs.append(BlockCost(end - begin, times.get(number, 0.0)))
    return tuple(costs)


@dataclass(frozen=True, slots=True)
class DripLine:
    """One machine's serial line as the scheduler sees it.

    `rate`: characters per second of the line (LineSettings.bytes_per_second);
    `buffer_size`: bytes the controller takes without holding the sender back
    (its DC3 level); `link`: the shared device server or uplink it goes through, if any;
    `lead_time`: this line's own lead (default: the scheduler's); `flow_control`: the controller
    holds the line back itself (DC1/DC3 or RTS/CTS), so the line is served whenever it is free.
    """

    key: str
    rate: float
    buffer_size: int
    blocks: Sequence[BlockCost]
    link: str | None = None
    lead_time: float | None = None
    flow_control: bool = True


@dataclass(frozen=True, slots=True)
class Grant:
    """Send `size` bytes to line `key` now: `blocks` whole blocks carrying `seconds` of run time.

    `arrives` is when the last byte reaches the controller (the model's view).
    """

    key: str
    size: int
    blocks: int
    seconds: float
    arrives: float


@dataclass(slots=True)
class _Granted:
    size: int
    seconds: float
    arrives: float
    finishes: float | None  # None until the machine has started


@dataclass(slots=True)
class _Line:
    spec: DripLine
    cursor: int = 0  # next block to grant
    partial: int = 0  # bytes of that block already granted
    free_at: float = -math.inf  # the serial line is busy sending until then
    started: bool = False
    exec_end: float = 0.0  # when the last granted block finishes (once started)
    paused: bool = False
    starvations: int = 0
    executed_any: bool = False
    last_served: float = -math.inf
    target: float = math.inf  # seconds of cutting it is filled to
    queued: int = 0  # bytes of the granted blocks in `queue`
    queue: deque[_Granted] = field(default_factory=deque)
    speed: float = 1.0  # the machine's pace over the estimate's, learned from DC1 to DC1
    ends: list[int] = field(default_factory=list)  # byte offset after each block
    secs: list[float] = field(default_factory=list)  # estimated seconds up to the end of each block
    cycle: tuple[float, int] | None = None  # (time, written) at the last DC1
    filled: tuple[float, int] | None = None  # (time, written) at the DC3 after it
    cycles: int = 0  # DC1s seen

    @property
    def low(self) -> int:
        """The bytes a controller is taken to hold at its DC1: a quarter of its buffer (Fanuc sends DC1
        well before its buffer is empty). The order of lines that just sent DC1 depends on it, not
        whether they are served."""
        return self.spec.buffer_size // 4

    @property
    def high(self) -> int:
        """The bytes a controller is taken to hold at its DC3: all but an eighth of its buffer (room for
        what a sender still sends after it)."""
        return self.spec.buffer_size - self.spec.buffer_size // 8

    def seconds_at(self, offset: int) -> float:
        """The estimate's run time of the program's first `offset` bytes (linear within a block)."""
        if offset <= 0 or not self.ends:
            return 0.0
        index = bisect.bisect_right(self.ends, offset)
        if index >= len(self.ends):
            return self.secs[-1]
        begin = self.ends[index - 1] if index else 0
        before = self.secs[index - 1] if index else 0.0
        size = self.ends[index] - begin
        return before + (self.secs[index] - before) * (offset - begin) / size

    @property
    def finished_sending(self) -> bool:
        return self.cursor >= len(self.spec.blocks)


class DripScheduler:
    """Earliest-dry-first service of drip-fed lines, with optional shared link capacities."""

    def __init__(
        self,
        *,
        lead_time: float,
        target: float | None = None,
        links: Mapping[str, float] | None = None,
        max_chunk: int = 200,
    ) -> None:
        if lead_time <= 0:
            raise ValueError("lead_time must be > 0 s")
        if max_chunk < 1:
            raise ValueError("max_chunk must be >= 1 byte")
        self.lead_time = lead_time
        self.target = 2 * lead_time if target is None else target
        if self.target < lead_time:
            raise ValueError("target must be >= lead_time")
        self.links = dict(links or {})
        for name, capacity in self.links.items():
            if capacity <= 0:
                raise ValueError(f"link {name!r}: capacity must be > 0 bytes/s")
        self.max_chunk = max_chunk
        self._lines: dict[str, _Line] = {}
        self._link_free: dict[str, float] = {}

    # --- lines -----------------------------------------------------------------------------------

    def add(self, line: DripLine) -> None:
        if line.key in self._lines:
            raise ValueError(f"line {line.key!r} is already scheduled")
        if line.rate <= 0 or line.buffer_size < 1:
            raise ValueError(f"line {line.key!r}: rate and buffer size must be > 0")
        if line.link is not None and line.link not in self.links:
            raise ValueError(f"line {line.key!r}: unknown link {line.link!r}")
        for index, block in enumerate(line.blocks):
            if block.size > line.buffer_size:
                raise ValueError(
                    f"line {line.key!r}: block {index + 1} ({block.size} bytes) is longer than the "
                    f"controller's buffer ({line.buffer_size} bytes): it cannot be drip-fed"
                )
        if line.lead_time is not None and line.lead_time <= 0:
            raise ValueError(f"line {line.key!r}: lead_time must be > 0 s")
        target = self.target if line.lead_time is None else self.target / self.lead_time * line.lead_time
        state = _Line(line, target=target)
        state.ends = list(itertools.accumulate(block.size for block in line.blocks))
        state.secs = list(itertools.accumulate(block.seconds for block in line.blocks))
        self._lines[line.key] = state

    def remove(self, key: str) -> None:
        self._lines.pop(key, None)

    def keys(self) -> list[str]:
        return list(self._lines)

    def start(self, key: str, now: float) -> None:
        """The machine started executing (cycle start): the blocks it holds begin to run now."""
        line = self._lines[key]
        if line.started:
            return
        line.started = True
        line.exec_end = now
        for item in line.queue:
            item.finishes = max(item.arrives, line.exec_end) + item.seconds / line.speed
            line.exec_end = item.finishes
            line.executed_any = True

    def set_paused(self, key: str, paused: bool) -> None:
        """A DC3 holds this line (True) until its DC1 (False): it gets no grants meanwhile."""
        self._lines[key].paused = paused

    def dc3(self, key: str, now: float, written: int) -> None:
        """The controller's DC3 after `written` bytes: its buffer is at its DC3 level; no grants until DC1."""
        line = self._lines[key]
        line.paused = True
        if line.filled is None:
            line.filled = (now, written)

    def dc1(self, key: str, now: float, written: int) -> None:
        """The controller's DC1 after `written` bytes: it is down to its DC1 level. Learns the line's speed
        from the cycle since the last DC1, then puts the model right (`resync`) and serves the line."""
        line = self._lines[key]
        line.paused = False
        self._learn(line, now, written)
        line.cycle = (now, written)
        line.filled = None
        line.cycles += 1
        self.resync(key, now, line.low)

    def _learn(self, line: _Line, now: float, written: int) -> None:
        if line.cycles < 2 and line.filled is not None:
            # The first cycle holds the machine's start, so it says little; its pause says more: from the
            # DC3 to the DC1 the controller went from its DC3 level to its DC1 level, held by nothing.
            paused_at, at_dc3 = line.filled
            took = line.seconds_at(written - line.low) - line.seconds_at(at_dc3 - line.high)
            if took > 0 and now > paused_at:
                line.speed = min(MAX_SPEED, max(line.speed, took / (now - paused_at)))
        if line.cycle is None:
            return
        then, before = line.cycle
        took = line.seconds_at(written - line.low) - line.seconds_at(before - line.low)
        if took <= 0 or now <= then:
            return  # nothing timed went through the machine: no evidence either way
        seen = took / (now - then)
        if seen > line.speed:
            line.speed = min(seen, MAX_SPEED)  # a lower bound of the truth: taken at once
            return
        if line.cycles < 2 or line.filled is None:
            return  # the first cycle holds the machine's start; a cycle without DC3 is not whole
        filled_at, filled = line.filled
        pace = (filled - before) / max(filled_at - then, 1e-9)
        if pace >= UNHINDERED * self._rate(line):
            line.speed = max(MIN_SPEED, line.speed + SLOWER_WEIGHT * (seen - line.speed))

    def speed(self, key: str) -> float:
        """The machine's pace over the estimate's, as learned (1.0 until a DC1 cycle says otherwise)."""
        return self._lines[key].speed

    def resync(self, key: str, now: float, holds: int = 0) -> None:
        """The controller says it holds about `holds` bytes: granted blocks beyond those count as executed,
        the rest run from now at the line's speed."""
        line = self._lines[key]
        self._expire(line, now)
        self._rebase(line, now, holds)

    def _rebase(self, line: _Line, now: float, holds: int) -> None:
        queue = line.queue
        while queue and line.partial + line.queued > max(0, holds):
            line.queued -= queue.popleft().size
        if not line.started:
            line.started = True
            line.executed_any = bool(queue)
        line.exec_end = now
        for item in queue:
            item.finishes = max(item.arrives, line.exec_end) + item.seconds / line.speed
            line.exec_end = item.finishes

    # --- the model -------------------------------------------------------------------------------

    def _expire(self, line: _Line, now: float) -> None:
        queue = line.queue
        while queue and queue[0].finishes is not None and queue[0].finishes <= now:
            line.queued -= queue.popleft().size

    def ahead(self, key: str, now: float) -> float:
        """Seconds of cutting the controller holds (granted blocks not yet executed)."""
        line = self._lines[key]
        return self._ahead(line, now)

    def _ahead(self, line: _Line, now: float) -> float:
        if not line.started:
            return sum(item.seconds for item in line.queue)
        return max(0.0, line.exec_end - now)

    def buffered(self, key: str, now: float) -> int:
        """Bytes the controller holds or will hold from what was granted, not yet executed."""
        line = self._lines[key]
        self._expire(line, now)
        return line.partial + line.queued

    def starvations(self, key: str) -> int:
        """How often the model's machine waited for data after it had started."""
        return self._lines[key].starvations

    def done(self, key: str) -> bool:
        """Everything was granted."""
        return self._lines[key].finished_sending

    # --- decisions -------------------------------------------------------------------------------

    def _rate(self, line: _Line) -> float:
        link = line.spec.link
        return line.spec.rate if link is None else min(line.spec.rate, self.links[link])

    def _need(self, line: _Line) -> int:
        """The smallest grant worth making: the rest of the current block, bounded."""
        piece = line.spec.blocks[line.cursor].size - line.partial
        return max(1, min(piece, self.max_chunk, max(1, line.spec.buffer_size // 4)))

    def _room(self, line: _Line, now: float) -> int:
        """What a grant may be now: the buffer's room in the model; at least a probe's worth on a line whose
        controller says itself when it is full (its DC3 is the authority, not the model)."""
        spec = line.spec
        room = spec.buffer_size - self.buffered(spec.key, now)
        if spec.flow_control:
            room = max(room, self._need(line), min(PROBE, spec.buffer_size // 8))
        if spec.link is not None:
            # A shared link is handed out in small pieces, so that the most urgent line is looked for
            # again soon: a quarter of the buffer (the DC1 level's worth) at a time.
            room = min(room, max(self._need(line), spec.buffer_size // 4))
        return min(self.max_chunk, room)

    def _eligible(self, line: _Line, now: float) -> bool:
        if line.finished_sending or line.paused or line.free_at > now:
            return False
        link = line.spec.link
        if link is not None and self._link_free.get(link, -math.inf) > now:
            return False
        if line.spec.flow_control:
            return True  # work-conserving: the controller's DC3 says when it is full
        if self._ahead(line, now) >= line.target:
            return False
        return self._room(line, now) >= self._need(line)

    def next_grant(self, now: float) -> Grant | None:
        """A chunk for the eligible line that runs dry first, or None (see `wake_at`).

        Lines equally close to dry (all of them, on a link too slow for everyone) are
        served least recently served first, so that they share the shortage alike.
        """
        best: _Line | None = None
        best_key = (math.inf, math.inf)
        for line in self._lines.values():
            if not self._eligible(line, now):
                continue
            key = (self._ahead(line, now), line.last_served)
            if best is None or key < best_key:
                best, best_key = line, key
        if best is None:
            return None
        best.last_served = now
        return self._grant(best, now, best_key[0])

    def _grant(self, line: _Line, now: float, ahead: float) -> Grant:
        spec = line.spec
        limit = self._room(line, now)
        size = 0
        seconds = 0.0
        whole: list[tuple[int, float]] = []  # (bytes, seconds) of the blocks this grant completes
        partial_added = 0
        while line.cursor + len(whole) < len(spec.blocks):
            block = spec.blocks[line.cursor + len(whole)]
            piece = block.size - (line.partial if not whole else 0)
            if size + piece > limit:
                if size == 0:
                    partial_added = limit  # a block longer than a chunk goes in pieces
                    size = limit
                break
            size += piece
            seconds += block.seconds
            whole.append((block.size, block.seconds))
            if ahead + seconds >= line.target and not spec.flow_control:
                break
        rate = self._rate(line)
        arrives = now + size / rate
        # Time a line or link stood idle because the caller came back late (a thread's wake-up) is
        # credited, up to SLACK: otherwise every late wake-up would be capacity lost for good.
        line.free_at = _resume(line.free_at, now) + size / spec.rate
        if spec.link is not None:
            free = self._link_free.get(spec.link, -math.inf)
            self._link_free[spec.link] = _resume(free, now) + size / self.links[spec.link]
        for block_size, block_seconds in whole:
            self._append(line, now, block_size, block_seconds, arrives)
        line.cursor += len(whole)
        if whole:
            line.partial = 0
        line.partial += partial_added
        return Grant(spec.key, size, len(whole), seconds, arrives)

    def _append(self, line: _Line, now: float, size: int, seconds: float, arrives: float) -> None:
        if line.started and line.partial + line.queued + size > line.spec.buffer_size:
            # Sent beyond the model's room with no DC3: the machine ran faster than the model says.
            self._rebase(line, now, line.spec.buffer_size - size)
        finishes: float | None = None
        if line.started:
            if line.executed_any and arrives > line.exec_end:
                line.starvations += 1
            finishes = max(arrives, line.exec_end) + seconds / line.speed
            line.exec_end = finishes
            line.executed_any = True
        line.queue.append(_Granted(size, seconds, arrives, finishes))
        line.queued += size

    def wake_at(self, now: float, key: str | None = None) -> float | None:
        """The earliest time after `now` when `next_grant` may give something (to line `key` alone, when
        given), None if never (until a `start`, `resync` or `set_paused` changes the picture)."""
        lines = self._lines.values() if key is None else [self._lines[key]]
        best: float | None = None
        for line in lines:
            when = self._line_wake(line, now)
            if when is not None and when > now and (best is None or when < best):
                best = when
        return best

    def _line_wake(self, line: _Line, now: float) -> float | None:
        if line.finished_sending or line.paused:
            return None
        when = max(now, line.free_at)
        link = line.spec.link
        if link is not None:
            when = max(when, self._link_free.get(link, -math.inf))
        if line.spec.flow_control:
            return when
        if self._ahead(line, now) >= line.target:
            if not line.started:
                return None  # holds enough until its machine starts
            # Strictly after: at exec_end - target the line holds exactly the target, not less.
            when = max(when, line.exec_end - line.target)
            if when <= now:
                when = now + 1e-9 * max(1.0, abs(now))
        self._expire(line, now)
        room = line.spec.buffer_size - self.buffered(line.spec.key, now)
        need = self._need(line)
        if room < need:
            freed = room
            for item in line.queue:  # finish times are in order
                if item.finishes is None:
                    return None
                freed += item.size
                if freed >= need:
                    return max(when, item.finishes)
            return None
        return when


def _resume(free: float, now: float) -> float:
    """When a line or link that was free at `free` starts its next piece, granted at `now`: where it would
    have been, had the caller come back in time (up to SLACK late), else now."""
    return free if now - SLACK <= free < now else now
