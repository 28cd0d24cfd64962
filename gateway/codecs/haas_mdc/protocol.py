"""Haas MDC over TCP: `?Q100` and its kin as lines, and the control's answers as labelled lines.

A query is `?Q<nnn>` (`?Q600 <variable>` for a macro or system variable), a write `?E<variable> <value>`,
each ended by CR LF. The control answers with a line `LABEL, value[, LABEL, value...]`, framed by STX
(0x02) and ETB (0x17) on some software, preceded by a `>` prompt on others: the reader takes all of
these. It answers every connected client (at most two), so a client may read answers it did not ask
for: `Reply.answers(query)` says whether an answer is the one a query waits for (by its label).

Answers (Haas's documentation and others' clients): `SERIAL NUMBER, 1234567`, `SOFTWARE VERSION,
100.17.000.2037`, `MODEL, VF-2`, `MODE, MEM`, `TOOL CHANGES, 35`, `USING TOOL, 4`, `P.O. TIME,
06282:17:13`, `C.S.TIME, ...`, `LAST CYCLE, ...`, `PREV CYCLE, ...`, `M30 #1, 380`, `M30 #2, 380`,
`PROGRAM, O12345, IDLE, PARTS, 380` (or `STATUS, BUSY`), `MACRO, 123.456`; `!` for a write taken, `?`
(with the request) for one refused or a query the control does not know.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from gateway.errors import AddressError, CodecError

STX, ETB = 0x02, 0x17
MAX_LINE = 1024
#: The label each query's answer starts with.
LABELS = {100: "SERIAL NUMBER", 101: "SOFTWARE VERSION", 102: "MODEL", 104: "MODE", 200: "TOOL CHANGES",
          201: "USING TOOL", 300: "P.O. TIME", 301: "C.S.TIME", 303: "LAST CYCLE", 304: "PREV CYCLE",
          402: "M30 #1", 403: "M30 #2", 500: "PROGRAM", 600: "MACRO"}  # fmt: skip
_BY_LABEL = {v.replace(" ", ""): k for k, v in LABELS.items()}
TIMES = (300, 301, 303, 304)
Q500_FIELDS = ("program", "status", "parts")
_ADDRESS = re.compile(r"^(?:Q(?P<q>[0-9]{3})(?:\.(?P<field>[a-z]+))?|(?:Q600:|#)(?P<var>[0-9]{1,5}))$")
_TIME = re.compile(r"^\s*(\d+):(\d{1,2}):(\d{1,2})\s*$")


class MdcError(CodecError):
    """An answer that does not hold the value asked for; `reason` says why."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Query:
    """One query (`number` 100..600, `variable` for Q600) or, with `value`, an ?E write."""

    number: int
    variable: int | None = None
    value: float | None = None

    def encode(self) -> bytes:
        if self.value is not None:
            return f"?E{self.variable} {format_value(self.value)}\r\n".encode("ascii")
        if self.number == 600:
            return f"?Q600 {self.variable}\r\n".encode("ascii")
        return f"?Q{self.number}\r\n".encode("ascii")


@dataclass(frozen=True, slots=True)
class Reply:
    """One answer line: its label (`PROGRAM`, `MACRO`, `!`, `?`) and the fields after it."""

    label: str
    fields: tuple[str, ...]
    text: str

    @property
    def query(self) -> int | None:
        """The query number this answer belongs to (None for `!`, `?` and unknown labels)."""
        return _BY_LABEL.get(self.label.replace(" ", ""))

    def answers(self, query: Query) -> bool:
        if query.value is not None:
            return self.label in ("!", "?")
        if self.label == "?":
            return True  # a query the control refused
        if query.number == 500:
            return self.label in ("PROGRAM", "STATUS")
        return self.query == query.number


@dataclass(frozen=True, slots=True)
class Junk:
    reason: str


def format_value(value: float) -> str:
    if not math.isfinite(value):
        raise ValueError(f"{value!r} cannot be written to a macro")
    text = f"{value:.6f}".rstrip("0").rstrip(".")
    return text if text not in ("", "-0") else "0"


