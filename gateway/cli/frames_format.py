"""What the `frames` tools share: the layout and id table to use, hex input, and readable output.

The layout (id and length widths, text encoding, size limit) and the id table
come from a mapping file's target when one is given (`--mapping`, `--target`),
and the command line refines them (`--widths 1,4`, `--encoding gbk`,
`--types 12=String,13=Double[]`). Without a table, items are still taken
apart and shown as hex: the framing does not depend on the types.
"""

from __future__ import annotations

import argparse
import json
import re
import string
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from gateway.cli.check import report_config_error
from gateway.codecs.copydata import (
    CopydataError,
    Frame,
    Layout,
    Variable,
    VariableTable,
)
from gateway.config.loader import load_mapping
from gateway.config.mapping import MachineMapping
from gateway.errors import ConfigError, GatewayError
from gateway.model.types import TypeSpec
from gateway.sinks.copydata.config import CopydataTarget, check_encoding
from gateway.sinks.copydata.feedback import plain

DWDATA_NAMES = {1: "one variable", 2: "several variables"}
_HEX_JUNK = re.compile(r"0x|[\s:,\-_]", re.IGNORECASE)


class UsageError(GatewayError):
    """Bad command-line input: printed as `error: …`, exit status 2."""


@dataclass
class Settings:
    layout: Layout
    table: dict[int, Variable] = field(default_factory=dict)
    target: CopydataTarget | None = None
    mapping: MachineMapping | None = None

    def variable(self, vid: int) -> Variable | None:
        return self.table.get(vid)

    def by_name(self, name: str) -> Variable | None:
        for var in self.table.values():
            if var.name == name:
                return var
        return None

    def variable_table(self) -> VariableTable:
        return VariableTable(self.table.values())


def add_layout_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mapping", type=Path, default=None, help="take ids, types and the layout from this mapping file"
    )
    p.add_argument(
        "--target", default=None, help="which of the mapping's copydata targets (default: the first)"
    )
    p.add_argument(
        "--widths", default=None, metavar="ID,LEN", help="id and length field widths in bytes (default 2,2)"
    )
    p.add_argument("--encoding", default=None, help="text encoding of String values (default utf-8)")
    p.add_argument("--max-cbdata", type=int, default=None, help="largest lpData accepted (default 1048576)")
    p.add_argument(
        "--types",
        action="append",
        default=[],
        metavar="ID=TYPE[:NAME],…",
        help="ids and types without a mapping, e.g. 1=Double:Axes/X/Position,5=UInt32",
    )


def settings_from(args: argparse.Namespace) -> Settings:
    """The layout and table the options describe. Raises UsageError or ConfigError."""
    id_width, len_width, encoding, max_cbdata = 2, 2, "utf-8", 1 << 20
    table: dict[int, Variable] = {}
    target: CopydataTarget | None = None
    mapping: MachineMapping | None = None
    if args.mapping is not None:
        mapping = load_mapping(args.mapping)
        target = pick_target(mapping, args.target)
        if target is not None:
            id_width, len_width, encoding, max_cbdata = (
                target.id_width,
                target.len_width,
                target.encoding,
                target.max_cbdata,
            )
        for vid, name, spec in mapping_variables(mapping, target):
            table[vid] = Variable(vid, name, spec)
    elif args.target is not None:
        raise UsageError("--target needs --mapping")
    if args.widths is not None:
        id_width, len_width = parse_widths(args.widths)
    if args.encoding is not None:
        try:
            encoding = check_encoding(args.encoding)
        except ValueError as exc:
            raise UsageError(f"--encoding: {exc}") from None
    if args.max_cbdata is not None:
        max_cbdata = args.max_cbdata
    for text in args.types:
        for vid, var in parse_types(text).items():
            table[vid] = var
    try:
        layout = Layout(id_width, len_width, encoding, max_cbdata)
    except (ValueError, TypeError) as exc:
        raise UsageError(str(exc)) from None
    return Settings(layout, table, target, mapping)


def pick_target(mapping: MachineMapping, name: str | None) -> CopydataTarget | None:
    targets = mapping.copydata.targets if mapping.copydata is not None else []
    if name is None:
        return targets[0] if targets else None
    for target in targets:
        if target.name == name:
            return target
    known = ", ".join(t.name for t in targets) or "none"
    raise UsageError(f"the mapping has no copydata target {name!r} (targets: {known})")


def mapping_variables(
    mapping: MachineMapping, target: CopydataTarget | None
) -> list[tuple[int, str, TypeSpec]]:
    """(id, path, type) of what the target sends (or of every variable with an id)."""
    out: list[tuple[int, str, TypeSpec]] = []
    if target is not None and target.connected_id is not None:
        out.append((target.connected_id, "Status/Connected", TypeSpec.parse("Boolean")))
    wanted = None if target is None or target.variables is None else set(target.variables)
    for spec in mapping.variables:
        if spec.copydata is not None and (wanted is None or spec.path in wanted):
            out.append((spec.copydata.id, spec.path, spec.type))
    return out


def parse_widths(text: str) -> tuple[int, int]:
    parts = text.replace(" ", "").split(",")
    if len(parts) != 2 or not all(p in ("1", "2", "4") for p in parts):
        raise UsageError(f"--widths {text!r}: expected two of 1, 2, 4 such as 2,2 or 1,4")
    return int(parts[0]), int(parts[1])


