"""Uploads are checked as they stream in; a check that no longer matches the file is never used.

The job service then has the verdict moments after the last byte and stores the
upload by a hard link, without reading it again (`validate_file` is not called).
Whenever the file may differ from what was checked (appended to, renamed into
another machine's folder) or the delivered program would differ (XON/XOFF bytes
stripped), the stored file is validated as before.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import aioftp
import pytest

from bench.gcode_gen import laser_program
from gateway.jobs.queue.store import JobState
from gateway.jobs.validation import compiled
from gateway.jobs.validation.file_check import ISOLATE_ABOVE, validate_file
from tests.integration.jobs.conftest import PASSWORD, USER, Harness, Store, in_thread, mapping_text

pytestmark = pytest.mark.skipif(
    compiled.plain is None, reason="uploads are checked on arrival with the compiled reader"
)

S = JobState
LARGE = laser_program(2 * ISOLATE_ABOVE, seed=31, number=31)


@contextmanager
def spying(h: Harness) -> Iterator[dict[str, int]]:
    """Counts the calls to the check thread and to validate_file (in a thread or the process)."""
    threads = h.service.threads
    counts = {"checking": 0, "validate_file": 0}
    originals = threads.checking, threads.work, threads.process

    def checking(fn: Any, *args: Any) -> Any:
        counts["checking"] += 1
        return originals[0](fn, *args)

    def counted(original: Any) -> Any:
        async def run(fn: Any, *args: Any, **kwargs: Any) -> Any:
            counts["validate_file"] += fn is validate_file
            return await original(fn, *args, **kwargs)

        return run

    threads.checking, threads.work, threads.process = checking, counted(originals[1]), counted(originals[2])  # type: ignore[method-assign]
    try:
        yield counts
    finally:
        threads.checking, threads.work, threads.process = originals  # type: ignore[method-assign]


async def test_a_large_upload_renamed_into_place_is_queued_on_its_check_on_arrival(
    store: Store, harness
) -> None:
    async with harness([mapping_text("laser", store.port)]) as h:
        with spying(h) as counts:
            async with aioftp.Client.context("127.0.0.1", h.port, USER, PASSWORD) as client:
                async with client.upload_stream("/laser/O31.nc.part") as stream:
                    for start in range(0, len(LARGE), 100_000):
                        await stream.write(LARGE[start : start + 100_000])
                await client.rename("/laser/O31.nc.part", "/laser/O31.nc")
            job = await h.wait_state(1, S.DELIVERED)
        assert counts["validate_file"] == 0 and counts["checking"] >= 2  # the blocks, then the verdict
        assert job.sha256 == hashlib.sha256(LARGE).hexdigest() and job.program_size == len(LARGE)
        assert job.estimate is not None and job.estimate["blocks"] > 10_000
        assert store.files()["O31.nc"] == LARGE


async def test_a_rejected_plain_stor_gets_its_reason_from_the_check_on_arrival(store: Store, harness) -> None:
    bad = LARGE.replace(b"M30\n", b"")
    async with harness([mapping_text("laser", store.port)]) as h:
        with spying(h) as counts:
            reply = await h.stor("laser", "O31.nc", bad)
        assert reply.startswith("550 J000001 rejected") and "end code" in reply
        assert counts["validate_file"] == 0 and counts["checking"] >= 2
        kept = h.state / "rejected" / "J000001-O31.nc"
        assert kept.read_bytes() == bad
        assert "[end-code]" in kept.with_name(kept.name + ".reason").read_text()


async def test_an_appended_upload_is_validated_as_stored(store: Store, harness) -> None:
    """The check saw the first part only: after APPE the stored file is validated again, as a whole."""
    head, tail = LARGE[: len(LARGE) // 2], LARGE[len(LARGE) // 2 :]
    async with harness([mapping_text("laser", store.port)]) as h:

        def run() -> str:
            ftp = h.ftp()
            try:
                ftp.storbinary("STOR /laser/O31.nc.part", io.BytesIO(head))
                ftp.storbinary("APPE /laser/O31.nc.part", io.BytesIO(tail))
                ftp.sendcmd("RNFR /laser/O31.nc.part")
                return ftp.sendcmd("RNTO /laser/O31.nc")
            finally:
                ftp.close()

        with spying(h) as counts:
            reply = await in_thread(run)
            job = await h.wait_state(1, S.DELIVERED)
        assert reply.startswith("250 J000001 queued")
        assert counts["validate_file"] == 1
        assert store.files()["O31.nc"] == LARGE and job.sha256 == hashlib.sha256(LARGE).hexdigest()


async def test_a_program_without_its_xon_xoff_bytes_is_validated_and_written_anew(
    store: Store, harness
) -> None:
    upload = b"\x11" + LARGE
    text = mapping_text("laser", store.port).replace(
        "dialect: laser-sim", "dialect: laser-sim, xon_xoff: strip"
    )
    async with harness([text]) as h:
        with spying(h) as counts:
            reply = await h.stor("laser", "O31.nc", upload)
            await h.wait_state(1, S.DELIVERED)
        assert reply.startswith("226 J000001 queued")
        assert counts["validate_file"] == 1
        assert store.files()["O31.nc"] == LARGE  # delivered without the XON byte
