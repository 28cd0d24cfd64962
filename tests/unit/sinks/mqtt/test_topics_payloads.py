"""Topic mapping, payload encoding and `/set` decoding: pure functions, no broker."""

from __future__ import annotations

import contextlib
import json
from datetime import UTC, datetime, timedelta, timezone

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.errors import MalformedRequest, OutOfRange, RequestError, TypeMismatch
from gateway.model.sample import Sample
from gateway.model.types import TypeSpec
from gateway.sinks.mqtt.config import MqttConfig, VariableMqtt
from gateway.sinks.mqtt.payloads import decode_set, encode_json, encode_raw, encode_result, iso, unit_suffix
from gateway.sinks.mqtt.topics import (
    TopicClash,
    clean_segment,
    plan_topics,
    result_topic,
    set_filters,
    target_of_set,
    variable_topic,
)

TS = datetime(2026, 3, 4, 5, 6, 7, 891234, tzinfo=UTC)


# --- topics ----------------------------------------------------------------------------------


def test_topic_is_prefix_machine_and_lower_cased_path() -> None:
    assert variable_topic("cnc", "laser-sim", "Axes/X/Position") == "cnc/laser-sim/axes/x/position"
    assert variable_topic("plant/hall2", "m1", "Feed/Override") == "plant/hall2/m1/feed/override"


@pytest.mark.parametrize(
    ("segment", "expected"),
    [("A+B", "a_b"), ("x#", "x_"), ("a/b", "a_b"), ("a b\tc", "a_b_c"), ("nul\x00", "nul_"), ("", "_")],
)
def test_unsafe_characters_are_replaced(segment: str, expected: str) -> None:
    assert clean_segment(segment) == expected


@given(st.text(max_size=40))
def test_a_cleaned_segment_is_always_one_safe_level(segment: str) -> None:
    cleaned = clean_segment(segment)
    assert cleaned and not any(ch in cleaned for ch in "+#/\x00") and not any(ch.isspace() for ch in cleaned)


def test_override_replaces_the_path_part_verbatim() -> None:
    assert variable_topic("cnc", "m1", "Feed/Override", "Speed/OVR") == "cnc/m1/Speed/OVR"


def test_set_and_result_topics() -> None:
    assert target_of_set("cnc/m1/feed/override/set") == "cnc/m1/feed/override"
    assert target_of_set("cnc/m1/feed/override") is None
    assert target_of_set("set") is None
    assert result_topic("cnc/m1/feed/override") == "cnc/m1/feed/override/set/result"
    assert set_filters("cnc", [2, 1, 2]) == ["cnc/+/+/set", "cnc/+/+/+/set"]


def test_plan_refuses_a_topic_claimed_twice_and_names_both() -> None:
    with pytest.raises(TopicClash, match="m1/Axes/X and m1/axes/x"):
        plan_topics([(1, "cnc/m1/axes/x", "m1/axes/x"), (2, "cnc/m1/axes/x", "m1/Axes/X")])
    with pytest.raises(TopicClash, match="status topic"):
        plan_topics([(1, "cnc/status", "m1/x")], reserved=["cnc/status"])


@pytest.mark.parametrize(
    "topic", ["a/+", "#", "a//b", "/a", "a/", "x/set", "x/set/result", "status", "$SYS/x"]
)
def test_override_topics_that_cannot_work_are_config_errors(topic: str) -> None:
    with pytest.raises(ValueError):
        VariableMqtt(topic=topic)


def test_prefix_and_protocol_are_checked() -> None:
    with pytest.raises(ValueError, match="wildcards"):
        MqttConfig(prefix="cnc/#")
    assert MqttConfig.model_validate({"protocol": 5}).protocol == "5"
    with pytest.raises(ValueError):
        MqttConfig.model_validate({"protocol": 4})


# --- payloads --------------------------------------------------------------------------------


def test_iso_is_utc_with_milliseconds_and_z() -> None:
    assert iso(TS) == "2026-03-04T05:06:07.891Z"
    assert iso(TS.astimezone(timezone(timedelta(hours=2)))) == "2026-03-04T05:06:07.891Z"
    assert iso(TS.replace(tzinfo=None)) == "2026-03-04T05:06:07.891Z"


def test_good_sample_json() -> None:
    doc = json.loads(encode_json(Sample(12.5, TS), unit_suffix("mm")))
    assert doc == {"value": 12.5, "ts": "2026-03-04T05:06:07.891Z", "quality": "good", "unit": "mm"}
    assert "unit" not in json.loads(encode_json(Sample(True, TS), unit_suffix("")))


def test_bad_sample_keeps_the_last_value_and_says_why() -> None:
    doc = json.loads(
        encode_json(Sample(7, TS, "BadNotConnected", "controller unreachable"), unit_suffix("%"))
    )
    assert doc == {
        "value": 7,
        "ts": "2026-03-04T05:06:07.891Z",
        "quality": "bad",
        "status": "BadNotConnected",
        "reason": "controller unreachable",
        "unit": "%",
    }
    assert json.loads(encode_json(Sample(1.0, TS, "UncertainLastUsableValue"), "}"))["quality"] == "uncertain"


