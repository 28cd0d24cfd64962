"""Drill: the device server's connection is cut at random moments in the middle of drip-feeds.

N times (3; 30 in soak), through the job queue, against the simulator's serial
DNC face over socket://: a drip-fed job is under way, the simulated device
server drops its connection at a random point. Each time the job is FAILED
with the line to resume at, and it is not sent again on its own (one attempt,
the line stays down); every line before that one ran on the controller; a
DripRestart there, after the operator's Reset, completes the program: the
controller then runs the header, the modal block and the program from that
line, byte for byte (a cut so early that the controller may not have run a
motion yet resumes with the whole program).
"""

from __future__ import annotations

import random
import re
from pathlib import Path
from typing import Any

import pytest

from gateway.jobs.queue.store import JobState
from simulator.alarms import DNC_LINE_DROPPED
from tests.integration.dnc.rig import Mode, body_lines, drip_program, face, simulator
from tests.integration.dnc.test_jobs import call, gateway, submit
from tests.integration.drills.conftest import Report, count
from tests.waiting import wait_until

CUTS = count("dnc_cuts")


@pytest.mark.timeout(90 + 20 * CUTS)
async def test_device_server_cuts_mid_drip(harness: Any, tmp_path: Path, drill_report: Report) -> None:
    cuts = CUTS
    rng = random.Random(14)
    resumed_at: list[int] = []
    async with simulator(tmp_path, mode=Mode.DRIP) as sim, gateway(harness, sim) as h:
        for cut in range(cuts):
            data = drip_program(300, step=0.5 + cut * 0.01)  # a new program each time (no duplicate)
            body = body_lines(data)
            first_motion = next(i for i, ln in enumerate(body) if ln.startswith((b"G0 ", b"G1 ")))
            start_rx = face(sim).stats()["rx_chars"]
            mark = len(face(sim).controller.executed)
            seq = await submit(h, data, f"cut{cut}.nc")
            target = start_rx + rng.randrange(600, len(data) - 1500)
            await wait_until(
                lambda t=target: face(sim).stats()["rx_chars"] > t,
                timeout=60,
                message="the drip under way",
            )
            assert face(sim).drop_link(), "the link was up"
            job = await h.wait_state(seq, JobState.FAILED, timeout=30)
            match = re.search(r"at line (\d+)", job.reason)
            assert match and "dropped" in job.reason, job.reason
            line = int(match.group(1))
            await wait_until(lambda: DNC_LINE_DROPPED in [a.id for a in sim.machine.alarms], message="086")
            ran = list(face(sim).controller.executed)[mark:]
            index = line - 2  # body_lines index of source line `line` (line 1 is the opening %)
            assert ran[:index] == body[:index], f"cut {cut}: a line before {line} did not run"
            assert h.job(seq).attempts == 1 and face(sim).stats()["link"] == "", "sent again on its own"
            sim.machine.reset()
            await wait_until(lambda: not sim.machine.alarms, message="the reset")
            resume_mark = len(face(sim).controller.executed)
            await call(h, "DripRestart", f"J{seq:06d}", line)
            await h.wait_state(seq, JobState.DELIVERED, timeout=60)
            await wait_until(
                lambda: sim.machine.state.name == "IDLE" and face(sim).stats()["stage"] != "running",
                timeout=60,
                message="the resumed drip to end",
            )
            resumed = list(face(sim).controller.executed)[resume_mark:]
            if index <= first_motion:
                # Cut before the controller could have run a motion (it may have held everything sent):
                # a restart that early is the whole program again.
                assert resumed == body, f"cut {cut}: a restart at line {line} is not the whole program"
            else:
                assert b"RESTART AT LINE %d" % line in resumed[2], resumed[:3]
                assert resumed[3:] == body[index:], f"cut {cut}: the resume is not the program from {line}"
            resumed_at.append(line)
    drill_report(
        "dnc cuts", cuts=cuts, failed_at_a_line=len(resumed_at), completed_byte_for_byte=len(resumed_at)
    )
    assert len(resumed_at) == cuts
