"""The MTConnect agent driver: a machine read from another agent (`driver: {type: mtconnect, url, device}`).

/probe first (which data items exist; each variable's `source` names one by id or by
name), then /current for the state, then /sample?from=<next>&interval=… as a stream. After
a lost connection it resumes at the sequence where it stopped; the agent says whether it
still holds it. What the driver does not accept silently:

- the agent's instanceId changed (it restarted): the sequences mean nothing any more, so
  it reads /probe and /current again;
- the agent no longer holds the next sequence (OUT_OF_RANGE, or a chunk whose first
  sequence is past it): observations were lost. That is logged as a gap, with how many
  sequences, counted in `gaps`, and the state is read again from /current.

MTConnect is read-only: writes are refused (the loader already refuses `access: readwrite`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence
from typing import Any, Self

from gateway.codecs.mtconnect.conditions import ActiveCondition
from gateway.codecs.mtconnect.model import Category, Device
from gateway.codecs.mtconnect.model import walk as walk_model
from gateway.codecs.mtconnect.responses import (
    AgentErrors,
    ObservedValue,
    ResponseError,
    StreamsDocument,
    parse_devices,
    parse_streams,
)
from gateway.codecs.mtconnect.timestamps import parse_timestamp
from gateway.errors import ControllerRefused, SourceError
from gateway.model.sample import ReadBack, utcnow
from gateway.model.tree import Machine, VariableNode
from gateway.reconnect import Backoff, OutageLog
from gateway.sources.base import DriverMapping, settings_of
from gateway.sources.mtconnect.config import MTConnectDriver
from gateway.sources.mtconnect.http_client import AgentClient
from gateway.sources.mtconnect.values import Ingest

log = logging.getLogger("gateway.sources.mtconnect")

_CONDITION_LEVELS = ("WARNING", "FAULT")


class Gap(Exception):
    """The stream cannot go on without losing observations (reported, then /current again)."""


class Restarted(Exception):
    """The agent's instanceId changed."""


