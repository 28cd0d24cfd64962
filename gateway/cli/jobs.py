"""`cnc-gateway jobs list|show|retry|restart|cancel|priority|submit|pause|resume|abort`: the job queue from
the command line.

list/show/retry/restart/cancel/priority open the queue file in the state
directory directly, so they work whether the gateway runs or not; a running
gateway notices their changes within about a second. `submit` uploads through
the FTP inbox, like nesting software does, and prints the gateway's verdict;
with `--follow` it then shows the job's delivery as a progress bar (a serial
line's progress file, `<state>/jobs/dnc/<machine>.json`: bytes, the line running,
the lead in the controller's buffer and the run time left) until it ends.

pause/resume/abort hold, continue or stop what a serial machine's line is
sending (a job's drip-feed, or the answer to a remote request): they need the
running gateway, which they reach through a request file in the state directory
(gateway/transports/dnc/control.py); it calls the machine's `Commands/DripPause` …
like OPC UA or MQTT would, audited with origin `cli` and the file owner's name.
"""

from __future__ import annotations

import argparse
import getpass
import json
import os
import re
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from gateway.cli.state_dir import add_state_dir_options, load_config, resolve_state_dir
from gateway.errors import JobError
from gateway.jobs.queue.base import JobStore
from gateway.jobs.queue.store import Job, JobQueue, JobState, parse_job_id

PASSWORD_ENV = "CNC_INBOX_PASSWORD"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("jobs", help="list, inspect, retry, cancel and submit jobs of the FTP job queue")
    jobs = p.add_subparsers(dest="jobs_command", metavar="ACTION", required=True)

    common = add_state_dir_options

    q = jobs.add_parser("list", help="recent jobs, newest first")
    common(q)
    q.add_argument("--machine", default=None)
    q.add_argument(
        "--state", action="append", choices=[s.value for s in JobState], type=str.upper, default=None
    )
    q.add_argument("--limit", type=int, default=30)
    q.add_argument("--json", action="store_true")
    q.set_defaults(handler=handle_list)

    q = jobs.add_parser("show", help="one job: its record and every state change")
    common(q)
    q.add_argument("job", help="job id, e.g. J000042 or 42")
    q.add_argument("--json", action="store_true")
    q.set_defaults(handler=handle_show)

    q = jobs.add_parser("retry", help="put FAILED or CANCELLED jobs back in the queue")
    common(q)
    q.add_argument("job", nargs="+")
    q.set_defaults(handler=handle_retry)

    q = jobs.add_parser(
        "restart",
        help="send a FAILED drip-feed again from a line: its header, modal state, then that line on",
    )
    common(q)
    q.add_argument("job")
    q.add_argument("--line", type=int, required=True, help="the program line (the job's reason names it)")
    q.set_defaults(handler=handle_restart)

    for action, text in (
        (
            "pause",
            "hold the drip-feed a serial machine's line is sending (the controller runs what it holds)",
        ),
        ("resume", "go on with a paused drip-feed"),
        ("abort", "stop the drip-feed being sent; its job is FAILED with the line to restart at"),
    ):
        q = jobs.add_parser(action, help=text + " (needs the running gateway)")
        common(q)
        q.add_argument("machine", help="the serial machine, as in its mapping")
        q.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the gateway's answer")
        q.set_defaults(handler=handle_drip, action=action)

    q = jobs.add_parser("cancel", help="take waiting jobs out of the queue")
    common(q)
    q.add_argument("job", nargs="+")
    q.set_defaults(handler=handle_cancel)

    q = jobs.add_parser("priority", help="change a waiting job's priority (higher goes first)")
    common(q)
    q.add_argument("job")
    q.add_argument("priority", type=int)
    q.set_defaults(handler=handle_priority)

    q = jobs.add_parser("submit", help="upload a program through the FTP inbox, as nesting software does")
    common(q)
    q.add_argument("file", type=Path)
    q.add_argument("--machine", required=True)
    q.add_argument("--name", default=None, help="file name on the controller (default: the file's name)")
    q.add_argument("--host", default=None, help="inbox host (default: from the config, else 127.0.0.1)")
    q.add_argument("--port", type=int, default=None, help="inbox port (default: from the config, else 2121)")
    q.add_argument("--user", default=os.environ.get("CNC_INBOX_USER"), help="inbox login (or CNC_INBOX_USER)")
    q.add_argument("--password", default=None, help=f"or set {PASSWORD_ENV}; asked for when missing")
    q.add_argument("--priority", type=int, default=None)
    q.add_argument(
        "--tls", action="store_true", help="implicit FTPS (default: when the config has inbox.tls)"
    )
    q.add_argument("--insecure", action="store_true", help="with --tls: do not check the certificate")
    q.add_argument("--timeout", type=float, default=30.0)
    q.add_argument(
        "--follow", action="store_true", help="then follow the job until it ends: state and delivery progress"
    )
    q.set_defaults(handler=handle_submit)


