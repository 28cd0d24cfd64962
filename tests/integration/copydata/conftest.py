"""The simulator, a gateway on laser-sim.yaml with the COPYDATA targets a test asks for, and receivers.

Receivers are what a nesting package's developer would write from docs/copydata.md: a TCP
client (for a tcp-server target), a TCP listener (for a tcp-client target), a UDP socket.
They decode with the gateway's codec and the target's own id table.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from gateway.app import Gateway
from gateway.codecs.copydata import Frame, FrameDecoder, Item, Layout, VariableTable, pack_tcp
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.model.context import WriteContext
from gateway.model.tree import Machine
from gateway.settings.access import AccessConfig
from gateway.sinks.copydata.config import MachineCopydata
from gateway.sinks.copydata.emitter import Emitter
from gateway.sinks.copydata.sink import CopydataSink
from gateway.sinks.copydata.tcp import TcpServerTransport
from gateway.sinks.mqtt.config import MqttConfig
from gateway.sinks.opcua.config import OpcUaServerConfig
from simulator.runner import Simulator
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber  # noqa: F401 - for this folder's tests, which import them from here
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
MACHINE = "laser-sim"
COPYDATA_ROLE = "operator"  # the gateway file's access.copydata_role: replies write as operators
STATE_IDLE, STATE_RUNNING = 0, 1


@dataclass
class Rig:
    gateway: Gateway
    sim: Simulator
    opcua_port: int

    @property
    def machine(self) -> Machine:
        return self.gateway.tree.machines[MACHINE]

    @property
    def sink(self) -> CopydataSink:
        return self.gateway.sink("copydata")  # type: ignore[no-any-return]

    def emitter(self, target: str = "nesting") -> Emitter:
        return self.sink.emitter(MACHINE, target)

    async def server_port(self, target: str = "nesting") -> int:
        transport = self.emitter(target).transport
        assert isinstance(transport, TcpServerTransport)
        await asyncio.wait_for(transport.listening.wait(), 10)
        return transport.port

    def value(self, path: str) -> Any:
        return self.machine.nodes[path].sample.value

    async def connected(self) -> None:
        await wait_until(
            lambda: self.machine.status.is_connected and self.machine.nodes["Axes/X/Position"].sample.good,
            timeout=15, message="the gateway connected to the simulator",
        )  # fmt: skip

    async def start_program(self, name: str = "demo.nc") -> None:
        await self.connected()
        ctx = WriteContext("test", role="operator")
        await self.machine.write("Control/SelectProgram", name, ctx)
        await wait_until(lambda: self.value("Program/Name") == name, message=f"{name} selected")
        await self.machine.write("Control/Start", True, ctx)


def targets(*entries: dict[str, Any]) -> MachineCopydata:
    return MachineCopydata.model_validate({"targets": list(entries)})


def make_config(tmp_path: Path, sim_port: int, opcua_port: int, copydata: MachineCopydata | None,
                mqtt: MqttConfig | None = None) -> Config:  # fmt: skip
    mapping = load_mapping(
        ROOT / "mappings" / "laser-sim.yaml",
        environ={"LASER_SIM_ENDPOINT": f"opc.tcp://127.0.0.1:{sim_port}"},
    )
    driver = mapping.driver.model_copy(
        update={
            "watchdog_interval": 0.5,
            "reconnect": mapping.driver.reconnect.model_copy(update={"initial": 0.2, "max": 1.0}),
        }
    )
    mapping = mapping.model_copy(update={"driver": driver, "copydata": copydata, "jobs": None})
    gateway = GatewayConfig(
        opcua=OpcUaServerConfig(endpoint=f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway"),
        state_dir=str(tmp_path / "state"),
        access=AccessConfig(copydata_role=COPYDATA_ROLE),  # what targets with accept_writes need
    ).model_copy(update={"mqtt": mqtt})
    return Config(gateway, (mapping,), tmp_path, ())


RigFactory = Callable[..., Awaitable[Rig]]


@pytest.fixture
async def make_rig(tmp_path: Path) -> AsyncIterator[RigFactory]:
    stack: list[Callable[[], Awaitable[None]]] = []

    async def make(
        copydata: MachineCopydata, *, mqtt: MqttConfig | None = None, loop_program: str | None = None
    ) -> Rig:
        sim_port, opcua_port = free_port(), free_port()
        store = tmp_path / "store"
        store.mkdir(exist_ok=True)
        sim = Simulator(
            opcua_port=sim_port, ftp_port=free_port(), speed=20.0, store=store, loop_program=loop_program
        )
        await sim.__aenter__()
        stack.append(lambda: sim.__aexit__(None, None, None))
        gw = Gateway(make_config(tmp_path, sim_port, opcua_port, copydata, mqtt))
        await gw.__aenter__()
        stack.append(lambda: gw.__aexit__(None, None, None))
        run = asyncio.create_task(gw.run(), name="gateway")

        async def stop() -> None:
            run.cancel()
            await asyncio.gather(run, return_exceptions=True)

        stack.append(stop)
        return Rig(gw, sim, opcua_port)

    yield make
    for undo in reversed(stack):
        await undo()


# --- receivers ---------------------------------------------------------------------------------------


@dataclass
class Received:
    """What one connection received, decoded with the target's table."""

    layout: Layout
    table: VariableTable
    frames: list[tuple[int, dict[str, Any]]] = field(default_factory=list)
    decoder: FrameDecoder | None = None

    def __post_init__(self) -> None:
        self.decoder = FrameDecoder(self.layout)

    def feed(self, data: bytes) -> None:
        assert self.decoder is not None
        for frame in self.decoder.feed(data):
            values = {r.variable.name: r.value for r in self.table.decode(frame, self.layout)}
            self.frames.append((frame.dwdata, values))

    def values(self, path: str) -> list[Any]:
        return [v[path] for _, v in self.frames if path in v]

    def latest(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for _, values in self.frames:
            out.update(values)
        return out


class TcpReceiver:
    """Connects to a tcp-server target, like nesting software would, and reads everything."""

    def __init__(self, emitter: Emitter) -> None:
        self.emitter = emitter
        self.got = Received(emitter.layout, emitter.encoder.table)
        self.closed = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def connect(self, port: int) -> TcpReceiver:
        reader, self.writer = await asyncio.open_connection("127.0.0.1", port)
        self._task = asyncio.create_task(self._read(reader))
        return self

    async def _read(self, reader: asyncio.StreamReader) -> None:
        try:
            while data := await reader.read(65536):
                self.got.feed(data)
        except ConnectionError:
            pass
        self.closed.set()

    def send(self, frame: Frame) -> None:
        assert self.writer is not None
        self.writer.write(pack_tcp(frame, self.emitter.layout))

    async def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)


