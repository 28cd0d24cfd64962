"""The change hub: fans every variable change out to the sinks without ever blocking.

A source calls `publish()` from its receive path; it costs one dict or list store
per sink and never awaits. Each sink drains its own `Subscription` at its own pace.
When a sink lags, its backlog is bounded: in the default mode only the latest
sample per variable is kept; in `every_change` mode (for sinks that promise
ordered delivery, such as MQTT at QoS 1) changes are kept in order up to a limit,
beyond which the backlog collapses to the latest sample per variable and the
collapsed count is recorded. A sink that mixes both (MQTT: QoS 0 topics carry the
latest value, QoS 1 topics every change) names the nodes whose every change it
keeps (`ordered=`); the rest coalesce, before anything queues, so that what it
sends under overload is fresh rather than old.

Generic in the variable type (the tree's `VariableNode`), so that this module
needs nothing from the tree: `ChangeHub[VariableNode]`, `Subscription[VariableNode]`.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Callable, Collection, Hashable, Mapping
from typing import Generic, TypeVar

from gateway.model.sample import Sample

N = TypeVar("N", bound=Hashable)

Change = tuple[N, Sample]


class Subscription(Generic[N]):
    """One sink's view of the change stream.

    Modes: latest value per variable (the default), every change in order
    (`every_change=True`), or mixed (`ordered=` a collection of nodes whose every
    change is kept; the others coalesce). `push` is bound to the mode's method
    once, so the hub's hot path makes no mode test per change.
    """

    __slots__ = (
        "_event",
        "_hub",
        "_latest",
        "_ordered",
        "_ordered_event",
        "_ordered_nodes",
        "coalesced",
        "coalesced_by",
        "delivered",
        "every_change",
        "limit",
        "name",
        "ordered",
        "push",
        "tally",
    )

    push: Callable[[N, Sample], None]

    def __init__(
        self,
        hub: ChangeHub[N],
        name: str,
        *,
        every_change: bool = False,
        limit: int = 100_000,
        ordered: Collection[N] | None = None,
        tally: Mapping[N, Hashable] | None = None,
    ) -> None:
        self.name = name
        self.every_change = every_change
        self.limit = limit
        self.ordered = ordered  # mixed mode: these nodes' every change is kept (a live collection)
        self.tally = tally  # node → group of the coalesced counts (`coalesced_by`), e.g. its machine
        self.coalesced = 0  # changes replaced by a newer sample before this sink took them
        self.coalesced_by: dict[Hashable | None, int] = {}
        self.delivered = 0
        self._latest: dict[N, Sample] = {}
        self._ordered: list[Change[N]] = []
        self._event = asyncio.Event()  # set by every push
        self._ordered_event = asyncio.Event()  # mixed mode: set by pushes of ordered nodes
        self._ordered_nodes: Collection[N] = () if ordered is None else ordered
        self._hub = hub
        if every_change:
            self.push = self._push_every
        elif ordered is not None:
            self.push = self._push_mixed
        else:
            self.push = self._push_latest

    def _push_every(self, node: N, sample: Sample) -> None:
        ordered = self._ordered
        ordered.append((node, sample))
        if len(ordered) > self.limit:
            self._collapse()
        self._event.set()

    def _push_latest(self, node: N, sample: Sample) -> None:
        latest = self._latest
        size = len(latest)
        latest[node] = sample
        if len(latest) == size:
            self.coalesced += 1
            tally = self.tally
            if tally is not None:  # inline: under overload this runs for nearly every change
                key = tally.get(node)
                by = self.coalesced_by
                by[key] = by.get(key, 0) + 1
        self._event.set()

    def _push_mixed(self, node: N, sample: Sample) -> None:
        if node in self._ordered_nodes:
            ordered = self._ordered
            ordered.append((node, sample))
            if len(ordered) > self.limit:
                self._collapse()
            self._ordered_event.set()
        else:
            latest = self._latest
            size = len(latest)
            latest[node] = sample
            if len(latest) == size:
                self.coalesced += 1
                tally = self.tally
                if tally is not None:
                    key = tally.get(node)
                    by = self.coalesced_by
                    by[key] = by.get(key, 0) + 1
        self._event.set()

    def _collapse(self) -> None:
        latest = dict(self._ordered)
        self.coalesced += len(self._ordered) - len(latest)
        self._ordered = list(latest.items())

    @property
    def backlog(self) -> int:
        return len(self._ordered) + len(self._latest)

    @property
    def latest_backlog(self) -> int:
        """Variables whose latest sample is waiting (the coalescing part)."""
        return len(self._latest)

    def take(self) -> list[Change[N]]:
        """Everything pending, oldest first (ordered changes before latest ones), without waiting."""
        batch: list[Change[N]]
        if self._ordered:
            batch, self._ordered = self._ordered, []
        else:
            batch = []
        if self._latest:
            batch.extend(self._latest.items())
            self._latest = {}
        self._event.clear()
        self._ordered_event.clear()
        self.delivered += len(batch)
        return batch

    def take_ordered(self) -> list[Change[N]]:
        """Mixed mode: the ordered changes pending, oldest first (the latest ones stay)."""
        batch, self._ordered = self._ordered, []
        self._ordered_event.clear()
        self.delivered += len(batch)
        return batch

    def take_latest(self, limit: int) -> list[Change[N]]:
        """Up to `limit` latest samples, the longest-waiting variables first; the rest keep coalescing."""
        latest = self._latest
        if len(latest) <= limit:
            batch = list(latest.items())
            self._latest = {}
        else:
            batch = list(itertools.islice(latest.items(), limit))
            for node, _ in batch:
                del latest[node]
        self.delivered += len(batch)
        return batch

    async def next_batch(self) -> list[Change[N]]:
        """Wait until something is pending, then take all of it."""
        while not self.backlog:
            self._event.clear()
            await self._event.wait()
        return self.take()

    async def next_ordered(self) -> list[Change[N]]:
        """Mixed mode: wait until an ordered change is pending, then take the ordered ones."""
        while not self._ordered:
            self._ordered_event.clear()
            await self._ordered_event.wait()
        return self.take_ordered()

    async def next_latest(self, limit: int) -> list[Change[N]]:
        """Wait until a latest sample is pending, then take up to `limit` of them."""
        while not self._latest:
            self._event.clear()
            await self._event.wait()
        return self.take_latest(limit)

    def close(self) -> None:
        self._hub.unsubscribe(self)


class ChangeHub(Generic[N]):
    def __init__(self) -> None:
        self._subs: tuple[Subscription[N], ...] = ()
        self._pushes: tuple[Callable[[N, Sample], None], ...] = ()

    def subscribe(
        self,
        name: str,
        *,
        every_change: bool = False,
        limit: int = 100_000,
        ordered: Collection[N] | None = None,
        tally: Mapping[N, Hashable] | None = None,
    ) -> Subscription[N]:
        sub = Subscription(self, name, every_change=every_change, limit=limit, ordered=ordered, tally=tally)
        self._subs = (*self._subs, sub)
        self._pushes = tuple(s.push for s in self._subs)
        return sub

    def unsubscribe(self, sub: Subscription[N]) -> None:
        self._subs = tuple(s for s in self._subs if s is not sub)
        self._pushes = tuple(s.push for s in self._subs)

    @property
    def subscriptions(self) -> tuple[Subscription[N], ...]:
        return self._subs

    def publish(self, node: N, sample: Sample) -> None:
        for push in self._pushes:
            push(node, sample)