# --- finding the queue ------------------------------------------------------------------------------


def state_dir(args: argparse.Namespace) -> Path:
    return resolve_state_dir(args, "queue", lambda d: d / "jobs" / "queue.sqlite3", _last_written)


def _last_written(state: Path) -> float:
    files = [state / "jobs" / "queue.sqlite3", state / "jobs" / "queue.sqlite3-wal"]
    return max(f.stat().st_mtime for f in files if f.exists())


def open_queue(args: argparse.Namespace) -> JobStore:
    from gateway.jobs.queue.postgres import PostgresJobQueue
    from gateway.jobs.spool import queue_path

    config = load_config(args) if args.state_dir is None else None
    if config is not None and config.gateway.queue is not None:  # the shards' shared queue (PostgreSQL)
        try:
            return PostgresJobQueue(config.gateway.queue).open()
        except JobError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
    path = queue_path(state_dir(args))
    if not path.is_file():
        print(f"error: no job queue at {path} (give -c FILE or --state-dir)", file=sys.stderr)
        raise SystemExit(2)
    try:
        return JobQueue(path).open()
    except JobError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def _seq(text: str) -> int:
    try:
        return parse_job_id(text)
    except JobError as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


# --- reading ------------------------------------------------------------------------------------------


def handle_list(args: argparse.Namespace) -> int:
    with open_queue(args) as queue:
        states = [JobState(s) for s in args.state] if args.state else []
        jobs = queue.list(machine=args.machine, states=states, limit=args.limit)
    if args.json:
        print(json.dumps([j.as_dict() for j in jobs], indent=2))
        return 0
    state = state_dir(args)
    print_table(jobs, sys.stdout, state)
    for line in _answers(state, args.machine):
        print(line)
    return 0


def _answers(state: Path | None, machine: str | None) -> list[str]:
    """Remote requests' answers being drip-fed (their progress files), a line each: they are no jobs."""
    if state is None:
        return []
    from gateway.transports.dnc.transport import ANSWER, progress_path, read_progress

    found = []
    folder = progress_path(state, "x").parent
    names = [machine] if machine else sorted(p.stem for p in folder.glob("*.json"))
    for name in names:
        point = read_progress(state, name)
        if point is None or not point.program.startswith(ANSWER):
            continue
        text = progress_text(point.offset, point.total, point.line, point.lead, point.remaining, point.held)
        found.append(f"{name}: answering a remote request with {point.program[len(ANSWER) :]}: {text}")
    return found


def print_table(jobs: list[Job], out: TextIO, state: Path | None = None) -> None:
    if not jobs:
        print("no jobs", file=out)
        return
    rows = [("JOB", "MACHINE", "STATE", "FILE", "SIZE", "RECEIVED", "TRIES", "REASON")]
    for j in jobs:
        rows.append(
            (
                j.id,
                j.machine,
                j.state.value,
                j.filename,
                _size(j.size),
                j.received_at.astimezone().strftime("%Y-%m-%d %H:%M:%S"),
                str(j.attempts),
                _short(_sending(j, state) or j.reason, 60),
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=False)) + "  " + row[-1], file=out)


def handle_show(args: argparse.Namespace) -> int:
    seq = _seq(args.job)
    with open_queue(args) as queue:
        try:
            job = queue.get(seq)
        except JobError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        history = queue.history(seq)
    if args.json:
        record = job.as_dict()
        record["history"] = [
            {
                "state": t.state.value,
                "previous": t.previous.value if t.previous else None,
                "reason": t.reason,
                "ts": t.ts.isoformat(),
            }
            for t in history
        ]
        print(json.dumps(record, indent=2))
        return 0
    fields: list[tuple[str, Any]] = [
        ("job", job.id),
        ("machine", job.machine),
        ("state", job.state.value),
        ("reason", job.reason),
        ("file", job.filename),
        ("size", f"{job.size} bytes"),
        ("sha256", job.sha256),
        ("from", f"{job.user} ({job.origin})"),
        ("priority", job.priority),
        ("attempts", job.attempts),
        ("received", job.received_at.astimezone().isoformat(timespec="seconds")),
    ]
    if job.program_name:
        fields.append(("program", job.program_name))
    if job.estimate:
        seconds = job.estimate.get("seconds")
        fields.append(
            ("estimate", f"{seconds:.1f} s" if isinstance(seconds, (int, float)) else "not estimated")
        )
        extents = job.estimate.get("extents")
        if extents:
            fields.append(
                (
                    "extents",
                    "X {min_x:g}..{max_x:g}  Y {min_y:g}..{max_y:g}  Z {min_z:g}..{max_z:g}".format(
                        **extents
                    ),
                )
            )
    sending = _sending(job, state_dir(args))
    if sending:
        fields.append(("progress", sending))
    if job.delivered_at:
        fields.append(
            (
                "delivered",
                f"{job.delivered_name} at {job.delivered_at.astimezone().isoformat(timespec='seconds')}",
            )
        )
    for warning in job.warnings:
        fields.append(("warning", warning))
    for key, value in fields:
        print(f"{key:<10} {value}")
    print("history:")
    for t in history:
        when = t.ts.astimezone().strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]
        print(f"  {when}  {t.state.value:<10} {t.reason}")
    return 0


