"""`cnc-gateway fleet FLEET.yaml`: the shards of one gateway file as processes on this host, supervised.

Checks the gateway file as each shard will read it (its `CNC_SHARD`, state directory and ports:
gateway/config/fleet.py), then starts one `cnc-gateway run` per shard and starts again any that
ends, with backoff (gateway/shards/supervisor.py). A line per shard says each start and end;
the table of every shard is printed once all are up. SIGINT/SIGTERM stop every shard cleanly.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
from pathlib import Path

from gateway.app import run_until_signalled
from gateway.cli.check import report_config_error
from gateway.config.fleet import load_fleet, shard_specs
from gateway.config.loader import load
from gateway.errors import ConfigError
from gateway.logconfig import configure
from gateway.reconnect import BackoffShape
from gateway.shards.supervisor import FleetSupervisor, ShardSpec, ShardState

log = logging.getLogger("gateway.fleet")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "fleet", help="run a gateway file's shards as processes on this host, restarted if they end"
    )
    p.add_argument("file", type=Path, metavar="FLEET.yaml")
    p.add_argument(
        "--check", action="store_true", help="check the fleet and every shard's gateway file, then exit"
    )
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"], default="info")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    try:
        fleet, gateway = load_fleet(args.file)
    except ConfigError as exc:
        report_config_error(exc)
        return 2
    specs = shard_specs(fleet, args.file, gateway)
    for spec in specs:  # each shard's view of the gateway file, before any starts
        try:
            config = load([gateway], environ={**os.environ, **spec.environ})
        except ConfigError as exc:
            print(f"{spec.label} ({' '.join(f'{k}={v}' for k, v in spec.environ.items())}):")
            report_config_error(exc)
            return 2
        names = ", ".join(m.machine for m in config.machines)
        print(f"{spec.label}: {len(config.machines)} machine(s): {names}; state {config.state_dir}")
    if args.check:
        return 0
    configure(args.log_level)
    return asyncio.run(_serve(specs, fleet.restart))


async def _serve(specs: list[ShardSpec], restart: BackoffShape) -> int:
    up: set[int] = set()

    def changed(state: ShardState) -> None:
        if state.pid is not None:
            up.add(state.spec.number)
        if len(up) == len(specs) and not printed:
            printed.append(True)
            print("\n".join(["", "fleet: every shard started", *supervisor.status(), ""]), flush=True)

    printed: list[bool] = []
    supervisor = FleetSupervisor(specs, backoff=restart, base_environ=os.environ, on_change=changed)

    async def main() -> None:
        async with supervisor:
            await supervisor.run()

    await run_until_signalled(main())
    print("\n".join(["fleet: stopped", *supervisor.status()]), flush=True)
    return 0
