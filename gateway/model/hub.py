"""The change hub: fans every variable change out to the sinks without ever blocking.

A source calls `publish()` from its receive path; it costs one dict or list store
per sink and never awaits. Each sink drains its own `Subscription` at its own pace.
When a sink lags, its backlog is bounded: in the default mode only the latest
sample per variable is kept; in `every_change` mode (for sinks that promise
ordered delivery, such as MQTT at QoS 1) changes are kept in order up to a limit,
beyond which the backlog collapses to the latest sample per variable and the
collapsed count is recorded.

Generic in the variable type (the tree's `VariableNode`), so that this module
needs nothing from the tree: `ChangeHub[VariableNode]`, `Subscription[VariableNode]`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Hashable
from typing import Generic, TypeVar

from gateway.model.sample import Sample

N = TypeVar("N", bound=Hashable)

Change = tuple[N, Sample]


class Subscription(Generic[N]):
    """One sink's view of the change stream."""

    __slots__ = (
        "_event",
        "_hub",
        "_latest",
        "_ordered",
        "coalesced",
        "delivered",
        "every_change",
        "limit",
        "name",
    )

    def __init__(
        self, hub: ChangeHub[N], name: str, *, every_change: bool = False, limit: int = 100_000
    ) -> None:
        self.name = name
        self.every_change = every_change
        self.limit = limit
        self.coalesced = 0  # changes replaced by a newer sample before this sink took them
        self.delivered = 0
        self._latest: dict[N, Sample] = {}
        self._ordered: list[Change[N]] = []
        self._event = asyncio.Event()
        self._hub = hub

    def push(self, node: N, sample: Sample) -> None:
        if self.every_change:
            ordered = self._ordered
            ordered.append((node, sample))
            if len(ordered) > self.limit:
                self._collapse()
        else:
            latest = self._latest
            size = len(latest)
            latest[node] = sample
            if len(latest) == size:
                self.coalesced += 1
        self._event.set()

    def _collapse(self) -> None:
        latest = dict(self._ordered)
        self.coalesced += len(self._ordered) - len(latest)
        self._ordered = list(latest.items())

    @property
    def backlog(self) -> int:
        return len(self._ordered) if self.every_change else len(self._latest)

    def take(self) -> list[Change[N]]:
        """Everything pending, oldest first, without waiting (may be empty)."""
        batch: list[Change[N]]
        if self.every_change:
            batch, self._ordered = self._ordered, []
        else:
            batch = list(self._latest.items())
            self._latest = {}
        self._event.clear()
        self.delivered += len(batch)
        return batch

    async def next_batch(self) -> list[Change[N]]:
        """Wait until something is pending, then take all of it."""
        while not self.backlog:
            self._event.clear()
            await self._event.wait()
        return self.take()

    def close(self) -> None:
        self._hub.unsubscribe(self)


class ChangeHub(Generic[N]):
    def __init__(self) -> None:
        self._subs: tuple[Subscription[N], ...] = ()

    def subscribe(self, name: str, *, every_change: bool = False, limit: int = 100_000) -> Subscription[N]:
        sub = Subscription(self, name, every_change=every_change, limit=limit)
        self._subs = (*self._subs, sub)
        return sub

    def unsubscribe(self, sub: Subscription[N]) -> None:
        self._subs = tuple(s for s in self._subs if s is not sub)

    @property
    def subscriptions(self) -> tuple[Subscription[N], ...]:
        return self._subs

    def publish(self, node: N, sample: Sample) -> None:
        for sub in self._subs:
            sub.push(node, sample)
