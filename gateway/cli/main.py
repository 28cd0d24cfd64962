"""Entry point: builds the argument parser from the command modules and dispatches."""

from __future__ import annotations

import argparse
import gc
import importlib
import sys
from collections.abc import Sequence

from gateway import __version__

# The command modules, in the order `--help` lists them. Only the module of the command given is
# imported (a command's module imports what it needs: `run` the gateway, `frames` the COPYDATA codec...),
# so that `cnc-gateway run` does not load every other command's libraries; `--help` imports them all.
COMMANDS = (
    "run",
    "check",
    "schema",
    "discover",
    "demo",
    "jobs",
    "programs",
    "passwords",
    "frames",
    "audit",
    "alarms",
    "dnc",  # serial DNC's transfer log: here, not in gateway/transports/dnc/, as it reads the gateway file
    "sparkplug",
    "tokens",
    "shards",
    "fleet",
)
MODULE_OF = {name: name for name in COMMANDS if name != "passwords"} | {"hash-password": "passwords"}


def _driver_commands() -> dict[str, str]:
    """The verbs drivers and delivery transports add (`DriverSpec.commands` in gateway/sources/base.py,
    `TransportSpec.commands` in gateway/transports/base.py): verb -> module. Read only for a verb that is
    not the gateway's own, so that those do not load the adapters' settings models."""
    from gateway.sources.registry import DRIVERS
    from gateway.transports.registry import TRANSPORTS

    verbs = [*(spec.commands for spec in DRIVERS), *(spec.commands for spec in TRANSPORTS)]
    return {verb: module for commands in verbs for verb, module in commands}


def _modules(argv: Sequence[str]) -> tuple[str, ...]:
    """The command modules to register (dotted names): the named command's alone, or all (no command,
    --help, a typo)."""
    first = next((arg for arg in argv if not arg.startswith("-")), None)
    module = MODULE_OF.get(first) if first is not None else None
    if module is not None:
        return (f"gateway.cli.{module}",)
    drivers = _driver_commands()
    if first is not None and first in drivers:
        return (drivers[first],)
    return (*(f"gateway.cli.{name}" for name in COMMANDS), *drivers.values())


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser, with every command, or with only the one `argv` names (argv given)."""
    parser = argparse.ArgumentParser(
        prog="cnc-gateway",
        description="Mirror CNC variables into OPC UA (and more), "
        "driven by one YAML mapping file per machine.",
    )
    parser.add_argument("--version", action="version", version=f"cnc-gateway {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in _modules([] if argv is None else argv):
        importlib.import_module(module).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    given = sys.argv[1:] if argv is None else argv
    enabled = gc.isenabled()
    gc.disable()  # importing a command's modules makes many objects and no garbage: no collector passes
    try:
        parser = build_parser(given)
        args = parser.parse_args(given)
    finally:
        if enabled:
            gc.enable()
    try:
        return int(args.handler(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `cnc-gateway check … | head`
        sys.stderr.close()
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
