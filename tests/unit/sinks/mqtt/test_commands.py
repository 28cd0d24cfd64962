"""MQTT command requests without a broker: topics, bodies, arguments, answers, and every refusal answered."""

from __future__ import annotations

import asyncio
import json
from datetime import UTC, datetime
from typing import Any

import pytest

from gateway.commands.runner import install_commands
from gateway.config.mapping import MachineMapping
from gateway.errors import ArgumentsMissing, ConfirmTimeout, MalformedRequest, TooManyArguments
from gateway.model.tree import VariableNode, VariableTree
from gateway.sinks.mqtt.commands import CommandRequests, command_target, encode_reply
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig
from gateway.sinks.mqtt_link.client import Incoming
from gateway.sinks.mqtt_link.requests import arguments, correlation_of, read_body
from tests.trees import MappedTree
from tests.waiting import wait_until

T0 = datetime(2026, 5, 6, tzinfo=UTC)


def tree(commands_enabled: bool = True, timeout: float = 2.0) -> MappedTree:
    mapping = MachineMapping.model_validate(
        {
            "machine": "laser-sim",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
            "variables": [
                {"path": "Program/Name", "source": "ns=2;s=name", "type": "String"},
                {
                    "path": "Control/Select",
                    "source": "ns=2;s=select",
                    "type": "String",
                    "access": "readwrite",
                },
            ],
            "commands": {
                "select-program": {
                    "arguments": [{"name": "name", "type": "String"}],
                    "writes": [{"path": "Control/Select", "value": "{name}"}],
                    "done": {"path": "Program/Name", "equals": "{name}"},
                    "timeout": timeout,
                },
            },
            "mqtt": MachineMqtt(commands=commands_enabled).model_dump(),
        }
    )
    t = MappedTree([mapping])
    install_commands(t, t.mappings)
    machine = t.machines["laser-sim"]
    machine.ingest(machine.nodes["Program/Name"], "", T0)
    return t


class Selects:
    """The controller: a selected name shows up in Program/Name (unless told to stay silent)."""

    def __init__(self, t: VariableTree, silent: bool = False) -> None:
        self.machine = t.machines["laser-sim"]
        self.silent = silent

    async def write(self, node: VariableNode, raw: Any) -> None:
        if not self.silent:
            self.machine.ingest(self.machine.nodes["Program/Name"], raw, T0)


class Answers(list[tuple[str, dict[str, Any], bytes | None]]):
    def __call__(self, topic: str, payload: bytes, correlation: bytes | None) -> None:
        self.append((topic, json.loads(payload), correlation))


def requests(t: MappedTree, answers: Answers, **cfg: Any) -> CommandRequests:
    return CommandRequests(t, MqttConfig.model_validate(cfg), t.mappings, answers)


TOPIC = "cnc/laser-sim/commands/select-program"


def test_command_topics() -> None:
    assert command_target(TOPIC, "cnc") == ("laser-sim", "select-program")
    assert command_target("plant/a/cnc/m/commands/start", "plant/a/cnc") == ("m", "start")
    for other in (
        "cnc/m/commands/start/result",
        "cnc/m/feed/override/set",
        "cnc/m/commands",
        "other/m/commands/x",
    ):
        assert command_target(other, "cnc") is None


def test_bodies_and_arguments() -> None:
    assert read_body(b"") == {} and read_body(b"  ") == {}
    assert read_body(b'{"name": "a.nc", "correlation_id": "c1"}') == {"name": "a.nc", "correlation_id": "c1"}
    for bad, fragment in [
        (b"\xff", "not UTF-8"),
        (b"{nope", "malformed JSON"),
        (b"[1]", "JSON object"),
        (b"5", "JSON object"),
        (b"[" * 100_000, "malformed JSON"),
    ]:
        with pytest.raises(MalformedRequest, match=fragment):
            read_body(bad)
    method = tree().machines["laser-sim"].methods[("Commands", "select-program")]
    assert arguments(method, {"name": "a.nc", "correlation_id": 7}) == ["a.nc"]
    with pytest.raises(ArgumentsMissing, match="needs name"):
        arguments(method, {})
    with pytest.raises(TooManyArguments, match="does not take 'nmae'"):
        arguments(method, {"nmae": "a.nc"})
    assert correlation_of({"correlation_id": 42}) == 42
    with pytest.raises(MalformedRequest):
        correlation_of({"correlation_id": {"a": 1}})


