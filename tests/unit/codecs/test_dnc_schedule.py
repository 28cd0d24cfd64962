"""The drip scheduler, against a machine model of its own in simulated time.

The first part feeds lines whose controllers do no flow control (`flow_control=False`): the model alone
keeps their buffers from overrunning. The last part (`Controller`) simulates DC3/DC1 and machines that cut
faster or slower than the estimate: the work-conserving lines of issue 22.

`replay` below does not trust the scheduler's bookkeeping: from the grants alone
it works out when each block arrives, when each machine runs it, what each
buffer holds, and whether a machine ever waited for data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gateway.codecs.dnc import (
    BlockCost,
    DripLine,
    DripScheduler,
    Grant,
    LineSettings,
    block_times,
    frame_program,
    program_costs,
)


@dataclass
class Outcome:
    grants: list[tuple[float, Grant]] = field(default_factory=list)
    starts: dict[str, float] = field(default_factory=dict)


def run(
    sched: DripScheduler, lines: list[DripLine], *, horizon: float = 1e6, max_steps: int = 200_000
) -> Outcome:
    """Drive the scheduler in simulated time; start each machine once it holds lead_time (or everything)."""
    for line in lines:
        sched.add(line)
    out = Outcome()
    now = 0.0
    for _ in range(max_steps):
        while (grant := sched.next_grant(now)) is not None:
            out.grants.append((now, grant))
        for line in lines:
            if line.key not in out.starts and (
                sched.ahead(line.key, now) >= sched.lead_time or sched.done(line.key)
            ):
                sched.start(line.key, now)
                out.starts[line.key] = now
        wake = sched.wake_at(now)
        if wake is None or wake > horizon:
            break
        assert wake > now
        now = wake
    return out


@dataclass
class Replay:
    starvations: dict[str, int]
    max_buffered: dict[str, int]
    finished: dict[str, float]
    sent_blocks: dict[str, list[int]]  # blocks complete after each grant, per line


def replay(lines: list[DripLine], out: Outcome, links: dict[str, float]) -> Replay:
    by_key = {line.key: line for line in lines}
    arrivals: dict[str, list[tuple[float, float]]] = {k: [] for k in by_key}  # (granted at, arrives)
    grant_times: dict[str, list[tuple[float, int]]] = {k: [] for k in by_key}  # (time, bytes granted so far)
    sent_bytes = dict.fromkeys(by_key, 0)
    sent_blocks: dict[str, list[int]] = {k: [] for k in by_key}
    for when, grant in out.grants:
        line = by_key[grant.key]
        rate = line.rate if line.link is None else min(line.rate, links[line.link])
        arrives = when + grant.size / rate
        sent_bytes[grant.key] += grant.size
        # Every block whose last byte is within what was sent so far is now complete.
        total = 0
        complete = 0
        for block in line.blocks:
            total += block.size
            if total > sent_bytes[grant.key]:
                break
            complete += 1
        arrivals[grant.key].extend([(when, arrives)] * (complete - len(arrivals[grant.key])))
        grant_times[grant.key].append((when, sent_bytes[grant.key]))
        sent_blocks[grant.key].append(complete)
    starvations = {}
    max_buffered = {}
    finished = {}
    for key, line in by_key.items():
        assert len(arrivals[key]) == len(line.blocks), f"{key}: not every block was sent"
        start = out.starts[key]
        end = start
        finishes = []
        waits = 0
        for (granted, arrive), block in zip(arrivals[key], line.blocks, strict=True):
            # A machine that has run something waits for a block granted after it started: starvation.
            if granted > start and finishes and arrive > end:
                waits += 1
            end = max(arrive, end) + block.seconds
            finishes.append(end)
        starvations[key] = waits
        finished[key] = finishes[-1]
        # Buffer: bytes granted minus bytes of blocks finished, at every grant.
        worst = 0
        for when, granted_bytes in grant_times[key]:
            done = sum(b.size for b, f in zip(line.blocks, finishes, strict=True) if f <= when)
            worst = max(worst, granted_bytes - done)
        max_buffered[key] = worst
    return Replay(starvations, max_buffered, finished, sent_blocks)


# --- simple cases ---------------------------------------------------------------------------------


def test_one_line_is_fed_by_run_time_not_by_bytes() -> None:
    blocks = [BlockCost(20, 1.0)] * 100  # 20 bytes that run for a second each
    sched = DripScheduler(lead_time=5.0, max_chunk=200)
    sched.add(DripLine("a", rate=1000.0, buffer_size=256, blocks=blocks, flow_control=False))
    first = sched.next_grant(0.0)
    assert first is not None
    # Fill to target = 2 x lead_time = 10 s: ten blocks, 200 bytes.
    assert (first.size, first.blocks, first.seconds) == (200, 10, pytest.approx(10.0))
    assert sched.next_grant(0.0) is None  # the line is busy sending
    sched.start("a", 0.0)
    assert sched.ahead("a", 0.2) == pytest.approx(10.0)  # arrived at 0.2 s, runs 0.2 .. 10.2
    assert sched.next_grant(0.2) is None  # holds more than the target
    wake = sched.wake_at(0.2)
    assert wake is not None and wake == pytest.approx(0.2)  # as soon as it holds less than the target
    grant = sched.next_grant(wake)
    assert grant is not None and grant.blocks == 1 and grant.seconds == pytest.approx(1.0)
    assert sched.buffered("a", wake) == 220
    assert sched.next_grant(0.3) is None  # 11 s ahead again
    assert sched.buffered("a", 1.2) == 200  # the first block has run: its bytes are free


def test_grants_never_exceed_the_buffer_and_long_blocks_go_in_pieces() -> None:
    blocks = [BlockCost(250, 10.0), BlockCost(10, 1.0)]
    sched = DripScheduler(lead_time=1.0, max_chunk=200)
    sched.add(DripLine("a", rate=10_000.0, buffer_size=300, blocks=blocks, flow_control=False))
    sched.start("a", 0.0)
    sizes = []
    now = 0.0
    while not sched.done("a"):
        grant = sched.next_grant(now)
        if grant is None:
            wake = sched.wake_at(now)
            assert wake is not None
            now = wake
            continue
        assert sched.buffered("a", now) <= 300
        sizes.append((grant.size, grant.blocks))
    assert sizes[0] == (200, 0)  # max_chunk: the rest of the block follows
    assert sum(s for s, _ in sizes) == 260
    with pytest.raises(ValueError, match="longer than the controller's buffer"):
        sched.add(DripLine("b", rate=1.0, buffer_size=100, blocks=[BlockCost(101, 1.0)]))


def test_earliest_dry_first_and_shared_link() -> None:
    slow = [BlockCost(10, 0.1)] * 50
    fast = [BlockCost(10, 5.0)] * 50
    sched = DripScheduler(lead_time=1.0, links={"nport": 100.0}, max_chunk=50)
    sched.add(
        DripLine("cutting-fast", rate=1000.0, buffer_size=256, blocks=slow, link="nport", flow_control=False)
    )
    sched.add(
        DripLine("cutting-slow", rate=1000.0, buffer_size=256, blocks=fast, link="nport", flow_control=False)
    )
    sched.start("cutting-fast", 0.0)
    sched.start("cutting-slow", 0.0)
    first = sched.next_grant(0.0)
    assert first is not None
    # Both are dry; the tie goes to the first added. Then the link is busy for 50 bytes / 100 B/s.
    assert sched.next_grant(0.0) is None
    assert sched.wake_at(0.0) == pytest.approx(first.size / 100.0)
    second = sched.next_grant(sched.wake_at(0.0) or 0.0)
    assert second is not None and second.key != first.key


def test_refuses_bad_configuration() -> None:
    with pytest.raises(ValueError, match="lead_time"):
        DripScheduler(lead_time=0)
    with pytest.raises(ValueError, match="target"):
        DripScheduler(lead_time=2, target=1)
    sched = DripScheduler(lead_time=1, links={"a": 10})
    with pytest.raises(ValueError, match="unknown link"):
        sched.add(DripLine("x", 100, 100, [], link="b"))
    sched.add(DripLine("x", 100, 100, []))
    with pytest.raises(ValueError, match="already"):
        sched.add(DripLine("x", 100, 100, []))


def test_costs_of_a_real_program() -> None:
    text = b"%\nO1\nG21 G90\nG0 X100\nG1 X200 F600\nM30\n%\n"
    line = LineSettings(baud=9600, leader=10)
    wire = frame_program(text, line)
    costs = program_costs(wire, block_times(text.decode(), rapid=6000))
    assert sum(c.size for c in costs) == len(wire.data)
    assert costs[0].size == 10 + 2 + 3  # leader, "%\n", "O1\n"
    assert [c.seconds for c in costs] == pytest.approx([0, 0, 1.0, 10.0, 0])


# --- properties -----------------------------------------------------------------------------------


@st.composite
def fleets(draw: st.DrawFn, *, sufficient: bool) -> tuple[list[DripLine], dict[str, float], float, int]:
    k = draw(st.integers(1, 6))
    capacity = draw(st.sampled_from([2_000.0, 5_000.0, 20_000.0]))
    max_chunk = draw(st.sampled_from([64, 128, 200]))
    rates = [draw(st.sampled_from([480.0, 960.0, 3_840.0, 11_520.0])) for _ in range(k)]
    lines = []
    share = 4 * k if sufficient else 1
    slowest = min(*rates, capacity)
    worst_block = 0.0
    worst_demand = 0.0
    programs = []
    for index in range(k):
        eff = min(rates[index], capacity)
        n = draw(st.integers(5, 60))
        blocks = []
        for _ in range(n):
            size = draw(st.integers(8, 60))
            # With enough capacity, each block runs long enough for its bytes to arrive `share` times over.
            floor = size * share / eff if sufficient else 0.0
            seconds = floor + draw(st.floats(0.0, 2.0))
            blocks.append(BlockCost(size, seconds))
            worst_block = max(worst_block, seconds)
            worst_demand = max(worst_demand, size / max(seconds, 1e-9))
        programs.append(blocks)
    lead = 2 * (k * max_chunk / capacity + max_chunk / slowest) + worst_block + 0.5
    for index, blocks in enumerate(programs):
        room = int(2 * lead * min(worst_demand, rates[index]) + 3 * max_chunk + 60)
        lines.append(DripLine(f"m{index}", rates[index], room, blocks, link="nport", flow_control=False))
    return lines, {"nport": capacity}, lead, max_chunk


@given(fleets(sufficient=True))
@settings(max_examples=150, deadline=None)
def test_no_starvation_and_no_overrun_when_capacity_suffices(
    case: tuple[list[DripLine], dict[str, float], float, int],
) -> None:
    lines, links, lead, max_chunk = case
    sched = DripScheduler(lead_time=lead, links=links, max_chunk=max_chunk)
    out = run(sched, lines)
    result = replay(lines, out, links)
    for line in lines:
        assert result.max_buffered[line.key] <= line.buffer_size, f"{line.key} overrun"
        assert result.starvations[line.key] == 0, f"{line.key} starved"
        assert sched.starvations(line.key) == 0


@given(fleets(sufficient=False))
@settings(max_examples=150, deadline=None)
def test_buffers_are_never_overrun_whatever_the_load(
    case: tuple[list[DripLine], dict[str, float], float, int],
) -> None:
    lines, links, lead, max_chunk = case
    sched = DripScheduler(lead_time=lead, links=links, max_chunk=max_chunk)
    out = run(sched, lines)
    result = replay(lines, out, links)
    for line in lines:
        assert result.max_buffered[line.key] <= line.buffer_size
        # The scheduler's own count of starvations agrees with the independent replay.
        assert sched.starvations(line.key) == result.starvations[line.key]


@given(
    st.integers(2, 6),
    st.integers(20, 80),
    st.integers(10, 40),
    st.floats(0.05, 1.0),
)
@settings(max_examples=100, deadline=None)
def test_identical_machines_on_a_short_link_share_it_fairly(
    k: int, n: int, size: int, seconds: float
) -> None:
    """k identical machines whose total demand exceeds the link: they all starve alike, none falls behind."""
    demand = size / seconds
    capacity = demand * k / 2  # half of what they need together
    assume(capacity >= 10)
    blocks = [BlockCost(size, seconds)] * n
    max_chunk = 4 * size
    lines = [
        DripLine(f"m{i}", 10 * capacity, 10 * max_chunk, blocks, link="uplink", flow_control=False)
        for i in range(k)
    ]
    sched = DripScheduler(lead_time=2 * seconds, links={"uplink": capacity}, max_chunk=max_chunk)
    out = run(sched, lines)
    # Each grant goes to a line that is no better off than any other with data to come.
    blocks_sent = {line.key: 0 for line in lines}
    for _when, grant in out.grants:
        blocks_sent[grant.key] += grant.blocks
        behind = [blocks_sent[key] for key in blocks_sent if blocks_sent[key] < n]
        if behind:
            assert max(blocks_sent.values()) - min(behind) <= max_chunk // size + 1
    result = replay(lines, out, {"uplink": capacity})
    finish = sorted(result.finished.values())
    assert finish[-1] - finish[0] <= (max_chunk / capacity) * k + 2 * seconds + 1e-6
    assert not math.isinf(finish[-1])


# --- the controller's word: DC1 resynchronises, a line's own lead --------------------------------


def test_resync_on_dc1_frees_what_the_controller_ran_faster_than_estimated() -> None:
    """The model thought the buffer full (estimated 1 s a block); the controller's DC1 says it is down to
    its low level: the line is served again at once, with the rest running from now."""
    blocks = [BlockCost(50, 1.0)] * 40
    sched = DripScheduler(lead_time=100.0, max_chunk=200)
    sched.add(DripLine("a", rate=10_000.0, buffer_size=200, blocks=blocks, flow_control=False))
    sched.start("a", 0.0)
    grant = sched.next_grant(0.0)
    assert grant is not None and grant.size == 200
    assert sched.buffered("a", 0.5) == 200
    assert sched.next_grant(0.5) is None  # no room in the model
    sched.set_paused("a", True)  # DC3 ...
    sched.set_paused("a", False)  # ... and DC1: the controller holds 50 bytes, not 200
    sched.resync("a", 0.5, holds=50)
    assert sched.buffered("a", 0.5) == 50
    assert sched.ahead("a", 0.5) == pytest.approx(1.0)  # the block it holds runs from now
    again = sched.next_grant(0.5)
    assert again is not None and again.size == 150


def test_resync_starts_a_machine_the_model_had_not_seen_start() -> None:
    blocks = [BlockCost(10, 1.0)] * 10
    sched = DripScheduler(lead_time=1.0)
    sched.add(DripLine("a", rate=1000.0, buffer_size=100, blocks=blocks, flow_control=False))
    assert sched.next_grant(0.0) is not None
    sched.resync("a", 1.0, holds=0)
    assert sched.buffered("a", 1.0) == 0
    assert sched.ahead("a", 1.0) == 0.0
    assert sched.next_grant(1.0) is not None  # dry: served at once


def test_a_line_with_a_longer_lead_is_filled_further() -> None:
    blocks = [BlockCost(10, 1.0)] * 100
    sched = DripScheduler(lead_time=2.0, max_chunk=1000)
    sched.add(DripLine("short", rate=10_000.0, buffer_size=1000, blocks=blocks, flow_control=False))
    sched.add(
        DripLine("long", rate=10_000.0, buffer_size=1000, blocks=blocks, lead_time=5.0, flow_control=False)
    )
    for key in ("short", "long"):
        sched.start(key, 0.0)
    granted = {"short": 0.0, "long": 0.0}
    while (grant := sched.next_grant(0.0)) is not None:
        granted[grant.key] += grant.seconds
    assert granted == {"short": pytest.approx(4.0), "long": pytest.approx(10.0)}  # 2 x lead each
    with pytest.raises(ValueError, match="lead_time"):
        sched.add(DripLine("bad", 1.0, 10, [], lead_time=0))


@given(fleets(sufficient=False), st.lists(st.tuples(st.floats(0, 50), st.integers(0, 500)), max_size=20))
@settings(max_examples=100, deadline=None)
def test_buffered_bookkeeping_matches_the_grants_through_resyncs(
    case: tuple[list[DripLine], dict[str, float], float, int], resyncs: list[tuple[float, int]]
) -> None:
    """`buffered` is kept as a running sum: it must equal what the queue holds, however resyncs cut it."""
    lines, links, lead, max_chunk = case
    sched = DripScheduler(lead_time=lead, links=links, max_chunk=max_chunk)
    for line in lines:
        sched.add(line)
        sched.start(line.key, 0.0)
    events = sorted(resyncs)
    now = 0.0
    for when, holds in events:
        while sched.next_grant(now) is not None:
            pass
        now = max(now, when)
        for line in lines:
            sched.resync(line.key, now, holds)
            state = sched._lines[line.key]
            assert state.queued == sum(item.size for item in state.queue)
            assert sched.buffered(line.key, now) == state.partial + state.queued
            assert state.queued <= max(holds, 0) or not state.queue


# --- work-conserving lines: controllers that say DC3 and DC1, machines faster or slower than estimated --


@dataclass
class Controller:
    """A Fanuc-style reader in simulated time, independent of the scheduler's model: a receive buffer with
    its DC3 and DC1 levels, and a machine that takes each block whole from it (freeing its bytes) and runs
    it for its estimated seconds divided by `pace` (8: eight times faster than the estimate)."""

    blocks: list[BlockCost]
    buffer_size: int
    pace: float
    buffered: int = 0
    arrived: int = 0
    taken: int = 0  # blocks the machine has taken
    busy_until: float = 0.0
    running: bool = False
    waiting: bool = False
    xoff: bool = False
    starvations: int = 0
    overruns: int = 0
    finished_at: float | None = None
    in_transit: list[tuple[float, int]] = field(default_factory=list)
    events: list[str] = field(default_factory=list)  # DC3/DC1 for the sender, in order

    @property
    def high(self) -> int:
        return self.buffer_size - 32

    @property
    def low(self) -> int:
        return self.buffer_size // 4

    def step(self, now: float) -> None:
        while self.in_transit and self.in_transit[0][0] <= now:
            _, n = self.in_transit.pop(0)
            self.arrived += n
            self.buffered += n
            if self.buffered > self.buffer_size:
                self.overruns += 1
        total = sum(b.size for b in self.blocks)
        if not self.running and (self.buffered >= self.high or self.arrived >= total):
            self.running = True
            self.busy_until = now
        while self.running and self.taken < len(self.blocks) and now >= self.busy_until:
            block = self.blocks[self.taken]
            if self.buffered < block.size or self.arrived < sum(
                b.size for b in self.blocks[: self.taken + 1]
            ):
                if not self.waiting:
                    self.starvations += 1
                    self.waiting = True
                break
            if self.waiting:
                self.busy_until = now
            self.waiting = False
            self.buffered -= block.size
            self.busy_until += block.seconds / self.pace
            self.taken += 1
        if self.taken == len(self.blocks) and self.finished_at is None and now >= self.busy_until:
            self.finished_at = now
        if not self.xoff and self.buffered >= self.high:
            self.xoff = True
            self.events.append("DC3")
        elif self.xoff and self.buffered <= self.low:
            self.xoff = False
            self.events.append("DC1")


def drip(
    sched: DripScheduler,
    lines: list[DripLine],
    paces: list[float],
    *,
    dt: float = 0.0005,
    limit: float = 120.0,
) -> list[Controller]:
    """Drive the scheduler as the transport does: grants become each line's budget, written at the line's
    rate while no DC3 holds it; the controller's DC3/DC1 go to the scheduler as they come."""
    controllers = [
        Controller(list(line.blocks), line.buffer_size, pace) for line, pace in zip(lines, paces, strict=True)
    ]
    for line in lines:
        sched.add(line)
        sched.start(line.key, 0.0)
    budget = {line.key: 0 for line in lines}
    written = {line.key: 0 for line in lines}
    paused = {line.key: False for line in lines}
    wire_free = {line.key: 0.0 for line in lines}
    now = 0.0
    while now < limit and any(c.finished_at is None for c in controllers):
        for line, ctl in zip(lines, controllers, strict=True):
            ctl.step(now)
            for event in ctl.events:
                paused[line.key] = event == "DC3"
                (sched.dc3 if event == "DC3" else sched.dc1)(line.key, now, written[line.key])
            ctl.events.clear()
        while (grant := sched.next_grant(now)) is not None:
            budget[grant.key] += grant.size
        for line, ctl in zip(lines, controllers, strict=True):
            key = line.key
            if paused[key] or budget[key] == 0 or wire_free[key] > now + dt:
                continue
            n = min(budget[key], 8)  # a transport's slice
            start = max(now, wire_free[key])
            wire_free[key] = start + n / line.rate
            ctl.in_transit.append((wire_free[key], n))
            budget[key] -= n
            written[key] += n
        now += dt
    return controllers


