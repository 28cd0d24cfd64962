"""`cnc-gateway dnc log`: the serial DNC transfer log (what went to and came from which machine).

Reads `<state_dir>/dnc/transfers.sqlite3` directly, so it works whether the
gateway runs or not.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gateway.cli.since import HELP as SINCE_HELP
from gateway.cli.since import since_arg
from gateway.cli.state_dir import add_state_dir_options, resolve_state_dir
from gateway.errors import TransferLogError
from gateway.sqlite_file import iso
from gateway.transports.dnc.transfers import DIRECTIONS, TransferLog, TransferRecord, transfers_path


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("dnc", help="serial DNC: the transfer log of programs sent and received")
    dnc = p.add_subparsers(dest="dnc_command", metavar="ACTION", required=True)
    q = dnc.add_parser("log", help="transfers, oldest first: machine, direction, program, size, SHA-256")
    add_state_dir_options(q)
    q.add_argument("--since", default=None, type=since_arg, metavar="WHEN", help=SINCE_HELP)
    q.add_argument("--machine", default=None)
    q.add_argument("--direction", choices=DIRECTIONS, default=None)
    q.add_argument("--limit", type=int, default=1000, help="at most the newest N (default 1000)")
    q.add_argument("--json", action="store_true", help="one JSON object per line")
    q.set_defaults(handler=handle_log)


def state_dir(args: argparse.Namespace) -> Path:
    return resolve_state_dir(args, "DNC transfers", transfers_path)


def handle_log(args: argparse.Namespace) -> int:
    path = transfers_path(state_dir(args))
    try:
        log = TransferLog(path, create=False)
    except TransferLogError as exc:
        hint = "" if path.is_file() else " (the gateway creates it with the first serial transfer)"
        print(f"{exc}{hint}", file=sys.stderr)
        return 1
    try:
        rows = log.query(since=args.since, machine=args.machine, direction=args.direction, limit=args.limit)
    finally:
        log.close()
    for row in rows:
        print(as_json(row.record) if args.json else as_line(row.record))
    if not rows and not args.json:
        print("no transfers", file=sys.stderr)
    return 0


def as_line(r: TransferRecord) -> str:
    local = r.ended.astimezone().strftime("%Y-%m-%d %H:%M:%S")
    arrow = "->" if r.direction == "send" else "<-"
    who = r.user or "-"
    tail = f"  {r.detail}" if r.detail else ""
    return (
        f"{local}  {r.machine} {arrow} {r.program}  {r.size} B  sha256 {r.sha256[:16]}  "
        f"{r.outcome}  {r.seconds:.1f} s  by {who}{tail}"
    )


def as_json(r: TransferRecord) -> str:
    return json.dumps(
        {
            "machine": r.machine,
            "direction": r.direction,
            "program": r.program,
            "size": r.size,
            "sha256": r.sha256,
            "started": iso(r.started),
            "ended": iso(r.ended),
            "outcome": r.outcome,
            "user": r.user,
            "detail": r.detail,
        },
        ensure_ascii=False,
    )
