"""`cnc-gateway check FILE...`: validate configuration and print each machine's tree.

Besides type, unit and access, a technician sees who may write what (once access
control is on: users configured in the gateway file), each command with its role
and the states it is allowed in, and each COPYDATA target with the ids it sends.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, TextIO

from gateway.commands.config import CommandSpec, Condition
from gateway.config.loader import Config, load
from gateway.config.mapping import MachineMapping, VariableSpec
from gateway.errors import ConfigError
from gateway.sinks.copydata.config import CopydataTarget
from gateway.sources.base import PlansPolls


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
    gw = config.gateway
    enabled = gw.access.is_enabled(gw.users)
    default_role = gw.access.default_write_role if enabled else None
    for mapping in config.machines:
        print_tree(mapping, out, default_role)
        if isinstance(mapping.driver, PlansPolls):  # a polled driver
            print(
                "\n".join(mapping.driver.describe_plan(mapping.variables, mapping.sampling_interval)),
                file=out,
            )
        print_commands(mapping, out)
        copydata_role = gw.access.copydata_role or "none: refused"  # never implied, users or not
        print_copydata(mapping, out, copydata_role if gw.access.checks_roles() else None)
        print_sections(mapping, out)
    print(
        f"OK: {len(config.machines)} machine(s), {sum(len(m.variables) for m in config.machines)} variables",
        file=out,
    )
    if enabled:
        print(f"access control on: {len(gw.users)} user(s), roles {' < '.join(gw.roles)}", file=out)
    elif not gw.access.checks_roles():
        print(
            "access control off (access.enabled: false): no role is checked; anonymous OPC UA clients may "
            "change what the mappings allow",
            file=out,
        )
    else:
        print(
            f"no users: OPC UA clients are anonymous, with role {gw.access.anonymous} (access.anonymous); "
            f"writes and commands the mappings open to MQTT act as {gw.roles[-1]}; COPYDATA writes as "
            f"{gw.access.copydata_role or 'nobody: refused'} (access.copydata_role)",
            file=out,
        )


def print_sections(mapping: MachineMapping, out: TextIO) -> None:
    """What the adapters' own keys of this mapping amount to (a Section's `report`: the umati view ...)."""
    for section in mapping.sections:
        value = mapping.section(section)
        if value is not None and section.report is not None:
            for line in section.report(value):
                print(f"  {line}", file=out)


def print_tree(mapping: MachineMapping, out: TextIO, default_role: str | None = None) -> None:
    """Folders in the order the file introduces them, variables with type, unit and access in columns.

    `default_role` (the gateway's access.default_write_role) is given while access control
    is on: each writable variable then shows the lowest role that may write it.
    """
    driver = mapping.driver
    print(
        f"{mapping.machine}  [{driver.type} {driver.endpoint}]  {len(mapping.variables)} variables", file=out
    )
    root: dict[str, Any] = {}
    for var in mapping.variables:
        folder = root
        *parents, leaf = var.path.split("/")
        for segment in parents:
            folder = folder.setdefault(segment, {})
        folder[leaf] = var
    rows: list[tuple[str, str]] = []
    write_role = (mapping.defaults.write_role or default_role) if default_role is not None else None
    _rows(root, 1, rows, write_role)
    width = max(len(name) for name, _ in rows) + 2
    for name, columns in rows:
        print(f"{name:<{width}}{columns}".rstrip(), file=out)


def _rows(folder: dict[str, Any], depth: int, rows: list[tuple[str, str]], write_role: str | None) -> None:
    for name, entry in folder.items():
        indent = "  " * depth
        if isinstance(entry, dict):
            rows.append((f"{indent}{name}/", ""))
            _rows(entry, depth + 1, rows, write_role)
            continue
        var: VariableSpec = entry
        extras = []
        if var.writable and write_role is not None:
            extras.append(f"role {var.role or write_role}")
        if var.range is not None:
            extras.append(f"range {var.range.min:g}..{var.range.max:g}")
        if var.scale is not None:
            extras.append(f"scale x{var.scale.gain:g}{var.scale.offset:+g}")
        if var.deadband is not None:
            extras.append(f"deadband {var.deadband}")
        if var.copydata is not None:
            extras.append(f"copydata {var.copydata.id}")
        rows.append(
            (f"{indent}{name}", f"{var.type!s:<10}{var.unit or '-':<8}{var.access:<11}{', '.join(extras)}")
        )


def print_commands(mapping: MachineMapping, out: TextIO) -> None:
    """One line per command: name(arguments), the lowest role that may run it, the states it is allowed in."""
    if not mapping.commands:
        return
    print("  commands (role, allowed when):", file=out)
    rows = [(_signature(name, spec), spec.role, _allowed(spec)) for name, spec in mapping.commands.items()]
    width = max(len(r[0]) for r in rows) + 2
    role_width = max(len(r[1]) for r in rows) + 2
    for signature, role, allowed in rows:
        print(f"    {signature:<{width}}{role:<{role_width}}{allowed}", file=out)


def _signature(name: str, spec: CommandSpec) -> str:
    args = ", ".join(f"{a.name}: {a.type}" for a in spec.arguments)
    return f"{name}({args})" if args else name


def _allowed(spec: CommandSpec) -> str:
    cond = spec.allowed
    if cond is None:
        return "any state"
    labels = [_label(cond, v) for v in cond.values]
    if cond.negated:
        return f"{cond.path} is " + (
            f"not {labels[0]}" if len(labels) == 1 else f"none of {', '.join(labels)}"
        )
    return f"{cond.path} is {' or '.join(labels)}"


def _label(cond: Condition, value: Any) -> str:
    """A value as the condition names it ("Idle"), else as written."""
    text = str(value).lower() if isinstance(value, bool) else str(value)
    return cond.names.get(text, text)


def print_copydata(mapping: MachineMapping, out: TextIO, writer: str | None = None) -> None:
    """One line per COPYDATA target: where it sends, the variable ids it gets (the tree shows their names).

    `writer` is the role writes from a target act with (the gateway file's access.copydata_role), while
    roles are checked.
    """
    if mapping.copydata is None:
        return
    ids = {v.path: v.copydata.id for v in mapping.variables if v.copydata is not None}
    print("  copydata targets (ids sent):", file=out)
    targets = mapping.copydata.targets
    width = max(len(t.name) for t in targets) + 2
    for target in targets:
        print(f"    {target.name:<{width}}{_target_line(target, ids, writer)}", file=out)


def _target_line(target: CopydataTarget, ids: dict[str, int], writer: str | None) -> str:
    paths = ids if target.variables is None else [p for p in target.variables if p in ids]
    sent = sorted(ids[p] for p in paths)
    parts = [target.describe(), target.mode, f"ids {id_ranges(sent)} ({len(sent)} variables)"]
    if target.connected_id is not None:
        parts.append(f"connected {target.connected_id}")
    if target.accept_writes:
        parts.append("accepts writes" + (f" (role {writer})" if writer else ""))
    return "  ".join(parts)


def id_ranges(ids: list[int]) -> str:
    """[1, 2, 3, 5, 7, 8] -> "1-3, 5, 7-8": sorted ids, runs joined."""
    runs: list[list[int]] = []
    for i in ids:
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs) or "none"
