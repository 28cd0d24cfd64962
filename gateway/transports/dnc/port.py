"""The gateway's one adapter for pyserial: open a serial line by device path or URL, read, write, close.

pyserial serves all three places a DNC line can be: a device path (`/dev/ttyUSB0`,
`COM3`), `rfc2217://host:port` and `socket://host:port`, through `serial_for_url`.
Every serial line of a gateway is served by one I/O thread (lineio.py), so
nothing here waits once the port is open: `read` returns what is there, `write`
takes what the port takes now (device paths and sockets are non-blocking), and
`fileno` gives the descriptor the thread's selector watches. An rfc2217:// port
has none (pyserial's RFC 2217 client reads in a thread of its own): the thread
looks at it on a short timer instead. Opening a port may wait (a TCP connect,
the RFC 2217 negotiation): the caller runs `open` off the I/O thread.

On socket:// the adapter reads and writes pyserial's socket itself: pyserial's
non-blocking read costs two selects per call, and a line that writes a slice every
few milliseconds pays that hundreds of times a second.

Every pyserial and OS error becomes a `DeliveryError` here, worded for the
operator: "device server 10.0.0.9:4001 unreachable (connection refused)",
"the line dropped (socket disconnected)", "DSR is off".
"""

from __future__ import annotations

import contextlib
import socket
import struct
import sys
from typing import Protocol, cast

import serial

from gateway.codecs.dnc import LineSettings
from gateway.errors import DeliveryError
from gateway.transports.dnc.config import ControllerSerial

READ_SIZE = 4096

_PARITY = {"none": serial.PARITY_NONE, "even": serial.PARITY_EVEN, "odd": serial.PARITY_ODD}
_LETTER = {"none": "N", "even": "E", "odd": "O"}


class _Port(Protocol):
    """What the line uses of a pyserial port. Every port `serial_for_url` makes (posix `Serial`, the
    socket:// and rfc2217:// classes) has these; the stubs put `dsr` on the
    subclasses only, not on the `SerialBase` it is annotated to return."""

    @property
    def dsr(self) -> bool: ...

    @property
    def out_waiting(self) -> int: ...

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
        software_parity=settings.software_parity,
    )


def describe(where: str) -> str:
    """Where a line is, for messages: `device server 10.0.0.9:4001`, `/dev/ttyUSB0`."""
    if where.startswith(("socket://", "rfc2217://")):
        return f"device server {where.split('://', 1)[1].rstrip('/')}"
    return where


class SerialPort:
    """One open serial line. Non-blocking once open; used from one thread at a time."""

    def __init__(self, settings: ControllerSerial) -> None:
        self.settings = settings
        self.where = settings.where
        self._port: _Port | None = None
        self._socket: socket.socket | None = None  # socket:// lines: pyserial's socket, read and written here
        self._fd: int | None = None
        self._dsr = settings.dsr and "://" not in settings.where

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        """Open the line (may wait: run it off the I/O thread). Raises DeliveryError (not permanent: a
        device server may come back)."""
        s = self.settings
        soft = s.software_parity
        url = s.where
        rfc2217 = url.startswith("rfc2217://")
        try:
            port = serial.serial_for_url(
                url,
                baudrate=s.baud,
                bytesize=serial.EIGHTBITS if soft else s.bytesize,
                parity=serial.PARITY_NONE if soft else _PARITY[s.parity],
                stopbits=s.stopbits,
                rtscts=s.handshake == "rtscts",
                xonxoff=False,  # the sender does XON/XOFF itself: it must see DC1/DC3 and count them
                timeout=0,  # reads return what is there
                write_timeout=None if rfc2217 else 0,  # writes take what the port takes now
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
                sock = cast(socket.socket, port._socket)  # type: ignore[attr-defined]  # the url handler's
                # Each slice goes out as it is written (pyserial leaves Nagle on): held back until the
                # device server acknowledges the last, slices would reach it in bursts, more of them
                # already on their way when the controller's DC3 comes.
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setblocking(False)
                self._socket = sock
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeliveryError(f"{describe(s.where)} unreachable ({_why(exc)})") from None
        self._port = cast(_Port, port)
        self._fd = None
        if not rfc2217:
            with contextlib.suppress(AttributeError, NotImplementedError, OSError, ValueError):
                self._fd = int(port.fileno())

    def fileno(self) -> int | None:
        """The descriptor the I/O thread selects on; None for rfc2217:// (looked at on a timer)."""
        return self._fd

    def close(self) -> None:
        port, self._port, self._socket, self._fd = self._port, None, None, None
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
        sock = self._socket
        try:
            if sock is not None:
                try:
                    data = sock.recv(READ_SIZE)
                except (BlockingIOError, InterruptedError):
                    return b""
                if not data:
                    raise LineLost("the line dropped (socket disconnected)")
                return data
            data = port.read(READ_SIZE)
            if self._dsr and not port.dsr:
                raise LineLost("DSR is off: the controller's port is not ready (cable, or power)")
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        return data

    def write(self, data: bytes) -> int:
        """Hand bytes to the port without waiting; how many it took (0 when its buffer is full). Raises
        LineLost."""
        port = self._open_port()
        sock = self._socket
        try:
            if sock is not None:
                try:
                    return sock.send(data)
                except (BlockingIOError, InterruptedError):
                    return 0
            written = port.write(data)
        except serial.SerialTimeoutException:
            return 0
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        return len(data) if written is None else int(written)

    def unsent(self) -> int:
        """Bytes the OS still holds for the line (a device's output queue, a socket's unsent bytes): a load
        is over when they are out. 0 where it cannot tell (rfc2217://). Raises LineLost."""
        port = self._open_port()
        try:
            if self._socket is not None:
                return _socket_unsent(self._socket)
            if self._fd is not None:
                return int(port.out_waiting)
        except (serial.SerialException, OSError) as exc:
            raise LineLost(f"the line dropped ({_why(exc)})") from None
        return 0


def _socket_unsent(sock: socket.socket) -> int:
    """A TCP socket's bytes not yet acknowledged by the device server (Linux's SIOCOUTQ, the same request
    number as TIOCOUTQ); 0 where the OS has no such request."""
    if sys.platform == "win32":
        return 0
    import fcntl
    import termios

    raw = fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, struct.pack("I", 0))
    return int(struct.unpack("I", raw)[0])


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
