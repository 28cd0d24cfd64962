"""An incremental decoder for the TCP byte stream, h11 style: bytes in, frames out, no I/O.

Any error is final. A byte stream has no resynchronisation marker, so after one
bad header nothing that follows can be trusted. The decoder then keeps the
error, drops its buffer, and refuses further input. The transport's job is to
log the error and close the connection.
"""

from __future__ import annotations

import struct

from gateway.codecs.copydata.errors import CopydataError, DecoderFailed, FrameTooLarge, TruncatedFrame
from gateway.codecs.copydata.frame import Frame
from gateway.codecs.copydata.frames import check_dwdata, decode_lpdata
from gateway.codecs.copydata.layout import TCP_HEADER, Layout

_DWDATA = struct.Struct("<I")
HEADER_SIZE = TCP_HEADER.size


class FrameDecoder:
    """Turns TCP bytes, in any chunking, into Frames.

    Memory is bounded: once a frame header has been checked, the decoder holds at
    most `HEADER_SIZE + layout.max_cbdata` bytes between calls. A cbData over the
    limit is refused as soon as its header arrives, and an unknown dwData as soon
    as its 4 bytes arrive, before any of lpData is buffered.
    """

    def __init__(self, layout: Layout | None = None) -> None:
        self.layout = layout if layout is not None else Layout()
        self._buf = bytearray()
        self._pos = 0  # stream offset of self._buf[0]
        self._error: CopydataError | None = None
        self._ended = False

    @property
    def failed(self) -> CopydataError | None:
        """The error that stopped this decoder, or None while it is healthy."""
        return self._error

    @property
    def buffered(self) -> int:
        """Bytes held for a frame that is not complete yet."""
        return len(self._buf)

    @property
    def position(self) -> int:
        """Stream offset of the next frame: every byte before it has been decoded."""
        return self._pos

    def feed(self, data: bytes) -> list[Frame]:
        """Add bytes from the stream; returns the frames they complete, in order.

        Raises a CopydataError whose offset counts from the first byte ever fed.
        Frames completed in the same call before the fault are on the error's
        `frames`. After an error (or after `feed_eof`), every call raises
        DecoderFailed.
        """
        self._check_usable()
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        offset = 0
        max_cbdata = self.layout.max_cbdata
        try:
            while True:
                available = len(buf) - offset
                if available < _DWDATA.size:
                    break
                (dwdata,) = _DWDATA.unpack_from(buf, offset)
                check_dwdata(dwdata, self._pos + offset)
                if available < HEADER_SIZE:
                    break
                _, cbdata = TCP_HEADER.unpack_from(buf, offset)
                if cbdata > max_cbdata:
                    raise FrameTooLarge(
                        f"cbData {cbdata} is over max_cbdata {max_cbdata}", offset=self._pos + offset + 4
                    )
                end = offset + HEADER_SIZE + cbdata
                if len(buf) < end:
                    break
                try:
                    frames.append(decode_lpdata(dwdata, bytes(buf[offset + HEADER_SIZE : end]), self.layout))
                except CopydataError as exc:
                    start = self._pos + offset
                    raise exc._shift(start + HEADER_SIZE, f"frame at byte {start}") from None
                offset = end
        except CopydataError as exc:
            exc.frames = tuple(frames)
            self._fail(exc)
            raise
        del buf[:offset]
        self._pos += offset
        return frames

    def feed_eof(self) -> None:
        """The peer closed the stream. Raises TruncatedFrame if it stopped inside a frame."""
        self._check_usable()
        self._ended = True
        if self._buf:
            exc = TruncatedFrame(
                f"stream ended {len(self._buf)} bytes into a frame (need at least {self._needed()} bytes)",
                offset=self._pos,
            )
            self._fail(exc)
            raise exc

    def _needed(self) -> int:
        if len(self._buf) < HEADER_SIZE:
            return HEADER_SIZE
        _, cbdata = TCP_HEADER.unpack_from(self._buf, 0)
        return HEADER_SIZE + int(cbdata)

    def _check_usable(self) -> None:
        if self._error is not None:
            raise DecoderFailed(
                f"decoder stopped at an earlier error and cannot resynchronise: {self._error}",
                offset=self._error.offset,
            ) from self._error
        if self._ended:
            raise DecoderFailed("decoder was already told the stream ended", offset=self._pos)

    def _fail(self, exc: CopydataError) -> None:
        self._error = exc
        self._buf = bytearray()
