"""`cnc-gateway jobs pause|resume|abort MACHINE` against a running gateway's drip-feed over a real line
(socket:// to the simulator's serial face): the command reaches the line through the state directory,
acts, is audited with origin cli and the OS user, and says why when there is nothing to act on."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from gateway.cli.main import main
from gateway.jobs.queue.store import JobState
from gateway.model.audit import AuditEntry
from gateway.transports.dnc.control import control_dir, owner
from tests.integration.dnc.rig import Mode, drip_program, face, simulator
from tests.integration.dnc.test_jobs import gateway, submit
from tests.waiting import wait_until

Build = Callable[..., Any]


async def shell(h: Any, *argv: str) -> int:
    return await asyncio.to_thread(main, ["jobs", *argv, "--state-dir", str(h.state)])


async def test_pause_resume_and_abort_from_the_shell(
    harness: Build, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    me = owner(Path(tmp_path).stat().st_uid)
    audited: list[AuditEntry] = []
    async with simulator(tmp_path, mode=Mode.DRIP) as sim, gateway(harness, sim) as h:
        h.tree.audit_sinks.append(audited.append)
        assert await shell(h, "pause", "lathe") == 1  # nothing is being sent: said, not a traceback
        assert "nothing is being sent" in capsys.readouterr().err

        seq = await submit(h, drip_program(600))
        await wait_until(lambda: face(sim).stats()["rx_chars"] > 500, timeout=30, message="drip under way")
        assert await shell(h, "pause", "lathe") == 0
        assert capsys.readouterr().out.strip() == "lathe: part.nc paused"
        await wait_until(lambda: h.value("lathe", "Jobs/Held") == "paused", message="held: paused")
        rx = face(sim).stats()["rx_chars"]
        assert await shell(h, "resume", "lathe") == 0
        await wait_until(lambda: face(sim).stats()["rx_chars"] > rx, timeout=30, message="sending again")
        assert await shell(h, "abort", "lathe") == 0
        job = await h.wait_state(seq, JobState.FAILED, timeout=30)
        assert f"aborted by {me}" in job.reason and "line" in job.reason, job.reason

        calls = [(e.target, e.origin, e.user, e.status) for e in audited]
        assert calls == [
            ("Commands.DripPause", "cli", me, "BadInvalidState"),
            ("Commands.DripPause", "cli", me, "Good"),
            ("Commands.DripResume", "cli", me, "Good"),
            ("Commands.DripAbort", "cli", me, "Good"),
        ]
        assert list(control_dir(h.state).iterdir()) == []  # requests and replies cleared


async def test_a_machine_without_a_line_or_a_gateway_that_is_not_running(
    harness: Build, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async with simulator(tmp_path) as sim, gateway(harness, sim) as h:
        assert await shell(h, "pause", "mill") == 1
        assert "mill has no serial line" in capsys.readouterr().err
        assert await shell(h, "resume", "../lathe") == 2
    assert await shell(h, "abort", "lathe", "--timeout", "0.3") == 1  # the gateway has stopped
    assert "no answer from the gateway" in capsys.readouterr().err
    assert [p for p in control_dir(h.state).iterdir() if p.suffix == ".request"] == []
