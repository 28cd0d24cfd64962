"""Leases in a real PostgreSQL: taken when free or expired, renewed, released, fenced; keepers share a fleet.

Expiry is the database's clock: the tests wait (with a deadline, tests/waiting.py) until the database
says a lease has run out, never sleep a fixed time.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest

from gateway.errors import JobError, LeaseError, StaleFence
from gateway.jobs.queue.postgres import PostgresJobQueue
from gateway.jobs.queue.records import JobState
from gateway.shards.fence import Fence
from gateway.shards.keeper import LeaseKeeper
from gateway.shards.leases import COMPONENT, MIGRATIONS, LeaseTable

LEASE = 2.0  # s: short, so that expiry comes quickly; long enough for a loaded machine's renewals


@pytest.fixture
def table(postgres_url: str) -> Iterator[LeaseTable]:
    with LeaseTable(postgres_url, lease_time=LEASE) as t:
        yield t


def wait_expired(table: LeaseTable, machine: str, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        lease = next(x for x in table.leases() if x.machine == machine)
        if not lease.live:
            return
        assert time.monotonic() < deadline, f"{machine}'s lease did not expire: {lease}"
        time.sleep(min(0.05, max(lease.remaining, 0.01)))


def test_a_free_machine_is_taken_and_a_held_one_is_not(table: LeaseTable) -> None:
    a = table.acquire("laser", "gw-a")
    assert a is not None and a.holder == "gw-a" and a.token > 0
    assert table.acquire("laser", "gw-b") is None  # gw-a's lease runs
    assert table.held() == {"laser": "gw-a"}
    table.check(a.fence)


def test_an_expired_lease_is_taken_over_with_a_greater_token_and_the_old_one_is_fenced(
    table: LeaseTable, postgres_url: str
) -> None:
    first = table.acquire("laser", "gw-a")
    assert first is not None
    wait_expired(table, "laser")  # gw-a stopped renewing
    with pytest.raises(StaleFence, match="expired"):
        table.check(first.fence)
    second = table.acquire("laser", "gw-b")
    assert second is not None and second.token > first.token
    with pytest.raises(StaleFence, match="stale"):
        table.check(first.fence)
    with pytest.raises(StaleFence):  # nor can gw-a renew what it lost
        table.renew(first)
    table.check(second.fence)
    wait_expired(table, "laser")
    third = table.acquire("laser", "gw-a")
    assert third is not None and third.token > second.token  # tokens only grow, whoever holds it


def test_renewal_keeps_a_lease_past_its_first_term(table: LeaseTable) -> None:
    lease = table.acquire("laser", "gw-a")
    assert lease is not None
    started = time.monotonic()
    while time.monotonic() - started < 2 * LEASE:  # two terms, renewed on the way
        lease = table.renew(lease)
        assert table.acquire("laser", "gw-b") is None
        time.sleep(LEASE / 10)  # the renewal interval: what this test is about, not a wait for something
    table.check(lease.fence)


def test_a_release_frees_the_machine_at_once(table: LeaseTable) -> None:
    lease = table.acquire("laser", "gw-a")
    assert lease is not None and table.release(lease)
    taken = table.acquire("laser", "gw-b")
    assert taken is not None and taken.token > lease.token
    assert not table.release(lease)  # not gw-a's any more


def test_a_claim_with_a_stale_token_is_refused_in_the_database(table: LeaseTable, postgres_url: str) -> None:
    with PostgresJobQueue(postgres_url) as queue:
        job = queue.receive("laser", "a.nc", 1, "a")
        queue.accept(job.seq, duplicates="skip", program_size=1, program_sha256="a")
        old = table.acquire("laser", "gw-a")
        assert old is not None
        wait_expired(table, "laser")
        new = table.acquire("laser", "gw-b")
        assert new is not None
        with pytest.raises(JobError, match="stale"):
            queue.start_sending(job.seq, fence=old.fence)
        with pytest.raises(JobError, match="not plasma"):
            queue.start_sending(job.seq, fence=Fence("plasma", new.token))
        assert queue.get(job.seq).state is JobState.QUEUED and queue.get(job.seq).attempts == 0
        assert queue.start_sending(job.seq, fence=new.fence).state is JobState.SENDING
        with pytest.raises(JobError, match="stale"):  # nor may the old holder record its delivery
            queue.delivered(job.seq, "a.nc", fence=old.fence)
        assert queue.delivered(job.seq, "a.nc", fence=new.fence).state is JobState.DELIVERED


def test_the_sqlite_queue_refuses_a_fence(tmp_path) -> None:
    from gateway.jobs.queue.store import JobQueue

    with JobQueue(tmp_path / "q.sqlite3") as queue, pytest.raises(JobError, match="holds no leases"):
        queue.start_sending(1, fence=Fence("laser", 1))


def test_two_keepers_share_the_fleet_and_one_takes_over_when_the_other_stops(postgres_url: str) -> None:
    machines = [f"m{i}" for i in range(5)]
    with LeaseTable(postgres_url, lease_time=LEASE) as ta, LeaseTable(postgres_url, lease_time=LEASE) as tb:
        a, b = LeaseKeeper(ta, "gw-a", machines), LeaseKeeper(tb, "gw-b", machines)
        a.step()
        assert sorted(a.leases) == machines  # alone, it takes the whole fleet
        tokens = {m: lease.token for m, lease in a.leases.items()}
        for _ in range(3):  # b joins: a releases what is beyond its share, b takes it
            b.step()
            a.step()
        assert sorted([len(a.leases), len(b.leases)]) == [2, 3]
        assert set(a.leases).isdisjoint(b.leases) and set(a.leases) | set(b.leases) == set(machines)
        assert all(b.leases[m].token > tokens[m] for m in b.leases)
        # a stops renewing (killed): once its leases run out, b takes every machine, with greater tokens
        stale = dict(a.leases)
        deadline = time.monotonic() + 15
        while len(b.leases) < len(machines):
            assert time.monotonic() < deadline, f"b holds only {sorted(b.leases)}"
            b.step()
            time.sleep(LEASE / 5)
        for machine, lease in stale.items():
            assert b.leases[machine].token > lease.token
            with pytest.raises(StaleFence):
                tb.check(lease.fence)
        lost = a.step()  # a wakes: what it held is lost, and it takes nothing b holds
        assert sorted(lost.lost) == sorted(stale) and a.leases == {}
        b.stop()
        assert tb.held() == {} and tb.members() == ["gw-a"]


def test_a_lease_table_from_a_newer_gateway_is_refused(postgres_url: str) -> None:
    LeaseTable(postgres_url).open().close()
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        assert conn.execute(
            "SELECT version FROM schema_versions WHERE component = %s", (COMPONENT,)
        ).fetchone() == (len(MIGRATIONS),)
        conn.execute("UPDATE schema_versions SET version = 7 WHERE component = %s", (COMPONENT,))
    with pytest.raises(LeaseError, match="newer cnc-gateway"):
        LeaseTable(postgres_url).open()


def test_the_shards_command_shows_who_holds_what(postgres_url: str, tmp_path) -> None:
    import json
    import subprocess
    import sys

    table = LeaseTable(postgres_url, lease_time=600).open()  # outlives the commands' start-up
    lease = table.acquire("laser", "gw-a")
    table.join("gw-a")
    assert lease is not None
    gateway = tmp_path / "gateway.yaml"
    mapping = Path(__file__).resolve().parents[3] / "mappings" / "laser-sim.yaml"
    gateway.write_text(f"machines: [{mapping}]\nqueue: {postgres_url}\n")
    run = [sys.executable, "-m", "gateway.cli.main", "shards", "-c", str(gateway)]
    proc = subprocess.run(run, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "members: gw-a" and lines[2].split()[:3] == ["laser", "gw-a", str(lease.token)]
    proc = subprocess.run([*run, "--json"], capture_output=True, text=True, timeout=60, check=False)
    shown = json.loads(proc.stdout)
    assert shown["leases"][0]["holder"] == "gw-a" and shown["leases"][0]["token"] == lease.token
    unreachable = "postgresql://gw:s3cret@127.0.0.1:1/plant"
    proc = subprocess.run(
        [sys.executable, "-m", "gateway.cli.main", "shards", "--database", unreachable],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2 and "cannot reach the lease table" in proc.stderr
    assert "s3cret" not in proc.stderr and "Traceback" not in proc.stderr
    table.close()
