"""`multipart/x-mixed-replace`, as agents stream /sample?interval=…: parts out of bytes, both ways.

Each part is `--BOUNDARY\\r\\n`, headers, a blank line, the body (its length in
`Content-length`, as the reference agent always sends), `\\r\\n`. The reader takes
the bytes in any chunking and returns complete bodies; it never raises: a part it
cannot read (no length, a length over `max_part`, garbage where a boundary belongs)
puts it in `failed` with the reason, and the caller drops the stream. Memory is
bounded by `max_part`.
"""

from __future__ import annotations

import re

DEFAULT_MAX_PART = 64 << 20
_BOUNDARY = re.compile(r'boundary="?([^";,\s]+)"?', re.IGNORECASE)


def boundary_of(content_type: str) -> str | None:
    """The boundary a Content-Type header names, or None."""
    m = _BOUNDARY.search(content_type)
    return m.group(1) if m else None


def part_head(boundary: str, length: int, content_type: str = "text/xml") -> bytes:
    """What goes before a part's body (the body is followed by CRLF)."""
    return f"--{boundary}\r\nContent-type: {content_type}\r\nContent-length: {length}\r\n\r\n".encode("ascii")


def encode_part(boundary: str, body: bytes, content_type: str = "text/xml") -> bytes:
    return part_head(boundary, len(body), content_type) + body + b"\r\n"


class MultipartReader:
    def __init__(self, boundary: str, *, max_part: int = DEFAULT_MAX_PART) -> None:
        self.delimiter = f"--{boundary}".encode("ascii")
        self.max_part = max_part
        self.failed: str | None = None
        self.parts = 0
        self._buf = bytearray()
        self._length: int | None = None  # the body length of the part whose headers were read

    def feed(self, data: bytes) -> list[bytes]:
        if self.failed is not None:
            return []
        buf = self._buf
        buf += data
        out: list[bytes] = []
        while True:
            if self._length is None and not self._headers():
                break
            length = self._length
            assert length is not None
            if len(buf) < length:
                break
            out.append(bytes(buf[:length]))
            del buf[:length]
            self._length = None
            self.parts += 1
        if self.failed is None and self._length is None and len(buf) > 64 * 1024:
            self.failed = "no part header in the first 64 KiB"
        return out

    def _headers(self) -> bool:
        """Read one part's delimiter and headers if complete; False to wait for more bytes."""
        buf = self._buf
        while buf[:2] == b"\r\n":
            del buf[:2]
        end = buf.find(b"\r\n\r\n")
        if end < 0:
            return False
        head = bytes(buf[:end]).decode("latin-1")
        lines = head.split("\r\n")
        if lines[0].strip() != self.delimiter.decode("ascii"):
            self.failed = f"expected the boundary, got {lines[0][:60]!r}"
            return False
        length: int | None = None
        for line in lines[1:]:
            name, _, value = line.partition(":")
            if name.strip().lower() == "content-length":
                try:
                    length = int(value.strip())
                except ValueError:
                    length = None
        if length is None or length < 0:
            self.failed = "a part without a Content-length"
            return False
        if length > self.max_part:
            self.failed = f"a part of {length} bytes (more than {self.max_part})"
            return False
        del buf[: end + 4]
        self._length = length
        return True
