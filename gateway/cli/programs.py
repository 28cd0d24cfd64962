"""`cnc-gateway programs list|get|put|delete MACHINE …`: the controller's program store (FTP).

`programs received [MACHINE]` lists the programs operators punched on serial
machines, which the gateway stored under its state directory (`dnc/received/`);
`programs received MACHINE --get NAME [-o FILE]` prints or saves one (the
newest whose stored file, O-number or name matches), checked against the
SHA-256 recorded when it arrived.

The machine's mapping file says where the store is (`jobs.controller`). `put`
checks the program with the machine's validation rules first (`--no-validate`
skips that, for restoring a backup that a newer rule would refuse); to queue a
program as a job instead, use `cnc-gateway jobs submit`.

`put` and `delete` change the machine, so each records an audit entry in the
gateway's audit trail, like a write or a method call through OPC UA or MQTT:
`call Programs.Put` / `Programs.Delete`, origin `cli`, the OS user (or
`--user`), and the outcome. The trail is opened before the controller is
touched: a change that could not be recorded is not made. It is the state
directory's `audit.sqlite3`, found as `cnc-gateway audit list` finds it
(`--state-dir`, else the gateway file's, else $CNC_GATEWAY_STATE_DIR, else
./state or ./state/demo).
"""

from __future__ import annotations

import argparse
import asyncio
import getpass
import os
import sqlite3
import sys
import time
from collections.abc import Coroutine, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.audit.tables import describe, open_table
from gateway.cli.check import report_config_error
from gateway.cli.state_dir import add_state_dir_options, audit_where, resolve_state_dir
from gateway.config.jobs import JobsConfig
from gateway.config.loader import load
from gateway.errors import AuditStoreError, ConfigError, DeliveryError
from gateway.model.audit import AuditEntry, as_text

if TYPE_CHECKING:
    from gateway.transports.base import OpenStore
    from gateway.transports.dnc.received import ReceivedProgram, ReceivedStore


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("programs", help="list, fetch, store or delete programs on a controller (FTP)")
    actions = p.add_subparsers(dest="programs_command", metavar="ACTION", required=True)

    def common(q: argparse.ArgumentParser) -> None:
        q.add_argument("machine")
        q.add_argument(
            "-c",
            "--config",
            type=Path,
            action="append",
            metavar="FILE",
            help="gateway or mapping file(s) (default: mappings/laser-sim.yaml, the demo's)",
        )

    def audited(q: argparse.ArgumentParser) -> None:
        q.add_argument(
            "--user", default=None, help="who makes the change, for the audit trail (default: the OS user)"
        )
        q.add_argument(
            "--state-dir",
            type=Path,
            default=None,
            help="the gateway's state directory, whose audit trail records the change",
        )

    q = actions.add_parser("list", help="programs in the controller's program folder")
    common(q)
    q.set_defaults(handler=handle_list)

    q = actions.add_parser("get", help="download a program")
    common(q)
    q.add_argument("name")
    q.add_argument("-o", "--output", default=None, help="file to write (default: NAME here; - for stdout)")
    q.set_defaults(handler=handle_get)

    q = actions.add_parser("put", help="upload a program straight to the controller (temporary name, rename)")
    common(q)
    q.add_argument("file", type=Path)
    q.add_argument("--name", default=None, help="name on the controller (default: the file's name)")
    q.add_argument("--no-validate", action="store_true", help="skip the machine's validation rules")
    audited(q)
    q.set_defaults(handler=handle_put)

    q = actions.add_parser("delete", help="delete a program from the controller")
    common(q)
    q.add_argument("name")
    audited(q)
    q.set_defaults(handler=handle_delete)

    q = actions.add_parser(
        "received", help="programs operators punched on serial machines (stored by the gateway), oldest first"
    )
    q.add_argument("machine", nargs="?", default=None, help="one machine's (default: every machine's)")
    add_state_dir_options(q)
    q.add_argument("--json", action="store_true", help="one JSON object per line")
    q.add_argument(
        "--get",
        metavar="NAME",
        default=None,
        help="print or save one: its stored file, O-number (O4711) or name; the newest that matches",
    )
    q.add_argument("-o", "--output", default="-", help="with --get: the file to write (default -: stdout)")
    q.set_defaults(handler=handle_received)


