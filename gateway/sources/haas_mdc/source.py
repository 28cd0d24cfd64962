"""`HaasMdcSource`: a Haas NGC read with Q-commands over its MDC port, polled in groups, changes only.

One connection (the control takes two and answers both: the other is left to others), one query at a
time; variables are grouped by `sampling_interval`, a group's distinct queries asked in turn each
cycle (Q500's three fields are one query). Values are stamped with the time of the answer. An answer
the control refuses (`?`) or one that does not hold the value turns its variables Bad with the reason;
a broken or silent connection drops the control: every variable Bad, reconnect with backoff
(gateway/reconnect.py). Q600 variables with `access: readwrite` are written with ?E and read back.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any, Self

from gateway.codecs.haas_mdc.protocol import Item, MdcError, Query, parse_address, value_of
from gateway.errors import ControllerRefused, ControllerUnavailable, SourceError, TypeMismatch
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.reconnect import Backoff, OutageLog
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.controller_values import fit
from gateway.sources.haas_mdc.config import HaasMdcDriver
from gateway.sources.haas_mdc.connection import MdcConnection

log = logging.getLogger("gateway.sources.haas_mdc")


class HaasMdcSource:
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.machine = machine
        self.driver = settings_of(mapping, HaasMdcDriver)
        self.items: dict[VariableNode, Item] = {}
        specs = {v.path: v for v in mapping.variables}
        groups: dict[float, list[tuple[VariableNode, Item]]] = {}
        for node in machine.mapped:
            item = parse_address(node.definition.source)
            self.items[node] = item
            interval = mapping.sampling_interval(specs[node.path])
            groups.setdefault(max(interval, 50.0) / 1000.0, []).append((node, item))
        self.groups = sorted(groups.items())
        self.connection: MdcConnection | None = None
        self.cycles = 0
        self._last: dict[VariableNode, Any] = {}
        self._outage = OutageLog(log)
        self._connected = False

    def __repr__(self) -> str:
        return f"<HaasMdcSource {self.machine.name} {self.driver.endpoint}>"

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None
        if self.connection is not None:
            self.connection.close()
        if self._connected:
            self._connected = False
            self.machine.status.disconnected("gateway stopped")

    async def run(self) -> None:
        backoff = Backoff.of(self.driver.reconnect, stable_after=10.0)
        while True:
            self.machine.status.connecting()
            d = self.driver
            connection = MdcConnection(d.host, d.port, d.timeout)
            try:
                await connection.open()
                self.connection = connection
                await self._first_answer(connection)
                self._connected = True
                backoff.connected()
                self.machine.status.connected()
                self._outage.recovered("%s: reading the Haas at %s", self.machine.name, d.endpoint)
                async with asyncio.TaskGroup() as tasks:
                    for interval, entries in self.groups:
                        tasks.create_task(self._poll(connection, interval, entries))
            except* SourceError as group:
                first = group.exceptions[0]
                self._drop(first.reason if isinstance(first, SourceError) else str(first))
            finally:
                connection.close()
                self.connection = None
            backoff.ended()
            await asyncio.sleep(backoff.next())

    async def _first_answer(self, connection: MdcConnection) -> None:
        """Haas: 'for the initial connection, ?Q100 may have to be entered twice'."""
        try:
            await connection.ask(Query(100))
        except SourceError:
            if not connection.is_open:
                await connection.open()
            await connection.ask(Query(100))

    async def _poll(
        self, connection: MdcConnection, interval: float, entries: list[tuple[VariableNode, Item]]
    ) -> None:
        queries: dict[Query, list[tuple[VariableNode, Item]]] = {}
        for node, item in entries:
            queries.setdefault(item.query, []).append((node, item))
        due = time.monotonic()
        while True:
            for query, users in queries.items():
                reply = await connection.ask(query)
                stamp = utcnow()
                for node, item in users:
                    try:
                        self._ingest(node, value_of(item, reply), stamp)
                    except MdcError as exc:
                        self._bad(
                            node,
                            "BadDataUnavailable" if reply.label == "STATUS" else "BadNoData",
                            exc.reason,
                            stamp,
                        )
            self.cycles += 1
            due += interval
            now = time.monotonic()
            due = max(due, now)
            await asyncio.sleep(due - now)

    def _ingest(self, node: VariableNode, value: Any, stamp: Any) -> None:
        if self._last.get(node) == value and type(self._last.get(node)) is type(value):
            return
        self._last[node] = value
        try:
            raw = fit(node, value)
        except TypeError as exc:
            self.machine.ingest(node, None, stamp, "BadTypeMismatch", str(exc))
            return
        self.machine.ingest(node, raw, stamp)

    def _bad(self, node: VariableNode, status: str, reason: str, stamp: Any) -> None:
        key = ("bad", reason)
        if self._last.get(node) != key:
            self._last[node] = key
            self.machine.ingest(node, None, stamp, status, reason)

    def _drop(self, reason: str) -> None:
        was = self._connected
        self._connected = False
        self._last.clear()
        self.machine.invalidate("BadNotConnected", reason)
        self.machine.status.disconnected(reason)
        name, where = self.machine.name, self.driver.endpoint
        if was:
            self._outage.failed(reason, "%s: lost the Haas at %s: %s; reconnecting", name, where, reason)
        else:
            self._outage.failed(reason, "%s: cannot reach the Haas at %s: %s; will keep retrying",
                                name, where, reason)  # fmt: skip

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        item = self.items.get(node)
        if item is None or not item.writable or item.variable is None:
            raise ControllerRefused(
                f"{node.full_path}: only Q600 variables are written (?E)", status="BadNotWritable"
            )
        if isinstance(raw, bool) or not isinstance(raw, (int, float)):
            raise TypeMismatch(f"{node.full_path}: a macro takes a number, not {raw!r}")
        connection = self.connection
        if connection is None:
            raise ControllerUnavailable(f"{node.full_path}: not connected to {self.driver.endpoint}")
        try:
            answer = await connection.ask(Query(600, item.variable, float(raw)))
            if answer.label != "!":
                raise ControllerRefused(
                    f"{node.full_path}: the control refused ?E{item.variable}: {answer.text[:60]}"
                )
            back = await connection.ask(item.query)
        except SourceError as exc:
            raise ControllerUnavailable(f"{node.full_path}: {exc.reason}") from None
        try:
            return ReadBack(fit(node, value_of(item, back)), utcnow(), hold=1.0)
        except (MdcError, TypeError):
            return None
