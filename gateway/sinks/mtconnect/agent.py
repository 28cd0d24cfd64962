"""The agent's state and answers, without HTTP: the buffer fed from the tree, and a document per request.

`Agent.feed()` turns the tree's changes into observations (through the profile's
bindings: value words, unit conversion, UNAVAILABLE for a Bad sample), `on_event()`
the gateway's alarms into the SYSTEM condition and the job queue's programs into File
assets. `answer(target, accept)` is /probe, /current, /sample and /assets as one
`Answer` (status, content type, body); streaming (http.py) calls `chunk()` per part.
Waiting streams are woken through `changed()`, which never blocks the feed.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

from gateway.codecs.mtconnect.assets import Asset, AssetRejected, make_asset, removed_copy
from gateway.codecs.mtconnect.buffer import Entry, ObservationBuffer, Window
from gateway.codecs.mtconnect.conditions import ActiveCondition, parse_condition_text
from gateway.codecs.mtconnect.documents import (
    DocumentInfo,
    assets_xml,
    devices_xml,
    error_xml,
    streams_xml,
)
from gateway.codecs.mtconnect.errors import ErrorCode, RequestError, ValueRejected
from gateway.codecs.mtconnect.json_documents import assets_json, devices_json, error_json, streams_json
from gateway.codecs.mtconnect.model import Catalog, Category
from gateway.codecs.mtconnect.paths import PathIndex
from gateway.codecs.mtconnect.queries import Request, parse_request, resolve_device, select_items
from gateway.codecs.mtconnect.timestamps import format_timestamp
from gateway.codecs.mtconnect.vocabulary import UNAVAILABLE, RawValue
from gateway.codecs.mtconnect.xmltext import xml_attr, xml_text
from gateway.model.events import Event
from gateway.model.sample import Sample, utcnow
from gateway.model.tree import VariableNode
from gateway.settings.mtconnect import value_key
from gateway.sinks.mtconnect.config import AgentConfig
from gateway.sinks.mtconnect.profile import Binding, DeviceItems, Profile

log = logging.getLogger("gateway.sinks.mtconnect")

XML = "text/xml; charset=utf-8"
JSON = "application/json; charset=utf-8"
ALARMS_ACTIVE = "alarms/active"
JOB_PREFIX = "jobs/J"


@dataclass(frozen=True, slots=True)
class Answer:
    status: int
    content_type: str
    body: str


def new_instance_id() -> int:
    """A fresh instanceId: the time in milliseconds, so that two runs a second apart still differ."""
    return time.time_ns() // 1_000_000


class Agent:
    def __init__(
        self,
        profile: Profile,
        config: AgentConfig,
        *,
        instance_id: int | None = None,
        sender: str | None = None,
    ) -> None:
        self.profile = profile
        self.config = config
        self.catalog = Catalog(profile.devices)
        for items in profile.machines.values():
            items.item_ids = sorted(self.catalog.device_items(items.device))
        self.buffer = ObservationBuffer(
            self.catalog, instance_id=instance_id or new_instance_id(), size=config.buffer_size
        )
        self.index = PathIndex(self.catalog)
        self.sender = sender or config.sender or socket.gethostname()
        self.model_time = format_timestamp(utcnow())
        self.rejected = 0  # values a data item could not hold (logged once per item)
        self._rejected_items: set[str] = set()
        self._selections: dict[tuple[str | None, str | None], frozenset[str] | None] = {}
        self._conditions: dict[str, dict[str, ActiveCondition]] = {}  # item id -> active, by key
        self._alarms: dict[str, list[ActiveCondition]] = {}  # machine -> its active alarms, as conditions
        self._connected: dict[str, bool] = {}
        self.assets: OrderedDict[str, Asset] = OrderedDict()
        self._wake = asyncio.Event()

    # --- waking streams -------------------------------------------------------------------------

    def changed(self) -> asyncio.Event:
        """An event set at the next change (each waiter takes the current one, then waits)."""
        return self._wake

    def notify(self) -> None:
        wake, self._wake = self._wake, asyncio.Event()
        wake.set()

    def info(self) -> DocumentInfo:
        return DocumentInfo(self.sender, format_timestamp(utcnow()), self.model_time)

    # --- from the tree --------------------------------------------------------------------------

    def start(self, nodes: Iterable[VariableNode]) -> None:
        """Every data item UNAVAILABLE, then what the tree holds now (the feed brings the rest)."""
        self.buffer.add_unavailable(self.catalog.items, utcnow())
        for node in nodes:
            self.feed_one(node, node.sample)
        self.notify()

    def feed(self, batch: Sequence[tuple[VariableNode, Sample]]) -> None:
        for node, sample in batch:
            self.feed_one(node, sample)
        if batch:
            self.notify()

    def feed_one(self, node: VariableNode, sample: Sample) -> None:
        binding = self.profile.bindings.get(node)
        if binding is None:
            machine = self.profile.connected.get(node)
            if machine is not None:
                self._availability(machine, bool(sample.value) and sample.good, sample.source_ts)
            return
        if not sample.good:
            self._unavailable(binding.item_id, sample.source_ts)
            return
        if binding.category is Category.CONDITION:
            self._condition_value(binding, sample)
            return
        value = _value(binding, sample.value)
        try:
            self.buffer.add_value(binding.item_id, sample.source_ts, value)
        except ValueRejected as exc:
            self._rejected(binding.item_id, exc)
            self.buffer.add_value(binding.item_id, sample.source_ts, None)

    def _rejected(self, item_id: str, exc: Exception) -> None:
        self.rejected += 1
        if item_id not in self._rejected_items:
            self._rejected_items.add(item_id)
            log.warning("MTConnect: %s is UNAVAILABLE: %s (said once per data item)", item_id, exc)

    def _unavailable(self, item_id: str, ts: datetime) -> None:
        self._conditions.pop(item_id, None)
        self.buffer.add_unavailable((item_id,), ts)

    def _availability(self, machine: str, up: bool, ts: datetime) -> None:
        items = self.profile.machines[machine]
        was = self._connected.get(machine)
        self._connected[machine] = up
        if up:
            self.buffer.add_value(items.availability, ts, "AVAILABLE")
            if items.system is not None and was is not True:  # the alarms as last heard, now known again
                self._set_conditions(items.system, self._alarms.get(machine, []), ts)
        else:
            self.buffer.add_value(items.availability, ts, None)
            if items.system is not None:
                self._unavailable(items.system, ts)

    def _condition_value(self, binding: Binding, sample: Sample) -> None:
        value = sample.value
        active: list[ActiveCondition] = []
        if isinstance(value, list):
            for text in value:
                try:
                    active.append(parse_condition_text(str(text)))
                except ValueError as exc:
                    self._rejected(binding.item_id, exc)
        elif isinstance(value, bool):
            if value:
                active.append(ActiveCondition("FAULT", condition_id=binding.item_id))
        elif isinstance(value, str):
            word = (binding.values or {}).get(value, value).upper()
            if word in ("WARNING", "FAULT"):
                active.append(ActiveCondition(word, condition_id=binding.item_id))
            elif word == UNAVAILABLE:
                self._unavailable(binding.item_id, sample.source_ts)
                return
        self._set_conditions(binding.item_id, active, sample.source_ts)

    def _set_conditions(self, item_id: str, active: list[ActiveCondition], ts: datetime) -> None:
        """Make the item's active conditions `active`: Normal for those gone, the new ones raised."""
        now = {c.key: c for c in active}
        before = self._conditions.get(item_id)
        self._conditions[item_id] = now
        add = self.buffer.add_condition
        stamp = format_timestamp(ts)
        if not now:
            add(item_id, stamp, "NORMAL")
            return
        for key, old in (before or {}).items():
            if key not in now:
                add(item_id, stamp, "NORMAL", native_code=old.native_code, condition_id=key)
        for key, c in now.items():
            add(item_id, stamp, c.level, native_code=c.native_code, native_severity=c.native_severity,
                qualifier=c.qualifier, condition_id=key, text=c.text)  # fmt: skip

    def on_event(self, event: Event) -> None:
        """The gateway's alarms (SYSTEM condition) and the job queue's programs (File assets)."""
        machine = event.machine
        if machine is None:
            return
        items = self.profile.machines.get(machine)
        if items is None:
            return
        if event.channel == ALARMS_ACTIVE and items.system is not None:
            self._alarm_list(items, event)
        elif event.channel.startswith(JOB_PREFIX) and items.asset_changed is not None:
            self._job_asset(items, event)

    def _alarm_list(self, items: DeviceItems, event: Event) -> None:
        payload = event.payload if isinstance(event.payload, list) else []
        active: list[ActiveCondition] = []
        for record in payload:
            if not isinstance(record, Mapping) or not record.get("active"):
                continue
            severity = record.get("severity")
            fault = isinstance(severity, int) and severity >= self.config.fault_severity
            cls = record.get("class")
            active.append(
                ActiveCondition(
                    "FAULT" if fault else "WARNING",
                    native_code=str(record.get("id", "")) or None,
                    native_severity=str(cls if cls is not None else severity),
                    text=str(record.get("text", "")),
                    condition_id=str(record.get("id", "")) or None,
                )
            )
        self._alarms[items.machine] = active
        if self._connected.get(items.machine) and items.system is not None:
            self._set_conditions(items.system, active, event.ts)
            self.notify()

    def _job_asset(self, items: DeviceItems, event: Event) -> None:
        asset_id = event.channel.removeprefix("jobs/")
        stamp = format_timestamp(event.ts)
        record = event.payload
        assert items.asset_changed is not None and items.asset_removed is not None
        if record is None:
            old = self.assets.pop(asset_id, None)
            if old is not None:
                self.assets[asset_id] = removed_copy(old, stamp)
                self.buffer.add_value(items.asset_removed, stamp, asset_id, asset_type="File")
                self.notify()
            return
        if not isinstance(record, Mapping):
            return
        try:
            asset = make_asset(
                _file_asset(record, stamp),
                asset_id=asset_id,
                asset_type="File",
                timestamp=stamp,
                device_uuid=items.device.uuid,
            )
        except AssetRejected as exc:
            log.warning("MTConnect: job %s is not served as an asset: %s", asset_id, exc)
            return
        known = self.assets.pop(asset_id, None)
        self.assets[asset_id] = asset
        while len(self.assets) > self.config.asset_buffer_size:
            self.assets.popitem(last=False)
        if known is None or known.xml != asset.xml:
            self.buffer.add_value(items.asset_changed, stamp, asset_id, asset_type="File")
            self.notify()

    # --- answers ---------------------------------------------------------------------------------

    def answer(self, target: str, accept: str = "") -> Answer:
        """One request (path and query) as its document; a refusal as an MTConnectError document."""
        json_wanted = _wants_json(target, accept)
        try:
            request = self.request(target, accept)
            if request.kind == "probe":
                return self.probe(request)
            if request.kind == "current":
                return self.current(request)
            if request.kind == "sample":
                return self.sample(request)
            return self.asset_answer(request)
        except RequestError as exc:
            return self.error([exc], "json" if json_wanted else "xml")

    def request(self, target: str, accept: str = "") -> Request:
        """The checked request, with the format the Accept header asks for unless `format=` says one."""
        request = parse_request(target)
        if request.format != "json" and _wants_json(target, accept):
            request = replace(request, format="json")
        return request

    def error(self, errors: Sequence[RequestError], fmt: str = "xml", status: int | None = None) -> Answer:
        info = self.info()
        size = self.buffer.size
        code = status or errors[0].http_status
        if fmt == "json":
            return Answer(
                code, JSON, error_json(errors, info, instance_id=self.buffer.instance_id, buffer_size=size)
            )
        return Answer(
            code, XML, error_xml(errors, info, instance_id=self.buffer.instance_id, buffer_size=size)
        )

    def probe(self, request: Request) -> Answer:
        device = resolve_device(self.catalog, request.device)
        args: dict[str, Any] = {
            "instance_id": self.buffer.instance_id,
            "buffer_size": self.buffer.size,
            "asset_buffer_size": self.config.asset_buffer_size,
            "asset_count": len(self.assets),
            "devices": None if device is None else [device],
        }
        if request.format == "json":
            return Answer(200, JSON, devices_json(self.catalog, self.info(), **args))
        return Answer(200, XML, devices_xml(self.catalog, self.info(), **args))

    def items(self, request: Request) -> frozenset[str] | None:
        key = (request.device, request.path)
        if key not in self._selections:
            self._selections[key] = select_items(request, self.catalog, self.index)
        return self._selections[key]

    def current(self, request: Request) -> Answer:
        entries, window = self.buffer.current(self.items(request), request.at)
        return self.streams(request.format, entries, window)

    def sample(self, request: Request) -> Answer:
        result = self.buffer.sample(
            self.items(request), from_=request.from_, count=request.count, to=request.to
        )
        return self.streams(request.format, result.entries, result.window)

    def streams(self, fmt: str, entries: Iterable[Entry], window: Window) -> Answer:
        if fmt == "json":
            return Answer(200, JSON, streams_json(self.catalog, entries, window, self.info()))
        return Answer(200, XML, streams_xml(self.catalog, entries, window, self.info()))

    def asset_answer(self, request: Request) -> Answer:
        device = resolve_device(self.catalog, request.device)
        if request.asset_ids:
            missing = [i for i in request.asset_ids if i not in self.assets]
            if missing:
                raise RequestError(ErrorCode.ASSET_NOT_FOUND, f"no asset {missing[0][:80]!r}")
            chosen = [self.assets[i] for i in request.asset_ids]
        else:
            chosen = [
                a
                for a in reversed(self.assets.values())
                if (request.removed or not a.removed)
                and (request.asset_type is None or a.type == request.asset_type)
                and (device is None or a.device_uuid == device.uuid)
            ]
            if request.count <= 0:
                raise RequestError(ErrorCode.INVALID_REQUEST, "'count' must be positive for assets")
            chosen = chosen[: request.count]
        args: dict[str, Any] = {
            "instance_id": self.buffer.instance_id,
            "asset_buffer_size": self.config.asset_buffer_size,
            "asset_count": len(self.assets),
        }
        if request.format == "json":
            return Answer(200, JSON, assets_json(chosen, self.info(), **args))
        return Answer(200, XML, assets_xml(chosen, self.info(), **args))


