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

from gateway.codecs.gcode import lex_line, split_lines
from gateway.config.validation import ValidationRules
from gateway.jobs.validation.estimate import Estimate, Extents
from gateway.jobs.validation.fast_read import read_ascii, read_text
from gateway.jobs.validation.file_names import check_file_name, split_name
from gateway.jobs.validation.reading import Parsed, Reading, assemble
from gateway.jobs.validation.text_checks import (
    SAMPLE,
    XON_XOFF,
    NulWatch,
    TextScan,
    TextScanner,
    detect_binary,
    text_stats,
)
from gateway.jobs.validation.verdict import MAX_REJECTIONS, Rejection, Verdict, capped

__all__ = [
    "MAX_REJECTIONS",
    "Estimate",
    "Extents",
    "ProgramCheck",
    "Rejection",
    "Verdict",
    "assemble",
    "validate_program",
]

#: Warnings beyond this are summarised in one last warning.
MAX_WARNINGS = 50
_SINUMERIK_HEADER = re.compile(r"^_N_([A-Za-z0-9_]+)_([A-Za-z]{3})$")
_CONTENT = re.compile(rb"[^ \t\n\r\x0b\x0c]")  # what bytes.strip() would keep
#: Bytes held back before reading starts (the binary check looks at the first SAMPLE); tests lower it.
_HEAD = SAMPLE


def validate_program(data: bytes, filename: str, rules: ValidationRules) -> Verdict:
    """Check `data`, to be stored as `filename` on a controller with these `rules`.

    The verdict's `program` is what would be delivered: `data` itself, or `data`
    without its XON/XOFF bytes where the rules strip them.
    """
    check = ProgramCheck(rules)
    check.feed(data)
    verdict = check.finish(filename)
    program = data.translate(None, XON_XOFF) if check.changed else data
    return dataclasses.replace(verdict, program=program)


class ProgramCheck:
    """`validate_program` in pieces: `feed` the bytes as they arrive, then `finish` with the file name.

    The inbox checks an upload while it streams in, so that a 50 MB program is
    judged moments after its last byte instead of after another read of the whole
    file. Pieces may split lines anywhere; lines are read once they are whole.
    Nothing is read until the first SAMPLE bytes are in (they decide whether the
    file is binary), nor beyond `max_size`, nor after a NUL byte. The tests feed
    programs split at every offset and compare with the whole-file verdict.
    """

    def __init__(self, rules: ValidationRules) -> None:
        self.rules = rules
        self.size = 0
        self.content = False  # any byte that is not white space
        self.head = b""  # the first SAMPLE bytes
        self.nuls = NulWatch()
        self.scanner = TextScanner(rules)
        self.reading = Reading(rules)
        self._pending = b""  # bytes not read yet: the head while it is short, then a partial last line
        self._started = False  # the head is complete and was looked at
        self._scan = True  # False once the file is known to be binary by its head
        self._line = 1  # the number of the next line to read

    @property
    def changed(self) -> bool:
        """Whether the program to deliver differs from the bytes fed (XON/XOFF bytes stripped)."""
        return (
            self.scanner.stripped > 0
            and self._scan
            and self.nuls.first is None
            and self.size <= self.rules.max_size
        )

    def feed(self, data: bytes) -> None:
        if not data:
            return
        self.size += len(data)
        if self.size > self.rules.max_size:
            self._pending = b""  # judged by its size alone
            return
        if not self.content and _CONTENT.search(data):
            self.content = True
        if len(self.head) < SAMPLE:
            self.head += data[: SAMPLE - len(self.head)]
        buffer = self._pending + data if self._pending else data
        if not self._started:
            if self.size < _HEAD:
                self._pending = buffer
                return
            self._start()
        cut = buffer.rfind(b"\n") + 1
        if cut == 0:
            self._pending = buffer
            return
        block, self._pending = (buffer, b"") if cut == len(buffer) else (buffer[:cut], buffer[cut:])
        self._block(block)

    def finish(self, filename: str) -> Verdict:
        """The verdict for everything fed, to be stored as `filename` (its `program` is empty)."""
        rules = self.rules
        rejections = check_file_name(filename, rules)
        if self.size > rules.max_size:
            # Not read further: the inbox limits uploads too, and reading a huge file helps nobody.
            rejections.append(
                Rejection(
                    "size", f"the program is {self.size} bytes; this machine takes at most {rules.max_size}"
                )
            )
            return _verdict(rejections, [], b"", None, None)
        if not self._started:
            self._start(final=True)
        if self._pending:
            pending, self._pending = self._pending, b""
            self._block(pending)
        if not self.content:
            what = "the file is empty" if not self.size else "the file holds only blank lines"
            rejections.append(Rejection("empty", what))
            return _verdict(rejections, [], b"", None, None)
        binary = detect_binary(self.head, self.nuls)
        if binary is not None:
            rejections.append(binary)
            return _verdict(rejections, [], b"", None, None)
        scan = self.scanner.finish()
        rejections.extend(scan.rejections)
        warnings = list(scan.warnings)
        reading = self.reading
        parsed = reading.parsed
        skipped = _syntax(parsed, scan, rules, rejections, warnings)
        _markers(parsed, rules, rejections, warnings)
        if not reading.any_words:
            rejections.append(
                Rejection(
                    "empty", "the program has no blocks with codes, only comments, markers or blank lines"
                )
            )
        else:
            _end_code(reading, rules, rejections)
        name = _program_name(parsed, filename, rules, rejections)
        _forbidden(reading, scan, rejections)
        estimate = reading.estimate.result()
        if skipped:
            estimate = dataclasses.replace(
                estimate,
                exact=False,
                notes=(*estimate.notes, f"{_lines(skipped)}: could not be read, so not estimated"),
            )
        warnings.extend(estimate.notes)
        return _verdict(rejections, warnings, b"", estimate, name)

    def _start(self, final: bool = False) -> None:
        """Reading begins: not at all if the head shows a binary file (magic, UTF-16, mostly not text).

        A head cut short (only where tests lower _HEAD) decides nothing: `finish` judges the file.
        """
        self._started = True
        if final or len(self.head) >= SAMPLE:
            self._scan = detect_binary(self.head, NulWatch()) is None

    def _block(self, raw: bytes) -> None:
        """Read whole lines (the last block of a file may end without LF)."""
        stats = text_stats(raw)
        first = self._line
        self._line += stats[2]
        if stats[3]:
            self.nuls.block(raw, first, stats[3])
        if not self._scan or self.nuls.first is not None:
            return  # the verdict is "binary" whatever the lines say
        text = self.scanner.block(raw, first, stats)
        reading = self.reading
        before = len(reading.forbidden)
        if isinstance(text, bytes):
            read_ascii(reading, text, first)
        else:
            read_text(reading, text, first)
        if len(reading.forbidden) > before:
            _locate_forbidden(reading, before, text if isinstance(text, str) else text.decode("ascii"), first)


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


def _end_code(reading: Reading, rules: ValidationRules, rejections: list[Rejection]) -> None:
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


def _locate_forbidden(reading: Reading, since: int, text: str, first: int) -> None:
    """Lex the plain lines (of `text`, from line `first`) that hold forbidden codes, for their columns."""
    lines = split_lines(text)
    for k in range(since, len(reading.forbidden)):
        line, index, code, block = reading.forbidden[k]
        if block is None:
            reading.forbidden[k] = (line, index, code, lex_line(lines[line - first], line))


def _forbidden(reading: Reading, scan: TextScan, rejections: list[Rejection]) -> None:
    for line, index, code, block in reading.forbidden:
        assert block is not None  # _locate_forbidden lexed it
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