def test_replies_carry_ok_or_error_reason_status_and_duration() -> None:
    ok = json.loads(encode_reply("start", duration_ms=12.34, correlation="c", result="Machine/State is 1"))
    assert ok == {
        "ok": True,
        "command": "start",
        "status": "Good",
        "reason": "Machine/State is 1",
        "result": "Machine/State is 1",
        "duration_ms": 12.3,
        "correlation_id": "c",
    }
    bad = json.loads(encode_reply("start", duration_ms=5001, error=ConfirmTimeout("no completion")))
    assert bad == {
        "ok": False,
        "command": "start",
        "status": "BadTimeout",
        "error": "no completion",
        "reason": "no completion",
        "duration_ms": 5001,
    }


async def run_worker(reqs: CommandRequests, answers: Answers, count: int) -> None:
    task = asyncio.create_task(reqs.worker("laser-sim"))
    try:
        await wait_until(lambda: len(answers) >= count, timeout=5, message=f"{count} answer(s)")
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


async def test_a_request_runs_the_command_and_answers_on_result_with_the_correlation() -> None:
    t = tree()
    t.machines["laser-sim"].writer = Selects(t)
    answers = Answers()
    reqs = requests(t, answers)
    assert reqs.filters == ["cnc/+/commands/+"]
    assert reqs.handle(Incoming(TOPIC, b'{"name": "demo.nc", "correlation_id": "c-17"}', 1))
    await run_worker(reqs, answers, 1)
    [(topic, doc, corr)] = answers
    assert topic == TOPIC + "/result" and corr is None
    assert (
        doc["ok"] is True and doc["correlation_id"] == "c-17" and doc["reason"] == "Program/Name is 'demo.nc'"
    )
    assert doc["duration_ms"] >= 0


async def test_mqtt5_response_topic_and_correlation_data_are_used() -> None:
    t = tree()
    t.machines["laser-sim"].writer = Selects(t)
    answers = Answers()
    reqs = requests(t, answers, response_topics=["client/+/reply"])
    reqs.handle(
        Incoming(TOPIC, b'{"name": "a.nc"}', 1, response_topic="client/7/reply", correlation_data=b"\x01")
    )
    await run_worker(reqs, answers, 1)
    assert [(topic, doc["ok"], corr) for topic, doc, corr in answers] == [("client/7/reply", True, b"\x01")]
    assert t.machines["laser-sim"].nodes["Program/Name"].sample.value == "a.nc"


@pytest.mark.parametrize(
    ("response_topic", "fragment"),
    [
        ("spBv1.0/cnc/NCMD/other-edge", "outside the gateway's prefix 'cnc' and not in mqtt.response_topics"),
        ("client/7/reply/more", "outside the gateway's prefix"),  # the filter is one level deep
        ("cnc/laser-sim/axes/x/position", "under the gateway's prefix but not a result topic"),
        ("cnc/laser-sim/status", "not a result topic"),
        ("replies/#", "not a topic one can publish to"),
    ],
)
def test_a_response_topic_the_gateway_may_not_publish_to_refuses_the_request(
    response_topic: str, fragment: str
) -> None:
    """Issue 23: a requester made the gateway publish, with its credentials, anywhere its ACL reached."""
    t = tree()
    t.machines["laser-sim"].writer = Selects(t)
    answers = Answers()
    reqs = requests(t, answers, response_topics=["client/+/reply"])
    reqs.handle(Incoming(TOPIC, b'{"name": "b.nc"}', 1, response_topic=response_topic, correlation_data=b"c"))
    [(topic, doc, corr)] = answers  # answered at once, on the request's own result topic
    assert topic == TOPIC + "/result" and corr == b"c"
    assert doc["ok"] is False and doc["status"] == "BadRequestNotAllowed" and fragment in doc["error"]
    assert reqs.refused == reqs.refused_response_topics == 1 and reqs.queues["laser-sim"].empty()
    assert t.machines["laser-sim"].nodes["Program/Name"].sample.value == ""  # the machine saw nothing


