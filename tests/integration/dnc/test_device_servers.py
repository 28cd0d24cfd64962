"""Serial DNC through both kinds of raw-TCP device server, the gateway configured as a user would from the
README, the controller's 256-byte buffer told truthfully (issue 22).

- `7bit` (the simulator's default): a Moxa NPort or Lantronix whose port is set 7E2, as one is set up
  for a Fanuc. Its UART does the parity: the controller's DC1 and DC3 reach the gateway as 0x11 and
  0x13. The mapping leaves `software_parity` at its default.
- `transparent`: a port set 8N1/8N2; the parity bit travels as bit 7, so the mapping says
  `software_parity: true`.

Whatever the kind, the controller's DC3 must stop the line: its buffer never overruns (alarm 087), the
characters that reach it after its DC3 stay few (its own count; a bound that only a broken flow control
exceeds, since the simulator's own wake-up lateness adds a little at 9,600 baud), and the job's record
reports the DC3s the gateway saw. The line runs at 9,600 baud in real time (speed 1), where a
millisecond of the simulator's lateness is less than one character.
"""

from __future__ import annotations

import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from gateway.jobs.queue.store import JobState
from gateway.transports.dnc.received import ReceivedStore
from simulator.alarms import DNC_BUFFER_OVERFLOW
from simulator.dnc import DeviceServer
from simulator.machine import MachineState
from simulator.runner import Simulator
from tests.integration.dnc.rig import (
    Mode,
    body_lines,
    face,
    load_program,
    paced_program,
    simulator,
    user_mapping,
)
from tests.integration.dnc.test_jobs import submit
from tests.waiting import wait_until

Build = Any

BAUD = 9600
SPEED = 1.0
TRUTHFUL = {"buffer_size": 256, "high_water": None, "low_water": None}  # DC3 at 224, DC1 at 64
AFTER_DC3 = 16  # characters after a DC3: a few of the simulator's lateness; a DC3 ignored gives hundreds
RATE = 520.0  # characters per second the machines really cut: 60 % of the line (873 characters a second)
KINDS = [DeviceServer.SEVEN_BIT, DeviceServer.TRANSPARENT]


@asynccontextmanager
async def gateway(
    harness: Build, sim: Simulator, kind: DeviceServer, **controller: Any
) -> AsyncIterator[Any]:
    text = user_mapping(face(sim).socket_url or "", kind, baud=int(BAUD * SPEED), buffer=256, **controller)
    async with harness([text], accounts=[]) as h:
        yield h


async def finished(h: Any, seq: int, sim: Simulator, *, timeout: float) -> Any:
    """The job once it ended; on the deadline, what the controller saw (so a failure says why)."""
    try:
        return await h.wait_state(seq, JobState.DELIVERED, JobState.FAILED, timeout=timeout)
    except TimeoutError as exc:
        raise AssertionError(f"{exc}; the controller: {controller_view(sim)}") from None


async def ran_to_the_end(sim: Simulator) -> None:
    """DELIVERED means sent: wait for the machine to run what its buffer still holds (or to stop in an
    alarm, which the asserts after this then name)."""
    await wait_until(
        lambda: (
            sim.machine.state is MachineState.ALARM
            or (face(sim).stats()["drips"] == 1 and sim.machine.state is MachineState.IDLE)
        ),
        timeout=30,
        message="the machine to run the rest of its buffer",
    )


def controller_view(sim: Simulator) -> dict[str, Any]:
    s = face(sim).stats()
    keys = ("stage", "dc3_sent", "dc1_sent", "after_dc3_max", "overflows", "parity_errors", "starvations")
    return {k: s[k] for k in keys} | {"alarms": [a.id for a in sim.machine.alarms]}


def dc3_reported(reason: str) -> int:
    """The DC3s the job's record says the gateway saw ("…; 12 DC3, at most 3 characters after one")."""
    match = re.search(r"(\d[\d,]*) DC3", reason)
    assert match, f"the job's record does not report the DC3s: {reason}"
    return int(match.group(1).replace(",", ""))


