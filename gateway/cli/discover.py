"""`cnc-gateway discover opc.tcp://…` (or `http://agent:5000`): a starting mapping file from a controller
(browsed over OPC UA) or from an MTConnect agent's /probe."""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from pathlib import Path

from gateway.errors import SourceError
from gateway.logconfig import configure
from gateway.settings.urls import check_endpoint


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "discover",
        help="browse a controller's OPC UA server (or an MTConnect agent) and print a starting mapping file",
    )
    p.add_argument(
        "endpoint", help="opc.tcp://host:port of the controller, or http://host:port of an MTConnect agent"
    )
    p.add_argument(
        "--device", default=None, help="MTConnect: the device's name or uuid, when the agent has several"
    )
    p.add_argument("--machine", default="my-machine", help="machine name for the generated file")
    p.add_argument("--user", default=None)
    p.add_argument("--password", default=None, help="or set CNC_DISCOVER_PASSWORD")
    p.add_argument("--security", default="None", help="asyncua security string (default None)")
    p.add_argument("--start", default=None, help="node id to browse from (default: Objects)")
    p.add_argument("--max-depth", type=int, default=12)
    p.add_argument("--max-variables", type=int, default=5000)
    p.add_argument("--timeout", type=float, default=5.0)
    p.add_argument("-o", "--output", type=Path, default=None, help="write to this file instead of stdout")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    import os

    from gateway.sources.opcua.discover import discover

    configure("warning")
    if args.endpoint.startswith(("http://", "https://")):
        return _mtconnect(args)
    try:
        check_endpoint(args.endpoint)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    password = args.password or os.environ.get("CNC_DISCOVER_PASSWORD")
    try:
        text = asyncio.run(
            discover(
                args.endpoint,
                machine=args.machine,
                username=args.user,
                password=password,
                security=args.security,
                start=args.start,
                max_depth=args.max_depth,
                max_variables=args.max_variables,
                timeout=args.timeout,
            )
        )
    except (SourceError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return _write(args, text)


def _mtconnect(args: argparse.Namespace) -> int:
    from gateway.sources.mtconnect.discover import discover_agent

    try:
        text = asyncio.run(
            discover_agent(args.endpoint, machine=args.machine, device=args.device, wait=args.timeout)
        )
    except (SourceError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return _write(args, text)


def _write(args: argparse.Namespace, text: str) -> int:
    if args.output:
        args.output.write_text(text, encoding="utf-8")
        print(f"wrote {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    logging.shutdown()
    return 0
