"""Serial DNC receiver (PUNCH), remote requests and their answers."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.dnc import (
    BadRequest,
    Junk,
    LineSettings,
    Overflow,
    ProgramReceived,
    ProgramReceiver,
    ProgramStarted,
    RemoteRequest,
    Unterminated,
    answer_program,
    check_name,
    frame_program,
    not_found,
    parse_request,
)
from gateway.codecs.dnc.receiver import ReceiverEvent

PUNCH = b"\x00" * 20 + b"\x12%\nO4711 (BRACKET)\nG0 X1\nM30\n%\x14" + b"\x00" * 20


def feed_split(data: bytes, cuts: list[int], receiver: ProgramReceiver | None = None) -> list[ReceiverEvent]:
    r = receiver or ProgramReceiver()
    events: list[ReceiverEvent] = []
    last = 0
    for cut in [*cuts, len(data)]:
        events += r.feed(data[last:cut])
        last = cut
    return events


def test_punched_program_with_leader_and_tape_codes() -> None:
    events = ProgramReceiver().feed(PUNCH)
    assert events == [
        ProgramStarted(b""),
        ProgramReceived(b"O4711 (BRACKET)\nG0 X1\nM30\n", 4711, "BRACKET", b""),
    ]


def test_split_at_every_offset_and_every_pair() -> None:
    whole = ProgramReceiver().feed(PUNCH)
    for cut in range(len(PUNCH) + 1):
        assert feed_split(PUNCH, [cut]) == whole, f"split at {cut}"
    short = PUNCH[15:60]
    expected = ProgramReceiver().feed(short)
    for a in range(len(short) + 1):
        for b in range(a, len(short) + 1):
            assert feed_split(short, [a, b]) == expected


def test_two_programs_in_a_row_and_headers() -> None:
    data = b"%O12\nG0 X1\n%\n\n%_N_PART_MPF\nG0 X2\n%"
    received = [e for e in ProgramReceiver().feed(data) if isinstance(e, ProgramReceived)]
    assert [(r.number, r.name, r.header) for r in received] == [
        (12, None, b"O12"),
        (None, "_N_PART_MPF", b"_N_PART_MPF"),
    ]


def test_junk_before_the_program_is_counted() -> None:
    r = ProgramReceiver()
    events = r.feed(b"\x00\x00xz\xfe\n%\nG0\n%")
    assert isinstance(events[0], Junk) and events[0].count == 3 and events[0].sample == b"xz\xfe"
    assert isinstance(events[-1], ProgramReceived) and events[-1].text == b"G0\n"
    assert r.junk_bytes == 3


def test_unterminated_when_the_line_ends_inside_a_program() -> None:
    r = ProgramReceiver()
    r.feed(b"\x00%\nO1\nG0 X1\n")
    assert r.receiving and r.received == len(b"O1\nG0 X1\n")
    assert r.end_of_input() == [Unterminated(b"O1\nG0 X1\n")]
    assert not r.receiving and r.end_of_input() == []
    # Outside a program, the end of the line is nothing to report.
    r.feed(b"%\nG0\n%\x00\x00")
    assert r.end_of_input() == []


def test_oversized_program_is_refused_and_skipped_until_its_end() -> None:
    r = ProgramReceiver(max_size=10)
    events = r.feed(b"%\n" + b"G1 X1\n" * 5 + b"%\n%\nG0\n%")
    assert events == [
        ProgramStarted(b""),
        Overflow(10),
        ProgramStarted(b""),
        ProgramReceived(b"G0\n", None, None, b""),
    ]


def test_oversized_program_split_anywhere_gives_the_same_events() -> None:
    data = b"%\n" + b"G1 X1\n" * 5 + b"%\n%\nG0\n%"
    whole = ProgramReceiver(max_size=10).feed(data)
    for cut in range(len(data) + 1):
        assert feed_split(data, [cut], ProgramReceiver(max_size=10)) == whole


def test_parity_bit_stripped_when_asked() -> None:
    line = LineSettings(software_parity=True)
    wire = line.encode(frame_program(b"O7\nG0 X1\n", line).data)
    assert any(b > 0x7F for b in wire)
    events = ProgramReceiver(strip_parity=True).feed(wire)
    assert events[-1] == ProgramReceived(b"O7\nG0 X1\n", 7, None, b"")


def test_without_markers_the_caller_ends_the_program() -> None:
    r = ProgramReceiver(markers=False)
    assert r.feed(b"BEGIN PGM 1 MM\nL X+10\n") == []
    assert r.end_of_input() == [ProgramReceived(b"BEGIN PGM 1 MM\nL X+10\n", None, None, b"")]


@given(st.binary(max_size=300), st.integers(0, 300))
@settings(max_examples=300, deadline=None)
def test_arbitrary_bytes_never_crash_and_splitting_changes_nothing(data: bytes, cut: int) -> None:
    """Junk comes in one event per feed, so a split may cut it in two: its count is what must agree."""
    cut = min(cut, len(data))
    one, two = ProgramReceiver(max_size=64), ProgramReceiver(max_size=64)
    whole = one.feed(data)
    split = feed_split(data, [cut], two)
    assert [e for e in split if not isinstance(e, Junk)] == [e for e in whole if not isinstance(e, Junk)]
    assert one.junk_bytes == two.junk_bytes == sum(e.count for e in whole if isinstance(e, Junk))


# --- remote requests -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("program", "expected"),
    [
        (b"%\nO9999 (PRG=O4711)\nM30\n%\n", RemoteRequest("O4711")),
        (b"O9999(PRG = part-7.nc)\nM30\n", RemoteRequest("part-7.nc")),
        (b"o09999\n(prg=A_1)\nM30\n", RemoteRequest("A_1")),
        (b"O9999 (PRG=../etc/passwd)\nM30\n", BadRequest("NAME LEAVES THE FOLDER", "../etc/passwd")),
        (b"O9999 (PRG=sub/part)\nM30\n", BadRequest("NAME LEAVES THE FOLDER", "sub/part")),
        (b"O9999 (PRG=.hidden)\nM30\n", BadRequest("NAME LEAVES THE FOLDER", ".hidden")),
        (b"O9999 (PRG=a b)\nM30\n", BadRequest("BAD CHARACTERS IN NAME", "a b")),
        (b"O9999 (PRG=)\nM30\n", BadRequest("NO PROGRAM NAME", "")),
        (b"O9999 (PART 7)\nM30\n", BadRequest("NO PRG= IN REQUEST")),
        (b"O4711 (PRG=O1)\nM30\n", None),
        (b"G0 X1\n", None),
    ],
)
def test_requests_are_recognised_and_names_checked(
    program: bytes, expected: RemoteRequest | BadRequest | None
) -> None:
    assert parse_request(program) == expected


def test_request_number_and_key_are_configurable() -> None:
    assert parse_request(b"O8000 (FILE=X1)\n", number=8000, key="FILE") == RemoteRequest("X1")
    assert parse_request(b"O9999 (PRG=X1)\n", number=8000) is None


def test_names_longer_than_the_limit_are_refused() -> None:
    assert check_name("A" * 64) is None
    assert check_name("A" * 65) == "NAME TOO LONG"


def test_answer_programs_are_safe_for_any_controller() -> None:
    assert not_found("O4711") == b"%\nO9999 (NOT FOUND O4711)\nM30\n%\n"
    answer = answer_program("bad (name) % ; \x13 " + "x" * 100, number=123)
    assert answer.startswith(b"%\nO0123 (BAD NAME ")
    comment = answer.split(b"(", 1)[1].split(b")", 1)[0]
    assert len(comment) <= 60 and b"%" not in comment and b"\x13" not in comment
    # The answer frames like any program.
    assert frame_program(answer, LineSettings(leader=0)).data == b"%\nO0123 (" + comment + b")\nM30\n%"
