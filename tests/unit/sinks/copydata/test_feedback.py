"""Replies from the nesting software: published on the event bus and in Status, and optionally written."""

from __future__ import annotations

import json
import logging

import pytest

from gateway.codecs.copydata import Frame, Item
from gateway.model.tree import Machine, VariableTree
from gateway.sinks.copydata.emitter import Emitter
from gateway.sinks.copydata.sink import CopydataSink
from tests.unit.sinks.copydata.helpers import RecordingWriter, mapping


def setup(accept_writes: bool) -> tuple[Machine, Emitter, RecordingWriter]:
    m = mapping({"name": "nest", "transport": "tcp-server", "accept_writes": accept_writes})
    tree = VariableTree([m.definition()])
    sink = CopydataSink(tree, {m.machine: m})
    machine = tree.machines["m1"]
    writer = RecordingWriter()
    machine.writer = writer
    return machine, sink.emitters[0], writer


def frame(*items: tuple[int, str]) -> Frame:
    return Frame(1 if len(items) == 1 else 2, tuple(Item(i, bytes.fromhex(h)) for i, h in items))


async def test_a_reply_is_published_as_an_event_and_in_status() -> None:
    machine, emitter, writer = setup(accept_writes=False)
    events = machine.tree.events.subscribe("test")
    await emitter.on_frame(frame((5, "2a000000"), (9, "6f6b")), "127.0.0.1:4000")
    (event,) = events.take()
    assert (event.machine, event.channel) == ("m1", "copydata/feedback")
    assert event.payload == {
        "target": "nest", "peer": "127.0.0.1:4000", "dwdata": 2,
        "items": [{"id": 5, "path": "Program/Block", "value": 42},
                  {"id": 9, "path": "Program/Name", "value": "ok"}],
    }  # fmt: skip
    status = machine.nodes["Status/CopydataFeedback"].sample.value
    assert json.loads(status) == event.payload
    assert writer.writes == []  # no writes without accept_writes
    assert emitter.feedback.received == 1


async def test_undecodable_items_are_reported_not_fatal() -> None:
    machine, emitter, _ = setup(accept_writes=False)
    events = machine.tree.events.subscribe("test")
    await emitter.on_frame(frame((99, "0102"), (1, "0000")), "peer")
    (event,) = events.take()
    unknown, short = event.payload["items"]
    assert unknown == {"id": 99, "error": "id 99 is not a variable of target nest", "hex": "0102"}
    assert short["path"] == "Axes/X/Position" and "Double needs 8 bytes, got 2" in short["error"]


async def test_accept_writes_writes_through_the_tree() -> None:
    machine, emitter, writer = setup(accept_writes=True)
    events = machine.tree.events.subscribe("test")
    await emitter.on_frame(frame((6, "3200")), "nesting-pc:4000")  # Feed/Override = 50
    assert writer.writes == [("Feed/Override", 50)]
    (event,) = events.take()
    assert event.payload["items"] == [{"id": 6, "path": "Feed/Override", "value": 50, "write": {"ok": True}}]
    assert emitter.feedback.written == 1


@pytest.mark.parametrize(
    ("item", "status", "fragment"),
    [
        ((1, "0000000000004940"), "BadNotWritable", "m1/Axes/X/Position is read-only"),  # X position = 50.0
        ((6, "c800"), "BadOutOfRange", "200 is outside the range 0..150"),  # Feed/Override = 200
        ((6, "32"), "BadDecodingError", "UInt16 needs 2 bytes, got 1"),
        ((77, "00"), "BadDecodingError", "id 77 is not a variable"),
    ],
)
async def test_refused_writes_are_logged_and_reach_nothing(
    item: tuple[int, str], status: str, fragment: str, caplog: pytest.LogCaptureFixture
) -> None:
    machine, emitter, writer = setup(accept_writes=True)
    events = machine.tree.events.subscribe("test")
    caplog.set_level(logging.INFO, logger="gateway.sinks.copydata")
    await emitter.on_frame(frame(item), "nesting-pc:4000")
    assert writer.writes == []
    (event,) = events.take()
    result = event.payload["items"][0]["write"]
    assert result["ok"] is False and result["status"] == status and fragment in result["error"]
    refusals = [r for r in caplog.records if "refused" in r.getMessage()]
    assert refusals and fragment in refusals[0].getMessage() and refusals[0].levelno == logging.WARNING
    assert emitter.feedback.refused == 1


async def test_a_reply_flood_does_not_flood_the_log(caplog: pytest.LogCaptureFixture) -> None:
    _machine, emitter, _ = setup(accept_writes=False)
    caplog.set_level(logging.INFO, logger="gateway.sinks.copydata")
    for i in range(500):
        await emitter.on_frame(frame((5, f"{i % 256:02x}000000")), "peer")
    lines = [r for r in caplog.records if "reply from" in r.getMessage()]
    assert 1 <= len(lines) <= 10
    assert emitter.feedback.received == 500
