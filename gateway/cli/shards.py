"""`cnc-gateway shards`: the machines' leases in the shards' PostgreSQL database, one line per machine.

Which process holds which machine, with which fencing token, for how long still (by the database's
clock), and which processes are members now. The database is the gateway file's `queue:` (-c), or
--database URL; the password from PGPASSWORD or ~/.pgpass.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gateway.cli.state_dir import load_config
from gateway.errors import LeaseError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("shards", help="the machines' leases and the live shards (PostgreSQL)")
    p.add_argument(
        "-c", "--config", type=Path, action="append", metavar="FILE",
        help="the gateway file whose queue: names the database",
    )  # fmt: skip
    p.add_argument("--database", default=None, metavar="URL", help="postgresql://… (instead of -c)")
    p.add_argument("--json", action="store_true", help="as JSON")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.shards.leases import LeaseTable

    url = args.database
    if url is None:
        config = load_config(args)
        url = config.gateway.queue if config is not None else None
    if url is None:
        print("error: give --database URL, or -c a gateway file with queue: postgresql://…", file=sys.stderr)
        return 2
    try:
        with LeaseTable(url) as table:
            leases, members = table.leases(), table.members()
    except LeaseError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        rows = [
            {"machine": x.machine, "holder": x.holder if x.live else None, "token": x.token,
             "remaining": round(x.remaining, 1) if x.live else None}
            for x in leases
        ]  # fmt: skip
        print(json.dumps({"members": members, "leases": rows}, indent=2))
        return 0
    print(f"members: {', '.join(members) or 'none'}")
    print(f"{'MACHINE':<20} {'HOLDER':<28} {'TOKEN':>8}  REMAINING")
    for x in leases:
        holder, left = (x.holder or "", f"{x.remaining:.1f} s") if x.live else ("(free)", "-")
        print(f"{x.machine:<20} {holder:<28} {x.token:>8}  {left}")
    return 0
