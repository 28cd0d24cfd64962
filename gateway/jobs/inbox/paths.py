"""The inbox's virtual folder layout, and the checks that keep uploads inside it.

Pure functions over the path text a client sends: no I/O, no asyncio. The layout
is fixed and shallow:

    /                       the machines this login may use, nothing else
    /<machine>/             drop programs here
    /<machine>/tmp/         or upload here first, then rename into /<machine>/

Anything else is refused before it touches the disk: `..` (never resolved, always
refused), backslashes, control characters, hidden names, device names that
Windows reserves, folders other than tmp/, and machines the login may not use
(reported exactly like a machine that does not exist, so names do not leak).
"""

from __future__ import annotations

import unicodedata
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Literal

from gateway.errors import PathRefused

TMP = "tmp"
MAX_NAME_BYTES = 255
# Characters no controller or file system we deliver to accepts in a name.
FORBIDDEN_CHARS = frozenset('\\/:*?"<>|')
WINDOWS_DEVICES = frozenset(
    {"CON", "PRN", "AUX", "NUL", *(f"COM{i}" for i in range(1, 10)), *(f"LPT{i}" for i in range(1, 10))}
)

Kind = Literal["root", "machine", "tmp", "file"]


@dataclass(frozen=True, slots=True)
class InboxPath:
    """A checked place in the inbox. `parts` are relative to the inbox root."""

    kind: Kind
    machine: str | None = None
    name: str | None = None
    in_tmp: bool = False

    @property
    def parts(self) -> tuple[str, ...]:
        out: list[str] = []
        if self.machine is not None:
            out.append(self.machine)
        if self.in_tmp or self.kind == "tmp":
            out.append(TMP)
        if self.name is not None:
            out.append(self.name)
        return tuple(out)

    @property
    def virtual(self) -> str:
        return "/" + "/".join(self.parts)

    @property
    def folder(self) -> InboxPath:
        """The folder that holds this file (or this folder itself)."""
        if self.kind != "file":
            return self
        return InboxPath("tmp" if self.in_tmp else "machine", self.machine)

    def is_temporary(self, suffixes: Sequence[str]) -> bool:
        """An upload that waits for a rename before it becomes a job."""
        if self.kind != "file" or self.name is None:
            return False
        return self.in_tmp or is_temp_name(self.name, suffixes)


def is_temp_name(name: str, suffixes: Sequence[str]) -> bool:
    lowered = name.lower()
    return any(lowered.endswith(s) and len(lowered) > len(s) for s in suffixes)


def check_file_name(name: str) -> str:
    """Refuse names that could escape, hide, or mean something else on some system."""
    if not name:
        raise PathRefused("empty file name", "553")
    if name in (".", ".."):
        raise PathRefused(f"{name!r} is not a file name", "553")
    if len(name.encode("utf-8")) > MAX_NAME_BYTES:
        raise PathRefused(f"file name longer than {MAX_NAME_BYTES} bytes", "553")
    for char in name:
        if char in FORBIDDEN_CHARS:
            raise PathRefused(f"file name {name!r} contains {char!r}", "553")
        if not char.isprintable() or unicodedata.category(char) in ("Cc", "Cf", "Zl", "Zp"):
            raise PathRefused(f"file name {name!r} contains the control character {ord(char):#04x}", "553")
    if name.startswith("."):
        raise PathRefused(f"hidden file names are not accepted: {name!r}", "553")
    if name.startswith("-"):
        raise PathRefused(f"file names must not start with '-': {name!r}", "553")
    if name != name.strip() or name.endswith("."):
        raise PathRefused(f"file names must not start or end with a space or end with a dot: {name!r}", "553")
    if name.split(".")[0].upper() in WINDOWS_DEVICES:
        raise PathRefused(f"{name!r} is a reserved device name", "553")
    return name


def resolve(cwd: str, argument: str, machines: Collection[str], elsewhere: Collection[str] = ()) -> InboxPath:
    """Where `argument` (absolute, or relative to `cwd`) points, for a login that may use `machines`.

    `cwd` is a virtual path this module produced earlier; `elsewhere` names machines another shard
    serves, whose jobs this inbox cannot take (the refusal says so). Raises PathRefused.
    """
    if "\x00" in argument or "\r" in argument or "\n" in argument:
        raise PathRefused("control characters in the path", "501")
    if "\\" in argument:
        raise PathRefused("use '/' in paths, not '\\'", "553")
    if len(argument) >= 2 and argument[1] == ":" and argument[0].isalpha():
        raise PathRefused("drive letters are not paths here", "553")
    base = PurePosixPath("/") if argument.startswith("/") else PurePosixPath(cwd)
    parts = list(base.parts[1:]) + [p for p in argument.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise PathRefused("'..' is not allowed in paths", "553")
    if not parts:
        return InboxPath("root")
    machine, rest = parts[0], parts[1:]
    if machine not in machines:
        if machine in elsewhere:
            raise PathRefused(
                f"/{machine}: {machine} is served by another shard, and this gateway's job queue is its own"
                " (SQLite): send its jobs to that shard's inbox, or give the shards one PostgreSQL queue"
                " (queue: postgresql://…), whose inboxes take jobs for every machine"
            )
        raise PathRefused(f"/{machine}: no such machine folder")
    if not rest:
        return InboxPath("machine", machine)
    if rest[0] == TMP:
        if len(rest) == 1:
            return InboxPath("tmp", machine)
        if len(rest) == 2:
            return InboxPath("file", machine, check_file_name(rest[1]), in_tmp=True)
        raise PathRefused("no folders inside tmp/")
    if len(rest) == 1:
        return InboxPath("file", machine, check_file_name(rest[0]))
    raise PathRefused(f"/{machine}/ has no sub-folders other than tmp/")
