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


async def test_mixed_mode_keeps_every_change_of_ordered_nodes_and_the_latest_of_the_rest() -> None:
    hub = ChangeHub()
    kept, fresh = Node(), Node()
    ordered = {kept}
    sub = hub.subscribe("mixed", ordered=ordered, tally={fresh: "m1", kept: "m2"})
    for i in range(50):
        hub.publish(kept, sample(i))
        hub.publish(fresh, sample(i))
    assert sub.backlog == 51  # 50 ordered changes + one latest sample
    assert [s.value for _, s in await asyncio.wait_for(sub.next_ordered(), 1)] == list(range(50))
    assert [(n, s.value) for n, s in await asyncio.wait_for(sub.next_latest(10), 1)] == [(fresh, 49)]
    assert sub.coalesced == 49 and sub.coalesced_by == {"m1": 49}
    assert sub.delivered == 51 and sub.backlog == 0


async def test_mixed_mode_follows_the_live_ordered_collection() -> None:
    hub = ChangeHub()
    late = Node()
    ordered: set[Node] = set()
    sub = hub.subscribe("mixed", ordered=ordered)
    hub.publish(late, sample(1))
    hub.publish(late, sample(2))
    ordered.add(late)  # a route that appeared later: from now on every change
    hub.publish(late, sample(3))
    hub.publish(late, sample(4))
    assert [s.value for _, s in sub.take_ordered()] == [3, 4]
    assert [s.value for _, s in sub.take_latest(5)] == [2]


async def test_take_latest_takes_a_chunk_longest_waiting_first_and_the_rest_keeps_coalescing() -> None:
    hub = ChangeHub()
    sub = hub.subscribe("chunks")
    nodes = [Node() for _ in range(10)]
    for i, node in enumerate(nodes):
        hub.publish(node, sample(i))
    first = sub.take_latest(4)
    assert [n for n, _ in first] == nodes[:4]
    hub.publish(nodes[5], sample("newer"))  # still waiting: replaced in place, keeps its turn
    hub.publish(nodes[0], sample("again"))  # taken already: waits again, at the end
    rest = sub.take_latest(100)
    assert [n for n, _ in rest] == [*nodes[4:], nodes[0]]
    assert {n: s.value for n, s in rest}[nodes[5]] == "newer"
    assert sub.coalesced == 1 and sub.backlog == 0


async def test_a_slow_subscriber_gets_the_latest_value_of_each_variable_and_the_count_of_the_rest() -> None:
    hub = ChangeHub()
    sub = hub.subscribe("slow")
    nodes = [Node() for _ in range(20)]
    for round_ in range(100):  # 2,000 changes while the subscriber takes nothing
        for node in nodes:
            hub.publish(node, sample(round_))
    got: dict[Node, object] = {}
    while sub.backlog:
        got.update((n, s.value) for n, s in await asyncio.wait_for(sub.next_latest(7), 1))
    assert got == dict.fromkeys(nodes, 99)
    assert sub.coalesced == 2000 - 20 and sub.delivered == 20
