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

from gateway.codecs.gcode import Block, GcodeError, Program, lex_lines, parse_program
from gateway.config.validation import ValidationRules
from gateway.jobs.estimate import Estimate, Extents, estimate_program
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
    parsed = assemble(lex_lines(scan.text))
    skipped = _syntax(parsed, scan, rules, rejections, warnings)
    program = parsed.program
    _markers(parsed, rules, rejections, warnings)
    if not any(b.words for b in program.blocks):
        rejections.append(
            Rejection("empty", "the program has no blocks with codes, only comments, markers or blank lines")
        )
    else:
        _end_code(parsed, rules, rejections)
    name = _program_name(parsed, filename, rules, rejections)
    _forbidden(program.blocks, scan, rules, rejections)
    estimate = estimate_program(
        program,
        rapid_feed_mm_min=rules.rapid_feed,
        default_feed_mm_min=rules.default_feed,
        dwell_p=rules.dwell_p,
    )
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
    blocks: list[Block] = []
    out = Parsed(Program((), False, False))
    start = end = seen_content = seen_words = False
    number: int | None = None
    name: str | None = None
    lines = 0
    for item in items:
        if end:
            if isinstance(item, GcodeError) or not item.is_blank:
                out.trailing += 1
            continue
        lines += 1
        if isinstance(item, GcodeError):
            out.errors.append(item)
            seen_content = True
            out.first_line = out.first_line or item.line
            out.last_line = item.line
            continue
        if item.marker:
            out.marker_lines.append(item.line)
            out.first_line = out.first_line or item.line
            if not seen_content and not start:
                start = True
                header = parse_program(item.text)
                number, name = header.program_number, header.program_name
                if number is not None or name is not None:
                    out.name_line = item.line
                continue
            end = True
            continue
        if item.is_blank:
            continue
        out.first_line = out.first_line or item.line
        out.last_line = item.line
        if not seen_words and number is None and item.words and item.words[0].letter == "O":
            number = int(item.words[0].value) if item.words[0].value.is_integer() else None
            name = name or (item.comments[0].strip() if item.comments else None) or None
            out.name_line = item.line
        seen_content = True
        seen_words = seen_words or bool(item.words)
        blocks.append(item)
    out.program = Program(tuple(blocks), start, end, number, name, lines)
    return out


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


def _end_code(parsed: Parsed, rules: ValidationRules, rejections: list[Rejection]) -> None:
    if rules.end_code == "optional":
        return
    codes = set(rules.end_codes)
    names = " or ".join(rules.end_codes)
    blocks = parsed.program.blocks
    end_at = next(
        (
            i
            for i, b in enumerate(blocks)
            if not b.block_delete and any(w.code in codes for w in b.words if w.letter in "GM")
        ),
        None,
    )
    if end_at is None:
        line = parsed.last_line or 1
        rejections.append(
            Rejection(
                "end-code",
                f"line {line}: the program ends without an end code ({names}); "
                "a truncated upload looks like this",
                line,
            )
        )
        return
    if rules.end_code != "last":
        return
    end_block = blocks[end_at]
    after = next((b for b in blocks[end_at + 1 :] if b.words), None)
    if after is not None:
        code = next(w.code for w in end_block.words if w.code in codes)
        rejections.append(
            Rejection(
                "end-code",
                f"line {after.line}: blocks after the end code {code} at line {end_block.line} "
                "would never run; the end code must be the last block",
                after.line,
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


def _forbidden(
    blocks: tuple[Block, ...], scan: TextScan, rules: ValidationRules, rejections: list[Rejection]
) -> None:
    if not rules.forbid_codes:
        return
    forbidden = set(rules.forbid_codes)
    for block in blocks:
        for word in block.words:
            if word.letter in "GM" and word.code in forbidden:
                column = scan.original_column(block.line, word.column)
                rejections.append(
                    Rejection(
                        "forbidden-code",
                        f"line {block.line}, column {column}: {word.code} is forbidden on this machine "
                        "(forbid_codes)",
                        block.line,
                        column,
                    )
                )
