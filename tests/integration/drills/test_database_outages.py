"""Drill: the job queue's PostgreSQL goes away under a running job service and comes back, again and again.

Issue 29's database drill (3 rounds in `make test`, 30 in `make soak`). The database is cut the way a restart
or a network cut looks from the gateway: the server ends every session of the queue's database and refuses
new ones (`ALLOW_CONNECTIONS false`), for a couple of seconds, then lets them in again. The shared server
itself is not restarted (other tests use it); the gateway sees the same thing: its connections dropped,
its reconnects refused. Each round: a job uploaded before the cut is delivered; one uploaded during it is
refused with a reason or queued, never lost; after it, one is queued and delivered. At the end every job
the inbox accepted is DELIVERED once with its program on the controller, and no traceback was logged.
"""

from __future__ import annotations

import asyncio
import re
import time
from urllib.parse import urlsplit

import psycopg
import pytest

from gateway.jobs.queue.records import JobState
from tests.integration.drills.conftest import Records, Report, count
from tests.integration.jobs.conftest import Store, mapping_text, program
from tests.postgres import ADMIN_URL

S = JobState
OUTAGE = 2.0  # s the database stays away each round: about a restart's length


def _set_reachable(database: str, reachable: bool) -> None:
    with psycopg.connect(ADMIN_URL, autocommit=True, connect_timeout=5) as admin:
        admin.execute(f'ALTER DATABASE "{database}" ALLOW_CONNECTIONS {str(reachable).lower()}'.encode())
        if not reachable:
            admin.execute(
                "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = %s", (database,)
            )


@pytest.mark.timeout(1800)
async def test_jobs_survive_the_queue_database_going_away_and_back(
    store: Store, harness, postgres_url: str, records: Records, drill_report: Report
) -> None:
    rounds = count("database_outages")
    database = urlsplit(postgres_url).path.lstrip("/")
    accepted: dict[int, str] = {}  # job number -> program name
    refused: list[str] = []
    queued_during = 0
    async with harness([mapping_text("laser", store.port)], queue=postgres_url) as h:

        async def upload(name: str) -> str:
            reply = await h.stor("laser", name, program(name))
            if reply.startswith("226 "):
                match = re.match(r"226 J(\d+) queued", reply)
                assert match, reply
                accepted[int(match.group(1))] = name
            return reply

        try:
            for r in range(rounds):
                before = await upload(f"before{r}.nc")
                assert before.startswith("226 "), before
                await h.wait_state(max(accepted), S.DELIVERED, timeout=30)
                _set_reachable(database, False)
                cut_at = time.monotonic()
                during = await upload(f"during{r}.nc")
                if during.startswith("226 "):
                    queued_during += 1
                else:
                    assert re.match(r"4\d\d |5\d\d ", during), during
                    refused.append(during)
                await asyncio.sleep(max(0.0, OUTAGE - (time.monotonic() - cut_at)))
                _set_reachable(database, True)
                after = await upload(f"after{r}.nc")
                assert after.startswith("226 "), f"round {r}: the inbox after the database came back: {after}"
            for seq in accepted:
                await h.wait_state(seq, S.DELIVERED, timeout=60)
        finally:
            _set_reachable(database, True)
        delivered = store.files()
        for seq, name in accepted.items():
            assert delivered.get(name) == program(name), f"J{seq:06d} {name} not on the controller as sent"
            assert h.job(seq).attempts >= 1
        tracebacks = [r for r in records.records if r.exc_info and r.levelname in ("ERROR", "CRITICAL")]
        assert not tracebacks, [r.getMessage() for r in tracebacks]
    drill_report(
        "database outages",
        rounds=rounds,
        accepted=len(accepted),
        delivered=len(accepted),
        queued_during_outage=queued_during,
        refused_during_outage=len(refused),
        refusal=refused[0] if refused else "",
    )
