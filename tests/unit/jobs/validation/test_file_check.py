"""Large programs are validated in the validation process: same verdicts, the program stored by the worker.

The gateway validates uploads above ISOLATE_ABOVE in a separate process so that the
CPU it takes does not stall the event loop; these tests run the real process
(JobThreads.process, "spawn") and compare with validation in this process.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import os
import time
from pathlib import Path

import pytest

from bench.gcode_gen import laser_program
from gateway.config.validation import ValidationRules
from gateway.jobs.threads import JobThreads
from gateway.jobs.validation.file_check import ISOLATE_ABOVE, Checked, validate_file
from gateway.jobs.validation.pipeline import validate_program
from tests.waiting import wait_until

RULES = ValidationRules.model_validate({"dialect": "laser-sim"})
LARGE = laser_program(2 * ISOLATE_ABOVE, seed=3, number=4321)


async def in_process(data: bytes, source: Path, destination: Path) -> Checked:
    """`data` uploaded to `source`, validated as O4321.nc in the validation process."""
    source.write_bytes(data)
    threads = JobThreads()
    try:
        return await threads.process(validate_file, source, destination, "O4321.nc", RULES)
    finally:
        await threads.shutdown()


async def test_a_large_program_is_validated_in_another_process_with_the_same_verdict(tmp_path: Path) -> None:
    source, destination = tmp_path / "job.received", tmp_path / "job.program"
    checked = await in_process(LARGE, source, destination)
    expected = validate_program(LARGE, "O4321.nc", RULES)
    assert len(LARGE) > ISOLATE_ABOVE
    assert checked.pid != os.getpid()
    assert expected.accepted and expected.estimate is not None and expected.estimate.blocks > 10_000
    assert checked.verdict == dataclasses.replace(expected, program=b"")
    assert destination.read_bytes() == expected.program
    assert (checked.size, checked.sha256) == (len(LARGE), hashlib.sha256(LARGE).hexdigest())
    assert source.read_bytes() == LARGE  # the caller decides what becomes of the upload


async def test_a_rejected_large_program_is_still_rejected_with_its_reason(tmp_path: Path) -> None:
    lines = LARGE.split(b"\n")
    middle = len(lines) // 2
    lines[middle] = lines[middle] + b" #1"  # a parameter, which laser-sim rules reject
    bad = b"\n".join(lines).replace(b"M30\n", b"")  # and no end code
    source, destination = tmp_path / "bad.received", tmp_path / "bad.program"
    checked = await in_process(bad, source, destination)
    expected = validate_program(bad, "O4321.nc", RULES)
    assert checked.pid != os.getpid()
    assert not checked.verdict.accepted
    assert {r.rule for r in checked.verdict.rejections} == {"syntax", "end-code"}
    assert checked.verdict.rejections[0].line == middle + 1
    assert "parameters (#) are not supported" in checked.verdict.reason
    assert checked.verdict == dataclasses.replace(expected, program=b"")
    assert (checked.size, checked.sha256) == (0, "")
    assert not destination.exists()


async def test_a_small_program_in_a_thread_gives_the_same_answer(tmp_path: Path) -> None:
    small = laser_program(20_000, seed=4, number=7)
    source, destination = tmp_path / "s.received", tmp_path / "s.program"
    source.write_bytes(small)
    threads = JobThreads()
    try:
        checked = await threads.work(validate_file, source, destination, "O7.nc", RULES)
    finally:
        await threads.shutdown()
    assert checked.pid == os.getpid()
    assert checked.verdict == dataclasses.replace(validate_program(small, "O7.nc", RULES), program=b"")
    assert destination.read_bytes() == small


def test_an_unchanged_program_is_linked_into_place_with_the_upload_digest(tmp_path: Path) -> None:
    small = laser_program(20_000, seed=6, number=8)
    source, destination = tmp_path / "u.received", tmp_path / "u.program"
    source.write_bytes(small)
    digest = hashlib.sha256(small).hexdigest()
    checked = validate_file(source, destination, "O8.nc", RULES, digest)
    assert checked.verdict.accepted
    assert (checked.size, checked.sha256) == (len(small), digest)
    assert destination.read_bytes() == small
    assert os.path.samefile(source, destination)  # one file, two names: no copy of a 50 MB program
    assert not list(tmp_path.glob("*.linking"))


def test_a_program_changed_by_validation_is_written_with_its_own_digest(tmp_path: Path) -> None:
    rules = ValidationRules.model_validate({"dialect": "laser-sim", "xon_xoff": "strip"})
    upload = b"\x11" + laser_program(20_000, seed=6, number=9)
    source, destination = tmp_path / "x.received", tmp_path / "x.program"
    source.write_bytes(upload)
    checked = validate_file(source, destination, "O9.nc", rules, hashlib.sha256(upload).hexdigest())
    stored = destination.read_bytes()
    assert checked.verdict.accepted and stored == upload[1:]
    assert (checked.size, checked.sha256) == (len(stored), hashlib.sha256(stored).hexdigest())
    assert not os.path.samefile(source, destination)


async def test_shutdown_stops_a_validation_whose_job_was_cancelled(tmp_path: Path) -> None:
    """A job cancelled mid-validation does not keep the process (or shutdown) waiting for it."""
    threads = JobThreads()
    # A call that outlasts the test, whatever the machine's speed (a validation can finish first).
    task = asyncio.ensure_future(threads.process(time.sleep, 600))
    pool = threads._pool()
    await wait_until(lambda: bool(pool._processes))  # the worker has started and took the call
    workers = list(pool._processes.values())
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    await threads.shutdown()
    assert workers and not any(w.is_alive() for w in workers)
    with pytest.raises(RuntimeError):
        await threads.process(os.getpid)