def parse_line(text: str) -> Reply | Junk:
    line = text.strip()
    if not line:
        return Junk("an empty answer")
    if line[0] in "!?":
        rest = line[1:].lstrip(", ")
        return Reply(line[0], tuple(p.strip() for p in rest.split(",")) if rest else (), line)
    if "," not in line:
        if line.upper().startswith("STATUS"):  # "STATUS BUSY"
            return Reply("STATUS", (line[6:].strip(),), line)
        return Junk(f"{line[:40]!r} is not an MDC answer (LABEL, value)")
    label, _, rest = line.partition(",")
    label = label.strip().upper()
    if not label or not all(c.isalnum() or c in " .#" for c in label):
        return Junk(f"{label[:40]!r} is not an MDC label")
    return Reply(label, tuple(p.strip() for p in rest.split(",")), line)


class LineReader:
    """Answers out of a byte stream split anywhere: CR/LF ends one; STX, ETB and a `>` prompt are dropped."""

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self._buf = bytearray()
        self.max_line = max_line

    def feed(self, data: bytes) -> list[Reply | Junk]:
        out: list[Reply | Junk] = []
        buf = self._buf
        for byte in data:
            if byte in (0x0D, 0x0A, ETB):
                if buf:
                    out.append(self._line(bytes(buf)))
                    buf.clear()
                continue
            if byte == STX or (byte == 0x3E and not buf):  # '>' prompt at a line's start
                continue
            if len(buf) >= self.max_line:
                out.append(Junk(f"an answer longer than {self.max_line} bytes"))
                buf.clear()
                continue
            buf.append(byte)
        return out

    def _line(self, raw: bytes) -> Reply | Junk:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            return Junk("an answer with bytes that are not ASCII")
        if not text.isprintable():
            return Junk("an answer with control characters")
        return parse_line(text)


@dataclass(frozen=True, slots=True)
class Item:
    """What a variable's `source` names: a query, and which field of its answer."""

    number: int
    field: str = ""
    variable: int | None = None

    @property
    def query(self) -> Query:
        return Query(self.number, self.variable)

    @property
    def writable(self) -> bool:
        return self.number == 600


def parse_address(source: str) -> Item:
    """`Q100`, `Q104`, `Q500.program`/`.status`/`.parts`, `Q600:5021` or `#5021`; AddressError otherwise."""
    m = _ADDRESS.match(source.strip())
    if m is None:
        raise AddressError(
            f"{source!r} is not a Haas MDC address: e.g. Q100, Q104, Q303, Q500.parts, #5021 (Q600), "
            f"Q600:10500"
        )
    if m["var"] is not None:
        return Item(600, variable=int(m["var"]))
    number = int(m["q"])
    if number == 600:
        raise AddressError(f"{source!r}: Q600 needs its variable, e.g. Q600:5021 or #5021")
    if number not in LABELS:
        raise AddressError(f"Q{number} is not an MDC query (one of {', '.join(f'Q{q}' for q in LABELS)})")
    field = m["field"] or ""
    if number == 500:
        if field not in Q500_FIELDS:
            raise AddressError(f"{source!r}: Q500 gives .program, .status or .parts")
    elif field:
        raise AddressError(f"{source!r}: only Q500 has fields")
    return Item(number, field)


def value_of(item: Item, reply: Reply) -> float | int | str:
    """The item's value out of its answer; MdcError when the answer does not hold it."""
    if reply.label == "?":
        raise MdcError(f"the control refused the query: {reply.text[:60]}")
    f = reply.fields
    if item.number == 500:
        if reply.label == "STATUS":
            if item.field == "status":
                return "BUSY"
            raise MdcError("the control is busy (STATUS BUSY): no program or parts now")
        # PROGRAM, O12345, IDLE, PARTS, 380
        if len(f) < 4 or f[2].upper() != "PARTS":
            raise MdcError(f"{reply.text[:60]!r} is not a Q500 answer")
        if item.field == "program":
            return f[0]
        if item.field == "status":
            return f[1]
        return _number(f[3])
    if not f or not f[0]:
        raise MdcError(f"{reply.text[:60]!r} has no value")
    if item.number in TIMES:
        m = _TIME.match(f[0])
        if m is None:
            raise MdcError(f"{f[0][:30]!r} is not a time (hours:minutes:seconds)")
        return int(m[1]) * 3600 + int(m[2]) * 60 + int(m[3])
    if item.number in (200, 201, 402, 403, 600):
        return _number(f[0])
    return f[0]


def _number(text: str) -> float | int:
    try:
        value = float(text)
    except ValueError:
        raise MdcError(f"{text[:30]!r} is not a number") from None
    if not math.isfinite(value):
        raise MdcError(f"{text[:30]!r} is not a finite number")
    return int(value) if value.is_integer() and "." not in text else value
