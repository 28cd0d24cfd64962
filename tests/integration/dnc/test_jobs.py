"""Serial DNC through the job queue: submit -> SENDING with drip progress -> DELIVERED, the transfer log,
a dropped line -> FAILED at a line, a gateway restart mid-drip that does not resend, DripRestart."""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from gateway.jobs.queue.store import JobState
from gateway.model.context import WriteContext
from gateway.transports.dnc.transfers import TransferLog
from simulator.alarms import DNC_LINE_DROPPED
from simulator.runner import Simulator
from tests.integration.dnc.rig import (
    GATEWAY_BUFFER,
    SIM_BAUD,
    SPEED,
    Mode,
    body_lines,
    drip_program,
    face,
    simulator,
)
from tests.waiting import free_port, wait_until

Build = Callable[..., Any]


def serial_mapping(
    where: str, *, mode: str = "drip", attempts: int = 3, opcua: int | None = None, alarm_when: bool = False
) -> str:
    alarm = "\n    alarm_when: {path: Machine/State, equals: 3}" if alarm_when else ""
    return f"""
machine: lathe
driver: {{endpoint: "opc.tcp://127.0.0.1:{opcua or free_port()}", reconnect: {{initial: 0.2, max: 1}}}}
variables:
  - {{path: Machine/State, source: "ns=2;s=::AsGlobalPV:gMachine.State", type: Int16}}
jobs:
  controller:
    type: serial
    where: "{where}"
    baud: {int(SIM_BAUD * SPEED)}
    software_parity: true  # the rig's device server is a transparent port
    mode: {mode}
    buffer: {GATEWAY_BUFFER}{alarm}
  validation: {{dialect: laser-sim}}
  retry: {{initial: 0.05, max: 0.2, factor: 2}}
  max_attempts: {attempts}
"""


@asynccontextmanager
async def gateway(harness: Build, sim: Simulator, **kw: Any) -> AsyncIterator[Any]:
    async with harness([serial_mapping(face(sim).socket_url or "", **kw)], accounts=[]) as h:
        yield h


async def submit(h: Any, data: bytes, name: str = "part.nc") -> int:
    reply = await h.service.submit_bytes("lathe", name, data, user="alice", origin="test")
    assert reply.ok, reply.message
    job = await wait_until(lambda: [j for j in h.jobs() if j.filename == name], message="the job")
    return int(job[0].seq)


async def call(h: Any, name: str, *args: Any) -> Any:
    machine = h.tree.machines["lathe"]
    method = machine.methods[("Commands", name)]
    return await machine.call_method(method, list(args), WriteContext("test", "bob", "admin"))


async def test_a_drip_job_shows_progress_and_is_logged(harness: Build, tmp_path: Path) -> None:
    data = drip_program(300)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim, gateway(harness, sim) as h:
        seq = await submit(h, data)
        await h.wait_state(seq, JobState.SENDING)
        await wait_until(lambda: h.value("lathe", "Jobs/Block") > 0, message="Jobs/Block")
        assert h.value("lathe", "Jobs/RemainingSeconds") > 0
        job = await h.wait_state(seq, JobState.DELIVERED, timeout=60)
        assert "drip-fed" in job.reason and "sha256" in job.reason
        log = TransferLog.in_state_dir(h.state, create=False)
        try:
            rows = log.query()
        finally:
            log.close()
        assert [(r.record.direction, r.record.outcome, r.record.user) for r in rows] == [
            ("send", "ok", "alice")
        ]
        assert rows[0].record.program == "part.nc" and rows[0].record.size > len(data)


async def test_a_cut_line_fails_the_job_at_a_line_and_drip_restart_completes_it(
    harness: Build, tmp_path: Path
) -> None:
    data = drip_program(400)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim, gateway(harness, sim) as h:
        seq = await submit(h, data)
        await wait_until(lambda: face(sim).stats()["rx_chars"] > 2000, timeout=30, message="drip under way")
        mark = len(face(sim).controller.executed)
        assert face(sim).drop_link()
        job = await h.wait_state(seq, JobState.FAILED, timeout=30)
        match = re.search(r"at line (\d+)", job.reason)
        assert match and "dropped" in job.reason, job.reason
        assert job.attempts == 1, "a drip that started is never sent again on its own"
        line = int(match.group(1))
        await wait_until(lambda: DNC_LINE_DROPPED in [a.id for a in sim.machine.alarms], message="086")
        sim.machine.reset()
        result = await call(h, "DripRestart", f"J{seq:06d}", line)
        assert "restart at line" in result[0]
        await h.wait_state(seq, JobState.DELIVERED, timeout=60)
        body = body_lines(data)
        # DELIVERED means sent: the controller may still be running the last blocks in its buffer.
        await wait_until(
            lambda: (
                list(face(sim).controller.executed)[mark:][-(len(body) - (line - 2)) :] == body[line - 2 :]
            ),
            timeout=30,
            message="the controller ran the program from the restart line to its end",
        )


