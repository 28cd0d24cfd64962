"""`cnc-gateway alarms list -c gateway.yaml` reads the PostgreSQL alarm history the gateway file names
(`alarm_history:`), written by any shard; nothing is read from or left in the state directory."""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

from gateway.alarms.records import ActiveAlarm
from gateway.alarms.store import history_at

T0 = datetime(2026, 5, 6, 7, 0, 0, tzinfo=UTC)


def test_alarms_list_reads_the_database_the_gateway_file_names(postgres_url: str, tmp_path: Path) -> None:
    with history_at(postgres_url, tmp_path / "shard-1").open() as one:
        [first] = one.apply("laser-1", [(ActiveAlarm("1001", "Soft limit", 3), 700)], [], T0)
        one.acknowledge(first, T0 + timedelta(seconds=2), "olga", "seen", True)
    with history_at(postgres_url, tmp_path / "shard-2").open() as two:
        two.apply("laser-2", [(ActiveAlarm("2001", "Program error"), 400)], [], T0 + timedelta(seconds=5))
    (tmp_path / "laser-1.yaml").write_text(
        "machine: laser-1\ndriver: {endpoint: 'opc.tcp://127.0.0.1:4840'}\n"
        "variables:\n  - {path: Feed/Override, source: 'ns=2;s=o', type: UInt16}\n"
    )
    gateway = tmp_path / "gateway.yaml"
    gateway.write_text(f"machines: [laser-1.yaml]\nstate_dir: state\nalarm_history: {postgres_url}\n")
    listed = subprocess.run(
        [sys.executable, "-m", "gateway.cli.main", "alarms", "list", "-c", str(gateway), "--json"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    records = json.loads(listed.stdout)
    assert [(r["machine"], r["id"]) for r in records] == [("laser-2", "2001"), ("laser-1", "1001")]
    assert records[1]["acked_by"] == "olga" and records[1]["ack_comment"] == "seen"
    assert not (tmp_path / "state" / "alarms.sqlite3").exists()
