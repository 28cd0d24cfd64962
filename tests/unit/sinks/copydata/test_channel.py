"""A receiver's bounded queue (snapshot first, drop-and-resync on overflow) and the rate limit."""

from __future__ import annotations

import asyncio

from gateway.sinks.copydata.channel import Channel, OutFrame, RateLimiter

SNAPSHOT: list[OutFrame] = [(2, b"snapshot")]


def channel(limit: int = 3) -> tuple[Channel, list[int]]:
    built: list[int] = []

    def snapshot() -> list[OutFrame]:
        built.append(1)
        return list(SNAPSHOT)

    return Channel("peer", limit, snapshot), built


def test_a_new_receiver_starts_with_a_snapshot_built_when_it_goes_out() -> None:
    ch, built = channel()
    ch.offer([(1, b"a")])  # older than the snapshot that is owed: not queued
    assert built == []
    assert ch.take() == SNAPSHOT and built == [1]
    ch.offer([(1, b"b"), (1, b"c")])
    assert ch.take() == [(1, b"b"), (1, b"c")]
    assert ch.take() == []
    assert ch.snapshots == 1 and ch.dropped == 0


def test_overflow_drops_the_stale_backlog_and_owes_a_snapshot() -> None:
    ch, _built = channel(limit=3)
    ch.take()
    ch.offer([(1, b"1"), (1, b"2")])
    ch.offer([(1, b"3"), (1, b"4")])  # 4 > limit 3
    assert ch.queued == 0 and ch.dropped == 4 and ch.needs_snapshot
    ch.offer([(1, b"5")])  # ignored: the snapshot will hold it
    assert ch.take() == SNAPSHOT and ch.snapshots == 2
    for i in range(100):  # memory stays bounded however long the receiver stalls
        ch.offer([(1, str(i).encode())])
        assert ch.queued <= 3


def test_a_lost_frame_turns_into_a_snapshot() -> None:
    ch, _ = channel()
    ch.take()
    ch.offer([(1, b"x")])
    ch.request_snapshot()
    assert ch.dropped == 1 and ch.take() == SNAPSHOT


async def test_next_frames_waits_for_an_offer() -> None:
    ch, _ = channel()
    assert await ch.next_frames() == SNAPSHOT
    waiter = asyncio.create_task(ch.next_frames())
    await asyncio.sleep(0.01)
    assert not waiter.done()
    ch.offer([(1, b"late")])
    assert await asyncio.wait_for(waiter, 2) == [(1, b"late")]


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_rate_limit_allows_a_tenth_of_a_second_in_a_burst_then_paces() -> None:
    clock = Clock()
    limiter = RateLimiter(50, clock)  # 50 frames/s: bursts of 5
    assert limiter.available() == 5 and limiter.delay() == 0
    limiter.spend(5)
    assert limiter.available() == 0
    assert abs(limiter.delay() - 0.02) < 1e-9  # one frame every 1/50 s
    clock.now += 0.02
    assert limiter.available() == 1
    clock.now += 10  # idle time does not pile up beyond the burst
    assert limiter.available() == 5


def test_an_overdrawn_limiter_waits_longer() -> None:
    clock = Clock()
    limiter = RateLimiter(10, clock)
    limiter.spend(3)  # a snapshot split into 3 frames
    assert abs(limiter.delay() - 0.3) < 1e-9


def test_no_limit_never_waits() -> None:
    limiter = RateLimiter(None)
    limiter.spend(10**6)
    assert limiter.delay() == 0 and limiter.available() > 10**6
