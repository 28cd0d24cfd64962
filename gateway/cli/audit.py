"""`cnc-gateway audit list`: who wrote, called, acknowledged or confirmed what, from the state directory's audit table.

Reads `<state_dir>/audit.sqlite3` directly, so it works whether the gateway runs
or not (entries reach the table within a moment of the write).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path

from gateway.model.audit import AuditEntry
from gateway.audit.store import AuditStore, audit_path, iso
from gateway.cli.state_dir import resolve_state_dir

_RELATIVE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([smhd])\s*$")
_UNITS = {"s": "seconds", "m": "minutes", "h": "hours", "d": "days"}
KIND_WIDTH = len("acknowledge")  # write, call, acknowledge, confirm


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("audit", help="the audit trail: every write, method call and alarm acknowledge/confirm, who, what, and the result")
    audit = p.add_subparsers(dest="audit_command", metavar="ACTION", required=True)
    q = audit.add_parser("list", help="audit entries, newest first")
    q.add_argument("-c", "--config", type=Path, action="append", metavar="FILE",
                   help="gateway or mapping file(s) the gateway runs with (to find its state directory)")
    q.add_argument("--state-dir", type=Path, default=None, help="the gateway's state directory")
    q.add_argument("--machine", default=None)
    q.add_argument("--user", default=None, help="entries of this user only")
    q.add_argument("--since", default=None, metavar="WHEN",
                   help="ISO time (2026-05-06T07:00, UTC unless it says otherwise) or an age: 30m, 2h, 7d")
    q.add_argument("--limit", type=int, default=100)
    q.add_argument("--json", action="store_true", help="one JSON object per line")
    q.set_defaults(handler=handle_list)


def parse_since(text: str, now: datetime | None = None) -> datetime:
    """An ISO time, or an age such as 30m, 2h, 7d. ValueError says what is expected."""
    m = _RELATIVE.match(text)
    if m:
        return (now or datetime.now(timezone.utc)) - timedelta(**{_UNITS[m.group(2)]: float(m.group(1))})
    try:
        ts = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(
            f"--since {text!r}: expected an ISO time such as 2026-05-06T07:00 or an age such as 2h"
        ) from None
    return ts if ts.tzinfo else ts.replace(tzinfo=timezone.utc)


def state_dir(args: argparse.Namespace) -> Path:
    return resolve_state_dir(args, "audit", audit_path)


def handle_list(args: argparse.Namespace) -> int:
    try:
        since = parse_since(args.since) if args.since else None
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    path = audit_path(state_dir(args))
    try:
        store = AuditStore(path, create=False)
    except FileNotFoundError:
        print(f"no audit table at {path} (the gateway creates it when it starts)", file=sys.stderr)
        return 1
    try:
        rows = store.query(machine=args.machine, user=args.user, since=since, limit=args.limit)
    finally:
        store.close()
    for row in rows:
        print(as_json(row.entry) if args.json else as_line(row.entry))
    if not rows and not args.json:
        print("no entries", file=sys.stderr)
    return 0


def as_line(e: AuditEntry) -> str:
    local = e.time.astimezone().strftime("%Y-%m-%d %H:%M:%S")
    who = f"{e.user or 'anonymous'}@{e.origin}" + (f"/{e.role}" if e.role else "")
    if e.kind == "write":
        what = f"{e.machine}/{e.target} {e.old} -> {e.new}"
    else:
        what = f"{e.machine}/{e.target}({(e.new or '[]')[1:-1]})"
    result = "ok" if e.ok else f"{e.status}: {e.reason}"
    return f"{local}  {e.kind:<{KIND_WIDTH}}  {who:<28}  {what}  {result}  ({e.duration * 1000:.0f} ms)"


def as_json(e: AuditEntry) -> str:
    return json.dumps(
        {
            "time": iso(e.time), "kind": e.kind, "machine": e.machine, "target": e.target, "origin": e.origin,
            "user": e.user, "role": e.role, "old": e.old, "new": e.new, "status": e.status, "reason": e.reason,
            "duration_ms": round(e.duration * 1000, 3),
        },
        ensure_ascii=False,
    )
