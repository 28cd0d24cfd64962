"""The punch desk: punches stored whole however the bytes arrive, refusals counted, requests answered."""

from __future__ import annotations

import asyncio
import hashlib
import json
from pathlib import Path

import pytest

from gateway.codecs.dnc import not_found
from gateway.config.validation import ValidationRules
from gateway.jobs.assembly import validator
from gateway.model.audit import AuditEntry
from gateway.model.definitions import MachineDefinition
from gateway.model.tree import VariableTree
from gateway.transports.base import QueuedProgram
from gateway.transports.dnc.desk import PunchDesk
from gateway.transports.dnc.punch import PunchSettings, RemoteRequests
from gateway.transports.dnc.received import ReceivedStore, safe_name
from gateway.transports.dnc.transfers import TransferLog
from tests.waiting import wait_until

PUNCH = b"\x00" * 10 + b"%\nO4711 (BRACKET)\nG0 X0 Y0\nG1 X10 F100\nM30\n%" + b"\x00" * 4
STORED = b"%\nO4711 (BRACKET)\nG0 X0 Y0\nG1 X10 F100\nM30\n%\n"
REQUEST = b"%\nO9999 (PRG=O1234)\nM30\n%\n"


def make_desk(
    tmp_path: Path, *, settings: PunchSettings | None = None
) -> tuple[PunchDesk, VariableTree, list[AuditEntry]]:
    tree = VariableTree([MachineDefinition("fanuc-1", ())])
    audited: list[AuditEntry] = []
    tree.audit_sinks.append(audited.append)
    desk = PunchDesk(
        tree.machines["fanuc-1"],
        settings or PunchSettings(),
        store=ReceivedStore(tmp_path),
        transfers=TransferLog.in_state_dir(tmp_path),
        validate=validator(ValidationRules()),
        backups=tmp_path / "backups" / "fanuc-1",
    )
    return desk, tree, audited


def value(tree: VariableTree, path: str) -> object:
    return tree.machines["fanuc-1"].nodes[path].sample.value


def programs_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "O1234.nc").write_bytes(b"%\nO1234\nG0 X1\nM30\n%\n")
    (tmp_path / "secret.nc").write_bytes(b"%\nO6666\nM30\n%\n")
    (folder / "LINK.nc").symlink_to(tmp_path / "secret.nc")
    return folder


@pytest.mark.parametrize("step", [1, 2, 3, 7])
def test_a_punch_split_anywhere_is_stored_whole_with_size_and_sha(tmp_path: Path, step: int) -> None:
    desk, tree, _ = make_desk(tmp_path)
    for pos in range(0, len(PUNCH), step):
        assert desk.feed(PUNCH[pos : pos + step]) is None
    asyncio.run(desk.drain())
    [rec] = desk.store.list("fanuc-1")
    assert desk.store.path(rec).read_bytes() == STORED
    assert rec.size == len(STORED) and rec.sha256 == hashlib.sha256(STORED).hexdigest()
    assert rec.number == 4711 and rec.file.endswith("-O4711-BRACKET.nc")
    assert value(tree, "Jobs/Dnc/LastReceived") == rec.file
    assert value(tree, "Jobs/Dnc/LastReceivedSha256") == rec.sha256
    assert value(tree, "Jobs/Dnc/ReceivedCount") == 1
    [row] = desk.transfers.query()  # type: ignore[union-attr]
    assert (row.record.direction, row.record.outcome, row.record.sha256) == ("receive", "ok", rec.sha256)


def test_every_split_point_of_a_punch_gives_the_same_program(tmp_path: Path) -> None:
    for cut in range(1, len(PUNCH)):
        desk, _, _ = make_desk(tmp_path / str(cut))
        desk.feed(PUNCH[:cut])
        desk.feed(PUNCH[cut:])
        asyncio.run(desk.drain())
        [rec] = desk.store.list()
        assert desk.store.path(rec).read_bytes() == STORED, cut


def test_parity_bits_are_stripped_from_a_7_bit_line(tmp_path: Path) -> None:
    desk, _, _ = make_desk(tmp_path)
    desk.feed(bytes(b | 0x80 if i % 2 else b for i, b in enumerate(PUNCH)))
    asyncio.run(desk.drain())
    [rec] = desk.store.list()
    assert desk.store.path(rec).read_bytes() == STORED


