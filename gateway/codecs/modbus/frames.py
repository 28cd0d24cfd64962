"""Modbus TCP frames for a server, from the specification (Modbus Application Protocol V1.1b3 and
Modbus Messaging on TCP/IP V1.0b): the MBAP header, the requests of functions 1-6, 15 and 16, their
answers and exception responses.

The gateway's driver reads through pymodbus; this codec is the other side, written independently of
it: the simulator's Modbus face (simulator/modbus_face.py) and the tests' device, which answers the
way odd real devices do (tests/modbus_device.py), are built on it. `EXCEPTIONS` names the exception
codes for both sides: the driver reports a device's refusal by these names.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from enum import IntEnum

from gateway.errors import CodecError

MBAP = struct.Struct(">HHHB")  # transaction id, protocol id (0), length (unit id + PDU), unit id
MAX_PDU = 253
MAX_READ_BITS = 2000
MAX_READ_REGISTERS = 125
MAX_WRITE_BITS = 1968
MAX_WRITE_REGISTERS = 123


class ExceptionCode(IntEnum):
    ILLEGAL_FUNCTION = 1
    ILLEGAL_DATA_ADDRESS = 2
    ILLEGAL_DATA_VALUE = 3
    SERVER_DEVICE_FAILURE = 4
    ACKNOWLEDGE = 5
    SERVER_DEVICE_BUSY = 6
    MEMORY_PARITY_ERROR = 8
    GATEWAY_PATH_UNAVAILABLE = 10
    GATEWAY_TARGET_NO_RESPONSE = 11


# The specification's name of each exception, and the OPC UA status a variable (or a write) gets.
EXCEPTIONS: dict[int, tuple[str, str]] = {
    1: ("ILLEGAL FUNCTION", "BadNotSupported"),
    2: ("ILLEGAL DATA ADDRESS", "BadNodeIdUnknown"),
    3: ("ILLEGAL DATA VALUE", "BadOutOfRange"),
    4: ("SERVER DEVICE FAILURE", "BadDeviceFailure"),
    5: ("ACKNOWLEDGE", "BadWaitingForResponse"),
    6: ("SERVER DEVICE BUSY", "BadResourceUnavailable"),
    8: ("MEMORY PARITY ERROR", "BadDeviceFailure"),
    10: ("GATEWAY PATH UNAVAILABLE", "BadNoCommunication"),
    11: ("GATEWAY TARGET DEVICE FAILED TO RESPOND", "BadTimeout"),
}


def exception_name(code: int) -> str:
    return EXCEPTIONS.get(code, (f"exception {code}", ""))[0]


def exception_status(code: int) -> str:
    return EXCEPTIONS.get(code, ("", "BadDeviceFailure"))[1] or "BadDeviceFailure"


class FrameError(CodecError):
    """Bytes that are not a Modbus TCP frame (the connection cannot be trusted after them)."""


@dataclass(frozen=True, slots=True)
class Adu:
    transaction: int
    unit: int
    pdu: bytes


class FrameReader:
    """Cuts a TCP byte stream into ADUs. `feed()` then iterate; a FrameError leaves the stream unusable."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> Iterator[Adu]:
        self._buffer += data
        while len(self._buffer) >= MBAP.size:
            transaction, protocol, length, unit = MBAP.unpack_from(self._buffer)
            if protocol != 0:
                raise FrameError(f"protocol id {protocol} is not Modbus (0)")
            if not 2 <= length <= MAX_PDU + 1:
                raise FrameError(f"MBAP length {length} is outside 2..{MAX_PDU + 1}")
            total = 6 + length
            if len(self._buffer) < total:
                return
            pdu = bytes(self._buffer[MBAP.size : total])
            del self._buffer[:total]
            yield Adu(transaction, unit, pdu)


def frame(transaction: int, unit: int, pdu: bytes) -> bytes:
    return MBAP.pack(transaction & 0xFFFF, 0, len(pdu) + 1, unit & 0xFF) + pdu


