"""The same documents in MTConnect JSON, version 2 of the reference agent (cppagent `JsonVersion = 2`).

The shape, as cppagent prints it (its JsonPrinter, json version 2):
- the root is `{"MTConnectStreams": {"jsonVersion": 2, "schemaVersion": "2.4", "Header": {...}, ...}}`;
  the Header carries the XML header's attributes as keys, numbers as numbers;
- lists of same-named elements become one key with an array: `"Devices": {"Device": [...]}`,
  `"DataItems": {"DataItem": [...]}`, `"Components": {"Axes": [...], "Controller": [...]}`,
  `"Streams": {"DeviceStream": [{..., "ComponentStream": [{..., "Samples": {"Position": [...]}}]}]}`,
  `"Errors": {"Error": [{"errorCode": ..., "value": ...}]}`;
- an element's attributes are keys, its text is `"value"`; a condition's key is its level
  (`"Condition": {"Fault": [...]}`) with `"type"` inside;
- SAMPLE values are numbers (three-space and time series: arrays of numbers), integer and
  float EVENT types numbers, everything else strings; UNAVAILABLE is the string "UNAVAILABLE".
Where cppagent's printer has no fixed shape (asset content, whose JSON it derives from its
own asset model), this module maps XML generically: attributes are keys, text is "value",
a child element that occurs once is an object, a repeated one an array.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Sequence
from typing import Any

from gateway.codecs.mtconnect.assets import Asset
from gateway.codecs.mtconnect.attributes import description_attributes, present
from gateway.codecs.mtconnect.buffer import Entry, Window
from gateway.codecs.mtconnect.documents import SCHEMA_VERSION, DocumentInfo
from gateway.codecs.mtconnect.errors import RequestError
from gateway.codecs.mtconnect.model import (
    CATEGORY_ELEMENTS,
    Catalog,
    Component,
    DataItem,
    Description,
    Device,
    Node,
)
from gateway.codecs.mtconnect.vocabulary import FLOAT_EVENTS, INTEGER_EVENTS, THREE_SPACE, UNAVAILABLE

JSON_VERSION = 2

_dumps = json.JSONEncoder(ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode


def _header(info: DocumentInfo, instance_id: int, model_change: bool = True) -> dict[str, Any]:
    header: dict[str, Any] = {
        "version": info.version,
        "creationTime": info.creation_time,
        "testIndicator": info.test_indicator,
        "instanceId": instance_id,
        "sender": info.sender,
        "schemaVersion": SCHEMA_VERSION,
    }
    if model_change:
        header["deviceModelChangeTime"] = info.device_model_change_time
    return header


def _root(document: str, header: dict[str, Any], key: str, body: str) -> str:
    head = _dumps({"jsonVersion": JSON_VERSION, "schemaVersion": SCHEMA_VERSION, "Header": header})
    return f'{{"{document}":{head[:-1]},"{key}":{body}}}}}'


# --- MTConnectDevices -------------------------------------------------------------------------


def devices_json(
    catalog: Catalog,
    info: DocumentInfo,
    *,
    instance_id: int,
    buffer_size: int,
    asset_buffer_size: int,
    asset_count: int,
    devices: Sequence[Device] | None = None,
) -> str:
    header = _header(info, instance_id)
    header.update(bufferSize=buffer_size, assetBufferSize=asset_buffer_size, assetCount=asset_count)
    body = {"Device": [_node_json(d) for d in (catalog.devices if devices is None else devices)]}
    return _root("MTConnectDevices", header, "Devices", _dumps(body))


def _node_json(node: Node) -> dict[str, Any]:
    out: dict[str, Any] = {"id": node.id}
    if node.name is not None:
        out["name"] = node.name
    if isinstance(node, Device):
        out["uuid"] = node.uuid
        if node.iso841_class is not None:
            out["iso841Class"] = node.iso841_class
        if node.mtconnect_version is not None:
            out["mtconnectVersion"] = node.mtconnect_version
    elif isinstance(node, Component) and node.uuid is not None:
        out["uuid"] = node.uuid
    if node.native_name is not None:
        out["nativeName"] = node.native_name
    if node.description is not None:
        out["Description"] = _description_json(node.description)
    if node.data_items:
        out["DataItems"] = {"DataItem": [_data_item_json(item) for item in node.data_items]}
    if node.components:
        groups: dict[str, list[dict[str, Any]]] = {}
        for child in node.components:
            groups.setdefault(child.type, []).append(_node_json(child))
        out["Components"] = groups
    return out


def _description_json(d: Description) -> dict[str, Any]:
    out: dict[str, Any] = dict(description_attributes(d))
    if d.text is not None:
        out["value"] = d.text
    return out


def _data_item_json(item: DataItem) -> dict[str, Any]:
    out: dict[str, Any] = {attribute.name: value for attribute, value in present(item)}
    if item.source is not None:
        out["Source"] = {"value": item.source}
    return out


# --- MTConnectStreams -------------------------------------------------------------------------


def _number(text: str) -> float | str:
    value = float(text)
    return value if math.isfinite(value) else text


def _json_value(entry: Entry) -> Any:
    text = entry.value
    info = entry.info
    if text == UNAVAILABLE:
        return text
    kind = info.item.type
    category = info.item.category.value
    if category == "SAMPLE":
        if info.time_series or kind in THREE_SPACE:
            return [_number(t) for t in text.split()]
        return _number(text)
    if kind in THREE_SPACE:
        return [_number(t) for t in text.split()]
    if kind in INTEGER_EVENTS:
        return int(text)
    if kind in FLOAT_EVENTS:
        return _number(text)
    return text


def entry_json(entry: Entry) -> str:
    """One observation as a JSON object (without its element-name key), rendered once and kept."""
    cached = entry.json_cache
    if cached is not None:
        return cached
    item = entry.info.item
    obj: dict[str, Any] = {"dataItemId": item.id, "timestamp": entry.timestamp, "sequence": entry.sequence}
    if item.name is not None:
        obj["name"] = item.name
    if item.sub_type is not None:
        obj["subType"] = item.sub_type
    if item.composition_id is not None:
        obj["compositionId"] = item.composition_id
    if item.statistic is not None:
        obj["statistic"] = item.statistic
    if entry.info.is_condition:
        obj["type"] = item.type
        for key, value in (
            ("nativeCode", entry.native_code),
            ("nativeSeverity", entry.native_severity),
            ("qualifier", entry.qualifier),
            ("conditionId", entry.condition_id),
        ):
            if value is not None:
                obj[key] = value
        if entry.value:
            obj["value"] = entry.value
    else:
        if entry.sample_count is not None:
            obj["sampleCount"] = entry.sample_count
        if entry.sample_rate is not None:
            obj["sampleRate"] = entry.sample_rate
        if entry.reset_triggered is not None:
            obj["resetTriggered"] = entry.reset_triggered
        if entry.duration is not None:
            obj["duration"] = entry.duration
        if entry.asset_type is not None:
            obj["assetType"] = entry.asset_type
        obj["value"] = _json_value(entry)
    text = entry.json_cache = _dumps(obj)
    return text


def streams_json(catalog: Catalog, entries: Iterable[Entry], window: Window, info: DocumentInfo) -> str:
    header = _header(info, window.instance_id)
    header.update(
        bufferSize=window.buffer_size,
        nextSequence=window.next_sequence,
        lastSequence=max(1, window.last_sequence),
        firstSequence=window.first_sequence,
    )
    return _root("MTConnectStreams", header, "Streams", streams_body_json(catalog, entries))


def streams_body_json(catalog: Catalog, entries: Iterable[Entry]) -> str:
    """The value of `"Streams"`: `{}` when empty, else `{"DeviceStream": [...]}`."""
    # stream index -> category -> element -> fragments
    buckets: dict[int, tuple[dict[str, list[str]], ...]] = {}
    for entry in entries:
        info = entry.info
        bucket = buckets.get(info.stream.index)
        if bucket is None:
            bucket = buckets[info.stream.index] = ({}, {}, {})
        element = entry.level if info.is_condition else info.element
        bucket[info.category_index].setdefault(element, []).append(entry_json(entry))
    if not buckets:
        return "{}"
    devices: list[str] = []
    components: list[str] = []
    device_index = -1

    def close_device() -> None:
        device = catalog.devices[device_index]
        head = _dumps({"name": device.name, "uuid": device.uuid})
        devices.append(f'{head[:-1]},"ComponentStream":[{",".join(components)}]}}')

    for key in sorted(buckets):
        stream = catalog.streams[key]
        if stream.device_index != device_index:
            if device_index >= 0:
                close_device()
                components = []
            device_index = stream.device_index
        node = stream.node
        head_obj: dict[str, Any] = {"component": node.type, "componentId": node.id}
        if node.name is not None:
            head_obj["name"] = node.name
        if node.native_name is not None:
            head_obj["nativeName"] = node.native_name
        parts = [_dumps(head_obj)[:-1]]
        for category, groups in enumerate(buckets[key]):
            if groups:
                inner = ",".join(f"{_dumps(name)}:[{','.join(frags)}]" for name, frags in groups.items())
                parts.append(f'"{CATEGORY_ELEMENTS[category]}":{{{inner}}}')
        components.append(",".join(parts) + "}")
    close_device()
    return f'{{"DeviceStream":[{",".join(devices)}]}}'


# --- MTConnectAssets --------------------------------------------------------------------------


def _element_json(element: ET.Element) -> dict[str, Any]:
    out: dict[str, Any] = dict(element.attrib)
    children: dict[str, list[dict[str, Any]]] = {}
    for child in element:
        children.setdefault(child.tag, []).append(_element_json(child))
    for tag, items in children.items():
        out[tag] = items[0] if len(items) == 1 else items
    text = (element.text or "").strip()
    if text:
        out["value"] = text
    return out


def assets_json(
    assets: Iterable[Asset], info: DocumentInfo, *, instance_id: int, asset_buffer_size: int, asset_count: int
) -> str:
    header = _header(info, instance_id)
    header.update(assetBufferSize=asset_buffer_size, assetCount=asset_count)
    groups: dict[str, list[dict[str, Any]]] = {}
    for asset in assets:
        groups.setdefault(asset.type, []).append(_element_json(ET.fromstring(asset.xml)))
    return _root("MTConnectAssets", header, "Assets", _dumps(groups))


# --- MTConnectError ---------------------------------------------------------------------------


def error_json(
    errors: Sequence[RequestError], info: DocumentInfo, *, instance_id: int, buffer_size: int
) -> str:
    if not errors:
        raise ValueError("an MTConnectError document needs at least one error")
    header = _header(info, instance_id, model_change=False)
    header["bufferSize"] = buffer_size
    body = {"Error": [{"errorCode": e.code.value, "value": e.message} for e in errors]}
    return _root("MTConnectError", header, "Errors", _dumps(body))
