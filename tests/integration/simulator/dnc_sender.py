"""A simple, honest DNC sender for tests, on a real pyserial port (socket://, rfc2217://, a pty path).

The gateway's own serial transport comes later; this one is the yardstick the
simulator's DNC face is tested with. It waits for DC1, stops on DC3, and keeps
at most `lead` characters ahead of the line (a token bucket at the line's rate),
so that what it has already handed to the port when a DC3 comes stays small.
The variants are the faults the controller must catch: a sender that ignores
DC3, one that drops the line half way, one too slow to keep a drip feed going.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import serial

from gateway.codecs.dnc import DncSender, LineSettings, ProgramReceived, ProgramReceiver, frame_program
from gateway.codecs.dnc.receiver import ReceiverEvent


def open_port(url: str, line: LineSettings) -> serial.SerialBase:
    """A port set like `line` (pyserial's own settings; software parity is the sender's business)."""
    bytesize = serial.EIGHTBITS if line.software_parity else line.data_bits
    parity = serial.PARITY_NONE if line.software_parity else line.parity
    return serial.serial_for_url(
        url,
        baudrate=line.baud,
        bytesize=bytesize,
        parity=parity,
        stopbits=line.stop_bits,
        timeout=0,  # reads return what is there; rfc2217:// has no write_timeout
    )


@dataclass
class Sent:
    sender: DncSender
    dc3_seen: int
    dc1_seen: int
    closed_early: bool
    heard: bytes = b""  # every byte the port read from the controller, as it came


def send(
    url: str,
    program: bytes,
    line: LineSettings,
    *,
    rate: float,
    lead: int = 8,
    ignore_dc3: bool = False,
    stop_after: int | None = None,
    timeout: float = 60.0,
) -> Sent:
    """Send `program` over `url` at `rate` characters per second (blocking: run it in a thread)."""
    port = open_port(url, line)
    try:
        return _send(port, program, line, rate, lead, ignore_dc3, stop_after, timeout)
    finally:
        port.close()


def _send(
    port: serial.SerialBase,
    program: bytes,
    line: LineSettings,
    rate: float,
    lead: int,
    ignore_dc3: bool,
    stop_after: int | None,
    timeout: float,
) -> Sent:
    sender = DncSender(frame_program(program, line), line)
    wire = line.encode(sender.program.data)
    deadline = time.monotonic() + timeout
    tokens = float(lead)
    last = time.monotonic()
    dc3 = dc1 = 0
    heard = bytearray()
    while not sender.done:
        now = time.monotonic()
        if now > deadline:
            raise AssertionError(f"sending took over {timeout}s ({sender.offset} of {sender.total} bytes)")
        data = port.read(4096)
        heard += data
        for event in sender.feed(data):
            name = type(event).__name__
            dc3 += name == "Pause"
            dc1 += name == "Resume"
        tokens = min(float(lead), tokens + (now - last) * rate)
        last = now
        budget = int(tokens)
        if stop_after is not None:
            if sender.offset >= stop_after:
                return Sent(sender, dc3, dc1, closed_early=True, heard=bytes(heard))
            budget = min(budget, stop_after - sender.offset)
        if ignore_dc3 and not sender.waiting_for_dc1:
            chunk = wire[sender.offset : sender.offset + budget]
        else:
            chunk = sender.next_chunk(budget)
        if chunk:
            written = port.write(chunk) or 0
            if ignore_dc3 and not sender.waiting_for_dc1:
                sender.offset += written  # past the codec: this sender does not care what it may send
            else:
                sender.sent(written)
            tokens -= written
        else:
            time.sleep(0.0005)
    port.flush()
    return Sent(sender, dc3, dc1, closed_early=False, heard=bytes(heard))


def receive(
    url: str, line: LineSettings, *, rate: float, timeout: float = 30.0, answer: bytes | None = None
) -> list[ReceiverEvent]:
    """Read one punched program (strip software parity), then optionally send `answer` (framed) back."""
    port = open_port(url, line)
    try:
        receiver = ProgramReceiver()
        events: list[ReceiverEvent] = []
        deadline = time.monotonic() + timeout
        while not any(isinstance(e, ProgramReceived) for e in events):
            if time.monotonic() > deadline:
                raise AssertionError(f"no program within {timeout}s: {events}")
            data = port.read(4096)
            if data:
                chars, _errors = line.decode(data)
                events += receiver.feed(chars)
            else:
                time.sleep(0.002)
        if answer is not None:
            _send(port, answer, line, rate, 8, False, None, timeout)
        return events
    finally:
        port.close()
