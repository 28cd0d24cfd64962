"""The FOCAS frame: `A0 A0 A0 A0`, a version (1 from a client, 2 or 4 from a controller), a type, a
16-bit payload length, the payload. Every exchange (open, close, commands, program transfer) is one.

`FrameReader` cuts a byte stream into frames however it was split; bytes that do not start a frame
become a `Junk` event (counted by the caller, who drops the session: a FOCAS peer never sends any).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

SYNC = b"\xa0\xa0\xa0\xa0"
HEADER = struct.Struct(">4sHHH")
HEADER_SIZE = HEADER.size  # 10
MAX_PAYLOAD = 0xFFFF
CLIENT_VERSION = 1
SERVER_VERSION = 2


class Kind(IntEnum):
    """Frame types (high byte: the exchange; low byte: 01 request, 02 answer, 04 data)."""

    OPEN = 0x0101
    OPEN_OK = 0x0102
    CLOSE = 0x0201
    CLOSE_OK = 0x0202
    DOWNLOAD_START = 0x1101
    DOWNLOAD_START_OK = 0x1102
    DOWNLOAD_DATA = 0x1204
    DOWNLOAD_END = 0x1301
    DOWNLOAD_END_OK = 0x1302
    UPLOAD_START = 0x1501
    UPLOAD_START_OK = 0x1502
    UPLOAD_DATA = 0x1604
    UPLOAD_END = 0x1701
    UPLOAD_END_OK = 0x1702
    REQUEST = 0x2101
    RESPONSE = 0x2102


#: The open request's payload: which kind of session (2: commands, 1: program transfer).
SESSION_COMMANDS = 2
SESSION_TRANSFER = 1


@dataclass(frozen=True, slots=True)
class Frame:
    kind: int
    payload: bytes = b""
    version: int = CLIENT_VERSION


@dataclass(frozen=True, slots=True)
class Junk:
    """Bytes that did not start a frame, skipped up to the next `A0 A0 A0 A0`."""

    skipped: int
    reason: str


def encode_frame(kind: int, payload: bytes = b"", version: int = CLIENT_VERSION) -> bytes:
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"a FOCAS frame carries at most {MAX_PAYLOAD} bytes, not {len(payload)}")
    return HEADER.pack(SYNC, version, kind, len(payload)) + payload


class FrameReader:
    """Frames from a stream of bytes, split anywhere."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.junk_bytes = 0

    @property
    def pending(self) -> int:
        """Bytes held that do not yet make a whole frame."""
        return len(self._buffer)

    def feed(self, data: bytes) -> list[Frame | Junk]:
        buf = self._buffer
        buf += data
        events: list[Frame | Junk] = []
        while buf:
            if not buf.startswith(SYNC[: min(len(buf), 4)]):
                at = buf.find(SYNC, 1)
                if at < 0:
                    # keep a tail that may be the start of the next sync
                    keep = 0
                    for k in (3, 2, 1):
                        if len(buf) >= k and buf.endswith(SYNC[:k]):
                            keep = k
                            break
                    at = len(buf) - keep
                events.append(Junk(at, f"{at} bytes that do not start a FOCAS frame"))
                self.junk_bytes += at
                del buf[:at]
                continue
            if len(buf) < HEADER_SIZE:
                break
            _, version, kind, length = HEADER.unpack_from(buf)
            end = HEADER_SIZE + length
            if len(buf) < end:
                break
            events.append(Frame(kind, bytes(buf[HEADER_SIZE:end]), version))
            del buf[:end]
        return events