def test_validation_and_backup_when_configured(tmp_path: Path) -> None:
    desk, tree, _ = make_desk(tmp_path, settings=PunchSettings(validate=True, backup=True))
    desk.feed(PUNCH)
    asyncio.run(desk.drain())
    [rec] = desk.store.list()
    assert rec.verdict == "accepted" and value(tree, "Jobs/Dnc/LastReceivedVerdict") == "accepted"
    assert (
        Path(rec.backup).read_bytes() == STORED
        and Path(rec.backup).parent == tmp_path / "backups" / "fanuc-1"
    )
    meta = json.loads(desk.store.path(rec).with_suffix(".json").read_text())
    assert meta["sha256"] == rec.sha256


def test_a_punch_without_its_closing_percent_is_refused_and_kept(tmp_path: Path) -> None:
    desk, tree, _ = make_desk(tmp_path)
    desk.feed(b"%\nO4711\nG0 X0\n")
    desk.idle_expired()
    desk.feed(b"%\nO4712\nG0 X1\n")
    desk.line_lost("DSR off")
    asyncio.run(desk.drain())
    assert desk.store.list() == [] and desk.refused == 2
    assert value(tree, "Jobs/Dnc/RefusedCount") == 2
    assert "line was lost (DSR off)" in str(value(tree, "Jobs/Dnc/LastRefusedReason"))
    kept = sorted((tmp_path / "dnc" / "refused" / "fanuc-1").glob("*.part"))
    assert [p.read_bytes() for p in kept] == [b"O4711\nG0 X0\n", b"O4712\nG0 X1\n"]
    assert "no closing % after 10 s" in kept[0].with_suffix(".reason").read_text()
    rows = desk.transfers.query()  # type: ignore[union-attr]
    assert [r.record.outcome for r in rows] == ["refused", "refused"]


def test_the_silence_timer_refuses_an_unterminated_punch_on_the_loop(tmp_path: Path) -> None:
    async def go() -> None:
        desk, _, _ = make_desk(tmp_path, settings=PunchSettings(idle_timeout=0.05))
        runner = asyncio.create_task(desk.run())
        desk.feed(b"%\nO4711\nG0 X0\n")
        await wait_until(lambda: desk.refused == 1, timeout=5)
        runner.cancel()
        assert desk.receiver.receiving is False

    asyncio.run(go())


def test_junk_and_oversize_are_counted_never_raised(tmp_path: Path) -> None:
    desk, tree, _ = make_desk(tmp_path, settings=PunchSettings(max_size=16))
    assert desk.feed(b"\xfe\xff garbage") is None
    desk.feed(b"%\n" + b"G1 X1\n" * 10 + b"%\n")
    asyncio.run(desk.drain())
    assert value(tree, "Jobs/Dnc/JunkBytes") == desk.junk_bytes > 0
    assert desk.refused == 1 and "larger than 16 bytes" in str(value(tree, "Jobs/Dnc/LastRefusedReason"))


def test_a_request_is_answered_with_the_program_and_audited(tmp_path: Path) -> None:
    folder = programs_folder(tmp_path)
    desk, tree, audited = make_desk(tmp_path, settings=PunchSettings(requests=RemoteRequests(folder=folder)))
    answers = [a for pos in range(len(REQUEST)) if (a := desk.feed(REQUEST[pos : pos + 1])) is not None]
    assert answers == [b"%\nO1234\nG0 X1\nM30\n%\n"]
    [entry] = audited
    assert (entry.target, entry.origin, entry.user, entry.status) == (
        "Dnc.Request",
        "dnc",
        "operator",
        "Good",
    )
    assert value(tree, "Jobs/Dnc/LastRequest") == "O1234: sent O1234.nc"
    asyncio.run(desk.drain())
    rows = [r.record for r in desk.transfers.query()]  # type: ignore[union-attr]
    assert [(r.direction, r.outcome) for r in rows] == [("receive", "ok")]  # the line logs its send
    assert desk.store.list() == []  # a request is not a punched program


