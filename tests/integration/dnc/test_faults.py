"""Drip-feed faults and control: a dropped line, pause/resume, abort, restart at a line (byte for byte)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gateway.errors import DeliveryError
from gateway.transports.dnc.transfer import TransferFailed
from gateway.transports.dnc.transport import SerialTransport, request_restart
from simulator.alarms import DNC_LINE_DROPPED
from simulator.runner import Simulator
from tests.integration.dnc.rig import (
    Mode,
    Progresses,
    body_lines,
    drip_program,
    face,
    line_index,
    program_file,
    simulator,
    transport,
)
from tests.waiting import wait_until


async def drip_until_idle(sim: Simulator) -> None:
    await wait_until(
        lambda: (
            sim.machine.state.name == "IDLE" and face(sim).stats()["stage"] in ("reading", "idle", "offline")
        ),
        timeout=60,
        message="the drip program to end",
    )


async def cut_and_resume(sim: Simulator, tmp_path: Path, data: bytes, cut_after: float) -> tuple[int, int]:
    """Drip `data`, cut the device server's link `cut_after` s in, resume at the line the job names.

    Returns (the resume line, bytes sent before the cut). Asserts the controller ran every line before
    the resume line, and after the resume exactly the header, the modal block and the program from it.
    """
    line = transport(face(sim).socket_url or "", tmp_path, mode="drip")
    program = program_file(tmp_path, data)
    before = len(face(sim).controller.executed)
    task = asyncio.create_task(line.deliver(program, Progresses()))
    await asyncio.sleep(cut_after)
    assert not task.done(), "the drip ended before the cut"
    assert face(sim).drop_link()
    with pytest.raises(TransferFailed) as failed:
        await task
    exc = failed.value
    assert exc.permanent and exc.resume_line is not None
    assert f"at line {exc.resume_line}" in exc.reason and "dropped" in exc.reason
    await wait_until(lambda: DNC_LINE_DROPPED in [a.id for a in sim.machine.alarms], message="alarm 086")
    ran = list(face(sim).controller.executed)[before:]
    body = body_lines(data)
    index = line_index(data, exc.resume_line)
    assert ran[:index] == body[:index], "every line before the resume line ran, as sent"
    # The operator resets the controller, then resumes at the line the job names.
    sim.machine.reset()
    await wait_until(lambda: not sim.machine.alarms, message="the reset")
    request_restart(program.path, exc.resume_line)
    mark = len(face(sim).controller.executed)
    await line.deliver(program, Progresses())
    await drip_until_idle(sim)
    resumed = list(face(sim).controller.executed)[mark:]
    header = [b"O0042 (DRIP)", b"G21 G90"]
    assert resumed[:2] == header
    assert resumed[2].startswith(b"G21 G90") and b"RESTART AT LINE" in resumed[2]
    assert resumed[3:] == body[index:], "from the resume line on, the program byte for byte"
    assert not sim.machine.alarms
    return exc.resume_line, exc.offset


async def test_a_dropped_line_fails_the_drip_with_its_line_and_a_resume_completes_it(tmp_path: Path) -> None:
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        resume, sent = await cut_and_resume(sim, tmp_path, drip_program(300), 1.5)
        assert resume > 5 and sent > 256


async def test_pause_holds_the_line_and_resume_finishes_the_program(tmp_path: Path) -> None:
    data = drip_program(200)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        line = transport(face(sim).socket_url or "", tmp_path, mode="drip")
        progress = Progresses()
        task = asyncio.create_task(line.deliver(program_file(tmp_path, data), progress))
        await wait_until(
            lambda: line.current is not None and progress and progress[-1].sent > 1000, message="sending"
        )
        line.pause()
        await wait_until(lambda: progress[-1].held == "paused", message="held")
        held_at = progress[-1].sent
        await wait_until(lambda: sim.machine.starvations > 0, timeout=30, message="the controller runs dry")
        assert progress[-1].sent == held_at, "nothing goes out while paused"
        line.resume()
        await task
        await drip_until_idle(sim)
        assert list(face(sim).controller.executed)[-len(body_lines(data)) :] == body_lines(data)


async def test_abort_fails_the_drip_and_nothing_more_is_sent(tmp_path: Path) -> None:
    data = drip_program(300)
    async with simulator(tmp_path, mode=Mode.DRIP) as sim:
        line = transport(face(sim).socket_url or "", tmp_path, mode="drip")
        progress = Progresses()
        task = asyncio.create_task(line.deliver(program_file(tmp_path, data), progress))
        await wait_until(lambda: progress and progress[-1].sent > 1000, message="sending")
        line.abort("tester")
        with pytest.raises(DeliveryError) as failed:
            await task
        assert failed.value.permanent and "aborted by tester" in failed.value.reason
        rx = face(sim).stats()["rx_chars"]
        await asyncio.sleep(0.5)  # nothing to wait for: the line is closed; look that no byte came
        assert face(sim).stats()["rx_chars"] == rx


async def test_no_dc1_fails_after_the_timeout(tmp_path: Path) -> None:
    async with simulator(tmp_path, auto_dc1=False) as sim:
        line = transport(face(sim).socket_url or "", tmp_path, dc1_timeout=0.5)
        with pytest.raises(DeliveryError) as failed:
            await line.deliver(program_file(tmp_path, drip_program(5)), Progresses())
        assert "no DC1" in failed.value.reason
        assert face(sim).stats()["rx_chars"] == 0


async def test_an_unreachable_device_server_is_a_retryable_failure(tmp_path: Path) -> None:
    from tests.waiting import free_port

    line: SerialTransport = transport(f"socket://127.0.0.1:{free_port()}", tmp_path)
    with pytest.raises(DeliveryError) as failed:
        await line.deliver(program_file(tmp_path, drip_program(5)), Progresses())
    assert not failed.value.permanent and "unreachable" in failed.value.reason
