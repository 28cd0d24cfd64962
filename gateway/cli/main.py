"""Entry point: builds the argument parser from the command modules and dispatches."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from gateway import __version__
from gateway.cli import (
    alarms,
    audit,
    check,
    demo,
    discover,
    dnc,
    frames,
    jobs,
    passwords,
    programs,
    run,
    schema,
    sparkplug,
    tokens,
)

COMMANDS = (
    run,
    check,
    schema,
    discover,
    demo,
    jobs,
    programs,
    passwords,
    frames,
    audit,
    alarms,
    dnc,
    sparkplug,
    tokens,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cnc-gateway",
        description="Mirror CNC variables into OPC UA (and more), "
        "driven by one YAML mapping file per machine.",
    )
    parser.add_argument("--version", action="version", version=f"cnc-gateway {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `cnc-gateway check … | head`
        sys.stderr.close()
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
