"""Any shard's inbox for any machine, on one PostgreSQL queue that carries the programs (docs/scaling.md).

Two gateways' job services, static shards 1/2 and 2/2 of one gateway file over a simulator fleet of two,
each with its own state directory, on one real PostgreSQL database: a job dropped into shard 1's FTP
inbox for shard 2's machine is validated and queued by shard 1 and delivered by shard 2, from the copy in
the database. A copy changed in the database is refused and kept. On a SQLite queue, an inbox refuses
another shard's machine and says why.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

import psycopg
import pytest

from gateway.config.loader import load
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.records import Job, JobState
from gateway.jobs.service import JobService
from simulator.fleet import SimulatorFleet
from tests.integration.jobs.conftest import PASSWORD_HASH, USER, Renames, in_thread, inbox_stor, program
from tests.trees import MappedTree
from tests.waiting import wait_until

S = JobState


@dataclass
class Shard:
    service: JobService
    state: Path

    @property
    def queue(self) -> JobStore:
        return self.service.queue

    @property
    def port(self) -> int:
        assert self.service.inbox is not None
        return self.service.inbox.port

    def spooled(self) -> list[str]:
        """What is in the spool (programs waiting, uploads being validated), by file name."""
        root = self.state / "jobs" / "spool"
        return sorted(p.name for p in root.iterdir() if p.is_file()) if root.is_dir() else []


def gateway_text(k: int, queue: str | None) -> str:
    lines = [
        "machines: [laser-001.yaml, laser-002.yaml]",
        f"shard: {k}/2",
        f"state_dir: state-{k}",
        "inbox:",
        "  host: 127.0.0.1",
        "  port: 0",
        f"  accounts: [{{user: {USER}, password_hash: '{PASSWORD_HASH}'}}]",
    ]
    if queue is not None:
        lines.append(f"queue: {queue}")
    return "\n".join(lines) + "\n"


@asynccontextmanager
async def shard(folder: Path, k: int, queue: str | None) -> AsyncIterator[Shard]:
    """Shard k/2's job service, as `cnc-gateway run` would build it from the gateway file."""
    path = folder / f"gateway-{k}.yaml"
    path.write_text(gateway_text(k, queue))
    config = load([path], environ={})
    service = JobService(config, MappedTree(config.machines), environ={})
    async with service:
        task = asyncio.create_task(service.run(), name=f"test:shard-{k}")
        try:
            yield Shard(service, config.state_dir)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def stor(port: int, machine: str, name: str, data: bytes) -> str:
    """STOR into /<machine>/ of the inbox at `port`: the final reply, or the refusal's text."""
    return await in_thread(inbox_stor, port, machine, name, data)


async def wait_state(queue: JobStore, seq: int, *states: JobState, timeout: float = 20.0) -> Job:
    return await wait_until(
        lambda: (j := queue.get(seq)).state in states and j,
        timeout=timeout,
        message=f"J{seq:06d} in {'/'.join(s.value for s in states)}",
    )


def stored_parts(url: str, seq: int) -> int:
    with psycopg.connect(url, autocommit=True) as conn:
        row = conn.execute("SELECT COUNT(*) FROM job_programs WHERE seq = %s", (seq,)).fetchone()
    assert row is not None
    return int(row[0])


