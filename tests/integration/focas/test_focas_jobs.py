"""A job to a FOCAS machine through the whole queue: FTP inbox → validation → queue → FOCAS download into
the simulator's memory folder → DELIVERED, checked by the folder's size (`verify: size`) or by uploading
it back and comparing SHA-256 (`verify: hash`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gateway.jobs.queue.store import JobState
from tests.integration.focas.conftest import simulator
from tests.integration.jobs.conftest import GOOD, Build, harness  # noqa: F401 - the fixture

MAPPING = """
machine: {name}
driver: {{type: focas, host: 127.0.0.1, port: {port}}}
variables:
  - {{path: Machine/Run, source: status.run, type: Int16}}
jobs:
  controller: {{type: focas, host: 127.0.0.1, port: {port}, timeout: 5}}
  validation: {{dialect: laser-sim}}
  retry: {{initial: 0.05, max: 0.2, factor: 2}}
  max_attempts: 3
  verify: {verify}
"""


async def test_a_job_goes_to_a_fanuc_over_focas(tmp_path: Path, harness: Build) -> None:  # noqa: F811
    async with simulator(tmp_path) as sim:
        assert sim.focas is not None
        texts = [
            MAPPING.format(name="fanuc-a", port=sim.focas.port, verify="size"),
            MAPPING.format(name="fanuc-b", port=sim.focas.port, verify="hash"),
        ]
        async with harness(texts, accounts=[_account(["fanuc-a", "fanuc-b"])]) as h:
            reply = await h.stor("fanuc-a", "part-a.nc", GOOD)
            assert reply.startswith("226"), reply
            job = await h.wait_state(1, JobState.DELIVERED, JobState.FAILED)
            assert job.state is JobState.DELIVERED, job
            assert job.delivered_name == "part-a.nc"
            assert (sim.store / "DATA" / "Programs" / "part-a.nc").read_bytes() == GOOD
            reply = await h.stor("fanuc-b", "part-b.nc", GOOD.replace(b"PART", b"PART B"))
            job = await h.wait_state(2, JobState.DELIVERED, JobState.FAILED)
            assert job.state is JobState.DELIVERED, job
            assert sim.focas.downloads == 2


def _account(machines: list[str]) -> dict[str, Any]:
    from tests.integration.jobs.conftest import PASSWORD_HASH, USER

    return {"user": USER, "password_hash": PASSWORD_HASH, "machines": machines}
