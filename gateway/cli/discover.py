"""`cnc-gateway discover opc.tcp://…` (or `http://agent:5000`, `focas://host:8193`): a starting mapping file
from a controller (browsed over OPC UA, asked over FOCAS2) or from an MTConnect agent's /probe. The
driver is the one whose spec `discovers` the endpoint's scheme (gateway/sources/base.py `DriverSpec`),
else the default driver (OPC UA)."""

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
        "endpoint",
        help="opc.tcp://host:port of the controller, http://host:port of an MTConnect agent, or "
        "focas://host:8193 of a Fanuc",
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

    from gateway.sources import registry
    from gateway.sources.base import DiscoverRequest

    configure("warning")
    spec = next(
        (s for s in registry.ordered() if s.discovers and args.endpoint.startswith(s.discovers)), None
    )
    if spec is None:  # the default driver's (OPC UA): its endpoint is checked first
        try:
            check_endpoint(args.endpoint)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        spec = registry.find(registry.DEFAULT)
    if spec is None or spec.discover is None:  # a driver that names endpoints without discovering them
        print(f"error: nothing discovers {args.endpoint}", file=sys.stderr)
        return 2
    request = DiscoverRequest(
        endpoint=args.endpoint,
        machine=args.machine,
        timeout=args.timeout,
        device=args.device,
        user=args.user,
        password=args.password or os.environ.get("CNC_DISCOVER_PASSWORD"),
        security=args.security,
        start=args.start,
        max_depth=args.max_depth,
        max_variables=args.max_variables,
    )
    try:
        text = asyncio.run(spec.discover(request))
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