@pytest.mark.parametrize(
    ("name", "comment", "status"),
    [
        ("O4711", "NOT FOUND O4711", "BadNotFound"),
        ("../secret", "NAME LEAVES THE FOLDER", "BadInvalidArgument"),
        ("LINK", "NOT FOUND LINK", "BadNotFound"),  # a link out of the folder is not followed
        ("", "NO PROGRAM NAME", "BadInvalidArgument"),
    ],
)
def test_unknown_or_escaping_names_get_a_short_answer_that_says_why(
    tmp_path: Path, name: str, comment: str, status: str
) -> None:
    folder = programs_folder(tmp_path)
    desk, _, audited = make_desk(tmp_path, settings=PunchSettings(requests=RemoteRequests(folder=folder)))
    answer = desk.feed(f"%\nO9999 (PRG={name})\nM30\n%\n".encode())
    assert answer is not None and f"({comment})".encode() in answer and answer.startswith(b"%\nO9999")
    assert [e.status for e in audited] == [status]


def test_not_found_answer_is_the_codecs(tmp_path: Path) -> None:
    folder = programs_folder(tmp_path)
    desk, _, _ = make_desk(tmp_path, settings=PunchSettings(requests=RemoteRequests(folder=folder)))
    assert desk.feed(b"%\nO9999 (PRG=O4711)\nM30\n%\n") == not_found("O4711")


def test_a_request_to_queue_is_submitted_as_a_job(tmp_path: Path) -> None:
    folder = programs_folder(tmp_path)
    submitted: list[tuple[str, str, bytes, str, str]] = []

    async def submit(machine: str, name: str, data: bytes, user: str, origin: str) -> str:
        submitted.append((machine, name, data, user, origin))
        return "J000001 queued"

    desk, tree, _ = make_desk(
        tmp_path, settings=PunchSettings(requests=RemoteRequests(folder=folder, send="queue"))
    )
    desk.submit = submit
    assert desk.feed(REQUEST) is None
    asyncio.run(desk.drain())
    assert submitted == [("fanuc-1", "O1234.nc", b"%\nO1234\nG0 X1\nM30\n%\n", "operator", "dnc")]
    assert value(tree, "Jobs/Dnc/LastRequest") == "O1234: J000001 queued"


def test_safe_names_never_leave_the_folder() -> None:
    assert safe_name(4711, "../../etc/passwd") == "O4711-etc_passwd"
    assert safe_name(None, "_N_PART_MPF") == "N_PART_MPF"
    assert safe_name(None, "/..") == "punch"
    assert safe_name(7, None) == "O0007"


