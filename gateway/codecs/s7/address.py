"""An S7 variable's `source`, in the notation of STEP 7 and TIA Portal, and its `Field`.

```
DB10.DBX2.3      bit 3 of byte 2 of DB10       M0.1, I0.1, Q4.0   a bit of the flags, inputs, outputs
DB10.DBB4        byte 4 (BYTE)                 MB20, IB0, QB4     (E and A for I and Q, as in German)
DB5.DBW0         bytes 0-1 (INT or WORD)       MW20, IW2, QW4
DB10.DBD4        bytes 4-7 (REAL/DINT/DWORD)   MD20, ID4, QD8
DB10.DBB20:STRING[30]     a STRING of 30 characters (32 bytes with its header) from byte 20
DB10.DBB40:DATE_AND_TIME, DB10.DBB8:LREAL     8-byte types start at a byte
DB10.DBW6:UINT, MD4:DINT  the type after a colon, where the width leaves a choice
```

Without a type, the width and the variable's type decide (W: INT for Int16, WORD for UInt16; D: REAL
for Float/Double, DINT for Int32, DWORD for UInt32). Errors are `S7AddressError` (a CodecError).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum, IntEnum

from gateway.codecs.overlap import overlaps as shared
from gateway.errors import CodecError

MAX_DB = 65535
MAX_BYTE = (1 << 21) - 1  # the protocol's 24-bit bit address
MAX_STRING = 254


class S7AddressError(CodecError):
    """A `source` that is not a usable S7 address for its variable."""


class Area(IntEnum):
    """S7 area codes, as the Read Var item carries them."""

    INPUTS = 0x81
    OUTPUTS = 0x82
    FLAGS = 0x83
    DB = 0x84

    @property
    def prefix(self) -> str:
        return {Area.INPUTS: "I", Area.OUTPUTS: "Q", Area.FLAGS: "M", Area.DB: "DB"}[self]


class Kind(str, Enum):
    BOOL = "BOOL"
    BYTE = "BYTE"
    SINT = "SINT"
    USINT = "USINT"
    WORD = "WORD"
    INT = "INT"
    UINT = "UINT"
    DWORD = "DWORD"
    DINT = "DINT"
    UDINT = "UDINT"
    REAL = "REAL"
    LINT = "LINT"
    ULINT = "ULINT"
    LREAL = "LREAL"
    STRING = "STRING"
    DATE_AND_TIME = "DATE_AND_TIME"

    @property
    def size(self) -> int:
        """Bytes (a STRING's depend on its length; a BOOL reads its byte)."""
        return _SIZES.get(self, 1)

    @property
    def integer(self) -> bool:
        return self in _INTEGER


_SIZES = {
    Kind.WORD: 2, Kind.INT: 2, Kind.UINT: 2,
    Kind.DWORD: 4, Kind.DINT: 4, Kind.UDINT: 4, Kind.REAL: 4,
    Kind.LINT: 8, Kind.ULINT: 8, Kind.LREAL: 8, Kind.DATE_AND_TIME: 8,
}  # fmt: skip
_INTEGER = frozenset({Kind.BYTE, Kind.SINT, Kind.USINT, Kind.WORD, Kind.INT, Kind.UINT, Kind.DWORD, Kind.DINT,
                      Kind.UDINT, Kind.LINT, Kind.ULINT})  # fmt: skip
_KIND_NAMES = {k.value: k for k in Kind if k is not Kind.STRING} | {"DT": Kind.DATE_AND_TIME}
_WIDTHS = {"X": 0, "B": 1, "W": 2, "D": 4}
_AREAS = {"I": Area.INPUTS, "E": Area.INPUTS, "Q": Area.OUTPUTS, "A": Area.OUTPUTS, "M": Area.FLAGS}

_DB_RE = re.compile(r"^DB(\d+)\.DB([XBWD])(\d+)(?:\.(\d+))?$")
_AREA_RE = re.compile(r"^([IEQAM])([BWD]?)(\d+)(?:\.(\d+))?$")
_STRING_RE = re.compile(r"^(?:STRING|S)\s*[\[(]\s*(\d+)\s*[\])]$")


@dataclass(frozen=True, slots=True)
class S7Address:
    """A parsed `source`: area, DB, byte, bit, the width letter's size (0: a bit), what the source names."""

    area: Area
    db: int
    byte: int
    bit: int | None
    width: int
    kind: Kind | None = None
    length: int | None = None  # characters of a STRING

    def __str__(self) -> str:
        letter = {0: "X", 1: "B", 2: "W", 4: "D"}[self.width]
        if self.area is Area.DB:
            text = f"DB{self.db}.DB{letter}{self.byte}"
        else:
            text = f"{self.area.prefix}{'' if letter == 'X' else letter}{self.byte}"
        if self.bit is not None:
            text += f".{self.bit}"
        if self.kind is Kind.STRING:
            text += f":STRING[{self.length}]"
        elif self.kind is not None and self.kind is not Kind.BOOL:
            text += f":{self.kind.value}"
        return text


@dataclass(frozen=True, slots=True)
class Field:
    """Where a variable's bytes are and what they hold: what the planner and the layouts work on."""

    area: Area
    db: int
    start: int  # first byte
    size: int  # bytes (a BOOL: its byte)
    kind: Kind
    bit: int | None = None
    length: int | None = None  # a STRING's declared characters
    as_float: bool = False  # the variable is Float/Double: integers are handed over as floats

    @property
    def end(self) -> int:
        return self.start + self.size

    def describe(self) -> str:
        where = f"DB{self.db}" if self.area is Area.DB else self.area.prefix
        kind = f"STRING[{self.length}]" if self.kind is Kind.STRING else self.kind.value
        bit = f".{self.bit}" if self.bit is not None else ""
        span = f"byte {self.start}" if self.size == 1 else f"bytes {self.start}-{self.end - 1}"
        return f"{where} {kind} at {self.start}{bit} ({span})"


def parse_address(text: str) -> S7Address:
    """Parse a `source`, or raise S7AddressError saying what is wrong with it."""
    if not isinstance(text, str) or not text.strip():
        raise S7AddressError("an S7 address must not be empty; e.g. DB10.DBD4 or MW20")
    place, _, type_text = text.strip().partition(":")
    place = place.strip().upper().replace(" ", "")
    kind: Kind | None = None
    length: int | None = None
    if type_text.strip():
        kind, length = _kind(type_text.strip().upper(), text)
    match = _DB_RE.match(place)
    if match is not None:
        db = int(match.group(1))
        if not 1 <= db <= MAX_DB:
            raise S7AddressError(f"{text!r}: data blocks are numbered 1-{MAX_DB}")
        area, width, byte, bit = Area.DB, _WIDTHS[match.group(2)], int(match.group(3)), match.group(4)
    else:
        match = _AREA_RE.match(place)
        if match is None:
            raise S7AddressError(
                f"{text!r} is not an S7 address; e.g. DB10.DBD4, DB10.DBX2.3, MW20, I0.1, Q4.0, "
                "DB5.DBB20:STRING[30]"
            )
        db = 0
        area = _AREAS[match.group(1)]
        letter = match.group(2) or "X"
        width, byte, bit = _WIDTHS[letter], int(match.group(3)), match.group(4)
    if byte > MAX_BYTE:
        raise S7AddressError(f"{text!r}: byte {byte} is past {MAX_BYTE}, the last an S7 address reaches")
    if width == 0:
        if bit is None:
            raise S7AddressError(f"{text!r}: a bit address needs its bit, e.g. {place}.0")
        if int(bit) > 7:
            raise S7AddressError(f"{text!r}: bit {bit} is not in a byte (0-7)")
        if kind not in (None, Kind.BOOL):
            raise S7AddressError(f"{text!r} is one bit: a BOOL, not {kind.value}")
        return S7Address(area, db, byte, int(bit), 0, Kind.BOOL)
    if bit is not None:
        raise S7AddressError(f"{text!r}: only bit addresses (DBX, M0.1, I0.1) take a bit number")
    if kind is Kind.BOOL:
        raise S7AddressError(f"{text!r}: a BOOL is a bit address (DB10.DBX2.3, M0.1)")
    if kind is not None:
        size = (length or 0) + 2 if kind is Kind.STRING else kind.size
        if size > 4 and width != 1:
            raise S7AddressError(f"{text!r}: a {kind.value} of {size} bytes starts at a byte (DBB, MB): "
                                 f"{_with_width(place, 'B')}:{type_text.strip()}")  # fmt: skip
        if size <= 4 and size != width:
            raise S7AddressError(f"{text!r}: a {kind.value} takes {size} byte{'s' if size > 1 else ''}, "
                                 f"the address names {width}")  # fmt: skip
    return S7Address(area, db, byte, None, width, kind, length)


def _with_width(place: str, letter: str) -> str:
    return re.sub(r"^(DB\d+\.DB|[IEQAM])[XBWD]?", lambda m: m.group(1) + letter, place)


def _kind(text: str, whole: str) -> tuple[Kind, int | None]:
    name = text.replace(" ", "")
    if name in _KIND_NAMES:
        return _KIND_NAMES[name], None
    match = _STRING_RE.match(name)
    if match is not None:
        length = int(match.group(1))
        if not 1 <= length <= MAX_STRING:
            raise S7AddressError(f"{whole!r}: an S7 STRING holds 1 to {MAX_STRING} characters, not {length}")
        return Kind.STRING, length
    if name == "STRING":
        raise S7AddressError(f"{whole!r}: give the STRING's declared length: STRING[30] (254 if undeclared)")
    names = ", ".join(k.value for k in Kind if k is not Kind.STRING)
    raise S7AddressError(f"{whole!r}: {text!r} is not an S7 type; expected {names}, STRING[n]")


# The S7 type a variable of each gateway type is, by the address's width, when the source names none.
_DEFAULTS: dict[tuple[int, str], Kind] = {
    (1, "Byte"): Kind.BYTE, (1, "SByte"): Kind.SINT, (1, "UInt16"): Kind.BYTE, (1, "Int16"): Kind.SINT,
    (2, "Int16"): Kind.INT, (2, "UInt16"): Kind.WORD, (2, "Int32"): Kind.INT, (2, "UInt32"): Kind.WORD,
    (4, "Int32"): Kind.DINT, (4, "UInt32"): Kind.DWORD, (4, "Float"): Kind.REAL, (4, "Double"): Kind.REAL,
    (4, "Int64"): Kind.DINT, (4, "UInt64"): Kind.DWORD,
}  # fmt: skip
_NUMBERS = frozenset(
    {"SByte", "Byte", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Float", "Double"}
)
_WHOLE = _NUMBERS - {"Float", "Double"}


def resolve(address: S7Address, raw_type: str) -> Field:
    """The field of a variable whose controller type is `raw_type` (an OPC UA type name: "Float",
    "Int16[]"); S7AddressError if the two do not fit."""
    if raw_type.endswith("[]"):
        raise S7AddressError(f"{address}: S7 variables are scalars here; map each element on its own")
    kind = address.kind
    if kind is None:
        kind = _DEFAULTS.get((address.width, raw_type))
        if kind is None:
            hint = {"String": ":STRING[30]", "DateTime": ":DATE_AND_TIME", "Double": ":LREAL"}.get(
                raw_type, ""
            )
            raise S7AddressError(
                f"{address}: a {raw_type} variable needs the S7 type after a colon"
                + (f", e.g. {_with_width(str(address), 'B')}{hint}" if hint else "")
            )
    expected = {Kind.BOOL: "Boolean", Kind.STRING: "String", Kind.DATE_AND_TIME: "DateTime"}.get(kind)
    if expected is not None and raw_type != expected:
        raise S7AddressError(f"{address} is a {kind.value}; the variable must be {expected}, not {raw_type}")
    if expected is None:
        if raw_type not in _NUMBERS:
            raise S7AddressError(f"{address} is a {kind.value}; a {raw_type} variable cannot hold it")
        if not kind.integer and raw_type in _WHOLE:
            raise S7AddressError(
                f"{address} is a {kind.value}; an {raw_type} variable would lose its fraction"
            )
    size = (address.length or 0) + 2 if kind is Kind.STRING else kind.size
    if address.byte + size - 1 > MAX_BYTE:
        raise S7AddressError(f"{address}: {size} bytes from {address.byte} reach past {MAX_BYTE}")
    return Field(address.area, address.db, address.byte, size, kind, address.bit, address.length,
                 as_float=raw_type in ("Float", "Double"))  # fmt: skip


def overlaps(fields: list[Field]) -> list[tuple[int, int]]:
    """(later, earlier) index pairs of fields sharing bytes; BOOLs of one byte may stand together (and
    beside the byte's own variable), the same bit twice may not."""
    return shared([((f.area, f.db), f.start, f.end, f.bit if f.kind is Kind.BOOL else None) for f in fields])