# --- requests --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Read:
    """Functions 1-4: `count` bits or registers from `address`."""

    function: int
    address: int
    count: int


@dataclass(frozen=True, slots=True)
class WriteBits:
    """Functions 5 (one coil) and 15."""

    function: int
    address: int
    values: tuple[bool, ...]


@dataclass(frozen=True, slots=True)
class WriteRegisters:
    """Functions 6 (one register) and 16."""

    function: int
    address: int
    values: tuple[int, ...]


Request = Read | WriteBits | WriteRegisters


class Refused(CodecError):
    """A request answered with an exception response."""

    def __init__(self, function: int, code: ExceptionCode, reason: str) -> None:
        super().__init__(reason)
        self.function = function
        self.code = code


def parse_request(pdu: bytes) -> Request:
    """A request PDU, or Refused with the exception the specification prescribes."""
    if not pdu:
        raise Refused(0, ExceptionCode.ILLEGAL_FUNCTION, "empty PDU")
    function = pdu[0]
    body = pdu[1:]
    if function in (1, 2, 3, 4):
        address, count = _two(function, body, 4)
        limit = MAX_READ_BITS if function in (1, 2) else MAX_READ_REGISTERS
        if not 1 <= count <= limit:
            raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, f"count {count} outside 1..{limit}")
        _in_range(function, address, count)
        return Read(function, address, count)
    if function == 5:
        address, value = _two(function, body, 4)
        if value not in (0x0000, 0xFF00):
            raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, f"coil value {value:#06x}")
        return WriteBits(function, address, (value == 0xFF00,))
    if function == 6:
        address, value = _two(function, body, 4)
        return WriteRegisters(function, address, (value,))
    if function in (15, 16):
        if len(body) < 5:
            raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, "request too short")
        address, count, size = struct.unpack_from(">HHB", body)
        data = body[5:]
        if function == 15:
            if not 1 <= count <= MAX_WRITE_BITS or size != (count + 7) // 8 or len(data) != size:
                raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, "coil count and bytes disagree")
            _in_range(function, address, count)
            bits = tuple(bool(data[i // 8] >> (i % 8) & 1) for i in range(count))
            return WriteBits(function, address, bits)
        if not 1 <= count <= MAX_WRITE_REGISTERS or size != 2 * count or len(data) != size:
            raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, "register count and bytes disagree")
        _in_range(function, address, count)
        return WriteRegisters(function, address, struct.unpack(f">{count}H", data))
    raise Refused(function, ExceptionCode.ILLEGAL_FUNCTION, f"function {function} is not supported")


def _two(function: int, body: bytes, size: int) -> tuple[int, int]:
    if len(body) != size:
        raise Refused(function, ExceptionCode.ILLEGAL_DATA_VALUE, f"request body of {len(body)} bytes")
    first, second = struct.unpack(">HH", body)
    return first, second


def _in_range(function: int, address: int, count: int) -> None:
    if address + count > 0x10000:
        raise Refused(function, ExceptionCode.ILLEGAL_DATA_ADDRESS, f"{address}+{count} past 65535")


# --- responses -------------------------------------------------------------------------------------


def read_bits_response(function: int, bits: Sequence[bool]) -> bytes:
    packed = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            packed[i // 8] |= 1 << (i % 8)
    return bytes((function, len(packed))) + bytes(packed)


def read_registers_response(function: int, registers: Sequence[int]) -> bytes:
    return struct.pack(f">BB{len(registers)}H", function, 2 * len(registers), *registers)


def write_response(request: WriteBits | WriteRegisters) -> bytes:
    """The echo a write gets: address and value (5, 6) or address and count (15, 16)."""
    if request.function == 5:
        return struct.pack(">BHH", 5, request.address, 0xFF00 if request.values[0] else 0)
    if request.function == 6:
        return struct.pack(">BHH", 6, request.address, request.values[0])
    return struct.pack(">BHH", request.function, request.address, len(request.values))


def exception_response(function: int, code: int) -> bytes:
    return bytes((function | 0x80 if function < 0x80 else function, code))
