"""Programs the operators punched, kept under the state directory: one file and one JSON record each.

    dnc/received/<machine>/<UTC stamp>-<name>.nc      the program, byte for byte as it came
    dnc/received/<machine>/<UTC stamp>-<name>.json    time, size, SHA-256, O-number, verdict
    dnc/refused/<machine>/<UTC stamp>-<what>.part     a punch that was refused (no closing %),
    dnc/refused/<machine>/<UTC stamp>-<what>.reason   and why: nothing that arrived is lost

The name comes from the controller (its O-number, the comment beside it, a
Sinumerik `%_N_…` header), so it is reduced to [A-Za-z0-9_-] before it becomes
part of a path, and the file's folder is checked once more after joining: no
name can leave `dnc/received/<machine>/`. Blocking file I/O: callers run it in
a thread.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from gateway.errors import PathRefused

_UNSAFE = re.compile(r"[^A-Za-z0-9_-]+")
_MACHINE = re.compile(r"^[a-z0-9][a-z0-9_\-]{0,62}$")
MAX_NAME = 40
SUFFIX = ".nc"


def safe_name(number: int | None, name: str | None) -> str:
    """A file-name stem for a punched program: `O4711`, `O4711-BRACKET`, or `PART_MPF`, else `punch`."""
    parts = []
    if number is not None:
        parts.append(f"O{number:04d}")
    if name:
        cleaned = _UNSAFE.sub("_", name).strip("_-")
        if cleaned:
            parts.append(cleaned)
    stem = "-".join(parts)[:MAX_NAME].strip("_-")
    return stem or "punch"


def stamp(at: datetime) -> str:
    return at.astimezone(UTC).strftime("%Y%m%dT%H%M%S%fZ")


@dataclass(frozen=True, slots=True)
class ReceivedProgram:
    """One stored punch. `file` is the program's file name in its machine's folder."""

    machine: str
    file: str
    received: datetime
    size: int
    sha256: str
    number: int | None
    name: str | None
    verdict: str  # "" (not validated), "accepted", or "rejected: <first reason>"
    backup: str  # the backup copy's path, "" when none

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["received"] = self.received.astimezone(UTC).isoformat().replace("+00:00", "Z")
        return out


class ReceivedStore:
    """The `dnc/` folder of one state directory."""

    def __init__(self, state_dir: Path) -> None:
        self.root = state_dir / "dnc"
        self.received_root = self.root / "received"
        self.refused_root = self.root / "refused"

    def folder(self, machine: str, *, refused: bool = False) -> Path:
        if not _MACHINE.match(machine):
            raise PathRefused(f"{machine!r} is not a machine name")
        return (self.refused_root if refused else self.received_root) / machine

    def _inside(self, folder: Path, file: str) -> Path:
        path = folder / file
        if path.parent != folder or os.sep in file or file.startswith("."):
            raise PathRefused(f"{file!r} would leave {folder}")
        return path

    def store(
        self,
        machine: str,
        data: bytes,
        *,
        at: datetime,
        number: int | None,
        name: str | None,
        verdict: str = "",
        backups: Path | None = None,
    ) -> ReceivedProgram:
        """Write the program and its record (fsynced: a punch is the operator's only copy)."""
        folder = self.folder(machine)
        folder.mkdir(parents=True, exist_ok=True)
        stem = f"{stamp(at)}-{safe_name(number, name)}"
        path = self._inside(folder, stem + SUFFIX)
        _write(path, data)
        backup = ""
        if backups is not None:
            backups.mkdir(parents=True, exist_ok=True)
            target = self._inside(backups, path.name)
            _write(target, data)
            backup = str(target)
        rec = ReceivedProgram(
            machine,
            path.name,
            at,
            len(data),
            hashlib.sha256(data).hexdigest(),
            number,
            name,
            verdict,
            backup,
        )
        _write(path.with_suffix(".json"), json.dumps(rec.as_dict(), indent=1).encode())
        return rec

    def refuse(self, machine: str, data: bytes, *, at: datetime, what: str, reason: str) -> Path:
        """Keep what arrived of a refused punch beside the reason it was refused."""
        folder = self.folder(machine, refused=True)
        folder.mkdir(parents=True, exist_ok=True)
        path = self._inside(folder, f"{stamp(at)}-{_UNSAFE.sub('_', what)[:MAX_NAME] or 'punch'}.part")
        _write(path, data)
        _write(path.with_suffix(".reason"), (reason + "\n").encode())
        return path

    def list(self, machine: str | None = None) -> list[ReceivedProgram]:
        """Stored punches, oldest first (of one machine, or of all)."""
        if not self.received_root.is_dir():
            return []
        folders = [self.folder(machine)] if machine else sorted(self.received_root.iterdir())
        out: list[ReceivedProgram] = []
        for folder in folders:
            if not folder.is_dir():
                continue
            for record in sorted(folder.glob("*.json")):
                try:
                    out.append(_read(record))
                except (OSError, ValueError, KeyError, TypeError):
                    continue  # a record being written, or damaged: the program file is still there
        out.sort(key=lambda r: r.received)
        return out

    def path(self, program: ReceivedProgram) -> Path:
        return self._inside(self.folder(program.machine), program.file)


def _write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _read(record: Path) -> ReceivedProgram:
    raw = json.loads(record.read_text())
    return ReceivedProgram(
        machine=str(raw["machine"]),
        file=str(raw["file"]),
        received=datetime.fromisoformat(str(raw["received"])),
        size=int(raw["size"]),
        sha256=str(raw["sha256"]),
        number=None if raw["number"] is None else int(raw["number"]),
        name=None if raw["name"] is None else str(raw["name"]),
        verdict=str(raw["verdict"]),
        backup=str(raw["backup"]),
    )
