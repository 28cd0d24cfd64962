"""Validate a G-code job before it is queued for a machine (pure: bytes in, a verdict out).

`validate_program` answers one question for the job queue: may these bytes go
to this machine's controller under this name? It reports every reason against
it, each with its line and column, not only the first (capped at MAX_REJECTIONS),
and estimates the run time of what it can read.

Order of checks: the file name; the size; empty; binary (one clear reason, and
nothing more is read); characters, encoding, XON/XOFF and line lengths; then the
lexed program: syntax, `%` markers, the end code, the program name, forbidden codes.

The end-code rule (`end_code`), precisely: the program is its blocks up to the
closing `%` (if any). An end code is a word whose code is in `end_codes`,
compared by value (M02 = M2 = M002), in a block that is not block-deleted (`/M30`
may be skipped by the operator's switch, so it does not count).
- `last`: an end code is required, and after the first block holding one, only
  blank lines, comment-only lines and the closing `%` may follow: a block with
  codes after it would never run (two programs pasted together look like this).
- `anywhere`: an end code is required somewhere.
- `optional`: not checked.
A missing end code is reported at the program's last line, because a truncated
upload looks exactly like that.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable
from dataclasses import dataclass, field

from gateway.codecs.gcode import (
    Block,
    GcodeError,
    Plain,
    Program,
    format_number,
    lex_line,
    parse_program,
    split_lines,
)
from gateway.config.validation import ValidationRules
from gateway.jobs.estimate import Estimate, Extents, RunningEstimate
from gateway.jobs.fast_read import read_text
from gateway.jobs.file_names import check_file_name, split_name
from gateway.jobs.text_checks import TextScan, detect_binary, scan_text
from gateway.jobs.verdict import MAX_REJECTIONS, Rejection, Verdict, capped

__all__ = ["Estimate", "Extents", "MAX_REJECTIONS", "Rejection", "Verdict", "validate_program"]

#: Warnings beyond this are summarised in one last warning.
MAX_WARNINGS = 50
_SINUMERIK_HEADER = re.compile(r"^_N_([A-Za-z0-9_]+)_([A-Za-z]{3})$")


def validate_program(data: bytes, filename: str, rules: ValidationRules) -> Verdict:
    """Check `data`, to be stored as `filename` on a controller with these `rules`."""
    rejections = check_file_name(filename, rules)
    if len(data) > rules.max_size:
        # Not read further: the inbox limits uploads too, and reading a huge file helps nobody.
        rejections.append(
            Rejection(
                "size", f"the program is {len(data)} bytes; this machine takes at most {rules.max_size}"
            )
        )
        return _verdict(rejections, [], data, None, None)
    if not data.strip():
        what = "the file is empty" if not data else "the file holds only blank lines"
        rejections.append(Rejection("empty", what))
        return _verdict(rejections, [], data, None, None)
    binary = detect_binary(data)
    if binary is not None:
        rejections.append(binary)
        return _verdict(rejections, [], data, None, None)
    scan = scan_text(data, rules)
    rejections.extend(scan.rejections)
    warnings = list(scan.warnings)
    reading = _Reading(rules)
    read_text(reading, scan.text)
    parsed = reading.parsed
    skipped = _syntax(parsed, scan, rules, rejections, warnings)
    _markers(parsed, rules, rejections, warnings)
    if not reading.any_words:
        rejections.append(
            Rejection("empty", "the program has no blocks with codes, only comments, markers or blank lines")
        )
    else:
        _end_code(reading, rules, rejections)
    name = _program_name(parsed, filename, rules, rejections)
    _forbidden(reading, scan, rules, rejections)
    estimate = reading.estimate.result()
    if skipped:
        estimate = dataclasses.replace(
            estimate,
            exact=False,
            notes=(*estimate.notes, f"{_lines(skipped)}: could not be read, so not estimated"),
        )
    warnings.extend(estimate.notes)
    return _verdict(rejections, warnings, scan.program, estimate, name)


def _verdict(
    rejections: list[Rejection],
    warnings: list[str],
    program: bytes,
    estimate: Estimate | None,
    name: str | None,
) -> Verdict:
    if len(warnings) > MAX_WARNINGS:
        warnings = [*warnings[: MAX_WARNINGS - 1], f"and {len(warnings) - MAX_WARNINGS + 1} more warnings"]
    return Verdict(not rejections, capped(rejections), tuple(warnings), program, estimate, name)


def _lines(numbers: list[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:10])
    more = f" and {len(numbers) - 10} more" if len(numbers) > 10 else ""
    return f"line {shown}" if len(numbers) == 1 else f"lines {shown}{more}"


# --- the program's structure -------------------------------------------------------------------


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


class _Reading:
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
                line, block_delete, block = item.line, item.block_delete, item  # type: ignore[union-attr]
                pairs = [(w.letter, w.value) for w in item.words]  # type: ignore[union-attr]
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


def _syntax(
    parsed: Parsed, scan: TextScan, rules: ValidationRules, rejections: list[Rejection], warnings: list[str]
) -> list[int]:
    """Lexing errors become rejections; with `macros: warn`, unsupported macro features are warnings."""
    skipped: list[int] = []
    macro_lines: list[int] = []
    for err in parsed.errors:
        skipped.append(err.line)
        column = scan.original_column(err.line, err.column)
        # The lexer words every parameter, expression and O-word message as "... not supported".
        if rules.macros == "warn" and "not supported" in err.reason:
            macro_lines.append(err.line)
            if len(macro_lines) <= 10:
                warnings.append(
                    f"line {err.line}, column {column}: {err.reason} here: the line is neither checked "
                    "nor estimated (the controller decides)"
                )
            continue
        rejections.append(
            Rejection("syntax", f"line {err.line}, column {column}: {err.reason}", err.line, column)
        )
    if len(macro_lines) > 10:
        warnings.append(f"and {len(macro_lines) - 10} more lines with macro features")
    return skipped


def _markers(
    parsed: Parsed, rules: ValidationRules, rejections: list[Rejection], warnings: list[str]
) -> None:
    program = parsed.program
    first = parsed.first_line or 1
    last = parsed.last_line or first
    if rules.markers == "forbid":
        for line in parsed.marker_lines:
            rejections.append(
                Rejection(
                    "forbidden-marker",
                    f"line {line}: '%' marker lines are not allowed on this controller",
                    line,
                    1,
                )
            )
    elif rules.markers == "require":
        if not program.start_marker:
            rejections.append(
                Rejection("start-marker", f"line {first}: the program must start with a '%' line", first)
            )
        if not program.end_marker:
            rejections.append(
                Rejection(
                    "end-marker",
                    f"line {last}: the program must end with a '%' line, and it has none "
                    "(a truncated upload looks like this)",
                    last,
                )
            )
    elif program.start_marker and not program.end_marker:
        rejections.append(
            Rejection(
                "end-marker",
                f"line {last}: the program starts with '%' at line {first} but has no closing '%' "
                "(a truncated upload looks like this)",
                last,
            )
        )
    elif program.end_marker and not program.start_marker:
        end_line = parsed.marker_lines[-1]
        warnings.append(
            f"line {end_line}: a closing '%' without one at the start; the controller reads up to it"
        )
    if program.end_marker and parsed.trailing and rules.markers != "forbid":
        warnings.append(
            f"{parsed.trailing} non-blank lines after the closing '%' at line {parsed.marker_lines[-1]} "
            "are ignored by the controller"
        )


def _end_code(reading: _Reading, rules: ValidationRules, rejections: list[Rejection]) -> None:
    if rules.end_code == "optional":
        return
    names = " or ".join(rules.end_codes)
    if reading.end_block is None:
        line = reading.parsed.last_line or 1
        rejections.append(
            Rejection(
                "end-code",
                f"line {line}: the program ends without an end code ({names}); "
                "a truncated upload looks like this",
                line,
            )
        )
        return
    if rules.end_code != "last" or reading.after_end is None:
        return
    end_line, code = reading.end_block
    after = reading.after_end
    rejections.append(
        Rejection(
            "end-code",
            f"line {after}: blocks after the end code {code} at line {end_line} "
            "would never run; the end code must be the last block",
            after,
        )
    )


def _program_name(
    parsed: Parsed, filename: str, rules: ValidationRules, rejections: list[Rejection]
) -> str | None:
    """The name the program gives itself, checked against the file name where the rules ask for it."""
    program = parsed.program
    number, header = program.program_number, program.program_name
    sinumerik = _SINUMERIK_HEADER.match(header or "") if program.start_marker else None
    own = f"O{number:04d}" if number is not None else header
    if rules.program_name == "ignore":
        return own
    stem, ext = split_name(filename)
    line = parsed.name_line
    if number is not None:
        m = re.fullmatch(r"[Oo]0*(\d+)", stem)
        if not m or int(m.group(1)) != number:
            rejections.append(
                Rejection(
                    "program-name",
                    f"line {line}: the program is {own}, so its file must be named {own} or {own}.nc, "
                    f"not {filename!r}",
                    line,
                )
            )
    elif sinumerik is not None:
        expected = f"{sinumerik.group(1)}.{sinumerik.group(2)}"
        if f"{stem}{ext}".upper() != expected.upper():
            rejections.append(
                Rejection(
                    "program-name",
                    f"line {line}: the header names the program {expected}, but the file is {filename!r}",
                    line,
                )
            )
    elif rules.program_name == "require":
        rejections.append(
            Rejection(
                "program-name",
                "the program has no O-number; this controller needs one that matches "
                f"the file name {filename!r}",
                parsed.first_line,
            )
        )
    return own


def _forbidden(reading: _Reading, scan: TextScan, rules: ValidationRules, rejections: list[Rejection]) -> None:
    if not reading.forbidden:
        return
    lines: list[str] | None = None
    for line, index, code, block in reading.forbidden:
        if block is None:  # an ordinary line: lex it again for the word's column
            if lines is None:
                lines = split_lines(scan.text)
            block = lex_line(lines[line - 1], line)
        word = block.words[index]
        column = scan.original_column(line, word.column)
        rejections.append(
            Rejection(
                "forbidden-code",
                f"line {line}, column {column}: {code} is forbidden on this machine (forbid_codes)",
                line,
                column,
            )
        )
