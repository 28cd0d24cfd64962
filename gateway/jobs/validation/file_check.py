"""Validate a spooled upload by path, and store the validated program: the job queue's unit of checking.

Large programs are validated in a separate process (`JobThreads.process`) so that
the seconds of CPU they take do not hold the gateway's GIL and stall its event
loop (OPC UA, MQTT). To avoid shipping tens of megabytes through pickles both
ways, the worker reads the upload itself, writes the program it validated durably
to its destination, and answers with the verdict alone (its `program` empty),
plus the stored program's size and SHA-256. Small programs take the same
function in a thread, where a process hop would only add latency.

No asyncio here: this module is what the validation process imports.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from gateway.config.validation import ValidationRules
from gateway.jobs.validation.pipeline import validate_program
from gateway.jobs.validation.verdict import Verdict

#: Uploads larger than this (bytes) are validated in the validation process, smaller ones in a thread.
ISOLATE_ABOVE = 512 * 1024


@dataclass(frozen=True, slots=True)
class Checked:
    """A validated upload. `verdict.program` is empty: the program, if accepted, is at the destination.

    `size` and `sha256` describe the stored program (0 and "" when rejected); `pid`
    is the process that validated it (the gateway's own, or its validation worker).
    """

    verdict: Verdict
    size: int
    sha256: str
    pid: int


def ready() -> int:
    """Nothing: sent to a new validation process so that it imports this module (and the validator) ahead
    of the first upload."""
    return os.getpid()


def validate_file(
    source: Path, destination: Path, filename: str, rules: ValidationRules, source_sha256: str = ""
) -> Checked:
    """Validate the upload at `source` as `filename`; if accepted, store the program durably at `destination`.

    `source` is left in place either way (the caller removes or keeps it). When the
    program is the upload unchanged (nearly always: only `xon_xoff: strip` alters
    it), the upload's file is hard-linked into place rather than copied, and
    `source_sha256`, the digest taken as it arrived, is its digest.
    """
    data = source.read_bytes()
    verdict = validate_program(data, filename, rules)
    unchanged = verdict.program is data
    del data
    size, digest = 0, ""
    if verdict.accepted:
        if not (unchanged and link_durably(source, destination)):
            write_durably(destination, verdict.program)
        size = len(verdict.program)
        digest = source_sha256 if unchanged and source_sha256 else hashlib.sha256(verdict.program).hexdigest()
    return Checked(dataclasses.replace(verdict, program=b""), size, digest, os.getpid())


def write_durably(path: Path, data: bytes) -> None:
    """Write, flush to disk, then rename into place: a crash leaves the old state or the new one."""
    temp = path.with_name(path.name + ".writing")
    with temp.open("wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(temp, path)


def link_durably(source: Path, path: Path) -> bool:
    """Give `source`'s file the name `path` as well, on disk before the rename: False where links fail.

    The inbox flushes every upload to disk before it commits, so the fsync here
    is usually free; it is there for programs that arrive by other ways.
    """
    temp = path.with_name(path.name + ".linking")
    try:
        temp.unlink(missing_ok=True)
        os.link(source, temp)
        fd = os.open(temp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(temp, path)
    except OSError:
        temp.unlink(missing_ok=True)
        return False
    return True
