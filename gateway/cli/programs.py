"""`cnc-gateway programs list|get|put|delete MACHINE …`: the controller's program store (FTP).

The machine's mapping file says where the store is (`jobs.controller`). `put`
checks the program with the machine's validation rules first (`--no-validate`
skips that, for restoring a backup that a newer rule would refuse); to queue a
program as a job instead, use `cnc-gateway jobs submit`.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.cli.check import report_config_error
from gateway.config.jobs import JobsConfig
from gateway.config.loader import load
from gateway.errors import ConfigError, DeliveryError

if TYPE_CHECKING:
    from gateway.jobs.delivery.transport import OpenStore


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("programs", help="list, fetch, store or delete programs on a controller (FTP)")
    actions = p.add_subparsers(dest="programs_command", metavar="ACTION", required=True)

    def common(q: argparse.ArgumentParser) -> None:
        q.add_argument("machine")
        q.add_argument("-c", "--config", type=Path, action="append", metavar="FILE",
                       help="gateway or mapping file(s) (default: mappings/laser-sim.yaml, the demo's)")

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
    q.set_defaults(handler=handle_put)

    q = actions.add_parser("delete", help="delete a program from the controller")
    common(q)
    q.add_argument("name")
    q.set_defaults(handler=handle_delete)


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
                print(f"error: {args.machine} has no jobs section (no program store configured)", file=sys.stderr)
                raise SystemExit(2)
            return mapping.jobs
    names = ", ".join(m.machine for m in config.machines)
    print(f"error: no machine {args.machine!r} in {', '.join(map(str, files))} (there: {names})", file=sys.stderr)
    raise SystemExit(2)


def open_store(args: argparse.Namespace, cfg: JobsConfig) -> OpenStore:
    """The machine's program store; exits 2 if its delivery transport has none."""
    from gateway.jobs.delivery.transports import program_store_for

    store = program_store_for(cfg)
    if store is None:
        print(f"error: {args.machine}'s controller has no program store to list or change", file=sys.stderr)
        raise SystemExit(2)
    return store


def _run(coro: object) -> int:
    try:
        return asyncio.run(coro)  # type: ignore[arg-type]
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
            target.write_bytes(data)
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
    if not args.no_validate:
        verdict = validate_program(data, name, cfg.validation)
        if not verdict.accepted:
            print(f"error: {name} would be rejected:", file=sys.stderr)
            for r in verdict.rejections:
                print(f"  [{r.rule}] {r.reason}", file=sys.stderr)
            return 1
        program = verdict.program

    async def main() -> int:
        async with store_of() as store:
            await store.put(name, program)
            size = await store.size(name)
        if size != len(program):
            print(f"error: the controller reports {size} bytes for {name}, expected {len(program)}", file=sys.stderr)
            return 1
        print(f"stored {name} ({len(program)} bytes) in {store.address}")
        return 0

    return _run(main())


def handle_delete(args: argparse.Namespace) -> int:
    cfg = jobs_config(args)
    store_of = open_store(args, cfg)

    async def main() -> int:
        async with store_of() as store:
            await store.delete(args.name)
        print(f"deleted {args.name} from {store.address}")
        return 0

    return _run(main())
