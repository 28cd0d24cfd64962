"""What an MQTT requester may make the gateway do, against a real Mosquitto (issue 23, item 9).

- A `/set` or command request whose MQTT 5 response topic is neither a result topic under the gateway's
  prefix nor allowed by `mqtt.response_topics` is refused, answered on its own result topic, and nothing is
  published where it asked (before: the answer went there, with the gateway's credentials; the issue's
  refusals landed on `spBv1.0/cnc/NCMD/other-edge`).
- A packet larger than `mqtt.max_packet_size` never reaches the gateway's memory: with MQTT 5 the CONNECT says
  the limit and the broker drops the message for the gateway; with MQTT 3.1.1 the gateway ends the connection
  as soon as the packet's header arrives, says why, and connects again (before: the whole packet was read,
  then answered `BadRequestTooLarge`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.integration.mqtt.test_sink import _Writer, make_tree, running
from tests.waiting import wait_until

SET = "cnc/m1/feed/override/set"
RESULT = SET + "/result"
ELSEWHERE = "spBv1.0/cnc/NCMD/other-edge"  # another edge node's command topic, as in the issue
MIB = 1024 * 1024


def response_to(topic: str) -> Any:
    props = Properties(PacketTypes.PUBLISH)
    props.ResponseTopic = topic
    props.CorrelationData = b"attack-1"
    return props


async def test_a_response_topic_outside_the_prefix_gets_nothing_published_there(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    writer = tree.machines["m1"].writer = _Writer()
    spy = subscriber(recorders, mosquitto.port, v5=True, topics=["spBv1.0/#", "elsewhere/#", RESULT])
    async with running(tree, mqtt_config(mosquitto.port, protocol="5"), tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        for topic in (ELSEWHERE, "elsewhere/me", "cnc/m1/feed/override"):  # the last: under the prefix
            before = len(spy.on(RESULT))
            spy.publish(SET, b"150", properties=response_to(topic))
            await wait_until(lambda n=before: len(spy.on(RESULT)) > n, message=f"the refusal for {topic}")
            answer = spy.on(RESULT)[-1]
            assert answer.json()["status"] == "BadRequestNotAllowed" and topic in answer.json()["error"]
            assert answer.properties.CorrelationData == b"attack-1"
        # A request the broker delivered after the three is answered, so theirs would have arrived by now.
        spy.publish(SET, b"20")
        await wait_until(lambda: spy.last_json(RESULT) == {"ok": True}, message="a plain write's answer")
        assert [m.topic for m in spy.messages if not m.topic.startswith("cnc/")] == []
        assert not spy.on("cnc/m1/feed/override")
        assert writer.writes == [("Feed/Override", 20)]  # the machine saw only the plain write
        assert sink.writes.refused_response_topics == 3


async def test_a_response_topic_the_gateway_file_allows_is_answered_on(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    writer = tree.machines["m1"].writer = _Writer()
    rec = subscriber(recorders, mosquitto.port, v5=True, topics=["cell/#", RESULT])
    cfg = mqtt_config(mosquitto.port, protocol="5", response_topics=["cell/+/answers"])
    async with running(tree, cfg, tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        rec.publish(SET, b"40", properties=response_to("cell/7/answers"))
        answer = await wait_until(lambda: rec.last("cell/7/answers"), message="the answer where it asked")
        assert answer.json() == {"ok": True} and writer.writes == [("Feed/Override", 40)]
        assert not rec.on(RESULT)


@pytest.mark.parametrize("protocol", ["5", "3.1.1"])
async def test_a_packet_over_max_packet_size_never_reaches_the_gateway(
    protocol: str,
    mosquitto: Mosquitto,
    recorders: list[Recorder],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="gateway.sinks.mqtt_link.client")
    tree = make_tree()
    writer = tree.machines["m1"].writer = _Writer()
    rec = subscriber(recorders, mosquitto.port, topics=[RESULT])
    cfg = mqtt_config(mosquitto.port, protocol=protocol, max_packet_size=MIB)
    async with running(tree, cfg, tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        rec.publish(SET, b"7" * (4 * MIB), qos=0)  # QoS 0: nothing for the broker to redeliver after a drop
        if protocol == "3.1.1":  # the broker sends it: the gateway drops it unread, with the connection
            await wait_until(lambda: sink._client and sink._client.oversized_packets == 1, timeout=20,
                             message="the oversized packet refused")  # fmt: skip
            assert sink.connects >= 1
            await wait_until(
                lambda: sink.connects == 2 and sink.online, timeout=20, message="connected again"
            )
        rec.publish(SET, b"30")
        await wait_until(lambda: rec.last_json(RESULT) == {"ok": True}, timeout=20, message="a small write")
        assert writer.writes == [("Feed/Override", 30)]
        # Received means handled by the write path: the 4 MiB request never was (nor answered "too large").
        assert sink.writes.received == 1 and len(rec.on(RESULT)) == 1
        client = sink._client
        assert client is not None
        if protocol == "5":  # the broker kept it from the gateway, which never lost its connection
            assert sink.connects == 1 and client.oversized_packets == 0
        else:
            [line] = [r.getMessage() for r in caplog.records if r.name == "gateway.sinks.mqtt_link.client"]
            size = 1 + 4 + 2 + len(SET) + 4 * MIB  # fixed header (4 length bytes), topic, payload
            assert f"a packet of {size} bytes, more than max_packet_size 1048576" in line
            assert "message_size_limit" in line
