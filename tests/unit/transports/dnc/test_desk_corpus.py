"""Every case of tests/corpus/dnc/punch.yaml gets the answer its entry promises from the punch desk."""

from __future__ import annotations

import asyncio
import re
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

CORPUS = Path(__file__).resolve().parents[3] / "corpus" / "dnc" / "punch.yaml"
CASES: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text(encoding="utf-8"))


def data(case: dict[str, Any]) -> bytes:
    if "hex" in case:
        return bytes.fromhex(case["hex"])
    return str(case["text"]).encode("utf-8")


def test_corpus_names_are_unique() -> None:
    assert len({case["name"] for case in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_case(case: dict[str, Any], tmp_path: Path) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "O1234.nc").write_bytes(b"%\nO1234\nG0 X1\nM30\n%\n")
    (folder / "BIG.nc").write_bytes(b"G1 X1\n" * 333 + b"M30\n%\n"[: 2000 - 6 * 333])
    (tmp_path / "secret.nc").write_bytes(b"%\nO6666 (SECRET)\nM30\n%\n")
    (folder / "LINK.nc").symlink_to(tmp_path / "secret.nc")
    assert (folder / "BIG.nc").stat().st_size == 2000
    tree = VariableTree([MachineDefinition("fanuc-1", ())])
    audited: list[AuditEntry] = []
    tree.audit_sinks.append(audited.append)
    settings = PunchSettings(
        max_size=case.get("max_size", 1 << 20),
        requests=RemoteRequests(folder=folder, max_size=1024),
    )
    state = tmp_path / "state"
    desk = PunchDesk(
        tree.machines["fanuc-1"],
        settings,
        store=ReceivedStore(state),
        transfers=TransferLog.in_state_dir(state),
    )
    answers = [a for a in [desk.feed(data(case))] if a is not None]
    then = case.get("then")
    if then == "silence":
        desk.idle_expired()
    elif then == "lost":
        desk.line_lost("socket disconnected")
    asyncio.run(desk.drain())

    expect = case["expect"]
    if "answer" in expect:
        wanted = expect["answer"]
        assert answers == ([] if wanted is None else [wanted.encode()])
    if "comment" in expect:
        [answer] = answers
        assert re.fullmatch(rb"%\nO9999 \((.*)\)\nM30\n%\n", answer), answer
        assert f"({expect['comment']})".encode() in answer
    stored = desk.store.list()
    if "stored" in expect:
        assert len(stored) == expect["stored"]
    if "file" in expect:
        [rec] = stored
        assert rec.file.endswith(f"-{expect['file']}.nc")
        assert desk.store.path(rec).parent == state / "dnc" / "received" / "fanuc-1"
    if "refused" in expect:
        assert desk.refused == expect["refused"]
    if "reason" in expect:
        assert expect["reason"] in str(
            tree.machines["fanuc-1"].nodes["Jobs/Dnc/LastRefusedReason"].sample.value
        )
    if "junk" in expect:
        assert desk.junk_bytes >= expect["junk"]
    if "audit" in expect:
        assert [e.status for e in audited] == expect["audit"]
        assert all(e.target == "Dnc.Request" and e.origin == "dnc" for e in audited)
    if "log" in expect:
        rows = desk.transfers.query()  # type: ignore[union-attr]
        assert [[r.record.direction, r.record.outcome] for r in rows] == expect["log"]
    # nothing was ever written outside the state directory's dnc folder
    written = {p for p in tmp_path.rglob("*") if p.is_file()}
    assert all(p.is_relative_to(state) or p.is_relative_to(folder) or p.name == "secret.nc" for p in written)
    assert (tmp_path / "secret.nc").read_bytes() == b"%\nO6666 (SECRET)\nM30\n%\n"
