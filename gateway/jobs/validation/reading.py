"""One pass over a lexed program that keeps no blocks: the structure `parse_program` would build,
plus what validation checks (end code, forbidden codes) and the run-time estimate.

A 50 MB program is two and a half million blocks; keeping them would cost
gigabytes, so each block is read once, as it is lexed, and dropped.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import cast

from gateway.codecs.gcode import Block, GcodeError, Plain, Program, format_number, parse_program
from gateway.config.validation import ValidationRules
from gateway.jobs.validation.estimate import RunningEstimate


@dataclass
class Parsed:
    """A program as `parse_program` builds it, plus what validation needs to locate problems."""

    program: Program
    errors: list[GcodeError] = field(default_factory=list)
    marker_lines: list[int] = field(default_factory=list)
    first_line: int | None = None  # first non-blank line of the program
    last_line: int | None = None  # last non-blank line before the closing %
    name_line: int | None = None  # where the O-number or header name is
    trailing: int = 0  # non-blank lines after the closing %


def assemble(items: Iterable[Block | GcodeError]) -> Parsed:
    """`parse_program`'s reading of the lexed lines, without stopping at the first error.

    Lines with errors count as content and are left out of the blocks. A `%`
    before any content starts the program (its header may name it); the next `%`
    ends it, and what follows is never read by a controller.
    """
    assembler = _Assembler()
    blocks = [item for item in items if assembler.take(item)]
    return assembler.finish(tuple(blocks))  # type: ignore[arg-type]


class _Assembler:
    """`assemble` one line at a time: `take(item)` says whether the item is a block of the program.

    Items are what `lex_compact` yields (Blocks, GcodeErrors, and Plain tuples for
    ordinary lines, which are never markers, never block-deleted and never hold an O word).
    """

    def __init__(self) -> None:
        self.out = Parsed(Program((), False, False))
        self.start = self.end = self.seen_content = self.seen_words = False
        self.number: int | None = None
        self.name: str | None = None
        self.lines = 0

    def take(self, item: Plain | Block | GcodeError) -> bool:
        out = self.out
        if type(item) is tuple:
            line, _, words, comments = item
            blank = not words and not comments and item[1] is None
            if self.end:
                out.trailing += not blank
                return False
            self.lines += 1
            if blank:
                return False
            out.first_line = out.first_line or line
            out.last_line = line
            self.seen_content = True
            self.seen_words = self.seen_words or bool(words)
            return True
        if self.end:
            if isinstance(item, GcodeError) or not item.is_blank:  # type: ignore[union-attr]
                out.trailing += 1
            return False
        self.lines += 1
        if isinstance(item, GcodeError):
            out.errors.append(item)
            self.seen_content = True
            out.first_line = out.first_line or item.line
            out.last_line = item.line
            return False
        assert isinstance(item, Block)
        if item.marker:
            out.marker_lines.append(item.line)
            out.first_line = out.first_line or item.line
            if not self.seen_content and not self.start:
                self.start = True
                header = parse_program(item.text)
                self.number, self.name = header.program_number, header.program_name
                if self.number is not None or self.name is not None:
                    out.name_line = item.line
                return False
            self.end = True
            return False
        if item.is_blank:
            return False
        out.first_line = out.first_line or item.line
        out.last_line = item.line
        if not self.seen_words and self.number is None and item.words and item.words[0].letter == "O":
            self.number = int(item.words[0].value) if item.words[0].value.is_integer() else None
            self.name = self.name or (item.comments[0].strip() if item.comments else None) or None
            self.out.name_line = item.line
        self.seen_content = True
        self.seen_words = self.seen_words or bool(item.words)
        return True

    def finish(self, blocks: tuple[Block, ...] = ()) -> Parsed:
        self.out.program = Program(blocks, self.start, self.end, self.number, self.name, self.lines)
        return self.out


class Reading:
    """One pass over a lexed program that keeps no blocks: what `assemble` reads, plus the end
    code, forbidden codes and the run-time estimate, so that memory does not grow with the
    program (a 50 MB program is two and a half million blocks)."""

    def __init__(self, rules: ValidationRules) -> None:
        self.assembler = _Assembler()
        self.estimate = RunningEstimate(
            rapid_feed_mm_min=rules.rapid_feed, default_feed_mm_min=rules.default_feed, dwell_p=rules.dwell_p
        )
        self.end_codes = frozenset(rules.end_codes)
        self.forbid_codes = frozenset(rules.forbid_codes)
        self.any_words = False
        self.end_block: tuple[int, str] | None = None  # (line, code) of the first block with an end code
        self.after_end: int | None = None  # line of the first block with words after it
        self.forbidden: list[tuple[int, int, str, Block | None]] = []  # (line, word index, code, block)
        self._codes: dict[tuple[str, float], str] = {}

    @property
    def parsed(self) -> Parsed:
        return self.assembler.finish()

    def code(self, letter: str, value: float) -> str:
        """`Word.code`, remembered: a program uses a handful of distinct G and M codes."""
        key = (letter, value)
        code = self._codes.get(key)
        if code is None:
            code = self._codes[key] = letter + format_number(value)
        return code

    def read(self, items: Iterable[Plain | Block | GcodeError]) -> None:
        take = self.assembler.take
        estimate = self.estimate.block
        end_codes, forbid = self.end_codes, self.forbid_codes
        for item in items:
            if not take(item):
                continue
            if type(item) is tuple:
                line, _, pairs, _ = item
                block_delete = False
                block = None
            else:
                block = cast(Block, item)  # take() turned errors away; a Plain is a tuple
                line, block_delete = block.line, block.block_delete
                pairs = [(w.letter, w.value) for w in block.words]
            estimate(line, pairs, block_delete)
            if not pairs:
                continue
            self.any_words = True
            if self.end_block is not None:
                if self.after_end is None:
                    self.after_end = line
            elif not block_delete and end_codes:
                for letter, value in pairs:
                    if (letter == "G" or letter == "M") and self.code(letter, value) in end_codes:
                        self.end_block = (line, self.code(letter, value))
                        break
            if forbid:
                for index, (letter, value) in enumerate(pairs):
                    if (letter == "G" or letter == "M") and self.code(letter, value) in forbid:
                        self.forbidden.append((line, index, self.code(letter, value), block))
