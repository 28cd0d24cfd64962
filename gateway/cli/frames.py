"""`cnc-gateway frames listen|decode|encode`: tools for whoever connects a nesting package.

- `listen --tcp HOST:PORT` connects to a gateway's tcp-server target and prints
  every frame as it arrives, with variable names from `--mapping`; `--serve`
  listens instead, for a tcp-client target; `--udp [HOST:]PORT` receives a udp
  target's datagrams.
- `decode HEX|FILE|-` takes a captured frame apart byte by byte: TCP framing
  (`dwData | cbData | lpData`, one or more frames), or bare lpData with
  `--dwdata 1|2` (what a WM_COPYDATA receiver sees).
- `encode ID=VALUE …` builds a frame (types from the mapping, or inline as
  `ID:TYPE=VALUE`), prints it as hex, writes it to a file, or sends it to a
  target over TCP or UDP: a quick way to try `accept_writes` or a receiver.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import sys
from datetime import datetime
from pathlib import Path

from gateway.app import run_until_signalled
from gateway.cli.frames_format import (
    Settings,
    UsageError,
    add_layout_options,
    config_failed,
    describe_items,
    fail,
    frame_header,
    frame_json,
    frame_line,
    parse_address,
    read_input,
    settings_from,
)
from gateway.codecs.copydata import (
    DWDATA_MULTI,
    DWDATA_SINGLE,
    TCP_HEADER,
    CopydataError,
    Frame,
    FrameDecoder,
    Item,
    Variable,
    decode_lpdata,
    encode_lpdata,
    pack_tcp,
    unpack_datagram,
)
from gateway.errors import ConfigError, RequestError
from gateway.model.types import TypeSpec, parse_text

RETRY_EVERY = 1.0  # s between attempts to reach the target


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "frames", help="COPYDATA frames: receive them live, decode captured ones, build test ones"
    )
    frames = p.add_subparsers(dest="frames_command", metavar="ACTION", required=True)

    q = frames.add_parser("listen", help="receive a target's frames and print them live")
    how = q.add_mutually_exclusive_group(required=True)
    how.add_argument(
        "--tcp",
        metavar="HOST:PORT",
        help="the tcp-server target to connect to (or, with --serve, where to listen)",
    )
    how.add_argument("--udp", metavar="[HOST:]PORT", help="receive a udp target's datagrams on this address")
    q.add_argument(
        "--serve", action="store_true", help="listen on --tcp for a tcp-client target instead of connecting"
    )
    q.add_argument("--json", action="store_true", help="one JSON object per frame")
    q.add_argument("--count", type=int, default=None, help="stop after this many frames")
    add_layout_options(q)
    q.set_defaults(handler=handle_listen)

    q = frames.add_parser("decode", help="take a captured frame apart: hex, a file, or - for stdin")
    q.add_argument("input", metavar="HEX|FILE|-")
    q.add_argument("--dwdata", type=int, choices=[1, 2], default=None,
                   help="the input is bare lpData (as WM_COPYDATA carries it) with this dwData")  # fmt: skip
    add_layout_options(q)
    q.set_defaults(handler=handle_decode)

    q = frames.add_parser("encode", help="build a frame from ID=VALUE pairs (or PATH=VALUE, ID:TYPE=VALUE)")
    q.add_argument("pairs", nargs="+", metavar="ID=VALUE")
    q.add_argument(
        "--dwdata", type=int, choices=[1, 2], default=None, help="default: 1 for one pair, 2 for more"
    )
    q.add_argument("--lpdata", action="store_true", help="output bare lpData instead of the TCP frame")
    q.add_argument("--send", metavar="HOST:PORT", default=None, help="send the frame to a tcp-server target")
    q.add_argument("--send-udp", metavar="HOST:PORT", default=None, help="send the frame as one UDP datagram")
    q.add_argument("-o", "--output", type=Path, default=None, help="write the bytes to this file")
    add_layout_options(q)
    q.set_defaults(handler=handle_encode)


def _settings(args: argparse.Namespace) -> Settings:
    return settings_from(args)


# --- decode ----------------------------------------------------------------------------------------


def handle_decode(args: argparse.Namespace) -> int:
    try:
        settings = _settings(args)
        data = read_input(args.input)
    except UsageError as exc:
        return fail(str(exc))
    except ConfigError as exc:
        return config_failed(exc)
    layout = settings.layout
    if args.dwdata is not None:
        try:
            frame = decode_lpdata(args.dwdata, data, layout)
        except CopydataError as exc:
            print(f"lpData ({len(data)} bytes) with dwData = {args.dwdata}")
            print(f"error: {exc}", file=sys.stderr)
            return 1
        print(frame_header(frame.dwdata, len(data), None))
        lines = describe_items(settings, frame, 0)
        print("\n".join(lines))
        return 1 if any(": <" in line for line in lines) else 0
    decoder = FrameDecoder(layout)
    error: CopydataError | None = None
    try:
        frames = decoder.feed(data)
        decoder.feed_eof()
    except CopydataError as exc:
        frames, error = list(exc.frames), exc
    offset, bad = 0, False
    for frame in frames:
        cbdata = sum(layout.header.size + len(item.data) for item in frame.items)
        print(frame_header(frame.dwdata, cbdata, offset))
        lines = describe_items(settings, frame, offset + TCP_HEADER.size)
        bad = bad or any(": <" in line for line in lines)
        print("\n".join(lines))
        offset += TCP_HEADER.size + cbdata
    if error is not None:
        print(f"error: {error}", file=sys.stderr)
        return 1
    if not frames:
        return fail("no frame in the input")
    print(f"{len(frames)} frame{'s' if len(frames) != 1 else ''}, {len(data)} bytes")
    return 1 if bad else 0


# --- encode ----------------------------------------------------------------------------------------


def build_frame(settings: Settings, pairs: list[str], dwdata: int | None) -> Frame:
    items: list[Item] = []
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep:
            raise UsageError(f"{pair!r}: expected ID=VALUE, PATH=VALUE or ID:TYPE=VALUE")
        var = _variable(settings, key.strip())
        try:
            value = parse_text(var.type, text)
        except RequestError as exc:  # TypeMismatch, OutOfRange
            raise UsageError(f"{pair!r}: {exc.reason}") from None
        try:
            items.append(var.encode(value, settings.layout))
        except CopydataError as exc:
            raise UsageError(f"{pair!r}: {exc}") from None
    if dwdata == DWDATA_SINGLE and len(items) != 1:
        raise UsageError(f"--dwdata 1 carries exactly one variable, {len(items)} given")
    return Frame(dwdata or (DWDATA_SINGLE if len(items) == 1 else DWDATA_MULTI), tuple(items))


def _variable(settings: Settings, key: str) -> Variable:
    vid_text, colon, type_name = key.partition(":")
    if colon:
        if not vid_text.isdigit():
            raise UsageError(f"{key!r}: expected ID:TYPE, e.g. 6:UInt16")
        try:
            return Variable(int(vid_text), f"id {vid_text}", TypeSpec.parse(type_name))
        except ValueError as exc:
            raise UsageError(f"{key!r}: {exc}") from None
    if key.isdigit():
        var = settings.variable(int(key))
        if var is None:
            raise UsageError(
                f"id {key} has no type: use --mapping, --types {key}=Double or {key}:Double=VALUE"
            )
        return var
    var = settings.by_name(key)
    if var is None:
        where = "the mapping's target" if settings.mapping is not None else "--types (or give --mapping)"
        raise UsageError(f"{key!r} is not a variable with a copydata id in {where}")
    return var


def handle_encode(args: argparse.Namespace) -> int:
    try:
        settings = _settings(args)
        frame = build_frame(settings, args.pairs, args.dwdata)
        data = encode_lpdata(frame, settings.layout) if args.lpdata else pack_tcp(frame, settings.layout)
        tcp = parse_address(args.send, "--send") if args.send else None
        udp = parse_address(args.send_udp, "--send-udp") if args.send_udp else None
    except UsageError as exc:
        return fail(str(exc))
    except ConfigError as exc:
        return config_failed(exc)
    except CopydataError as exc:
        return fail(str(exc))
    if args.output is not None:
        args.output.write_bytes(data)
    else:
        print(data.hex(" "))
    wire = pack_tcp(frame, settings.layout)  # what goes on the network is always the framed form
    try:
        if tcp is not None:
            send_tcp(tcp, wire)
            print(f"sent {len(wire)} bytes to {tcp[0]}:{tcp[1]}", file=sys.stderr)
        if udp is not None:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(wire, udp)
            print(f"sent a {len(wire)}-byte datagram to {udp[0]}:{udp[1]}", file=sys.stderr)
    except OSError as exc:
        print(f"error: cannot send: {exc.strerror or exc}", file=sys.stderr)
        return 1
    return 0


def send_tcp(address: tuple[str, int], wire: bytes, timeout: float = 5.0) -> None:
    """Send, then close our side and read until the gateway closes: it has then taken our frame."""
    with socket.create_connection(address, timeout=timeout) as s:
        s.sendall(wire)
        s.shutdown(socket.SHUT_WR)
        try:
            while s.recv(65536):
                pass
        except TimeoutError:
            pass


# --- listen ----------------------------------------------------------------------------------------


class Printer:
    def __init__(self, settings: Settings, as_json: bool, count: int | None) -> None:
        self.settings = settings
        self.as_json = as_json
        self.count = count
        self.printed = 0
        self.done = asyncio.Event()

    def frame(self, frame: Frame) -> None:
        stamp = datetime.now().strftime("%H:%M:%S.%f")[:-3]
        line = (
            frame_json(self.settings, frame, stamp)
            if self.as_json
            else frame_line(self.settings, frame, stamp)
        )
        print(line, flush=True)
        self.printed += 1
        if self.count is not None and self.printed >= self.count:
            self.done.set()


def note(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


async def read_stream(reader: asyncio.StreamReader, printer: Printer, settings: Settings) -> str:
    decoder = FrameDecoder(settings.layout)
    while True:
        data = await reader.read(65536)
        try:
            if not data:
                decoder.feed_eof()
                return "connection closed"
            frames = decoder.feed(data)
        except CopydataError as exc:
            for frame in exc.frames:
                printer.frame(frame)
            return f"malformed stream: {exc}"
        for frame in frames:
            printer.frame(frame)
            if printer.done.is_set():
                return "done"


async def listen_connect(address: tuple[str, int], printer: Printer, settings: Settings) -> None:
    last = ""
    while not printer.done.is_set():
        try:
            reader, writer = await asyncio.open_connection(*address)
        except OSError as exc:
            reason = exc.strerror or str(exc)
            if reason != last:
                note(
                    f"cannot connect to {address[0]}:{address[1]}: {reason}; retrying every {RETRY_EVERY:g} s"
                )
                last = reason
            await asyncio.sleep(RETRY_EVERY)
            continue
        last = ""
        note(f"connected to {address[0]}:{address[1]}")
        try:
            reason = await read_stream(reader, printer, settings)
        finally:
            writer.close()
        if reason != "done":
            note(f"{reason}; reconnecting")
            await asyncio.sleep(RETRY_EVERY)


async def listen_serve(address: tuple[str, int], printer: Printer, settings: Settings) -> None:
    clients: set[asyncio.Task[None]] = set()

    async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        clients.add(task)
        peer = writer.get_extra_info("peername")
        note(f"gateway connected from {peer[0]}:{peer[1]}")
        try:
            reason = await read_stream(reader, printer, settings)
        except asyncio.CancelledError:
            return  # stopping; asyncio's stream callback would print a traceback for a cancelled task
        finally:
            writer.close()
            clients.discard(task)
        note(f"{peer[0]}:{peer[1]}: {reason}")

    server = await asyncio.start_server(client, *address, reuse_address=True)
    note(f"listening on {address[0]}:{address[1]} for a tcp-client target")
    try:
        async with server:
            await printer.done.wait()
    finally:
        for task in list(clients):
            task.cancel()
        await asyncio.gather(*clients, return_exceptions=True)


async def listen_udp(address: tuple[str, int], printer: Printer, settings: Settings) -> None:
    loop = asyncio.get_running_loop()

    class Receiver(asyncio.DatagramProtocol):
        def datagram_received(self, data: bytes, addr: object) -> None:
            try:
                printer.frame(unpack_datagram(data, settings.layout))
            except CopydataError as exc:
                note(f"datagram from {addr}: {exc}")

    transport, _ = await loop.create_datagram_endpoint(Receiver, local_addr=address)
    note(f"receiving datagrams on {address[0]}:{address[1]}")
    try:
        await printer.done.wait()
    finally:
        transport.close()


def handle_listen(args: argparse.Namespace) -> int:
    try:
        settings = _settings(args)
        if args.udp is not None:
            address = parse_address(args.udp, "--udp", default_host="0.0.0.0")
        else:
            address = parse_address(args.tcp, "--tcp")
    except UsageError as exc:
        return fail(str(exc))
    except ConfigError as exc:
        return config_failed(exc)
    if args.serve and args.udp is not None:
        return fail("--serve goes with --tcp")
    printer = Printer(settings, args.json, args.count)
    if args.udp is not None:
        main = listen_udp(address, printer, settings)
    elif args.serve:
        main = listen_serve(address, printer, settings)
    else:
        main = listen_connect(address, printer, settings)
    try:
        asyncio.run(run_until_signalled(main))
    except OSError as exc:
        print(f"error: {exc.strerror or exc}", file=sys.stderr)
        return 1
    return 0
