"""Multi-command requests (frame type 2101) and their responses (2102).

A request's payload is a count and that many blocks; each block is its length (itself included),
the device (1 CNC, 2 PMC), the path, the function code, five 32-bit arguments and, for functions
that take data (writes, names), the data, whose length the fifth argument carries. A response block
echoes device, path and function, then a 16-bit error code (0: EW_OK), four reserved bytes, the
data length and the data. Several commands in one request are answered in one response, in order:
that is the batching the driver does.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from gateway.codecs.focas.errors import FocasError
from gateway.codecs.focas.frame import SERVER_VERSION, Kind, encode_frame

CNC = 1
PMC = 2
_REQUEST = struct.Struct(">HHHHiiiii")  # length, device, path, function, 5 arguments
_RESPONSE = struct.Struct(">HHHHh4sH")  # length, device, path, function, error, reserved, data length
REQUEST_BLOCK = _REQUEST.size  # 28
RESPONSE_BLOCK = _RESPONSE.size  # 16
MAX_COMMANDS = 255  # a sane cap: the count field could say 65535, nobody sends that many


@dataclass(frozen=True, slots=True)
class Command:
    function: int
    args: tuple[int, int, int, int, int] = (0, 0, 0, 0, 0)
    data: bytes = b""
    device: int = CNC
    path: int = 1


@dataclass(frozen=True, slots=True)
class Reply:
    function: int
    error: int = 0
    data: bytes = b""
    device: int = CNC
    path: int = 1

    def answers(self, command: Command) -> bool:
        return (self.device, self.path, self.function) == (command.device, command.path, command.function)


def command(function: int, *args: int, data: bytes = b"", device: int = CNC, path: int = 1) -> Command:
    """A command with up to five arguments; with data, the fifth is the data's length."""
    a = list(args) + [0] * (5 - len(args))
    if len(a) != 5:
        raise ValueError("a FOCAS command has five arguments")
    if data:
        a[4] = len(data)
    return Command(function, (a[0], a[1], a[2], a[3], a[4]), data, device, path)


def encode_request(commands: Sequence[Command]) -> bytes:
    """The payload of one request frame carrying `commands`."""
    if not 1 <= len(commands) <= MAX_COMMANDS:
        raise ValueError(f"a request carries 1 to {MAX_COMMANDS} commands, not {len(commands)}")
    parts = [struct.pack(">H", len(commands))]
    for c in commands:
        parts.append(_REQUEST.pack(REQUEST_BLOCK + len(c.data), c.device, c.path, c.function, *c.args))
        parts.append(c.data)
    return b"".join(parts)


def request_frame(commands: Sequence[Command]) -> bytes:
    return encode_frame(Kind.REQUEST, encode_request(commands))


def _blocks(payload: bytes, minimum: int, what: str) -> list[memoryview]:
    if len(payload) < 2:
        raise FocasError(f"a {what} of {len(payload)} bytes has no block count")
    (count,) = struct.unpack_from(">H", payload)
    if count == 0 or count > MAX_COMMANDS:
        raise FocasError(f"a {what} says it carries {count} blocks")
    view = memoryview(payload)
    at = 2
    blocks = []
    for index in range(count):
        if at + 2 > len(payload):
            raise FocasError(f"{what} block {index + 1} of {count} is missing (the {what} ends)")
        (length,) = struct.unpack_from(">H", payload, at)
        if length < minimum:
            raise FocasError(f"{what} block {index + 1} says it is {length} bytes, less than {minimum}")
        if at + length > len(payload):
            raise FocasError(
                f"{what} block {index + 1} says it is {length} bytes; {len(payload) - at} are there"
            )
        blocks.append(view[at : at + length])
        at += length
    if at != len(payload):
        raise FocasError(f"{len(payload) - at} bytes after the {count} blocks of a {what}")
    return blocks


def decode_request(payload: bytes) -> list[Command]:
    out = []
    for block in _blocks(payload, REQUEST_BLOCK, "request"):
        _, device, path, function, a1, a2, a3, a4, a5 = _REQUEST.unpack_from(block)
        out.append(Command(function, (a1, a2, a3, a4, a5), bytes(block[REQUEST_BLOCK:]), device, path))
    return out


def encode_response(replies: Sequence[Reply]) -> bytes:
    parts = [struct.pack(">H", len(replies))]
    for r in replies:
        data = b"" if r.error else r.data
        parts.append(
            _RESPONSE.pack(
                RESPONSE_BLOCK + len(data), r.device, r.path, r.function, r.error, bytes(4), len(data)
            )
        )
        parts.append(data)
    return b"".join(parts)


def response_frame(replies: Sequence[Reply], version: int = SERVER_VERSION) -> bytes:
    return encode_frame(Kind.RESPONSE, encode_response(replies), version)


def decode_response(payload: bytes) -> list[Reply]:
    out = []
    for index, block in enumerate(_blocks(payload, RESPONSE_BLOCK - 2, "response")):
        if len(block) < RESPONSE_BLOCK:
            # an error answer may end after the error field (seen from controllers): no data
            if len(block) < 10:
                raise FocasError(f"response block {index + 1} of {len(block)} bytes has no error field")
            _, device, path, function, error = struct.unpack_from(">HHHHh", block)
            if not error:
                raise FocasError(f"response block {index + 1} is {len(block)} bytes: too short for data")
            out.append(Reply(function, error, b"", device, path))
            continue
        _, device, path, function, error, _, size = _RESPONSE.unpack_from(block)
        data = bytes(block[RESPONSE_BLOCK:])
        if size != len(data):
            raise FocasError(
                f"response block {index + 1} says its data is {size} bytes; {len(data)} are there"
            )
        out.append(Reply(function, error, data, device, path))
    return out
