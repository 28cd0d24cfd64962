"""One configured target: changes from the hub become frames, frames go to each receiver's channel.

Flow: the target's own hub subscription keeps the latest sample per variable
while the emitter waits, so a rate limit or a slow cycle loses intermediate
values, never the current one. Each cycle takes what changed, waits for the
rate limit, and builds either one dwData=1 frame per changed variable
(`mode: single`) or one dwData=2 frame for all of them (`mode: batch`). The
frames are offered to every connected receiver's bounded channel, which never
blocks (see channel.py); each transport drains its channels at the receiver's
pace. With nobody connected, changes are dropped at once: the snapshot that
starts every connection carries the current state.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any, Self

from gateway.codecs.copydata import Frame, Layout
from gateway.model.hub import Change, Subscription
from gateway.model.sample import Sample
from gateway.model.tree import Machine, VariableNode
from gateway.sinks.copydata.channel import Channel, OutFrame, RateLimiter
from gateway.sinks.copydata.config import CopydataMachineEntry, CopydataTarget
from gateway.sinks.copydata.encoder import TargetEncoder, sendable
from gateway.sinks.copydata.feedback import Feedback
from gateway.sinks.copydata.port import Transport, TransportPort
from gateway.sinks.copydata.status import CopydataStatus
from gateway.sinks.copydata.throttle import LogThrottle

log = logging.getLogger("gateway.sinks.copydata")

UDP_MAX_CBDATA = 65507 - 8  # the largest UDP payload over IPv4, less the frame header

TransportFactory = Callable[[TransportPort], Transport]
"""Builds a target's transport when its emitter is entered (sink.make_transport)."""


def target_nodes(
    machine: Machine, mapping: CopydataMachineEntry, target: CopydataTarget
) -> list[tuple[VariableNode, int]]:
    """The (node, id) pairs a target sends, in mapping order; the connection flag first if asked for."""
    pairs: list[tuple[VariableNode, int]] = []
    if target.connected_id is not None:
        pairs.append((machine.status.connected_node, target.connected_id))
    wanted = None if target.variables is None else set(target.variables)
    for spec in mapping.variables:
        if spec.copydata is not None and (wanted is None or spec.path in wanted):
            pairs.append((machine.nodes[spec.path], spec.copydata.id))
    return pairs


def target_layout(target: CopydataTarget) -> Layout:
    max_cbdata = target.max_cbdata
    if target.transport == "udp":
        max_cbdata = min(max_cbdata, UDP_MAX_CBDATA)
    return Layout(target.id_width, target.len_width, target.encoding, max_cbdata)


