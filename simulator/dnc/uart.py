"""What a UART makes of characters sent with other settings: the garbage of a misconfigured line.

`resample` puts the sender's characters on a wire as bits (start bit, data bits
LSB first, parity, stop bits, back to back) at the sender's baud rate, and reads
them back the way the receiver's UART would at its own rate and format: wait for
a falling edge, sample each bit in its middle, check the parity and the stop
bits. A wrong baud rate gives the familiar junk and framing errors, a wrong
parity gives parity errors, exactly as on a real line. Pure.

`Coupling` is one connection's path between the controller and the sender:
- a raw-TCP device server of kind `7bit` (the default; a Moxa NPort or Lantronix
  in TCP-server mode with its port set 7E2, as a Fanuc wants it): its UART does
  the parity. Towards the controller it sends the low 7 bits of each TCP byte
  with the right parity bit, whatever bit 7 was; towards TCP it hands on the
  controller's characters as 7-bit bytes (bit 7 = 0), also a character its UART
  received with a parity or framing error (counted);
- a raw-TCP device server of kind `transparent` (its port set 8N1/8N2) and a
  pseudo-terminal carry 8-bit bytes and no parity, so on a 7E/7O line the parity
  bit travels as bit 7 (the sender's software parity; without it the controller
  sees parity errors); a pseudo-terminal also knows the baud rate its user set,
  and a different one is resampled;
- RFC 2217 carries the sender's settings (baud, data bits, parity, stop bits):
  the device server's UART uses them, and any difference is resampled.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from gateway.codecs.dnc import LineSettings


@dataclass(frozen=True, slots=True)
class Frame:
    """A UART's character format and rate."""

    baud: int
    data_bits: int
    parity: str  # N, E, O, M (mark: 1), S (space: 0)
    stop_bits: float  # 1, 1.5, 2

    @classmethod
    def of(cls, line: LineSettings) -> Frame:
        return cls(line.baud, line.data_bits, line.parity, line.stop_bits)

    def transparent(self) -> Frame:
        """The same rate with 8 data bits and no parity: what a transparent port carries."""
        return Frame(self.baud, 8, "N", self.stop_bits)


def _parity_bit(value: int, parity: str) -> int:
    ones = value.bit_count() & 1
    return {"E": ones, "O": ones ^ 1, "M": 1, "S": 0}[parity]


def _bits(data: bytes, frame: Frame) -> list[int]:
    """The wire's level, one entry per bit time at the sender's rate (idle is 1)."""
    bits: list[int] = []
    stop = 2 if frame.stop_bits > 1 else 1
    mask = (1 << frame.data_bits) - 1
    for byte in data:
        value = byte & mask
        bits.append(0)
        bits.extend((value >> i) & 1 for i in range(frame.data_bits))
        if frame.parity != "N":
            bits.append(_parity_bit(value, frame.parity))
        bits.extend([1] * stop)
    return bits


def resample(data: bytes, sender: Frame, receiver: Frame) -> tuple[bytes, int]:
    """The characters the receiver's UART reads from `data` sent with `sender`'s settings, and how many
    of them had a parity or framing error (kept, as a UART hands them over with an error flag)."""
    if sender == receiver:
        return data, 0
    bits = _bits(data, sender)
    bit_time = 1.0 / sender.baud
    sample = 1.0 / receiver.baud
    end = len(bits) * bit_time

    def level(t: float) -> int:
        index = int(t / bit_time)
        return bits[index] if 0 <= index < len(bits) else 1

    out = bytearray()
    errors = 0
    t = 0.0
    step = bit_time / 4  # edge search resolution
    parity = receiver.parity != "N"
    while t < end:
        # Find the next falling edge: idle (1) to start bit (0).
        while t < end and level(t) == 1:
            t += step
        if t >= end:
            break
        start = t
        if level(start + sample / 2) != 0:
            t = start + step  # a glitch, not a start bit
            continue
        value = 0
        for i in range(receiver.data_bits):
            value |= level(start + sample * (1.5 + i)) << i
        position = 1 + receiver.data_bits
        bad = False
        if parity:
            bad = level(start + sample * (position + 0.5)) != _parity_bit(value, receiver.parity)
            position += 1
        if level(start + sample * (position + 0.5)) != 1:
            bad = True  # framing error: no stop bit
        out.append(value)
        errors += bad
        t = start + sample * (position + 1)  # one stop bit is all a receiver waits for
    return bytes(out), errors


