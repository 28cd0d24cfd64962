"""Frames: items in, lpData and TCP/UDP bytes out, and back.

lpData is `[id][length N][N data bytes]`, once for dwData=1 and one or more
times for dwData=2. On TCP and UDP a frame is `dwData (u32) | cbData (u32) |
lpData`. These functions never look at what the data bytes mean; the variable
table does that (`gateway.codecs.copydata.table`).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

from gateway.codecs.copydata.errors import (
    CopydataError,
    FieldOverflow,
    FrameTooLarge,
    ItemCountMismatch,
    LengthOverrun,
    TrailingBytes,
    TruncatedFrame,
    TruncatedHeader,
    UnknownDwData,
    ValueTypeError,
)
from gateway.codecs.copydata.frame import Frame, Item
from gateway.codecs.copydata.layout import DWDATA_MULTI, DWDATA_SINGLE, DWDATA_VALUES, TCP_HEADER, Layout

# --- encode ----------------------------------------------------------------------------------


def _append_item(parts: list[bytes], item: Item, layout: Layout, index: int) -> None:
    data = item.data
    try:
        parts.append(layout.header.pack(item.id, len(data)))
    except struct.error:
        if isinstance(item.id, bool) or not isinstance(item.id, int):
            raise ValueTypeError(f"item {index}: id must be an integer, got {item.id!r}") from None
        if not 0 <= item.id <= layout.max_id:
            raise FieldOverflow(
                f"item {index}: id {item.id} does not fit a {layout.id_width}-byte id field "
                f"(0..{layout.max_id})"
            ) from None
        raise FieldOverflow(
            f"item {index} (id {item.id}): {len(data)} data bytes do not fit a {layout.len_width}-byte "
            f"length field (max {layout.max_length})"
        ) from None
    parts.append(data)


def _join(parts: list[bytes], layout: Layout) -> bytes:
    lpdata = b"".join(parts)
    if len(lpdata) > layout.max_cbdata:
        raise FrameTooLarge(f"lpData would be {len(lpdata)} bytes, over max_cbdata {layout.max_cbdata}")
    return lpdata


def encode_single(item: Item, layout: Layout) -> bytes:
    """lpData of a dwData=1 frame: exactly one triple."""
    parts: list[bytes] = []
    _append_item(parts, item, layout, 0)
    return _join(parts, layout)


def encode_multi(items: Iterable[Item], layout: Layout) -> bytes:
    """lpData of a dwData=2 frame: one or more triples back to back."""
    parts: list[bytes] = []
    for index, item in enumerate(items):
        _append_item(parts, item, layout, index)
    if not parts:
        raise ItemCountMismatch("a dwData=2 frame needs at least one item")
    return _join(parts, layout)


def encode_lpdata(frame: Frame, layout: Layout) -> bytes:
    """lpData of any frame, checking that dwData and the item count agree."""
    if frame.dwdata == DWDATA_SINGLE:
        if len(frame.items) != 1:
            raise ItemCountMismatch(
                f"a dwData=1 frame carries exactly one item, this one has {len(frame.items)}"
            )
        return encode_single(frame.items[0], layout)
    if frame.dwdata == DWDATA_MULTI:
        return encode_multi(frame.items, layout)
    raise UnknownDwData(f"dwData {frame.dwdata!r} is neither 1 (one variable) nor 2 (several)")


def pack_tcp(frame: Frame, layout: Layout) -> bytes:
    """The frame as sent on TCP (or as one UDP datagram): dwData | cbData | lpData."""
    lpdata = encode_lpdata(frame, layout)
    return TCP_HEADER.pack(frame.dwdata, len(lpdata)) + lpdata


# --- decode ----------------------------------------------------------------------------------


def check_dwdata(dwdata: int, offset: int | None = None) -> None:
    if dwdata not in DWDATA_VALUES:
        raise UnknownDwData(f"dwData {dwdata} is neither 1 (one variable) nor 2 (several)", offset=offset)


def _read_item(lpdata: bytes, offset: int, layout: Layout, index: int) -> tuple[Item, int]:
    header = layout.header
    end = len(lpdata)
    if end - offset < header.size:
        raise TruncatedHeader(
            f"item {index}: {end - offset} bytes left, its id and length fields need {header.size}",
            offset=offset,
        )
    item_id, length = header.unpack_from(lpdata, offset)
    start = offset + header.size
    if start + length > end:
        raise LengthOverrun(
            f"item {index} (id {item_id}) declares {length} data bytes "
            f"but only {end - start} remain in lpData",
            offset=offset + layout.id_width,
        )
    return Item(item_id, lpdata[start : start + length]), start + length


def decode_lpdata(dwdata: int, lpdata: bytes, layout: Layout) -> Frame:
    """Split lpData into items; error offsets count from the start of lpData.

    The data bytes are not interpreted here: `VariableTable.decode` does that,
    so a receiver can still skip ids it does not know.
    """
    check_dwdata(dwdata)
    lpdata = bytes(lpdata)
    if len(lpdata) > layout.max_cbdata:
        raise FrameTooLarge(f"cbData {len(lpdata)} is over max_cbdata {layout.max_cbdata}", offset=0)
    end = len(lpdata)
    if dwdata == DWDATA_SINGLE:
        if end == 0:
            raise ItemCountMismatch(
                "a dwData=1 frame carries exactly one item, this lpData is empty", offset=0
            )
        item, offset = _read_item(lpdata, 0, layout, 0)
        if offset != end:
            raise ItemCountMismatch(
                f"a dwData=1 frame carries exactly one item, but {end - offset} more bytes follow it",
                offset=offset,
            )
        return Frame(DWDATA_SINGLE, (item,))
    if end == 0:
        raise ItemCountMismatch("a dwData=2 frame needs at least one item, this lpData is empty", offset=0)
    items: list[Item] = []
    offset = 0
    while offset < end:
        item, offset = _read_item(lpdata, offset, layout, len(items))
        items.append(item)
    return Frame(DWDATA_MULTI, tuple(items))


def unpack_datagram(datagram: bytes, layout: Layout) -> Frame:
    """One UDP datagram holding exactly one frame; error offsets count from the datagram's start."""
    size = len(datagram)
    if size < TCP_HEADER.size:
        raise TruncatedFrame(f"datagram of {size} bytes is shorter than the 8-byte frame header", offset=0)
    dwdata, cbdata = TCP_HEADER.unpack_from(datagram, 0)
    check_dwdata(dwdata, 0)
    if cbdata > layout.max_cbdata:
        raise FrameTooLarge(f"cbData {cbdata} is over max_cbdata {layout.max_cbdata}", offset=4)
    if size < TCP_HEADER.size + cbdata:
        raise TruncatedFrame(f"cbData says {cbdata} bytes but the datagram holds {size - 8}", offset=0)
    if size > TCP_HEADER.size + cbdata:
        raise TrailingBytes(
            f"{size - 8 - cbdata} bytes follow the {cbdata} bytes of lpData that cbData announces",
            offset=TCP_HEADER.size + cbdata,
        )
    try:
        return decode_lpdata(dwdata, datagram[TCP_HEADER.size :], layout)
    except CopydataError as exc:
        raise exc._shift(TCP_HEADER.size) from None
