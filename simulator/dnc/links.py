"""Where the controller's serial port can be reached: a device server (raw TCP, RFC 2217) or a pty.

- raw TCP, like a Moxa NPort in TCP-server mode (`socket://host:4001` for pyserial), of a kind
  (uart.DeviceServer): `7bit` (its port set to the controller's 7E2: the UART does the parity) or
  `transparent` (8N1/8N2: the parity bit travels as bit 7; uart.Coupling emulates a 7-bit parity line);
- RFC 2217 (`rfc2217://host:4002`): Telnet with COM-port control; pyserial's
  `serial.rfc2217.PortManager` answers the client's settings, which the
  controller's UART then sees (a wrong setting garbles the line);
- a pseudo-terminal pair: the gateway opens the slave path with pyserial as a
  real device; its baud rate is seen through the master (Linux ptys keep no
  parity or data bits: those travel as bit 7, like raw TCP).

Each link is one connection at a time: the port has one cable. Every link
reports to the face through the `Port` protocol (feed, connect, disconnect) and
is written to with `write`. serial's RFC 2217 machinery is used only here.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import termios
import tty
from typing import Protocol, Self, cast

from serial.rfc2217 import PortManager, Serial

from gateway.codecs.dnc import LineSettings
from simulator.dnc.uart import Coupling, DeviceServer, Frame

log = logging.getLogger("simulator.dnc")

PTY_POLL = 0.05  # s between looks for a gateway opening the pty
_READ = 4096


class Link(Protocol):
    name: str

    def write(self, data: bytes) -> None: ...

    def pause(self) -> None: ...

    def resume(self) -> None: ...

    @property
    def paused(self) -> bool: ...

    def close(self) -> None: ...


class Port(Protocol):
    """The face's side of a link."""

    def link_up(self, link: Link, coupling: Coupling) -> bool: ...

    def link_data(self, link: Link, data: bytes) -> None: ...

    def link_down(self, link: Link) -> None: ...


# --- raw TCP ---------------------------------------------------------------------------------------


