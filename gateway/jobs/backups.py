"""Programs.Backup's copies of one machine's programs: the folder, how many are kept, how often.

Before issue 23 any caller, anonymous viewers included, could store up to 16 MiB per call in
`<state>/backups/<machine>/` with nothing ever deleted, and the reply named the server's absolute path.
Now the method needs the operator role (gateway/jobs/programs.py) and this shelf bounds what it writes:
at most `per_hour` backups per machine in any hour (`TooManyBackups`, BadTooManyOperations, audited like
every refused call), the newest `keep` copies, none older than `max_age_days`. A copy is named
`<UTC stamp>-<program>` (`20250102T030405Z-part.nc`); punched programs filed in the same folder
(`punch.backup`, whose stamps carry microseconds) are neither counted nor deleted. Files are created with
O_EXCL|O_NOFOLLOW: a name already there (or a planted link) is never written through.
"""

from __future__ import annotations

import os
import re
import time
from collections import deque
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

from gateway.config.jobs import BackupSettings
from gateway.errors import CallError

HOUR = 3600.0
STAMP = "%Y%m%dT%H%M%SZ"
COPY = re.compile(r"^(\d{8}T\d{6}Z)-")  # Programs.Backup's copies (not punch.backup's: %f in their stamp)
FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


class TooManyBackups(CallError):
    status = "BadTooManyOperations"


class BackupShelf:
    """One machine's backups folder. `admit()` counts a call against the rate; `store()` writes a copy and
    prunes (blocking: run it in a thread)."""

    def __init__(
        self,
        folder: Path,
        settings: BackupSettings,
        *,
        clock: Callable[[], float] = time.monotonic,
        now: Callable[[], datetime] = lambda: datetime.now(UTC),
    ) -> None:
        self.folder = folder
        self.settings = settings
        self._clock = clock
        self._now = now
        self._calls: deque[float] = deque()

    def admit(self) -> None:
        """Count one backup; TooManyBackups when `per_hour` were made in the last hour."""
        now = self._clock()
        while self._calls and now - self._calls[0] >= HOUR:
            self._calls.popleft()
        if len(self._calls) >= self.settings.per_hour:
            wait = HOUR - (now - self._calls[0])
            raise TooManyBackups(
                f"at most {self.settings.per_hour} backups an hour of {self.folder.name}'s programs "
                f"(jobs.backups.per_hour); try again in {wait:.0f} s"
            )
        self._calls.append(now)

    def store(self, program: str, data: bytes) -> str:
        """Write a copy of `program`; the copy's file name (never the server's path)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        stamp = self._now().strftime(STAMP)
        for n in range(1, 100):
            name = f"{stamp}-{program}" if n == 1 else f"{stamp}-{n}-{program}"
            try:
                fd = os.open(self.folder / name, FLAGS, 0o640)
            except FileExistsError:
                continue
            with os.fdopen(fd, "wb") as out:
                out.write(data)
            break
        else:  # pragma: no cover - a hundred copies of one program in one second, refused by per_hour first
            raise TooManyBackups(f"too many backups of {program} in one second")
        self.prune()
        return name

    def prune(self) -> list[str]:
        """Delete the copies beyond `keep` and older than `max_age_days`; the names deleted."""
        copies = []
        for path in self.folder.iterdir():
            found = COPY.match(path.name)
            if found and path.is_file() and not path.is_symlink():
                copies.append((found.group(1), path))
        copies.sort(key=lambda c: (c[0], c[1].stat().st_mtime_ns))
        doomed = []
        if self.settings.keep and len(copies) > self.settings.keep:
            doomed = copies[: len(copies) - self.settings.keep]
        if self.settings.max_age_days:
            oldest = (self._now() - timedelta(days=self.settings.max_age_days)).strftime(STAMP)
            doomed += [c for c in copies if c[0] < oldest and c not in doomed]
        for _, path in doomed:
            path.unlink(missing_ok=True)
        return [path.name for _, path in doomed]
