from __future__ import annotations

import contextlib
import pickle

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.gcode import (
    Block,
    GcodeError,
    Program,
    Word,
    format_number,
    format_program,
    lex_line,
    lex_lines,
    parse_program,
)
from gateway.errors import CodecError


def words(block: Block) -> list[tuple[str, float]]:
    return [(w.letter, w.value) for w in block.words]


def test_markers_header_numbers_comments_and_crlf() -> None:
    text = (
        "%O1234 (BRACKET)\r\nN10 G1 x 10. Y-.5 (first)(second) ; rest\r\n\r\n/G 0 Z5\r\n%\r\nanything (\r\n"
    )
    program = parse_program(text)
    assert program.start_marker and program.end_marker
    assert (program.program_number, program.program_name) == (1234, "BRACKET")
    assert program.lines == 5  # lexing stops at the end marker: the bad line after it is never read
    first, second = program.blocks
    assert (first.line, first.number) == (2, 10)
    assert words(first) == [("G", 1.0), ("X", 10.0), ("Y", -0.5)]
    assert first.comments == ("first", "second", " rest")
    assert first.text == "N10 G1 x 10. Y-.5 (first)(second) ; rest"
    assert second.line == 4 and second.block_delete and words(second) == [("G", 0.0), ("Z", 5.0)]


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G1X.5", [("G", 1.0), ("X", 0.5)]),
        ("G1 X-0.5", [("G", 1.0), ("X", -0.5)]),
        ("G1 X10.", [("G", 1.0), ("X", 10.0)]),
        ("G5.2", [("G", 5.2)]),
        ("G 1 X 10 Y - 2", [("G", 1.0), ("X", 10.0), ("Y", -2.0)]),
        ("g90 g21 m3 s1000", [("G", 90.0), ("G", 21.0), ("M", 3.0), ("S", 1000.0)]),
        ("G1 ^45 @10", [("G", 1.0), ("^", 45.0), ("@", 10.0)]),
        ("X+3", [("X", 3.0)]),
        ("\tG4 P0.5\t", [("G", 4.0), ("P", 0.5)]),
    ],
)
def test_words(line: str, expected: list[tuple[str, float]]) -> None:
    assert words(lex_line(line)) == expected


def test_word_code_and_text_keep_what_was_written() -> None:
    block = lex_line("g 01 G5.20 M030")
    assert [w.code for w in block.words] == ["G1", "G5.2", "M30"]
    assert [w.text for w in block.words] == ["g 01", "G5.20", "M030"]
    assert [w.column for w in block.words] == [1, 6, 12]
    assert block.get("M") == Word("M", 30.0, "M030", 12)
    assert len(block.all("G")) == 2 and block.get("X") is None


def test_o_word_header_fanuc_style() -> None:
    program = parse_program("O0042 (SIDE PANEL)\nG0 X1\n")
    assert (program.program_number, program.program_name) == (42, "SIDE PANEL")
    assert not program.start_marker and not program.end_marker


def test_siemens_style_percent_header_is_a_name() -> None:
    assert parse_program("%_N_PANEL_MPF\nG0 X1\nM30\n").program_name == "_N_PANEL_MPF"


def test_blank_and_comment_lines() -> None:
    blocks = list(lex_lines("\n   \n(only a comment)\n; semicolon\n"))
    assert all(isinstance(b, Block) for b in blocks)
    assert [b.is_blank for b in blocks] == [True, True, False, False]  # type: ignore[union-attr]
    assert [b.line for b in parse_program("\n\n(c)\nG0\n").blocks] == [3, 4]


