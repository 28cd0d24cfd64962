"""The punch desk inside the job service, against the simulator: the line listens between jobs; a punch
is stored, shown in Jobs/Dnc/*, published as an event and listed by `cnc-gateway programs received`; a
remote request with `send: queue` becomes a job that the line delivers; requests are audited."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from gateway.cli.main import main
from gateway.jobs.queue.store import JobState
from gateway.model.audit import AuditEntry
from tests.integration.dnc.rig import SIM_BAUD, SPEED, face, load_program, simulator
from tests.waiting import free_port, wait_until

Build = Callable[..., Any]
ANSWER = b"%\nO1234 (ANSWER)\nG21 G90\nG1 X5 Y5 F1000\nM30\n%\n"


def punch_mapping(where: str, folder: Path, send: str) -> str:
    return f"""
machine: lathe
driver: {{endpoint: "opc.tcp://127.0.0.1:{free_port()}", reconnect: {{initial: 0.2, max: 1}}}}
variables:
  - {{path: Machine/State, source: "ns=2;s=::AsGlobalPV:gMachine.State", type: Int16}}
jobs:
  controller: {{type: serial, where: "{where}", baud: {int(SIM_BAUD * SPEED)}, mode: load,
                software_parity: true}}  # the rig's device server is a transparent port
  validation: {{dialect: laser-sim}}
  punch:
    validate: true
    requests: {{folder: "{folder}", send: {send}, user: otto}}
"""


async def test_a_punch_reaches_the_tree_the_events_and_the_cli(
    harness: Build, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    program = load_program(30)
    folder = tmp_path / "programs"
    folder.mkdir()
    async with simulator(tmp_path) as sim:
        mapping = punch_mapping(face(sim).socket_url or "", folder, "load")
        async with harness([mapping], accounts=[]) as h:
            events = h.tree.events.subscribe("test")
            sim.programs.write("O4711", program)
            await wait_until(lambda: face(sim).stats()["link"], message="the line open between jobs")
            face(sim).punch("O4711")
            stored = await wait_until(lambda: h.value("lathe", "Jobs/Dnc/LastReceived"), timeout=30)
            assert stored.endswith("-O4711-BRACKET.nc")
            assert h.value("lathe", "Jobs/Dnc/LastReceivedVerdict") == "accepted"
            assert h.value("lathe", "Jobs/Dnc/ReceivedCount") == 1
            [event] = [e for e in events.take() if e.channel == "dnc/received"]
            assert event.machine == "lathe" and event.payload["file"] == stored  # type: ignore[index,call-overload]
    assert main(["programs", "received", "--state-dir", str(h.state), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert Path(record["path"]).read_bytes() == program and record["verdict"] == "accepted"
    assert main(["dnc", "log", "--state-dir", str(h.state)]) == 0
    assert "lathe <- O4711 (BRACKET)" in capsys.readouterr().out


async def test_a_request_to_queue_becomes_a_job_the_line_delivers(harness: Build, tmp_path: Path) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "O1234.nc").write_bytes(ANSWER)
    audited: list[AuditEntry] = []
    async with simulator(tmp_path) as sim:
        mapping = punch_mapping(face(sim).socket_url or "", folder, "queue")
        async with harness([mapping], accounts=[]) as h:
            h.tree.audit_sinks.append(audited.append)
            await wait_until(lambda: face(sim).stats()["link"], message="the line open between jobs")
            face(sim).request("O1234")
            [job] = await wait_until(h.jobs, timeout=30, message="the request queued as a job")
            assert (job.filename, job.user, job.origin) == ("O1234.nc", "otto", "dnc")
            await h.wait_state(job.seq, JobState.DELIVERED, timeout=30)
            await wait_until(lambda: sim.programs.exists("O1234"), message="the program loaded")
            assert sim.programs.read("O1234").encode() == ANSWER
            assert [(e.target, e.user, e.status) for e in audited] == [("Dnc.Request", "otto", "Good")]
