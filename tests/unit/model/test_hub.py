from __future__ import annotations

import asyncio

from gateway.model.hub import ChangeHub
from gateway.model.sample import Sample, utcnow


class Node:  # the hub only needs something hashable
    pass


def sample(v: object) -> Sample:
    return Sample(v, utcnow())


async def test_latest_mode_keeps_only_the_newest_sample_per_variable() -> None:
    hub = ChangeHub()
    sub = hub.subscribe("slow")
    a, b = Node(), Node()
    for i in range(1000):
        hub.publish(a, sample(i))
    hub.publish(b, sample("x"))
    batch = await asyncio.wait_for(sub.next_batch(), 1)
    assert [(n, s.value) for n, s in batch] == [(a, 999), (b, "x")]
    assert sub.coalesced == 999
    assert sub.backlog == 0


async def test_every_change_mode_keeps_order_then_collapses_beyond_the_limit() -> None:
    hub = ChangeHub()
    sub = hub.subscribe("ordered", every_change=True, limit=10)
    a, b = Node(), Node()
    for i in range(5):
        hub.publish(a, sample(i))
    assert [s.value for _, s in sub.take()] == [0, 1, 2, 3, 4]
    for i in range(8):
        hub.publish(a, sample(i))
        hub.publish(b, sample(-i))
    # 16 changes > limit 10: the backlog collapsed to the latest per variable, and never grew past the limit
    assert sub.backlog <= 10
    batch = sub.take()
    assert {n: s.value for n, s in batch}[a] == 7
    assert sub.coalesced > 0


async def test_a_lagging_sink_never_blocks_the_publisher_or_other_sinks() -> None:
    hub = ChangeHub()
    lagging = hub.subscribe("lagging")
    fast = hub.subscribe("fast")
    a = Node()
    received = []

    async def fast_sink() -> None:
        while len(received) < 100:
            received.extend(s.value for _, s in await fast.next_batch())

    task = asyncio.create_task(fast_sink())
    for i in range(100):
        hub.publish(a, sample(i))
        await asyncio.sleep(0)
    await asyncio.wait_for(task, 2)
    assert received == list(range(100))
    assert lagging.backlog == 1  # the lagging sink holds one sample, not a hundred


async def test_unsubscribed_sinks_get_nothing() -> None:
    hub = ChangeHub()
    sub = hub.subscribe("gone")
    sub.close()
    hub.publish(Node(), sample(1))
    assert sub.backlog == 0 and hub.subscriptions == ()


async def test_event_bus_bounds_each_subscriber_and_counts_drops() -> None:
    from gateway.model.events import Event, EventBus

    bus = EventBus()
    slow = bus.subscribe("slow", limit=3)
    fast = bus.subscribe("fast", limit=100)
    for i in range(5):
        bus.publish(Event("m1", "jobs/events", {"n": i}))
    assert [e.payload["n"] for e in slow.take()] == [2, 3, 4]
    assert slow.dropped == 2
    assert [e.payload["n"] for e in await asyncio.wait_for(fast.next_batch(), 1)] == [0, 1, 2, 3, 4]
    assert fast.dropped == 0