class Emitter:
    """Frames for one target of one machine (an async context manager with a long-running `run()`).

    It is the `TransportPort` of its transport, which `make_transport` builds when the emitter
    is entered (so that a target this system cannot serve fails the start, not the construction).
    """

    def __init__(
        self,
        machine: Machine,
        mapping: CopydataMachineEntry,
        target: CopydataTarget,
        status: CopydataStatus,
        make_transport: TransportFactory,
    ) -> None:
        self.machine = machine
        self.target = target
        self.name = f"{machine.name}/{target.name}"
        self.layout = target_layout(target)
        self.encoder = TargetEncoder(self.name, target_nodes(machine, mapping, target), self.layout)
        self.status = status
        self.throttle = LogThrottle(log)
        self.feedback = Feedback(
            machine, target.name, self.encoder.table, self.encoder.by_id, self.layout, status,
            accept_writes=target.accept_writes, throttle=self.throttle,
        )  # fmt: skip
        self.limiter = RateLimiter(target.max_rate)
        self.channels: list[Channel] = []
        self.frames_built = 0
        self.closed_sent = 0  # frames sent on channels that are gone
        self.closed_dropped = 0
        self.transport: Transport | None = None
        self._make_transport = make_transport
        self._state = "starting"
        self._sub: Subscription[VariableNode] | None = None
        self._pending: dict[VariableNode, Sample] = {}
        status.add_target(self.describe)

    def __repr__(self) -> str:
        return f"<Emitter {self.name} {self.target.describe()}>"

    # --- lifecycle -----------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        self.transport = self._make_transport(self)
        self._sub = self.machine.tree.hub.subscribe(f"copydata:{self.name}")
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
        self.channels.clear()
        self._pending.clear()

    async def run(self) -> None:
        """Emit frames and run the transport, until cancelled."""
        if self._sub is None or self.transport is None:
            raise RuntimeError("enter the emitter before running it")
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self.emit(self._sub), name=f"copydata:{self.name}:emit")
            tg.create_task(self.transport.run(), name=f"copydata:{self.name}:transport")
            every = self.target.snapshot_every
            if every is not None:
                tg.create_task(self._snapshots(every), name=f"copydata:{self.name}:snapshots")

    @property
    def subscription(self) -> Subscription[VariableNode]:
        if self._sub is None:
            raise RuntimeError("the emitter is not entered")
        return self._sub

    # --- what transports call (TransportPort) ----------------------------------------------------

    def open_channel(self, peer: str) -> Channel:
        """A receiver connected: it gets its own bounded queue, starting with a snapshot."""
        channel = Channel(peer, self.target.queue_limit, self.snapshot)
        self.channels.append(channel)
        self.status.refresh()
        return channel

    def close_channel(self, channel: Channel) -> None:
        if channel in self.channels:
            self.channels.remove(channel)
            self.closed_sent += channel.sent
            self.closed_dropped += channel.dropped
            self.status.refresh()

    def set_state(self, state: str) -> None:
        """The transport's link state (`listening`, `connecting (refused)` …) for Status/CopydataTargets."""
        self._state = state
        self.status.refresh()

    async def on_frame(self, frame: Frame, peer: str) -> None:
        """A frame a receiver sent back."""
        await self.feedback.handle(frame, peer)

    def snapshot(self) -> list[OutFrame]:
        frames = self.encoder.snapshot()
        self.frames_built += len(frames)
        return frames

    def describe(self) -> str:
        text = (
            f"{self.target.name}: {self.transport.describe() if self.transport else self.target.describe()}"
        )
        return f"{text} {self._state}" if self._state else text

    # --- statistics ----------------------------------------------------------------------------

    @property
    def sent(self) -> int:
        return self.closed_sent + sum(c.sent for c in self.channels)

    @property
    def dropped(self) -> int:
        return self.closed_dropped + sum(c.dropped for c in self.channels)

    @property
    def queued(self) -> int:
        """Frames held for receivers right now: bounded by queue_limit per receiver."""
        return sum(c.queued for c in self.channels)

    def stats(self) -> dict[str, Any]:
        return {
            "target": self.name,
            "link": self.describe(),
            "receivers": len(self.channels),
            "frames_built": self.frames_built,
            "sent": self.sent,
            "dropped": self.dropped,
            "superseded": sum(c.superseded for c in self.channels),
            "queued": self.queued,
            "pending": len(self._pending),
            "skipped_values": self.encoder.skipped,
            "replies": self.feedback.received,
            "writes": self.feedback.written,
            "refused_writes": self.feedback.refused,
        }

    # --- the emit loop -------------------------------------------------------------------------

    def _merge(self, batch: list[Change[VariableNode]]) -> None:
        """Keep the latest sendable sample per variable of this target."""
        pending = self._pending
        wanted = self.encoder.encoders
        for node, sample in batch:
            if node in wanted:
                if sendable(sample):
                    pending[node] = sample
                else:
                    pending.pop(node, None)

    async def emit(self, sub: Subscription[VariableNode]) -> None:
        """The emit loop: changes to frames to channels until cancelled; run() runs it by the transport."""
        pending = self._pending
        limiter = self.limiter
        single = self.target.mode == "single"
        while True:
            self._merge(sub.take() if pending else await sub.next_batch())
            if not pending:
                continue
            if not any(not channel.needs_snapshot for channel in self.channels):
                # Nobody listens, or every receiver is owed a snapshot (new, or fallen behind), which
                # will hold these values: building frames now would be wasted work.
                pending.clear()
                continue
            wait = limiter.delay()
            if wait > 0:
                await asyncio.sleep(wait)
                self._merge(sub.take())  # what changed meanwhile: the latest value of each
                if not self.channels:
                    continue
            if single:
                count = min(len(pending), max(1, limiter.available()))
                frames = []
                for _ in range(count):
                    node = next(iter(pending))
                    frame = self.encoder.single(node, pending.pop(node))
                    if frame is not None:
                        frames.append(frame)
            else:
                frames = self.encoder.batch(pending.items())
                pending.clear()
            if not frames:
                continue
            limiter.spend(len(frames))
            self.frames_built += len(frames)
            for channel in self.channels:
                channel.offer(frames)
            await asyncio.sleep(0)  # one cycle at a time: the rest of the gateway gets its turn

    async def _snapshots(self, every: float) -> None:
        while True:
            await asyncio.sleep(every)
            if not self.channels:
                continue
            frames = self.snapshot()
            for channel in self.channels:
                channel.offer(frames)
