"""PUBACKs decoded without new objects (gateway/sinks/mqtt/client.py, `_shared_success_acks`): the same
answer as paho's own decoder, for every PUBACK paho can be given."""

from __future__ import annotations

from paho.mqtt import _packet
from paho.mqtt.enums import MQTTProtocolVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from gateway.sinks.mqtt_link.client import _shared_success_acks

V5, V311 = MQTTProtocolVersion.MQTTv5, MQTTProtocolVersion.MQTTv311
HEADER = 0x40


def _seen(packet: object) -> tuple[object, ...]:
    mid, reason, properties = packet  # type: ignore[misc]
    return mid, reason.value, reason.getName(), reason.packetType, str(properties)


def test_two_byte_acks_decode_as_paho_decodes_them_to_one_shared_pair() -> None:
    _shared_success_acks()
    fast = _packet.decode_puback
    for protocol in (V5, V311):
        for mid in (1, 255, 256, 65535):
            body = mid.to_bytes(2, "big")
            ours = fast(HEADER, body, protocol)
            assert _seen(ours) == _seen(_packet.PubackPacket(mid, *_reference(protocol, body)))
    a, b = fast(HEADER, b"\x00\x01", V5), fast(HEADER, b"\x00\x02", V5)
    assert a.reason is b.reason and a.properties is b.properties
    _shared_success_acks()  # once per process
    assert _packet.decode_puback is fast


def _reference(protocol: MQTTProtocolVersion, body: bytes) -> tuple[object, object]:
    """What paho's own decoder builds for a two-byte PUBACK (paho/mqtt/_packet.py)."""
    return ReasonCode(PacketTypes.PUBACK), Properties(PacketTypes.PUBACK)  # type: ignore[no-untyped-call]


def test_acks_with_a_reason_or_properties_go_to_paho() -> None:
    _shared_success_acks()
    refused = _packet.decode_puback(HEADER, b"\x00\x07\x80", V5)  # unspecified error
    assert refused.mid == 7 and refused.reason.value == 0x80 and refused.reason.is_failure
    with_props = _packet.decode_puback(HEADER, b"\x00\x08\x00\x00", V5)
    assert with_props.mid == 8 and not with_props.reason.is_failure
