"""The pyserial adapter's socket:// port: what it sets on the connection to a raw TCP device server."""

from __future__ import annotations

import socket

from gateway.transports.dnc.port import SerialPort
from tests.integration.dnc.rig import settings


def test_a_socket_port_sends_each_slice_at_once() -> None:
    """Nagle off: a slice written while the last is unacknowledged goes out now, not with the next."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = SerialPort(settings(f"socket://127.0.0.1:{server.getsockname()[1]}"))
        port.open()
        try:
            conn, _ = server.accept()
            with conn:
                sock = port._port._socket  # type: ignore[union-attr]  # pyserial's, as the adapter sets it
                assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
                assert port.write(b"%\n") == 2
                assert conn.recv(16) == b"%\n"
        finally:
            port.close()