# --- changing -------------------------------------------------------------------------------------


def _each(args: argparse.Namespace, action: str) -> int:
    user = getpass.getuser()
    failures = 0
    with open_queue(args) as queue:
        for text in args.job:
            try:
                job = getattr(queue, action)(_seq(text), by=f"{user} (cli)")
            except JobError as exc:
                print(f"error: {exc}", file=sys.stderr)
                failures += 1
                continue
            print(f"{job.id} {job.state.value}: {job.reason}")
    return 1 if failures else 0


def handle_retry(args: argparse.Namespace) -> int:
    return _each(args, "retry")


def handle_cancel(args: argparse.Namespace) -> int:
    return _each(args, "cancel")


def handle_restart(args: argparse.Namespace) -> int:
    from gateway.jobs.spool import Spool
    from gateway.transports.dnc.transport import request_restart

    if args.line < 1:
        print("error: --line must be a program line (1 or more)", file=sys.stderr)
        return 2
    spool = Spool(state_dir(args) / "jobs" / "spool")
    with open_queue(args) as queue:
        try:
            job = queue.get(_seq(args.job))
            if job.state is not JobState.FAILED:
                raise JobError(f"{job.id} is {job.state.value}: only a FAILED job restarts at a line")
            program = spool.program(job)
            if not program.is_file():
                raise JobError(f"{job.id}'s program is no longer in the spool")
            request_restart(program, args.line)
            job = queue.retry(job.seq, by=f"{getpass.getuser()} (cli, restart at line {args.line})")
        except JobError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    print(f"{job.id} {job.state.value}: restarts at line {args.line}")
    return 0


def handle_drip(args: argparse.Namespace) -> int:
    """pause/resume/abort: a request file the running gateway takes, acts on and answers."""
    from gateway.transports.dnc.control import ask, read_reply, reply_for

    if not re.fullmatch(r"[A-Za-z0-9_.-]+", args.machine):
        print(f"error: {args.machine!r} is not a machine name", file=sys.stderr)
        return 2
    state = state_dir(args)
    try:
        request = ask(state, args.machine, args.action)
    except OSError as exc:
        print(f"error: cannot write the request in {state}: {exc}", file=sys.stderr)
        return 2
    reply_file = reply_for(request)
    deadline = time.monotonic() + args.timeout
    while (reply := read_reply(reply_file)) is None:
        if time.monotonic() >= deadline:
            request.unlink(missing_ok=True)
            if (reply := read_reply(reply_file)) is not None:  # taken as the time ran out
                break
            print(
                f"error: no answer from the gateway within {args.timeout:g} s (is it running, with the "
                f"state directory {state}?); nothing was changed",
                file=sys.stderr,
            )
            return 1
        time.sleep(0.1)
    reply_file.unlink(missing_ok=True)
    if reply.status != "Good":
        print(f"error: {args.machine}: {reply.text} ({reply.status})", file=sys.stderr)
        return 1
    print(f"{args.machine}: {reply.text}")
    return 0


def _sending(job: Job, state: Path | None) -> str:
    """A SENDING job's progress on a serial line (its progress file), '' when there is none."""
    if state is None or job.state is not JobState.SENDING:
        return ""
    from gateway.transports.dnc.transport import read_progress

    point = read_progress(state, job.machine)
    if point is None or Path(point.program).stem != job.id:
        return ""
    return progress_text(point.offset, point.total, point.line, point.lead, point.remaining, point.held)


def progress_text(
    sent: int, total: int, line: int | None, lead: float | None, remaining: float | None, held: str
) -> str:
    """`45% 2.5/5.6 kB, line 120, lead 12 s, 3:20 left, held: DC3`."""
    parts = [f"{100 * sent / total if total else 100:.0f}% {_size(sent)}/{_size(total)}"]
    if line:
        parts.append(f"line {line}")
    if lead is not None:
        parts.append(f"lead {lead:.0f} s")
    if remaining is not None:
        parts.append(f"{int(remaining) // 60}:{int(remaining) % 60:02d} left")
    if held:
        parts.append(f"held: {held}")
    return ", ".join(parts)


def handle_priority(args: argparse.Namespace) -> int:
    with open_queue(args) as queue:
        try:
            job = queue.set_priority(_seq(args.job), args.priority)
        except JobError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    print(f"{job.id} priority {job.priority}")
    return 0