class MTConnectSource:
    def __init__(self, machine: Machine, mapping: DriverMapping) -> None:
        self.machine = machine
        self.mapping = mapping
        self.driver = settings_of(mapping, MTConnectDriver)
        self.ingest = Ingest(machine, "the agent")
        self.instance_id: int | None = None
        self.next_sequence: int | None = None
        self.gaps = 0  # times observations were lost (reported each time)
        self.lost = 0  # sequences lost in those gaps, where the agent said how many
        self.restarts = 0  # instanceId changes seen
        self.resumed = 0  # reconnections that went on where the stream had stopped
        self._items: dict[str, VariableNode] = {}  # data item id -> variable
        self._outage = OutageLog(log)
        self._connected = False

    def __repr__(self) -> str:
        return f"<MTConnectSource {self.machine.name} {self.driver.endpoint}>"

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

    @property
    def prefix(self) -> str:
        return f"/{self.driver.device}" if self.driver.device else ""

    async def run(self) -> None:
        backoff = Backoff.of(self.driver.reconnect, stable_after=10.0)
        while True:
            self.machine.status.connecting()
            try:
                async with AgentClient(self.driver.url, timeout=self.driver.timeout) as client:
                    await self._session(client, backoff)
            except (SourceError, ResponseError) as exc:
                self._drop(exc.reason if isinstance(exc, SourceError) else f"unreadable answer: {exc}")
            backoff.ended()
            await asyncio.sleep(backoff.next())

    async def _session(self, client: AgentClient, backoff: Backoff) -> None:
        while True:
            if self.instance_id is None or self.next_sequence is None:
                await self._probe(client)
                await self._current(client)
                self._up(backoff)
            try:
                await self._follow(client, backoff)
            except Gap as exc:
                self.gaps += 1
                log.warning("%s: a gap in the stream from %s: %s; reading /current again",
                            self.machine.name, self.driver.endpoint, exc)  # fmt: skip
                self.next_sequence = None
            except Restarted as exc:
                self.restarts += 1
                log.warning("%s: %s; reading /probe and /current again", self.machine.name, exc)
                self.instance_id = self.next_sequence = None

    def _up(self, backoff: Backoff) -> None:
        if not self._connected:
            self._connected = True
            backoff.connected()
            self.machine.status.connected()
            self._outage.recovered("%s: following %s (instanceId %s, from sequence %s)", self.machine.name,
                                   self.driver.endpoint, self.instance_id, self.next_sequence)  # fmt: skip

    def _drop(self, reason: str) -> None:
        was = self._connected
        self._connected = False
        self.machine.invalidate("BadNotConnected", reason)
        self.machine.status.disconnected(reason)
        name, where = self.machine.name, self.driver.endpoint
        if was:
            self._outage.failed(reason, "%s: lost %s: %s; reconnecting", name, where, reason)
        else:
            self._outage.failed(reason, "%s: cannot read %s: %s; will keep retrying", name, where, reason)

    # --- the model ---------------------------------------------------------------------------------

    async def _probe(self, client: AgentClient) -> None:
        document = parse_devices(await client.get(f"{self.prefix}/probe"))
        devices = document.devices
        if not devices:
            raise SourceError(f"{self.driver.endpoint}: the agent describes no device")
        device = _pick(devices, self.driver.device)
        if device is None:
            raise SourceError(f"{self.driver.endpoint}: no device {self.driver.device!r} at the agent")
        by_id: dict[str, tuple[str, Category]] = {}
        by_name: dict[str, str] = {}
        for node in walk_model(device):
            for item in node.data_items:
                by_id[item.id] = (item.id, item.category)
                if item.name:
                    by_name.setdefault(item.name, item.id)
        self._items.clear()
        missing: list[str] = []
        now = utcnow()
        for variable in self.machine.mapped:
            source = variable.definition.source
            item_id = source if source in by_id else by_name.get(source)
            if item_id is None:
                missing.append(variable.path)
                reason = f"{self.driver.endpoint} has no data item {source!r} (by id or name)"
                self.machine.ingest(variable, None, now, "BadNodeIdUnknown", reason)
                continue
            self._items[item_id] = variable
        if missing:
            message = f"{len(missing)} variable(s) name no data item of the agent: {', '.join(missing[:3])}"
            log.warning("%s: %s", self.machine.name, message)
            self.machine.status.error(message)
        self.instance_id = document.header.instance_id

    async def _current(self, client: AgentClient) -> None:
        document = parse_streams(await client.get(f"{self.prefix}/current"))
        if document.header.instance_id != self.instance_id:
            raise SourceError(f"{self.driver.endpoint}: the agent restarted while being read")
        self.ingest.forget()
        self._apply(document.observations, snapshot=True)
        self.next_sequence = document.header.next_sequence

    # --- the stream ----------------------------------------------------------------------------------

    async def _follow(self, client: AgentClient, backoff: Backoff) -> None:
        d = self.driver
        start = self.next_sequence
        path = (
            f"{self.prefix}/sample?from={start}&count={d.count}&interval={d.interval}&heartbeat={d.heartbeat}"
        )
        idle = 2 * d.heartbeat / 1000.0 + d.timeout
        first = True
        async for part in client.stream(path, idle):
            try:
                document = parse_streams(part)
            except AgentErrors as exc:
                if exc.instance_id is not None and exc.instance_id != self.instance_id:
                    raise Restarted(
                        f"the agent restarted (instanceId {self.instance_id} -> {exc.instance_id})"
                    ) from None
                if "OUT_OF_RANGE" in exc.codes:
                    raise Gap(f"the agent no longer holds sequence {self.next_sequence} ({exc})") from None
                raise SourceError(f"{d.endpoint}: {exc}") from None
            if first:
                first = False
                if document.header.instance_id == self.instance_id and not self._connected:
                    self.resumed += 1
                    self.ingest.restore()  # the state at `from`; the chunk brings what changed since
            self._chunk(document)
            self._up(backoff)

    def _chunk(self, document: StreamsDocument) -> None:
        header = document.header
        if header.instance_id != self.instance_id:
            raise Restarted(f"the agent restarted (instanceId {self.instance_id} -> {header.instance_id})")
        expected = self.next_sequence
        observations = document.observations
        if expected is not None and header.first_sequence is not None and header.first_sequence > expected:
            self.lost += header.first_sequence - expected
            raise Gap(f"sequences {expected} to {header.first_sequence - 1} were overwritten at the agent")
        if expected is not None and observations and observations[0].sequence < expected:
            observations = [o for o in observations if o.sequence >= expected]
        self._apply(observations)
        if header.next_sequence is not None:
            self.next_sequence = header.next_sequence

    def _apply(self, observations: Sequence[ObservedValue], *, snapshot: bool = False) -> None:
        items = self._items
        ingest = self.ingest
        replaced: set[VariableNode] = set()
        for o in observations:
            node = items.get(o.data_item_id)
            if node is None:
                continue
            ts = parse_timestamp(o.timestamp) or utcnow()
            if o.category is Category.CONDITION:
                level = o.level or "UNAVAILABLE"
                active = None
                if level in _CONDITION_LEVELS or o.native_code or o.condition_id:
                    active = ActiveCondition(
                        level if level in _CONDITION_LEVELS else "FAULT",
                        o.native_code, o.native_severity, o.qualifier, o.value, o.condition_id,
                    )  # fmt: skip
                first = snapshot and node not in replaced
                replaced.add(node)
                ingest.condition(node, level, ts, active, replace=first)
            else:
                ingest.value(node, o.value, ts)


def _pick(devices: list[Device], wanted: str | None) -> Device | None:
    if wanted is None:
        real = [d for d in devices if d.type == "Device"]
        return (real or devices)[0]
    return next((d for d in devices if wanted in (d.name, d.uuid, d.id)), None)
