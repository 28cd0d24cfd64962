"""Every case of tests/corpus/dnc/line.yaml gets the answer its entry promises from the DNC codec."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.codecs.dnc import (
    BadRequest,
    DncSender,
    FramingError,
    Junk,
    LineSettings,
    ProgramReceived,
    ProgramReceiver,
    RemoteRequest,
    Unterminated,
    answer_program,
    frame_program,
    not_found,
    parse_request,
)

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "dnc" / "line.yaml"
CASES: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
SENDABLE = b"%\nO1\nG0 X1\nM30\n%\n"


def settings(case: dict[str, Any]) -> LineSettings:
    baud, fmt = case.get("line", "9600 7E2").split()
    base = LineSettings(baud=int(baud), handshake=case.get("handshake", "xonxoff"))
    line = LineSettings.from_format(fmt, base)
    return dataclasses.replace(line, software_parity=bool(case.get("software_parity")))


def data(case: dict[str, Any]) -> bytes:
    if "hex" in case:
        return bytes.fromhex(case["hex"])
    return str(case["text"]).encode("utf-8")


def test_corpus_covers_every_kind() -> None:
    kinds = {case["kind"] for case in CASES}
    assert kinds == {"sender", "receiver", "request", "framing"}
    assert len({case["name"] for case in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_case(case: dict[str, Any]) -> None:
    expect = case["expect"]
    kind = case["kind"]
    if kind == "sender":
        line = settings(case)
        sender = DncSender(frame_program(SENDABLE, line), line)
        events = sender.feed(data(case))
        assert [type(e).__name__ for e in events] == expect["events"]
        for key in ("waiting_for_dc1", "paused", "parity_errors"):
            if key in expect:
                assert getattr(sender, key) == expect[key], key
        if "junk" in expect:
            assert sender.junk_bytes == expect["junk"]
        if "reason" in expect:
            assert any(isinstance(e, Junk) and expect["reason"] in e.reason for e in events)
        if "sendable" in expect:
            assert len(sender.next_chunk()) == expect["sendable"]
    elif kind == "receiver":
        receiver = ProgramReceiver(max_size=case.get("max_size", 1 << 20))
        events = receiver.feed(data(case))
        if case.get("end_of_input"):
            events += receiver.end_of_input()
        assert [type(e).__name__ for e in events] == expect["events"]
        if "text" in expect:
            last = events[-1]
            assert isinstance(last, ProgramReceived | Unterminated)
            assert last.text == expect["text"].encode()
        if "junk" in expect:
            assert receiver.junk_bytes == expect["junk"]
    elif kind == "request":
        parsed = parse_request(data(case))
        if "request" in expect:
            assert parsed == RemoteRequest(expect["request"])
            assert not_found(expect["request"]) == expect["answer_if_missing"].encode()
        else:
            assert isinstance(parsed, BadRequest) and parsed.reason.startswith(expect["refused"])
            if "answer" in expect:
                assert answer_program(parsed.reason) == expect["answer"].encode()
    else:
        with pytest.raises(
            FramingError, match=expect["error"].replace("(", r"\(").replace(")", r"\)")
        ) as info:
            frame_program(data(case), settings(case))
        assert info.value.line == expect["line"]
