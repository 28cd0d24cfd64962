"""The program store: where the controller keeps its part programs.

The machine model only needs `exists` and `read` (the DNC face also `write`s); `DirectoryStore` serves them
from `<root>/DATA/Programs` on disk, the folder the FTP server exposes, and reads
a program afresh each time it is selected or started, so programs uploaded over
FTP are runnable at once. `MemoryStore` serves unit tests.
"""

from __future__ import annotations

import logging
import os
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Protocol

from simulator.errors import ProgramNotFound

log = logging.getLogger("simulator.store")

PROGRAMS_DIR = ("DATA", "Programs")
MAX_NAME = 255


class ProgramStore(Protocol):
    def exists(self, name: str) -> bool: ...

    def read(self, name: str) -> str:
        """The program's text; raises ProgramNotFound."""
        ...


def check_name(name: str) -> None:
    """A program name is a plain file name in the programs folder; raise ValueError if not."""
    if not name or not name.strip():
        raise ValueError("program name is empty")
    if len(name) > MAX_NAME:
        raise ValueError(f"program name is longer than {MAX_NAME} characters")
    if "/" in name or "\\" in name or name in (".", "..") or "\x00" in name:
        raise ValueError(f"program name {name!r} must be a plain file name, without folders")


class MemoryStore:
    """Programs held in a dict, for tests."""

    def __init__(self, programs: dict[str, str] | None = None) -> None:
        self.programs = dict(programs or {})

    def exists(self, name: str) -> bool:
        return name in self.programs

    def read(self, name: str) -> str:
        try:
            return self.programs[name]
        except KeyError:
            raise ProgramNotFound(name) from None

    def write(self, name: str, data: bytes) -> None:
        check_name(name)
        self.programs[name] = data.decode("utf-8", errors="replace")


class DirectoryStore:
    """Programs as files in `<root>/DATA/Programs`."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.programs = root.joinpath(*PROGRAMS_DIR)

    def prepare(self) -> None:
        """Create the folders and copy in the sample programs that are not there yet."""
        self.programs.mkdir(parents=True, exist_ok=True)
        for sample in sample_programs():
            target = self.programs / sample.name
            if not target.exists():
                target.write_bytes(sample.read_bytes())
                log.debug("installed sample program %s", target)

    def _path(self, name: str) -> Path | None:
        try:
            check_name(name)
        except ValueError:
            return None
        return self.programs / name

    def exists(self, name: str) -> bool:
        path = self._path(name)
        return path is not None and path.is_file()

    def read(self, name: str) -> str:
        path = self._path(name)
        if path is None:
            raise ProgramNotFound(name)
        try:
            # Undecodable bytes become U+FFFD, which the lexer reports with its line.
            return path.read_bytes().decode("utf-8", errors="replace")
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            raise ProgramNotFound(name) from None

    def write(self, name: str, data: bytes) -> None:
        """Store a program (a DNC load) under `name`, replacing one of that name: a whole file or nothing."""
        check_name(name)
        target = self.programs / name
        staging = self.programs / f".{name}.dnc-partial"
        staging.write_bytes(data)
        os.replace(staging, target)

    def read_bytes(self, name: str) -> bytes:
        """The program's bytes as stored (a FOCAS upload sends them unchanged)."""
        path = self._path(name)
        if path is None or not path.is_file():
            raise ProgramNotFound(name)
        return path.read_bytes()

    def delete(self, name: str) -> None:
        """Remove a program (a FOCAS delete); ProgramNotFound when there is none."""
        path = self._path(name)
        if path is None or not path.is_file():
            raise ProgramNotFound(name)
        path.unlink()

    def names(self) -> list[str]:
        if not self.programs.is_dir():
            return []
        return sorted(p.name for p in self.programs.iterdir() if p.is_file())


def sample_programs() -> list[Traversable]:
    """The programs shipped in simulator/programs (package data)."""
    folder = resources.files("simulator").joinpath("programs")
    return sorted((p for p in folder.iterdir() if p.name.endswith(".nc")), key=lambda p: p.name)
