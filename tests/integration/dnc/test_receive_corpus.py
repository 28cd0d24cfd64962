"""Every case of tests/corpus/dnc/punch.yaml over a real line: a scripted controller on a raw TCP port
sends the case's bytes to the gateway's serial transport (real pyserial, socket://), whose idle listener is
the punch desk; the controller reads back the answer, if any. The same expectations as the unit runner
(tests/unit/transports/dnc/test_desk_corpus.py), here with the line's own reads, timers and drops."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager, suppress
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.model.audit import AuditEntry
from gateway.model.definitions import MachineDefinition
from gateway.model.tree import VariableTree
from gateway.transports.dnc.desk import PunchDesk
from gateway.transports.dnc.punch import PunchSettings, RemoteRequests
from gateway.transports.dnc.received import ReceivedStore
from gateway.transports.dnc.transfers import TransferLog
from tests.integration.dnc.rig import SIM_BAUD, transport
from tests.waiting import wait_until

CORPUS = Path(__file__).resolve().parents[2] / "corpus" / "dnc" / "punch.yaml"
CASES: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))
DC1 = b"\x11"
SILENCE = 0.3  # s: the desk's idle_timeout here


def data(case: dict[str, Any]) -> bytes:
    if "hex" in case:
        return bytes.fromhex(case["hex"])
    return str(case["text"]).encode("utf-8")


class Controller:
    """Sends the case once (to the first connection, once the gateway's port is open), then DC1 now and
    then, as a Fanuc in READ after a request; keeps what comes back. `lost`: closes the connection after
    the case."""

    def __init__(self, case: dict[str, Any]) -> None:
        self.case = case
        self.sent = False
        self.received = bytearray()
        self.writers: list[asyncio.StreamWriter] = []
        self.serving = 0
        self.port_open: Callable[[], bool] = lambda: True

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.serving += 1
        self.writers.append(writer)
        try:
            await self._serve(reader, writer)
        finally:
            self.serving -= 1

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.sent:
            writer.close()
            return
        self.sent = True
        # The operator presses PUNCH once the gateway listens: pyserial empties its input as it opens
        await wait_until(self.port_open, message="the gateway's port open")
        writer.write(data(self.case))
        await writer.drain()
        if self.case.get("then") == "lost":
            writer.close()
            return

        async def ready() -> None:
            while not writer.is_closing():
                await asyncio.sleep(0.2)
                writer.write(DC1)

        task = asyncio.create_task(ready())
        try:
            while chunk := await reader.read(4096):
                self.received += chunk
        except ConnectionError:
            pass
        finally:
            task.cancel()
            writer.close()

    @property
    def answer(self) -> bytes:
        """What came back, as characters (parity bit and leader dropped)."""
        return bytes(b & 0x7F for b in self.received).replace(b"\x00", b"")


@asynccontextmanager
async def line(tmp_path: Path, case: dict[str, Any]) -> AsyncIterator[tuple[PunchDesk, Controller, Any]]:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "O1234.nc").write_bytes(b"%\nO1234\nG0 X1\nM30\n%\n")
    (folder / "BIG.nc").write_bytes(b"G1 X1\n" * 333 + b"M3")  # 2,000 bytes
    (tmp_path / "secret.nc").write_bytes(b"%\nO6666 (SECRET)\nM30\n%\n")
    (folder / "LINK.nc").symlink_to(tmp_path / "secret.nc")
    tree = VariableTree([MachineDefinition("serial", ())])
    audited: list[AuditEntry] = []
    tree.audit_sinks.append(audited.append)
    state = tmp_path / "state"
    log = TransferLog.in_state_dir(state)
    settings = PunchSettings(
        max_size=case.get("max_size", 1 << 20),
        idle_timeout=SILENCE,
        requests=RemoteRequests(folder=folder, max_size=1024),
    )
    desk = PunchDesk(tree.machines["serial"], settings, store=ReceivedStore(state), transfers=log)
    controller = Controller(case)
    server = await asyncio.start_server(controller.serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    owner = transport(f"socket://127.0.0.1:{port}", tmp_path, baud=SIM_BAUD, dc1_timeout=5)
    owner.listener = desk
    owner.transfer_log = log
    controller.port_open = lambda: owner.port.is_open
    async with server:
        tasks = [asyncio.create_task(owner.run()), asyncio.create_task(desk.run())]
        try:
            yield desk, controller, audited
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with suppress(asyncio.CancelledError):
                    await task
            owner.close()
            log.close()
            for writer in controller.writers:
                writer.close()
            await wait_until(lambda: controller.serving == 0, message="the controller's connections closed")


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
async def test_case(case: dict[str, Any], tmp_path: Path) -> None:
    expect = case["expect"]
    async with line(tmp_path, case) as (desk, controller, audited):
        await wait_until(lambda: controller.sent, message="the case sent")
        refused = expect.get("refused", 0)
        stored = expect.get("stored", 0)
        wanted = expect.get("answer")
        if "comment" in expect:
            wanted = f"%\nO9999 ({expect['comment']})\nM30\n%\n"
        if "audit" in expect:
            await wait_until(lambda: len(audited) >= len(expect["audit"]), message="the request heard")
        if wanted is not None:
            await wait_until(
                lambda: wanted.encode().rstrip(b"\n") in controller.answer,  # the line ends on its %
                timeout=15,
                message="the answer",
            )
        await wait_until(lambda: desk.refused >= refused, timeout=10, message=f"{refused} refused")
        await wait_until(lambda: len(desk.store.list()) >= stored, timeout=10, message=f"{stored} stored")
        await wait_until(lambda: not desk._work, message="the desk's work done")
        if "junk" in expect:
            await wait_until(lambda: desk.junk_bytes >= expect["junk"], message="junk counted")
        assert desk.refused == refused
        assert len(desk.store.list()) == stored
        if "audit" in expect:
            assert [e.status for e in audited] == expect["audit"]
        if expect.get("answer", "") is None:
            assert controller.answer.strip(b"\x11") == b""
        if "file" in expect:
            [rec] = desk.store.list()
            assert rec.file.endswith(f"-{expect['file']}.nc")
    assert (tmp_path / "secret.nc").read_bytes() == b"%\nO6666 (SECRET)\nM30\n%\n"
