"""The SHDR driver: a machine read straight from its MTConnect adapter (`driver: {type: shdr, host, port}`).

An adapter listens (usually on 7878) and, once an agent connects, sends every value
it has, then each change, as pipe-delimited lines (gateway/codecs/mtconnect/shdr.py).
This driver is that agent for one machine: it connects, sends `* PING`, answers the
adapter's period with PINGs (AgentHeartbeat) and drops the connection when two periods
pass without a PONG (or, for an adapter that never answers, `legacy_timeout` without a
line). Each variable's `source` is its SHDR key (`Xact`, or `device:Xact`); a variable
whose `mtconnect:` key says CONDITION reads the five condition fields, MESSAGE the two
message fields, a TIME_SERIES representation the three time-series fields.

Lines it cannot read are counted (`junk`) and logged, throttled; keys no variable maps
are counted (`unmapped`) and otherwise ignored. Read-only, as MTConnect is.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any, Self

from gateway.codecs.mtconnect.conditions import ActiveCondition
from gateway.codecs.mtconnect.heartbeat import Action, AgentHeartbeat
from gateway.codecs.mtconnect.shdr import (
    PING,
    ConditionObservation,
    ItemKind,
    Junk,
    MessageObservation,
    Observation,
    Pong,
    ShdrReader,
    TimeSeriesObservation,
)
from gateway.errors import ControllerRefused, SourceError
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.reconnect import Backoff, OutageLog
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.mtconnect.config import ShdrDriver
from gateway.sources.mtconnect.values import Ingest

log = logging.getLogger("gateway.sources.mtconnect")

READ_SIZE = 256 * 1024
JUNK_LOG_EVERY = 10.0  # s between log lines about unreadable lines


class ShdrSource:
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.machine = machine
        self.driver = settings_of(mapping, ShdrDriver)
        self.ingest = Ingest(machine, "the adapter")
        self.keys: dict[str, VariableNode] = {}
        self.kinds: dict[str, ItemKind] = {}
        specs = {v.path: v for v in mapping.variables}
        for node in machine.mapped:
            key = node.definition.source
            self.keys[key] = node
            settings = specs[node.path].mtconnect if node.path in specs else None
            if settings is not None:
                if settings.category == "CONDITION":
                    self.kinds[key] = ItemKind.CONDITION
                elif settings.type == "MESSAGE":
                    self.kinds[key] = ItemKind.MESSAGE
                elif settings.representation == "TIME_SERIES":
                    self.kinds[key] = ItemKind.TIME_SERIES
        self.junk = 0
        self.unmapped = 0
        self.changes = 0  # observations put into the tree
        self._outage = OutageLog(log)
        self._connected = False
        self._junk_said = 0.0

    def __repr__(self) -> str:
        return f"<ShdrSource {self.machine.name} {self.driver.endpoint}>"

    def kind_of(self, key: str) -> ItemKind:
        return self.kinds.get(key) or self.kinds.get(key.partition(":")[2], ItemKind.VALUE)

    async def __aenter__(self) -> Self:
        self.machine.writer = self
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self.machine.writer is self:
            self.machine.writer = None
        if self._connected:
            self._connected = False
            self.machine.status.disconnected("gateway stopped")

    async def write(self, node: VariableNode, raw: Any) -> ReadBack | None:
        raise ControllerRefused(f"{node.full_path}: MTConnect is read-only", status="BadNotWritable")

    async def run(self) -> None:
        backoff = Backoff.of(self.driver.reconnect, stable_after=10.0)
        while True:
            self.machine.status.connecting()
            try:
                await self._session(backoff)
            except SourceError as exc:
                self._drop(exc.reason)
            backoff.ended()
            await asyncio.sleep(backoff.next())

    async def _session(self, backoff: Backoff) -> None:
        d = self.driver
        try:
            async with asyncio.timeout(d.timeout):
                reader, writer = await asyncio.open_connection(d.host, d.port)
        except (OSError, TimeoutError) as exc:
            raise SourceError(_reason(exc)) from None
        try:
            heartbeat = AgentHeartbeat(time.monotonic(), legacy_timeout=d.legacy_timeout)
            writer.write(heartbeat.opening())
            shdr = ShdrReader(self.kind_of)
            self._connected = True
            backoff.connected()
            self.machine.status.connected()
            self._outage.recovered("%s: reading the adapter at %s", self.machine.name, d.endpoint)
            while True:
                wait = max(0.01, heartbeat.next_deadline() - time.monotonic())
                try:
                    async with asyncio.timeout(wait):
                        data = await reader.read(READ_SIZE)
                except TimeoutError:
                    data = None
                except OSError as exc:
                    raise SourceError(_reason(exc)) from None
                now = time.monotonic()
                if data is not None:
                    if not data:
                        self._events(shdr.feed_eof(utcnow()), heartbeat, now)
                        raise SourceError("the adapter closed the connection")
                    heartbeat.on_data(now)
                    self._events(shdr.feed(data, utcnow()), heartbeat, now)
                action = heartbeat.poll(now)
                if action is Action.SEND_PING:
                    writer.write(PING)
                elif action is Action.TIMED_OUT:
                    raise SourceError("the adapter stopped answering (no heartbeat)")
        finally:
            writer.close()
            try:
                async with asyncio.timeout(0.5):
                    await writer.wait_closed()
            except (OSError, TimeoutError):
                pass

    def _events(self, events: list[Any], heartbeat: AgentHeartbeat, now: float) -> None:
        keys = self.keys
        ingest = self.ingest
        for event in events:
            kind = type(event)
            if kind is Observation:
                node = keys.get(event.key) or (
                    keys.get(f"{event.device}:{event.key}") if event.device else None
                )
                if node is None:
                    self.unmapped += 1
                    continue
                ingest.value(node, event.value, event.timestamp)
                self.changes += 1
            elif kind is ConditionObservation:
                node = keys.get(event.key) or (
                    keys.get(f"{event.device}:{event.key}") if event.device else None
                )
                if node is None:
                    self.unmapped += 1
                    continue
                active = ActiveCondition(
                    event.level if event.level in ("WARNING", "FAULT") else "FAULT",
                    event.native_code, event.native_severity, event.qualifier, event.text, event.condition_id,
                )  # fmt: skip
                ingest.condition(node, event.level, event.timestamp, active)
                self.changes += 1
            elif kind is MessageObservation:
                node = keys.get(event.key)
                if node is not None:
                    ingest.value(node, event.text, event.timestamp)
                    self.changes += 1
            elif kind is TimeSeriesObservation:
                node = keys.get(event.key)
                if node is not None:
                    text = " ".join(repr(v) for v in event.values) if event.values else "UNAVAILABLE"
                    ingest.value(node, text, event.timestamp)
                    self.changes += 1
            elif kind is Pong:
                heartbeat.on_pong(event.heartbeat_ms, now)
            elif kind is Junk:
                self.junk += 1
                if now - self._junk_said >= JUNK_LOG_EVERY:
                    self._junk_said = now
                    log.warning("%s: unreadable SHDR line %d from %s: %s (%d so far)", self.machine.name,
                                event.line, self.driver.endpoint, event.reason, self.junk)  # fmt: skip

    def _drop(self, reason: str) -> None:
        was = self._connected
        self._connected = False
        self.machine.invalidate("BadNotConnected", reason)
        self.ingest.forget()
        self.machine.status.disconnected(reason)
        name, where = self.machine.name, self.driver.endpoint
        if was:
            self._outage.failed(reason, "%s: lost the adapter at %s: %s; reconnecting", name, where, reason)
        else:
            self._outage.failed(reason, "%s: cannot reach the adapter at %s: %s; will keep retrying",
                                name, where, reason)  # fmt: skip


def _reason(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "timed out"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, ConnectionResetError):
        return "connection reset"
    return exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
