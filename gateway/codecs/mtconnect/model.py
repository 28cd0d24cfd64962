"""The MTConnect device model as plain data: what /probe describes and /current reports against.

`Device` > `Component` (nested) > `DataItem`, immutable, built by whoever maps a machine
onto MTConnect (the agent sink, later). `Catalog` indexes a list of devices once: it
checks what the schema requires of ids and names, gives every data item its place
(device, component stream, category) and keeps the pieces of XML that every
observation of that data item repeats, rendered once, so that documents are joined
from strings instead of built element by element.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from enum import Enum

from gateway.codecs.mtconnect.errors import ModelError
from gateway.codecs.mtconnect.vocabulary import element_name
from gateway.codecs.mtconnect.xmltext import xml_attr


class Category(str, Enum):
    SAMPLE = "SAMPLE"
    EVENT = "EVENT"
    CONDITION = "CONDITION"


class Representation(str, Enum):
    """The representations these codecs render (DATA_SET and TABLE are not supported yet)."""

    VALUE = "VALUE"
    TIME_SERIES = "TIME_SERIES"


@dataclass(frozen=True, slots=True)
class DataItem:
    """One DataItem of /probe. `source` is the <Source> text: the adapter key or native address."""

    id: str
    category: Category
    type: str
    name: str | None = None
    sub_type: str | None = None
    units: str | None = None
    native_units: str | None = None
    native_scale: float | None = None
    significant_digits: int | None = None
    coordinate_system: str | None = None
    statistic: str | None = None
    composition_id: str | None = None
    representation: Representation = Representation.VALUE
    discrete: bool = False
    source: str | None = None


@dataclass(frozen=True, slots=True)
class Description:
    manufacturer: str | None = None
    model: str | None = None
    serial_number: str | None = None
    station: str | None = None
    text: str | None = None


@dataclass(frozen=True, slots=True)
class Component:
    """A component; `type` is its element name in the 2.4 schema: Axes, Linear, Controller, Path, ..."""

    type: str
    id: str
    name: str | None = None
    native_name: str | None = None
    uuid: str | None = None
    description: Description | None = None
    data_items: tuple[DataItem, ...] = ()
    components: tuple[Component, ...] = ()


@dataclass(frozen=True, slots=True)
class Device:
    id: str
    name: str
    uuid: str
    description: Description | None = None
    data_items: tuple[DataItem, ...] = ()
    components: tuple[Component, ...] = ()
    native_name: str | None = None
    iso841_class: int | None = None
    mtconnect_version: str | None = None

    @property
    def type(self) -> str:
        return "Device"


Node = Device | Component

# xs:ID is an NCName; this is its ASCII subset, which is what machine mappings produce.
_NCNAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*\Z")
_ELEMENT = re.compile(r"(?:[a-z][a-z0-9]*:)?[A-Z][A-Za-z0-9]*\Z")
_TYPE = re.compile(r"(?:[a-z][a-z0-9]*:)?[A-Z][A-Z0-9_]*\Z")

CATEGORY_INDEX = {Category.SAMPLE: 0, Category.EVENT: 1, Category.CONDITION: 2}
CATEGORY_ELEMENTS = ("Samples", "Events", "Condition")


@dataclass(frozen=True, slots=True)
class StreamInfo:
    """One ComponentStream: the component (or device) that owns data items directly."""

    index: int  # position in probe order across all devices
    device_index: int
    node: Node
    open_tag: str  # `<ComponentStream component="Linear" componentId="x" name="X">`


@dataclass(frozen=True, slots=True)
class ItemInfo:
    """Where a data item's observations go in a Streams document, and their repeated XML."""

    item: DataItem
    stream: StreamInfo
    category_index: int  # 0 Samples, 1 Events, 2 Condition
    element: str  # the observation element; "" for a CONDITION, whose level names it
    attrs: str  # ` dataItemId="x" name="Xact" subType="ACTUAL"` (and `type=` for conditions)
    is_condition: bool = field(default=False)
    time_series: bool = field(default=False)
    bucket: int = 0  # stream.index * 3 + category_index: the documents' grouping key
    prefix: str = ""  # `<Position dataItemId="x" ... sequence="` (not for conditions)


