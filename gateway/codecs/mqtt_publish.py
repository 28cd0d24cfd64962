"""MQTT PUBLISH packets at QoS 0, encoded ahead of the client library: bytes in, bytes out.

The MQTT sink sends thousands of QoS 0 changes a second. Handing each to paho
costs a message-info object, a lock, a packet dict, a socket write and, once
written, a PUBACK-shaped callback with freshly built reason-code and properties
objects. A QoS 0 PUBLISH needs none of that: it is a first byte, a length, the
topic and the payload, with no packet id. The sink encodes a batch of them here
and queues the batch as one write (`MqttClient.publish_packets`).

Wire format (MQTT 3.1.1 §3.3, MQTT 5 §3.3): `0x30 | retain`, the remaining length
as a variable byte integer, the topic as a UTF-8 string with a 2-byte length,
(MQTT 5: the properties' length, 0), then the payload.
"""

from __future__ import annotations

MAX_REMAINING = 268_435_455  # the largest length a variable byte integer holds (4 bytes)
MAX_TOPIC = 65_535


def topic_field(topic: str, *, v5: bool = False) -> bytes:
    """The variable header of a QoS 0 PUBLISH: the topic with its length (and no properties, MQTT 5)."""
    raw = topic.encode("utf-8")
    if len(raw) > MAX_TOPIC:
        raise ValueError(f"topic of {len(raw)} bytes (MQTT allows {MAX_TOPIC})")
    return len(raw).to_bytes(2, "big") + raw + (b"\x00" if v5 else b"")


def first_byte(retain: bool) -> bytes:
    """The fixed header's first byte: PUBLISH, QoS 0, not a duplicate, the retain flag."""
    return b"\x31" if retain else b"\x30"


def remaining_length(n: int) -> bytes:
    """`n` as MQTT's variable byte integer (7 bits a byte, least significant first)."""
    if n < 128:
        return bytes((n,))
    if n < 16_384:
        return bytes((n & 0x7F | 0x80, n >> 7))
    if n > MAX_REMAINING:
        raise ValueError(f"packet of {n} bytes (MQTT allows {MAX_REMAINING})")
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | 0x80 if n else byte)
        if not n:
            return bytes(out)


def publish_packet(first: bytes, field: bytes, payload: bytes) -> bytes:
    """One QoS 0 PUBLISH: `first` and `field` from `first_byte()` and `topic_field()`."""
    return first + remaining_length(len(field) + len(payload)) + field + payload
