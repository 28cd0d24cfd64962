"""The emit loop: per-change or per-cycle frames, the rate limit keeps the latest value, snapshots first."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

import pytest

from gateway.codecs.copydata import decode_lpdata
from gateway.model.tree import Machine
from gateway.sinks.copydata.channel import Channel, OutFrame
from gateway.sinks.copydata.emitter import Emitter
from tests.unit.sinks.copydata.helpers import copydata_sink, ingest, mapping
from tests.waiting import wait_until


class Receiver:
    """Drains a channel the way a transport does, and keeps every decoded frame."""

    def __init__(self, emitter: Emitter, channel: Channel) -> None:
        self.emitter = emitter
        self.channel = channel
        self.frames: list[tuple[int, dict[str, Any]]] = []

    async def run(self) -> None:
        while True:
            for dwdata, lpdata in await self.channel.next_frames():
                frame = decode_lpdata(dwdata, lpdata, self.emitter.layout)
                values = {
                    r.variable.name: r.value
                    for r in self.emitter.encoder.table.decode(frame, self.emitter.layout)
                }
                self.frames.append((dwdata, values))
                self.channel.sent += 1

    def values(self, path: str) -> list[Any]:
        return [v[path] for _, v in self.frames if path in v]


@pytest.fixture
async def started(request: pytest.FixtureRequest) -> AsyncIterator[tuple[Machine, Emitter]]:
    target = {"name": "nest", "transport": "tcp-server", "port": 0, **getattr(request, "param", {})}
    sink = copydata_sink(mapping(target))
    emitter = sink.emitters[0]
    async with sink:
        task = asyncio.create_task(emitter.emit(emitter.subscription))
        try:
            yield emitter.machine, emitter
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def receiver(emitter: Emitter, tasks: list[asyncio.Task[None]]) -> Receiver:
    rec = Receiver(emitter, emitter.open_channel("test"))
    tasks.append(asyncio.create_task(rec.run()))
    return rec


@pytest.fixture
async def tasks() -> AsyncIterator[list[asyncio.Task[None]]]:
    made: list[asyncio.Task[None]] = []
    yield made
    for t in made:
        t.cancel()
    await asyncio.gather(*made, return_exceptions=True)


@pytest.mark.parametrize("started", [{"mode": "single", "max_rate": None}], indirect=True)
async def test_single_mode_sends_one_dwdata_1_frame_per_change(
    started: tuple[Machine, Emitter], tasks: list[asyncio.Task[None]]
) -> None:
    m, emitter = started
    ingest(m, "Axes/X/Position", 1.0)
    rec = await receiver(emitter, tasks)
    await wait_until(lambda: rec.frames, message="the snapshot")
    assert rec.frames[0] == (2, {"Axes/X/Position": 1.0})
    ingest(m, "Axes/X/Position", 2.0)
    ingest(m, "Program/Block", 5)
    await wait_until(lambda: len(rec.frames) >= 3, message="two single frames")
    assert rec.frames[1:] == [(1, {"Axes/X/Position": 2.0}), (1, {"Program/Block": 5})]


@pytest.mark.parametrize("started", [{"mode": "batch", "max_rate": None}], indirect=True)
async def test_batch_mode_sends_a_cycle_in_one_dwdata_2_frame(
    started: tuple[Machine, Emitter], tasks: list[asyncio.Task[None]]
) -> None:
    m, emitter = started
    rec = await receiver(emitter, tasks)
    ingest(m, "Axes/X/Position", 3.0)
    ingest(m, "Axes/Y/Position", 4.0)
    ingest(m, "Feed/Rate", 99.0)  # no copydata id: never sent
    await wait_until(lambda: rec.frames, message="a frame")
    assert rec.frames[-1] == (2, {"Axes/X/Position": 3.0, "Axes/Y/Position": 4.0})
    assert all("Feed/Rate" not in values for _, values in rec.frames)


@pytest.mark.parametrize("started", [{"mode": "single", "max_rate": 10}], indirect=True)
async def test_the_rate_limit_keeps_the_latest_value_per_variable(
    started: tuple[Machine, Emitter], tasks: list[asyncio.Task[None]]
) -> None:
    m, emitter = started
    rec = await receiver(emitter, tasks)
    await wait_until(lambda: rec.channel.snapshots, message="the snapshot")
    for i in range(1, 2001):
        ingest(m, "Axes/X/Position", float(i))
        if i % 100 == 0:
            await asyncio.sleep(0.005)
    await wait_until(lambda: rec.values("Axes/X/Position")[-1:] == [2000.0], message="the latest value")
    # 2000 changes in well under a second at 10 frames/s: most were coalesced, none went out of order
    sent = rec.values("Axes/X/Position")
    assert len(sent) < 50 and sent == sorted(sent)


@pytest.mark.parametrize("started", [{"max_rate": None}], indirect=True)
async def test_bad_values_are_withheld_and_good_ones_sent_again(
    started: tuple[Machine, Emitter], tasks: list[asyncio.Task[None]]
) -> None:
    m, emitter = started
    rec = await receiver(emitter, tasks)
    ingest(m, "Program/Block", 1)
    await wait_until(lambda: rec.values("Program/Block")[-1:] == [1])
    # the change may also arrive a second time, after the snapshot that already held it: let it settle
    await wait_until(
        lambda: not emitter.subscription.backlog and not emitter.stats()["pending"] and not rec.channel.queued
    )
    sent_before = len(rec.values("Program/Block"))
    ingest(m, "Program/Block", 1, status="BadNotConnected")
    ingest(m, "Axes/X/Position", 5.0)
    await wait_until(lambda: rec.values("Axes/X/Position")[-1:] == [5.0])
    assert len(rec.values("Program/Block")) == sent_before  # the Bad sample was not sent
    ingest(m, "Program/Block", 2)
    await wait_until(lambda: rec.values("Program/Block")[-1:] == [2])


@pytest.mark.parametrize("started", [{"max_rate": None, "queue_limit": 4}], indirect=True)
async def test_a_receiver_that_stops_reading_costs_at_most_its_queue(
    started: tuple[Machine, Emitter],
) -> None:
    m, emitter = started
    stuck = emitter.open_channel("stuck")
    stuck.take()  # its snapshot went out; then it stops reading
    fast_frames: list[OutFrame] = []
    fast = emitter.open_channel("fast")

    async def drain() -> None:
        while True:
            fast_frames.extend(await fast.next_frames())

    task = asyncio.create_task(drain())
    try:
        for i in range(200):
            ingest(m, "Axes/X/Position", float(i))
            await asyncio.sleep(0)
            assert stuck.queued <= 4
        await wait_until(lambda: len(fast_frames) > 50, message="the fast receiver keeps getting frames")
        assert stuck.dropped > 0 and stuck.needs_snapshot
        assert emitter.queued <= 8
        assert emitter.stats()["dropped"] == stuck.dropped + fast.dropped
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


@pytest.mark.parametrize("started", [{"max_rate": None, "snapshot_interval": 0.05}], indirect=True)
async def test_periodic_snapshots_repeat_every_variable(
    started: tuple[Machine, Emitter], tasks: list[asyncio.Task[None]]
) -> None:
    m, emitter = started
    ingest(m, "Program/Block", 8)
    rec = await receiver(emitter, tasks)
    snapshots = asyncio.create_task(emitter._snapshots(0.05))
    tasks.append(snapshots)
    await wait_until(lambda: rec.values("Program/Block").count(8) >= 3, message="repeated snapshots")


async def test_with_nobody_connected_changes_are_not_kept(
    started: tuple[Machine, Emitter], tasks: list[asyncio.Task[None]]
) -> None:
    m, emitter = started
    for i in range(10):
        ingest(m, "Axes/X/Position", float(i))
    await wait_until(lambda: emitter.subscription.backlog == 0 and not emitter.stats()["pending"])
    assert emitter.frames_built == 0
    rec = await receiver(emitter, tasks)
    await wait_until(lambda: rec.frames, message="the snapshot")
    assert rec.frames[0] == (2, {"Axes/X/Position": 9.0})
