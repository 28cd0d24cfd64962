"""Structured events beside the variable tree: job progress, alarm transitions, feedback.

Variables hold state; events tell what happened (a job moved to DELIVERED, an
alarm was raised, the nesting software sent a reply). Components publish them
here without knowing who listens; sinks that can carry them (MQTT as JSON on
`<prefix>/<machine>/<channel>`) subscribe. Like the change hub, publishing never
blocks and each subscriber's backlog is bounded: the oldest events are dropped
and counted when a subscriber falls too far behind.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from gateway.model.sample import utcnow


@dataclass(frozen=True, slots=True)
class Event:
    """One event. `channel` is a '/'-separated name such as "jobs/events" or "jobs/J000042".

    `retain` marks state-like events (the latest per channel is what matters, e.g.
    a job's current record); others are a stream (every one matters, in order).
    `payload` must be JSON-serialisable: an object, or a list for state that is a
    list (a machine's active alarms), which is published as it is, without `ts`.
    None, retained, withdraws the state (MQTT: an empty retained message clears the topic).
    """

    machine: str | None
    channel: str
    payload: Mapping[str, Any] | Sequence[Any] | None
    retain: bool = False
    ts: datetime = field(default_factory=utcnow)


class EventSubscription:
    __slots__ = ("_accept", "_bus", "_event", "_queue", "dropped", "name")

    def __init__(
        self, bus: EventBus, name: str, limit: int, accept: Callable[[Event], bool] | None = None
    ) -> None:
        self.name = name
        self.dropped = 0
        self._queue: deque[Event] = deque(maxlen=limit)
        self._event = asyncio.Event()
        self._bus = bus
        self._accept = accept

    def push(self, event: Event) -> None:
        if self._accept is not None and not self._accept(event):
            return  # decided as the event is published, not when the subscriber gets round to it
        queue = self._queue
        if len(queue) == queue.maxlen:
            self.dropped += 1
        queue.append(event)
        self._event.set()

    def take(self) -> list[Event]:
        batch = list(self._queue)
        self._queue.clear()
        self._event.clear()
        return batch

    async def next_batch(self) -> list[Event]:
        while not self._queue:
            self._event.clear()
            await self._event.wait()
        return self.take()

    def close(self) -> None:
        self._bus.unsubscribe(self)


class EventBus:
    def __init__(self) -> None:
        self._subs: tuple[EventSubscription, ...] = ()

    def subscribe(
        self, name: str, *, limit: int = 10_000, accept: Callable[[Event], bool] | None = None
    ) -> EventSubscription:
        """`accept`: the events this subscriber wants, judged when each is published."""
        sub = EventSubscription(self, name, limit, accept)
        self._subs = (*self._subs, sub)
        return sub

    def unsubscribe(self, sub: EventSubscription) -> None:
        self._subs = tuple(s for s in self._subs if s is not sub)

    def publish(self, event: Event) -> None:
        for sub in self._subs:
            sub.push(event)
