"""Temporary uploads nobody came back for: found and deleted after `inbox.temp_max_age`.

An upload to a temporary name (`*.part`, or into `tmp/`) waits in the machine's folder for the
rename that submits it, and can be resumed (REST, APPE) meanwhile. Nesting software renames it
right after the upload, and a resumed upload writes to it, so one untouched for `temp_max_age`
seconds was abandoned. Without a sweep such files would pile up until the disk is full. Only
regular files with temporary names are deleted (never a symbolic link, a folder, or anything
else someone put there), and never one an upload is writing to right now.
"""

from __future__ import annotations

import logging
import stat
from collections.abc import Collection, Sequence
from pathlib import Path

from gateway.jobs.inbox.paths import TMP, is_temp_name

log = logging.getLogger("gateway.jobs.inbox")

#: Seconds between sweeps: a quarter of the age limit, within these bounds.
MIN_EVERY, MAX_EVERY = 0.25, 600.0


def every(max_age: float) -> float:
    """How often to sweep for files older than `max_age` seconds."""
    return min(max(max_age / 4, MIN_EVERY), MAX_EVERY)


def stale(
    root: Path,
    machines: Collection[str],
    suffixes: Sequence[str],
    older_than: float,
    busy: Collection[Path] = (),
) -> list[Path]:
    """Temporary uploads under `root` last written before `older_than` (a time.time()), not in `busy`."""
    found = []
    for machine in machines:
        folder = root / machine
        candidates = [p for p in _files(folder) if is_temp_name(p.name, suffixes)]
        candidates += _files(folder / TMP)
        for path in candidates:
            if path in busy:
                continue
            try:
                st = path.lstat()
            except OSError:
                continue
            if stat.S_ISREG(st.st_mode) and st.st_mtime < older_than:
                found.append(path)
    return found


def delete(paths: Sequence[Path]) -> list[Path]:
    """Delete these files; the ones that were deleted (a file gone meanwhile is not an error)."""
    gone = []
    for path in paths:
        try:
            path.unlink()
        except FileNotFoundError:
            continue
        except OSError as exc:
            log.warning("inbox: cannot delete the stale temporary upload %s: %s", path, exc.strerror or exc)
            continue
        gone.append(path)
    return gone


def _files(folder: Path) -> list[Path]:
    try:
        return [p for p in folder.iterdir() if not p.name.startswith(".")]
    except OSError:
        return []