@pytest.mark.parametrize(
    ("value", "json_value", "raw"),
    [
        (1.5, 1.5, b"1.5"),
        (float("nan"), None, b"null"),
        (3, 3, b"3"),
        (False, False, b"false"),
        ('part "1".nc', 'part "1".nc', b'part "1".nc'),
        ([1.0, 2.5], [1.0, 2.5], b"[1.0,2.5]"),
        (["a", "b"], ["a", "b"], b'["a","b"]'),
        (TS, "2026-03-04T05:06:07.891Z", b"2026-03-04T05:06:07.891Z"),
        ("äö", "äö", "äö".encode()),
    ],
)
def test_value_forms(value: object, json_value: object, raw: bytes) -> None:
    assert json.loads(encode_json(Sample(value, TS), "}"))["value"] == json_value
    assert encode_raw(value) == raw


def test_results() -> None:
    assert json.loads(encode_result()) == {"ok": True}
    assert json.loads(encode_result("out of range", "BadOutOfRange")) == {
        "ok": False,
        "error": "out of range",
        "status": "BadOutOfRange",
    }


# --- /set decoding ---------------------------------------------------------------------------

U16, DBL, BOOL, STR = (TypeSpec.parse(t) for t in ("UInt16", "Double", "Boolean", "String"))


@pytest.mark.parametrize(
    ("payload", "spec", "value"),
    [
        (b'{"value": 50}', U16, 50),
        (b"50", U16, 50),
        (b" 50\n", U16, 50),
        (b"12.5", DBL, 12.5),
        (b"true", BOOL, True),
        (b"on", BOOL, True),
        (b"part.nc", STR, "part.nc"),
        (b'{"value": "a b"}', STR, "a b"),
        (b"[1, 2]", TypeSpec.parse("UInt16[]"), [1, 2]),
    ],
)
def test_accepted_requests(payload: bytes, spec: TypeSpec, value: object) -> None:
    assert decode_set(payload, spec) == value


@pytest.mark.parametrize(
    ("payload", "spec", "error", "fragment"),
    [
        (b'{"value": 5', U16, MalformedRequest, "malformed JSON"),
        (b'{"valeu": 5}', U16, MalformedRequest, '"value" key'),
        (b'{"value": 5, "x": 1}', U16, MalformedRequest, "unknown key 'x'"),
        (b"", U16, MalformedRequest, "empty"),
        (b"\xff\xfe", U16, MalformedRequest, "not UTF-8"),
        (b"fast", U16, TypeMismatch, "expected UInt16"),
        (b"70000", U16, OutOfRange, "does not fit UInt16"),
        (b"[" * 100_000, U16, MalformedRequest, "cannot read"),
        (b'{"value": ' + b"[" * 100_000, U16, MalformedRequest, "nested too deeply"),
        (b"9" * 5000, U16, TypeMismatch, "expected UInt16"),
    ],
)
def test_refused_requests_say_precisely_why(
    payload: bytes, spec: TypeSpec, error: type, fragment: str
) -> None:
    with pytest.raises(error) as info:
        decode_set(payload, spec)
    assert fragment in info.value.reason


def test_a_json_request_hands_its_value_to_the_tree_unchecked() -> None:
    assert (
        decode_set(b'{"value": "fast"}', U16) == "fast"
    )  # the tree's write path refuses it, with its reason


SPECS = [
    TypeSpec.parse(t) for t in ("UInt16", "Double", "Boolean", "String", "DateTime", "Int32[]", "String[]")
]


@settings(max_examples=300)
@given(st.binary(max_size=200), st.sampled_from(SPECS))
def test_arbitrary_bytes_never_raise_anything_but_a_write_error(payload: bytes, spec: TypeSpec) -> None:
    try:
        decode_set(payload, spec)
    except RequestError as exc:
        assert exc.reason and exc.status.startswith("Bad")


@settings(max_examples=200)
@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
        lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
        max_leaves=10,
    ),
    st.sampled_from(SPECS),
)
def test_arbitrary_json_never_raises_anything_but_a_write_error(doc: object, spec: TypeSpec) -> None:
    with contextlib.suppress(RequestError):
        decode_set(json.dumps(doc).encode(), spec)


def test_topic_filters_match_as_mqtt_says() -> None:
    from gateway.sinks.mqtt.topics import topic_matches

    assert topic_matches("replies/#", "replies/a/b") and topic_matches("replies/#", "replies")
    assert topic_matches("replies/+/x", "replies/7/x") and not topic_matches("replies/+/x", "replies/7/y")
    assert not topic_matches("replies/+", "replies/7/x") and not topic_matches("replies/+", "replies")
    assert topic_matches("#", "a") and not topic_matches("#", "$SYS/broker") and topic_matches("a", "a")
    assert not topic_matches("a/b", "a") and not topic_matches("a", "a/b")


def test_response_topics_only_results_under_the_prefix_or_the_allow_list() -> None:
    from gateway.sinks.mqtt.topics import ResponseTopics

    policy = ResponseTopics("cnc", ["replies/#", "cell/+/answers"])
    suffix = "/set/result"
    for allowed in ("cnc/m1/feed/override/set/result", "replies/me", "replies", "cell/7/answers"):
        assert policy.refusal(allowed, suffix) is None, allowed
    for refused in ("cnc/m1/feed/override", "spBv1.0/cnc/NCMD/other-edge", "cell/7/answers/x", "cncx/a"):
        assert policy.refusal(refused, suffix) is not None, refused
    assert "not a topic one can publish to" in (policy.refusal("replies/+", suffix) or "")
    assert ResponseTopics("cnc").refusal("replies/me", suffix) is not None  # nothing allowed by default