class _TcpLink(asyncio.Protocol):
    kind = "tcp"

    def __init__(self, port: Port, line: LineSettings, device_server: DeviceServer) -> None:
        self.port = port
        self.line = line
        self.device_server = device_server
        self.name = "tcp"
        self.transport: asyncio.Transport | None = None
        self._paused = False
        self.active = False

    def coupling(self) -> Coupling:
        return Coupling(self.line, self.device_server.value)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        peer = transport.get_extra_info("peername")
        self.name = f"{self.kind} {peer[0]}:{peer[1]}" if peer else self.kind
        self.active = self.port.link_up(self, self.coupling())
        if not self.active:
            log.warning("DNC %s refused: the port already has a link", self.name)
            transport.close()

    def data_received(self, data: bytes) -> None:
        if self.active:
            self.port.link_data(self, data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.active:
            self.active = False
            self.port.link_down(self)

    def write(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def pause(self) -> None:
        if self.transport is not None and not self._paused:
            self._paused = True
            self.transport.pause_reading()

    def resume(self) -> None:
        if self.transport is not None and self._paused:
            self._paused = False
            with contextlib.suppress(RuntimeError):
                self.transport.resume_reading()

    @property
    def paused(self) -> bool:
        return self._paused

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


# --- RFC 2217 --------------------------------------------------------------------------------------


class _PortState:
    """What pyserial's PortManager reads and sets: the settings the client asked for, and the modem lines."""

    def __init__(self, line: LineSettings) -> None:
        self.baudrate = line.baud
        self.bytesize = line.data_bits
        self.parity = line.parity
        self.stopbits: float = line.stop_bits
        self.xonxoff = line.handshake == "xonxoff"
        self.rtscts = line.handshake == "rtscts"
        self.dtr = True
        self.rts = True
        self.break_condition = False
        # The controller's side of the modem lines: powered and ready.
        self.cts = True
        self.dsr = True
        self.ri = False
        self.cd = True

    def reset_input_buffer(self) -> None:
        """Purge: nothing is held back on the controller's side of the device server."""

    def reset_output_buffer(self) -> None:
        """Purge: the bytes in flight are already the controller's (as on a real line)."""

    def frame(self) -> Frame:
        return Frame(int(self.baudrate), int(self.bytesize), str(self.parity), float(self.stopbits))


class _Rfc2217Link(_TcpLink):
    kind = "rfc2217"

    def __init__(self, port: Port, line: LineSettings, device_server: DeviceServer) -> None:
        super().__init__(port, line, device_server)  # RFC 2217 sets the UART itself: the kind is unused
        self.state = _PortState(line)
        self.manager: PortManager | None = None

    def coupling(self) -> Coupling:
        return Coupling(self.line, "rfc2217", self.state.frame)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        # PortManager only touches the settings and modem lines of its "serial", and only calls
        # `write` on its "connection": these stand in for the real port and socket (duck typing).
        self.manager = PortManager(cast(Serial, self.state), cast(Serial, _Raw(transport)))
        super().connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if not self.active or self.manager is None:
            return
        plain = b"".join(self.manager.filter(data))
        if plain:
            self.port.link_data(self, plain)

    def write(self, data: bytes) -> None:
        super().write(data.replace(b"\xff", b"\xff\xff"))  # Telnet's IAC doubled


class _Raw:
    """PortManager's `connection`: Telnet answers go straight to the socket."""

    def __init__(self, transport: asyncio.Transport) -> None:
        self.transport = transport

    def write(self, data: bytes) -> None:
        if not self.transport.is_closing():
            self.transport.write(data)


class TcpServer:
    """A listening device-server port (raw TCP or RFC 2217). Async context manager."""

    def __init__(
        self,
        port: Port,
        line: LineSettings,
        *,
        host: str,
        tcp_port: int,
        rfc2217: bool,
        device_server: DeviceServer = DeviceServer.SEVEN_BIT,
    ) -> None:
        self.port_handler = port
        self.line = line
        self.device_server = device_server
        self.host = host
        self.port = tcp_port
        self.rfc2217 = rfc2217
        self._server: asyncio.Server | None = None

    async def __aenter__(self) -> Self:
        loop = asyncio.get_running_loop()
        kind = _Rfc2217Link if self.rfc2217 else _TcpLink

        def factory() -> asyncio.Protocol:
            return kind(self.port_handler, self.line, self.device_server)

        self._server = await loop.create_server(factory, self.host, self.port, reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None


# --- pseudo-terminal -------------------------------------------------------------------------------

_BAUDS = {
    getattr(termios, f"B{rate}"): rate
    for rate in (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400,
                 57600, 115200, 230400, 460800, 921600)
    if hasattr(termios, f"B{rate}")
}  # fmt: skip


class PtyLink:
    """The controller's end (master) of a pseudo-terminal; the gateway opens `path`. Async context manager.

    A pty has no carrier: the master reads EIO while no one holds the slave open,
    so the link polls for a gateway, and a gateway that closes the slave drops the line.
    """

    def __init__(self, port: Port, line: LineSettings) -> None:
        self.port_handler = port
        self.line = line
        self.path = ""
        self.name = "pty"
        self._master = -1
        self._up = False
        self._paused = False
        self._reading = False
        self._pending = bytearray()
        self._poller: asyncio.Task[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    async def __aenter__(self) -> Self:
        self._loop = asyncio.get_running_loop()
        master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self.name = f"pty {self.path}"
        os.close(slave)
        os.set_blocking(master, False)
        self._master = master
        self._poller = asyncio.create_task(self._poll(), name="cnc-simulator:dnc-pty")
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._poller is not None:
            self._poller.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._poller
        self._stop_reading()
        if self._up:
            self._up = False
            self.port_handler.link_down(self)
        if self._master >= 0:
            os.close(self._master)
            self._master = -1

    def _peer(self) -> Frame | None:
        try:
            speed = termios.tcgetattr(self._master)[5]
        except (termios.error, OSError):
            return None
        baud = _BAUDS.get(speed)
        return None if baud is None else Frame(baud, 8, "N", self.line.stop_bits)

    async def _poll(self) -> None:
        while True:
            if not self._up:
                self._try_connect()
            await asyncio.sleep(PTY_POLL)

    def _try_connect(self) -> None:
        try:
            data = os.read(self._master, _READ)
        except BlockingIOError:
            data = b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return  # nobody holds the slave
            raise
        self._up = self.port_handler.link_up(self, Coupling(self.line, "pty", self._peer))
        if not self._up:
            return
        if data:
            self.port_handler.link_data(self, data)
        self._start_reading()

    def _start_reading(self) -> None:
        if not self._reading and self._loop is not None and not self._paused:
            self._loop.add_reader(self._master, self._readable)
            self._reading = True

    def _stop_reading(self) -> None:
        if self._reading and self._loop is not None:
            self._loop.remove_reader(self._master)
            self._reading = False

    def _readable(self) -> None:
        try:
            data = os.read(self._master, _READ)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                log.warning("pty read failed: %s", exc)
            self._drop()
            return
        if data:
            self.port_handler.link_data(self, data)

    def _drop(self) -> None:
        self._stop_reading()
        self._pending.clear()
        if self._up:
            self._up = False
            self.port_handler.link_down(self)

    def write(self, data: bytes) -> None:
        if not self._up:
            return
        self._pending += data
        self._flush()

    def _flush(self) -> None:
        while self._pending:
            try:
                n = os.write(self._master, self._pending)
            except BlockingIOError:
                if self._loop is not None:
                    self._loop.add_writer(self._master, self._writable)
                return
            except OSError:
                self._drop()
                return
            del self._pending[:n]

    def _writable(self) -> None:
        if self._loop is not None:
            self._loop.remove_writer(self._master)
        self._flush()

    def pause(self) -> None:
        self._paused = True
        self._stop_reading()

    def resume(self) -> None:
        self._paused = False
        if self._up:
            self._start_reading()

    @property
    def paused(self) -> bool:
        return self._paused

    def close(self) -> None:
        self._drop()
