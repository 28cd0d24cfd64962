"""The job queue's claims (QUEUED → SENDING) per second: the SQLite file against PostgreSQL (issue 29).

Each store gets `claims` jobs queued on a few machines, then claims every one of them:
one connection in a loop (SQLite's baseline, and PostgreSQL's), PostgreSQL again with a
fencing token checked in each claim (leases in the same database), and PostgreSQL with
one connection per machine claiming at once. PostgreSQL is the server at 127.0.0.1:5432
(CNC_BENCH_POSTGRES: another admin URL); each run gets a database of its own, dropped after.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import psycopg

from bench.context import Context
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.store import JobQueue
from gateway.shards.fence import Fence
from gateway.shards.leases import LeaseTable

SECTION = "Job queue: claims (QUEUED → SENDING), SQLite file and PostgreSQL (issue 29)"
ADMIN = os.environ.get("CNC_BENCH_POSTGRES", "postgresql://postgres@127.0.0.1:5432/postgres")
MACHINES = 4


@contextmanager
def database() -> Iterator[str]:
    name = f"cnc_bench_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(ADMIN, autocommit=True) as admin:
        admin.execute(f'CREATE DATABASE "{name}"'.encode())
    parts = urlsplit(ADMIN)
    try:
        yield urlunsplit((parts.scheme, parts.netloc, f"/{name}", parts.query, parts.fragment))
    finally:
        with psycopg.connect(ADMIN, autocommit=True) as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'.encode())


def fill(queue: JobStore, count: int) -> dict[str, list[int]]:
    seqs: dict[str, list[int]] = {f"m{k}": [] for k in range(MACHINES)}
    for i in range(count):
        machine = f"m{i % MACHINES}"
        job = queue.receive(machine, f"p{i}.nc", 10, f"sha-{i}")
        queue.accept(job.seq, duplicates="skip", program_size=10, program_sha256=job.sha256)
        seqs[machine].append(job.seq)
    return seqs


def claim_all(queue: JobStore, seqs: dict[str, list[int]], fence: Callable[[str], Fence | None]) -> float:
    started = time.perf_counter()
    for machine, mine in seqs.items():
        for seq in mine:
            queue.start_sending(seq, fence=fence(machine))
    return sum(map(len, seqs.values())) / (time.perf_counter() - started)


def measure(workdir: Path, count: int) -> dict[str, float]:
    figures: dict[str, float] = {}
    with JobQueue(workdir / "queue.sqlite3") as sqlite:
        figures["sqlite"] = claim_all(sqlite, fill(sqlite, count), lambda m: None)
    with database() as url, PostgresJobQueue(url) as pg:
        figures["postgresql"] = claim_all(pg, fill(pg, count), lambda m: None)
    with database() as url, PostgresJobQueue(url) as pg, LeaseTable(url, lease_time=600) as leases:
        fences = {}
        for k in range(MACHINES):
            lease = leases.acquire(f"m{k}", "bench")
            assert lease is not None
            fences[lease.machine] = lease.fence
        figures["postgresql_fenced"] = claim_all(pg, fill(pg, count), fences.get)
    with database() as url:
        with PostgresJobQueue(url) as pg:
            seqs = fill(pg, count)
        queues = [PostgresJobQueue(url).open() for _ in seqs]
        try:
            threads = [
                threading.Thread(target=claim_all, args=(q, {m: s}, lambda m: None))
                for q, (m, s) in zip(queues, seqs.items(), strict=True)
            ]
            started = time.perf_counter()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            figures["postgresql_parallel"] = count / (time.perf_counter() - started)
        finally:
            for q in queues:
                q.close()
    return figures


async def run(ctx: Context) -> None:
    count = 200 if ctx.settings.quick else 1000
    ctx.log(f"queue: {count} claims per store (SQLite, PostgreSQL at {urlsplit(ADMIN).netloc})")
    figures = await asyncio.to_thread(measure, ctx.workdir, count)
    r = ctx.results
    r.details["queue"] = {"claims": count, **figures}
    sqlite = figures["sqlite"]
    rows = (
        ("postgresql", "PostgreSQL, one connection"),
        ("postgresql_fenced", "PostgreSQL, a fencing token checked in each claim"),
        ("postgresql_parallel", f"PostgreSQL, {MACHINES} connections at once (a machine each), in total"),
    )
    r.add(
        "queue.claims.sqlite", SECTION, "SQLite file (synchronous=FULL), one connection", sqlite, "claims/s"
    )
    for key, label in rows:
        r.add(f"queue.claims.{key}", SECTION, label, figures[key], "claims/s", baseline=sqlite,
              baseline_label="SQLite file")  # fmt: skip
