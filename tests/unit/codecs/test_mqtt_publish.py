"""gateway/codecs/mqtt_publish.py: QoS 0 and 1 PUBLISH packets, byte for byte what paho itself would send,
and PUBACKs read from a stream however it is split."""

from __future__ import annotations

from typing import Any, cast

import paho.mqtt.client as paho
import pytest
from hypothesis import given
from hypothesis import strategies as st
from paho.mqtt.enums import CallbackAPIVersion

from gateway.codecs.mqtt_publish import (
    first_byte,
    publish_packet,
    qos1_first_byte,
    qos1_packet,
    read_puback,
    remaining_length,
    topic_field,
    topic_head,
)


class _NoSocket:
    pass


def _ignore(*args: object) -> None:
    pass


def _unconnected(v5: bool) -> paho.Client:
    protocol = paho.MQTTv5 if v5 else paho.MQTTv311
    client = paho.Client(CallbackAPIVersion.VERSION2, protocol=protocol)
    client._sock = cast(Any, _NoSocket())  # paho builds a packet only for a connected client
    client.on_socket_register_write = _ignore  # ...and then leaves it in its queue for the loop to write
    return client


def _queued(client: paho.Client) -> bytes:
    packet = bytes(client._out_packet.popleft()["packet"])
    client._sock = None  # nothing for paho to close
    return packet


def paho_packet(
    topic: str, payload: bytes, retain: bool, v5: bool, qos: int = 0, mid: int = 0, dup: bool = False
) -> bytes:
    """The packet paho builds for the same message (never connected: it only queues it)."""
    client = _unconnected(v5)
    client._send_publish(mid, topic.encode(), payload, qos, retain, dup)
    return _queued(client)


def paho_puback(mid: int) -> bytes:
    """The PUBACK paho itself sends for a QoS 1 message it received."""
    client = _unconnected(False)
    client._send_puback(mid)
    return _queued(client)


@given(
    topic=st.text(st.characters(codec="utf-8", exclude_characters="+#\x00"), min_size=1),
    payload=st.binary(max_size=20_000),
    retain=st.booleans(),
    v5=st.booleans(),
)
def test_a_packet_is_what_paho_sends(topic: str, payload: bytes, retain: bool, v5: bool) -> None:
    ours = publish_packet(first_byte(retain), topic_field(topic, v5=v5), payload)
    assert ours == paho_packet(topic, payload, retain, v5)


@pytest.mark.parametrize(
    ("n", "encoded"),
    [
        (0, b"\x00"),
        (127, b"\x7f"),
        (128, b"\x80\x01"),
        (16_383, b"\xff\x7f"),
        (16_384, b"\x80\x80\x01"),
        (2_097_151, b"\xff\xff\x7f"),
        (2_097_152, b"\x80\x80\x80\x01"),
        (268_435_455, b"\xff\xff\xff\x7f"),
    ],
)
def test_remaining_length_at_every_boundary(n: int, encoded: bytes) -> None:
    assert remaining_length(n) == encoded


def test_what_mqtt_cannot_carry_is_refused() -> None:
    with pytest.raises(ValueError, match="MQTT allows 268435455"):
        remaining_length(268_435_456)
    with pytest.raises(ValueError, match="MQTT allows 65535"):
        topic_field("x" * 65_536)


@given(
    topic=st.text(st.characters(codec="utf-8", exclude_characters="+#\x00"), min_size=1),
    payload=st.binary(max_size=20_000),
    retain=st.booleans(),
    dup=st.booleans(),
    v5=st.booleans(),
    mid=st.integers(1, 65_535),
)
def test_a_qos1_packet_is_what_paho_sends(
    topic: str, payload: bytes, retain: bool, dup: bool, v5: bool, mid: int
) -> None:
    ours = qos1_packet(qos1_first_byte(retain, dup), topic_head(topic), mid, payload, v5=v5)
    assert ours == paho_packet(topic, payload, retain, v5, qos=1, mid=mid, dup=dup)


@given(mid=st.integers(0, 65_535))
def test_a_puback_paho_sends_is_read_back(mid: int) -> None:
    assert read_puback(paho_puback(mid)) == (mid, 0, 4)


def _v5_puback(mid: int, reason: int, reason_string: bytes | None) -> bytes:
    """MQTT 5 §3.4: packet id, reason code, properties (here a Reason String, 0x1F), written out by hand."""
    props = b"" if reason_string is None else b"\x1f" + len(reason_string).to_bytes(2, "big") + reason_string
    body = (
        mid.to_bytes(2, "big") + bytes((reason,)) + (remaining_length(len(props)) + props if props else b"")
    )
    return b"\x40" + remaining_length(len(body)) + body


@given(
    acks=st.lists(
        st.tuples(st.integers(0, 65_535), st.sampled_from([0, 0x10, 0x80, 0x87, 0x97]),
                  st.none() | st.binary(max_size=300)),
        min_size=1, max_size=20,
    ),
)  # fmt: skip
def test_a_stream_of_pubacks_split_anywhere_reads_the_same(acks: list[tuple[int, int, bytes | None]]) -> None:
    stream = b"".join(_v5_puback(mid, reason, text) for mid, reason, text in acks)
    want = [(mid, reason) for mid, reason, _ in acks]
    for cut in range(len(stream) + 1):
        buf = bytearray(stream[:cut])
        got: list[tuple[int, int]] = []
        pos = 0
        while (ack := read_puback(buf, pos)) is not None:
            got.append(ack[:2])
            pos = ack[2]
        buf += stream[cut:]  # the rest arrives
        while (ack := read_puback(buf, pos)) is not None:
            got.append(ack[:2])
            pos = ack[2]
        assert got == want and pos == len(stream)


def test_other_packets_are_left_to_paho() -> None:
    suback = b"\x90\x03\x00\x01\x01"
    assert read_puback(suback) is None
    assert read_puback(b"\x40\x02\x00\x07" + suback) == (7, 0, 4)
    assert read_puback(b"\x40\x02\x00\x07" + suback, 4) is None


@pytest.mark.parametrize(
    "junk",
    [b"\x40\x00", b"\x40\x01\x00", b"\x40\xff\xff\xff\xff\x7f", b"\x40\x04\x00\x01\x87\x07",
     b"\x40\x05\x00\x01\x87\x00\x00"],
    ids=["empty", "one byte", "five-byte length", "properties cut short", "properties shorter than said"],
)  # fmt: skip
def test_a_malformed_puback_is_refused(junk: bytes) -> None:
    with pytest.raises(ValueError, match="PUBACK"):
        read_puback(junk)
