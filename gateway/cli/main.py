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
    "dnc",
    "sparkplug",
    "tokens",
    "modbus",
)
MODULE_OF = {name: name for name in COMMANDS if name != "passwords"} | {"hash-password": "passwords"}


def _modules(argv: Sequence[str]) -> tuple[str, ...]:
    """The command modules to register: the named command's alone, or all (no command, --help, a typo)."""
    first = next((arg for arg in argv if not arg.startswith("-")), None)
    if first is None:
        return COMMANDS
    module = MODULE_OF.get(first)
    return COMMANDS if module is None else (module,)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser, with every command, or with only the one `argv` names (argv given)."""
    parser = argparse.ArgumentParser(
        prog="cnc-gateway",
        description="Mirror CNC variables into OPC UA (and more), "
        "driven by one YAML mapping file per machine.",
    )
    parser.add_argument("--version", action="version", version=f"cnc-gateway {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS if argv is None else _modules(argv):
        importlib.import_module(f"gateway.cli.{name}").register(sub)
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
