"""`Simulator`: the machine model, its OPC UA server, its FTP store and the tick that drives them.

Used by the `cnc-simulator` command, by tests and by `cnc-gateway demo`. Each tick
advances the model by the real time elapsed times `speed`, then publishes the
values that changed. The machine's clock (OPC UA SourceTimestamp) is the wall
clock at the tick: a PLC's clock runs in real time however fast the process does.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Self

from gateway.errors import RequestError
from gateway.shims.heap import settled_heap
from simulator.dnc import DncFace, DncOptions
from simulator.errors import SimulatorError
from simulator.focas import DEFAULT_SESSIONS as FOCAS_SESSIONS
from simulator.focas import FocasFace
from simulator.ftp_store import FtpStore
from simulator.haas_mdc import HaasMdcFace
from simulator.machine import Machine, MachineState
from simulator.modbus import Chiller, ModbusFace
from simulator.noise import Noise, NoiseSpec
from simulator.opcua_server import PlcServer, SharedOpcUa, utcnow
from simulator.s7_face import S7Face
from simulator.shdr import ShdrFace
from simulator.store import DirectoryStore
from simulator.variables import Variable, build_variables

log = logging.getLogger("simulator")

DEFAULT_FTP_USER = "cnc"
DEFAULT_FTP_PASSWORD = "simulator"  # a simulator-only default; set CNC_SIM_FTP_PASSWORD elsewhere
LOOP_RESTART_DELAY = 1.0  # s (real time) between the end of a looped program and its restart


class Simulator:
    """Async context manager: starts OPC UA, FTP and the tick task; leaving stops them within a second."""

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        opcua_port: int = 4841,
        ftp_port: int = 2122,
        speed: float = 1.0,
        store: Path | None = None,
        loop_program: str | None = None,
        ftp_user: str | None = None,
        ftp_password: str | None = None,
        tick: float = 0.02,
        opcua_user: str | None = None,
        opcua_password: str | None = None,
        extra_variables: Sequence[Variable] = (),
        clock: Callable[[], datetime] = utcnow,
        noise: NoiseSpec | None = None,
        dnc: DncOptions | None = None,
        shdr_port: int | None = None,
        focas_port: int | None = None,
        focas_sessions: int = FOCAS_SESSIONS,
        haas_port: int | None = None,
        modbus_port: int | None = None,
        s7_port: int | None = None,
        opcua: SharedOpcUa | None = None,
        opcua_folder: str | None = None,
    ) -> None:
        if speed <= 0:
            raise ValueError("speed must be > 0")
        if tick <= 0:
            raise ValueError("tick must be > 0")
        self.host = host
        self.opcua_port = opcua_port
        self.ftp_port = ftp_port
        self.speed = speed
        self.tick = tick
        self.loop_program = loop_program
        self.ftp_user = ftp_user or os.environ.get("CNC_SIM_FTP_USER") or DEFAULT_FTP_USER
        self.ftp_password = ftp_password or os.environ.get("CNC_SIM_FTP_PASSWORD") or DEFAULT_FTP_PASSWORD
        self._given_store = store
        self.store: Path = store if store is not None else Path()
        self.programs = DirectoryStore(self.store)
        self.machine = Machine(self.programs)
        # Benchmark load (simulator/noise.py): extra variables written at a set rate by their own task.
        self.noise: Noise | None = Noise(noise) if noise is not None else None
        self.variables: list[Variable] = build_variables() + list(extra_variables)
        if self.noise is not None:
            self.variables += self.noise.variables
        # The serial DNC face (simulator/dnc): off unless asked for; its variables join the PLC's.
        self.dnc: DncFace | None = None
        if dnc is not None:
            self.dnc = DncFace(dnc.spec, self.machine, self.programs, host=host, tcp_port=dnc.tcp_port,
                               rfc2217_port=dnc.rfc2217_port, pty=dnc.pty, speed=speed,
                               device_server=dnc.device_server, override=dnc.override)  # fmt: skip
            self.variables += self.dnc.variables
        # The MTConnect adapter face (simulator/shdr.py): off unless a port is given (0: any free one).
        self.shdr_port = shdr_port
        self.shdr: ShdrFace | None = None
        # The FOCAS2 face (simulator/focas): off unless a port is given (0: any free one).
        self.focas_port, self.focas_sessions = focas_port, focas_sessions
        self.focas: FocasFace | None = None
        # The Haas MDC face (simulator/haas_mdc.py): off unless a port is given (0: any free one).
        self.haas_port = haas_port
        self.haas: HaasMdcFace | None = None
        # The chiller's Modbus TCP face (simulator/modbus): off unless a port is given (0: any free one).
        self.chiller = Chiller(ambient=self.machine.ambient)
        self.modbus_port = modbus_port
        self.modbus: ModbusFace | None = None
        # The PLC's S7 face (simulator/s7_face.py): off unless a port is given (0: any free one).
        self.s7_port = s7_port
        self.s7: S7Face | None = None
        self._opcua_auth = (opcua_user, opcua_password)
        self._shared_opcua, self.opcua_folder = opcua, opcua_folder  # a fleet's one server, this one's folder
        self.settle_on_exit = True  # a full collection after stopping; a fleet does one for all its machines
        self.clock = clock  # the PLC's clock, which stamps values (SourceTimestamp)
        self._stack: contextlib.AsyncExitStack | None = None
        self._opcua: PlcServer | None = None
        self._idle_since: float | None = None

    @property
    def opcua_endpoint(self) -> str:
        return f"opc.tcp://{self.host}:{self.opcua_port}"

    async def __aenter__(self) -> Self:
        stack = contextlib.AsyncExitStack()
        await stack.__aenter__()
        try:
            with settled_heap():  # its address space out of the collector's sight: no 0.2-s stalls later
                await self._start(stack)
        except BaseException:
            await stack.aclose()
            raise
        self._stack = stack
        return self

    async def _start(self, stack: contextlib.AsyncExitStack) -> None:
        if self._given_store is None:
            self.store = Path(tempfile.mkdtemp(prefix="cnc-simulator-"))
            stack.callback(shutil.rmtree, self.store, ignore_errors=True)
            self.programs = DirectoryStore(self.store)
            self.machine.store = self.programs
            if self.dnc is not None:
                self.dnc.controller.store = self.programs
        try:
            self.programs.prepare()
        except OSError as exc:
            raise SimulatorError(f"cannot use {self.store} as the program store: {exc}") from None
        # Fail fast and in one line (asyncua logs a traceback, after a second of set-up, otherwise).
        if self._shared_opcua is None:
            _check_port(self.host, self.opcua_port, "OPC UA server")
        _check_port(self.host, self.ftp_port, "FTP server")
        user, password = self._opcua_auth
        self._opcua = await stack.enter_async_context(
            PlcServer(
                self.machine,
                self.variables,
                host=self.host,
                port=self.opcua_port,
                user=user,
                password=password,
                clock=self.clock,
                shared=self._shared_opcua,
                folder=self.opcua_folder,
            )
        )
        self.opcua_port = self._opcua.port
        ftp = await stack.enter_async_context(
            FtpStore(
                self.store, host=self.host, port=self.ftp_port, user=self.ftp_user, password=self.ftp_password
            )
        )
        self.ftp_port = ftp.port
        if self.dnc is not None:
            await stack.enter_async_context(self.dnc)
        if self.shdr_port is not None:
            self.shdr = await stack.enter_async_context(
                ShdrFace(self.machine, host=self.host, port=self.shdr_port, clock=self.clock)
            )
        if self.focas_port is not None:
            self.focas = await stack.enter_async_context(
                FocasFace(self.machine, self.programs, host=self.host, port=self.focas_port,
                          sessions=self.focas_sessions)
            )  # fmt: skip
        if self.haas_port is not None:
            self.haas = await stack.enter_async_context(
                HaasMdcFace(self.machine, host=self.host, port=self.haas_port)
            )
        if self.modbus_port is not None:
            self.modbus = await stack.enter_async_context(
                ModbusFace(self.chiller.image, host=self.host, port=self.modbus_port)
            )
        if self.s7_port is not None:
            self.s7 = await stack.enter_async_context(
                S7Face(self.machine, host=self.host, port=self.s7_port, clock=self.clock)
            )
        if self.loop_program:
            try:
                self.machine.select_program(self.loop_program)
                self.machine.start()
            except RequestError as exc:
                raise SimulatorError(f"cannot loop {self.loop_program!r}: {exc.reason}") from None
        task = asyncio.create_task(self._tick_loop(), name="cnc-simulator:tick")
        stack.push_async_callback(_cancel, task)
        if self.noise is not None:
            noise = asyncio.create_task(
                self.noise.run(self._opcua.server, self._opcua.ns), name="cnc-simulator:noise"
            )
            stack.push_async_callback(_cancel, noise)
        log.info(
            "simulator serving OPC UA on %s and FTP on %s:%d (store %s, speed %g)",
            self.opcua_endpoint,
            self.host,
            self.ftp_port,
            self.store,
            self.speed,
        )

    async def __aexit__(self, *exc_info: object) -> None:
        stack, self._stack = self._stack, None
        try:
            if stack is not None:
                await stack.aclose()
        finally:
            if self.settle_on_exit:
                settle_after_stop()

    async def _tick_loop(self) -> None:
        assert self._opcua is not None
        last = time.monotonic()
        while True:
            now = time.monotonic()
            try:
                self.machine.step((now - last) * self.speed)
                if self.modbus is not None:
                    self.chiller.step((now - last) * self.speed, self.machine.laser.power_act)
                if self.s7 is not None:
                    self.s7.publish()
                self._keep_looping(now)
                await self._opcua.publish()
                if self.shdr is not None:
                    self.shdr.publish()
            except Exception:  # a model bug must not stop the server; say so loudly, once per tick
                log.exception("simulator tick failed")
            last = now
            await asyncio.sleep(max(0.0, self.tick - (time.monotonic() - now)))

    def _keep_looping(self, now: float) -> None:
        """With `loop_program`, restart the program about a second after it ends (or after a reset)."""
        if not self.loop_program or self.machine.state is not MachineState.IDLE:
            self._idle_since = None
            return
        if self._idle_since is None:
            self._idle_since = now
        elif now - self._idle_since >= LOOP_RESTART_DELAY:
            self._idle_since = None
            try:
                if self.machine.program.name != self.loop_program:
                    self.machine.select_program(self.loop_program)
                self.machine.start()
            except RequestError as exc:
                log.warning("cannot restart %s: %s", self.loop_program, exc.reason)


def settle_after_stop() -> None:
    """Make what a stopped simulator built collectable, and collect it, without leaving the rest of the
    process's heap in the collector's sight: the demo stops and starts the simulator beside a running
    gateway, whose frozen heap must stay frozen (one full pass now, not one every few seconds later)."""
    gc.unfreeze()
    gc.collect()
    gc.freeze()


def _check_port(host: str, port: int, what: str) -> None:
    """Raise SimulatorError if nothing could listen on host:port (bound the way asyncio binds)."""
    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise SimulatorError(f"{what} cannot listen on {host}:{port}: {exc}") from None
    for family, kind, proto, _name, address in infos:
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind(address)
            except OSError as exc:
                raise SimulatorError(
                    f"{what} cannot listen on {host}:{port}: {exc.strerror or exc}"
                ) from None


async def _cancel(task: asyncio.Task[None]) -> None:
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task
