"""`cnc-gateway alarms list`: the alarm history from the state directory, whether the gateway runs or not.

    cnc-gateway alarms list --machine laser-sim --since 2h
    cnc-gateway alarms list --since 2026-05-06 --active --json

`--since` takes a duration back from now (`90s`, `15m`, `2h`, `7d`, `2w`), `today`,
or an ISO-8601 date or time (local time unless it names a zone); see since.py.
Listed: occurrences raised since then, and those still active then, newest first.
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import datetime
from typing import Any, TextIO

from gateway.alarms.records import AlarmRecord
from gateway.alarms.store import AlarmHistory, AlarmStore, history_at, store_path
from gateway.cli.since import HELP as SINCE_HELP
from gateway.cli.since import since_arg
from gateway.cli.state_dir import add_state_dir_options, load_config, resolve_state_dir
from gateway.errors import AlarmStoreError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("alarms", help="the alarm history kept in the state directory")
    alarms = p.add_subparsers(dest="alarms_command", metavar="ACTION", required=True)
    q = alarms.add_parser("list", help="alarm occurrences, newest first")
    add_state_dir_options(q)
    q.add_argument("--machine", default=None)
    q.add_argument(
        "--since", default=None, type=since_arg, metavar="WHEN", help=f"{SINCE_HELP} (default: everything)"
    )
    q.add_argument("--active", action="store_true", help="only alarms that are still active")
    q.add_argument("--limit", type=int, default=200)
    q.add_argument("--json", action="store_true")
    q.set_defaults(handler=handle_list)


def history(args: argparse.Namespace) -> AlarmHistory:
    """The gateway file's `alarm_history:` database (-c), else the state directory's file."""
    if args.state_dir is None:
        config = load_config(args)
        if config is not None:
            return history_at(config.gateway.alarm_history, config.state_dir)
    return AlarmStore(store_path(resolve_state_dir(args, "alarms", store_path)))


def handle_list(args: argparse.Namespace) -> int:
    store = history(args)
    try:
        store.open(create=False)
        records = store.history(args.machine, args.since, active_only=args.active, limit=args.limit)
    except AlarmStoreError as exc:
        print(f"error: {exc} (give -c FILE or --state-dir)", file=sys.stderr)
        return 1
    finally:
        store.close()
    if args.json:
        print(json.dumps([_json(r) for r in records], indent=2))
        return 0
    print_table(records, sys.stdout)
    return 0


def _json(record: AlarmRecord) -> dict[str, Any]:
    doc = record.as_dict()
    doc["machine"] = record.machine
    doc.pop("quality", None)  # a property of the running gateway's view, not of the history
    return {k: (v.isoformat() if isinstance(v, datetime) else v) for k, v in doc.items()}


def _when(ts: datetime | None) -> str:
    return ts.astimezone().strftime("%Y-%m-%d %H:%M:%S") if ts is not None else "-"


def print_table(records: list[AlarmRecord], out: TextIO) -> None:
    if not records:
        print("no alarms", file=out)
        return
    rows = [("OCC", "MACHINE", "ALARM", "SEV", "RAISED", "CLEARED", "ACKNOWLEDGED", "TEXT")]
    for r in records:
        acked = f"{_when(r.acked_at)} {r.acked_by}" if r.acked else "-"
        if r.confirmed:
            acked += " (confirmed)"
        rows.append(
            (
                str(r.occurrence),
                r.machine,
                r.id,
                str(r.severity),
                _when(r.raised_at),
                "active" if r.active else _when(r.cleared_at),
                acked,
                r.text,
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=False)) + "  " + row[-1], file=out)