def assert_flow_control_held(sim: Simulator) -> None:
    seen = controller_view(sim)
    assert seen["overflows"] == 0 and DNC_BUFFER_OVERFLOW not in seen["alarms"], f"alarm 087: {seen}"
    assert seen["after_dc3_max"] <= AFTER_DC3, f"characters after the controller's DC3: {seen}"
    assert seen["parity_errors"] == 0, seen


@pytest.mark.parametrize("kind", KINDS, ids=[k.value for k in KINDS])
async def test_a_drip_to_a_machine_slower_than_the_estimate_is_held_by_its_dc3(
    harness: Build, tmp_path: Path, kind: DeviceServer
) -> None:
    # The machine cuts at half the gateway's estimate (feed override 50 %): the buffer fills, DC3 and
    # DC1 take turns.
    data = paced_program(3000, factor=0.5, rate=RATE, speed=SPEED)
    async with (
        simulator(tmp_path, speed=SPEED, baud=BAUD, device_server=kind, override=50, mode=Mode.DRIP,
                  **TRUTHFUL) as sim,
        gateway(harness, sim, kind) as h,
    ):  # fmt: skip
        seq = await submit(h, data)
        job = await finished(h, seq, sim, timeout=len(data) / RATE * 3 + 30)
        assert_flow_control_held(sim)
        assert job.state is JobState.DELIVERED, job.reason
        await ran_to_the_end(sim)
        assert_flow_control_held(sim)
        sent = face(sim).stats()["dc3_sent"]
        assert sent >= 1, "the machine never let its buffer fill: the test proves nothing"
        assert 1 <= dc3_reported(job.reason) <= sent, (job.reason, sent)
        assert list(face(sim).controller.executed) == body_lines(data)


@pytest.mark.parametrize("kind", KINDS, ids=[k.value for k in KINDS])
async def test_a_load_into_a_slow_program_memory_is_held_by_its_dc3(
    harness: Build, tmp_path: Path, kind: DeviceServer
) -> None:
    data = load_program(150)  # about 2.6 KB, taken at RATE characters per second
    async with (
        simulator(tmp_path, speed=SPEED, baud=BAUD, device_server=kind, mode=Mode.LOAD, load_rate=RATE,
                  **TRUTHFUL) as sim,
        gateway(harness, sim, kind, mode="load") as h,
    ):  # fmt: skip
        seq = await submit(h, data)
        job = await finished(h, seq, sim, timeout=len(data) / RATE * 3 + 30)
        assert_flow_control_held(sim)
        assert job.state is JobState.DELIVERED, job.reason
        await wait_until(lambda: sim.programs.exists("O4711"), timeout=30, message="O4711 stored")
        assert sim.programs.read("O4711").encode() == data
        sent = face(sim).stats()["dc3_sent"]
        assert sent >= 1 and 1 <= dc3_reported(job.reason) <= sent, (job.reason, sent)


@pytest.mark.parametrize("kind", KINDS, ids=[k.value for k in KINDS])
async def test_a_punch_through_either_device_server_is_stored_as_punched(
    harness: Build, tmp_path: Path, kind: DeviceServer
) -> None:
    async with (
        simulator(tmp_path, speed=SPEED, baud=BAUD, device_server=kind, **TRUTHFUL) as sim,
        gateway(harness, sim, kind, punch={"validate": True}) as h,
    ):  # fmt: skip
        await wait_until(lambda: face(sim).controller.connected, timeout=20, message="the gateway listening")
        face(sim).punch("demo.nc")
        face(sim).kick()
        store = ReceivedStore(h.state)
        [program] = await wait_until(lambda: store.list("lathe"), timeout=30, message="the punch stored")
    stored = store.path(program).read_bytes()
    assert stored.replace(b"\r\n", b"\n").strip(b"%\n") == sim.programs.read("demo.nc").encode().strip(b"%\n")
    assert program.number == 1001 and program.verdict == "accepted"
