"""A pure G-code lexer: text in, blocks of words out (no asyncio, no I/O).

Two consumers shape it. The simulator's interpreter executes the blocks; the
gateway's job validator checks programs before they reach a machine and must
name every problem with its line. So lexing never stops at the first bad line:
`lex_lines` yields one `Block` or one `GcodeError` per physical line, and
`parse_program` builds on it for callers that want the first error raised.

The dialect is the common subset of LinuxCNC, Fanuc and most laser controllers:
`%` marker lines (the first may carry a header such as `%O1234` or `%_N_PART_MPF`),
`(comments)` anywhere in a line (several per line, not nested) and `; comments`
to the end of the line, an optional `/` block delete at the start, an N word
that must come first, upper- or lower-case letters, spaces between a letter and
its number (`G 1 X 10`), numbers like `X.5`, `X-0.5`, `X10.` and `G5.2`.
LinuxCNC's polar words `^` (angle) and `@` (distance) are lexed as ordinary
words with those letters; whether to run them is the interpreter's business.
Parameters (`#1`), expressions (`[1+2]`) and O-word control flow (`o100 sub`)
are reported as clear errors, not guessed at.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from decimal import Decimal

from gateway.errors import CodecError

#: Letters that start a word. `^` and `@` are LinuxCNC's polar angle and distance.
LETTERS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZ^@")

_BLANKS = " \t"
_DIGITS = "0123456789"
_O_FLOW = "O-word subroutines and control flow (sub, call, if, while) are not supported"
_WORD_START = LETTERS | frozenset("abcdefghijklmnopqrstuvwxyz")


class GcodeError(CodecError):
    """One lexing problem, located by 1-based line and column."""

    def __init__(self, line: int, column: int, reason: str) -> None:
        self.line = line
        self.column = column
        self.reason = reason
        super().__init__(f"line {line}, column {column}: {reason}")

    def __reduce__(self) -> tuple[type[GcodeError], tuple[int, int, str]]:
        return (type(self), (self.line, self.column, self.reason))


@dataclass(frozen=True, slots=True)
class Word:
    """A letter and its number, e.g. `X-0.5`. `text` is the word as written (`g 01`)."""

    letter: str
    value: float
    text: str
    column: int = 0

    @property
    def code(self) -> str:
        """Normalised spelling for comparisons and messages: `G01` -> `G1`, `g5.20` -> `G5.2`."""
        return self.letter + format_number(self.value)


@dataclass(frozen=True, slots=True)
class Block:
    """One physical line of a program.

    `words` holds every word except N, whose value is `number`. A `%` line is a
    block with `marker=True` and no words. Blank lines are blocks with nothing in them.
    """

    line: int
    number: int | None
    words: tuple[Word, ...]
    comments: tuple[str, ...]
    text: str
    block_delete: bool = False
    marker: bool = False

    @property
    def is_blank(self) -> bool:
        return not (
            self.words or self.comments or self.marker or self.block_delete or self.number is not None
        )

    def get(self, letter: str) -> Word | None:
        """The first word with this letter, if any."""
        for word in self.words:
            if word.letter == letter:
                return word
        return None

    def all(self, letter: str) -> tuple[Word, ...]:
        """Every word with this letter, in order (a block may hold several G or M codes)."""
        return tuple(w for w in self.words if w.letter == letter)


@dataclass(frozen=True, slots=True)
class Program:
    """A whole program: its blocks between the `%` markers, and what its header says.

    `blocks` leaves out blank lines, the `%` lines themselves and everything after
    the end marker (controllers ignore it). `lines` counts the physical lines read.
    """

    blocks: tuple[Block, ...]
    start_marker: bool
    end_marker: bool
    program_number: int | None = None
    program_name: str | None = None
    lines: int = 0


# --- lexing ------------------------------------------------------------------------------------


def split_lines(text: str) -> list[str]:
    """Physical lines without their ends. LF and CRLF both end a line; a final line end adds no line."""
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return [line.removesuffix("\r") for line in lines]


def lex_lines(text: str) -> Iterator[Block | GcodeError]:
    """One `Block` or one `GcodeError` per physical line, never raising: the validator's entry point."""
    for number, raw in enumerate(split_lines(text), start=1):
        try:
            yield lex_line(raw, number)
        except GcodeError as exc:
            yield exc


#: An ordinary line in `lex_compact`'s form: (line, N number or None, [(letter, value), ...], has comments).
Plain = tuple[int, "int | None", list[tuple[str, float]], bool]


