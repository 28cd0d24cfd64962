"""The Haas MDC codec: answers read the same however the stream is split; values out of the documented
answers; addresses; junk counted and skipped (tests/corpus/focas/haas_mdc.yaml)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.haas_mdc.protocol import (
    Item,
    Junk,
    LineReader,
    MdcError,
    Query,
    Reply,
    format_value,
    parse_address,
    parse_line,
    value_of,
)
from gateway.errors import AddressError

ANSWERS = [
    b"\x02SERIAL NUMBER, 1234567\x17\r\n>",
    b"SOFTWARE VERSION, 100.17.000.2037\r\n",
    b">PROGRAM, O12345, IDLE, PARTS, 380\r\n",
    b"\x02MACRO, -12.5\x17\r\n>",
    b"P.O. TIME, 06282:17:13\r\n",
    b"!\r\n",
    b"?, ?Q999\r\n",
]
CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "focas" / "haas_mdc.yaml"


@given(st.lists(st.sampled_from(ANSWERS), min_size=1, max_size=12), st.data())
def test_a_stream_split_anywhere_reads_the_same(answers: list[bytes], data: st.DataObject) -> None:
    stream = b"".join(answers)
    whole = LineReader().feed(stream)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    reader = LineReader()
    got: list[Reply | Junk] = []
    last = 0
    for cut in [*cuts, len(stream)]:
        got += reader.feed(stream[last:cut])
        last = cut
    assert got == whole and len(whole) == len(answers)


def test_every_offset() -> None:
    stream = b"".join(ANSWERS)
    whole = LineReader().feed(stream)
    for cut in range(len(stream) + 1):
        reader = LineReader()
        assert reader.feed(stream[:cut]) + reader.feed(stream[cut:]) == whole


def test_values_of_documented_answers() -> None:
    assert (
        value_of(parse_address("Q500.program"), parse_line("PROGRAM, O12345, IDLE, PARTS, 380")) == "O12345"
    )
    assert (
        value_of(parse_address("Q500.status"), parse_line("PROGRAM, O12345, ALARM ON, PARTS, 380"))
        == "ALARM ON"
    )
    assert value_of(parse_address("Q500.parts"), parse_line("PROGRAM, O12345, IDLE, PARTS, 380")) == 380
    assert value_of(parse_address("Q500.status"), parse_line("STATUS BUSY")) == "BUSY"
    with pytest.raises(MdcError, match="busy"):
        value_of(parse_address("Q500.parts"), parse_line("STATUS, BUSY"))
    assert value_of(parse_address("Q300"), parse_line("P.O. TIME, 06282:17:13")) == 6282 * 3600 + 17 * 60 + 13
    assert value_of(parse_address("#5021"), parse_line("MACRO, 234.567")) == 234.567
    assert value_of(parse_address("Q201"), parse_line("USING TOOL, 4")) == 4
    assert value_of(parse_address("Q104"), parse_line("MODE, ZERO")) == "ZERO"
    with pytest.raises(MdcError, match="refused"):
        value_of(parse_address("#99999"), parse_line("?, ?Q600 99999"))


def test_answers_match_their_queries() -> None:
    assert parse_line("MACRO, 1").answers(Query(600, 5021))  # type: ignore[union-attr]
    assert not parse_line("MODEL, VF-2").answers(Query(600, 5021))  # type: ignore[union-attr]
    assert parse_line("STATUS, BUSY").answers(Query(500))  # type: ignore[union-attr]
    assert parse_line("!").answers(Query(600, 10500, 1.0))  # type: ignore[union-attr]
    assert not parse_line("MACRO, 1").answers(Query(600, 10500, 1.0))  # type: ignore[union-attr]


def test_queries_and_addresses() -> None:
    assert Query(100).encode() == b"?Q100\r\n"
    assert Query(600, 5021).encode() == b"?Q600 5021\r\n"
    assert Query(600, 10500, 2.5).encode() == b"?E10500 2.5\r\n"
    assert format_value(-0.0000001) == "0" and format_value(3.0) == "3"
    assert parse_address("#5021") == Item(600, variable=5021) == parse_address("Q600:5021")
    for bad in ["Q999", "Q600", "Q100.parts", "Q500.speed", "5021", "#"]:
        with pytest.raises(AddressError):
            parse_address(bad)


def _cases() -> list[dict[str, Any]]:
    loaded = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
    assert isinstance(loaded, list) and loaded
    return loaded


@pytest.mark.parametrize("case", _cases(), ids=lambda c: c["name"])
def test_junk_is_counted_and_the_reader_goes_on(case: dict[str, Any]) -> None:
    data = bytes.fromhex(case["hex"]) if "hex" in case else case["text"].encode()
    data += case.get("then", "").encode() * case.get("repeat", 0) + case.get("end", "").encode()
    events = LineReader().feed(data + b"MACRO, 1.5\r\n")
    junk = [e for e in events if isinstance(e, Junk)]
    assert len(junk) >= len(case["junk"])
    for fragment, event in zip(case["junk"], junk, strict=False):
        assert fragment in event.reason
    assert events[-1] == parse_line("MACRO, 1.5")
