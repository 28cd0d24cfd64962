"""The job service on a PostgreSQL queue (`queue: postgresql://…`): from the FTP inbox to the controller.

A real inbox, a real FTP program store (the simulator's), a real PostgreSQL database; the queue's rows are
read back over a connection of their own, as another shard or the CLI would, and `cnc-gateway jobs -c`
finds the same queue through the gateway file.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.records import JobState
from simulator.fleet import SimulatorFleet, machine_name
from tests.integration.jobs.conftest import GOOD, Store, mapping_text
from tests.waiting import wait_until

S = JobState


async def test_an_upload_is_queued_in_postgresql_and_delivered_once(
    store: Store, harness, postgres_url: str, renames, tmp_path: Path
) -> None:
    async with harness([mapping_text("laser", store.port)], queue=postgres_url) as h:
        assert isinstance(h.queue, PostgresJobQueue)
        assert not (h.state / "jobs" / "queue.sqlite3").exists()  # no SQLite file beside it
        reply = await h.stor("laser", "part.nc", GOOD)
        assert reply.startswith("226 J000001 queued for laser")
        job = await h.wait_state(1, S.DELIVERED)
        assert job.attempts == 1 and store.files()["part.nc"] == GOOD
        assert renames.targets == ["part.nc"]
        await wait_until(
            lambda: h.value("laser", "Jobs/LastDelivered") == "J000001 part.nc", message="LastDelivered"
        )
        with PostgresJobQueue(postgres_url) as other:  # another process's view of the same queue
            assert [t.state for t in other.history(1)] == [
                S.RECEIVED,
                S.VALIDATED,
                S.QUEUED,
                S.SENDING,
                S.DELIVERED,
            ]
        gateway_file = tmp_path / "gateway.yaml"
        gateway_file.write_text(f"queue: {postgres_url}\nstate_dir: elsewhere\nmachines: [machine0.yaml]\n")
        proc = await asyncio.create_subprocess_exec(
            str(Path(sys.executable).with_name("cnc-gateway")),
            *("jobs", "list", "-c", str(gateway_file)),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        out, err = await proc.communicate()
        assert proc.returncode == 0, err.decode()
        assert out.decode().splitlines()[1].split()[:4] == ["J000001", "laser", "DELIVERED", "part.nc"]


async def test_a_job_for_one_machine_of_the_fleet_reaches_its_store_only(
    tmp_path: Path, harness, postgres_url: str
) -> None:
    async with SimulatorFleet(3, store_root=tmp_path / "stores") as fleet:
        mappings = [fleet.mapping(i) for i in (1, 2, 3)]
        async with harness(mappings, queue=postgres_url) as h:
            reply = await h.stor("laser-002", "part.nc", GOOD)
            assert reply.startswith("226 J000001 queued for laser-002")
            await h.wait_state(1, S.DELIVERED)
        stores = {
            machine_name(i): (
                tmp_path / "stores" / machine_name(i) / "DATA" / "Programs" / "part.nc"
            ).is_file()
            for i in (1, 2, 3)
        }
        assert stores == {"laser-001": False, "laser-002": True, "laser-003": False}