def lex_compact(text: str, first_line: int = 1) -> Iterator[Plain | Block | GcodeError]:
    """`lex_lines` for programs of millions of lines: the same reading, in a lighter form.

    Ordinary lines (an optional N number, then words other than N and O, and
    comments: nearly every line of a real program) come out as `Plain` tuples of
    (letter, value) pairs, found by two regexes over the whole text instead of
    one Word object per word; any other line comes out exactly as `lex_lines`
    gives it (a Block or a GcodeError). For a Plain line, `lex_line` would give a
    Block with the same line, number, letters and values, and comments when the
    flag says so (a property test holds the two to it). Lines are numbered from `first_line`.
    """
    end = len(text)
    pos = 0
    line = first_line
    run_match = _ORDINARY_RUN.match
    while pos < end:
        run = run_match(text, pos).end()  # type: ignore[union-attr]
        if run > pos:
            yield from _lex_run(text, pos, run, line)
            line += text.count("\n", pos, run)
            pos = run
            continue
        nl = text.find("\n", pos)
        stop = end if nl < 0 else nl
        raw = text[pos:stop].removesuffix("\r")
        try:
            yield lex_line(raw, line)
        except GcodeError as exc:
            yield exc
        line += 1
        pos = end if nl < 0 else nl + 1


# Ordinary lines, for `lex_compact`: an optional leading N number, then words (not N, not O) and
# (comments) in any order, optionally a ;comment; CRLF or LF. Possessive quantifiers: a line
# that is not ordinary fails at once, without backtracking (no regex blow-up on hostile input),
# and a run of a million lines keeps no state per line.
_NUMBER = r"[+-]?+[ \t]*+(?:[0-9]++(?:\.[0-9]*+)?+|\.[0-9]++)"
_ORDINARY_LINE = (
    r"[ \t]*+(?:[Nn][ \t]*+[0-9]++(?![0-9.])[ \t]*+)?+"
    rf"(?:(?:[A-MP-Za-mp-z^@][ \t]*+{_NUMBER}|\([^()\n\r]*+\))[ \t]*+)*+(?:;[^\n\r]*+)?+"
)
_ORDINARY_RUN = re.compile(rf"(?:{_ORDINARY_LINE}\r?\n)*+(?:{_ORDINARY_LINE}\Z)?+")
_RUN_TOKEN = re.compile(
    rf"([A-MP-Za-mp-z^@])[ \t]*({_NUMBER})|(\()[^()\n\r]*\)|(;)[^\n\r]*|[Nn][ \t]*([0-9]+)|\r?\n|\Z"
)
_INFINITE = (math.inf, -math.inf)
_CHUNK = 1 << 16  # characters of a run lexed by one findall (the tuples of a chunk are kept at once)


def _lex_run(text: str, start: int, end: int, line: int) -> Iterator[Plain | Block | GcodeError]:
    """The lines of text[start:end], which `_ORDINARY_RUN` matched, a chunk of lines at a time.

    `findall` hands over every token as a tuple of groups (no match objects): a word
    fills the letter and the number, a comment its `(` or `;`, an N word its digits,
    and a line end (or the end of the chunk) nothing at all.
    """
    findall = _RUN_TOKEN.findall
    while start < end:
        stop = text.find("\n", start + _CHUNK, end)
        stop = end if stop < 0 else stop + 1
        lines: list[Plain] = []
        words: list[tuple[str, float]] = []
        comments = False
        number: int | None = None
        for letter, found, paren, semi, block in findall(text, start, stop):
            if letter:
                digits = found.replace(" ", "").replace("\t", "") if " " in found or "\t" in found else found
                value = float(digits)
                if value in _INFINITE:  # too large for a float: the exact lexer words the error
                    lines = []
                    break
                words.append((letter.upper(), value))
            elif paren or semi:
                comments = True
            elif block:
                number = int(block)
            else:  # a line end, or the end of the chunk (one too many after a final line end)
                lines.append((line + len(lines), number, words, comments))
                words, comments, number = [], False, None
        count = _line_count(text, start, stop)
        if len(lines) >= count:
            yield from lines[:count]
        else:
            yield from _lex_exactly(text, start, stop, line)
        line += count
        start = stop


def _line_count(text: str, start: int, end: int) -> int:
    """Physical lines in text[start:end]: its line ends, plus a last line without one."""
    count = text.count("\n", start, end)
    return count + (1 if end > start and text[end - 1] != "\n" else 0)


def _lex_exactly(text: str, start: int, end: int, line: int) -> Iterator[Block | GcodeError]:
    for offset, raw in enumerate(split_lines(text[start:end])):
        try:
            yield lex_line(raw, line + offset)
        except GcodeError as exc:
            yield exc


def lex_line(raw: str, line: int = 1) -> Block:
    """Lex one line (without its line end). Raises GcodeError naming the column."""
    block = _fast_line(raw, line)
    return block if block is not None else _LineLexer(raw, line).run()


