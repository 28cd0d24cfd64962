"""MTConnect assets (cutting tools, files, raw material...): checked once, kept as rendered XML.

An asset arrives as XML text (from an SHDR `@ASSET@` line, or built by the gateway).
`make_asset` parses it with the standard library, refuses what an agent should not
serve (not well-formed, a DOCTYPE or entity declarations, a root element other than
the asset type, too large), and stamps the attributes the Assets schema requires
(assetId, timestamp, deviceUuid, removed). The result is kept as text for documents.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from gateway.codecs.mtconnect.errors import MTConnectCodecError

MAX_ASSET_BYTES = 1 << 20
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*\Z")


class AssetRejected(MTConnectCodecError):
    """Asset XML the agent will not store."""


@dataclass(frozen=True, slots=True)
class Asset:
    asset_id: str
    type: str
    timestamp: str
    device_uuid: str | None
    xml: str  # the asset element, without namespace declarations of its own
    removed: bool = False


def make_asset(
    body: str,
    *,
    asset_id: str,
    asset_type: str,
    timestamp: str,
    device_uuid: str | None = None,
    removed: bool = False,
) -> Asset:
    """Check `body` (one element named `asset_type`) and stamp the header attributes. Raises AssetRejected."""
    if not _NAME.match(asset_type):
        raise AssetRejected(f"asset type {asset_type!r} is not an element name")
    if not asset_id:
        raise AssetRejected("an asset needs an assetId")
    if len(body.encode("utf-8", "surrogatepass")) > MAX_ASSET_BYTES:
        raise AssetRejected(f"asset {asset_id} is larger than {MAX_ASSET_BYTES} bytes")
    if "<!DOCTYPE" in body or "<!ENTITY" in body:
        raise AssetRejected(f"asset {asset_id}: DOCTYPE and entity declarations are not accepted")
    try:
        root = ET.fromstring(body)
    except ET.ParseError as exc:
        raise AssetRejected(f"asset {asset_id} is not well-formed XML: {exc}") from None
    if root.tag != asset_type:
        raise AssetRejected(f"asset {asset_id}: the root element is {root.tag!r}, not {asset_type!r}")
    root.set("assetId", asset_id)
    root.set("timestamp", timestamp)
    if device_uuid is not None:
        root.set("deviceUuid", device_uuid)
    if removed:
        root.set("removed", "true")
    elif "removed" in root.attrib:
        del root.attrib["removed"]
    return Asset(asset_id, asset_type, timestamp, device_uuid, ET.tostring(root, encoding="unicode"), removed)


def removed_copy(asset: Asset, timestamp: str) -> Asset:
    """The same asset marked removed (what /assets?removed=true shows after @REMOVE_ASSET@)."""
    root = ET.fromstring(asset.xml)
    root.set("removed", "true")
    root.set("timestamp", timestamp)
    return Asset(
        asset.asset_id, asset.type, timestamp, asset.device_uuid, ET.tostring(root, encoding="unicode"), True
    )
