"""Many lines at once: drip-feeds that share a device server's link, against simulated controllers.

Three of the simulator's DNC faces (raw TCP device servers, each with its own
machine cutting what it receives) are drip-fed at once by three serial transports
in one fleet (gateway/transports/dnc/fleet.py). Their link to the device server is
configured narrower than what the machines would take together, so the scheduler
must share it: the device servers together never receive faster than the link
carries, the machines get their shares alike, and every program runs byte for byte.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator
from pathlib import Path

from gateway.codecs.dnc import LineSettings
from gateway.transports.dnc.fleet import DripFleet
from gateway.transports.dnc.transport import SerialTransport
from simulator.dnc.controller import DncSpec
from simulator.dnc.face import DncFace
from simulator.dnc.links import Link
from simulator.dnc.uart import DeviceServer
from simulator.machine import Machine
from simulator.store import MemoryStore
from tests.integration.dnc.rig import (
    ROOMY,
    SIM_BAUD,
    SPEED,
    Mode,
    Progresses,
    body_lines,
    drip_program,
    program_file,
    settings,
)
from tests.waiting import wait_until

CAPACITY = 1500.0  # characters/s the shared link carries: less than the three machines would take


class CountingFace(DncFace):
    """A DNC face that notes when each piece of data reached its device server, and how much."""

    arrivals: list[tuple[float, int]]

    def link_data(self, link: Link, data: bytes) -> None:
        self.arrivals.append((time.monotonic(), len(data)))
        super().link_data(link, data)


@contextlib.asynccontextmanager
async def controllers(count: int) -> AsyncIterator[list[CountingFace]]:
    spec = DncSpec(line=LineSettings(baud=SIM_BAUD), mode=Mode.DRIP, **ROOMY)
    faces = [
        CountingFace(
            spec,
            Machine(MemoryStore()),
            MemoryStore(),
            tcp_port=0,
            speed=SPEED,
            device_server=DeviceServer.TRANSPARENT,  # as the rig's: `settings` sets software_parity
        )
        for _ in range(count)
    ]
    async with contextlib.AsyncExitStack() as stack:
        for face in faces:
            face.arrivals = []
            await stack.enter_async_context(face)

        async def cut() -> None:
            last = time.monotonic()
            while True:
                await asyncio.sleep(0.01)
                now = time.monotonic()
                for face in faces:
                    face.machine.step((now - last) * SPEED)
                last = now

        ticker = asyncio.create_task(cut(), name="test:machines")
        try:
            yield faces
        finally:
            ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await ticker


async def test_lines_sharing_a_link_keep_to_its_capacity_share_it_and_run_byte_for_byte(
    tmp_path: Path,
) -> None:
    data = drip_program(200, step=0.2, feed=1200)  # 10 ms of cutting per 16-byte block at speed 1
    async with controllers(3) as faces:
        line_settings = [
            settings(
                face.socket_url or "",
                mode="drip",
                buffer=ROOMY["high_water"],
                link="nport-1",
                link_capacity=CAPACITY,
            )
            for face in faces
        ]
        fleet = DripFleet.for_lines((f"m{i}", s) for i, s in enumerate(line_settings))
        assert fleet.links == {"nport-1": CAPACITY}
        lines = [
            SerialTransport(s, machine=f"m{i}", state_dir=tmp_path / f"m{i}", fleet=fleet)
            for i, s in enumerate(line_settings)
        ]
        marks = [len(face.controller.executed) for face in faces]
        try:
            await asyncio.gather(
                *(
                    line.deliver(program_file(tmp_path, data, f"part{i}.nc"), Progresses())
                    for i, line in enumerate(lines)
                )
            )
        finally:
            for line in lines:
                line.close()
        for face, mark in zip(faces, marks, strict=True):
            await wait_until(
                lambda face=face, mark=mark: list(face.controller.executed)[mark:] == body_lines(data),
                timeout=60,
                message="each machine ran its program, line for line",
            )
            assert not face.machine.alarms and face.stats()["overflows"] == 0

    arrivals = sorted(a for face in faces for a in face.arrivals)
    total = sum(n for _, n in arrivals)
    assert total >= 3 * len(data)
    # Without the link's limit the three lines would carry far more (each line alone: 7,000 chars/s, the
    # machines together cut about 4,800 chars/s at this speed); a busy machine only makes it slower.
    seconds = arrivals[-1][0] - arrivals[0][0]
    assert total / seconds <= CAPACITY * 1.1, f"{total / seconds:.0f} chars/s through a {CAPACITY:g} link"
    # Shared alike: when the first line had its whole program, the others had most of theirs.
    done = [sum(n for _, n in face.arrivals) for face in faces]
    first_done = min(
        next(t for t, total in _running(face.arrivals) if total >= full)
        for face, full in zip(faces, done, strict=True)
    )
    for face, full in zip(faces, done, strict=True):
        got = sum(n for t, n in face.arrivals if t <= first_done)
        assert got >= 0.7 * full, f"a line had {got} of {full} characters when another had all of its own"


def _running(arrivals: list[tuple[float, int]]) -> list[tuple[float, int]]:
    out, total = [], 0
    for t, n in arrivals:
        total += n
        out.append((t, total))
    return out
