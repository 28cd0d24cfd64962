"""The transfer log: what is recorded reads back, filtered by time and machine; the CLI prints it."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gateway.cli.main import main
from gateway.errors import TransferLogError
from gateway.transports.dnc.transfers import TransferLog, TransferRecord, transfers_path

T0 = datetime(2026, 5, 6, 7, 0, tzinfo=UTC)


def rec(machine: str, minutes: int, direction: str = "send", outcome: str = "ok") -> TransferRecord:
    return TransferRecord(
        machine=machine,
        direction=direction,  # type: ignore[arg-type]
        program="O4711.nc",
        size=1234,
        sha256="ab" * 32,
        started=T0 + timedelta(minutes=minutes),
        ended=T0 + timedelta(minutes=minutes, seconds=30),
        outcome=outcome,  # type: ignore[arg-type]
        user="otto",
        detail="",
    )


def test_a_record_reads_back_whole(tmp_path: Path) -> None:
    with TransferLog.in_state_dir(tmp_path) as log:
        r = rec("fanuc-1", 0, "receive")
        log.record(r)
        [row] = log.query()
    assert row.record == r and row.record.seconds == 30.0
    assert transfers_path(tmp_path).is_file()


def test_query_filters_by_since_machine_and_direction_oldest_first(tmp_path: Path) -> None:
    with TransferLog.in_state_dir(tmp_path) as log:
        for i, m in enumerate(["a", "b", "a", "a"]):
            log.record(rec(m, i * 10, "receive" if i == 3 else "send"))
        since = T0 + timedelta(minutes=5)
        assert [r.record.started for r in log.query(since=since, machine="a")] == [
            T0 + timedelta(minutes=20),
            T0 + timedelta(minutes=30),
        ]
        assert [r.record.machine for r in log.query(direction="receive")] == ["a"]
        assert [r.record.machine for r in log.query(limit=2)] == ["a", "a"]  # the newest two


def test_a_record_refuses_an_unknown_direction_or_outcome() -> None:
    with pytest.raises(ValueError, match="direction"):
        rec("a", 0, "sideways")
    with pytest.raises(ValueError, match="outcome"):
        rec("a", 0, outcome="maybe")


def test_a_missing_log_is_an_error_when_only_reading(tmp_path: Path) -> None:
    with pytest.raises(TransferLogError, match="no DNC transfer log"):
        TransferLog.in_state_dir(tmp_path, create=False)


def test_cli_lists_since_as_lines_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    now = datetime.now(UTC)
    with TransferLog.in_state_dir(tmp_path) as log:
        log.record(rec("old", 0))
        log.record(
            TransferRecord("fanuc-1", "receive", "O0001", 12, "cd" * 32, now, now, "refused", None, "no %")
        )
    assert main(["dnc", "log", "--state-dir", str(tmp_path), "--since", "1h"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 1 and "fanuc-1 <- O0001" in out[0] and "refused" in out[0] and "no %" in out[0]
    assert main(["dnc", "log", "--state-dir", str(tmp_path), "--json", "--machine", "old"]) == 0
    [line] = capsys.readouterr().out.splitlines()
    assert json.loads(line)["started"] == "2026-05-06T07:00:00.000000Z"


def test_cli_without_a_log_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["dnc", "log", "--state-dir", str(tmp_path)]) == 1
    assert "creates it with the first serial transfer" in capsys.readouterr().err


def test_cli_refuses_a_bad_since(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["dnc", "log", "--state-dir", str(tmp_path), "--since", "yesterday"])
    assert "expected an ISO time" in capsys.readouterr().err