LINE_RATE = 38_400 / 11  # 7E2 at 38,400 baud


def program(size: int, seconds: float, count: int) -> list[BlockCost]:
    return [BlockCost(size, seconds)] * count


@pytest.mark.parametrize("pace", [0.5, 1.0, 1.5, 8.0])
def test_one_line_is_never_starved_whatever_the_machines_pace(pace: float) -> None:
    """256-byte buffer; blocks of 20 bytes estimated at 50 ms (400 chars/s at the estimate): at 8x the
    machine takes 3,200 chars/s of a 3,490 chars/s line. Nothing but the DC3 holds the line back."""
    blocks = program(20, 0.05, 3000 if pace > 2 else 600)
    sched = DripScheduler(lead_time=30.0)
    line = DripLine("m", LINE_RATE, 256, blocks)
    (ctl,) = drip(sched, [line], [pace])
    assert ctl.finished_at is not None
    assert ctl.overruns == 0
    assert ctl.starvations == 0
    if pace > 1:
        assert sched.speed("m") >= 0.8 * pace  # learned from the DC1 cycles


def test_twenty_lines_on_a_link_of_1_2_times_their_real_consumption_never_starve() -> None:
    """Machines at 0.5x to 8x their estimate; the link carries 1.2 times what they really take together
    (far less than their lines could carry). Served earliest-dry-first by the learned speeds, none runs dry
    and no buffer overruns."""
    paces = [0.5, 1.0, 1.5, 8.0] * 5
    lines = []
    real = 0.0
    for index, pace in enumerate(paces):
        seconds = 0.05 if pace < 8 else 0.2  # the 8x machines: 20 bytes in 25 ms, 800 chars/s
        blocks = program(20, seconds, int(8.0 * pace / seconds))  # about eight seconds of cutting
        real += 20 / (seconds / pace)
        lines.append(DripLine(f"m{index:02d}", LINE_RATE, 256, blocks, link="nport"))
    sched = DripScheduler(lead_time=30.0, links={"nport": 1.2 * real})
    controllers = drip(sched, lines, paces, limit=60.0)
    for line, ctl in zip(lines, controllers, strict=True):
        assert ctl.finished_at is not None, f"{line.key} did not finish"
        assert ctl.overruns == 0, f"{line.key} overran"
        assert ctl.starvations == 0, f"{line.key} starved {ctl.starvations} times"


