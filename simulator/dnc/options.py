"""`cnc-simulator`'s DNC options: on by default on the DESIGN's ports 4001 (raw TCP) and 4002 (RFC 2217).

`CNC_SIM_DNC_PORT` and `CNC_SIM_DNC_RFC2217_PORT` change the defaults; `off`
turns a face off. The test suite sets both to `off` (tests/conftest.py), so a
simulator started by a test never takes a fixed port unless the test asks for one.
"""

from __future__ import annotations

import argparse
import os

from gateway.codecs.dnc import LineSettings, LineSettingsError
from simulator.dnc.controller import DncSpec, Mode
from simulator.dnc.face import DEFAULT_RFC2217_PORT, DEFAULT_TCP_PORT, DncFace, DncOptions
from simulator.dnc.uart import DeviceServer
from simulator.machine import OVERRIDE_LIMIT

ENV_TCP = "CNC_SIM_DNC_PORT"
ENV_RFC2217 = "CNC_SIM_DNC_RFC2217_PORT"


def _port_or_off(text: str) -> int | None:
    if text.strip().lower() in ("off", "none", "no"):
        return None
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number (or 'off')") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is outside 0..65535")
    return port


def _default(env: str, port: int) -> int | None:
    value = os.environ.get(env)
    if value is None:
        return port
    try:
        return _port_or_off(value)
    except argparse.ArgumentTypeError:
        return port


def add_dnc_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("serial DNC (RS-232 through a device server)")
    group.add_argument(
        "--dnc-port", type=_port_or_off, default=_default(ENV_TCP, DEFAULT_TCP_PORT), metavar="PORT",
        help="raw TCP device-server port, socket://HOST:PORT "
        f"(default ${ENV_TCP} or {DEFAULT_TCP_PORT}; 'off')",
    )  # fmt: skip
    group.add_argument(
        "--dnc-rfc2217-port", type=_port_or_off, default=_default(ENV_RFC2217, DEFAULT_RFC2217_PORT),
        metavar="PORT",
        help=f"RFC 2217 port, rfc2217://HOST:PORT (default ${ENV_RFC2217} or {DEFAULT_RFC2217_PORT}; 'off')",
    )  # fmt: skip
    group.add_argument(
        "--dnc-pty", action="store_true", help="also offer a pseudo-terminal (its path is printed)"
    )
    group.add_argument("--dnc-baud", type=int, default=9600, help="line baud rate (default 9600)")
    group.add_argument("--dnc-format", default="7E2", help="character format: 7E2 (default), 7N1, 8N1 ...")
    group.add_argument(
        "--dnc-handshake", choices=["xonxoff", "rtscts", "none"], default="xonxoff", help="(default xonxoff)"
    )
    group.add_argument(
        "--dnc-mode", choices=[m.value for m in Mode], default="load", help="load (default) or drip"
    )
    group.add_argument("--dnc-buffer", type=int, default=256, help="receive buffer, bytes (default 256)")
    group.add_argument(
        "--dnc-device-server", choices=[k.value for k in DeviceServer], default=DeviceServer.SEVEN_BIT.value,
        help="the raw TCP port's kind: 7bit (default; a device server set to the line's format, e.g. 7E2: "
        "its UART does the parity, DC1/DC3 arrive as 0x11/0x13) or transparent (8-bit: the parity bit "
        "travels as bit 7, the sender does software parity)",
    )  # fmt: skip
    group.add_argument(
        "--dnc-override", type=int, default=None, metavar="PCT",
        help=f"the machine's feed override at start, 1..{OVERRIDE_LIMIT} %% (default: 100): beyond the "
        "panel's 200 %%, a machine that cuts faster than its programs' F words (a feed is still capped "
        "at the rapid)",
    )  # fmt: skip


def dnc_options(args: argparse.Namespace) -> DncOptions | None:
    """The DNC face the arguments ask for, None if every face is off. Raises ValueError, worded for users."""
    if args.dnc_port is None and args.dnc_rfc2217_port is None and not args.dnc_pty:
        return None
    try:
        line = LineSettings.from_format(
            args.dnc_format, LineSettings(baud=args.dnc_baud, handshake=args.dnc_handshake)
        )
        spec = DncSpec(line=line, mode=Mode(args.dnc_mode), buffer_size=args.dnc_buffer)
        return DncOptions(
            spec, tcp_port=args.dnc_port, rfc2217_port=args.dnc_rfc2217_port, pty=args.dnc_pty,
            device_server=DeviceServer(args.dnc_device_server), override=args.dnc_override,
        )  # fmt: skip
    except (LineSettingsError, ValueError) as exc:
        raise ValueError(f"DNC settings: {exc}") from None


def dnc_banner(face: DncFace) -> list[str]:
    line = face.spec.line
    where = [u for u in (face.socket_url, face.rfc2217_url, face.pty_path) if u]
    lines = [
        f"  DNC      {', '.join(where)}",
        (
            f"           {line.baud} baud {line.format} {line.handshake}, {face.controller.mode.value} mode, "
            f"buffer {face.spec.buffer_size} bytes, feed override {face.machine.override} %"
        ),
    ]
    if face.socket_url:
        lines.append(f"           raw TCP: {_KIND_BANNER[face.device_server]}")
    return lines


_KIND_BANNER = {
    DeviceServer.SEVEN_BIT: "a 7-bit device server (its UART does the parity: no software_parity)",
    DeviceServer.TRANSPARENT: "a transparent 8-bit port (the parity bit as bit 7: software_parity: true)",
}