# One token of an ordinary line: a word (letter, optional sign, number), a (comment) or a ;comment.
_TOKEN = re.compile(
    r"[ \t]*(?:(?P<letter>[A-Za-z^@])[ \t]*(?P<number>[+-]?[ \t]*(?:[0-9]+\.?[0-9]*|\.[0-9]+))"
    r"|\((?P<comment>[^()]*)\)|;(?P<tail>.*))"
)
_SIMPLE_END = re.compile(r"[ \t]*")


def _fast_line(raw: str, line: int) -> Block | None:
    """The common case in one regex pass per token; None sends the line to the exact lexer.

    Anything unusual (a marker, block delete, N or O words, a character that is not
    a word or a comment, a number too large) takes the slow path, which also owns
    every error message, so both paths agree on what a line means.
    """
    words: list[Word] = []
    comments: list[str] = []
    pos = 0
    end = len(raw)
    match = _TOKEN.match
    while True:
        m = match(raw, pos)
        if m is None:
            if _SIMPLE_END.match(raw, pos).end() != end:  # type: ignore[union-attr]
                return None
            break
        letter = m.group("letter")
        if letter is not None:
            upper = letter.upper()
            if upper in "NO":
                return None
            number = m.group("number")
            value = float(number.replace(" ", "").replace("\t", ""))
            if value in (math.inf, -math.inf):
                return None
            start = m.start("letter")
            words.append(Word(upper, value, raw[start : m.end()], start + 1))
        else:
            tail = m.group("tail")
            if tail is not None:
                comments.append(tail)
                break
            comments.append(m.group("comment"))
        pos = m.end()
        if pos >= end:
            break
    return Block(line, None, tuple(words), tuple(comments), raw)


class _LineLexer:
    """A cursor over one line; small enough to keep every error message next to its cause."""

    def __init__(self, raw: str, line: int) -> None:
        self.raw = raw
        self.line = line
        self.pos = 0

    def error(self, reason: str, pos: int | None = None) -> GcodeError:
        return GcodeError(self.line, (self.pos if pos is None else pos) + 1, reason)

    def skip_blanks(self) -> None:
        while self.pos < len(self.raw) and self.raw[self.pos] in _BLANKS:
            self.pos += 1

    def run(self) -> Block:
        raw = self.raw
        self.skip_blanks()
        if self.pos < len(raw) and raw[self.pos] == "%":
            return Block(self.line, None, (), (), raw, marker=True)
        block_delete = False
        if self.pos < len(raw) and raw[self.pos] == "/":
            block_delete = True
            self.pos += 1
        number: int | None = None
        words: list[Word] = []
        comments: list[str] = []
        while True:
            self.skip_blanks()
            if self.pos >= len(raw):
                break
            ch = raw[self.pos]
            if ch == "(":
                comments.append(self.comment())
            elif ch == ";":
                comments.append(raw[self.pos + 1 :])
                break
            elif ch in _WORD_START:
                start = self.pos
                if words and words[-1].letter == "O" and re.match(r"[A-Za-z]{2}", raw[start:]):
                    raise self.error(_O_FLOW)
                word = self.word()
                if word.letter == "N":
                    if words or number is not None:
                        raise self.error(
                            "the N word (block number) must be the first word of the block", start
                        )
                    if not word.value.is_integer() or word.value < 0:
                        raise self.error(f"block number {word.text!r} must be a whole number >= 0", start)
                    number = int(word.value)
                else:
                    words.append(word)
            else:
                raise self.error(self.unexpected(ch, words))
        return Block(self.line, number, tuple(words), tuple(comments), raw, block_delete)

    def comment(self) -> str:
        start = self.pos
        end = self.raw.find(")", start + 1)
        nested = self.raw.find("(", start + 1)
        if end < 0:
            raise self.error("unterminated comment: '(' without ')'", start)
        if 0 <= nested < end:
            raise self.error("nested '(' inside a comment (comments cannot be nested)", nested)
        self.pos = end + 1
        return self.raw[start + 1 : end]

    def word(self) -> Word:
        start = self.pos
        letter = self.raw[self.pos].upper()
        self.pos += 1
        self.skip_blanks()
        sign_end = self.pos
        if self.pos < len(self.raw) and self.raw[self.pos] in "+-":
            self.pos += 1
            self.skip_blanks()
        digits_start = self.pos
        while self.pos < len(self.raw) and self.raw[self.pos] in _DIGITS:
            self.pos += 1
        if self.pos < len(self.raw) and self.raw[self.pos] == ".":
            self.pos += 1
            while self.pos < len(self.raw) and self.raw[self.pos] in _DIGITS:
                self.pos += 1
        number = self.raw[digits_start : self.pos]
        if not any(c in _DIGITS for c in number):
            raise self.error(
                self.missing_number(letter), digits_start if digits_start < len(self.raw) else start
            )
        sign = self.raw[sign_end:digits_start].strip()
        value = float(sign + number)
        if not math.isfinite(value):
            raise self.error(f"the number after {letter!r} is too large", digits_start)
        return Word(letter, value, self.raw[start : self.pos], start + 1)

    def missing_number(self, letter: str) -> str:
        rest = self.raw[self.pos :]
        if rest[:1] == "#":
            return "parameters (#) are not supported"
        if rest[:1] == "[":
            return "expressions ([...]) are not supported"
        if letter == "O" and rest[:1] == "<":
            return "named O-words (o<name>) are not supported"
        return f"{letter!r} is not followed by a number"

    def unexpected(self, ch: str, words: list[Word]) -> str:
        if ch in _DIGITS or ch in "+-.":
            return "a number without a letter in front of it"
        if ch == ")":
            return "')' without '('"
        if ch == "#":
            return "parameters (#) are not supported"
        if ch == "[":
            return "expressions ([...]) are not supported"
        if ch == "<":
            return "named parameters and O-words (<name>) are not supported"
        if ch == "%":
            return "'%' is only allowed alone on a line (program start/end marker)"
        if ch == "/":
            return "'/' (block delete) must be the first character of the line"
        return f"unexpected character {ch!r}"


