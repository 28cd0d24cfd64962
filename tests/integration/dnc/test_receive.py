"""The receive side against the simulator's DNC face, with real pyserial: the operator's PUNCH is stored,
a remote request answered with the program (or with a comment that says why not), a punch cut off by a
dropped line refused. The line is the send side's SerialTransport with the punch desk as its idle listener.
"""

from __future__ import annotations

import asyncio
import hashlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from gateway.model.audit import AuditEntry
from gateway.model.definitions import MachineDefinition
from gateway.model.tree import VariableTree
from gateway.transports.dnc.desk import PunchDesk
from gateway.transports.dnc.punch import PunchSettings, RemoteRequests
from gateway.transports.dnc.received import ReceivedStore
from gateway.transports.dnc.transfers import TransferLog
from gateway.transports.dnc.transport import SerialTransport
from simulator.runner import Simulator
from tests.integration.dnc.rig import SIM_BAUD, face, load_program, simulator, transport
from tests.waiting import wait_until

PROGRAM = load_program(40)
ANSWER = b"%\nO1234 (ANSWER)\nG21 G90\nG1 X5 Y5 F1000\nM30\n%\n"


class Desk:
    def __init__(self, desk: PunchDesk, line: SerialTransport, audited: list[AuditEntry]) -> None:
        self.desk = desk
        self.line = line
        self.audited = audited


@asynccontextmanager
async def listening(tmp_path: Path, where: str, **more: object) -> AsyncIterator[Desk]:
    folder = tmp_path / "programs"
    folder.mkdir(exist_ok=True)
    (folder / "O1234.nc").write_bytes(ANSWER)
    tree = VariableTree([MachineDefinition("serial", ())])
    audited: list[AuditEntry] = []
    tree.audit_sinks.append(audited.append)
    state = tmp_path / "state"
    log = TransferLog.in_state_dir(state)
    desk = PunchDesk(
        tree.machines["serial"],
        PunchSettings(idle_timeout=2.0, requests=RemoteRequests(folder=folder)),
        store=ReceivedStore(state),
        transfers=log,
    )
    line = transport(where, tmp_path, **more)
    line.listener = desk
    line.transfer_log = log
    async with asyncio.TaskGroup() as tg:
        tasks = [tg.create_task(line.run(), name="line"), tg.create_task(desk.run(), name="desk")]
        try:
            yield Desk(desk, line, audited)
        finally:
            for task in tasks:
                task.cancel()
    line.close()
    log.close()


async def linked(sim: Simulator) -> None:
    await wait_until(lambda: face(sim).stats()["link"], message="the gateway's line connected")


async def test_a_punch_over_socket_is_stored_byte_for_byte_and_logged(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim, listening(tmp_path, face(sim).socket_url or "") as rig:
        sim.programs.write("O4711", PROGRAM)
        await linked(sim)
        face(sim).punch("O4711")
        await wait_until(rig.desk.store.list, timeout=30, message="the punch stored")
        [rec] = rig.desk.store.list()
        assert rig.desk.store.path(rec).read_bytes() == PROGRAM
        assert rec.sha256 == hashlib.sha256(PROGRAM).hexdigest() and rec.number == 4711
        rows = await wait_until(rig.desk.transfers.query, message="the transfer logged")  # type: ignore[union-attr]
        assert [(r.record.direction, r.record.outcome, r.record.sha256) for r in rows] == [
            ("receive", "ok", rec.sha256)
        ]
        assert face(sim).stats()["parity_errors"] == 0


async def test_a_remote_request_is_answered_with_the_program(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim, listening(tmp_path, face(sim).socket_url or "") as rig:
        await linked(sim)
        face(sim).request("O1234")
        await wait_until(lambda: sim.programs.exists("O1234"), timeout=30, message="the answer loaded")
        assert sim.programs.read("O1234").encode() == ANSWER
        assert [(e.target, e.status, e.origin) for e in rig.audited] == [("Dnc.Request", "Good", "dnc")]
        rows = await wait_until(
            lambda: [r for r in rig.desk.transfers.query() if r.record.direction == "send"],  # type: ignore[union-attr]
            message="the answer's send logged",
        )
        assert rows[0].record.outcome == "ok" and rows[0].record.program.startswith("O1234")


async def test_a_request_for_a_missing_or_escaping_name_is_answered_with_why(tmp_path: Path) -> None:
    async with simulator(tmp_path) as sim, listening(tmp_path, face(sim).socket_url or "") as rig:
        await linked(sim)
        face(sim).request("O0815")
        await wait_until(
            lambda: face(sim).stats()["request_reply"] == "NOT FOUND O0815", timeout=30, message="the answer"
        )
        await wait_until(lambda: face(sim).stats()["stage"] in ("idle", "reading"), message="line free")
        face(sim).request("LINK")  # a name the simulator lets through; nothing of that name in the folder
        await wait_until(
            lambda: face(sim).stats()["request_reply"] == "NOT FOUND LINK", timeout=30, message="the answer"
        )
        assert [e.status for e in rig.audited] == ["BadNotFound", "BadNotFound"]
        assert not sim.programs.exists("O1234")


async def test_a_punch_cut_off_by_a_dropped_line_is_refused(tmp_path: Path) -> None:
    """A raw TCP device server that sends half a program and closes: refused with its reason, kept."""
    sent = asyncio.Event()

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(b"\x00" * 8 + b"%\nO4711 (CUT)\nG0 X1\nG1 X2 F100\n")
        await writer.drain()
        sent.set()
        writer.close()

    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    async with server, listening(tmp_path, f"socket://127.0.0.1:{port}", baud=SIM_BAUD) as rig:
        await wait_until(lambda: rig.desk.refused, timeout=20, message="the cut punch refused")
        assert rig.desk.store.list() == []
        reason = rig.desk.machine.nodes["Jobs/Dnc/LastRefusedReason"].sample.value
        assert "punch refused" in reason and ("line was lost" in reason or "no closing %" in reason)
        folder = tmp_path / "state" / "dnc" / "refused" / "serial"
        kept = await wait_until(lambda: list(folder.glob("*.part")), message="what arrived kept")
        assert [p.read_bytes() for p in kept] == [b"O4711 (CUT)\nG0 X1\nG1 X2 F100\n"]


async def test_a_punch_over_a_pty_with_real_pyserial(tmp_path: Path) -> None:
    async with simulator(tmp_path, speed=1.0, pty=True) as sim:
        path = face(sim).pty_path
        small = load_program(8)
        sim.programs.write("O4711", small)
        async with listening(tmp_path, path, baud=SIM_BAUD) as rig:
            await linked(sim)
            face(sim).punch("O4711")
            await wait_until(rig.desk.store.list, timeout=30, message="the punch stored")
            [rec] = rig.desk.store.list()
            assert rig.desk.store.path(rec).read_bytes() == small
