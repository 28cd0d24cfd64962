"""Programs.Backup's shelf on a real folder: the hourly rate, the retention by count and by age, names that
never repeat or follow a link, and the punched programs filed beside the copies left alone."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from gateway.config.jobs import BackupSettings
from gateway.jobs.backups import BackupShelf, TooManyBackups


class Clock:
    def __init__(self) -> None:
        self.mono = 1000.0
        self.wall = datetime(2025, 3, 1, 12, 0, 0, tzinfo=UTC)

    def advance(self, seconds: float) -> None:
        self.mono += seconds
        self.wall += timedelta(seconds=seconds)


def shelf(folder: Path, clock: Clock, **settings: object) -> BackupShelf:
    return BackupShelf(
        folder, BackupSettings.model_validate(settings), clock=lambda: clock.mono, now=lambda: clock.wall
    )


def test_the_rate_refuses_beyond_per_hour_and_lets_the_next_through_an_hour_later(tmp_path: Path) -> None:
    clock = Clock()
    s = shelf(tmp_path, clock, per_hour=3)
    for _ in range(3):
        s.admit()
        clock.advance(600)
    with pytest.raises(TooManyBackups, match=r"at most 3 backups an hour .*try again in 1800 s") as refused:
        s.admit()
    assert refused.value.status == "BadTooManyOperations"
    clock.advance(1800)  # the first call is an hour old now
    s.admit()
    with pytest.raises(TooManyBackups):
        s.admit()


def test_copies_beyond_keep_go_oldest_first_and_punched_programs_stay(tmp_path: Path) -> None:
    clock = Clock()
    s = shelf(tmp_path, clock, keep=3, max_age_days=0)
    punched = tmp_path / "20250101T000000123456Z-O4711.nc"  # punch.backup's name: microseconds in the stamp
    punched.write_bytes(b"punched")
    names = []
    for n in range(5):
        names.append(s.store("part.nc", f"v{n}".encode()))
        clock.advance(1)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([punched.name, *names[-3:]])
    assert [(tmp_path / n).read_bytes() for n in names[-3:]] == [b"v2", b"v3", b"v4"]
    assert names[0] == "20250301T120000Z-part.nc"


def test_copies_older_than_max_age_go_at_the_next_backup(tmp_path: Path) -> None:
    clock = Clock()
    s = shelf(tmp_path, clock, keep=0, max_age_days=2)
    old = s.store("a.nc", b"old")
    clock.advance(86400 * 1.5)
    middle = s.store("b.nc", b"middle")
    clock.advance(86400)  # `old` is 2.5 days old now, `middle` 1
    new = s.store("c.nc", b"new")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([middle, new])
    assert old not in {p.name for p in tmp_path.iterdir()}


def test_two_copies_in_one_second_get_two_names_and_a_planted_link_is_not_written_through(
    tmp_path: Path,
) -> None:
    clock = Clock()
    s = shelf(tmp_path / "laser", clock, keep=0, max_age_days=0)
    (tmp_path / "laser").mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_bytes(b"precious")
    (tmp_path / "laser" / "20250301T120000Z-part.nc").symlink_to(victim)
    first = s.store("part.nc", b"one")
    second = s.store("part.nc", b"two")
    assert (first, second) == ("20250301T120000Z-2-part.nc", "20250301T120000Z-3-part.nc")
    assert victim.read_bytes() == b"precious"
    assert (tmp_path / "laser" / second).read_bytes() == b"two"