async def test_a_gateway_restart_mid_drip_waits_for_an_operator(harness: Build, tmp_path: Path) -> None:
    data = drip_program(400)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        async with gateway(harness, sim) as h:
            seq = await submit(h, data)
            await wait_until(
                lambda: face(sim).stats()["rx_chars"] > 2000, timeout=30, message="drip under way"
            )
        await wait_until(
            lambda: face(sim).stats()["link"] == "", message="the line closed as the gateway stopped"
        )
        rx = face(sim).stats()["rx_chars"]
        async with gateway(harness, sim) as h:
            job = await h.wait_state(seq, JobState.FAILED, timeout=30)
            assert "interrupted by a gateway restart" in job.reason and "line" in job.reason, job.reason
            assert face(sim).stats()["rx_chars"] == rx, "nothing was sent again"
            from gateway.errors import NotFound

            with pytest.raises(NotFound):
                await call(h, "DripRestart", "J999999", 5)


@asynccontextmanager
async def mirrored(h: Any) -> AsyncIterator[None]:
    """The machine's OPC UA source, so that its variables (Machine/State) are in the tree."""
    from gateway.sources.registry import create_source

    [mapping] = h.service.config.machines
    source = create_source(h.tree.machines[mapping.machine], mapping)
    async with source:
        task = asyncio.create_task(source.run(), name="test:source")
        try:
            yield
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(Path(sys.executable).parent / "cnc-gateway"), *args],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )


async def test_the_cli_shows_drip_progress_and_restarts_a_failed_drip(harness: Build, tmp_path: Path) -> None:
    data = drip_program(400)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim, gateway(harness, sim) as h:
        seq = await submit(h, data)
        await wait_until(lambda: face(sim).stats()["rx_chars"] > 2000, timeout=30, message="drip under way")
        listing = await asyncio.to_thread(cli, "jobs", "list", "--state-dir", str(h.state))
        assert listing.returncode == 0, listing.stderr
        assert re.search(r"SENDING .*\d+% .*line \d+, lead \d+ s, \d+:\d\d left", listing.stdout), (
            listing.stdout
        )
        assert face(sim).drop_link()
        job = await h.wait_state(seq, JobState.FAILED, timeout=30)
        match = re.search(r"at line (\d+)", job.reason)
        assert match, job.reason
        sim.machine.reset()
        await wait_until(lambda: not sim.machine.alarms, message="the reset")
        restart = await asyncio.to_thread(
            cli, "jobs", "restart", f"J{seq:06d}", "--line", match.group(1), "--state-dir", str(h.state)
        )
        assert restart.returncode == 0 and f"restarts at line {match.group(1)}" in restart.stdout, (
            restart.stderr
        )
        job = await h.wait_state(seq, JobState.DELIVERED, timeout=60)
        assert f"from line {match.group(1)}" in job.reason


async def test_a_controller_alarm_mid_drip_fails_the_job_with_it(harness: Build, tmp_path: Path) -> None:
    from simulator.alarms import Alarm, Severity

    data = drip_program(400)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        text = serial_mapping(face(sim).socket_url or "", opcua=sim.opcua_port, alarm_when=True)
        async with harness([text], accounts=[]) as h, mirrored(h):
            await wait_until(
                lambda: h.tree.machines["lathe"].nodes["Machine/State"].sample.status == "Good",
                timeout=30,
                message="the machine's state mirrored",
            )
            seq = await submit(h, data)
            await wait_until(
                lambda: face(sim).stats()["rx_chars"] > 2000, timeout=30, message="drip under way"
            )
            sim.machine.raise_alarm(Alarm(9001, "Laser head collision", Severity.ERROR))
            job = await h.wait_state(seq, JobState.FAILED, timeout=30)
            assert "the controller is in alarm (Machine/State = 3)" in job.reason and "at line" in job.reason
            assert job.attempts == 1
