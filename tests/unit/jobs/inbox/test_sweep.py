"""Which temporary uploads the sweep deletes (gateway/jobs/inbox/sweep.py): real files, real times."""

from __future__ import annotations

import os
import time
from pathlib import Path

from gateway.jobs.inbox import sweep

SUFFIXES = [".part", ".tmp"]


def make(path: Path, age: float) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"G1 X1\n")
    when = time.time() - age
    os.utime(path, (when, when))
    return path


def test_only_stale_regular_files_with_temporary_names_or_in_tmp(tmp_path: Path) -> None:
    root = tmp_path / "inbox"
    old, new = 7200, 10
    stale = [make(root / "laser" / "a.nc.part", old), make(root / "laser" / "tmp" / "b.nc", old)]
    make(root / "laser" / "c.nc.part", new)  # fresh
    make(root / "laser" / "plain.nc", old)  # not a temporary name: not ours to delete
    make(root / "laser" / ".hidden.part", old)
    make(root / "other" / "d.nc.part", old)  # a machine not served
    busy = make(root / "laser" / "busy.nc.part", old)  # an upload writes to it right now
    (root / "laser" / "link.nc.part").symlink_to(stale[0])
    found = sweep.stale(root, ["laser", "gone"], SUFFIXES, time.time() - 3600, busy={busy})
    assert sorted(found) == sorted(stale)
    assert sweep.delete([*found, root / "laser" / "vanished.nc.part"]) == found
    assert not any(p.exists() for p in stale) and busy.exists()
    assert (root / "laser" / "link.nc.part").is_symlink()


def test_sweeps_a_quarter_of_the_age_within_bounds() -> None:
    assert sweep.every(3600) == 600 and sweep.every(1) == 0.25 and sweep.every(0.1) == sweep.MIN_EVERY
    assert sweep.every(86400) == sweep.MAX_EVERY
