"""Program transfer, on a session of its own (opened with payload 1, not 2).

Download (into the controller): `1101` with a 4-byte 1 and a 512-byte field naming the target folder
(and, on the gateway's side, the file); answered `1102`; then the text in `1204` frames (no answers);
then `1301`, answered `1302` whose first two bytes are the result (0: stored). Upload (out of it):
`1501` with the same 516 bytes naming the program (`O1234-O1234`, or a full path on 30i-series);
answered `1502` (result first); then the controller sends the text in `1604` frames and `1701` at the
end, which the client answers with `1702`.
"""

from __future__ import annotations

import struct

from gateway.codecs.focas.errors import FocasError
from gateway.codecs.focas.frame import SERVER_VERSION, Frame, Kind, encode_frame

NAME_FIELD = 512
CHUNK = 1400  # text per data frame: one Ethernet segment (others use 512; any up to 65535 works)


def start_payload(name: str) -> bytes:
    raw = name.encode("ascii")
    if len(raw) >= NAME_FIELD or b"\x00" in raw:
        raise ValueError(f"{name!r} does not fit a FOCAS program name ({NAME_FIELD - 1} ASCII characters)")
    return struct.pack(">i", 1) + raw + b"\x00" * (NAME_FIELD - len(raw))


def read_start(payload: bytes) -> str:
    """The name a start frame carries (server side); FocasError if it is not a start payload."""
    if len(payload) != 4 + NAME_FIELD:
        raise FocasError(f"a transfer start carries {4 + NAME_FIELD} bytes, not {len(payload)}")
    raw = payload[4:].split(b"\x00", 1)[0]
    try:
        return raw.decode("ascii")
    except UnicodeDecodeError:
        raise FocasError("a transfer start names a program in bytes that are not ASCII") from None


def download_frames(name: str, text: bytes, chunk: int = CHUNK) -> tuple[bytes, list[bytes], bytes]:
    """The start frame, the data frames and the end frame of a download."""
    data = [encode_frame(Kind.DOWNLOAD_DATA, text[i : i + chunk]) for i in range(0, len(text), chunk)]
    return encode_frame(Kind.DOWNLOAD_START, start_payload(name)), data, encode_frame(Kind.DOWNLOAD_END)


def result_frame(kind: Kind, code: int) -> bytes:
    return encode_frame(kind, struct.pack(">h", code) + bytes(2), SERVER_VERSION)


def result_of(frame: Frame, expected: Kind) -> int:
    """The result code a `1102`/`1302`/`1502` answer carries; FocasError for any other frame."""
    if frame.kind != expected:
        raise FocasError(f"a frame of type {frame.kind:#06x} where {int(expected):#06x} was due")
    if len(frame.payload) < 2:
        return 0
    (code,) = struct.unpack_from(">h", frame.payload)
    return int(code)


def upload_name(name: str) -> str:
    """What the upload start names: a bare O-number as `O1234-O1234` (a range of one), a path as it is."""
    if name.startswith("O") and name[1:].isdigit():
        return f"{name}-{name}"
    return name
