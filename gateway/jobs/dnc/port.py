"""The gateway's one adapter for pyserial: open a serial line by device path or URL, read, write, close.

pyserial serves all three places a DNC line can be: a device path (`/dev/ttyUSB0`,
`COM3`), `rfc2217://host:port` and `socket://host:port`, through `serial_for_url`.
Its calls block, and it is used from one thread per line (line.py): the RFC 2217
client runs its own reader thread and its ports have no file descriptor an event
loop could watch, so an asyncio wrapper (pyserial-asyncio) would serve device
paths only. A thread per line is cheap beside a line's pace (at most a few
thousand characters a second) and lets the sender react to a DC3 between two
small writes without waiting for the event loop.

Every pyserial and OS error becomes a `DeliveryError` here, worded for the
operator: "device server 10.0.0.9:4001 unreachable (connection refused)",
"the line dropped (socket disconnected)", "DSR is off".
"""

from __future__ import annotations

import contextlib
import select
import socket
import time
from typing import Protocol, cast

import serial

from gateway.codecs.dnc import LineSettings
from gateway.config.jobs import ControllerSerial
from gateway.errors import DeliveryError

WAIT = 0.05  # s wait() waits at most for a first byte (back at once when one comes); the port never waits
POLL = 0.002  # s between looks in wait() where the port has no descriptor to select on (rfc2217://)

_PARITY = {"none": serial.PARITY_NONE, "even": serial.PARITY_EVEN, "odd": serial.PARITY_ODD}
_LETTER = {"none": "N", "even": "E", "odd": "O"}


class _Port(Protocol):
    """What the line uses of a pyserial port. Every port `serial_for_url` makes (posix `Serial`, the
    socket:// and rfc2217:// classes) has these; the stubs put `dsr` on the
    subclasses only, not on the `SerialBase` it is annotated to return."""

    @property
    def dsr(self) -> bool: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes, /) -> int | None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...


class LineLost(DeliveryError):
    """The line went away during a transfer (dropped connection, device gone, DSR off)."""


def line_settings(settings: ControllerSerial) -> LineSettings:
    """The codec's view of a mapping's serial section."""
    return LineSettings(
        baud=settings.baud,
        data_bits=settings.bytesize,
        parity=_LETTER[settings.parity],  # type: ignore[arg-type]  # N/E/O: the codec's Parity literal
        stop_bits=settings.stopbits,
        handshake=settings.handshake,
        eob=settings.eob,
        leader=settings.leader,
        markers=settings.percent,
        chunk_size=settings.chunk_size,
        software_parity=settings.soft_parity,
    )


def describe(where: str) -> str:
    """Where a line is, for messages: `device server 10.0.0.9:4001`, `/dev/ttyUSB0`."""
    if where.startswith(("socket://", "rfc2217://")):
        return f"device server {where.split('://', 1)[1].rstrip('/')}"
    return where


class SerialPort:
    """One open serial line. Blocking; used from one thread at a time."""

    def __init__(self, settings: ControllerSerial) -> None:
        self.settings = settings
        self.where = settings.where
        self._port: _Port | None = None
        self._dsr = settings.dsr and "://" not in settings.where

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        """Open the line. Raises DeliveryError (not permanent: a device server may come back)."""
        s = self.settings
        soft = s.soft_parity
        url = s.where
        try:
            port = serial.serial_for_url(
                url,
                baudrate=s.baud,
                bytesize=serial.EIGHTBITS if soft else s.bytesize,
                parity=serial.PARITY_NONE if soft else _PARITY[s.parity],
                stopbits=s.stopbits,
                rtscts=s.handshake == "rtscts",
                xonxoff=False,  # the sender does XON/XOFF itself: it must see DC1/DC3 and count them
                timeout=0,  # reads return what is there (in_waiting is 0/1 on socket://, not a count)
                write_timeout=None if s.where.startswith("rfc2217://") else s.connect_timeout,
                do_not_open=True,
            )
            if url.startswith("socket://"):
                # pyserial empties a socket's input as it opens it: what a device server passes on at
                # once (the controller's DC1, the start of a punch) would be lost. A serial device
                # keeps its flush (stale characters from before are the OS buffer's, not the controller's).
                port.reset_input_buffer = _keep_input  # type: ignore[method-assign]
            port.open()
            if url.startswith("socket://"):
                del port.reset_input_buffer  # the class's again
                # Each slice goes out as it is written (pyserial leaves Nagle on): held back until the
                # device server acknowledges the last, slices would reach it in bursts, more of them
                # already on their way when the controller's DC3 comes.
                sock = getattr(port, "_socket", None)
                if sock is not None:
                    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeliveryError(f"{describe(s.where)} unreachable ({_why(exc)})") from None
        self._port = cast(_Port, port)
        try:
            self._fd: int | None = int(port.fileno())  # posix and socket://
        except (AttributeError, NotImplementedError, OSError, ValueError, serial.SerialException):
            self._fd = None  # rfc2217:// reads in a thread of its own: wait() polls

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):  # a line that is already gone
                port.close()

    def _open_port(self) -> _Port:
        if self._port is None:
            raise LineLost("the line is not open")
        return self._port

    def read(self) -> bytes:
        """What the controller sent, without waiting (b"" when nothing). Raises LineLost."""
        port = self._open_port()
        try:
            data: bytes = port.read(4096)
            if self._dsr and not port.dsr:
                raise LineLost("DSR is off: the controller's port is not ready (cable, or power)")
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        return data

    def wait(self, also: int | None = None, timeout: float = WAIT) -> bytes:
        """What the controller sends within `timeout` (back at its first byte, or when descriptor `also`
        becomes readable: another line's grant, fleet.py). Raises LineLost."""
        port = self._open_port()
        try:
            if self._fd is not None:
                select.select([self._fd] if also is None else [self._fd, also], [], [], timeout)
            elif also is not None:
                select.select([also], [], [], min(timeout, POLL))
            else:
                time.sleep(min(timeout, POLL))
            data: bytes = port.read(4096)
            if self._dsr and not port.dsr:
                raise LineLost("DSR is off: the controller's port is not ready (cable, or power)")
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        return data

    def pause(self, seconds: float) -> bool:
        """Let `seconds` pass, back early if the controller sends; whether it may have sent something (a
        port without a descriptor cannot tell: True). Raises LineLost."""
        port = self._open_port()
        if self._fd is None:
            time.sleep(seconds)
            return True
        try:
            readable, _, _ = select.select([self._fd], [], [], seconds)
        except (OSError, ValueError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        if self._dsr and not port.dsr:
            raise LineLost("DSR is off: the controller's port is not ready (cable, or power)")
        return bool(readable)

    def write(self, data: bytes) -> int:
        """Hand bytes to the port; how many it took. Raises LineLost."""
        port = self._open_port()
        try:
            written = port.write(data)
        except serial.SerialTimeoutException:
            raise LineLost(
                "the port took nothing for too long (a device server's connection stalled)"
            ) from None
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        return len(data) if written is None else int(written)

    def flush(self) -> None:
        """Wait until the port has passed on what it was given (device paths; a no-op on sockets)."""
        port = self._open_port()
        try:
            port.flush()
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None


def _keep_input() -> None:
    """Stands in for pyserial's reset_input_buffer while a socket:// port opens."""


def _why(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror.lower()
    text = str(exc).strip()
    # pyserial wraps OS errors as "could not open port …: [Errno 111] Connection refused"
    if "] " in text:
        text = text.rsplit("] ", 1)[1]
    return text.lower() or type(exc).__name__
