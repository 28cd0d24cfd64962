"""UploadCheck: blocks handed over from the event loop, checked in order in one thread, bounded."""

from __future__ import annotations

import dataclasses
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import pytest

from bench.gcode_gen import laser_program
from gateway.config.validation import ValidationRules
from gateway.jobs.validation import upload_check
from gateway.jobs.validation.pipeline import validate_program
from gateway.jobs.validation.upload_check import UploadCheck

RULES = ValidationRules.for_dialect("laser-sim")
PROGRAM = laser_program(400_000, seed=41, number=41)


@pytest.fixture
def small_batches(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(upload_check, "BATCH", 20_000)
    monkeypatch.setattr(upload_check, "MAX_BEHIND", 60_000)


async def test_blocks_checked_in_a_thread_give_the_whole_file_verdict(small_batches: None) -> None:
    pool = ThreadPoolExecutor(1)
    threads: set[str] = set()

    def submit(fn: Any, *args: Any) -> Future[Any]:
        def run() -> Any:
            threads.add(threading.current_thread().name)
            return fn(*args)

        return pool.submit(run)

    check = UploadCheck(RULES, submit)
    try:
        for start in range(0, len(PROGRAM), 4096):
            await check.feed(PROGRAM[start : start + 4096])
            assert check._behind <= upload_check.MAX_BEHIND + upload_check.BATCH
        verdict = await check.verdict("O41.nc")
    finally:
        pool.shutdown()
    assert verdict == dataclasses.replace(validate_program(PROGRAM, "O41.nc", RULES), program=b"")
    assert verdict.accepted and not check.changed
    assert threads and threading.current_thread().name not in threads


async def test_a_check_that_fails_fails_its_verdict_and_never_the_upload(small_batches: None) -> None:
    def broken(fn: Any, *args: Any) -> Future[Any]:
        raise RuntimeError("the job workers are shut down")

    check = UploadCheck(RULES, broken)
    for start in range(0, 100_000, 4096):
        await check.feed(PROGRAM[start : start + 4096])  # never raises
    with pytest.raises(RuntimeError, match="shut down"):
        await check.verdict("O41.nc")


async def test_an_error_in_the_thread_is_the_verdicts(
    small_batches: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    pool = ThreadPoolExecutor(1)
    check = UploadCheck(RULES, pool.submit)

    def boom(data: bytes) -> None:
        raise ValueError("a bug")

    monkeypatch.setattr(check._check, "feed", boom)
    try:
        await check.feed(PROGRAM[:30_000])  # handed over; the thread raises
        with pytest.raises(ValueError, match="a bug"):
            await check.verdict("O41.nc")
    finally:
        pool.shutdown()
