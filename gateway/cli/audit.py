"""`cnc-gateway audit list`: who wrote, called, acknowledged or confirmed what (the audit table).

Reads `<state_dir>/audit.sqlite3` directly, or the PostgreSQL database of the gateway file's `audit:`
(-c), so it works whether the gateway runs or not (entries reach the table within a moment of the
write).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gateway.audit.tables import open_table
from gateway.cli.since import HELP as SINCE_HELP
from gateway.cli.since import since_arg
from gateway.cli.state_dir import add_state_dir_options, audit_where
from gateway.errors import AuditStoreError
from gateway.model.audit import AuditEntry
from gateway.sqlite_file import iso

KIND_WIDTH = len("acknowledge")  # write, call, acknowledge, confirm


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "audit",
        help="the audit trail: every write, method call and alarm acknowledge/confirm, "
        "who, what, and the result",
    )
    audit = p.add_subparsers(dest="audit_command", metavar="ACTION", required=True)
    q = audit.add_parser("list", help="audit entries, newest first")
    add_state_dir_options(q)
    q.add_argument("--machine", default=None)
    q.add_argument("--user", default=None, help="entries of this user only")
    q.add_argument("--since", default=None, type=since_arg, metavar="WHEN", help=SINCE_HELP)
    q.add_argument("--limit", type=int, default=100)
    q.add_argument("--json", action="store_true", help="one JSON object per line")
    q.set_defaults(handler=handle_list)


def handle_list(args: argparse.Namespace) -> int:
    where = audit_where(args)
    try:
        store = open_table(where, create=False)
    except AuditStoreError as exc:
        missing = isinstance(where, Path) and not where.is_file()
        print(f"{exc}{' (the gateway creates it when it starts)' if missing else ''}", file=sys.stderr)
        return 1
    try:
        rows = store.query(machine=args.machine, user=args.user, since=args.since, limit=args.limit)
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
            "time": iso(e.time),
            "kind": e.kind,
            "machine": e.machine,
            "target": e.target,
            "origin": e.origin,
            "user": e.user,
            "role": e.role,
            "old": e.old,
            "new": e.new,
            "status": e.status,
            "reason": e.reason,
            "duration_ms": round(e.duration * 1000, 3),
        },
        ensure_ascii=False,
    )