def handle_received(args: argparse.Namespace) -> int:
    """Punched programs: when, which machine, the stored file, size, SHA-256 and the verdict."""
    import json

    from gateway.errors import PathRefused
    from gateway.transports.dnc.received import ReceivedStore
    from gateway.transports.dnc.transfers import transfers_path

    state = resolve_state_dir(args, "received programs", transfers_path)
    store = ReceivedStore(state)
    if args.get is not None and not args.machine:
        print("error: --get needs the machine: programs received MACHINE --get NAME", file=sys.stderr)
        return 2
    try:
        programs = store.list(args.machine)
    except PathRefused as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.get is not None:
        return _get_received(store, [p for p in programs if received_matches(p, args.get)], args)
    for p in programs:
        if args.json:
            print(json.dumps({**p.as_dict(), "path": str(store.path(p))}, ensure_ascii=False))
        else:
            local = p.received.astimezone().strftime("%Y-%m-%d %H:%M:%S")
            verdict = f"  {p.verdict}" if p.verdict else ""
            print(f"{local}  {p.machine}  {p.file}  {p.size} B  sha256 {p.sha256[:16]}{verdict}")
    if not programs and not args.json:
        print("no received programs", file=sys.stderr)
    return 0


def received_matches(program: ReceivedProgram, name: str) -> bool:
    """Does `name` name this punched program: its stored file (with or without .nc), its O-number
    (O4711 = O04711 = 4711) or the name in its header?"""
    wanted = name.strip().upper()
    if wanted in (program.file.upper(), program.file.upper().removesuffix(".NC")):
        return True
    if program.name is not None and program.name.upper() == wanted:
        return True
    digits = wanted.removeprefix("O")
    return program.number is not None and digits.isdigit() and int(digits) == program.number


def _get_received(store: ReceivedStore, matching: list[ReceivedProgram], args: argparse.Namespace) -> int:
    import hashlib

    if not matching:
        print(f"error: no program punched on {args.machine} is named {args.get!r}", file=sys.stderr)
        return 1
    program = matching[-1]  # oldest first: the newest
    try:
        data = store.path(program).read_bytes()
    except OSError as exc:
        print(f"error: cannot read {program.file}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    if len(data) != program.size or hashlib.sha256(data).hexdigest() != program.sha256:
        print(f"error: {program.file} is not the program received (size or SHA-256 differ)", file=sys.stderr)
        return 1
    if args.output == "-":
        sys.stdout.buffer.write(data)
        sys.stdout.flush()
    else:
        Path(args.output).write_bytes(data)
        print(f"wrote {args.output} ({len(data)} bytes, {program.file})", file=sys.stderr)
    return 0


def jobs_config(args: argparse.Namespace) -> JobsConfig:
    from gateway.cli.demo import find_mapping

    files = args.config or [find_mapping(None)]
    try:
        config = load(files)
    except ConfigError as exc:
        report_config_error(exc)
        raise SystemExit(2) from None
    for mapping in config.machines:
        if mapping.machine == args.machine:
            if mapping.jobs is None:
                print(
                    f"error: {args.machine} has no jobs section (no program store configured)",
                    file=sys.stderr,
                )
                raise SystemExit(2)
            return mapping.jobs
    names = ", ".join(m.machine for m in config.machines)
    print(
        f"error: no machine {args.machine!r} in {', '.join(map(str, files))} (there: {names})",
        file=sys.stderr,
    )
    raise SystemExit(2)


def open_store(args: argparse.Namespace, cfg: JobsConfig) -> OpenStore:
    """The machine's program store; exits 2 if its delivery transport has none."""
    from gateway.transports.registry import program_store_for

    store = program_store_for(cfg.controller)
    if store is None:
        print(f"error: {args.machine}'s controller has no program store to list or change", file=sys.stderr)
        raise SystemExit(2)
    return store


def os_user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):  # no login name and no passwd entry (a container's bare uid)
        return f"uid {os.getuid()}" if hasattr(os, "getuid") else "unknown"


