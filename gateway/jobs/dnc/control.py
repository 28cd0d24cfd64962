"""Drip-feed commands from the shell: `cnc-gateway jobs pause|resume|abort MACHINE` to the running gateway.

The CLI runs in another process. Like `jobs restart` (which goes through the
queue file), it speaks to the gateway through the state directory: it writes a
request file, `<state>/jobs/dnc/control/<machine>.<id>.request`, holding the
command's name; the job service looks at that folder a few times a second,
takes the request (it deletes it first, so a request is acted on once), calls
the machine's `Commands/Drip*` method through `Machine.call_method` (so it is
audited like every door: origin `cli`) and writes `<machine>.<id>.reply` with
the status and the method's result, which the CLI prints and removes.

Who asks is who owns the request file: the operating system says so, not the
file's text. Being able to write the state directory is the CLI's
authentication, as for `jobs retry|cancel|restart` (the queue file lives there
too); the call then acts with the role the command needs. A request older than
`STALE` seconds (a gateway that was not running) is dropped unanswered.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

ACTIONS = {"pause": "DripPause", "resume": "DripResume", "abort": "DripAbort"}
STALE = 30.0  # s after which an unanswered request is dropped by the gateway
_FILE = re.compile(r"^(?P<machine>[A-Za-z0-9_.-]+)\.(?P<id>[0-9a-f]{32})\.request$")
_REPLY = re.compile(r"^[A-Za-z0-9_.-]+\.[0-9a-f]{32}\.reply$")


def control_dir(state_dir: Path) -> Path:
    return state_dir / "jobs" / "dnc" / "control"


@dataclass(frozen=True, slots=True)
class ControlRequest:
    machine: str
    id: str
    method: str  # DripPause, DripResume, DripAbort
    user: str  # the request file's owner
    path: Path


@dataclass(frozen=True, slots=True)
class ControlReply:
    status: str  # "Good" or a Bad status name
    text: str


def ask(state_dir: Path, machine: str, action: str) -> Path:
    """Write a request (the CLI's side); returns its file. Raises KeyError for an unknown action."""
    method = ACTIONS[action]
    folder = control_dir(state_dir)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{machine}.{uuid.uuid4().hex}.request"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"method": method}) + "\n")
    os.replace(tmp, path)
    return path


def reply_for(request: Path) -> Path:
    return request.with_suffix(".reply")


def read_reply(path: Path) -> ControlReply | None:
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return ControlReply("BadInternalError", f"unreadable reply {path}")
    if not isinstance(raw, dict):
        return ControlReply("BadInternalError", f"unreadable reply {path}")
    return ControlReply(str(raw.get("status", "BadInternalError")), str(raw.get("text", "")))


def take_requests(state_dir: Path, *, now: float | None = None) -> list[ControlRequest]:
    """The requests waiting (the gateway's side), each taken out of the folder. A file that is not a
    well-formed request, a link, or a stale one is removed and skipped."""
    folder = control_dir(state_dir)
    try:
        entries = list(os.scandir(folder))
    except FileNotFoundError:
        return []
    now = time.time() if now is None else now
    found: list[ControlRequest] = []
    for entry in entries:
        match = _FILE.match(entry.name)
        if match is None:
            if _REPLY.match(entry.name):  # a reply nobody waited for (the CLI gave up): cleared in time
                with contextlib.suppress(OSError):
                    if now - entry.stat(follow_symlinks=False).st_mtime > STALE:
                        os.unlink(entry.path)
            continue
        path = Path(entry.path)
        try:
            st = entry.stat(follow_symlinks=False)
            text = "" if entry.is_symlink() else path.read_text()
        except OSError:
            continue
        with contextlib.suppress(OSError):
            path.unlink()  # taken: acted on once, whatever follows
        if entry.is_symlink() or now - st.st_mtime > STALE:
            continue
        try:
            raw = json.loads(text)
            method = raw["method"] if isinstance(raw, dict) else None
        except (ValueError, KeyError):
            method = None
        if method not in ACTIONS.values():
            continue
        found.append(ControlRequest(match["machine"], match["id"], str(method), owner(st.st_uid), path))
    return found


def answer(request: ControlRequest, reply: ControlReply) -> None:
    path = reply_for(request.path)
    tmp = path.with_suffix(".reply-tmp")
    tmp.write_text(json.dumps({"status": reply.status, "text": reply.text}) + "\n")
    os.replace(tmp, path)


def owner(uid: int) -> str:
    """The login name of a file's owner (`uid 1000` without a passwd entry, as in a bare container)."""
    try:
        import pwd

        return pwd.getpwuid(uid).pw_name
    except (ImportError, KeyError):
        return f"uid {uid}"