def test_programs_received_lists_the_punches(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gateway.cli.main import main

    desk, _, _ = make_desk(tmp_path)
    desk.feed(PUNCH)
    asyncio.run(desk.drain())
    assert main(["programs", "received", "--state-dir", str(tmp_path)]) == 0
    [line] = capsys.readouterr().out.splitlines()
    assert "fanuc-1" in line and "O4711-BRACKET.nc" in line and f"{len(STORED)} B" in line
    assert main(["programs", "received", "fanuc-1", "--state-dir", str(tmp_path), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert Path(record["path"]).read_bytes() == STORED
    assert main(["programs", "received", "../etc", "--state-dir", str(tmp_path)]) == 2


def test_a_requested_program_that_validation_refuses_is_not_sent(tmp_path: Path) -> None:
    folder = programs_folder(tmp_path)
    (folder / "BAD.nc").write_bytes(b"%\nO1235\nG0 X1\n%\n")  # no end code
    desk, tree, audited = make_desk(tmp_path, settings=PunchSettings(requests=RemoteRequests(folder=folder)))
    answer = desk.feed(b"%\nO9999 (PRG=BAD)\nM30\n%\n")
    assert answer is not None and answer.startswith(b"%\nO9999 (REJECTED BAD")
    assert [e.status for e in audited] == ["BadInvalidArgument"]
    assert str(value(tree, "Jobs/Dnc/LastRequest")).startswith("BAD: REJECTED BAD")


def queue_desk(
    tmp_path: Path, sources: list[str], **more: object
) -> tuple[PunchDesk, VariableTree, list[AuditEntry], list[tuple[bytes, str | None, bool]]]:
    folder = programs_folder(tmp_path)
    requests = RemoteRequests.model_validate({"folder": folder, "from": sources, **more})
    desk, tree, audited = make_desk(tmp_path, settings=PunchSettings(requests=requests))
    sent: list[tuple[bytes, str | None, bool]] = []

    async def find_job(machine: str, name: str) -> QueuedProgram | None:
        assert machine == "fanuc-1"
        return QueuedProgram(QUEUED, "O4711.nc", "alice", "J000007") if name == "O4711" else None

    desk.find_job = find_job
    desk.send_answer = lambda data, user, load: sent.append((data, user, load))
    return desk, tree, audited, sent


QUEUED = b"%\nO4711\nG0 X2\nM30\n%\n"


def test_a_request_is_answered_from_the_queues_accepted_jobs(tmp_path: Path) -> None:
    desk, tree, audited, sent = queue_desk(tmp_path, ["folder", "queue"])
    assert desk.feed(b"%\nO9999 (PRG=O4711)\nM30\n%\n") is None  # answered off the loop
    asyncio.run(desk.drain())
    assert sent == [(QUEUED, "alice", False)]  # the send names the job's submitter
    assert value(tree, "Jobs/Dnc/LastRequest") == "O4711: sent O4711.nc (J000007)"
    assert [(e.user, e.status) for e in audited] == [("operator", "Good")]


def test_the_folder_comes_first_when_from_says_so(tmp_path: Path) -> None:
    desk, _, _, sent = queue_desk(tmp_path, ["folder", "queue"], send="load")
    desk.feed(REQUEST)  # O1234: in the folder
    asyncio.run(desk.drain())
    assert sent == [(b"%\nO1234\nG0 X1\nM30\n%\n", "operator", True)]


@pytest.mark.parametrize(
    ("name", "comment", "status"),
    [
        ("O0815", "NOT FOUND O0815", "BadNotFound"),
        ("LINK", "NOT FOUND LINK", "BadNotFound"),
        ("../secret", "NAME LEAVES THE FOLDER", "BadInvalidArgument"),
    ],
)
def test_queue_requests_for_unknown_or_escaping_names_get_why(
    tmp_path: Path, name: str, comment: str, status: str
) -> None:
    desk, _, audited, sent = queue_desk(tmp_path, ["queue", "folder"])
    answer = desk.feed(f"%\nO9999 (PRG={name})\nM30\n%\n".encode())
    asyncio.run(desk.drain())
    answers = [a for a in [answer, *(s[0] for s in sent)] if a is not None]
    assert len(answers) == 1 and f"({comment})".encode() in answers[0]
    assert [e.status for e in audited] == [status]


def test_a_queue_request_to_queue_submits_the_jobs_program_in_its_submitters_name(tmp_path: Path) -> None:
    desk, _, _, sent = queue_desk(tmp_path, ["queue"], send="queue")
    submitted: list[tuple[str, str, bytes, str, str]] = []

    async def submit(machine: str, name: str, data: bytes, user: str, origin: str) -> str:
        submitted.append((machine, name, data, user, origin))
        return "J000008 queued"

    desk.submit = submit
    desk.feed(b"%\nO9999 (PRG=O4711)\nM30\n%\n")
    asyncio.run(desk.drain())
    assert submitted == [("fanuc-1", "O4711.nc", QUEUED, "alice", "dnc")] and sent == []


def test_programs_received_get_prints_or_saves_one_checked(
    tmp_path: Path, capsysbinary: pytest.CaptureFixture[bytes]
) -> None:
    from gateway.cli.main import main

    desk, _, _ = make_desk(tmp_path / "state")
    desk.feed(PUNCH)
    asyncio.run(desk.drain())
    base = ["programs", "received", "--state-dir", str(tmp_path / "state")]
    assert main([*base[:2], "fanuc-1", *base[2:], "--get", "O4711"]) == 0
    assert capsysbinary.readouterr().out == STORED
    out = tmp_path / "copy.nc"
    assert main([*base[:2], "fanuc-1", *base[2:], "--get", "bracket", "-o", str(out)]) == 0
    assert out.read_bytes() == STORED
    assert main([*base[:2], "fanuc-1", *base[2:], "--get", "O0815"]) == 1
    assert b"no program punched on fanuc-1 is named 'O0815'" in capsysbinary.readouterr().err
    assert main([*base, "--get", "O4711"]) == 2  # which machine's?
    [program] = desk.store.list()
    desk.store.path(program).write_bytes(STORED.replace(b"X10", b"X99"))  # changed since it arrived
    assert main([*base[:2], "fanuc-1", *base[2:], "--get", "O4711"]) == 1
    assert b"not the program received" in capsysbinary.readouterr().err
