"""Reading another agent's answers: MTConnectDevices, MTConnectStreams and MTConnectError XML, pure.

What the MTConnect source needs from an agent's documents, whatever its version (1.3 to
2.x: elements are matched by local name, so any namespace goes): the header's
instanceId and sequence numbers, the observations with their data item ids, and the
device model. Documents with a DOCTYPE (entity declarations) are refused: an agent has
no use for them and they are how XML bombs arrive. Every refusal is a ResponseError
(a CodecError), never an exception of the XML library.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass, field

from gateway.codecs.mtconnect.errors import MTConnectCodecError
from gateway.codecs.mtconnect.model import Category, Component, DataItem, Description, Device, Representation

CATEGORY_GROUPS = {"Samples": Category.SAMPLE, "Events": Category.EVENT, "Condition": Category.CONDITION}
CONDITION_ELEMENTS = {
    "Normal": "NORMAL",
    "Warning": "WARNING",
    "Fault": "FAULT",
    "Unavailable": "UNAVAILABLE",
}


class ResponseError(MTConnectCodecError):
    """A document that is not what an agent should send (not XML, wrong root, no header)."""


@dataclass(frozen=True, slots=True)
class Header:
    instance_id: int
    buffer_size: int | None = None
    first_sequence: int | None = None
    last_sequence: int | None = None
    next_sequence: int | None = None
    sender: str = ""
    version: str = ""


@dataclass(frozen=True, slots=True)
class ObservedValue:
    """One observation of a Streams document; `level` is set for conditions (NORMAL, WARNING, ...)."""

    data_item_id: str
    sequence: int
    timestamp: str
    category: Category
    value: str  # the element's text; a condition's message
    element: str  # Position, Execution, Fault ...
    device_uuid: str = ""
    name: str | None = None
    level: str | None = None
    native_code: str | None = None
    native_severity: str | None = None
    qualifier: str | None = None
    condition_id: str | None = None
    condition_type: str | None = None

    @property
    def unavailable(self) -> bool:
        if self.category is Category.CONDITION:
            return self.level == "UNAVAILABLE"
        return self.value == "UNAVAILABLE"


@dataclass(frozen=True, slots=True)
class StreamsDocument:
    header: Header
    observations: list[ObservedValue] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class DevicesDocument:
    header: Header
    devices: list[Device] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class AgentError:
    code: str
    message: str


def _local(tag: str) -> str:
    return tag.rpartition("}")[2] if tag.startswith("{") else tag.rpartition(":")[2]


def _parse(text: str | bytes) -> ET.Element:
    head = text[:4096] if isinstance(text, str) else text[:4096].decode("utf-8", "replace")
    if "<!DOCTYPE" in head or "<!ENTITY" in head:
        raise ResponseError("the document has a DOCTYPE, which an agent never sends")
    try:
        return ET.fromstring(text)
    except ET.ParseError as exc:
        raise ResponseError(f"not well-formed XML: {exc}") from None


def _int(text: str | None, what: str) -> int | None:
    if text is None:
        return None
    try:
        return int(text)
    except ValueError:
        raise ResponseError(f"{what} {text[:40]!r} is not an integer") from None


def _children(element: ET.Element, name: str) -> Iterator[ET.Element]:
    return (child for child in element if _local(child.tag) == name)


def _child(element: ET.Element, name: str) -> ET.Element | None:
    return next(_children(element, name), None)


def _header(root: ET.Element) -> Header:
    element = _child(root, "Header")
    if element is None:
        raise ResponseError(f"{_local(root.tag)} has no Header")
    a = element.attrib
    instance = _int(a.get("instanceId"), "instanceId")
    if instance is None:
        raise ResponseError("the Header has no instanceId")
    return Header(
        instance_id=instance,
        buffer_size=_int(a.get("bufferSize"), "bufferSize"),
        first_sequence=_int(a.get("firstSequence"), "firstSequence"),
        last_sequence=_int(a.get("lastSequence"), "lastSequence"),
        next_sequence=_int(a.get("nextSequence"), "nextSequence"),
        sender=a.get("sender", ""),
        version=a.get("version", ""),
    )


def document_kind(text: str | bytes) -> str:
    """`Streams`, `Devices`, `Assets` or `Error`: the root element without its `MTConnect` prefix."""
    name = _local(_parse(text).tag)
    if not name.startswith("MTConnect"):
        raise ResponseError(f"the root element is {name!r}, not an MTConnect document")
    return name.removeprefix("MTConnect")


def parse_streams(text: str | bytes) -> StreamsDocument:
    """An MTConnectStreams document. An MTConnectError document raises AgentErrors."""
    root = _parse(text)
    kind = _local(root.tag)
    if kind == "MTConnectError":
        raise AgentErrors(_errors(root), _instance(root))
    if kind != "MTConnectStreams":
        raise ResponseError(f"expected MTConnectStreams, got {kind}")
    header = _header(root)
    out: list[ObservedValue] = []
    streams = _child(root, "Streams")
    if streams is not None:
        for device in _children(streams, "DeviceStream"):
            uuid = device.get("uuid", "")
            for component in _children(device, "ComponentStream"):
                for group in component:
                    category = CATEGORY_GROUPS.get(_local(group.tag))
                    if category is None:
                        continue
                    for element in group:
                        out.append(_observation(element, category, uuid))
    out.sort(key=lambda o: o.sequence)
    return StreamsDocument(header, out)


def _observation(element: ET.Element, category: Category, uuid: str) -> ObservedValue:
    a = element.attrib
    item = a.get("dataItemId")
    if not item:
        raise ResponseError(f"a {_local(element.tag)} observation has no dataItemId")
    sequence = _int(a.get("sequence"), "sequence")
    if sequence is None:
        raise ResponseError(f"observation {item} has no sequence")
    name = _local(element.tag)
    text = "".join(element.itertext()).strip() if len(element) else (element.text or "").strip()
    if category is Category.CONDITION:
        level = CONDITION_ELEMENTS.get(name)
        if level is None:
            raise ResponseError(f"condition {item}: {name!r} is not Normal, Warning, Fault or Unavailable")
        return ObservedValue(
            item, sequence, a.get("timestamp", ""), category, text, name, uuid, a.get("name"), level,
            a.get("nativeCode"), a.get("nativeSeverity"), a.get("qualifier"), a.get("conditionId"),
            a.get("type"),
        )  # fmt: skip
    return ObservedValue(item, sequence, a.get("timestamp", ""), category, text, name, uuid, a.get("name"))


class AgentErrors(ResponseError):
    """The agent answered with an MTConnectError document."""

    def __init__(self, errors: list[AgentError], instance_id: int | None = None) -> None:
        self.errors = errors
        self.instance_id = instance_id  # the agent's, from the document's header (whose numbering refused us)
        super().__init__("; ".join(f"{e.code}: {e.message}" for e in errors) or "MTConnectError")

    @property
    def codes(self) -> set[str]:
        return {e.code for e in self.errors}


def _errors(root: ET.Element) -> list[AgentError]:
    found: list[AgentError] = []
    for element in root.iter():
        if _local(element.tag) == "Error":
            found.append(AgentError(element.get("errorCode", ""), (element.text or "").strip()))
    return found


def _instance(root: ET.Element) -> int | None:
    header = _child(root, "Header")
    text = header.get("instanceId") if header is not None else None
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def parse_error(text: str | bytes) -> list[AgentError]:
    root = _parse(text)
    if _local(root.tag) != "MTConnectError":
        raise ResponseError(f"expected MTConnectError, got {_local(root.tag)}")
    return _errors(root)


# --- MTConnectDevices -------------------------------------------------------------------------


def parse_devices(text: str | bytes) -> DevicesDocument:
    """An MTConnectDevices document's Devices (not its Agent) as the codecs' own model.

    Data items of representation DATA_SET or TABLE come as VALUE: their text is kept as it is.
    """
    root = _parse(text)
    kind = _local(root.tag)
    if kind == "MTConnectError":
        raise AgentErrors(_errors(root), _instance(root))
    if kind != "MTConnectDevices":
        raise ResponseError(f"expected MTConnectDevices, got {kind}")
    header = _header(root)
    devices: list[Device] = []
    container = _child(root, "Devices")
    for element in container if container is not None else ():
        if _local(element.tag) != "Device":  # 2.x agents list themselves first, as an Agent: not a machine
            continue
        devices.append(
            Device(
                id=element.get("id", ""),
                name=element.get("name", ""),
                uuid=element.get("uuid", ""),
                description=_description(element),
                data_items=_data_items(element),
                components=_components(element),
                native_name=element.get("nativeName"),
            )
        )
    return DevicesDocument(header, devices)


def _description(element: ET.Element) -> Description | None:
    d = _child(element, "Description")
    if d is None:
        return None
    return Description(
        manufacturer=d.get("manufacturer"),
        model=d.get("model"),
        serial_number=d.get("serialNumber"),
        station=d.get("station"),
        text=(d.text or "").strip() or None,
    )


def _data_items(element: ET.Element) -> tuple[DataItem, ...]:
    container = _child(element, "DataItems")
    if container is None:
        return ()
    items: list[DataItem] = []
    for d in _children(container, "DataItem"):
        a = d.attrib
        try:
            category = Category(a.get("category", ""))
        except ValueError:
            continue
        representation = (
            Representation.TIME_SERIES if a.get("representation") == "TIME_SERIES" else Representation.VALUE
        )
        source = _child(d, "Source")
        items.append(
            DataItem(
                id=a.get("id", ""),
                category=category,
                type=a.get("type", ""),
                name=a.get("name"),
                sub_type=a.get("subType"),
                units=a.get("units"),
                native_units=a.get("nativeUnits"),
                coordinate_system=a.get("coordinateSystem"),
                statistic=a.get("statistic"),
                representation=representation,
                discrete=a.get("discrete") == "true",
                source=(source.text or "").strip() or None if source is not None else None,
            )
        )
    return tuple(items)


def _components(element: ET.Element) -> tuple[Component, ...]:
    container = _child(element, "Components")
    if container is None:
        return ()
    return tuple(
        Component(
            type=_local(c.tag),
            id=c.get("id", ""),
            name=c.get("name"),
            native_name=c.get("nativeName"),
            uuid=c.get("uuid"),
            description=_description(c),
            data_items=_data_items(c),
            components=_components(c),
        )
        for c in container
    )
