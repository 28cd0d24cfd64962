"""Remote requests answered from the job queue's accepted programs, and answers that honour the line's mode,
over a real line (socket:// to the simulator's serial face): a delivered job's program is sent back when the
operator punches a request for it, logged with the job's submitter as the user; an unknown name gets the
short answer; on a drip line the answer is drip-fed (send: now), or loaded (send: load)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.jobs.queue.store import JobState
from gateway.model.audit import AuditEntry
from gateway.transports.dnc.transfers import TransferLog
from tests.integration.dnc.rig import (
    GATEWAY_BUFFER,
    SIM_BAUD,
    SPEED,
    Mode,
    body_lines,
    drip_program,
    face,
    load_program,
    simulator,
)
from tests.waiting import free_port, wait_until

Build = Callable[..., Any]


def mapping(where: str, *, mode: str, requests: str) -> str:
    return f"""
machine: lathe
driver: {{endpoint: "opc.tcp://127.0.0.1:{free_port()}", reconnect: {{initial: 0.2, max: 1}}}}
variables:
  - {{path: Machine/State, source: "ns=2;s=::AsGlobalPV:gMachine.State", type: Int16}}
jobs:
  controller: {{type: serial, where: "{where}", baud: {int(SIM_BAUD * SPEED)}, mode: {mode},
                buffer: {GATEWAY_BUFFER}, software_parity: true}}  # the rig's transparent port
  validation: {{dialect: laser-sim}}
  punch:
    requests: {requests}
"""


def sends(state: Path) -> list[Any]:
    log = TransferLog.in_state_dir(state, create=False)
    try:
        return [r.record for r in log.query() if r.record.direction == "send"]
    finally:
        log.close()


async def test_a_request_is_answered_with_a_delivered_jobs_program(harness: Build, tmp_path: Path) -> None:
    program = load_program(40)  # O4711 (BRACKET)
    audited: list[AuditEntry] = []
    async with simulator(tmp_path) as sim:
        text = mapping(face(sim).socket_url or "", mode="load", requests="{from: [queue], user: otto}")
        async with harness([text], accounts=[]) as h:
            h.tree.audit_sinks.append(audited.append)
            reply = await h.service.submit_bytes("lathe", "O4711.nc", program, user="alice", origin="test")
            assert reply.ok, reply.message
            [job] = h.jobs()
            await h.wait_state(job.seq, JobState.DELIVERED, timeout=30)
            kept = h.state / "jobs" / "spool" / "delivered" / "lathe" / f"{job.id}.program"
            await wait_until(
                kept.is_file, message="the delivered program kept for requests"
            )  # after DELIVERED
            assert kept.read_bytes() == program
            loaded = face(sim).controller.stats.programs_loaded
            await wait_until(lambda: face(sim).stats()["link"], message="the line open between jobs")

            face(sim).request("O4711")
            await wait_until(
                lambda: face(sim).controller.stats.programs_loaded > loaded, timeout=30, message="the answer"
            )
            assert sim.programs.read("O4711").encode() == program
            await wait_until(lambda: len(sends(h.state)) == 2, message="the answer's send logged")
            [answer] = [r for r in sends(h.state) if r.detail.startswith("answer")]
            assert (answer.outcome, answer.user) == ("ok", "alice")
            assert answer.detail.startswith("answer, load; ") and " DC3, " in answer.detail
            assert job.id in h.value("lathe", "Jobs/Dnc/LastRequest")
            assert [(e.target, e.user, e.status) for e in audited] == [("Dnc.Request", "otto", "Good")]

            face(sim).request("O0815")  # no job of that name: the short answer that says why
            await wait_until(
                lambda: face(sim).stats()["request_reply"] == "NOT FOUND O0815", timeout=30, message="why"
            )
            assert audited[-1].status == "BadNotFound"


async def test_an_answer_on_a_drip_line_is_drip_fed_and_can_be_paused(harness: Build, tmp_path: Path) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    data = drip_program(200)
    (folder / "O0042.nc").write_bytes(data)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        text = mapping(face(sim).socket_url or "", mode="drip", requests=f'{{folder: "{folder}"}}')
        async with harness([text], accounts=[]) as h:
            await wait_until(lambda: face(sim).stats()["link"], message="the line open between jobs")
            face(sim).request("O0042")
            line = h.service.delivery.transports["serial"].lines["lathe"]  # type: ignore[attr-defined]
            await wait_until(lambda: line.current is not None, timeout=30, message="the answer under way")
            assert line.pause() == "O0042 (DRIP) paused"
            assert line.resume() == "O0042 (DRIP) resumed"
            await wait_until(lambda: sends(h.state), timeout=60, message="the answer's send logged")
            [answer] = sends(h.state)
            assert answer.outcome == "ok"
            assert answer.detail.startswith("answer, drip; ") and " DC3, " in answer.detail
            body = body_lines(data)
            await wait_until(
                lambda: list(face(sim).controller.executed)[-len(body) :] == body,
                timeout=60,
                message="the controller ran the answer as it arrived",
            )


async def test_send_load_answers_a_drip_line_with_a_load(harness: Build, tmp_path: Path) -> None:
    folder = tmp_path / "programs"
    folder.mkdir()
    (folder / "O0042.nc").write_bytes(drip_program(20))
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        requests = f'{{folder: "{folder}", send: load}}'
        text = mapping(face(sim).socket_url or "", mode="drip", requests=requests)
        async with harness([text], accounts=[]) as h:
            await wait_until(lambda: face(sim).stats()["link"], message="the line open between jobs")
            face(sim).request("O0042")
            await wait_until(lambda: sends(h.state), timeout=60, message="the answer's send logged")
            [answer] = sends(h.state)
            assert (answer.outcome, answer.user) == ("ok", "operator")
            assert answer.detail.startswith("answer, load; ")
