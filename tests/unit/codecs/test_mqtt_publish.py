"""gateway/codecs/mqtt_publish.py: QoS 0 PUBLISH packets, byte for byte what paho itself would send."""

from __future__ import annotations

from typing import Any, cast

import paho.mqtt.client as paho
import pytest
from hypothesis import given
from hypothesis import strategies as st
from paho.mqtt.enums import CallbackAPIVersion

from gateway.codecs.mqtt_publish import first_byte, publish_packet, remaining_length, topic_field


class _NoSocket:
    pass


def _ignore(*args: object) -> None:
    pass


def paho_packet(topic: str, payload: bytes, retain: bool, v5: bool) -> bytes:
    """The packet paho builds for the same QoS 0 message (never connected: it only queues it)."""
    protocol = paho.MQTTv5 if v5 else paho.MQTTv311
    client = paho.Client(CallbackAPIVersion.VERSION2, protocol=protocol)
    client._sock = cast(Any, _NoSocket())  # paho builds a packet only for a connected client
    client.on_socket_register_write = _ignore  # ...and then leaves it in its queue for the loop to write
    client._send_publish(0, topic.encode(), payload, 0, retain)
    packet = bytes(client._out_packet.popleft()["packet"])
    client._sock = None  # nothing for paho to close
    return packet


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
