"""Per-target layout settings, and the Windows COPYDATASTRUCT described as plain numbers.

The widths of the id and length fields and the text encoding are what a nesting
package's developer chose, so they are per target. COPYDATASTRUCT is described
here without ctypes, so tests on any platform can check the Windows sender
against the same numbers.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import NamedTuple

WM_COPYDATA = 0x004A
"""The Windows message number; lParam points to a COPYDATASTRUCT."""

DWDATA_SINGLE = 1
"""dwData of a frame that carries exactly one variable."""

DWDATA_MULTI = 2
"""dwData of a frame that carries one or more variables back to back."""

DWDATA_VALUES = (DWDATA_SINGLE, DWDATA_MULTI)

U32_MAX = 2**32 - 1

_WIDTH_FORMATS = {1: "B", 2: "H", 4: "I"}

# Every (id_width, len_width) header, compiled once at import: 9 Structs.
_HEADERS: dict[tuple[int, int], struct.Struct] = {
    (i, n): struct.Struct("<" + _WIDTH_FORMATS[i] + _WIDTH_FORMATS[n])
    for i in _WIDTH_FORMATS
    for n in _WIDTH_FORMATS
}
_LENGTHS: dict[int, struct.Struct] = {n: struct.Struct("<" + f) for n, f in _WIDTH_FORMATS.items()}

TCP_HEADER = struct.Struct("<II")
"""dwData (u32 LE) then cbData (u32 LE), in front of lpData on TCP and UDP."""


@dataclass(frozen=True, slots=True)
class Layout:
    """How one target expects its frames: field widths, text encoding and a size limit.

    `max_cbdata` bounds what a decoder buffers and what an encoder produces, so a
    corrupt length can never make the gateway allocate more than this.
    """

    id_width: int = 2
    len_width: int = 2
    encoding: str = "utf-8"
    max_cbdata: int = 1 << 20

    def __post_init__(self) -> None:
        for name in ("id_width", "len_width"):
            width = getattr(self, name)
            if isinstance(width, bool) or width not in _WIDTH_FORMATS:
                raise ValueError(f"{name} must be 1, 2 or 4 bytes, got {width!r}")
        if isinstance(self.max_cbdata, bool) or not isinstance(self.max_cbdata, int):
            raise TypeError(f"max_cbdata must be an integer, got {self.max_cbdata!r}")
        if not 0 < self.max_cbdata <= U32_MAX:
            raise ValueError(
                f"max_cbdata must be between 1 and {U32_MAX} (cbData is a DWORD), got {self.max_cbdata}"
            )
        try:
            "".encode(self.encoding)
            b"".decode(self.encoding)
        except (LookupError, TypeError):
            raise ValueError(f"encoding {self.encoding!r} is not a text encoding Python knows") from None

    @property
    def header(self) -> struct.Struct:
        """The precompiled `id | length` item header."""
        return _HEADERS[self.id_width, self.len_width]

    @property
    def length(self) -> struct.Struct:
        """The precompiled length field alone (String[] element prefixes)."""
        return _LENGTHS[self.len_width]

    @property
    def max_id(self) -> int:
        return (1 << (8 * self.id_width)) - 1

    @property
    def max_length(self) -> int:
        return (1 << (8 * self.len_width)) - 1


class CopyDataStructLayout(NamedTuple):
    """Byte size and field offsets of COPYDATASTRUCT for one pointer size."""

    size: int
    offset_dwdata: int
    offset_cbdata: int
    offset_lpdata: int


def _align(offset: int, alignment: int) -> int:
    return (offset + alignment - 1) // alignment * alignment


def copydatastruct_layout(pointer_size: int) -> CopyDataStructLayout:
    """`{ULONG_PTR dwData; DWORD cbData; PVOID lpData;}` with natural alignment.

    64-bit: 24 bytes, offsets 0 / 8 / 16 (4 bytes of padding after cbData).
    32-bit: 12 bytes, offsets 0 / 4 / 8.
    """
    if pointer_size not in (4, 8):
        raise ValueError(f"pointer_size must be 4 (32-bit) or 8 (64-bit), got {pointer_size!r}")
    offset_cbdata = pointer_size
    offset_lpdata = _align(offset_cbdata + 4, pointer_size)
    size = _align(offset_lpdata + pointer_size, pointer_size)
    return CopyDataStructLayout(size, 0, offset_cbdata, offset_lpdata)


_CDS_STRUCTS = {4: struct.Struct("<III"), 8: struct.Struct("<QI4xQ")}


def pack_copydatastruct(pointer_size: int, dwdata: int, cbdata: int, lpdata_address: int) -> bytes:
    """The struct's bytes as a little-endian Windows process holds them (for tests of the sender)."""
    copydatastruct_layout(pointer_size)  # validates pointer_size
    try:
        return _CDS_STRUCTS[pointer_size].pack(dwdata, cbdata, lpdata_address)
    except struct.error as exc:
        raise ValueError(f"COPYDATASTRUCT field out of range for {8 * pointer_size}-bit: {exc}") from None
