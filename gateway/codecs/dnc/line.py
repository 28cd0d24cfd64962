"""The serial line's settings, and the character codes DNC uses on it.

One value object says everything both ends must agree on: baud rate, the
character format (7E2, 7N1, 8N1 ...), the handshake, the end of block and the
framing (leader, `%` markers). From it a scheduler knows the line's real rate:
each character costs a start bit, its data bits, a parity bit and its stop bits.

`software_parity` is for a 7-bit line driven through an 8-bit transparent port
(a device server in raw TCP mode set to 8N1/8N2, or a pseudo-terminal, which has
no parity at all): the parity bit travels as bit 7 of each byte, computed here,
which is exactly what a UART would put on the wire for 7E1/7E2 or 7O1/7O2.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Literal, cast

from gateway.errors import CodecError

NUL = 0x00
LF = 0x0A
CR = 0x0D
DC1 = 0x11  # XON: the controller can take data
DC2 = 0x12  # tape punch on (old controls send it before punching)
DC3 = 0x13  # XOFF: the controller's buffer is nearly full
DC4 = 0x14  # tape punch off
PERCENT = 0x25
DEL = 0x7F
#: Bytes a program must never contain: they would be taken for flow control (or tape control).
CONTROL_BYTES = frozenset({DC1, DC2, DC3, DC4})

Parity = Literal["N", "E", "O"]
Handshake = Literal["xonxoff", "rtscts", "none"]
EndOfBlock = Literal["lf", "crlf"]

MIN_BAUD = 50
MAX_BAUD = 4_000_000
MAX_LEADER = 10_000
_FORMAT = re.compile(r"^([78])([NEOneo])([12])$")


class LineSettingsError(CodecError):
    """Line settings that no serial line can have."""


def _odd_bits(value: int) -> bool:
    return value.bit_count() % 2 == 1


def _parity_tables(parity: Literal["E", "O"]) -> tuple[bytes, bytes, bytes]:
    """(encode, strip, bad) translate tables for 7-bit characters with the parity bit in bit 7.

    encode: char -> char with its parity bit; strip: byte -> its low 7 bits;
    bad: the 256 byte values whose parity bit is wrong (for `bytes.translate(None, good)`).
    """
    encode = bytearray(256)
    good = bytearray()
    for value in range(256):
        low = value & 0x7F
        ones_odd = _odd_bits(low)
        # Even parity: the 8 bits hold an even number of ones; odd parity: an odd number.
        bit = ones_odd if parity == "E" else not ones_odd
        encode[value] = low | (0x80 if bit else 0)
        if value == encode[value]:
            good.append(value)
    strip = bytes(v & 0x7F for v in range(256))
    return bytes(encode), strip, bytes(good)


@dataclass(frozen=True, slots=True)
class LineSettings:
    """What both ends of one serial DNC line agree on. Immutable; `replace()` for variants."""

    baud: int = 9600
    data_bits: Literal[7, 8] = 7
    parity: Parity = "E"
    stop_bits: Literal[1, 2] = 2
    handshake: Handshake = "xonxoff"
    eob: EndOfBlock = "lf"
    leader: int = 20  # NULs before the first `%` (Fanuc's feed)
    markers: bool = True  # `%` before and after the program (Fanuc, Sinumerik, Meldas; not Heidenhain)
    chunk_size: int = 200  # bytes handed to the port at once (the article's 200-byte pieces)
    software_parity: bool = False  # bit 7 carries the parity bit (7-bit line over an 8-bit port)

    def __post_init__(self) -> None:
        problems: list[str] = []
        if not isinstance(self.baud, int) or not MIN_BAUD <= self.baud <= MAX_BAUD:
            problems.append(f"baud {self.baud!r} is outside {MIN_BAUD}..{MAX_BAUD}")
        if self.data_bits not in (7, 8):
            problems.append(f"data bits {self.data_bits!r} must be 7 or 8")
        if self.parity not in ("N", "E", "O"):
            problems.append(f"parity {self.parity!r} must be N, E or O")
        if self.stop_bits not in (1, 2):
            problems.append(f"stop bits {self.stop_bits!r} must be 1 or 2")
        if self.handshake not in ("xonxoff", "rtscts", "none"):
            problems.append(f"handshake {self.handshake!r} must be xonxoff, rtscts or none")
        if self.eob not in ("lf", "crlf"):
            problems.append(f"end of block {self.eob!r} must be lf or crlf")
        if not isinstance(self.leader, int) or not 0 <= self.leader <= MAX_LEADER:
            problems.append(f"leader {self.leader!r} must be 0..{MAX_LEADER} characters")
        if not isinstance(self.chunk_size, int) or self.chunk_size < 1:
            problems.append(f"chunk size {self.chunk_size!r} must be >= 1 byte")
        if self.software_parity and (self.data_bits != 7 or self.parity == "N"):
            problems.append("software parity needs 7 data bits and parity E or O (its bit travels as bit 7)")
        if problems:
            raise LineSettingsError("; ".join(problems))

    @classmethod
    def from_format(cls, text: str, base: LineSettings | None = None) -> LineSettings:
        """`LineSettings.from_format("7E2")`: the usual shorthand for the character format (on `base`)."""
        match = _FORMAT.match(text.strip())
        if match is None:
            raise LineSettingsError(f"line format {text!r} is not like 7E2, 7N1 or 8N1")
        bits, parity, stop = match.groups()
        return dataclasses.replace(
            base if base is not None else cls(),
            data_bits=cast(Literal[7, 8], int(bits)),
            parity=cast(Parity, parity.upper()),
            stop_bits=cast(Literal[1, 2], int(stop)),
        )

    @property
    def format(self) -> str:
        """`7E2`, `8N1`, ..."""
        return f"{self.data_bits}{self.parity}{self.stop_bits}"

    @property
    def bits_per_char(self) -> int:
        """Start bit + data bits + parity bit (if any) + stop bits: what one character costs on the wire."""
        return 1 + self.data_bits + (0 if self.parity == "N" else 1) + self.stop_bits

    @property
    def char_time(self) -> float:
        """Seconds one character takes on the line."""
        return self.bits_per_char / self.baud

    @property
    def bytes_per_second(self) -> float:
        """Characters per second the line carries when it never idles."""
        return self.baud / self.bits_per_char

    @property
    def eob_bytes(self) -> bytes:
        return b"\r\n" if self.eob == "crlf" else b"\n"

    @property
    def seven_bit(self) -> bool:
        return self.data_bits == 7

    def encode(self, chars: bytes) -> bytes:
        """Characters -> the bytes handed to the port (the parity bit in bit 7 with software parity)."""
        if not self.software_parity:
            return chars
        return chars.translate(_TABLES[self.parity][0])

    def decode(self, wire: bytes) -> tuple[bytes, int]:
        """Bytes read from the port -> (characters, how many had a wrong parity bit).

        With software parity, bit 7 is checked and stripped; on any 7-bit line the
        characters are the low 7 bits. Characters with a wrong parity bit are kept
        (stripped) so that the caller can count and report them.
        """
        if not self.software_parity:
            return wire, 0
        _encode, strip, good = _TABLES[self.parity]
        errors = len(wire.translate(None, good))
        return wire.translate(strip), errors


_TABLES: dict[str, tuple[bytes, bytes, bytes]] = {"E": _parity_tables("E"), "O": _parity_tables("O")}
