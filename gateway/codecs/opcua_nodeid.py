"""OPC UA node addresses as written in mapping files, parsed strictly.

A mapping's `source` is an OPC UA node id string: `ns=2;s=::AsGlobalPV:gAxis[0].ActPos`,
`ns=3;i=1001`, `g=…`, `b=…`, or `nsu=<namespace uri>;s=…`. The `nsu=` form names the
namespace by URI, because controllers may renumber their namespaces after a restart;
the driver resolves it against the server's namespace array at every connect.

asyncua's own parser silently ignores what it does not understand; this one says
what is wrong, so a typo turns one variable Bad with a reason instead of
subscribing to the wrong node. Pure: no I/O, no asyncua, so that the config
loader checks every address at load time and the OPC UA source driver
(gateway/sources/opcua/client.py) resolves them at connect time with the same code.
Errors are `gateway.errors.AddressError` (a CodecError).
"""

from __future__ import annotations

import base64
import binascii
import re
import sys
import uuid
from dataclasses import dataclass

from gateway.errors import AddressError

__all__ = ["AddressError", "OpcUaAddress", "parse_address"]

_ADDRESS_RE = re.compile(r"^(?:ns=(?P<ns>[^;]*);|nsu=(?P<nsu>.+?);)?(?P<kind>[isgb])=(?P<id>.*)$", re.DOTALL)


@dataclass(frozen=True, slots=True)
class OpcUaAddress:
    """A parsed node id. Exactly one of `namespace` (an index) and `namespace_uri` is meaningful."""

    kind: str  # "i" numeric, "s" string, "g" GUID, "b" opaque bytes
    identifier: int | str | uuid.UUID | bytes
    namespace: int = 0
    namespace_uri: str | None = None

    def resolve(self, namespaces: list[str] | tuple[str, ...]) -> int:
        """The namespace index on a server with this namespace array. Raises AddressError."""
        if self.namespace_uri is None:
            if namespaces and self.namespace >= len(namespaces):
                raise AddressError(
                    f"namespace index {self.namespace} is not on the server ({len(namespaces)} namespaces)"
                )
            return self.namespace
        try:
            return list(namespaces).index(self.namespace_uri)
        except ValueError:
            raise AddressError(f"namespace {self.namespace_uri!r} is not on the server") from None


def parse_address(text: str) -> OpcUaAddress:
    """Parse a node id string, or raise AddressError saying what is wrong with it."""
    match = _ADDRESS_RE.match(text.strip()) if isinstance(text, str) else None
    if match is None:
        raise AddressError(
            f"{text!r} is not an OPC UA node id; "
            "expected e.g. 'ns=2;s=Name', 'ns=3;i=1001' or 'nsu=urn:…;s=Name'"
        )
    namespace = 0
    if match["ns"] is not None:
        ns_text = match["ns"].strip()
        if not ns_text.isdigit() or int(ns_text) > 0xFFFF:
            raise AddressError(f"{text!r}: namespace index {ns_text!r} must be a number from 0 to 65535")
        namespace = int(ns_text)
    uri = match["nsu"]
    if uri is not None:
        uri = sys.intern(uri.strip())  # one controller's URI on every variable: one string, not thousands
        if not uri:
            raise AddressError(f"{text!r}: nsu= needs a namespace URI")
    kind = match["kind"]
    raw = match["id"]
    return OpcUaAddress(kind, _identifier(text, kind, raw), namespace, uri)


def _identifier(text: str, kind: str, raw: str) -> int | str | uuid.UUID | bytes:
    if kind == "s":
        if not raw:
            raise AddressError(f"{text!r}: the string identifier after s= is empty")
        return raw
    value = raw.strip()
    if kind == "i":
        if not value.isdigit() or int(value) > 0xFFFFFFFF:
            raise AddressError(f"{text!r}: a numeric identifier (i=) must be a number from 0 to 4294967295")
        return int(value)
    if kind == "g":
        try:
            return uuid.UUID(value)
        except ValueError:
            raise AddressError(f"{text!r}: {value!r} is not a GUID") from None
    if not value:
        raise AddressError(f"{text!r}: the identifier after b= is empty")
    try:
        return base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise AddressError(f"{text!r}: the identifier after b= must be base64") from None
