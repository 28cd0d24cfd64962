"""`FocasSource`: a Fanuc read over FOCAS2 Ethernet, polled in groups, changes only.

Variables are grouped by their `sampling_interval`; each group is planned once
(gateway/codecs/focas/plan.py: items that one function answers share its command, nearby macros and
PMC bytes are read as ranges) and polled as one multi-command request per cycle (or a few, at
`max_commands` each), on a session from the pool. Values are stamped with the time the answer came.
A command the controller refuses makes its items Bad with the controller's reason (EW_NUMBER: no
such macro, ...), the rest of the group goes on; a broken session drops the controller like the OPC
UA source does: every variable Bad, reconnect with backoff (gateway/reconnect.py), an outage logged
once. Writes (macros, PMC, program.select/start) go through the checked write path and are read back.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Sequence
from typing import Any, Self

from gateway.codecs.focas.address import Item, parse_address
from gateway.codecs.focas.commands import Reply
from gateway.codecs.focas.errors import EW_BUSY, EW_DATA, EW_FUNC, EW_NOOPT, EW_NUMBER, FocasError, describe
from gateway.codecs.focas.plan import Outcome, Plan, make_plan
from gateway.codecs.focas.writes import (
    NotWritableItem,
    ValueTooLarge,
    WrongValueType,
    pmc_read_byte,
    write_commands,
)
from gateway.errors import ControllerRefused, ControllerUnavailable, OutOfRange, SourceError, TypeMismatch
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.reconnect import Backoff, OutageLog
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.controller_values import fit
from gateway.sources.focas.config import FocasDriver
from gateway.sources.focas.pool import SessionPool

log = logging.getLogger("gateway.sources.focas")

#: A controller's refusal of a read, as the status a variable shows.
STATUS_OF = {EW_FUNC: "BadNotSupported", EW_NOOPT: "BadNotSupported", EW_NUMBER: "BadNodeIdUnknown",
             EW_DATA: "BadDataUnavailable", EW_BUSY: "BadResourceUnavailable"}  # fmt: skip


class Group:
    """The variables polled at one interval, and their plan."""

    def __init__(self, interval: float, entries: list[tuple[VariableNode, Item]], max_alarms: int) -> None:
        self.interval = interval  # s
        self.entries = entries
        self.plan: Plan = make_plan([item for _, item in entries], max_alarms)
        self.cycles = 0
        self.late = 0  # cycles that started after their time (the previous one overran)


class FocasSource:
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.machine = machine
        self.driver = settings_of(mapping, FocasDriver)
        d = self.driver
        self.pool = SessionPool(d.host, d.port, d.timeout, d.sessions)
        self.items: dict[VariableNode, Item] = {}
        specs = {v.path: v for v in mapping.variables}
        by_interval: dict[float, list[tuple[VariableNode, Item]]] = {}
        for node in machine.mapped:
            item = parse_address(node.definition.source)  # the loader checked it
            self.items[node] = item
            interval = mapping.sampling_interval(specs[node.path])
            by_interval.setdefault(max(interval, 10.0) / 1000.0, []).append((node, item))
        self.groups = [Group(i, e, d.max_alarms) for i, e in sorted(by_interval.items())]
        self._last: dict[VariableNode, Any] = {}
        self._outage = OutageLog(log)
        self._connected = False

    def __repr__(self) -> str:
        return f"<FocasSource {self.machine.name} {self.driver.endpoint}>"

    @property
    def requests(self) -> int:
        """Round trips made (a multi-command request is one)."""
        return self.pool.requests

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None
        await self.pool.close()
        if self._connected:
            self._connected = False
            self.machine.status.disconnected("gateway stopped")

    async def run(self) -> None:
        backoff = Backoff.of(self.driver.reconnect, stable_after=10.0)
        while True:
            self.machine.status.connecting()
            try:
                await self._connected_run(backoff)
            except SourceError as exc:
                self._drop(exc.reason)
            finally:
                await self.pool.close()
            backoff.ended()
            await asyncio.sleep(backoff.next())

    async def _connected_run(self, backoff: Backoff) -> None:
        async with self.pool.session() as session:
            sysinfo = session.sysinfo
        self._connected = True
        backoff.connected()
        self.machine.status.connected()
        what = f"{sysinfo.cnc_type}{sysinfo.mt_type} {sysinfo.series} {sysinfo.version}" if sysinfo else "?"
        self._outage.recovered(
            "%s: reading the Fanuc at %s (%s)", self.machine.name, self.driver.endpoint, what
        )
        try:
            async with asyncio.TaskGroup() as tasks:
                for group in self.groups:
                    tasks.create_task(self._poll(group), name=f"focas:{self.machine.name}:{group.interval:g}")
        except* SourceError as group:
            raise group.exceptions[0] from None

    async def _poll(self, group: Group) -> None:
        due = time.monotonic()
        plan = group.plan
        batches = plan.batches(self.driver.max_commands)
        while True:
            replies: list[Reply] = []
            async with self.pool.session() as session:
                for batch in batches:
                    replies += await session.request(batch)
                context = session.context
            stamp = utcnow()
            try:
                outcomes = plan.outcomes(replies, context)
            except FocasError as exc:
                raise SourceError(f"unreadable answer: {exc.reason}") from None
            self._ingest(group.entries, outcomes, stamp)
            group.cycles += 1
            due += group.interval
            now = time.monotonic()
            if now > due:
                group.late += 1
                due = now
            await asyncio.sleep(due - now)

    def _ingest(
        self, entries: Sequence[tuple[VariableNode, Item]], outcomes: Sequence[Outcome], stamp: Any
    ) -> None:
        last = self._last
        machine = self.machine
        for (node, _), outcome in zip(entries, outcomes, strict=True):
            if outcome.error:
                key = ("bad", outcome.error)
                if last.get(node) != key:
                    last[node] = key
                    machine.ingest(
                        node, None, stamp, STATUS_OF.get(outcome.error, "BadDeviceFailure"), outcome.reason
                    )
                continue
            value = outcome.value
            if last.get(node) == value and type(last.get(node)) is type(value):
                continue
            last[node] = value
            try:
                raw = fit(node, value)
            except TypeError as exc:
                machine.ingest(node, None, stamp, "BadTypeMismatch", str(exc))
                continue
            machine.ingest(node, raw, stamp)

    def _drop(self, reason: str) -> None:
        was = self._connected
        self._connected = False
        self._last.clear()
        self.machine.invalidate("BadNotConnected", reason)
        self.machine.status.disconnected(reason)
        name, where = self.machine.name, self.driver.endpoint
        if was:
            self._outage.failed(reason, "%s: lost the Fanuc at %s: %s; reconnecting", name, where, reason)
        else:
            self._outage.failed(reason, "%s: cannot reach the Fanuc at %s: %s; will keep retrying",
                                name, where, reason)  # fmt: skip

    # --- writes ------------------------------------------------------------------------------

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        item = self.items.get(node)
        if item is None:
            raise ControllerRefused(f"{node.full_path} is not a FOCAS variable", status="BadNotWritable")
        folder = self.driver.folder
        try:
            async with self.pool.session() as session:
                current = None
                if item.kind == "pmc" and item.bit is not None:
                    (reply,) = await session.request([pmc_read_byte(item)])
                    _refused(node, reply)
                    current = reply.data[0] if reply.data else 0
                try:
                    commands = write_commands(item, raw, folder, current)
                except NotWritableItem as exc:
                    kind = {WrongValueType: TypeMismatch, ValueTooLarge: OutOfRange}.get(
                        type(exc), ControllerRefused
                    )
                    raise kind(f"{node.full_path}: {exc}") from None
                for reply in await session.request(commands) if commands else []:
                    _refused(node, reply)
                if item.kind == "program":
                    return None  # the next poll shows what it did
                plan = make_plan([item], self.driver.max_alarms)
                replies = await session.request(plan.commands)
                context = session.context
        except SourceError as exc:
            raise ControllerUnavailable(f"{node.full_path}: {exc.reason}") from None
        (outcome,) = plan.outcomes(replies, context)
        if outcome.error:
            return None
        try:
            return ReadBack(fit(node, outcome.value), utcnow(), hold=1.0)
        except TypeError:
            return None


def _refused(node: VariableNode, reply: Reply) -> None:
    if reply.error:
        kind = OutOfRange if reply.error == EW_NUMBER else ControllerRefused
        raise kind(f"{node.full_path}: the controller refused: {describe(reply.error)}")
