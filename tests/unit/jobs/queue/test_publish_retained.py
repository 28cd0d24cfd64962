"""Only the most recently ended jobs keep a retained `jobs/<id>` record: when one more ends, the oldest
ended job's record is withdrawn with an empty retained event, whatever state it ended in."""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime
from typing import Any

from gateway.config.jobs import JobsConfig
from gateway.config.mapping import MachineMapping
from gateway.jobs.queue.publish import JobPublisher
from gateway.jobs.queue.records import Job, JobState
from gateway.model.events import Event
from gateway.model.tree import VariableTree

T0 = datetime(2026, 5, 6, 7, 0, tzinfo=UTC)
S = JobState


def jobs_config(keep: int | None = None) -> JobsConfig:
    extra: dict[str, Any] = {} if keep is None else {"mqtt_retained_jobs": keep}
    return JobsConfig.model_validate({"controller": {"host": "127.0.0.1"}, **extra})


def publisher(keep: int | None = None) -> tuple[JobPublisher, Any]:
    tree = VariableTree(
        [
            MachineMapping.model_validate(
                {
                    "machine": "m1",
                    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
                    "variables": [{"path": "State", "source": "s", "type": "Int16"}],
                }
            ).definition()
        ]
    )
    events = tree.events.subscribe("test")
    return JobPublisher(tree, {"m1": jobs_config(keep)}), events


def job(seq: int, state: JobState) -> Job:
    return Job(
        seq=seq,
        machine="m1",
        filename=f"p{seq}.nc",
        user="nest",
        origin="ftp",
        size=10,
        sha256="0" * 64,
        priority=0,
        state=state,
        reason="",
        attempts=0,
        next_attempt_at=None,
        received_at=T0,
        updated_at=T0,
        program_name=None,
        program_size=None,
        program_sha256=None,
        estimate=None,
        warnings=(),
        delivered_name=None,
        delivered_at=None,
        rev=seq,
    )


def cleared(events: list[Event]) -> list[str]:
    return [e.channel for e in events if e.payload is None]


def test_the_default_keeps_100_ended_jobs() -> None:
    pub, _ = publisher()
    assert pub.keep == {"m1": 100} and jobs_config().mqtt_retained_jobs == 100


def test_beyond_the_limit_the_oldest_ended_record_is_withdrawn_whatever_its_final_state() -> None:
    pub, events = publisher(2)
    got: list[Event] = []
    for seq, final in enumerate([S.DELIVERED, S.REJECTED, S.FAILED, S.CANCELLED], start=1):
        pub.job(job(seq, S.QUEUED))
        live = events.take()
        assert cleared(live) == []  # a job that goes live never pushes anything out
        pub.job(job(seq, final))
        got += live + events.take()
    assert cleared(got) == ["jobs/J000001", "jobs/J000002"]
    assert all(e.retain for e in got)
    # withdrawn after J000003 and J000004 ended, each right after the record that pushed it out
    channels = [(e.channel, e.payload is None) for e in got]
    assert channels[channels.index(("jobs/J000001", True)) - 1] == ("jobs/J000003", False)
    assert channels[-2:] == [("jobs/J000004", False), ("jobs/J000002", True)]


def test_a_retried_job_is_live_again_and_a_republished_one_keeps_its_place() -> None:
    pub, events = publisher(2)
    pub.job(job(1, S.FAILED))
    pub.job(job(2, S.DELIVERED))
    pub.job(job(1, S.QUEUED))  # retried from the CLI: no longer ended
    pub.job(job(3, S.DELIVERED))
    assert cleared(events.take()) == []
    pub.job(replace(job(2, S.DELIVERED), rev=9))  # the same ended job published again
    pub.job(job(1, S.DELIVERED))
    assert cleared(events.take()) == ["jobs/J000002"]


def test_zero_withdraws_each_record_as_soon_as_the_job_ends_and_earlier_runs_can_be_handed_over() -> None:
    pub, events = publisher(0)
    pub.job(job(5, S.SENDING))
    pub.job(job(5, S.DELIVERED))
    assert [(e.channel, e.payload is None) for e in events.take()] == [
        ("jobs/J000005", False),
        ("jobs/J000005", False),
        ("jobs/J000005", True),
    ]
    pub, events = publisher(1)
    pub.ended_before([job(1, S.DELIVERED), job(2, S.REJECTED)])
    assert cleared(events.take()) == ["jobs/J000001"]
