"""Drill: the gateway is killed (SIGKILL) at random moments while it delivers jobs, and started again.

N times (5; 50 in soak): a batch of programs of random sizes is uploaded to the
inbox (each answered `226 … queued`), then, at a random moment during the
batch's delivery to the controller's FTP program store (slowed to 1 MB/s so that
uploads are caught half-way), the gateway process is SIGKILLed and started again.
At the end every job must be DELIVERED exactly once: the queue holds each job
once, in DELIVERED; the store holds each program once, byte for byte; the store's
log shows exactly one completed upload (RNTO) per program; no temporary file is
left behind.

The moments are random but seeded: the seed is printed, and `CNC_DRILL_SEED=<seed>`
replays the same choices (timings on a busy machine still vary).
"""

from __future__ import annotations

import asyncio
import ftplib
import hashlib
import io
import os
import random
from collections import Counter
from pathlib import Path

import pytest

from gateway.jobs.queue.store import JobQueue, JobState
from gateway.jobs.spool import queue_path
from tests.integration.drills import processes
from tests.integration.drills.conftest import Report, count
from tests.integration.jobs.conftest import (
    PASSWORD,
    PASSWORD_HASH,
    USER,
    Renames,
    Store,
    in_thread,
    mapping_text,
)
from tests.waiting import free_port, wait_until

KILLS = count("gateway_kills")
RATE = 1_000_000  # bytes/s to the controller
BATCH = 3  # programs uploaded per cycle
SIZES = (50_000, 400_000)  # bytes per program
S = JobState


def program(tag: str, size: int) -> bytes:
    """A valid laser-sim program of about `size` bytes whose content depends on `tag`."""
    lines = ["%", f"({tag})", "G21 G90"]
    total, i = 0, 0
    while total < size:
        line = f"N{i} G1 X{i % 1000}.5 Y{(i * 7) % 1000}.25 F6000 (nest {tag} part {i % 37})"
        lines.append(line)
        total += len(line) + 1
        i += 1
    return ("\n".join([*lines, "M30", "%"]) + "\n").encode()


def upload(port: int, name: str, data: bytes) -> str:
    ftp = ftplib.FTP()
    ftp.connect("127.0.0.1", port, timeout=30)
    try:
        ftp.login(USER, PASSWORD)
        return ftp.storbinary(f"STOR /laser/{name}", io.BytesIO(data))
    finally:
        ftp.close()


@pytest.mark.timeout(120 + 12 * KILLS)
async def test_gateway_kills_deliver_every_job_exactly_once(
    store: Store, renames: Renames, tmp_path: Path, drill_report: Report
) -> None:
    seed = int(os.environ.get("CNC_DRILL_SEED") or random.SystemRandom().randrange(2**32))
    rng = random.Random(seed)
    inbox_port = free_port()
    mapping = mapping_text("laser", store.port, opcua_port=free_port()).replace(
        "timeout: 5}", f"timeout: 5, rate_limit: {RATE}}}"
    )
    (tmp_path / "laser.yaml").write_text(mapping)
    gw_file = processes.gateway_file(
        tmp_path, ["laser.yaml"], opcua_port=free_port(), inbox_port=inbox_port,
        inbox={"reply_within": 30, "accounts": [{"user": USER, "password_hash": PASSWORD_HASH}]},
    )  # fmt: skip
    gateway = processes.gateway(tmp_path, gw_file)
    sent: dict[str, bytes] = {}  # file name -> program, for every job the inbox queued
    caught = Counter[str]()  # what each kill interrupted
    queue: JobQueue | None = None
    try:
        for cycle in range(KILLS):
            await asyncio.to_thread(gateway.start)
            await asyncio.to_thread(processes.wait_for_port, gateway, inbox_port)
            if queue is None:
                queue = JobQueue(queue_path(tmp_path / "state")).open()
            batch = []
            for n in range(BATCH):
                name = f"c{cycle:03d}-{n}.nc"
                data = program(f"{seed}-{cycle}-{n}", rng.randint(*SIZES))
                reply = await in_thread(upload, inbox_port, name, data)
                assert reply.startswith("226 J") and "queued" in reply, (name, reply, gateway.tail())
                sent[name] = data
                batch.append((int(reply.split()[1][1:]), len(data)))
            # A random moment while the batch is being delivered: some job of it under way, a random
            # share of its transfer time later.
            seq, size = rng.choice(batch)
            share = rng.random()
            await wait_until(lambda s=seq, q=queue: q.get(s).state in (S.SENDING, S.DELIVERED), timeout=60,
                             message=f"J{seq:06d} to be under way (seed {seed})")  # fmt: skip
            await asyncio.sleep(share * size / RATE)
            await asyncio.to_thread(gateway.kill)
            sending = queue.list(states=(S.SENDING,), limit=10)
            temps = [p for p in store.folder().iterdir() if p.name.endswith(".tmp")]
            if sending and temps:
                caught["mid_upload"] += 1
            elif sending:
                caught["sending"] += 1
            else:
                caught["between_jobs"] += 1
        await asyncio.to_thread(gateway.start)
        assert queue is not None
        await wait_until(
            lambda: queue.count(states=(S.DELIVERED,)) == len(sent), timeout=60 + len(sent),
            message=f"every job DELIVERED (seed {seed})",
        )  # fmt: skip
        jobs = queue.list(limit=100_000, newest_first=False)
        histories = {job.seq: [t.reason for t in queue.history(job.seq)] for job in jobs}
    finally:
        await asyncio.to_thread(gateway.stop)
        if queue is not None:
            queue.close()

    completed = Counter(renames.targets)
    on_store = store.files()
    resent = sum(1 for reasons in histories.values() if "interrupted by a restart; sending again" in reasons)
    found = sum(1 for reasons in histories.values()
                if any("found complete on the controller" in r for r in reasons))  # fmt: skip
    lost = [name for name in sent if name not in on_store]
    wrong = [name for name, data in sent.items() if name in on_store and on_store[name] != data]
    twice = sorted(name for name, n in completed.items() if n > 1)
    drill_report(
        "gateway kills", seed=seed, kills=KILLS, jobs=len(sent),
        delivered=sum(j.state is S.DELIVERED for j in jobs),
        duplicates=len(twice), lost=len(lost), corrupt=len(wrong), kills_mid_upload=caught["mid_upload"],
        kills_while_sending=caught["sending"], kills_between_jobs=caught["between_jobs"], resent=resent,
        found_complete_after_restart=found,
    )  # fmt: skip
    assert len(jobs) == len(sent) and all(j.state is S.DELIVERED for j in jobs), f"seed {seed}"
    assert {j.filename for j in jobs} == set(sent)
    assert lost == [] and wrong == [], f"seed {seed}: lost {lost}, corrupt {wrong}"
    assert twice == [] and set(completed) == set(sent), f"seed {seed}: uploads completed {completed}"
    assert not [p.name for p in store.folder().iterdir() if p.name.endswith(".tmp")]
    for name, data in sent.items():  # and the queue's record matches what arrived
        job = next(j for j in jobs if j.filename == name)
        assert job.program_sha256 == hashlib.sha256(data).hexdigest()
