"""`DncFace`: the simulator's serial DNC port, reachable as device servers and a pty. Async context manager.

It owns the controller model (controller.py), the listeners (links.py) and one
task that paces the line: it advances the model to the wall clock whenever
bytes arrive, a character falls due, or the machine took a block, and writes
what the controller sends. Its state is published as PLC variables under
`Objects/PLC/Tasks/DNC` (node ids `::DNC:<name>`), with writable commands:
`punch` and `request` (write a program name), `arm` (the operator starts a
read), `mode` (load or drip).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Self

from simulator.dnc.controller import DncController, DncSpec, WritableStore
from simulator.dnc.links import Link, PtyLink, TcpServer
from simulator.dnc.uart import Coupling, DeviceServer
from simulator.errors import SimulatorError
from simulator.machine import OVERRIDE_LIMIT, Machine
from simulator.variables import Variable

log = logging.getLogger("simulator.dnc")

IDLE_WAKE = 0.05  # s: the model looks at the machine (Reset, end of a drip program) at least this often
DEFAULT_TCP_PORT = 4001  # a Moxa NPort's first port in TCP-server mode
DEFAULT_RFC2217_PORT = 4002


@dataclass(frozen=True, slots=True)
class DncOptions:
    """The DNC face as `Simulator(dnc=...)` starts it: the controller's setup and where it listens.

    A port of None leaves that face off; 0 picks a free port (tests). `device_server` is the raw TCP
    port's kind (uart.DeviceServer: `7bit` as a device server set 7E2 is, or `transparent`); `override`
    the machine's feed override at start, in %, up to machine.OVERRIDE_LIMIT (None: as it is)."""

    spec: DncSpec = field(default_factory=DncSpec)
    tcp_port: int | None = DEFAULT_TCP_PORT
    rfc2217_port: int | None = DEFAULT_RFC2217_PORT
    pty: bool = False
    device_server: DeviceServer = DeviceServer.SEVEN_BIT
    override: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "device_server", DeviceServer(self.device_server))
        if self.override is not None and not 1 <= self.override <= OVERRIDE_LIMIT:
            raise ValueError(f"feed override {self.override} % is outside 1..{OVERRIDE_LIMIT} %")


class DncFace:
    """The serial DNC face of one simulated controller."""

    def __init__(
        self,
        spec: DncSpec,
        machine: Machine,
        store: WritableStore,
        *,
        host: str = "127.0.0.1",
        tcp_port: int | None = None,
        rfc2217_port: int | None = None,
        pty: bool = False,
        speed: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        device_server: DeviceServer = DeviceServer.SEVEN_BIT,
        override: int | None = None,
    ) -> None:
        self.spec = spec
        self.host = host
        self.tcp_port = tcp_port
        self.rfc2217_port = rfc2217_port
        self.use_pty = pty
        self.device_server = DeviceServer(device_server)
        self.clock = clock
        self.controller = DncController(spec, machine, store, speed=speed, on_change=self.kick)
        self.machine = machine
        if override is not None:
            machine.set_override(override, limit=OVERRIDE_LIMIT)
        self.pty_path = ""
        self._link: Link | None = None
        self._waiter: asyncio.Future[None] | None = None
        self._stack: contextlib.AsyncExitStack | None = None
        self.variables = _variables(self)

    # --- where it listens ------------------------------------------------------------------------

    @property
    def socket_url(self) -> str | None:
        return None if self.tcp_port is None else f"socket://{self.host}:{self.tcp_port}"

    @property
    def rfc2217_url(self) -> str | None:
        return None if self.rfc2217_port is None else f"rfc2217://{self.host}:{self.rfc2217_port}"

    async def __aenter__(self) -> Self:
        stack = contextlib.AsyncExitStack()
        await stack.__aenter__()
        try:
            for rfc2217, port in ((False, self.tcp_port), (True, self.rfc2217_port)):
                if port is None:
                    continue
                server = TcpServer(
                    self, self.spec.line, host=self.host, tcp_port=port, rfc2217=rfc2217,
                    device_server=self.device_server,
                )  # fmt: skip
                try:
                    bound = (await stack.enter_async_context(server)).port
                except OSError as exc:
                    what = "RFC 2217" if rfc2217 else "raw TCP"
                    raise SimulatorError(
                        f"DNC {what} server cannot listen on {self.host}:{port}: {exc.strerror or exc}"
                    ) from None
                if rfc2217:
                    self.rfc2217_port = bound
                else:
                    self.tcp_port = bound
            if self.use_pty:
                self.pty_path = (await stack.enter_async_context(PtyLink(self, self.spec.line))).path
            task = asyncio.create_task(self._run(), name="cnc-simulator:dnc")
            stack.push_async_callback(_cancel, task)
        except BaseException:
            await stack.aclose()
            raise
        self._stack = stack
        where = [u for u in (self.socket_url, self.rfc2217_url, self.pty_path) if u]
        log.info(
            "DNC %s %s, %s mode, on %s (raw TCP: a %s device server), feed override %d %%",
            self.spec.line.baud,
            self.spec.line.format,
            self.controller.mode.value,
            ", ".join(where) or "no link",
            self.device_server.value,
            self.machine.override,
        )
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        stack, self._stack = self._stack, None
        if self._link is not None:
            self._link.close()
        if stack is not None:
            await stack.aclose()

    # --- links (links.Port) ----------------------------------------------------------------------

    def link_up(self, link: Link, coupling: Coupling) -> bool:
        if not self.controller.connect(coupling, link.name, self.clock()):
            return False
        self._link = link
        log.info("DNC link up: %s", link.name)
        return True

    def link_data(self, link: Link, data: bytes) -> None:
        if link is not self._link:
            return
        self.controller.feed(data, self.clock())
        if self.controller.wire_room() <= 0:
            link.pause()  # the device server's buffer is full: TCP (or the pty) holds the sender
        self.kick()

    def link_down(self, link: Link) -> None:
        if link is not self._link:
            return
        self._link = None
        self.controller.disconnect(self.clock())
        log.info("DNC link down: %s", link.name)

    # --- the pacing task -------------------------------------------------------------------------

    def kick(self) -> None:
        """Something changed: advance the model now."""
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        controller = self.controller
        while True:
            self._waiter = loop.create_future()
            try:
                now = self.clock()
                controller.advance(now)
                out = controller.take_output()
                link = self._link
                if link is not None:
                    if out:
                        link.write(out)
                    if link.paused and controller.wire_room() > 0:
                        link.resume()
                due = controller.next_due(now)
            except Exception:  # a model bug must not stop the face; say so loudly
                log.exception("DNC face step failed")
                due = None
            delay = IDLE_WAKE if due is None else min(IDLE_WAKE, max(0.0, due - self.clock()))
            handle = loop.call_later(delay, _wake, self._waiter)
            try:
                await self._waiter
            finally:
                handle.cancel()

    # --- commands (also the PLC variables' setters) ----------------------------------------------

    def punch(self, name: str) -> None:
        self.controller.punch(name)

    def drop_link(self) -> bool:
        """Cut the connected link (a device server losing its network, a cable pulled); False if none."""
        link = self._link
        if link is None:
            return False
        link.close()
        return True

    def request(self, name: str) -> None:
        self.controller.request(name)

    def arm(self) -> None:
        self.controller.arm()

    def set_mode(self, mode: str) -> None:
        self.controller.set_mode(mode)

    def stats(self) -> dict[str, Any]:
        """Everything the tests and benchmarks read, in one dict."""
        c = self.controller
        s = c.stats
        return {
            "stage": c.stage.value,
            "mode": c.mode.value,
            "link": c.link,
            "buffer_level": c.buffer_level,
            "device_server": self.device_server.value,
            "override": self.machine.override,
            "starvations": self.machine.starvations,
            "after_dc3_episodes": list(c.episodes),
            **{name: getattr(s, name) for name in s.__dataclass_fields__},
        }