@pytest.mark.parametrize(
    ("line", "column", "reason"),
    [
        ("G1 X10 (never closed", 8, "unterminated comment"),
        ("G1 (a (b) c)", 7, "nested"),
        ("G1 X", 4, "'X' is not followed by a number"),
        ("G1 X.", 5, "'X' is not followed by a number"),
        ("G1 XY", 5, "'X' is not followed by a number"),
        ("G1 X#1", 5, "parameters (#) are not supported"),
        ("#1 = 5", 1, "parameters (#) are not supported"),
        ("G1 X[1+2]", 5, "expressions"),
        ("G1 N10", 4, "N word (block number) must be the first word"),
        ("N10 N20", 5, "N word"),
        ("N1.5 G0", 1, "whole number"),
        ("10 G0", 1, "number without a letter"),
        ("G1 X1 )", 7, "')' without '('"),
        ("G1 %", 4, "'%' is only allowed alone"),
        ("G1 / X1", 4, "block delete"),
        ("G1 X1 é", 7, "unexpected character 'é'"),
        ("G1 X1\rY2", 6, "unexpected character '\\r'"),
        ("o100 sub", 6, "O-word subroutines"),
        ("o<probe> call", 2, "named O-words"),
        ("X" + "9" * 400, 2, "too large"),
    ],
)
def test_errors_name_line_column_and_reason(line: str, column: int, reason: str) -> None:
    with pytest.raises(GcodeError) as info:
        lex_line(line, 12)
    assert (info.value.line, info.value.column) == (12, column)
    assert reason in info.value.reason
    assert str(info.value).startswith(f"line 12, column {column}: ")
    assert isinstance(info.value, CodecError) and isinstance(info.value, ValueError)


def test_lex_lines_reports_every_bad_line_without_raising() -> None:
    items = list(lex_lines("G0 X1\nG1 (oops\nG1 X2 F100\nG1 X\n"))
    assert [type(i).__name__ for i in items] == ["Block", "GcodeError", "Block", "GcodeError"]
    assert [i.line for i in items] == [1, 2, 3, 4]


def test_parse_program_raises_the_first_error() -> None:
    with pytest.raises(GcodeError, match=r"^line 2, column 4: unterminated comment"):
        parse_program("G0\nG1 (x\nG1 X\n")


def test_error_pickles_with_its_location() -> None:
    err = pickle.loads(pickle.dumps(GcodeError(3, 4, "bad")))
    assert (err.line, err.column, err.reason, str(err)) == (3, 4, "bad", "line 3, column 4: bad")


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (1.0, "1"),
        (-0.0, "0"),
        (0.5, "0.5"),
        (-2.25, "-2.25"),
        (1.5e-07, "0.00000015"),
        (1e20, "100000000000000000000"),
    ],
)
def test_format_number_is_plain_decimal(value: float, text: str) -> None:
    assert format_number(value) == text


# --- properties -------------------------------------------------------------------------------

LETTERS = "ABCDEFGHIJKLMOPQRSTUVWXYZ^@"  # N is the block number, generated separately
values = st.floats(allow_nan=False, allow_infinity=False)
comment_text = st.text(
    st.characters(blacklist_characters="()\n\r", blacklist_categories=("Cs",)), max_size=12
)
word = st.builds(lambda letter, value: Word(letter, value, ""), st.sampled_from(LETTERS), values)
block = st.builds(
    lambda number, ws, comments, delete: Block(0, number, tuple(ws), tuple(comments), "", delete),
    st.none() | st.integers(0, 99999),
    st.lists(word, max_size=6),
    st.lists(comment_text, max_size=2),
    st.booleans(),
).filter(lambda b: not b.is_blank)
program = st.builds(
    lambda blocks, start, end: Program(tuple(blocks), start, end),
    st.lists(block, max_size=8),
    st.booleans(),
    st.booleans(),
).filter(lambda p: p.blocks or p.start_marker or not p.end_marker)  # a lone '%' reads as a start marker


def shape(b: Block) -> tuple[object, ...]:
    return (b.number, tuple((w.letter, w.value) for w in b.words), b.comments, b.block_delete)


@given(program)
@settings(max_examples=200)
def test_formatted_programs_round_trip(original: Program) -> None:
    again = parse_program(format_program(original))
    assert [shape(b) for b in again.blocks] == [shape(b) for b in original.blocks]
    assert again.start_marker == original.start_marker
    # Without a start marker, a lone trailing '%' still ends the program.
    assert again.end_marker == original.end_marker


