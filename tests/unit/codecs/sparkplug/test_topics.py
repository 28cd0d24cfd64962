"""Topics: built and parsed as Sparkplug 3.0 chapter 4 says, and every malformed one refused."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.sparkplug import (
    BadId,
    BadTopic,
    MessageType,
    StateTopic,
    Topic,
    check_id,
    command_subscriptions,
    device_topic,
    node_topic,
    parse_topic,
    state_topic,
)

NODE_TYPES = [t for t in MessageType if not t.is_device]
DEVICE_TYPES = [t for t in MessageType if t.is_device]

ids = st.text(st.characters(codec="utf-8", exclude_characters="+#/\x00"), min_size=1, max_size=20).filter(
    lambda s: s != "STATE"
)


def test_the_specifications_examples() -> None:
    assert node_topic("Sparkplug B Devices", MessageType.NBIRTH, "Raspberry Pi") == (
        "spBv1.0/Sparkplug B Devices/NBIRTH/Raspberry Pi"
    )
    assert device_topic("Sparkplug B Devices", MessageType.DBIRTH, "Raspberry Pi", "Pibrella") == (
        "spBv1.0/Sparkplug B Devices/DBIRTH/Raspberry Pi/Pibrella"
    )
    assert state_topic("scada-1") == "spBv1.0/STATE/scada-1"


def test_which_types_carry_a_device_id() -> None:
    assert {t.value for t in DEVICE_TYPES} == {"DBIRTH", "DDEATH", "DDATA", "DCMD"}
    assert {t.value for t in NODE_TYPES} == {"NBIRTH", "NDEATH", "NDATA", "NCMD"}


def test_qos_and_retain_as_the_specification_requires() -> None:
    assert {t.value: (t.qos, t.retain) for t in MessageType} == {
        "NBIRTH": (0, False), "NDEATH": (1, False), "NDATA": (0, False), "NCMD": (0, False),
        "DBIRTH": (0, False), "DDEATH": (0, False), "DDATA": (0, False), "DCMD": (0, False),
    }  # fmt: skip


@given(group=ids, edge=ids, kind=st.sampled_from(NODE_TYPES))
def test_node_topics_round_trip(group: str, edge: str, kind: MessageType) -> None:
    assert parse_topic(node_topic(group, kind, edge)) == Topic(group, kind, edge)


@given(group=ids, edge=ids, device=ids, kind=st.sampled_from(DEVICE_TYPES))
def test_device_topics_round_trip(group: str, edge: str, device: str, kind: MessageType) -> None:
    assert parse_topic(device_topic(group, kind, edge, device)) == Topic(group, kind, edge, device)


@given(host=ids)
def test_state_topics_round_trip(host: str) -> None:
    assert parse_topic(state_topic(host)) == StateTopic(host)
    assert parse_topic(f"STATE/{host}") == StateTopic(host, legacy=True)
    assert str(StateTopic(host, legacy=True)) == f"STATE/{host}"


def test_command_subscriptions_cover_the_node_and_every_device() -> None:
    assert command_subscriptions("plant", "gw") == ("spBv1.0/plant/NCMD/gw", "spBv1.0/plant/DCMD/gw/+")


@pytest.mark.parametrize("bad", ["", "a+b", "a#", "a/b", "+", "#", "nul\x00", "lone\ud800"])
def test_ids_sparkplug_reserves_are_refused(bad: str) -> None:
    with pytest.raises(BadId):
        check_id("edge node id", bad)
    with pytest.raises(BadId):
        node_topic("plant", MessageType.NBIRTH, bad)
    with pytest.raises(BadId):
        device_topic("plant", MessageType.DDATA, "gw", bad)
    with pytest.raises(BadId):
        state_topic(bad)


def test_a_group_named_state_is_refused() -> None:
    with pytest.raises(BadId, match="host applications publish their STATE"):
        node_topic("STATE", MessageType.NBIRTH, "gw")


def test_device_ids_go_with_device_types_only() -> None:
    with pytest.raises(BadTopic, match="DDATA topic needs a device id"):
        Topic("plant", MessageType.DDATA, "gw")
    with pytest.raises(BadTopic, match="NDATA topic has no device id"):
        Topic("plant", MessageType.NDATA, "gw", "laser")


@pytest.mark.parametrize(
    ("topic", "fragment"),
    [
        ("spBv1.0", "got 1 levels"),
        ("spBv1.0/plant/NBIRTH", "got 3 levels"),
        ("spBv1.0/plant/DDATA/gw/laser/extra", "got 6 levels"),
        ("spAv1.0/plant/NBIRTH/gw", "not in the spBv1.0 namespace"),
        ("cnc/laser-sim/feed/override", "not in the spBv1.0 namespace"),
        ("spBv1.0/plant/NBIRTHX/gw", "unknown message type 'NBIRTHX'"),
        ("spBv1.0/plant/nbirth/gw", "unknown message type 'nbirth'"),  # topics are case-sensitive
        ("spBv1.0/plant/DDATA/gw", "DDATA topic needs a device id"),
        ("spBv1.0/plant/NCMD/gw/laser", "NCMD topic has no device id"),
        ("spBv1.0/plant/NCMD//", "edge node id is empty"),
        ("spBv1.0/STATE/", "host id is empty"),
        ("STATE/a/b", "not in the spBv1.0 namespace"),
        ("spBv1.0/plant/DCMD/gw/+", "contains '+'"),
        ("spBv1.0/plant/DCMD/gw/#", "contains '#'"),
        ("spBv1.0/STATE/NBIRTH/gw", "host applications publish their STATE"),
        ("spBv1.0/x/NDATA/" + "a" * 70000, "longer than an MQTT topic"),
    ],
)
def test_topics_that_are_not_sparkplug_are_refused(topic: str, fragment: str) -> None:
    with pytest.raises((BadTopic, BadId)) as info:
        parse_topic(topic)
    assert fragment in str(info.value)
