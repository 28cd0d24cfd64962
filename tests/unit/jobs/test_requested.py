"""Remote requests from the queue: which job a name names, and the delivered programs a machine keeps."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pytest

from gateway.jobs.intake import matches
from gateway.jobs.queue.store import Job, JobState
from gateway.jobs.spool import Spool


def job(seq: int, filename: str = "part.nc", program_name: str | None = None, machine: str = "m1") -> Job:
    now = datetime.now(UTC)
    return Job(
        seq, machine, filename, "alice", "test", 10, "", 0, JobState.DELIVERED, "", 1, None, now, now,
        program_name, 10, "", None, (), None, None, 1,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("filename", "own", "name", "named"),
    [
        ("O4711.nc", "O4711", "O4711", True),
        ("O4711.nc", "O4711", "o4711.nc", True),
        ("bracket.nc", "O4711", "O04711", True),  # the program's own O-number
        ("bracket.nc", None, "BRACKET", True),
        ("bracket.nc", "O4711", "O4712", False),
        ("bracket.nc", None, "BRACK", False),
    ],
)
def test_a_request_names_a_job_by_file_name_or_program_number(
    filename: str, own: str | None, name: str, named: bool
) -> None:
    assert matches(job(1, filename, own), name) is named


def test_delivered_programs_are_kept_up_to_the_machines_limit(tmp_path: Path) -> None:
    spool = Spool(tmp_path, {"m1": 2})
    jobs = [job(n) for n in (8, 9, 10)] + [job(11, machine="m2")]
    for j in jobs:
        spool.program(j).write_bytes(j.id.encode())
        spool.delivered(j)
    kept = sorted(p.name for p in (tmp_path / "delivered" / "m1").iterdir())
    assert kept == ["J000009.program", "J000010.program"]  # the newest two; J000008's went
    assert spool.kept(jobs[2]).read_bytes() == b"J000010"
    assert not spool.program(jobs[3]).exists() and not spool.kept(jobs[3]).exists()  # m2 keeps none
