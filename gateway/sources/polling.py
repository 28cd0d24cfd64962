"""What the polled drivers (Modbus TCP, S7) share: polling groups on one connection, and reconnecting.

A polled driver reads its variables in groups, one per `sampling_interval`, over one connection to the
device. `Poller.run()` connects, polls until the connection fails, reports the outage once (OutageLog),
waits as gateway.reconnect's backoff says, and connects again; it never raises for device trouble. Its
scheduler runs each group when it is due; a group whose cycle overran starts its next at once and
counts the overrun (missed cycles are not made up, so a slow device is polled as often as it can be,
not in bursts). The driver says how to connect, how to close, and what one cycle of a group reads.
"""

from __future__ import annotations

import asyncio
import logging
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

from gateway.errors import SourceError
from gateway.model.tree import Machine
from gateway.reconnect import Backoff, BackoffShape, OutageLog

F = TypeVar("F")  # a driver's field (where a variable's value is)
R = TypeVar("R")  # a driver's planned read

# A status that names what went wrong with the connection itself; other failures read as BadNotConnected.
_LINK_STATUSES = frozenset({"BadTimeout", "BadCommunicationError"})


class PolledSettings(Protocol):
    @property
    def endpoint(self) -> str: ...

    @property
    def reconnect(self) -> BackoffShape: ...


@dataclass(slots=True)
class Group(Generic[F, R]):
    """The variables polled at one interval: their fields (keyed by tree node), and the reads planned."""

    interval: float  # s
    fields: list[tuple[Any, F]]
    isolated: set[Any] = field(default_factory=set)  # keys read alone after the device refused them
    reads: list[R] = field(default_factory=list)
    due: float = 0.0
    cycles: int = 0
    overruns: int = 0  # cycles that ended after the next one was due


class Poller(ABC, Generic[F, R]):
    machine: Machine
    groups: list[Group[F, R]]

    def __init__(self, machine: Machine, settings: PolledSettings, log: logging.Logger) -> None:
        self.machine = machine
        self.settings = settings
        self.log = log
        self.groups = []
        self._outage = OutageLog(log)
        self._connected = False

    @abstractmethod
    async def connect(self) -> None:
        """Open the connection (and plan what depends on it); SourceError if the device cannot be reached."""

    @abstractmethod
    async def close(self) -> None:
        """Close the connection, quietly."""

    @abstractmethod
    async def cycle(self, group: Group[F, R]) -> None:
        """Read a group once; SourceError ends the connection."""

    @abstractmethod
    def forget(self) -> None:
        """Forget the last values read: after a reconnect every value goes to the tree again."""

    def describe(self) -> str:
        """The connection's plan, for the line that says the device is back."""
        return ""

    async def run(self) -> None:
        backoff = Backoff.of(self.settings.reconnect, stable_after=10.0)
        while True:
            self.machine.status.connecting()
            try:
                await self.connect()
                self._up(backoff)
                await self._poll()
            except SourceError as exc:
                self._drop(exc.reason, exc.status)
            finally:
                await self.close()
            backoff.ended()
            await asyncio.sleep(backoff.next())

    async def stopped(self) -> None:
        """The gateway stops: close, and say the machine is disconnected."""
        await self.close()
        if self._connected:
            self._connected = False
            self.machine.status.disconnected("gateway stopped")

    def _up(self, backoff: Backoff) -> None:
        self._connected = True
        backoff.connected()
        self.machine.status.connected()
        self.forget()
        plan = self.describe()
        self._outage.recovered("%s: polling %s%s", self.machine.name, self.settings.endpoint,
                               f" ({plan})" if plan else "")  # fmt: skip

    def _drop(self, reason: str, status: str) -> None:
        was = self._connected
        self._connected = False
        self.machine.invalidate(status if status in _LINK_STATUSES else "BadNotConnected", reason)
        self.machine.status.disconnected(reason)
        name, where = self.machine.name, self.settings.endpoint
        if was:
            self._outage.failed(reason, "%s: lost %s: %s; reconnecting", name, where, reason)
        else:
            self._outage.failed(reason, "%s: cannot reach %s: %s; will keep retrying", name, where, reason)

    async def _poll(self) -> None:
        now = time.monotonic()
        for group in self.groups:
            group.due = now
        while True:
            group = min(self.groups, key=lambda g: g.due)
            delay = group.due - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            await self.cycle(group)
            group.cycles += 1
            group.due += group.interval
            now = time.monotonic()
            if group.due < now:
                group.overruns += 1
                group.due = now