def parse_types(text: str) -> dict[int, Variable]:
    out: dict[int, Variable] = {}
    for entry in filter(None, (e.strip() for e in text.split(","))):
        key, sep, rest = entry.partition("=")
        if not sep or not key.strip().isdigit():
            raise UsageError(
                f"--types {entry!r}: expected ID=TYPE or ID=TYPE:NAME, e.g. 1=Double:Axes/X/Position"
            )
        type_name, _, name = rest.partition(":")
        vid = int(key)
        try:
            out[vid] = Variable(vid, name or f"id {vid}", TypeSpec.parse(type_name))
        except ValueError as exc:
            raise UsageError(f"--types {entry!r}: {exc}") from None
    return out


def parse_address(text: str, option: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = default_host, text
    host = host.strip("[]") or default_host
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"{option} {text!r}: expected HOST:PORT, e.g. 127.0.0.1:5020")
    return host, int(port)


# --- input ----------------------------------------------------------------------------------------


def read_input(arg: str) -> bytes:
    """Bytes from hex text, a file (binary, or hex text) or `-` (stdin)."""
    if arg == "-":
        return bytes_or_hex(sys.stdin.buffer.read())
    path = Path(arg)
    if path.is_file():
        return bytes_or_hex(path.read_bytes())
    return parse_hex(arg)


def bytes_or_hex(data: bytes) -> bytes:
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return data
    if text and all(c.isprintable() or c.isspace() for c in text):
        return parse_hex(text)
    return data


def parse_hex(text: str) -> bytes:
    """Hex digits with any spacing; also the `offset | bytes | field` tables of docs/copydata.md."""
    lines = text.splitlines()
    if any("|" in line for line in lines):  # a table: only its rows with an offset hold bytes
        lines = [
            cells[1]
            for cells in (line.split("|") for line in lines)
            if len(cells) > 1 and cells[0].strip().isdigit()
        ]
    digits = _HEX_JUNK.sub("", "".join(lines))
    if not digits:
        raise UsageError("no bytes given")
    if len(digits) % 2:
        raise UsageError(f"odd number of hex digits ({len(digits)})")
    try:
        return bytes.fromhex(digits)
    except ValueError:
        bad = next((c for c in digits if c not in string.hexdigits), "?")
        raise UsageError(f"not hex: {bad!r} (give hex digits, a file, or - for stdin)") from None


# --- output ---------------------------------------------------------------------------------------


def show_value(value: Any) -> str:
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    if isinstance(value, float):
        return repr(value)
    return json.dumps(value, ensure_ascii=False)


def decode_item(settings: Settings, vid: int, data: bytes) -> tuple[Variable | None, Any, str | None]:
    """(variable, value, error); an unknown id is not an error here, just untyped."""
    var = settings.variable(vid)
    if var is None:
        return None, None, None
    try:
        return var, var.decode(data, settings.layout), None
    except CopydataError as exc:
        return var, None, str(exc)


def frame_line(settings: Settings, frame: Frame, stamp: str) -> str:
    """One line per frame for `listen`: `12:00:01.250 dwData=2 Axes/X/Position=12.5 …`."""
    parts = [stamp, f"dwData={frame.dwdata}"]
    for item in frame.items:
        var, value, error = decode_item(settings, item.id, item.data)
        if var is None:
            parts.append(f"id{item.id}=0x{item.data.hex() or '-'}")
        elif error is not None:
            parts.append(f"{var.name}=<{error}>")
        else:
            parts.append(f"{var.name}={show_value(value)}")
    return "  ".join(parts)


def frame_json(settings: Settings, frame: Frame, stamp: str) -> str:
    items = []
    for item in frame.items:
        var, value, error = decode_item(settings, item.id, item.data)
        entry: dict[str, Any] = {"id": item.id}
        if var is not None:
            entry["path"] = var.name
        if var is None or error is not None:
            entry["hex"] = item.data.hex()
            if error is not None:
                entry["error"] = error
        else:
            entry["value"] = plain(value)
        items.append(entry)
    return json.dumps({"ts": stamp, "dwdata": frame.dwdata, "items": items}, ensure_ascii=False)


def describe_items(settings: Settings, frame: Frame, base: int) -> list[str]:
    """The annotated items of one frame for `decode`; `base` is the byte offset of lpData."""
    lines = []
    offset = base
    header = settings.layout.header.size
    for index, item in enumerate(frame.items, start=1):
        var, value, error = decode_item(settings, item.id, item.data)
        what = f"id {item.id}" + (f" ({var.name}, {var.type})" if var is not None else "")
        shown = (
            f"<{error}> {item.data.hex(' ')}" if error is not None
            else show_value(value) if var is not None
            else item.data.hex(" ") or "(empty)"
        )  # fmt: skip
        lines.append(f"  item {index} at byte {offset}: {what}, N = {len(item.data)}: {shown}")
        offset += header + len(item.data)
    return lines


def frame_header(dwdata: int, cbdata: int, at: int | None) -> str:
    where = f"frame at byte {at}: " if at is not None else ""
    return f"{where}dwData = {dwdata} ({DWDATA_NAMES.get(dwdata, 'unknown')}), cbData = {cbdata}"


def fail(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2


def config_failed(exc: ConfigError) -> int:
    report_config_error(exc)
    return 2