# --- submitting ----------------------------------------------------------------------------------


def handle_submit(args: argparse.Namespace) -> int:
    from gateway.cli.upload import UploadFailed, upload

    if not args.file.is_file():
        print(f"error: {args.file}: no such file", file=sys.stderr)
        return 2
    config = load_config(args)
    inbox = config.gateway.inbox if config is not None else None
    host = args.host or (
        inbox.host if inbox is not None and inbox.host not in ("0.0.0.0", "::") else "127.0.0.1"
    )
    port = args.port or (inbox.port if inbox is not None else 2121)
    tls = args.tls or (inbox is not None and inbox.tls is not None)
    user = args.user or input("inbox user: ")
    password = args.password or os.environ.get(PASSWORD_ENV) or getpass.getpass(f"password for {user}: ")
    name = args.name or args.file.name
    progress = Progress(args.file.stat().st_size, sys.stderr)
    try:
        ok, reply = upload(
            host,
            port,
            user,
            password,
            args.machine,
            args.file,
            name,
            priority=args.priority,
            tls=tls,
            verify=not args.insecure,
            timeout=args.timeout,
            progress=progress,
        )
    except UploadFailed as exc:
        progress.done()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    progress.done()
    print(reply)
    if not ok:
        return 1
    if args.follow:
        return follow(args, reply, sys.stderr)
    return 0


def follow(args: argparse.Namespace, reply: str, out: TextIO, *, poll: float = 0.5) -> int:
    """Show the job named in the inbox's reply until it ends: 0 when DELIVERED, 1 otherwise."""
    import re

    match = re.search(r"\bJ\d{6}\b", reply)
    if match is None:
        print("error: the reply names no job to follow", file=sys.stderr)
        return 1
    seq = _seq(match.group(0))
    state = state_dir(args)
    bar = Progress(1, out, threshold=0)
    last = ""
    while True:
        with open_queue(args) as queue:
            job = queue.get(seq)
        if job.state in (JobState.DELIVERED, JobState.REJECTED, JobState.FAILED, JobState.CANCELLED):
            bar.done()
            print(f"{job.id} {job.state.value}: {job.reason}")
            return 0 if job.state is JobState.DELIVERED else 1
        from gateway.transports.dnc.transport import read_progress

        point = read_progress(state, job.machine) if job.state is JobState.SENDING else None
        if point is not None and Path(point.program).stem == job.id and bar.enabled:
            bar.total = point.total
            text = progress_text(
                point.offset, point.total, point.line, point.lead, point.remaining, point.held
            )
            bar.show(point.offset, text)
        elif job.state.value != last:
            bar.done()
            print(f"{job.id} {job.state.value}: {job.reason}", file=out)
        last = job.state.value
        time.sleep(poll)


class Progress:
    """`[#########           ]  45%  9.0/20.0 MB  3.1 MB/s` on a terminal, for files over a megabyte."""

    def __init__(self, total: int, out: TextIO, *, threshold: int = 1024 * 1024) -> None:
        self.total = total
        self.out = out
        self.enabled = total >= threshold and out.isatty()
        self.started = time.monotonic()
        self._last = 0.0
        self._shown = False

    def __call__(self, sent: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if sent < self.total and now - self._last < 0.1:
            return
        self._last = now
        self.out.write("\r" + self.line(sent, now - self.started))
        self.out.flush()
        self._shown = True

    def line(self, sent: int, elapsed: float, width: int = 30) -> str:
        share = sent / self.total if self.total else 1.0
        filled = int(share * width)
        rate = sent / elapsed if elapsed > 0 else 0.0
        return (
            f"[{'#' * filled}{' ' * (width - filled)}] {share * 100:5.1f}%  "
            f"{sent / 1e6:.1f}/{self.total / 1e6:.1f} MB  {rate / 1e6:.1f} MB/s"
        )

    def show(self, sent: int, text: str, width: int = 30) -> None:
        """A bar with the caller's words after it (a serial delivery's line, lead and time left)."""
        share = min(1.0, sent / self.total) if self.total else 1.0
        filled = int(share * width)
        self.out.write(f"\r[{'#' * filled}{' ' * (width - filled)}] {text}\x1b[K")
        self.out.flush()
        self._shown = True

    def done(self) -> None:
        if self._shown:
            self.out.write("\n")
            self.out.flush()
            self._shown = False


def _size(n: int) -> str:
    if n < 1000:
        return f"{n} B"
    value = float(n)
    for unit in ("kB", "MB", "GB"):
        value /= 1000
        if value < 1000 or unit == "GB":
            break
    return f"{value:.1f} {unit}"


def _short(text: str, width: int) -> str:
    text = " ".join(text.split())
    return text if len(text) <= width else text[: width - 1] + "…"