class Catalog:
    """An index of devices for documents, the buffer and path filters. Raises ModelError on a bad model."""

    def __init__(self, devices: Sequence[Device]) -> None:
        self.devices: tuple[Device, ...] = tuple(devices)
        self.items: dict[str, ItemInfo] = {}  # by data item id, in probe order
        self.streams: list[StreamInfo] = []
        self.device_open_tags: list[str] = []
        self._by_name: dict[str, Device] = {}
        _check(self.devices)
        for device_index, device in enumerate(self.devices):
            self._by_name[device.name] = device
            self._by_name[device.uuid] = device
            self.device_open_tags.append(
                f'<DeviceStream name="{xml_attr(device.name)}" uuid="{xml_attr(device.uuid)}">'
            )
            for node in walk(device):
                if not node.data_items:
                    continue
                stream = StreamInfo(len(self.streams), device_index, node, _stream_tag(node))
                self.streams.append(stream)
                for item in node.data_items:
                    self.items[item.id] = _item_info(item, stream)

    def device(self, name_or_uuid: str) -> Device | None:
        """The device with this name or uuid (what /<device>/... names), or None."""
        return self._by_name.get(name_or_uuid)

    def device_items(self, device: Device) -> frozenset[str]:
        """Ids of every data item of one device."""
        return frozenset(item.id for node in walk(device) for item in node.data_items)


def walk(node: Node) -> Iterator[Node]:
    """The node and its components, depth first, in document order."""
    yield node
    for child in node.components:
        yield from walk(child)


def _stream_tag(node: Node) -> str:
    parts = [f'<ComponentStream component="{xml_attr(node.type)}" componentId="{xml_attr(node.id)}"']
    if node.name is not None:
        parts.append(f' name="{xml_attr(node.name)}"')
    if node.native_name is not None:
        parts.append(f' nativeName="{xml_attr(node.native_name)}"')
    if isinstance(node, Component) and node.uuid is not None:
        parts.append(f' uuid="{xml_attr(node.uuid)}"')
    parts.append(">")
    return "".join(parts)


def _item_info(item: DataItem, stream: StreamInfo) -> ItemInfo:
    attrs = [f' dataItemId="{xml_attr(item.id)}"']
    if item.name is not None:
        attrs.append(f' name="{xml_attr(item.name)}"')
    if item.sub_type is not None:
        attrs.append(f' subType="{xml_attr(item.sub_type)}"')
    if item.composition_id is not None:
        attrs.append(f' compositionId="{xml_attr(item.composition_id)}"')
    if item.statistic is not None:
        attrs.append(f' statistic="{xml_attr(item.statistic)}"')
    is_condition = item.category is Category.CONDITION
    time_series = item.representation is Representation.TIME_SERIES
    if is_condition:
        attrs.append(f' type="{xml_attr(item.type)}"')
        element = ""
    else:
        element = element_name(item.type) + ("TimeSeries" if time_series else "")
    category_index = CATEGORY_INDEX[item.category]
    attr_text = "".join(attrs)
    return ItemInfo(
        item=item,
        stream=stream,
        category_index=category_index,
        element=element,
        attrs=attr_text,
        is_condition=is_condition,
        time_series=time_series,
        bucket=stream.index * 3 + category_index,
        prefix="" if is_condition else f'<{element}{attr_text} sequence="',
    )


def _check(devices: tuple[Device, ...]) -> None:
    problems: list[str] = []
    ids: set[str] = set()
    names: set[str] = set()
    uuids: set[str] = set()

    def check_id(kind: str, ident: str) -> None:
        if not _NCNAME.match(ident):
            problems.append(
                f"{kind} id {ident!r} is not an XML id (a letter or _ first; letters, digits, _.-)"
            )
        elif ident in ids:
            problems.append(f"{kind} id {ident!r} is used twice (ids are unique across all devices)")
        ids.add(ident)

    if not devices:
        problems.append("an MTConnectDevices document needs at least one Device")
    for device in devices:
        if device.name in names:
            problems.append(f"device name {device.name!r} is used twice")
        if device.uuid in uuids:
            problems.append(f"device uuid {device.uuid!r} is used twice")
        if not device.name or not device.uuid:
            problems.append(f"device {device.id!r} needs a name and a uuid")
        names.add(device.name)
        uuids.add(device.uuid)
        for node in walk(device):
            check_id(node.type, node.id)
            if not _ELEMENT.match(node.type):
                problems.append(f"component type {node.type!r} is not an element name (Axes, Linear, ...)")
            for item in node.data_items:
                check_id("DataItem", item.id)
                if not _TYPE.match(item.type):
                    problems.append(f"data item {item.id!r}: type {item.type!r} is not an MTConnect type")
                if not isinstance(item.category, Category):
                    problems.append(
                        f"data item {item.id!r}: category {item.category!r} is not one of Category"
                    )
                if not isinstance(item.representation, Representation):
                    problems.append(
                        f"data item {item.id!r}: representation {item.representation!r} unsupported"
                    )
                elif (
                    item.representation is Representation.TIME_SERIES and item.category is not Category.SAMPLE
                ):
                    problems.append(f"data item {item.id!r}: only a SAMPLE can be a TIME_SERIES")
    if problems:
        raise ModelError("; ".join(problems))
