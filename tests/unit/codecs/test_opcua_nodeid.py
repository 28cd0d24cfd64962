import uuid

import pytest

from gateway.codecs.opcua_nodeid import OpcUaAddress, parse_address
from gateway.errors import AddressError


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("ns=2;s=::AsGlobalPV:gAxis[0].ActPos", OpcUaAddress("s", "::AsGlobalPV:gAxis[0].ActPos", 2)),
        ("ns=3;i=1001", OpcUaAddress("i", 1001, 3)),
        ("i=2258", OpcUaAddress("i", 2258, 0)),
        ("ns=2;s=a;b=c", OpcUaAddress("s", "a;b=c", 2)),  # string ids may contain ';' and '='
        ("nsu=urn:acme:plc;s=Line.Speed", OpcUaAddress("s", "Line.Speed", 0, "urn:acme:plc")),
        ("nsu=http://x.org/UA/;i=5", OpcUaAddress("i", 5, 0, "http://x.org/UA/")),
        (
            "ns=4;g=09087e75-8e5e-499b-954f-f2a9603db28a",
            OpcUaAddress("g", uuid.UUID("09087e75-8e5e-499b-954f-f2a9603db28a"), 4),
        ),
        ("ns=1;b=AAEC", OpcUaAddress("b", b"\x00\x01\x02", 1)),
        ("  ns=2;s=Padded  ", OpcUaAddress("s", "Padded", 2)),
    ],
)
def test_parses_node_id_strings(text: str, expected: OpcUaAddress) -> None:
    assert parse_address(text) == expected


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("", "not an OPC UA node id"),
        ("gAxis.ActPos", "not an OPC UA node id"),
        ("ns=2;x=5", "not an OPC UA node id"),
        ("ns=two;s=A", "namespace index 'two'"),
        ("ns=70000;s=A", "0 to 65535"),
        ("ns=2;s=", "empty"),
        ("ns=2;i=abc", "numeric identifier"),
        ("ns=2;i=-1", "numeric identifier"),
        ("ns=2;i=4294967296", "numeric identifier"),
        ("ns=2;g=not-a-guid", "not a GUID"),
        ("ns=2;b=***", "base64"),
        ("nsu= ;s=A", "namespace URI"),
    ],
)
def test_rejects_bad_addresses_with_a_reason(text: str, fragment: str) -> None:
    with pytest.raises(AddressError, match=fragment.replace("(", r"\(")):
        parse_address(text)


def test_namespace_uri_resolves_to_its_index_on_this_server() -> None:
    address = parse_address("nsu=urn:acme:plc;s=Speed")
    assert address.resolve(["http://opcfoundation.org/UA/", "urn:server", "urn:acme:plc"]) == 2
    assert address.resolve(["http://opcfoundation.org/UA/", "urn:acme:plc"]) == 1


def test_unknown_namespace_uri_or_index_is_an_address_error() -> None:
    with pytest.raises(AddressError, match="urn:acme:plc"):
        parse_address("nsu=urn:acme:plc;s=Speed").resolve(["http://opcfoundation.org/UA/"])
    with pytest.raises(AddressError, match="namespace index 5"):
        parse_address("ns=5;s=Speed").resolve(["http://opcfoundation.org/UA/", "urn:server"])
    assert parse_address("ns=1;s=Speed").resolve(["http://opcfoundation.org/UA/", "urn:server"]) == 1