class TcpListener:
    """Plays the nesting software's listener for a tcp-client target; can stop and start again."""

    def __init__(
        self, emitter: Emitter, port: int, *, read: bool = True, receive_buffer: int | None = None
    ) -> None:
        self.emitter = emitter
        self.port = port
        self.read = read
        self.receive_buffer = receive_buffer
        self.connections: list[Received] = []
        self._server: asyncio.Server | None = None
        self._writers: list[asyncio.StreamWriter] = []
        self._tasks: set[asyncio.Task[None]] = set()

    async def start(self) -> TcpListener:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if self.receive_buffer is not None:  # inherited by accepted connections: a small TCP window
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.receive_buffer)
        sock.bind(("127.0.0.1", self.port))
        self._server = await asyncio.start_server(self._client, sock=sock)
        return self

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        got = Received(self.emitter.layout, self.emitter.encoder.table)
        self.connections.append(got)
        self._writers.append(writer)
        self._tasks.add(asyncio.current_task())  # type: ignore[arg-type]
        try:
            if not self.read:  # accept, then never read: the slowest receiver there is
                writer.transport.pause_reading()  # (asyncio would otherwise buffer 128 KiB for us)
                await asyncio.Future()
            while data := await reader.read(65536):
                got.feed(data)
        except (ConnectionError, asyncio.CancelledError):
            pass

    async def stop(self) -> None:
        assert self._server is not None
        self._server.close()
        for writer in self._writers:
            writer.transport.abort()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        self._writers.clear()
        await self._server.wait_closed()


def single(vid: int, data: bytes) -> Frame:
    return Frame(1, (Item(vid, data),))