PeerFrame = Callable[[], "Frame | None"]


class DeviceServer(StrEnum):
    """What a raw-TCP device server's port does with the characters (see the module's docstring)."""

    SEVEN_BIT = "7bit"  # its UART runs the controller's format and does the parity
    TRANSPARENT = "transparent"  # 8-bit bytes pass as they are; the sender does the parity


KINDS = ("7bit", "transparent", "rfc2217", "pty")
#: A UART's data bits of a byte, by how many it has (bytes.translate tables).
_DATA_BITS = {7: bytes(i & 0x7F for i in range(256)), 8: bytes(range(256))}


class Coupling:
    """One connection between the controller's UART (its `line`) and a sender's port.

    `kind` is one of KINDS: a raw-TCP device server's kind (DeviceServer), rfc2217 or pty. `uart` is a
    7-bit device server's own UART setting when it differs from the controller's (a misconfigured
    device server: its characters are resampled as a real UART would read them)."""

    def __init__(
        self, line: LineSettings, kind: str, peer: PeerFrame | None = None, *, uart: Frame | None = None
    ) -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown link kind {kind!r} (one of {', '.join(KINDS)})")
        if uart is not None and (kind != "7bit" or uart.data_bits not in _DATA_BITS):
            raise ValueError("uart: a 7bit device server's own 7- or 8-bit setting")
        self.line = line
        self.kind = kind
        self._peer = peer
        self._own = Frame.of(line)
        self._uart = uart or self._own
        # On transparent links a 7-bit line with parity puts its parity bit in bit 7.
        self._emulate = kind in ("transparent", "pty") and line.data_bits == 7 and line.parity != "N"
        self._parity_line = LineSettings(
            baud=line.baud, data_bits=7, parity=line.parity if line.parity != "N" else "E",
            stop_bits=line.stop_bits, software_parity=True,
        )  # fmt: skip

    def _frames(self) -> tuple[Frame, Frame]:
        """(the sender's frame, the controller's frame) as the wire between them sees it."""
        peer = self._peer() if self._peer is not None else None
        if self.kind == "rfc2217":
            return (peer or self._own), self._own
        if self.kind == "7bit":
            return self._uart, self._own
        own = self._own.transparent()
        if peer is None:
            return own, own
        return Frame(peer.baud, 8, "N", own.stop_bits), own

    def to_controller(self, data: bytes) -> tuple[bytes, int]:
        """Bytes from the sender -> (characters the controller reads, parity/framing errors)."""
        sender, own = self._frames()
        if self.kind == "7bit":
            # The device server's UART sends the data bits of each byte with its own parity bit.
            return resample(data.translate(_DATA_BITS[sender.data_bits]), sender, own)
        chars, errors = resample(data, sender, own)
        if self._emulate:
            chars, bad = self._parity_line.decode(chars)
            errors += bad
        elif self.line.data_bits == 7:
            chars = chars.translate(_DATA_BITS[7])
        return chars, errors

    def to_sender(self, chars: bytes) -> tuple[bytes, int]:
        """Characters the controller sends -> (the bytes the sender's port reads, how many of them the
        device server's UART received with a parity or framing error and handed on all the same)."""
        if self._emulate:
            chars = self._parity_line.encode(chars)
        sender, own = self._frames()
        out, errors = resample(chars, own, sender)
        if self.kind == "7bit":
            return out.translate(_DATA_BITS[sender.data_bits]), errors
        return out, 0