def test_a_model_only_line_starves_a_machine_eight_times_faster() -> None:
    """Why flow-controlled lines are work-conserving: fed by the model alone, an 8x machine whose controller
    never reaches its DC3 level is served at the estimate's pace and runs dry again and again."""
    blocks = program(20, 0.05, 1000)
    sched = DripScheduler(lead_time=30.0)
    (ctl,) = drip(sched, [DripLine("m", LINE_RATE, 256, blocks, flow_control=False)], [8.0], limit=40.0)
    assert ctl.starvations > 10


def test_machines_that_all_take_the_same_but_are_estimated_from_half_to_eight_times_never_starve() -> None:
    """The bench's fleet: every machine takes 1,000 chars/s, but their programs are estimated at 0.5x to 8x
    what they really take; 48-byte blocks; a link of 1.2x their consumption. The harness comes back every
    0.5 ms, as a thread that wakes late: link time lost to late wake-ups must be made up for, or the 20 %
    spare capacity goes and every line runs dry at once."""
    factors = [0.5 * 16 ** (i / 19) for i in range(20)]
    lines = [
        DripLine(f"m{i:02d}", LINE_RATE, 256, program(48, 0.048 * factor, 200), link="nport")
        for i, factor in enumerate(factors)
    ]
    sched = DripScheduler(lead_time=30.0, links={"nport": 1.2 * 20 * 1000.0})
    controllers = drip(sched, lines, factors, limit=40.0)
    for line, factor, ctl in zip(lines, factors, controllers, strict=True):
        assert ctl.finished_at is not None and ctl.overruns == 0
        assert ctl.starvations == 0, f"{line.key} ({factor:.1f}x) starved {ctl.starvations} times"
        assert sched.speed(line.key) == pytest.approx(factor, rel=0.1)
