"""The audit trail in PostgreSQL (`audit: postgresql://…`): the same behaviour as the SQLite file, one
table for every shard, read back by `cnc-gateway audit list -c gateway.yaml`. A real server, a fresh
database per test (tests/postgres.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import psycopg
import pytest

from gateway.audit.postgres import COMPONENT, PostgresAuditStore
from gateway.audit.tables import open_table
from gateway.audit.trail import AuditTrail
from gateway.errors import AuditStoreError
from tests.unit.audit.test_trail import T0, entry


@pytest.fixture(params=["sqlite", "postgresql"])
def where(request: pytest.FixtureRequest, tmp_path: Path) -> Path | str:
    """The same tests against both tables: the SQLite file, and a fresh PostgreSQL database."""
    if request.param == "sqlite":
        return tmp_path / "audit.sqlite3"
    url: str = request.getfixturevalue("postgres_url")
    return url


async def test_a_burst_is_stored_in_batches_and_read_back_newest_first(where: Path | str) -> None:
    async with AuditTrail(where) as trail:
        for i in range(1200):
            trail.record(entry(i, machine=f"m{i % 3}"))
        await trail.flush()
        assert trail.stored == 1200 and trail.dropped == 0
        newest = await trail.query_audit(limit=2)
    assert newest == [entry(1199, machine="m2"), entry(1198, machine="m1")]  # whole, times to the microsecond
    table = open_table(where, create=False)
    try:
        assert len(table.query(limit=5000)) == 1200
        assert {r.entry.machine for r in table.query(machine="m1", limit=5000)} == {"m1"}
    finally:
        table.close()


async def test_queries_by_machine_user_origin_and_time_agree(where: Path | str) -> None:
    async with AuditTrail(where) as trail:
        trail.record(entry(0, user="olga", machine="m1"))
        trail.record(entry(10, user="ivan", machine="m2", status="BadUserAccessDenied"))
        trail.record(entry(20, user=None, machine="m1"))
    table = open_table(where)
    try:
        assert [r.entry.user for r in table.query(machine="m1")] == [None, "olga"]
        assert [r.entry.status for r in table.query(user="ivan")] == ["BadUserAccessDenied"]
        assert [r.entry.machine for r in table.query(since=T0 + timedelta(seconds=5))] == ["m1", "m2"]
        assert len(table.query(origin="opcua", kind="write")) == 3 and not table.query(origin="mqtt")
    finally:
        table.close()


async def test_entries_older_than_the_retention_go_at_start(where: Path | str) -> None:
    now = datetime.now(UTC)
    table = open_table(where)
    table.insert([entry(0, at=now - timedelta(days=400)), entry(0, at=now - timedelta(days=1))])
    table.close()
    async with AuditTrail(where, retention_days=365):
        pass
    table = open_table(where)
    try:
        assert [r.entry.time for r in table.query()] == [now - timedelta(days=1)]
    finally:
        table.close()


async def test_two_shards_write_one_trail_and_say_who_recorded(
    postgres_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    for shard, machine in (("1/2", "laser-1"), ("2/2", "laser-2")):
        monkeypatch.setenv("CNC_SHARD", shard)
        async with AuditTrail(postgres_url) as trail:
            trail.record(entry(0 if shard == "1/2" else 1, machine=machine))
    with psycopg.connect(postgres_url) as conn:
        rows = conn.execute("SELECT machine, recorded_by FROM audit ORDER BY id").fetchall()
    assert rows == [("laser-1", "shard 1/2"), ("laser-2", "shard 2/2")]


def test_a_database_from_a_newer_gateway_is_refused(postgres_url: str) -> None:
    PostgresAuditStore(postgres_url).close()
    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("UPDATE schema_versions SET version = 99 WHERE component = %s", (COMPONENT,))
    with pytest.raises(AuditStoreError, match="schema 99, from a newer cnc-gateway"):
        PostgresAuditStore(postgres_url)


def test_an_unreachable_database_is_an_audit_error_without_the_password() -> None:
    with pytest.raises(AuditStoreError) as caught:
        PostgresAuditStore("postgresql://gw:s3cret@127.0.0.1:1/cnc")
    assert "s3cret" not in str(caught.value) and "cannot reach the audit table" in str(caught.value)


async def test_audit_list_reads_the_database_the_gateway_file_names(
    postgres_url: str, tmp_path: Path
) -> None:
    async with AuditTrail(postgres_url) as trail:
        trail.record(entry(0, user="olga", machine="laser-1"))
        trail.record(entry(5, user="ivan", machine="laser-2"))
    (tmp_path / "laser-1.yaml").write_text(
        "machine: laser-1\ndriver: {endpoint: 'opc.tcp://127.0.0.1:4840'}\n"
        "variables:\n  - {path: Feed/Override, source: 'ns=2;s=o', type: UInt16}\n"
    )
    gateway = tmp_path / "gateway.yaml"
    gateway.write_text(f"machines: [laser-1.yaml]\nstate_dir: state\naudit: {postgres_url}\n")
    listed = subprocess.run(
        [sys.executable, "-m", "gateway.cli.main", "audit", "list", "-c", str(gateway), "--json"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    lines = [json.loads(line) for line in listed.stdout.splitlines()]
    assert [(e["machine"], e["user"]) for e in lines] == [("laser-2", "ivan"), ("laser-1", "olga")]
    assert not (tmp_path / "state" / "audit.sqlite3").exists()  # nothing went to the state directory


def test_a_bad_audit_url_is_a_config_error_with_its_line(tmp_path: Path) -> None:
    (tmp_path / "gateway.yaml").write_text("machines: []\naudit: mysql://db/cnc\n")
    checked = subprocess.run(
        [sys.executable, "-m", "gateway.cli.main", "check", str(tmp_path / "gateway.yaml")],
        check=False, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert checked.returncode == 2
    assert "gateway.yaml:2" in checked.stderr and "audit" in checked.stderr
    assert "leave audit out" in checked.stderr
