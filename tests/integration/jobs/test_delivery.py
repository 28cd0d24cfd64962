"""Delivery to a real FTP program store: retries, dead letters, duplicates, order, recovery after a crash."""

from __future__ import annotations

import asyncio
import hashlib
import io
import subprocess
import sys
from pathlib import Path

from gateway.jobs.queue.store import JobQueue, JobState
from gateway.jobs.spool import queue_path
from simulator.ftp_store import FtpStore
from tests.integration.jobs.conftest import (
    GOOD,
    STORE_PASSWORD,
    STORE_USER,
    Store,
    in_thread,
    mapping_text,
    program,
)
from tests.waiting import free_port, wait_until

S = JobState


async def cli(*args: str) -> tuple[int, str, str]:
    proc = await asyncio.create_subprocess_exec(
        str(Path(sys.executable).with_name("cnc-gateway")),
        *args,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    out, err = await proc.communicate()
    return proc.returncode or 0, out.decode(), err.decode()


async def test_a_controller_that_is_down_fails_the_job_after_retries_and_a_retry_delivers_it(
    harness, tmp_path: Path, renames
) -> None:
    port = free_port()  # nothing listens here yet
    async with harness([mapping_text("laser", port, attempts=3)]) as h:
        assert (await h.stor("laser", "part.nc", GOOD)).startswith("226 J000001 queued")
        job = await h.wait_state(1, S.FAILED)
        assert job.attempts == 3 and "after 3 attempts" in job.reason and "unreachable" in job.reason
        history = [t.reason for t in h.queue.history(1) if t.state is S.QUEUED]
        assert any("attempt 1 of 3 failed" in r for r in history) and any(
            "attempt 2 of 3" in r for r in history
        )
        await wait_until(
            lambda: h.value("laser", "Jobs/LastFailed") == "J000001 part.nc", message="LastFailed"
        )
        assert h.value("laser", "Jobs/LastFailedReason") == job.reason
        assert h.value("laser", "Jobs/FailedCount") == 1
        assert (h.state / "jobs" / "spool" / "J000001.program").read_bytes() == GOOD  # kept for a retry

        root = tmp_path / "late-controller"
        from simulator.store import DirectoryStore

        DirectoryStore(root).prepare()
        async with FtpStore(root, host="127.0.0.1", port=port, user=STORE_USER, password=STORE_PASSWORD):
            code, out, err = await cli("jobs", "retry", "J000001", "--state-dir", str(h.state))
            assert code == 0, err
            assert out.startswith("J000001 QUEUED: retry requested by")
            job = await h.wait_state(1, S.DELIVERED)  # the running service noticed the CLI's change
            assert (root / "DATA" / "Programs" / "part.nc").read_bytes() == GOOD
        assert job.attempts == 1
        await wait_until(lambda: h.value("laser", "Jobs/FailedCount") == 0, message="FailedCount back to 0")


async def test_a_controller_that_refuses_us_fails_with_its_reply(
    store: Store, tmp_path: Path, harness
) -> None:
    text = mapping_text("laser", store.port, attempts=2).replace("password: simulator", "password: wrong")
    async with harness([text]) as h:
        await h.stor("laser", "part.nc", GOOD)
        job = await h.wait_state(1, S.FAILED)
        assert "refused the login: 530" in job.reason


async def test_duplicates_are_skipped_while_the_first_waits(harness) -> None:
    async with harness([mapping_text("laser", free_port(), attempts=1000)]) as h:
        first = await h.stor("laser", "a.nc", GOOD)
        second = await h.stor("laser", "a-again.nc", GOOD)
        assert first.startswith("226 J000001 queued")
        assert second.startswith("226 J000002 skipped: duplicate of J000001")
        assert h.job(2).state is S.REJECTED
        assert not (h.state / "jobs" / "spool" / "J000002.program").exists()


async def test_replace_cancels_the_waiting_copy(harness) -> None:
    extra = "duplicates: replace"
    async with harness([mapping_text("laser", free_port(), attempts=1000).rstrip() + f"\n  {extra}\n"]) as h:
        await h.stor("laser", "a.nc", GOOD)
        assert (await h.stor("laser", "a.nc", GOOD)).startswith("226 J000002 queued")
        assert h.job(1).state is S.CANCELLED and "replaced by J000002" in h.job(1).reason


async def test_site_priority_and_cancel_from_the_cli(harness) -> None:
    async with harness([mapping_text("laser", free_port(), attempts=1000)]) as h:
        for name in ("first", "dropped"):
            await h.stor("laser", f"{name}.nc", program(name))

        def urgent() -> str:
            ftp = h.ftp()
            ftp.cwd("/laser")
            ftp.sendcmd("SITE PRIORITY 5")
            reply = ftp.storbinary("STOR urgent.nc", io.BytesIO(program("urgent")))
            ftp.quit()
            return reply

        assert (await in_thread(urgent)).startswith("226 J000003")
        assert h.job(3).priority == 5 and h.job(1).priority == 0
        code, out, err = await cli("jobs", "cancel", "J000002", "--state-dir", str(h.state))
        assert code == 0 and out.startswith("J000002 CANCELLED"), err
        assert h.job(2).state is S.CANCELLED
        code, _, err = await cli("jobs", "cancel", "J000099", "--state-dir", str(h.state))
        assert code == 1 and "no job J000099" in err


async def test_jobs_go_in_priority_then_arrival_order_and_cancelled_ones_not_at_all(
    store: Store, harness, tmp_path: Path, renames
) -> None:
    state = tmp_path / "state"
    spool = state / "jobs" / "spool"
    spool.mkdir(parents=True)
    with JobQueue(queue_path(state)) as q:
        for name, priority in (("first", 0), ("second", 0), ("dropped", 0), ("urgent", 5), ("later", -1)):
            data = program(name)
            digest = hashlib.sha256(data).hexdigest()
            job = q.receive("laser", f"{name}.nc", len(data), digest, priority=priority)
            q.accept(job.seq, duplicates="skip", program_size=len(data), program_sha256=digest)
            (spool / f"{job.id}.program").write_bytes(data)
        q.cancel(3)
    async with harness([mapping_text("laser", store.port)]) as h:
        for seq in (1, 2, 4, 5):
            await h.wait_state(seq, S.DELIVERED, timeout=20)
        assert renames.targets == ["urgent.nc", "first.nc", "second.nc", "later.nc"]
        assert h.job(3).state is S.CANCELLED and "dropped.nc" not in store.files()


async def test_verify_by_hash_downloads_the_program_back(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port).rstrip() + "\n  verify: hash\n"]) as h:
        await h.stor("laser", "part.nc", GOOD)
        await h.wait_state(1, S.DELIVERED)


