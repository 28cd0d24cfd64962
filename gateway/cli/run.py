"""`cnc-gateway run FILE...`: run the gateway from a gateway file or from mapping files."""

from __future__ import annotations

import argparse
import gc
import logging
import os
from pathlib import Path

from gateway.app import Gateway, run_until_signalled
from gateway.cli.check import report_config_error
from gateway.config.loader import Config, load
from gateway.errors import ConfigError, SinkError, StoreError
from gateway.logconfig import configure
from gateway.shims.loop import ENV, LOOPS, loop_factory, loop_name, run

log = logging.getLogger("gateway")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "run", help="run the gateway (a gateway file, or one or more mapping files with defaults)"
    )
    p.add_argument("files", nargs="+", type=Path, metavar="FILE")
    p.add_argument("--log-level", choices=["debug", "info", "warning", "error"], default=None)
    p.add_argument(
        "--loop",
        choices=LOOPS,
        default=None,
        help=f"event loop: asyncio's own (the default), uvloop (pip install 'cnc-gateway[fast]'), or auto: "
        f"uvloop when installed; also ${ENV}",
    )
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    # No cyclic GC passes from here until the gateway has started: loading the mappings and building
    # the tree and the address space make millions of objects and little garbage, and each pass scans
    # them all (a fifth of the configuration's load time). The gateway collects once, freezes what
    # start-up built (app.Gateway._settle_heap), and then the collector runs again.
    enabled = gc.isenabled()
    gc.disable()
    try:
        try:
            config = load(args.files)
        except ConfigError as exc:
            report_config_error(exc)
            return 2
        configure(args.log_level or config.gateway.log_level)
        try:
            factory = loop_factory(args.loop)
        except ValueError as exc:
            log.error("%s", exc)
            return 2
        log.debug("event loop: %s", loop_name(factory))
        return run(serve(config, resume_gc=enabled), factory)
    finally:
        if enabled:
            gc.enable()


async def serve(config: Config, *, resume_gc: bool = False) -> int:
    try:
        await run_until_signalled(_serve(config, resume_gc))
    except (SinkError, StoreError) as exc:  # a port taken, a database (queue, leases, audit) out of reach
        log.error("cannot start: %s", exc)
        return 1
    return 0


async def _serve(config: Config, resume_gc: bool = False) -> None:
    # handle paused the collector: the gateway turns it on again once its start-up is over
    async with Gateway(config, collector=True if resume_gc else None) as gw:
        for sink in gw.sinks:
            endpoint = getattr(sink, "endpoint", None)
            if endpoint:
                log.info("%s serving on %s", sink.name, endpoint)
        log.info(
            "mirroring %s", ", ".join(f"{m.machine} ({len(m.variables)} variables)" for m in config.machines)
        )
        from gateway.shards.parent import orphan_watch  # a shard of `cnc-gateway fleet` stops with it

        await gw.run(*orphan_watch(os.environ))