@given(st.text(max_size=200))
@settings(max_examples=300)
def test_arbitrary_text_raises_nothing_but_gcode_error(text: str) -> None:
    with contextlib.suppress(GcodeError):
        parse_program(text)
    assert sum(1 for _ in lex_lines(text)) == text.count("\n") + (0 if text.endswith("\n") or not text else 1)


@given(st.text(alphabet="GXYZNMF0123456789.-+ ()%;/\t\r\nabc#[", max_size=120))
@settings(max_examples=300)
def test_gcode_like_text_raises_nothing_but_gcode_error(text: str) -> None:
    for item in lex_lines(text):
        assert isinstance(item, (Block, GcodeError))
    try:
        parse_program(text)
    except GcodeError as exc:
        assert exc.line >= 1 and exc.column >= 1


@given(st.text(alphabet="GXYZgxyzFIJKMNOS0123456789.+- \t();%/#[]", max_size=40))
def test_fast_path_agrees_with_the_exact_lexer(line: str) -> None:
    from gateway.codecs.gcode import _fast_line, _LineLexer

    fast = _fast_line(line, 7)
    if fast is None:
        return
    assert fast == _LineLexer(line, 7).run()


# --- the compact reading for large programs (lex_compact) ----------------------------------------


def _same_reading(compact: object, exact: Block | GcodeError) -> None:
    """A Plain tuple reads like the Block of `lex_lines`; anything else is exactly that item."""
    if isinstance(compact, tuple):
        assert isinstance(exact, Block) and not exact.marker and not exact.block_delete
        assert all(w.letter not in "NO" for w in exact.words)
        line, number, pairs, comments = compact
        assert (line, number, pairs, comments) == (
            exact.line, exact.number, [(w.letter, w.value) for w in exact.words], bool(exact.comments)
        )  # fmt: skip
    elif isinstance(compact, GcodeError):
        assert isinstance(exact, GcodeError)
        assert (compact.line, compact.column, compact.reason) == (exact.line, exact.column, exact.reason)
    else:
        assert compact == exact


@given(st.text(alphabet="GXYZgxyzFIJKMNnOoS0123456789.+- \t();%/#[]\r\n^@", max_size=200))
@settings(max_examples=400)
def test_compact_lexing_reads_like_lex_lines(text: str) -> None:
    from gateway.codecs.gcode import lex_compact

    compact, exact = list(lex_compact(text)), list(lex_lines(text))
    assert len(compact) == len(exact)
    for c, e in zip(compact, exact, strict=True):
        _same_reading(c, e)


def test_compact_lexing_of_a_large_program_across_chunks() -> None:
    """Runs longer than one findall chunk, broken by unusual lines, CRLF, and a last line without an end."""
    from gateway.codecs.gcode import lex_compact

    ordinary = [f"N{i} G1 X{i * 0.5:.3f} Y-{i % 97}. F3000 (cut) ; c" for i in range(12000)]
    odd = ((500, "%"), (5000, "/G0 X1"), (9000, "O1234 (NAME)"), (11000, "G1 X#1"), (11500, "x" + "9" * 400))
    for at, line in odd:
        ordinary[at] = line
    for text in ("\n".join(ordinary), "\r\n".join(ordinary) + "\r\n", "\n".join(ordinary) + "\n\n"):
        compact, exact = list(lex_compact(text)), list(lex_lines(text))
        assert len(compact) == len(exact) > 12000 - 1
        # the fast path took nearly all of it (a number too large for a float sends its chunk to lex_line)
        assert sum(isinstance(c, tuple) for c in compact) >= 10000
        for c, e in zip(compact, exact, strict=True):
            _same_reading(c, e)


def test_compact_lexing_does_not_backtrack_on_hostile_lines() -> None:
    """A long line that almost reads as ordinary fails at once, not after exponential backtracking."""
    from gateway.codecs.gcode import lex_compact

    line = " ".join(f"X{'1' * 30}" for _ in range(3000)) + " #"
    items = list(lex_compact(line + "\n"))
    assert len(items) == 1 and isinstance(items[0], GcodeError)
