"""The S7 driver against the simulator's PLC (python-snap7's server, the S7 face): every elementary type
read in multi-variable requests and written through the gateway's write path, a BOOL written as a bit,
items the CPU refuses marking only their variables Bad, the negotiated PDU, and a PLC restart."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from gateway.config.loader import load_mapping
from gateway.config.mapping import MachineMapping
from gateway.model.context import WriteContext
from gateway.model.tree import Machine, VariableTree
from gateway.sources.s7.source import S7Source
from simulator.machine import Machine as SimMachine
from simulator.machine import MachineState
from simulator.s7_face import S7Face
from simulator.store import DirectoryStore
from tests.waiting import wait_until

ROOT = Path(__file__).resolve().parents[3]
ADMIN = WriteContext("test", "tester", "admin")
T0 = datetime(2024, 5, 1, 13, 45, 7, 123000, tzinfo=UTC)


def s7_mapping(port: int, variables: list[dict[str, Any]], **driver: Any) -> MachineMapping:
    settings = {"type": "s7", "host": "127.0.0.1", "port": port, "timeout": 1,
                "reconnect": {"initial": 0.05, "max": 0.3, "factor": 2}, **driver}  # fmt: skip
    return MachineMapping.model_validate(
        {"machine": "plc", "driver": settings, "defaults": {"sampling_interval": 50}, "variables": variables}
    )


@asynccontextmanager
async def polling(mapping: MachineMapping) -> AsyncIterator[tuple[Machine, S7Source]]:
    tree = VariableTree([mapping.definition()])
    machine = tree.machines[mapping.machine]
    async with S7Source(machine, mapping) as source:
        task = asyncio.create_task(source.run(), name="s7")
        try:
            yield machine, source
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


@asynccontextmanager
async def ticking(face: S7Face) -> AsyncIterator[S7Face]:
    """The face with the simulator's tick: the machine into the blocks, the commands into the machine."""

    async def tick() -> None:
        while True:
            face.publish()
            await asyncio.sleep(0.02)

    async with face:
        task = asyncio.create_task(tick())
        try:
            yield face
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def sample(machine: Machine, path: str) -> Any:
    return machine.nodes[path].sample


def good(machine: Machine, *paths: str) -> bool:
    return all(sample(machine, p).good for p in paths)


@pytest.fixture
def plc(tmp_path: Path) -> SimMachine:
    store = DirectoryStore(tmp_path)
    store.prepare()
    machine = SimMachine(store)
    machine.select_program("demo.nc")
    machine.start()
    machine.program.block = 42
    machine.program.run_time = 12.5
    machine.override = 90
    machine.laser.on = True
    machine.laser.power_act = 2500.0
    return machine


async def test_the_shipped_mapping_reads_the_plc_in_three_requests(plc: SimMachine) -> None:
    async with ticking(S7Face(plc, port=0, clock=lambda: T0)) as face:
        environ = {"LASER_SIM_S7_PORT": str(face.port)}
        mapping = load_mapping(ROOT / "mappings" / "laser-sim-s7.yaml", environ=environ)
        quick = mapping.driver.model_copy(
            update={"reconnect": mapping.driver.reconnect.model_copy(update={"max": 0.3})}
        )  # type: ignore[attr-defined]
        async with polling(mapping.model_copy(update={"driver": quick})) as (machine, source):
            paths = [v.path for v in mapping.variables]
            await wait_until(lambda: good(machine, *paths), message="every variable Good")
            assert sample(machine, "Program/Name").value == "demo.nc"  # STRING[32]
            assert sample(machine, "PLC/Clock").value == T0  # DATE_AND_TIME
            assert sample(machine, "Program/RunTime").value == 12.5  # LREAL
            assert sample(machine, "Program/Block").value == 42  # DWORD
            assert sample(machine, "Laser/Power").value == 2500.0  # REAL
            assert sample(machine, "Feed/Override").value == 90  # INT
            assert sample(machine, "Machine/State").value == 1
            assert sample(machine, "Laser/StatusBits").value == 0b101  # BYTE: laser on, running
            assert (
                sample(machine, "Laser/On").value is True and sample(machine, "Machine/Running").value is True
            )
            assert (
                sample(machine, "IO/DoorClosed").value is True
                and sample(machine, "IO/ShutterOpen").value is True
            )
            assert [len(g.reads) for g in source.groups] == [1, 1, 1]  # 29 variables, 3 Read Var requests
            assert source.link.pdu_size == 480

            await machine.write("Requests/Override", 77, ADMIN)
            await wait_until(lambda: plc.override == 77, message="the override applied by the PLC")
            await wait_until(lambda: sample(machine, "Feed/Override").value == 77, message="and read back")
            face.db20[2] |= 0b1111_0000  # other bits of the byte the BOOL lives in
            await machine.write("Requests/FeedHold", True, ADMIN)
            assert face.db20[2] == 0b1111_0001  # the bit alone was written
            await wait_until(lambda: plc.state is MachineState.PAUSED, message="feed hold")
            await machine.write("Requests/FeedHold", False, ADMIN)
            assert face.db20[2] == 0b1111_0000
            await machine.write("Requests/Message", "Nozzle check", ADMIN)
            await wait_until(lambda: sample(machine, "Operator/Message").value == "Nozzle check",
                             message="the message, through the PLC")  # fmt: skip


