"""Which state directory jobs, alarms and audit read when not told.

--state-dir, then -c, then the environment, then the default with the newest store.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import pytest

from gateway.cli.state_dir import DEFAULT_STATE_DIRS, resolve_state_dir


def store(d: Path) -> Path:
    return d / "audit.sqlite3"


def args(**kw: object) -> argparse.Namespace:
    return argparse.Namespace(state_dir=kw.get("state_dir"), config=kw.get("config"))


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("CNC_GATEWAY_STATE_DIR", raising=False)
    return tmp_path


def touch(path: Path, mtime: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    os.utime(path, (mtime, mtime))


def test_the_given_directory_wins(here: Path) -> None:
    assert resolve_state_dir(args(state_dir="elsewhere"), "audit", store) == Path("elsewhere")


def test_the_environment_comes_before_the_defaults(here: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    touch(store(Path("state")), 1_000)
    monkeypatch.setenv("CNC_GATEWAY_STATE_DIR", "from-env")
    assert resolve_state_dir(args(), "audit", store) == Path("from-env")


def test_the_default_with_the_newest_store_is_chosen_and_named(
    here: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    touch(store(Path("state")), 1_000)
    touch(store(Path("state/demo")), 2_000)
    assert resolve_state_dir(args(), "audit", store) == Path("state/demo")
    assert "(audit: state/demo/audit.sqlite3; -c FILE or --state-dir to choose)" in capsys.readouterr().err
    oldest_first = resolve_state_dir(args(), "audit", store, last_written=lambda d: -store(d).stat().st_mtime)
    assert oldest_first == Path("state")


def test_without_any_store_the_first_default(here: Path) -> None:
    assert resolve_state_dir(args(), "audit", store) == DEFAULT_STATE_DIRS[0]