# --- programs ----------------------------------------------------------------------------------

_O_HEADER = re.compile(r"^[Oo]\s*(\d+)")


def parse_program(text: str) -> Program:
    """Lex a whole program; raise the first GcodeError. Lines after the end marker are ignored."""
    blocks: list[Block] = []
    start_marker = end_marker = False
    number: int | None = None
    name: str | None = None
    seen_content = seen_words = False
    lines = 0
    for item in lex_lines(text):
        lines += 1
        if isinstance(item, GcodeError):
            raise item
        if item.marker:
            if not seen_content and not start_marker:
                start_marker = True
                number, name = _percent_header(item.text)
                continue
            end_marker = True
            break
        if item.is_blank:
            continue
        if not seen_words and number is None and item.words and item.words[0].letter == "O":
            # Fanuc style: the first block is `O1234 (PART NAME)`.
            number = int(item.words[0].value) if item.words[0].value.is_integer() else None
            name = name or (item.comments[0].strip() if item.comments else None) or None
        seen_content = True
        seen_words = seen_words or bool(item.words)
        blocks.append(item)
    return Program(tuple(blocks), start_marker, end_marker, number, name, lines)


def _percent_header(text: str) -> tuple[int | None, str | None]:
    """`%O1234 (BRACKET)` -> (1234, "BRACKET"); `%_N_PART_MPF` -> (None, "_N_PART_MPF"); `%` -> nothing."""
    rest = text.strip()[1:].strip()
    comments = re.findall(r"\(([^()]*)\)", rest)
    bare = re.sub(r"\([^()]*\)", " ", rest).split(";", 1)[0].strip()
    number = None
    match = _O_HEADER.match(bare)
    if match:
        number = int(match.group(1))
        bare = bare[match.end() :].strip()
    name = next((c.strip() for c in comments if c.strip()), None) or bare or None
    return number, name


# --- formatting --------------------------------------------------------------------------------


def format_number(value: float) -> str:
    """The shortest plain decimal (no exponent) that reads back as exactly `value`."""
    if value.is_integer() and abs(value) < 1e16:
        return str(int(value))
    text = format(Decimal(repr(value)), "f")
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def format_block(block: Block) -> str:
    """Canonical text of a block: `/`, N, words, then comments. Markers format as `%`."""
    if block.marker:
        return "%"
    parts: list[str] = []
    if block.block_delete:
        parts.append("/")
    if block.number is not None:
        parts.append(f"N{block.number}")
    parts.extend(w.letter + format_number(w.value) for w in block.words)
    for index, comment in enumerate(block.comments):
        if "(" in comment or ")" in comment or "\n" in comment:
            if index != len(block.comments) - 1:
                raise ValueError(f"comment {comment!r} needs ';' form, which must be the last comment")
            parts.append(";" + comment)
        else:
            parts.append(f"({comment})")
    return " ".join(parts)


def format_program(program: Program) -> str:
    """Text of a program, one block per line, LF line ends, markers as given."""
    lines = ["%"] if program.start_marker else []
    lines += [format_block(b) for b in program.blocks]
    if program.end_marker:
        lines.append("%")
    return "".join(line + "\n" for line in lines)
