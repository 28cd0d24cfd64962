"""The SHDR reader and writer: any chunking, every line form, junk refused and counted, round trips."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.mtconnect.shdr import (
    PING,
    AlarmObservation,
    AllAssetsRemoved,
    AssetChanged,
    AssetRemoved,
    AssetUpdated,
    Command,
    ConditionObservation,
    Event,
    ItemKind,
    Junk,
    MessageObservation,
    Observation,
    Ping,
    Pong,
    ShdrReader,
    TimeSeriesObservation,
    encode,
    format_condition,
    format_pairs,
    format_pong,
    quote_field,
    split_fields,
)

NOW = datetime(2024, 5, 1, 12, 0, 0, tzinfo=UTC)
T1 = datetime(2024, 5, 1, 11, 59, 59, 123456, tzinfo=UTC)

KINDS = {
    "system": ItemKind.CONDITION,
    "dev2:system": ItemKind.CONDITION,
    "msg": ItemKind.MESSAGE,
    "alarm": ItemKind.ALARM,
    "vib": ItemKind.TIME_SERIES,
}


def kind_of(key: str) -> ItemKind:
    return KINDS.get(key, ItemKind.VALUE)


def read(data: bytes, chunks: list[int] | None = None, **options: int) -> tuple[list[Event], ShdrReader]:
    reader = ShdrReader(kind_of, **options)
    events: list[Event] = []
    if chunks is None:
        events += reader.feed(data, NOW)
    else:
        start = 0
        for end in [*chunks, len(data)]:
            events += reader.feed(data[start:end], NOW)
            start = end
    events += reader.feed_eof(NOW)
    return events, reader


STREAM = (
    b"2024-05-01T11:59:59.123456Z|Xact|12.5|execution|ACTIVE\n"
    b"|Yact|-3\r\n"
    b"2024-05-01T11:59:59.123456Z|system|FAULT|E42:c1|2|HIGH|Laser overheated\n"
    b"2024-05-01T11:59:59.123456Z|msg|CHG|Change inserts\n"
    b"2024-05-01T11:59:59.123456Z|vib|4|100|1 2 3.5 -4\n"
    b'2024-05-01T11:59:59.123456Z|program|"O1000 \\| rough \\"cut\\""\n'
    b"2024-05-01T11:59:59.123456Z@2.5|pcount|3\n"
    b"* shdrVersion: 2\n"
    b"* PONG 10000\n"
    b"2024-05-01T11:59:59.123456Z|@ASSET@|T1.1|CuttingTool|--multiline--ABC\n"
    b'<CuttingTool serialNumber="1">\n'
    b"  <Description>Drill | 8 mm</Description>\n"
    b"</CuttingTool>\n"
    b"--multiline--ABC\n"
    b"2024-05-01T11:59:59.123456Z|@REMOVE_ASSET@|T1.1|Zact|unavailable\n"
    b"\n"
    b"2024-05-01T11:59:59.123456Z|dev2:system|normal||||\n"
)
EXPECTED: list[Event] = [
    Observation(T1, "Xact", "12.5"),
    Observation(T1, "execution", "ACTIVE"),
    Observation(NOW, "Yact", "-3"),
    ConditionObservation(T1, "system", "FAULT", "E42", "2", "HIGH", "Laser overheated", "c1"),
    MessageObservation(T1, "msg", "CHG", "Change inserts"),
    TimeSeriesObservation(T1, "vib", (1.0, 2.0, 3.5, -4.0), 100.0),
    Observation(T1, "program", 'O1000 | rough "cut"'),
    Observation(T1, "pcount", "3", duration=2.5),
    Command("shdrVersion", "2"),
    Pong(10000),
    AssetChanged(
        T1,
        "T1.1",
        "CuttingTool",
        '<CuttingTool serialNumber="1">\n  <Description>Drill | 8 mm</Description>\n</CuttingTool>',
    ),
    AssetRemoved(T1, "T1.1"),
    Observation(T1, "Zact", "UNAVAILABLE"),
    ConditionObservation(T1, "system", "NORMAL", device="dev2"),
]


def test_a_stream_of_every_line_form_reads_as_its_events() -> None:
    events, reader = read(STREAM)
    assert events == EXPECTED
    assert reader.errors == 0


def test_the_stream_split_at_every_offset_reads_the_same() -> None:
    for offset in range(len(STREAM) + 1):
        events, reader = read(STREAM, [offset])
        assert events == EXPECTED, f"split at {offset}"
        assert reader.errors == 0


def test_the_stream_fed_byte_by_byte_reads_the_same() -> None:
    events, _ = read(STREAM, list(range(1, len(STREAM))))
    assert events == EXPECTED


@pytest.mark.parametrize(
    ("stamp", "expected"),
    [
        ("2024-05-01T11:59:59Z", datetime(2024, 5, 1, 11, 59, 59, tzinfo=UTC)),
        ("2024-05-01T11:59:59.5", datetime(2024, 5, 1, 11, 59, 59, 500000, tzinfo=UTC)),
        ("2024-05-01T11:59:59.1234567891Z", datetime(2024, 5, 1, 11, 59, 59, 123456, tzinfo=UTC)),
        ("2024-05-01T13:59:59+02:00", datetime(2024, 5, 1, 11, 59, 59, tzinfo=UTC)),
        ("", NOW),
        ("  ", NOW),
    ],
)
def test_timestamps_with_z_without_zone_with_offset_or_missing(stamp: str, expected: datetime) -> None:
    events, reader = read(f"{stamp}|Xact|1\n".encode())
    assert events == [Observation(expected, "Xact", "1")]
    assert isinstance(events[0], Observation) and events[0].timestamp.tzinfo is not None
    assert reader.errors == 0


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        (b"Xact|12.5", "is not a timestamp"),
        (b"2024-13-01T00:00:00Z|Xact|1", "is not a timestamp"),
        (b"2024-05-01 12:00:00|Xact|1", "is not a timestamp"),
        (b"2024-05-01T12:00:00Z", "no key|value"),
        (b"2024-05-01T12:00:00Z|", "no key|value"),
        (b"2024-05-01T12:00:00Z@abc|Xact|1", "bad duration"),
        (b"2024-05-01T12:00:00Z@-1|Xact|1", "bad duration"),
        (b"|Xact", "has no value"),
        (b"|system|BROKEN|E1|1||text", "is not NORMAL/WARNING/FAULT/UNAVAILABLE"),
        (b"|vib|3|100|1 2", "count 3 but 2 values"),
        (b"|vib|x|100|1 2", "must be numbers"),
        (b"|@ASSET@|T1", "needs an asset id, a type and a body"),
        (b"|@REMOVE_ASSET@", "needs an asset id"),
        (b"|@UPDATE_ASSET@|T1|OverallToolLength", "property|value pairs"),
        (b"|@FROB@|x", "unknown asset command"),
        (b"* PONG soon", "period in milliseconds"),
        (b"* PONG 0", "period in milliseconds"),
        (b"* hello world", "protocol command"),
        (b"* shdrVersion: two", "needs a number"),
        (b"|Xact|1\xff\xfe", "not UTF-8"),
        (b"||1", "empty key"),
    ],
)
def test_junk_lines_become_counted_junk_and_the_next_line_is_read(line: bytes, reason: str) -> None:
    events, reader = read(line + b"\n|after|ok\n")
    junk = [e for e in events if isinstance(e, Junk)]
    assert len(junk) == 1 and reason in junk[0].reason, events
    assert junk[0].line == 1
    assert events[-1] == Observation(NOW, "after", "ok")
    assert reader.errors == 1


def test_one_bad_item_does_not_lose_the_good_items_of_its_line() -> None:
    events, reader = read(b"|Xact|1|system|HOT|E1|||x|Yact|2\n")
    assert events[0] == Observation(NOW, "Xact", "1")
    assert isinstance(events[1], Junk)
    assert events[2] == Observation(NOW, "Yact", "2")
    assert reader.errors == 1


def test_a_line_over_the_limit_is_refused_and_memory_stays_bounded() -> None:
    reader = ShdrReader(max_line=100)
    events: list[Event] = []
    for _ in range(50):  # 5000 bytes of one line, in 100-byte pieces
        events += reader.feed(b"x" * 100, NOW)
        assert reader.buffered <= 100
    events += reader.feed(b"yyy\n|Xact|1\n", NOW)
    assert [type(e) for e in events] == [Junk, Observation]
    assert "longer than 100 bytes" in events[0].reason  # type: ignore[union-attr]
    assert reader.errors == 1


def test_a_complete_line_over_the_limit_is_refused_too() -> None:
    events, reader = read(b"|Xact|" + b"9" * 200 + b"\n|Yact|2\n", max_line=100)
    assert isinstance(events[0], Junk) and events[1] == Observation(NOW, "Yact", "2")
    assert (reader.errors, reader.lines) == (1, 2)


def test_a_multiline_asset_over_the_limit_is_dropped_and_reading_goes_on() -> None:
    body = b"".join(b"<Line>%d</Line>\n" % i for i in range(100))
    data = b"|@ASSET@|A1|File|--multiline--Z\n" + body + b"--multiline--Z\n|Xact|1\n"
    events, reader = read(data, max_asset=500)
    assert isinstance(events[0], Junk) and "larger than 500 bytes" in events[0].reason
    assert events[1:] == [Observation(NOW, "Xact", "1")]  # the asset's lines were skipped, not junk
    assert reader.errors == 1


def test_a_stream_ending_inside_a_multiline_asset_reports_it() -> None:
    events, reader = read(b"|@ASSET@|A1|File|--multiline--Z\n<File>\n")
    assert len(events) == 1 and isinstance(events[0], Junk) and "A1" in events[0].reason
    assert reader.errors == 1


def test_a_last_line_without_newline_is_read_at_eof() -> None:
    events, _ = read(b"|Xact|1\n|Yact|2")
    assert events == [Observation(NOW, "Xact", "1"), Observation(NOW, "Yact", "2")]


def test_heartbeats_and_commands() -> None:
    events, _ = read(b"* PING\n* PONG\n* PONG 2500\n* adapterVersion: 2.0\n* device: laser1\n")
    assert events == [
        Ping(),
        Pong(None),
        Pong(2500),
        Command("adapterVersion", "2.0"),
        Command("device", "laser1"),
    ]


def test_asset_commands() -> None:
    events, _ = read(
        b"|@ASSET@|T2|CuttingTool|<CuttingTool/>|Xact|1\n"
        b"|@REMOVE_ALL_ASSETS@|CuttingTool\n"
        b"|@REMOVE_ALL_ASSETS@\n"
        b"|@UPDATE_ASSET@|T2|OverallToolLength|323.64|CuttingDiameterMax|76.211\n"
    )
    assert events == [
        AssetChanged(NOW, "T2", "CuttingTool", "<CuttingTool/>"),
        Observation(NOW, "Xact", "1"),
        AllAssetsRemoved(NOW, "CuttingTool"),
        AllAssetsRemoved(NOW, None),
        AssetUpdated(NOW, "T2", (("OverallToolLength", "323.64"), ("CuttingDiameterMax", "76.211"))),
    ]


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        ("|system|WARNING|E1|||", ConditionObservation(NOW, "system", "WARNING", "E1", condition_id="E1")),
        (
            "|system|fault|:only-id|||",
            ConditionObservation(NOW, "system", "FAULT", None, condition_id="only-id"),
        ),
        (
            "|system|Fault|code:id|5|LOW|t",
            ConditionObservation(NOW, "system", "FAULT", "code", "5", "LOW", "t", "id"),
        ),
        ("|system|unavailable", ConditionObservation(NOW, "system", "UNAVAILABLE")),
        (
            "|alarm|OTHER|E7|CRITICAL|ACTIVE|door open",
            AlarmObservation(NOW, "alarm", "OTHER", "E7", "CRITICAL", "ACTIVE", "door open"),
        ),
        ("|msg||hello", MessageObservation(NOW, "msg", None, "hello")),
        ("|vib|UNAVAILABLE||", TimeSeriesObservation(NOW, "vib", ())),
        ("|vib|2||1 2", TimeSeriesObservation(NOW, "vib", (1.0, 2.0), None)),
    ],
)
def test_multi_field_items(fields: str, expected: Event) -> None:
    events, reader = read(fields.encode() + b"\n")
    assert events == [expected]
    assert reader.errors == 0


def test_shdr_version_1_ends_a_line_after_a_multi_field_item() -> None:
    line = b"|system|NORMAL||||text|Xact|1\n"
    v2, _ = read(line)
    v1, _ = read(b"* shdrVersion: 1\n" + line)
    assert Observation(NOW, "Xact", "1") in v2
    assert v1 == [Command("shdrVersion", "1"), ConditionObservation(NOW, "system", "NORMAL", text="text")]


@pytest.mark.parametrize(
    ("line", "fields"),
    [
        ("a|b|c", ["a", "b", "c"]),
        ("|a", ["", "a"]),
        ("a|", ["a", ""]),
        ("a||b", ["a", "", "b"]),
        ("  a  |  b ", ["a", "b"]),
        ('"x \\| y"|z', ["x | y", "z"]),
        ('"say \\"hi\\""', ['say "hi"']),
        ('"back\\\\slash"', ["back\\slash"]),
        ('"  inner  "  |z', ["  inner  ", "z"]),
        ('"unterminated|z', ['"unterminated', "z"]),
        ('"quoted" tail|z', ['"quoted" tail', "z"]),
        ("plain \\| pipe", ["plain \\", "pipe"]),
        ("", []),
    ],
)
def test_split_fields_follows_the_reference_tokenizer(line: str, fields: list[str]) -> None:
    assert split_fields(line) == fields


# --- the writer ----------------------------------------------------------------------------------


def test_writer_lines_read_back() -> None:
    data = (
        format_pairs(T1, [("Xact", "1.5"), ("program", "a|b"), ("note", " padded ")])
        + format_condition(None, "system", "fault", "E1", "3", "HIGH", "hot|cold", "c9")
        + PING
        + format_pong(1500)
    )
    events, reader = read(data)
    assert events == [
        Observation(T1, "Xact", "1.5"),
        Observation(T1, "program", "a|b"),
        Observation(T1, "note", " padded "),
        ConditionObservation(NOW, "system", "FAULT", "E1", "3", "HIGH", "hot|cold", "c9"),
        Ping(),
        Pong(1500),
    ]
    assert reader.errors == 0


@pytest.mark.parametrize(
    "bad",
    [
        lambda: format_pairs(T1, [("Xact", "line\nbreak")]),
        lambda: format_pairs(T1, [("X act", "1")]),
        lambda: format_pairs(T1, [("@ASSET@", "1")]),
        lambda: format_pairs(T1, [("*cmd", "1")]),
        lambda: format_pairs(T1, []),
        lambda: format_pairs(T1, [("Xact", "1")], duration=-1.0),
        lambda: format_condition(T1, "system", "HOT"),
        lambda: format_condition(T1, "system", "FAULT", native_code="a:b"),
        lambda: format_pong(0),
        lambda: quote_field("a\rb"),
        lambda: encode(Junk(1, "x", "y")),
    ],
)
def test_the_writer_refuses_what_it_cannot_write(bad: object) -> None:
    with pytest.raises(ValueError):
        bad()  # type: ignore[operator]


# --- round trips ----------------------------------------------------------------------------------

times = st.datetimes(min_value=datetime(2000, 1, 1), max_value=datetime(2100, 1, 1), timezones=st.just(UTC))
# Field text: no line breaks (a line is a line); anything else, pipes and quotes included.
texts = st.text(st.characters(codec="utf-8", exclude_characters="\r\n"), max_size=30)
names = st.from_regex(r"[A-Za-z][A-Za-z0-9_.]{0,10}", fullmatch=True)
devices = st.none() | st.from_regex(r"[a-z][a-z0-9]{0,5}", fullmatch=True)
codes = st.none() | st.from_regex(r"[A-Za-z0-9_\-]{1,8}", fullmatch=True)
values = texts.filter(lambda t: t.upper() != "UNAVAILABLE")
numbers = st.floats(allow_nan=False, allow_infinity=False, width=64)


def prefixed(prefix: str) -> st.SearchStrategy[str]:
    return names.map(lambda n: prefix + n)


def round_kind(key: str) -> ItemKind:
    return {
        "c_": ItemKind.CONDITION,
        "m_": ItemKind.MESSAGE,
        "a_": ItemKind.ALARM,
        "t_": ItemKind.TIME_SERIES,
    }.get(key.split(":")[-1][:2], ItemKind.VALUE)


@st.composite
def conditions(draw: st.DrawFn) -> ConditionObservation:
    level = draw(st.sampled_from(["NORMAL", "WARNING", "FAULT", "UNAVAILABLE"]))
    code = draw(codes)
    condition_id = draw(st.none() | codes) or code
    return ConditionObservation(
        draw(times),
        draw(prefixed("c_")),
        level,
        code,
        draw(st.none() | codes),
        draw(st.sampled_from([None, "HIGH", "LOW"])),
        draw(texts.map(str.strip)),
        condition_id,
        draw(devices),
    )


events_strategy = st.one_of(
    st.builds(Observation, times, prefixed("v_"), values, devices, st.none() | st.floats(0, 1e6)),
    conditions(),
    st.builds(MessageObservation, times, prefixed("m_"), codes, texts, devices),
    st.builds(
        AlarmObservation,
        times,
        prefixed("a_"),
        st.from_regex(r"[A-Z]{1,8}", fullmatch=True),
        codes,
        codes,
        codes,
        texts,
        devices,
    ),
    st.builds(
        TimeSeriesObservation,
        times,
        prefixed("t_"),
        st.lists(numbers, max_size=8).map(tuple),
        st.none() | st.floats(0.001, 1e6),
        devices,
    ).filter(lambda e: e.values or e.rate is None),
    st.builds(AssetChanged, times, names, names, texts.filter(lambda t: not t.startswith("--multiline--"))),
    st.builds(AssetRemoved, times, names),
    st.builds(Command, names, texts.map(str.strip)),
    st.just(Ping()),
    st.builds(Pong, st.none() | st.integers(1, 10**9)),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(events_strategy, min_size=1, max_size=12), st.data())
def test_writer_then_reader_gives_the_events_back_in_any_chunking(
    events: list[Event], data: st.DataObject
) -> None:
    wire = b"".join(encode(e) for e in events)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(wire)), max_size=6)))
    reader = ShdrReader(round_kind)
    got: list[Event] = []
    start = 0
    for end in [*cuts, len(wire)]:
        got += reader.feed(wire[start:end], NOW)
        start = end
    got += reader.feed_eof(NOW)
    assert got == events
    assert reader.errors == 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.lists(st.integers(0, 400), max_size=5))
def test_arbitrary_bytes_never_raise_and_memory_stays_bounded(data: bytes, cuts: list[int]) -> None:
    reader = ShdrReader(round_kind, max_line=64, max_asset=128)
    start = 0
    for end in [*sorted(c for c in cuts if c <= len(data)), len(data)]:
        for event in reader.feed(data[start:end], NOW):
            assert not isinstance(event, Junk) or event.reason
        assert reader.buffered <= 64
        start = end
    reader.feed_eof(NOW)
    reader.feed(b"|v_x|1\n", NOW + timedelta(seconds=1))  # still usable afterwards
