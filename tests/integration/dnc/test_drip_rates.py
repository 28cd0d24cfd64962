"""Drip-feeds to machines that cut slower and faster than the gateway's run-time estimate (issue 22).

"The estimate" is the gateway's (gateway/codecs/dnc/runtime.py, `block_times` with the line's `rapid`):
a machine at 8x consumes the program 8 times faster than it says, as one at a 150-200 % feed override,
with rapids faster than the estimator's, or reading a feed per revolution as mm/min does. The
simulator's machine runs at a feed override of 100 x the factor; each program's feed moves are paced so
that the machine really consumes about RATE characters a second (a third of the 9,600-baud line), so
that the line can always keep up: a starvation is the gateway's doing.

Through both kinds of device server, configured as a user would, with the controller's 256-byte buffer
told truthfully: the machine never starves (at 0.5x, 1x, 1.5x and 8x), its buffer never overruns (alarm
087), the characters after its DC3 stay few, and it runs every block as sent.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.jobs.queue.store import JobState
from simulator.dnc import DeviceServer
from tests.integration.dnc.rig import Mode, body_lines, face, paced_program, simulator
from tests.integration.dnc.test_device_servers import (
    BAUD,
    KINDS,
    RATE,
    SPEED,
    TRUTHFUL,
    Build,
    assert_flow_control_held,
    controller_view,
    finished,
    gateway,
    ran_to_the_end,
)
from tests.integration.dnc.test_jobs import submit

FACTORS = [0.5, 1.0, 1.5, 8.0]
SIZE = 2000  # bytes: about 7 s of cutting at RATE


@pytest.mark.parametrize("kind", KINDS, ids=[k.value for k in KINDS])
@pytest.mark.parametrize("factor", FACTORS, ids=[f"{f:g}x" for f in FACTORS])
async def test_a_machine_faster_or_slower_than_the_estimate_never_starves_nor_overruns(
    harness: Build, tmp_path: Path, kind: DeviceServer, factor: float
) -> None:
    data = paced_program(SIZE, factor=factor, rate=RATE, speed=SPEED)
    async with (
        simulator(tmp_path, speed=SPEED, baud=BAUD, device_server=kind, override=round(100 * factor),
                  mode=Mode.DRIP, **TRUTHFUL) as sim,
        gateway(harness, sim, kind) as h,
    ):  # fmt: skip
        seq = await submit(h, data)
        job = await finished(h, seq, sim, timeout=len(data) / RATE * 3 + 30)
        assert job.state is JobState.DELIVERED, (job.reason, controller_view(sim))
        await ran_to_the_end(sim)
        seen = controller_view(sim)
        assert_flow_control_held(sim)
        assert seen["starvations"] == 0, f"the machine ran dry at {factor:g}x the estimate: {seen}"
        assert list(face(sim).controller.executed) == body_lines(data)