class Audit:
    """The audit entry of one change made from the shell, as the tree records a method call.

    Opened before the controller is touched, so that a change that could not be
    recorded is not made; `record()` writes the entry once the outcome is known.
    """

    def __init__(self, args: argparse.Namespace, method: str) -> None:
        self.machine = args.machine
        self.target = f"Programs.{method}"
        self.user = args.user or os_user()
        self.path = audit_where(args)
        try:
            self.store = open_table(self.path)
        except (AuditStoreError, sqlite3.Error, OSError) as exc:
            print(f"error: cannot open the audit trail {describe(self.path)} ({exc}); nothing changed",
                  file=sys.stderr)  # fmt: skip
            raise SystemExit(2) from None
        self.time = datetime.now(UTC)
        self.started = time.monotonic()

    def record(self, arguments: Sequence[Any], status: str = "Good", reason: str = "") -> None:
        entry = AuditEntry(
            self.time,
            "call",
            self.machine,
            self.target,
            "cli",
            self.user,
            None,
            None,
            as_text(list(arguments)),
            status,
            reason,
            time.monotonic() - self.started,
        )
        try:
            self.store.insert([entry])
        except (AuditStoreError, sqlite3.Error, OSError) as exc:
            print(f"error: {entry.describe()}; not recorded in {describe(self.path)}: {exc}", file=sys.stderr)
            raise SystemExit(1) from None
        finally:
            self.store.close()

    def refused(self, arguments: Sequence[Any], exc: DeliveryError) -> None:
        """The controller's store refused, or could not be reached: as a method call would answer."""
        from gateway.jobs.programs import as_write_error

        self.record(arguments, as_write_error(exc).status, exc.reason)


def _run(coro: Coroutine[Any, Any, int]) -> int:
    try:
        return asyncio.run(coro)
    except DeliveryError as exc:
        print(f"error: {exc.reason}", file=sys.stderr)
        return 1


def handle_list(args: argparse.Namespace) -> int:
    cfg = jobs_config(args)
    store_of = open_store(args, cfg)

    async def main() -> int:
        async with store_of() as store:
            files = await store.list()
        for f in files:
            size = "?" if f.size is None else str(f.size)
            print(f"{size:>12}  {f.modified or '':<14}  {f.name}")
        print(f"{len(files)} program(s) in {store.address}", file=sys.stderr)
        return 0

    return _run(main())


def handle_get(args: argparse.Namespace) -> int:
    cfg = jobs_config(args)
    store_of = open_store(args, cfg)

    async def main() -> int:
        async with store_of() as store:
            data = await store.get(args.name)
        if args.output == "-":
            sys.stdout.buffer.write(data)
            sys.stdout.flush()
        else:
            target = Path(args.output or args.name)
            target.write_bytes(data)  # noqa: ASYNC240 - the command's last step: nothing else runs
            print(f"wrote {target} ({len(data)} bytes)", file=sys.stderr)
        return 0

    return _run(main())


def handle_put(args: argparse.Namespace) -> int:
    from gateway.jobs.validation.pipeline import validate_program

    cfg = jobs_config(args)
    store_of = open_store(args, cfg)
    if not args.file.is_file():
        print(f"error: {args.file}: no such file", file=sys.stderr)
        return 2
    name = args.name or args.file.name
    data = args.file.read_bytes()
    program = data
    audit = Audit(args, "Put")
    arguments: list[Any] = [name, data, "--no-validate"] if args.no_validate else [name, data]
    if not args.no_validate:
        verdict = validate_program(data, name, cfg.validation)
        if not verdict.accepted:
            first, more = verdict.rejections[0].reason, len(verdict.rejections) - 1
            audit.record(arguments, "BadInvalidArgument", first + (f" (and {more} more)" if more else ""))
            print(f"error: {name} would be rejected:", file=sys.stderr)
            for r in verdict.rejections:
                print(f"  [{r.rule}] {r.reason}", file=sys.stderr)
            return 1
        program = verdict.program

    async def main() -> int:
        try:
            async with store_of() as store:
                await store.put(name, program)
                size = await store.size(name)
        except DeliveryError as exc:
            audit.refused(arguments, exc)
            raise
        if size != len(program):
            reason = f"the controller reports {size} bytes for {name}, expected {len(program)}"
            audit.record(arguments, "BadUnexpectedError", reason)
            print(f"error: {reason}", file=sys.stderr)
            return 1
        audit.record(arguments)
        print(f"stored {name} ({len(program)} bytes) in {store.address}")
        return 0

    return _run(main())


def handle_delete(args: argparse.Namespace) -> int:
    cfg = jobs_config(args)
    store_of = open_store(args, cfg)
    audit = Audit(args, "Delete")

    async def main() -> int:
        try:
            async with store_of() as store:
                await store.delete(args.name)
        except DeliveryError as exc:
            audit.refused([args.name], exc)
            raise
        audit.record([args.name])
        print(f"deleted {args.name} from {store.address}")
        return 0

    return _run(main())
