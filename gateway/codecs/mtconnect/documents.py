"""MTConnect 2.4 XML response documents, joined from strings.

MTConnectDevices (/probe), MTConnectStreams (/current, /sample), MTConnectAssets
(/assets) and MTConnectError. Observations bring their own element, rendered once
(`Entry.xml`), and the catalog holds every stream's opening tag, so a /current of
10,000 data items is a grouping pass and one join. The documents validate against the
official 2.4 schemas (tests/unit/codecs/mtconnect/test_documents.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from gateway.codecs.mtconnect.assets import Asset
from gateway.codecs.mtconnect.attributes import description_attributes, present
from gateway.codecs.mtconnect.buffer import Entry, Window, entry_xml
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
from gateway.codecs.mtconnect.xmltext import TEXT_SPECIAL, xml_attr, xml_text

SCHEMA_VERSION = "2.4"
XSI = "http://www.w3.org/2001/XMLSchema-instance"
DECLARATION = '<?xml version="1.0" encoding="UTF-8"?>\n'


@dataclass(frozen=True, slots=True)
class DocumentInfo:
    """What every header says besides sequence numbers; the caller supplies the clock.

    `version` is the header's document version (the agent's version, by the reference agent's
    habit); times are ISO 8601 text (see timestamps.format_timestamp).
    """

    sender: str
    creation_time: str
    device_model_change_time: str
    version: str = "2.4.0.0"
    test_indicator: bool = False


def namespace(document: str) -> str:
    """`urn:mtconnect.org:MTConnectStreams:2.4` for document "Streams"."""
    return f"urn:mtconnect.org:MTConnect{document}:{SCHEMA_VERSION}"


def _root_open(document: str) -> str:
    ns = namespace(document)
    return (
        f'<MTConnect{document} xmlns:m="{ns}" xmlns="{ns}" xmlns:xsi="{XSI}" '
        f'xsi:schemaLocation="{ns} http://schemas.mtconnect.org/schemas/MTConnect{document}_{SCHEMA_VERSION}.xsd">'
    )


def _header_attrs(info: DocumentInfo, instance_id: int, device_model_change: bool = True) -> str:
    parts = [
        f' creationTime="{xml_attr(info.creation_time)}" sender="{xml_attr(info.sender)}"',
        f' instanceId="{instance_id}" version="{xml_attr(info.version)}"',
    ]
    if device_model_change:
        parts.append(f' deviceModelChangeTime="{xml_attr(info.device_model_change_time)}"')
    if info.test_indicator:
        parts.append(' testIndicator="true"')
    return "".join(parts)


# --- MTConnectDevices -------------------------------------------------------------------------


def devices_xml(
    catalog: Catalog,
    info: DocumentInfo,
    *,
    instance_id: int,
    buffer_size: int,
    asset_buffer_size: int,
    asset_count: int,
    devices: Sequence[Device] | None = None,
) -> str:
    """/probe: every device of the catalog, or only `devices` (for /<device>/probe)."""
    out = [
        DECLARATION,
        _root_open("Devices"),
        (
            f'<Header{_header_attrs(info, instance_id)} bufferSize="{buffer_size}"'
            f' assetBufferSize="{asset_buffer_size}" assetCount="{asset_count}"/>'
        ),
        "<Devices>",
    ]
    for device in catalog.devices if devices is None else devices:
        _node_xml(device, out)
    out.append("</Devices></MTConnectDevices>")
    return "".join(out)


def _node_xml(node: Node, out: list[str]) -> None:
    tag = node.type
    attrs = [f'<{tag} id="{xml_attr(node.id)}"']
    if node.name is not None:
        attrs.append(f' name="{xml_attr(node.name)}"')
    if isinstance(node, Device):
        attrs.append(f' uuid="{xml_attr(node.uuid)}"')
        if node.iso841_class is not None:
            attrs.append(f' iso841Class="{node.iso841_class}"')
        if node.mtconnect_version is not None:
            attrs.append(f' mtconnectVersion="{xml_attr(node.mtconnect_version)}"')
    elif isinstance(node, Component) and node.uuid is not None:
        attrs.append(f' uuid="{xml_attr(node.uuid)}"')
    if node.native_name is not None:
        attrs.append(f' nativeName="{xml_attr(node.native_name)}"')
    attrs.append(">")
    out.append("".join(attrs))
    if node.description is not None:
        out.append(_description_xml(node.description))
    if node.data_items:
        out.append("<DataItems>")
        out.extend(_data_item_xml(item) for item in node.data_items)
        out.append("</DataItems>")
    if node.components:
        out.append("<Components>")
        for child in node.components:
            _node_xml(child, out)
        out.append("</Components>")
    out.append(f"</{tag}>")


def _description_xml(d: Description) -> str:
    parts = ["<Description"]
    for attr, value in description_attributes(d):
        parts.append(f' {attr}="{xml_attr(value)}"')
    if d.text:
        parts.append(f">{xml_text(d.text)}</Description>")
    else:
        parts.append("/>")
    return "".join(parts)


def _data_item_xml(item: DataItem) -> str:
    parts = ["<DataItem"]
    for attribute, value in present(item):
        parts.append(f' {attribute.name}="{attribute.xml(value)}"')
    if item.source is not None:
        parts.append(f"><Source>{xml_text(item.source)}</Source></DataItem>")
    else:
        parts.append("/>")
    return "".join(parts)


# --- MTConnectStreams -------------------------------------------------------------------------


def streams_xml(catalog: Catalog, entries: Iterable[Entry], window: Window, info: DocumentInfo) -> str:
    """/current or /sample: the entries grouped by device, component stream and category.

    Within a category the entries keep the order given (probe order for /current, sequence
    order for /sample).
    """
    return "".join(
        (
            DECLARATION,
            _root_open("Streams"),
            _streams_header(window, info),
            streams_body(catalog, entries),
            "</MTConnectStreams>",
        )
    )


def _streams_header(window: Window, info: DocumentInfo) -> str:
    return (
        f'<Header{_header_attrs(info, window.instance_id)} bufferSize="{window.buffer_size}"'
        f' nextSequence="{window.next_sequence}" firstSequence="{window.first_sequence}"'
        f' lastSequence="{max(1, window.last_sequence)}"/>'
    )


def streams_body(catalog: Catalog, entries: Iterable[Entry]) -> str:
    """The `<Streams>` element alone (also what one chunk of a streamed /sample carries)."""
    buckets: dict[int, list[str]] = {}
    needs_escaping = TEXT_SPECIAL.search
    for entry in entries:
        info = entry.info
        key = info.bucket
        fragment = entry.xml_cache
        if fragment is None:
            # entry_xml's common case inline (a value or event without extra attributes): a streamed chunk
            # renders every observation once for all its clients, and the call per entry was a fifth of it.
            if (
                info.prefix  # not a condition
                and entry.sample_count is None
                and entry.reset_triggered is None
                and entry.duration is None
                and entry.asset_type is None
            ):
                value = entry.value
                if value:
                    if needs_escaping(value) is not None:
                        value = xml_text(value)
                    fragment = (
                        f'{info.prefix}{entry.sequence}" timestamp="{entry.timestamp}">'
                        f"{value}</{info.element}>"
                    )
                else:
                    fragment = f'{info.prefix}{entry.sequence}" timestamp="{entry.timestamp}"/>'
                entry.xml_cache = fragment
            else:
                fragment = entry_xml(entry)
        bucket = buckets.get(key)
        if bucket is None:
            buckets[key] = [fragment]
        else:
            bucket.append(fragment)
    if not buckets:
        return "<Streams/>"
    out = ["<Streams>"]
    streams = catalog.streams
    tags = catalog.device_open_tags
    device_index = -1
    stream_index = -1
    for key in sorted(buckets):
        index, category = divmod(key, 3)
        if index != stream_index:
            if stream_index >= 0:
                out.append("</ComponentStream>")
            stream = streams[index]
            if stream.device_index != device_index:
                if device_index >= 0:
                    out.append("</DeviceStream>")
                device_index = stream.device_index
                out.append(tags[device_index])
            out.append(stream.open_tag)
            stream_index = index
        out.append(_CATEGORY_OPEN[category])
        out.extend(buckets[key])
        out.append(_CATEGORY_CLOSE[category])
    out.append("</ComponentStream></DeviceStream></Streams>")
    return "".join(out)


_CATEGORY_OPEN = tuple(f"<{name}>" for name in CATEGORY_ELEMENTS)
_CATEGORY_CLOSE = tuple(f"</{name}>" for name in CATEGORY_ELEMENTS)


# --- MTConnectAssets --------------------------------------------------------------------------


def assets_xml(
    assets: Iterable[Asset], info: DocumentInfo, *, instance_id: int, asset_buffer_size: int, asset_count: int
) -> str:
    out = [
        DECLARATION,
        _root_open("Assets"),
        (
            f'<Header{_header_attrs(info, instance_id)} assetBufferSize="{asset_buffer_size}"'
            f' assetCount="{asset_count}"/>'
        ),
        "<Assets>",
    ]
    out.extend(asset.xml for asset in assets)
    out.append("</Assets></MTConnectAssets>")
    return "".join(out)


# --- MTConnectError ---------------------------------------------------------------------------


def error_xml(
    errors: Sequence[RequestError], info: DocumentInfo, *, instance_id: int, buffer_size: int
) -> str:
    """An MTConnectError document with one Error per refusal (at least one)."""
    if not errors:
        raise ValueError("an MTConnectError document needs at least one error")
    out = [
        DECLARATION,
        _root_open("Error"),
        f'<Header{_header_attrs(info, instance_id, device_model_change=False)} bufferSize="{buffer_size}"/>',
        "<Errors>",
    ]
    out.extend(f'<Error errorCode="{e.code.value}">{xml_text(e.message)}</Error>' for e in errors)
    out.append("</Errors></MTConnectError>")
    return "".join(out)
