"""`cnc-gateway check FILE...`: validate configuration and print each machine's tree."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, TextIO

from gateway.config.loader import Config, load
from gateway.config.mapping import MachineMapping, VariableSpec
from gateway.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="validate mapping/gateway files and print each machine's variable tree")
    p.add_argument("files", nargs="+", type=Path, metavar="FILE")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    try:
        config = load(args.files)
    except ConfigError as exc:
        report_config_error(exc)
        return 2
    print_config(config, sys.stdout)
    return 0


def report_config_error(exc: ConfigError, out: TextIO = sys.stderr) -> None:
    for issue in exc.issues:
        print(f"error: {issue}", file=out)
    count = len(exc.issues)
    print(f"{count} error{'s' if count != 1 else ''}; nothing was started.", file=out)


def print_config(config: Config, out: TextIO) -> None:
    for mapping in config.machines:
        print_tree(mapping, out)
    print(f"OK: {len(config.machines)} machine(s), {sum(len(m.variables) for m in config.machines)} variables", file=out)


def print_tree(mapping: MachineMapping, out: TextIO) -> None:
    """Folders in the order the file introduces them, variables with type, unit and access in columns."""
    driver = mapping.driver
    print(f"{mapping.machine}  [{driver.type} {driver.endpoint}]  {len(mapping.variables)} variables", file=out)
    root: dict[str, Any] = {}
    for var in mapping.variables:
        folder = root
        *parents, leaf = var.path.split("/")
        for segment in parents:
            folder = folder.setdefault(segment, {})
        folder[leaf] = var
    rows: list[tuple[str, str]] = []
    _rows(root, 1, rows)
    width = max(len(name) for name, _ in rows) + 2
    for name, columns in rows:
        print(f"{name:<{width}}{columns}".rstrip(), file=out)


def _rows(folder: dict[str, Any], depth: int, rows: list[tuple[str, str]]) -> None:
    for name, entry in folder.items():
        indent = "  " * depth
        if isinstance(entry, dict):
            rows.append((f"{indent}{name}/", ""))
            _rows(entry, depth + 1, rows)
            continue
        var: VariableSpec = entry
        extras = []
        if var.range is not None:
            extras.append(f"range {var.range.min:g}..{var.range.max:g}")
        if var.scale is not None:
            extras.append(f"scale x{var.scale.gain:g}{var.scale.offset:+g}")
        if var.deadband is not None:
            extras.append(f"deadband {var.deadband}")
        rows.append((f"{indent}{name}", f"{str(var.type):<10}{var.unit or '-':<8}{var.access:<10}{', '.join(extras)}"))