async def test_a_command_that_times_out_answers_an_error_with_its_duration() -> None:
    t = tree(timeout=0.2)
    t.machines["laser-sim"].writer = Selects(t, silent=True)
    answers = Answers()
    reqs = requests(t, answers)
    reqs.handle(Incoming(TOPIC, b'{"name": "a.nc", "correlation_id": 1}', 1))
    await run_worker(reqs, answers, 1)
    doc = answers[0][1]
    assert doc["ok"] is False and doc["status"] == "BadTimeout" and doc["duration_ms"] >= 200
    assert doc["correlation_id"] == 1 and "no completion within 0.2 s" in doc["error"]


@pytest.mark.parametrize(
    ("topic", "payload", "retain", "status", "fragment"),
    [
        (TOPIC, b"{oops", False, "BadDecodingError", "malformed JSON"),
        (TOPIC, b'"demo.nc"', False, "BadDecodingError", "JSON object"),
        (TOPIC, b"{}", False, "BadArgumentsMissing", "needs name"),
        (TOPIC, b'{"name": "a", "copies": 2}', False, "BadTooManyArguments", "does not take 'copies'"),
        (TOPIC, b'{"name": "a"}', True, "BadDecodingError", "retained"),
        ("cnc/laser-sim/commands/launch", b"", False, "BadMethodInvalid", "no command 'launch'"),
        ("cnc/press-9/commands/start", b"", False, "BadNodeIdUnknown", "no machine 'press-9'"),
        (TOPIC, b'{"name": "' + b"x" * 70_000 + b'"}', False, "BadRequestTooLarge", "bytes"),
    ],
)
def test_refusals_are_answered_at_once(
    topic: str, payload: bytes, retain: bool, status: str, fragment: str
) -> None:
    answers = Answers()
    reqs = requests(tree(), answers)
    assert reqs.handle(Incoming(topic, payload, 1, retain=retain))
    [(reply, doc, _)] = answers
    assert reply == topic + "/result"
    assert doc["ok"] is False and doc["status"] == status and fragment in doc["error"]


async def test_the_type_of_an_argument_is_checked_by_the_call() -> None:
    t = tree()
    t.machines["laser-sim"].writer = Selects(t)
    answers = Answers()
    reqs = requests(t, answers)
    reqs.handle(Incoming(TOPIC, b'{"name": 5}', 1))
    assert answers == []  # queued: the call itself checks the types, as for every sink
    await run_worker(reqs, answers, 1)
    doc = answers[0][1]
    assert doc["status"] == "BadTypeMismatch" and "argument name" in doc["error"]


def test_commands_over_mqtt_are_off_unless_the_mapping_enables_them() -> None:
    answers = Answers()
    reqs = requests(tree(commands_enabled=False), answers)
    reqs.handle(Incoming(TOPIC, b'{"name": "a.nc", "correlation_id": "z"}', 1))
    [(_, doc, _)] = answers
    assert doc["status"] == "BadUserAccessDenied" and "mqtt: {commands: true}" in doc["error"]
    assert doc["correlation_id"] == "z"


def test_a_flood_is_bounded_per_machine() -> None:
    answers = Answers()
    reqs = requests(tree(), answers, max_pending_writes=2)
    for _ in range(5):
        reqs.handle(Incoming(TOPIC, b'{"name": "a.nc"}', 1))
    assert reqs.queues["laser-sim"].qsize() == 2
    assert [doc["status"] for _, doc, _ in answers] == ["BadTooManyOperations"] * 3


def test_other_topics_are_not_ours() -> None:
    answers = Answers()
    reqs = requests(tree(), answers)
    assert not reqs.handle(Incoming("cnc/laser-sim/feed/override/set", b"50", 1))
    assert answers == []


def test_no_commands_no_subscription() -> None:
    t = MappedTree(
        [
            MachineMapping.model_validate(
                {
                    "machine": "m",
                    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
                    "variables": [{"path": "A", "source": "ns=2;s=a", "type": "Int16"}],
                }
            )
        ]
    )
    assert requests(t, Answers()).filters == []
