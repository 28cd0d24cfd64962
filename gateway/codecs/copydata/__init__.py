"""COPYDATA frames for nesting software: a pure, sans-I/O codec.

The byte layout is documented for receiver authors in docs/copydata.md. This
package only turns values into bytes and bytes into frames; the WM_COPYDATA
sender and the TCP/UDP transports are built on top of it elsewhere.

    layout = Layout(id_width=2, len_width=2, encoding="utf-8")
    table = VariableTable.from_ids({1: ("Axes/X/Position", "Double")})
    frame = table.encode({1: 12.5}, layout)          # Frame(dwdata=1, items=(Item(1, b"..."),))
    wire = pack_tcp(frame, layout)                   # dwData | cbData | lpData
    frames = FrameDecoder(layout).feed(wire)         # [frame]
    table.decode(frames[0], layout)                  # (Reading(Variable(1, ...), 12.5),)
"""

from gateway.codecs.copydata.errors import (
    BadBoolean,
    BadFiletime,
    BadText,
    BadValue,
    CopydataEncodeError,
    CopydataError,
    DecoderFailed,
    FieldOverflow,
    FrameTooLarge,
    ItemCountMismatch,
    LengthOverrun,
    TrailingBytes,
    TruncatedFrame,
    TruncatedHeader,
    Unencodable,
    UnknownDwData,
    UnknownId,
    ValueOutOfRange,
    ValueTypeError,
    WrongSize,
)
from gateway.codecs.copydata.frame import Frame, Item
from gateway.codecs.copydata.frames import (
    decode_lpdata,
    encode_lpdata,
    encode_multi,
    encode_single,
    pack_tcp,
    unpack_datagram,
)
from gateway.codecs.copydata.layout import (
    DWDATA_MULTI,
    DWDATA_SINGLE,
    TCP_HEADER,
    WM_COPYDATA,
    CopyDataStructLayout,
    Layout,
    copydatastruct_layout,
    pack_copydatastruct,
)
from gateway.codecs.copydata.stream import FrameDecoder
from gateway.codecs.copydata.table import Reading, Variable, VariableTable
from gateway.codecs.copydata.values import FILETIME_EPOCH, decode_value, encode_value, filetime_ticks

__all__ = [
    "DWDATA_MULTI",
    "DWDATA_SINGLE",
    "FILETIME_EPOCH",
    "TCP_HEADER",
    "WM_COPYDATA",
    "BadBoolean",
    "BadFiletime",
    "BadText",
    "BadValue",
    "CopyDataStructLayout",
    "CopydataEncodeError",
    "CopydataError",
    "DecoderFailed",
    "FieldOverflow",
    "Frame",
    "FrameDecoder",
    "FrameTooLarge",
    "Item",
    "ItemCountMismatch",
    "Layout",
    "LengthOverrun",
    "Reading",
    "TrailingBytes",
    "TruncatedFrame",
    "TruncatedHeader",
    "Unencodable",
    "UnknownDwData",
    "UnknownId",
    "ValueOutOfRange",
    "ValueTypeError",
    "Variable",
    "VariableTable",
    "WrongSize",
    "copydatastruct_layout",
    "decode_lpdata",
    "decode_value",
    "encode_lpdata",
    "encode_multi",
    "encode_single",
    "encode_value",
    "filetime_ticks",
    "pack_copydatastruct",
    "pack_tcp",
    "unpack_datagram",
]