class Fetches(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if "read from the job queue" in record.getMessage():
            self.messages.append(record.getMessage())


@pytest.fixture
def fetches() -> Iterator[Fetches]:
    handler = Fetches()
    logger = logging.getLogger("gateway.jobs.delivery")
    old = logger.level
    logger.setLevel(logging.INFO)
    logger.addHandler(handler)
    yield handler
    logger.removeHandler(handler)
    logger.setLevel(old)


def controller_file(root: Path, machine: str, name: str) -> Path:
    return root / machine / "DATA" / "Programs" / name


async def test_a_job_in_shard_1s_inbox_for_shard_2s_machine_is_delivered_by_shard_2_once(
    tmp_path: Path, postgres_url: str, renames: Renames, fetches: Fetches
) -> None:
    stores = tmp_path / "stores"
    data = program("any shard", lines=2000)  # about 45 kB
    async with SimulatorFleet(2, store_root=stores) as fleet:
        fleet.write_mappings(tmp_path)
        async with shard(tmp_path, 1, postgres_url) as one, shard(tmp_path, 2, postgres_url) as two:
            assert set(one.service.machines) == {"laser-001"} and set(two.service.machines) == {"laser-002"}
            reply = await stor(one.port, "laser-002", "part.nc", data)
            assert reply.startswith("226 J000001 queued for laser-002"), reply
            job = await wait_state(two.queue, 1, S.DELIVERED, S.FAILED)
            assert job.state is S.DELIVERED, job.reason
            delivered = controller_file(stores, "laser-002", "part.nc").read_bytes()
            assert hashlib.sha256(delivered).hexdigest() == hashlib.sha256(data).hexdigest()
            assert not controller_file(stores, "laser-001", "part.nc").exists()
            assert renames.targets == ["part.nc"]  # one upload reached a controller
            states = [t.state for t in two.queue.history(1)]
            assert states == [S.RECEIVED, S.VALIDATED, S.QUEUED, S.SENDING, S.DELIVERED]  # one claim
            assert job.attempts == 1
            # Shard 2 took its program from the database, not from an upload of its own ...
            assert fetches.messages == [
                f"laser-002: J000001's program read from the job queue ({len(data)} bytes, SHA-256 checked)"
            ]
            assert not (two.state / "inbox" / "laser-002" / "part.nc").exists()
            # ... and neither spool, nor the database, keeps it once delivered.
            await wait_until(lambda: not one.spooled() and not two.spooled(), message="spools empty")
            assert stored_parts(postgres_url, 1) == 0


async def test_a_program_changed_in_the_database_is_refused_and_kept(
    tmp_path: Path, postgres_url: str, renames: Renames
) -> None:
    stores = tmp_path / "stores"
    data = program("changed in the database")
    async with SimulatorFleet(2, store_root=stores) as fleet:
        fleet.write_mappings(tmp_path)
        async with shard(tmp_path, 1, postgres_url) as one:  # shard 2 is not running yet
            reply = await stor(one.port, "laser-002", "part.nc", data)
            assert reply.startswith("226 J000001 queued for laser-002"), reply
            assert not one.spooled()  # shard 1 does not keep what it does not deliver
        with psycopg.connect(postgres_url, autocommit=True) as conn:
            row = conn.execute("SELECT data FROM job_programs WHERE seq = 1 AND part = 0").fetchone()
            assert row is not None and bytes(row[0]) == data
            changed = bytes(row[0]).replace(b"X1 ", b"X9 ", 1)
            conn.execute("UPDATE job_programs SET data = %s WHERE seq = 1 AND part = 0", (changed,))
        async with shard(tmp_path, 2, postgres_url) as two:
            job = await wait_state(two.queue, 1, S.FAILED, S.DELIVERED)
            assert job.state is S.FAILED
            assert "the program read back from the job queue is not the one validated" in job.reason
            assert hashlib.sha256(changed).hexdigest() in job.reason
            assert "cnc-gateway jobs retry J000001" in job.reason
            assert not controller_file(stores, "laser-002", "part.nc").exists() and renames.targets == []
            assert not two.spooled()  # the changed bytes are not left where a transport reads
            assert stored_parts(postgres_url, 1) == 1  # kept: the job is FAILED, not lost


async def test_an_inbox_on_its_own_sqlite_queue_refuses_another_shards_machine(tmp_path: Path) -> None:
    async with SimulatorFleet(2, store_root=tmp_path / "stores") as fleet:
        fleet.write_mappings(tmp_path)
        async with shard(tmp_path, 1, None) as one:
            reply = await stor(one.port, "laser-002", "part.nc", program("elsewhere"))
            assert reply.startswith("550 /laser-002: laser-002 is served by another shard"), reply
            assert "queue: postgresql://" in reply
            unknown = await stor(one.port, "laser-999", "part.nc", program("nowhere"))
            assert unknown.startswith("550 /laser-999: no such machine folder"), unknown
            assert one.queue.count() == 0
            mine = await stor(one.port, "laser-001", "part.nc", program("mine"))
            assert mine.startswith("226 J000001 queued for laser-001"), mine
