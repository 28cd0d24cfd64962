"""Drip-feed scheduling for many machines: who is served next, and with how many bytes (pure).

The network-DNC patent's idea: size each transmission by the run time of the
G-code it carries (t = s / v per block), so that every machine has data before
it runs dry. Here each line's controller should always hold at least
`lead_time` seconds of cutting; the line whose buffer will run dry first is
served first (earliest dry first); lines that share a device server or uplink
with a configured capacity share it by that same rule.

The scheduler keeps a model of each controller: the blocks granted, when each
arrives (the chunk's last byte, at the slower of the line and the link), and
when each finishes executing (in order, each starting when it has arrived and
its predecessor is done). From it:

- `ahead(key, now)`: seconds of cutting the controller holds;
- `buffered(key, now)`: bytes it holds not yet executed (a block's bytes count
  until it has finished, and bytes on their way count at once: a conservative
  view that never overruns the buffer);
- `next_grant(now)`: one chunk for the most urgent eligible line, of whole
  blocks where possible, at most `max_chunk` bytes and never more than the
  buffer has room for, filled until the line holds `target` seconds;
- `wake_at(now)`: when calling again may give something.

The caller sends what it is granted, tells `start(key, now)` when the machine
starts executing (cycle start), and `set_paused(key, ...)` while a DC3 holds the
line. The model is an estimate (feed override, acceleration); the controller's
DC1 says what it really holds, and `resync(key, now, holds)` puts the model right.
Time is whatever monotonic clock the caller uses, in seconds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from gateway.codecs.dnc.framing import WireProgram


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
    `lead_time`: this line's own lead (default: the scheduler's).
    """

    key: str
    rate: float
    buffer_size: int
    blocks: Sequence[BlockCost]
    link: str | None = None
    lead_time: float | None = None


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
        self._lines[line.key] = _Line(line, target=target)

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
            item.finishes = max(item.arrives, line.exec_end) + item.seconds
            line.exec_end = item.finishes
            line.executed_any = True

    def set_paused(self, key: str, paused: bool) -> None:
        """A DC3 holds this line (True) until its DC1 (False): it gets no grants meanwhile."""
        self._lines[key].paused = paused

    def resync(self, key: str, now: float, holds: int = 0) -> None:
        """The controller says it holds about `holds` bytes (its DC1: down to its low level): granted blocks
        beyond those count as executed, the rest run from now. A machine that cut faster than the
        estimate is served again at once; one that cut slower has already held the line with DC3."""
        line = self._lines[key]
        self._expire(line, now)
        queue = line.queue
        while queue and line.partial + line.queued > max(0, holds):
            line.queued -= queue.popleft().size
        if not line.started:
            line.started = True
            line.executed_any = bool(queue)
        line.exec_end = now
        for item in queue:
            item.finishes = max(item.arrives, line.exec_end) + item.seconds
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

    def _eligible(self, line: _Line, now: float) -> bool:
        if line.finished_sending or line.paused or line.free_at > now:
            return False
        link = line.spec.link
        if link is not None and self._link_free.get(link, -math.inf) > now:
            return False
        if self._ahead(line, now) >= line.target:
            return False
        room = line.spec.buffer_size - self.buffered(line.spec.key, now)
        return room >= self._need(line)

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
        limit = min(self.max_chunk, spec.buffer_size - self.buffered(spec.key, now))
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
            if ahead + seconds >= line.target:
                break
        rate = self._rate(line)
        arrives = now + size / rate
        line.free_at = now + size / spec.rate
        if spec.link is not None:
            self._link_free[spec.link] = now + size / self.links[spec.link]
        for block_size, block_seconds in whole:
            self._append(line, block_size, block_seconds, arrives)
        line.cursor += len(whole)
        if whole:
            line.partial = 0
        line.partial += partial_added
        return Grant(spec.key, size, len(whole), seconds, arrives)

    def _append(self, line: _Line, size: int, seconds: float, arrives: float) -> None:
        finishes: float | None = None
        if line.started:
            if line.executed_any and arrives > line.exec_end:
                line.starvations += 1
            finishes = max(arrives, line.exec_end) + seconds
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
