"""The console's job upload on a shard with a shared PostgreSQL queue (docs/scaling.md): a job for a machine
of the fleet that another shard serves is validated here by that machine's rules and queued, with its
program in the database, for its shard to deliver; a bad one is refused with the validator's reason."""

from __future__ import annotations

from pathlib import Path

import aiohttp
import psycopg

from gateway.jobs.queue.records import JobState
from tests.integration.web.conftest import web_gateway
from tests.integration.web.test_uploads import PART

OTHER = "laser-elsewhere"


async def test_the_console_queues_a_job_for_another_shards_machine(tmp_path: Path, postgres_url: str) -> None:
    async with web_gateway(tmp_path, elsewhere=(OTHER,), queue=postgres_url) as rig:
        assert OTHER not in rig.gateway.tree.machines  # served elsewhere: not mirrored here
        otto = await rig.session("otto")
        form = aiohttp.FormData({"machine": OTHER})
        form.add_field("file", PART, filename="fleet.nc")
        async with otto.post("/api/jobs", data=form) as r:
            body = await r.json()
        assert r.status == 201 and body["message"].startswith(f"{body['job_id']} queued for {OTHER}"), body
        bad = aiohttp.FormData({"machine": OTHER})
        bad.add_field("file", b"%\nG1 X10 Q\n%\n", filename="bad.nc")
        async with otto.post("/api/jobs", data=bad) as r:
            refused = await r.json()
        assert r.status == 422 and "rejected" in refused["message"], refused
        unknown = aiohttp.FormData({"machine": "laser-nowhere"})
        unknown.add_field("file", PART, filename="x.nc")
        async with otto.post("/api/jobs", data=unknown) as r:
            assert r.status == 404
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        rows = conn.execute(
            "SELECT j.machine, j.state, COUNT(p.part) FROM jobs j LEFT JOIN job_programs p ON p.seq = j.seq"
            " GROUP BY j.seq, j.machine, j.state ORDER BY j.seq"
        ).fetchall()
    assert rows == [(OTHER, JobState.QUEUED.value, 1), (OTHER, JobState.REJECTED.value, 0)]