# --- after a crash: jobs found SENDING ---------------------------------------------------------------


def left_sending(state: Path, name: str, data: bytes) -> None:
    """What a gateway killed mid-delivery leaves: a job in SENDING and its program in the spool."""
    with JobQueue(queue_path(state)) as q:
        digest = hashlib.sha256(data).hexdigest()
        job = q.receive("laser", name, len(data), digest, user="nest", origin="ftp")
        q.accept(job.seq, duplicates="skip", program_size=len(data), program_sha256=digest)
        q.start_sending(job.seq)
    spool = state / "jobs" / "spool"
    spool.mkdir(parents=True, exist_ok=True)
    (spool / f"{job.id}.program").write_bytes(data)


async def test_a_job_that_reached_the_controller_before_the_crash_is_not_sent_again(
    store: Store, harness, tmp_path: Path, renames
) -> None:
    left_sending(tmp_path / "state", "part.nc", GOOD)
    (store.folder() / "part.nc").write_bytes(GOOD)  # renamed into place just before the crash
    (store.folder() / "part.nc.tmp").write_bytes(GOOD[:5])  # and a stale temporary upload of an older try
    async with harness([mapping_text("laser", store.port)]) as h:
        job = await h.wait_state(1, S.DELIVERED)
        assert job.reason == "found complete on the controller after a restart"
        assert renames.targets == []
        assert "part.nc.tmp" not in store.files()
        assert job.attempts == 1


async def test_a_job_cut_off_by_the_crash_is_sent_again_once(
    store: Store, harness, tmp_path: Path, renames
) -> None:
    left_sending(tmp_path / "state", "part.nc", GOOD)
    (store.folder() / "part.nc.tmp").write_bytes(GOOD[:20])  # the upload the crash interrupted
    (store.folder() / "part.nc").write_bytes(GOOD.replace(b"X50", b"X60"))  # an older program, same size
    async with harness([mapping_text("laser", store.port)]) as h:
        job = await h.wait_state(1, S.DELIVERED)
        assert renames.targets == ["part.nc"]
        assert store.files()["part.nc"] == GOOD and "part.nc.tmp" not in store.files()
        assert job.attempts == 2
        assert "interrupted by a restart" in [t.reason for t in h.queue.history(1)][-3]


async def test_an_upload_received_but_not_yet_checked_is_finished_after_a_restart(
    store: Store, harness, tmp_path: Path
) -> None:
    state = tmp_path / "state"
    with JobQueue(queue_path(state)) as q:
        kept = q.receive("laser", "kept.nc", len(GOOD), hashlib.sha256(GOOD).hexdigest())
        lost = q.receive("laser", "lost.nc", 10, "00")
    (state / "jobs" / "spool").mkdir(parents=True)
    (state / "jobs" / "spool" / f"{kept.id}.received").write_bytes(GOOD)
    async with harness([mapping_text("laser", store.port)]) as h:
        await h.wait_state(kept.seq, S.DELIVERED)
        lost_job = await h.wait_state(lost.seq, S.REJECTED)
        assert "lost" in lost_job.reason


async def test_jobs_cli_lists_and_shows(store: Store, harness) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:
        await h.stor("laser", "part.nc", GOOD)
        await h.stor("laser", "bad.nc", b"G1 X1\n")
        await h.wait_state(1, S.DELIVERED)
        code, out, err = await cli("jobs", "list", "--state-dir", str(h.state))
        assert code == 0, err
        lines = out.splitlines()
        assert lines[0].split()[:3] == ["JOB", "MACHINE", "STATE"]
        assert lines[1].split()[:4] == ["J000002", "laser", "REJECTED", "bad.nc"]
        assert lines[2].split()[:4] == ["J000001", "laser", "DELIVERED", "part.nc"]
        code, out, err = await cli("jobs", "show", "1", "--state-dir", str(h.state))
        assert code == 0, err
        assert "state      DELIVERED" in out and "extents    X 10..50  Y 10..40" in out
        assert [line.split()[2] for line in out.split("history:")[1].strip().splitlines()] == [
            "RECEIVED",
            "VALIDATED",
            "QUEUED",
            "SENDING",
            "DELIVERED",
        ]
        code, out, err = await cli(
            "jobs", "list", "--json", "--state", "rejected", "--state-dir", str(h.state)
        )
        import json

        assert [j["id"] for j in json.loads(out)] == ["J000002"]