TYPES = [  # (S7 address in DB30, gateway type, a value, its bytes as the S7 manuals give them)
    ("DB30.DBX0.5", "Boolean", True, None),
    ("DB30.DBB1", "Byte", 200, b"\xc8"),
    ("DB30.DBB2:SINT", "SByte", -100, struct.pack(">b", -100)),
    ("DB30.DBW4", "Int16", -12345, struct.pack(">h", -12345)),
    ("DB30.DBW6", "UInt16", 54321, struct.pack(">H", 54321)),
    ("DB30.DBD8", "Int32", -123456789, struct.pack(">i", -123456789)),
    ("DB30.DBD12", "UInt32", 4000000000, struct.pack(">I", 4000000000)),
    ("DB30.DBD16", "Float", 123.5, struct.pack(">f", 123.5)),
    ("DB30.DBB20:LREAL", "Double", -9876.54321, struct.pack(">d", -9876.54321)),
    ("DB30.DBB28:LINT", "Int64", -(2**40), struct.pack(">q", -(2**40))),
    ("DB30.DBB36:ULINT", "UInt64", 2**63 + 5, struct.pack(">Q", 2**63 + 5)),
    ("DB30.DBB44:STRING[10]", "String", "Düse", b"\x0a\x04D\xfcse" + bytes(6)),
    ("DB30.DBB56:DATE_AND_TIME", "DateTime", T0, bytes.fromhex("2405011345071234")),
    ("DB30.DBW64:UINT", "Double", 7.0, struct.pack(">H", 7)),
]


async def test_every_type_written_and_read_back(plc: SimMachine) -> None:
    block = bytearray(80)
    block[56:64] = bytes.fromhex("9001010000000002")  # DT#1990-01-01-00:00:00, the default (zeros: no date)
    variables = [
        {"path": f"T/v{i}", "source": a, "type": t, "access": "readwrite"}
        for i, (a, t, _, _) in enumerate(TYPES)
    ]
    face = S7Face(plc, port=0, clock=lambda: T0, blocks={30: block})
    async with face, polling(s7_mapping(face.port, variables)) as (machine, source):
        await wait_until(lambda: good(machine, *[v["path"] for v in variables]), message="all Good")
        assert sum(len(r.request.items) for g in source.groups for r in g.reads) == 1  # one item, DB30 0-65
        for i, (address, _, value, data) in enumerate(TYPES):
            await machine.write(f"T/v{i}", value, ADMIN)
            assert sample(machine, f"T/v{i}").value == value, address
            if data is not None:
                start = int(address.split(".DB")[1][1:].split(":")[0].split(".")[0])
                assert bytes(block[start : start + len(data)]) == data, address
        assert block[0] == 0b0010_0000


async def test_items_the_cpu_refuses_mark_only_their_variables_bad(plc: SimMachine) -> None:
    variables = [
        {"path": "Good/X", "source": "DB10.DBD0", "type": "Float"},
        {"path": "Good/Block", "source": "DB10.DBD88", "type": "UInt32"},
        {"path": "Near", "source": "DB10.DBD124", "type": "Float"},
        {"path": "Past", "source": "DB10.DBD130", "type": "Float"},  # DB10 has 128 bytes: coalesced with Near
        {"path": "NoBlock", "source": "DB99.DBW0", "type": "Int16"},
    ]
    async with (
        S7Face(plc, port=0, clock=lambda: T0) as face,
        polling(s7_mapping(face.port, variables)) as (machine, _),
    ):
        await wait_until(lambda: sample(machine, "NoBlock").status == "BadNodeIdUnknown", message="DB99 Bad")
        assert "object does not exist" in sample(machine, "NoBlock").reason
        await wait_until(
            lambda: sample(machine, "Past").status == "BadNodeIdUnknown", message="the address Bad"
        )
        assert "address out of range" in sample(machine, "Past").reason
        await wait_until(
            lambda: good(machine, "Good/X", "Good/Block", "Near"), message="its neighbour read alone"
        )


async def test_the_negotiated_pdu_and_a_plc_restart(plc: SimMachine) -> None:
    variables = [{"path": f"B/b{i}", "source": f"DB10.DBB{i}", "type": "Byte"} for i in range(0, 128, 2)]
    face = S7Face(plc, port=0, clock=lambda: T0)
    await face.__aenter__()
    port = face.port
    try:
        async with polling(s7_mapping(port, variables, pdu_size=240, max_gap=0)) as (machine, source):
            await wait_until(lambda: good(machine, "B/b0", "B/b126"), message="Good")
            assert source.link.pdu_size == 240
            assert all(r.request.response_size <= 240 for g in source.groups for r in g.reads)
            await face.__aexit__(None, None, None)
            await wait_until(lambda: not machine.status.is_connected and not sample(machine, "B/b0").good,
                             message="Bad while the PLC is down")  # fmt: skip
            face = S7Face(plc, port=port, clock=lambda: T0)
            await face.__aenter__()
            await wait_until(lambda: good(machine, "B/b0", "B/b126"), timeout=10, message="Good again")
            assert machine.status.reconnects >= 1
    finally:
        await face.__aexit__(None, None, None)
