"""Byte- and character-level checks of a program, before it is lexed.

A stray byte is what stops a machine halfway through a sheet, so every one is
named by line and column. Binary files get one clear reason instead of thousands
of character errors. The checks are fast on clean input (a 20 MB program is one
`bytes.translate` when nothing is wrong) and look closely only at lines that fail.

The text handed on to the lexer has every offending character removed, so that
one bad byte is reported once, here, and not again as a syntax error (a BEL inside
`G9<BEL>0` would otherwise split the number). `TextScan.original_column` maps the
lexer's columns on such lines back to columns in the file.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass, field

from gateway.config.validation import ValidationRules
from gateway.jobs.validation import compiled
from gateway.jobs.validation.verdict import Rejection

TEXT_BYTES = bytes(range(0x20, 0x7F)) + b"\t\n\r"
XON_XOFF = b"\x11\x12\x13\x14"
XON_XOFF_CHARS = frozenset(XON_XOFF.decode("ascii"))
#: Bytes that never occur in text files: controls other than TAB, LF, CR, VT, FF and DC1-DC4.
BINARY_BYTES = bytes(b for b in range(0x20) if b not in b"\t\n\r\x0b\x0c" + XON_XOFF) + b"\x7f"
SAMPLE = 64 * 1024
#: A file whose first SAMPLE bytes hold more than this share of non-text bytes is binary (Perl's -B uses 1/3).
BINARY_SHARE = 0.3

#: Signatures of files that people rename to .nc by mistake.
MAGIC: tuple[tuple[bytes, str], ...] = (
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"GIF87a", "a GIF image"),
    (b"GIF89a", "a GIF image"),
    (b"%PDF-", "a PDF document"),
    (b"PK\x03\x04", "a ZIP archive (or an Office document)"),
    (b"\x1f\x8b", "a gzip archive"),
    (b"7z\xbc\xaf\x27\x1c", "a 7-Zip archive"),
    (b"Rar!\x1a\x07", "a RAR archive"),
    (b"\x7fELF", "a Linux program"),
    (b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1", "an old Office document"),
)
CONTROL_NAMES = {0x07: "BEL", 0x08: "BS", 0x0B: "VT", 0x0C: "FF", 0x1B: "ESC", 0x7F: "DEL", 0x1A: "SUB"}


def line_column(data: bytes, index: int) -> tuple[int, int]:
    """1-based line and column (in bytes) of `data[index]`."""
    line = data.count(b"\n", 0, index) + 1
    start = data.rfind(b"\n", 0, index) + 1
    return line, index - start + 1


@dataclass
class NulWatch:
    """NUL bytes, a block of whole lines at a time: how many, and the line and column of the first."""

    count: int = 0
    first: tuple[int, int] | None = None

    def block(self, raw: bytes, first_line: int, found: int) -> None:
        """`found` NUL bytes are in `raw`, whose first line is `first_line`."""
        if found and self.first is None:
            line, column = line_column(raw, raw.find(0))
            self.first = (first_line + line - 1, column)
        self.count += found


def detect_binary(head: bytes, nuls: NulWatch) -> Rejection | None:
    """One rejection for a file that is not text at all (an image, an archive, UTF-16), or None.

    `head` is the file's first SAMPLE bytes; `nuls` watched all of it.
    """
    for magic, kind in MAGIC:
        if head.startswith(magic):
            return Rejection("binary", f"the file is {kind}, not a G-code program")
    sample = head[:SAMPLE]
    if head.startswith((b"\xff\xfe", b"\xfe\xff")) or _looks_utf16(sample):
        return Rejection(
            "encoding", "the file is UTF-16 text; save it as ASCII (or UTF-8) for the controller"
        )
    odd = len(sample) - len(sample.translate(None, BINARY_BYTES))
    odd += sample.decode("utf-8", errors="replace").count("\ufffd")
    binary = odd >= 16 and odd > BINARY_SHARE * len(sample)
    if nuls.first is not None:
        line, column = nuls.first
        what = (
            "this is a binary file, not a G-code program"
            if binary
            else "no G-code program holds one (padding from a transfer, or a binary file)"
        )
        first = "NUL byte (0x00)" if nuls.count == 1 else f"the first of {nuls.count} NUL bytes (0x00)"
        return Rejection("binary", f"line {line}, column {column}: {first}: {what}", line, column)
    if binary:
        share = 100.0 * odd / len(sample)
        return Rejection(
            "binary",
            f"{share:.0f}% of the file's first bytes are not text: this is a binary file, not G-code",
        )
    return None


def _looks_utf16(sample: bytes) -> bool:
    """ASCII text saved as UTF-16 without a byte-order mark: every other byte is NUL."""
    if len(sample) < 8:
        return False
    pairs = len(sample) // 2
    even, odd = sample[0 : 2 * pairs : 2], sample[1 : 2 * pairs : 2]
    for nul_half, text_half in ((odd, even), (even, odd)):
        if nul_half.count(0) > 0.9 * pairs and text_half.count(0) < 0.1 * pairs:
            return True
    return False


@dataclass
class TextScan:
    """The outcome of the character checks: the text for the lexer, and what will be delivered."""

    text: str
    program: bytes
    rejections: list[Rejection] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    removed: dict[int, list[int]] = field(default_factory=dict)  # line -> 0-based indices removed from it

    def original_column(self, line: int, column: int) -> int:
        """The file's column for a 1-based column of the lexer's text on `line`."""
        index = column - 1
        for gone in self.removed.get(line, ()):
            if gone <= index:
                index += 1
            else:
                break
        return index + 1


class TextScanner:
    """The character checks, a block of whole lines at a time (an upload is checked as it arrives).

    `block` takes lines that end with LF (the last block may lack it) and returns
    the text for the lexer, XON/XOFF bytes stripped where the rules say so;
    `finish` returns what was found, in the order of the lines: every line-length
    problem, then every character problem.
    """

    def __init__(self, rules: ValidationRules) -> None:
        self.rules = rules
        self.lengths: list[Rejection] = []
        self.characters: list[Rejection] = []
        self.removed: dict[int, list[int]] = {}
        self.utf8_lines: list[int] = []
        self.stripped = 0  # XON/XOFF bytes removed (xon_xoff: strip)
        self.stripped_line: int | None = None  # where the first was

    def block(self, raw: bytes, first: int, stats: tuple[int, bool, int, int]) -> str | bytes:
        """Check the lines of `raw`, the first of them line `first`; `stats` are its `text_stats`.

        Clean ASCII comes back as bytes (the readers take it as it is), anything else as the str to lex.
        """
        rules = self.rules
        longest, clean, _, _ = stats
        program = raw
        if not clean and rules.xon_xoff == "strip":
            program = raw.translate(None, XON_XOFF)
            if len(program) != len(raw):
                if self.stripped_line is None:
                    index = min(i for i in (raw.find(bytes([b])) for b in XON_XOFF) if i >= 0)
                    self.stripped_line = first + raw.count(b"\n", 0, index)
                self.stripped += len(raw) - len(program)
                longest, clean, _, _ = text_stats(program)
        limit = rules.max_line_length
        lines: list[bytes] = []
        if longest > limit or not clean:
            lines = program.split(b"\n")
            if lines and lines[-1] == b"":
                lines.pop()
        if longest > limit:
            for number, line in enumerate(lines, start=first):
                size = len(line) - line.endswith(b"\r")
                if size > limit:
                    self.lengths.append(
                        Rejection(
                            "line-length",
                            f"line {number} is {size} bytes long; this controller takes at most {limit}",
                            number,
                            limit + 1,
                        )
                    )
        if clean:
            return program
        texts: list[str] = []
        for number, line in enumerate(lines, start=first):
            body = line[:-1] if line.endswith(b"\r") else line
            if not body.translate(None, TEXT_BYTES) and b"\r" not in body:
                texts.append(body.decode("ascii"))
                continue
            text, found, utf8, gone = _scan_line(number, body, rules)
            texts.append(text)
            self.characters.extend(found)
            if gone:
                self.removed[number] = gone
            if utf8:
                self.utf8_lines.append(number)
        return "\n".join(texts) + ("\n" if program.endswith(b"\n") else "")

    def finish(self) -> TextScan:
        """What the blocks held; `text` and `program` are left empty (they went to the lexer)."""
        warnings: list[str] = []
        if self.stripped:
            warnings.append(
                f"removed {self.stripped} XON/XOFF handshake bytes (DC1-DC4), the first at line "
                f"{self.stripped_line}; the delivered program is without them"
            )
        if self.utf8_lines:
            lines = self.utf8_lines
            more = f" and {len(lines) - 1} more" if len(lines) > 1 else ""
            warnings.append(f"UTF-8 text in comments (line {lines[0]}{more}); utf8_comments allows it")
        return TextScan("", b"", [*self.lengths, *self.characters], warnings, self.removed)


def text_stats(data: bytes) -> tuple[int, bool, int, int]:
    """The longest line (bytes, a CR before LF included), whether the text is clean ASCII, and how
    many LF and NUL bytes it holds.

    Clean: only printable ASCII, TAB, LF, and CR directly before LF. One pass in
    the compiled module where it is built; a few bytes methods otherwise.
    """
    if compiled.plain is not None:
        return compiled.plain.text_stats(data)  # type: ignore[no-any-return]
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    longest = max(map(len, lines), default=0)
    clean = not data.translate(None, TEXT_BYTES) and data.count(b"\r") == data.count(b"\r\n")
    return longest, clean, data.count(b"\n"), 0 if clean else data.count(0)


def comment_mask(text: str) -> list[bool]:
    """Which characters of a line are inside a comment: `( ... )`, or `;` to the end of the line.

    An unterminated `(` runs to the end of the line (the lexer reports it).
    """
    mask = [False] * len(text)
    i = 0
    while i < len(text):
        ch = text[i]
        if ch == "(":
            end = text.find(")", i + 1)
            end = len(text) - 1 if end < 0 else end
            for k in range(i, end + 1):
                mask[k] = True
            i = end + 1
        elif ch == ";":
            for k in range(i, len(text)):
                mask[k] = True
            break
        else:
            i += 1
    return mask


def _describe(ch: str) -> str:
    code = ord(ch)
    if code < 0x80:
        name = CONTROL_NAMES.get(code) or ("NUL" if code == 0 else f"control {code:#04x}")
        return f"character 0x{code:02X} ({name})"
    name = unicodedata.name(ch, "")
    return f"character U+{code:04X}" + (f" ({name})" if name else "")


def _scan_line(
    number: int, body: bytes, rules: ValidationRules
) -> tuple[str, list[Rejection], bool, list[int]]:
    """Look closely at one line that is not plain ASCII.

    Returns the text for the lexer, the rejections, whether UTF-8 comments were
    allowed through, and the indices of the characters removed.
    """
    found: list[Rejection] = []
    bad_bytes = False
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError as exc:
        bad_bytes = True
        column = len(body[: exc.start].decode("utf-8", errors="replace")) + 1
        found.append(
            Rejection(
                "encoding",
                f"line {number}, column {column}: byte 0x{body[exc.start]:02X} is not valid UTF-8 "
                "(the file must be ASCII, or UTF-8)",
                number,
                column,
            )
        )
        text = body.decode("utf-8", errors="replace")
    mask = comment_mask(text)
    keep = [True] * len(text)
    hits: dict[str, list[tuple[int, str]]] = {}
    utf8 = False
    for i, ch in enumerate(text):
        code = ord(ch)
        if 0x20 <= code < 0x7F or ch == "\t":
            continue
        keep[i] = False
        if ch == "\ufffd" and bad_bytes:
            continue  # reported as an encoding problem
        if ch in XON_XOFF_CHARS:
            hits.setdefault("xon-xoff", []).append(
                (i, f"XON/XOFF handshake byte 0x{code:02X} (DC{code - 0x10})")
            )
        elif ch == "\r":
            hits.setdefault("character", []).append(
                (i, "a carriage return (0x0D) inside a line: lines must end with LF or CR LF")
            )
        elif ch == "\ufeff" and number == 1 and i == 0:
            hits.setdefault("character", []).append((i, "a byte-order mark (BOM): save the file without one"))
        elif code < 0x20 or code == 0x7F:
            hits.setdefault("character", []).append((i, f"{_describe(ch)} is not allowed"))
        elif mask[i] and rules.utf8_comments:
            keep[i] = True
            utf8 = True
        else:
            where = (
                "; utf8_comments would allow it in this comment"
                if mask[i]
                else " outside a comment"
                if rules.utf8_comments
                else ""
            )
            hits.setdefault("character", []).append((i, f"{_describe(ch)} is not allowed: only ASCII{where}"))
    for rule, items in hits.items():
        i, what = items[0]
        more = f" (and {len(items) - 1} more on this line)" if len(items) > 1 else ""
        if rule == "xon-xoff":
            what += " is not allowed (xon_xoff: strip would remove it)"
        found.append(Rejection(rule, f"line {number}, column {i + 1}: {what}{more}", number, i + 1))
    out = "".join(ch for ch, kept in zip(text, keep, strict=True) if kept)
    return out, found, utf8, [i for i, kept in enumerate(keep) if not kept]
