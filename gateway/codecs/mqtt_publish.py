"""MQTT PUBLISH packets at QoS 0 and 1, and the PUBACKs that answer them: bytes in, bytes out.

The MQTT sink sends thousands of QoS 0 changes a second. Handing each to paho
costs a message-info object, a lock, a packet dict, a socket write and, once
written, a PUBACK-shaped callback with freshly built reason-code and properties
objects. A QoS 0 PUBLISH needs none of that: it is a first byte, a length, the
topic and the payload, with no packet id. The sink encodes a batch of them here
and queues the batch as one write (`MqttClient.publish_packets`).

Wire format (MQTT 3.1.1 §3.3, MQTT 5 §3.3): `0x30 | retain`, the remaining length
as a variable byte integer, the topic as a UTF-8 string with a 2-byte length,
(MQTT 5: the properties' length, 0), then the payload.

QoS 1 (issue 28) is the same packet with the QoS bits set (`0x32 | retain`,
`| 0x08` when it is sent again), and a 2-byte packet identifier between the
topic and the properties. The broker answers each with a PUBACK: `0x40`, a
remaining length of 2 (MQTT 5: 2, 3 or more, for a reason code and properties),
the packet identifier. `read_puback` takes those from a receive buffer one by
one, so that a burst of acknowledgements costs no per-packet object and no
per-packet read from the socket.
"""

from __future__ import annotations

MAX_REMAINING = 268_435_455  # the largest length a variable byte integer holds (4 bytes)
MAX_TOPIC = 65_535


PUBACK = 0x40
FAILURE = 0x80  # reason codes from here on say the broker did not accept the message (MQTT 5 §3.4.2.1)


def topic_head(topic: str) -> bytes:
    """The topic as an MQTT UTF-8 string: its length in 2 bytes, then the bytes."""
    raw = topic.encode("utf-8")
    if len(raw) > MAX_TOPIC:
        raise ValueError(f"topic of {len(raw)} bytes (MQTT allows {MAX_TOPIC})")
    return len(raw).to_bytes(2, "big") + raw


def topic_field(topic: str, *, v5: bool = False) -> bytes:
    """The variable header of a QoS 0 PUBLISH: the topic with its length (and no properties, MQTT 5)."""
    return topic_head(topic) + (b"\x00" if v5 else b"")


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


def qos1_first_byte(retain: bool, dup: bool = False) -> bytes:
    """The fixed header's first byte of a QoS 1 PUBLISH; `dup` when it is a re-delivery attempt."""
    return bytes((0x32 | (0x08 if dup else 0) | (0x01 if retain else 0),))


def qos1_packet(first: bytes, head: bytes, packet_id: int, payload: bytes, *, v5: bool = False) -> bytes:
    """One QoS 1 PUBLISH: `first` from `qos1_first_byte()`, `head` from `topic_head()`."""
    ident = packet_id.to_bytes(2, "big")
    if v5:
        return first + remaining_length(len(head) + 3 + len(payload)) + head + ident + b"\x00" + payload
    return first + remaining_length(len(head) + 2 + len(payload)) + head + ident + payload


def read_puback(buf: bytes | bytearray, pos: int = 0) -> tuple[int, int, int] | None:
    """The PUBACK at `buf[pos:]` as (packet id, reason code, where the next packet starts); None when
    what starts there is another kind of packet or not all of it has arrived yet.

    The reason code is 0 (success) when the packet carries none (MQTT 3.1.1, and MQTT 5's short form).
    A PUBACK whose length cannot hold a packet id is malformed: ValueError.
    """
    end = len(buf)
    if end - pos < 2 or buf[pos] != PUBACK:
        return None
    found = _varint(buf, pos + 1, end, "remaining length")
    if found is None:
        return None
    length, at = found
    if length < 2:
        raise ValueError(f"a PUBACK of remaining length {length} (a packet id takes 2)")
    if end - at < length:
        return None
    reason = buf[at + 2] if length > 2 else 0
    if length > 3:  # MQTT 5: properties follow, their length first; they must fill the packet exactly
        props = _varint(buf, at + 3, at + length, "properties' length")
        if props is None:
            raise ValueError("a PUBACK whose properties' length is cut short")
        size, prop = props
        if prop + size != at + length:
            raise ValueError(f"a PUBACK whose properties ({size} bytes) do not fill its remaining length")
    return (buf[at] << 8) | buf[at + 1], reason, at + length


def _varint(buf: bytes | bytearray, at: int, end: int, what: str) -> tuple[int, int] | None:
    """The variable byte integer at `buf[at:end]` and where it ends; None when `end` cuts it short."""
    value = shift = 0
    while True:
        if at >= end:
            return None
        byte = buf[at]
        value |= (byte & 0x7F) << shift
        at += 1
        if not byte & 0x80:
            return value, at
        shift += 7
        if shift > 21:
            raise ValueError(f"a PUBACK whose {what} takes more than 4 bytes")
