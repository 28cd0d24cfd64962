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

So the folder must be the gateway's: the gateway makes it (mode 0770 before the
umask) and takes nothing from it while it is a link, belongs to another user or
may be written by every user (`folder_problem`; the service logs why). Files are
written under a random temporary name created with O_EXCL|O_NOFOLLOW, then
renamed into place: a link planted in the folder is never followed (before issue
23, a link at the reply's temporary name made the reply overwrite its target).
Requests are read with O_NOFOLLOW|O_NONBLOCK, regular files only, so neither a
link nor a FIFO can make the gateway read elsewhere or wait.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import stat
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

ACTIONS = {"pause": "DripPause", "resume": "DripResume", "abort": "DripAbort"}
STALE = 30.0  # s after which an unanswered request is dropped by the gateway
_FILE = re.compile(r"^(?P<machine>[A-Za-z0-9_.-]+)\.(?P<id>[0-9a-f]{32})\.request$")
_REPLY = re.compile(r"^[A-Za-z0-9_.-]+\.[0-9a-f]{32}\.reply$")
_TEMP = re.compile(r"^\..+\.[0-9a-f]{16}\.tmp$")  # `write_new`'s, left by a crash between create and rename
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # not on Windows, which has no such links to plant for a user
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)
MAX_REQUEST = 4096  # bytes read of a request file ({"method": "DripPause"} is 24)
FOLDER_MODE = 0o770  # the gateway's user and its group (who may use the CLI); never every user


def control_dir(state_dir: Path) -> Path:
    return state_dir / "jobs" / "dnc" / "control"


def make_control_dir(state_dir: Path) -> Path:
    """The folder, made by the gateway at start-up so that it is the gateway's (the CLI makes it only when
    no gateway ever ran there)."""
    folder = control_dir(state_dir)
    folder.mkdir(parents=True, exist_ok=True, mode=FOLDER_MODE)
    return folder


def folder_problem(state_dir: Path) -> str | None:
    """Why the control folder must not be used, or None: it is a link, not a folder, belongs to another
    user than the gateway's, or every user may write it (anyone could then ask for drip-feed commands, or
    plant links). A folder that does not exist yet holds nothing to take: None."""
    folder = control_dir(state_dir)
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{folder} cannot be examined: {exc.strerror or exc}"
    if stat.S_ISLNK(st.st_mode):
        return f"{folder} is a symbolic link; it must be a folder of the gateway's own"
    if not stat.S_ISDIR(st.st_mode):
        return f"{folder} is not a folder"
    uid = os.geteuid() if hasattr(os, "geteuid") else None
    if uid is not None and st.st_uid != uid:
        return (
            f"{folder} belongs to {owner(st.st_uid)}, not to the gateway's user {owner(uid)} "
            f"(chown {owner(uid)} {folder})"
        )
    if st.st_mode & stat.S_IWOTH:
        return (
            f"every user may write {folder} (mode {stat.S_IMODE(st.st_mode):04o}); "
            f"chmod o-w {folder} (the CLI's users belong in the gateway's group)"
        )
    return None


def write_new(final: Path, text: str) -> None:
    """`text` into `final`, by way of a temporary file of a random name in the same folder, created with
    O_CREAT|O_EXCL|O_NOFOLLOW (never a file or link that was there), then renamed over `final` (the rename
    replaces a link there, never its target; a reader sees the whole file or none)."""
    tmp = final.with_name(f".{final.name}.{secrets.token_hex(8)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o644)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


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
    path = make_control_dir(state_dir) / f"{machine}.{uuid.uuid4().hex}.request"
    write_new(path, json.dumps({"method": method}) + "\n")
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
    well-formed request, a link or anything but a regular file, or a stale one is removed and skipped.
    Nothing is taken from a folder `folder_problem` refuses."""
    if folder_problem(state_dir) is not None:
        return []
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
            if _REPLY.match(entry.name) or _TEMP.match(entry.name):  # nobody waited for it, or a crash's
                with contextlib.suppress(OSError):
                    if now - entry.stat(follow_symlinks=False).st_mtime > STALE:
                        os.unlink(entry.path)
            continue
        path = Path(entry.path)
        read = _read_request(path)
        with contextlib.suppress(OSError):
            path.unlink()  # taken: acted on once, whatever follows
        if read is None:
            continue
        st, text = read
        if now - st.st_mtime > STALE:
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


def _read_request(path: Path) -> tuple[os.stat_result, str] | None:
    """The request file's status and text; None for a link, a FIFO, a device, a folder, or what vanished.
    Opened without following links and without waiting, then checked, so that what is read is what was
    checked."""
    try:
        fd = os.open(path, os.O_RDONLY | _NOFOLLOW | _NONBLOCK)
    except OSError:  # a link (ELOOP), gone, unreadable
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return None
        data = os.read(fd, MAX_REQUEST)
    except OSError:
        return None
    finally:
        os.close(fd)
    return st, data.decode("utf-8", "replace")


def answer(request: ControlRequest, reply: ControlReply) -> None:
    write_new(reply_for(request.path), json.dumps({"status": reply.status, "text": reply.text}) + "\n")


def owner(uid: int) -> str:
    """The login name of a file's owner (`uid 1000` without a passwd entry, as in a bare container)."""
    try:
        import pwd

        return pwd.getpwuid(uid).pw_name
    except (ImportError, KeyError):
        return f"uid {uid}"