def _wake(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


async def _cancel(task: asyncio.Task[None]) -> None:
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


def _variables(face: DncFace) -> list[Variable]:
    """The face's PLC variables (read with the machine argument ignored: they read the face)."""
    c = face.controller
    s = c.stats

    def counter(node: str, read: Callable[[], int], description: str) -> Variable:
        return Variable(f"::DNC:{node}", "UInt32", lambda _m: read(), description=description)

    def command(action: Callable[[str], None]) -> Callable[[Machine, Any], None]:
        def write(_machine: Machine, value: Any) -> None:
            if value:
                action(str(value))
                face.kick()

        return write

    def arm(_machine: Machine, value: Any) -> None:
        if value:
            face.arm()
            face.kick()

    return [
        Variable(
            "::DNC:state",
            "String",
            lambda _m: c.stage.value,
            description="offline, idle, reading, receiving, buffering, running, punching, alarm",
        ),
        Variable("::DNC:mode", "String", lambda _m: c.mode.value, command(face.set_mode), "load or drip"),
        Variable("::DNC:link", "String", lambda _m: c.link, description="The connected link, empty if none"),
        Variable("::DNC:connected", "Boolean", lambda _m: c.connected),
        Variable("::DNC:line", "String", lambda _m: f"{c.line.baud} {c.line.format} {c.line.handshake}"),
        counter("bufferLevel", lambda: c.buffer_level, "Bytes in the receive buffer"),
        counter("rxChars", lambda: s.rx_chars, "Characters received"),
        counter("txChars", lambda: s.tx_chars, "Characters punched"),
        counter("dc3Sent", lambda: s.dc3_sent, "DC3 (XOFF) sent"),
        counter("dc1Sent", lambda: s.dc1_sent, "DC1 (XON) sent"),
        counter("afterDc3Last", lambda: s.after_dc3_last, "Characters received after the last DC3"),
        counter("afterDc3Max", lambda: s.after_dc3_max, "Most characters received after one DC3"),
        counter("parityErrors", lambda: s.parity_errors, "Parity and framing errors"),
        counter(
            "deviceErrors",
            lambda: s.device_errors,
            "Characters the device server's UART received with an error and passed on",
        ),
        counter("overflows", lambda: s.overflows, "Receive buffer overflows (alarm 087)"),
        counter("lineDrops", lambda: s.line_drops, "Lines dropped during a transfer (alarm 086)"),
        counter("starvations", lambda: face.machine.starvations, "Drip feed ran dry while running"),
        counter("programsLoaded", lambda: s.programs_loaded, "Programs stored in load mode"),
        Variable("::DNC:lastLoaded", "String", lambda _m: s.last_loaded, description="Last program stored"),
        Variable(
            "::DNC:punch", "String", lambda _m: "", command(face.punch), "Write a program name: punch it"
        ),
        Variable(
            "::DNC:request",
            "String",
            lambda _m: "",
            command(face.request),
            "Write a program name: send a remote request for it",
        ),
        Variable(
            "::DNC:requestReply",
            "String",
            lambda _m: s.request_reply,
            description="Comment of the last answer to a remote request",
        ),
        Variable("::DNC:arm", "Boolean", lambda _m: False, arm, "Write true: start a read (DC1)"),
    ]