def _wants_json(target: str, accept: str) -> bool:
    if "format=" in target:
        return "format=json" in target.lower()
    accept = accept.lower()
    return "application/json" in accept and "xml" not in accept


def _value(binding: Binding, value: Any) -> RawValue:
    if binding.values is not None:
        key = value_key(value)
        return binding.values.get(key, key)
    if binding.converts and not isinstance(value, bool):
        scale, offset = binding.scale, binding.offset
        if isinstance(value, (int, float)):
            return value * scale + offset
        if isinstance(value, list):
            return [v * scale + offset for v in value if isinstance(v, (int, float))]
    if isinstance(value, list):
        if binding.category is Category.SAMPLE:
            return value
        return " ".join(value_key(v) for v in value)
    result: RawValue = value
    return result


def _file_asset(record: Mapping[str, Any], stamp: str) -> str:
    """A job's program as a minimal MTConnect File asset (the 2.4 schema's required parts)."""

    def text(value: Any) -> str:
        return "" if value is None else str(value)

    name = xml_attr(text(record.get("program_name") or record.get("filename") or "program"))
    size = int(record.get("program_size") or record.get("size") or 0)
    version = xml_attr(text(record.get("program_sha256") or record.get("sha256"))[:16] or "1")
    created = xml_text(_utc(text(record.get("received_at")) or stamp))
    job = text(record.get("id"))
    comment = xml_text(f"job {job}: {text(record.get('state')) or 'QUEUED'}")
    return (
        f'<File name="{name}" mediaType="text/plain" applicationCategory="DEVICE"'
        f' applicationType="PRODUCTION_PROGRAM" size="{size}" versionId="{version}" state="PRODUCTION">'
        f'<FileComments><FileComment timestamp="{stamp}">{comment}</FileComment></FileComments>'
        f'<FileLocation href="{xml_attr("jobs/" + job)}"/><CreationTime>{created}</CreationTime></File>'
    )


def _utc(text: str) -> str:
    try:
        return format_timestamp(datetime.fromisoformat(text))
    except ValueError:
        return text
