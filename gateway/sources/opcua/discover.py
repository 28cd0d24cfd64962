"""`discover`: browse a controller and write a starting mapping file for what it finds.

Mapping tags one by one is the chore users of other gateways complain about most.
This walks the controller's address space from Objects (or a given node), keeps
the variables whose types the gateway understands, and writes them as a mapping
file the user prunes and renames. Browse names become tree paths: sanitised to
the mapping rules, made unique (case-insensitively, because MQTT topics are
lower-case), and never both a folder and a variable. A B&R structure is a
variable with component children; its members become the mapped variables.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import yaml
from asyncua import Client, ua
from asyncua.ua.uaerrors import UaError

from gateway.codecs.opcua_nodeid import parse_address
from gateway.errors import AddressError, SourceError
from gateway.settings.names import MACHINE_RE
from gateway.settings.urls import check_endpoint
from gateway.shims.ua import new_node_id
from gateway.sources.browse_paths import Key, assign_paths
from gateway.sources.opcua.client import close_client, open_client
from gateway.sources.opcua.status import describe_error

BROWSE_BATCH = 100  # nodes per Browse request
READ_BATCH = 1000  # attributes per Read request
MAX_SKIP_COMMENTS = 200

_HIERARCHICAL = new_node_id(ua.ObjectIds.HierarchicalReferences)
_HAS_PROPERTY = new_node_id(ua.ObjectIds.HasProperty)
_HAS_SUBTYPE = new_node_id(ua.ObjectIds.HasSubtype)
_BASE_TYPES = {
    1: "Boolean", 2: "SByte", 3: "Byte", 4: "Int16", 5: "UInt16", 6: "Int32", 7: "UInt32",
    8: "Int64", 9: "UInt64", 10: "Float", 11: "Double", 12: "String", 13: "DateTime",
    29: "Int32",  # Enumeration: enumerated values travel as Int32
}  # fmt: skip
_UNSUPPORTED_TYPES = {
    14: "Guid", 15: "ByteString", 16: "XmlElement", 17: "NodeId", 18: "ExpandedNodeId", 19: "StatusCode",
    20: "QualifiedName", 21: "LocalizedText", 22: "Structure", 23: "DataValue", 24: "BaseDataType",
    25: "DiagnosticInfo", 26: "Number", 27: "Integer", 28: "UInteger",
}  # fmt: skip
_CURRENT_READ = 0x01  # AccessLevel bits
_CURRENT_WRITE = 0x02
_ALL_RESULTS = 0x3F  # BrowseResultMask: every field of each reference
_NUMERIC = {"SByte", "Byte", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Float", "Double"}
_ATTRIBUTES = (
    ua.AttributeIds.DataType,
    ua.AttributeIds.ValueRank,
    ua.AttributeIds.AccessLevel,
    ua.AttributeIds.UserAccessLevel,
    ua.AttributeIds.Description,
)


def _type_entry(base: str, value_rank: int) -> str | None:
    if value_rank in (-1, -2, -3):
        return base
    if value_rank in (0, 1):
        return base + "[]"
    return None


# --- browsing ---------------------------------------------------------------------------------


@dataclass
class _Item:
    node_id: ua.NodeId
    keys: tuple[Key, ...]
    order: tuple[int, ...]
    depth: int
    is_variable: bool = False
    children_wanted: bool = True
    found: Found | None = None


@dataclass
class Found:
    """A variable worth mapping (type set) or one skipped (skip set)."""

    keys: tuple[Key, ...]
    order: tuple[int, ...]
    source: str
    type: str | None = None
    writable: bool = False
    description: str = ""
    unit: str = ""
    range: tuple[float, float] | None = None
    skip: str = ""


class _Browser:
    def __init__(self, client: Client, *, max_depth: int, max_variables: int) -> None:
        self.session = client.uaclient.session
        self.max_depth = max_depth
        self.max_variables = max_variables
        self.found: list[Found] = []
        self.notes: list[str] = []
        self._types: dict[str, tuple[str | None, str]] = {}
        self._properties: list[tuple[Found, str, ua.NodeId]] = []

    async def walk(self, start: ua.NodeId) -> None:
        visited = {start.to_string()}
        frontier = [_Item(start, (), (), 0)]
        emitted = 0
        depth_cut = truncated = False
        strict = True  # the start node must be browsable; later nodes may fail one by one
        while frontier:
            results = await self._browse([item.node_id for item in frontier], strict=strict)
            strict = False
            objects: list[_Item] = []
            variables: list[_Item] = []
            for item, refs in zip(frontier, results, strict=True):
                for position, ref in enumerate(refs):
                    target = ref.NodeId
                    if getattr(target, "ServerIndex", 0):
                        continue
                    if ref.ReferenceTypeId == _HAS_PROPERTY:
                        owner = item.found
                        if owner is not None and ref.BrowseName.Name in ("EngineeringUnits", "EURange"):
                            self._properties.append((owner, ref.BrowseName.Name, _plain(target)))
                        continue
                    if not item.children_wanted or target.NamespaceIndex == 0:
                        continue
                    if emitted >= self.max_variables:
                        truncated = True  # full: from here on only the properties of what we have
                        continue
                    key = target.to_string()
                    if key in visited:
                        continue
                    visited.add(key)
                    child = _Item(
                        _plain(target),
                        (*item.keys, (key, ref.BrowseName.Name or key)),
                        (*item.order, position),
                        item.depth + 1,
                        is_variable=ref.NodeClass == ua.NodeClass.Variable,
                    )
                    if child.is_variable:
                        variables.append(child)
                    elif ref.NodeClass == ua.NodeClass.Object:
                        if child.depth < self.max_depth:
                            objects.append(child)
                        else:
                            depth_cut = True
            frontier = objects
            for item, found in zip(variables, await self._describe(variables), strict=True):
                if found.type is not None:
                    if emitted >= self.max_variables:
                        truncated = True
                        continue
                    emitted += 1
                self.found.append(found)
                item.found = found
                item.children_wanted = item.depth < self.max_depth and (
                    found.type is None or not found.type.endswith("[]")
                )
                if found.type is None and item.depth >= self.max_depth:
                    depth_cut = True
                frontier.append(item)
        if truncated:
            self.notes.append(f"stopped after {self.max_variables} variables (max_variables)")
        if depth_cut:
            self.notes.append(
                f"some branches go deeper than {self.max_depth} levels and were not browsed (max_depth)"
            )
        await self._read_properties()

    async def _browse(
        self, node_ids: list[ua.NodeId], *, strict: bool
    ) -> list[list[ua.ReferenceDescription]]:
        out: list[list[ua.ReferenceDescription]] = []
        for start in range(0, len(node_ids), BROWSE_BATCH):
            batch = node_ids[start : start + BROWSE_BATCH]
            params = ua.BrowseParameters(
                RequestedMaxReferencesPerNode=0,
                NodesToBrowse=[
                    ua.BrowseDescription(
                        NodeId=nid,
                        BrowseDirection=ua.BrowseDirection.Forward,
                        ReferenceTypeId=_HIERARCHICAL,
                        IncludeSubtypes=True,
                        NodeClassMask=ua.NodeClass.Object | ua.NodeClass.Variable,
                        ResultMask=_ALL_RESULTS,
                    )
                    for nid in batch
                ],
            )
            for nid, result in zip(batch, await self.session.browse(params), strict=True):
                if result.StatusCode.is_bad():
                    if strict:
                        raise SourceError(f"cannot browse {nid.to_string()}: {result.StatusCode.name}")
                    out.append([])
                    continue
                refs = list(result.References or [])
                point = result.ContinuationPoint
                while point:
                    more = await self.session.browse_next(
                        ua.BrowseNextParameters(ReleaseContinuationPoints=False, ContinuationPoints=[point])
                    )
                    refs.extend(more[0].References or [])
                    point = more[0].ContinuationPoint
                out.append(refs)
        return out

    async def _read(self, requests: list[tuple[ua.NodeId, int]]) -> list[ua.DataValue]:
        values: list[ua.DataValue] = []
        for start in range(0, len(requests), READ_BATCH):
            params = ua.ReadParameters(
                TimestampsToReturn=ua.TimestampsToReturn.Neither,
                NodesToRead=[
                    ua.ReadValueId(NodeId=n, AttributeId=a) for n, a in requests[start : start + READ_BATCH]
                ],
            )
            values.extend(await self.session.read(params))
        return values

    async def _describe(self, items: list[_Item]) -> list[Found]:
        """Type, access and description of each variable, from one batch of Read requests."""
        values = await self._read([(item.node_id, attr) for item in items for attr in _ATTRIBUTES])
        out = []
        for i, item in enumerate(items):
            data_type, rank, access, user_access, description = (
                _value(dv) for dv in values[i * 5 : i * 5 + 5]
            )
            found = Found(item.keys, item.order, item.node_id.to_string())
            out.append(found)
            if isinstance(access, int) and not access & _CURRENT_READ:
                found.skip = "not readable"
                continue
            base, label = (
                await self._type_name(data_type) if isinstance(data_type, ua.NodeId) else (None, "unknown")
            )
            if base is None:
                found.skip = f"unsupported data type {label}"
                continue
            found.type = _type_entry(base, rank if isinstance(rank, int) else -1)
            if found.type is None:
                found.skip = f"{rank}-dimensional array of {base}"
                continue
            found.writable = (
                isinstance(access, int)
                and bool(access & _CURRENT_WRITE)
                and (not isinstance(user_access, int) or bool(user_access & _CURRENT_WRITE))
            )
            if isinstance(description, ua.LocalizedText) and description.Text:
                text = " ".join(description.Text.split())
                if text != item.keys[-1][1]:  # many servers just repeat the browse name
                    found.description = text
        return out

    async def _type_name(self, data_type: ua.NodeId) -> tuple[str | None, str]:
        """(our type name or None, a label for comments), following HasSubtype up to a built-in type."""
        key = data_type.to_string()
        if key in self._types:
            return self._types[key]
        result: tuple[str | None, str]
        ident = data_type.Identifier if data_type.NamespaceIndex == 0 else None  # built-in types: numeric ids
        if isinstance(ident, int) and ident in _BASE_TYPES:
            result = (_BASE_TYPES[ident], _BASE_TYPES[ident])
        elif isinstance(ident, int) and ident in _UNSUPPORTED_TYPES:
            result = (None, _UNSUPPORTED_TYPES[ident])
        else:
            self._types[key] = (None, key)  # guards against cycles while we look upwards
            params = ua.BrowseParameters(
                NodesToBrowse=[
                    ua.BrowseDescription(
                        NodeId=data_type,
                        BrowseDirection=ua.BrowseDirection.Inverse,
                        ReferenceTypeId=_HAS_SUBTYPE,
                        IncludeSubtypes=False,
                        ResultMask=_ALL_RESULTS,
                    )
                ]
            )
            (browsed,) = await self.session.browse(params)
            parents = list(browsed.References or []) if browsed.StatusCode.is_good() else []
            if parents:
                base, label = await self._type_name(_plain(parents[0].NodeId))
                result = (base, label if base is not None else f"{key} (a {label})")
            else:
                result = (None, key)
        self._types[key] = result
        return result

    async def _read_properties(self) -> None:
        if not self._properties:
            return
        values = await self._read([(nid, ua.AttributeIds.Value) for _, _, nid in self._properties])
        for (found, name, _), dv in zip(self._properties, values, strict=True):
            value = _value(dv)
            if found.type is None:
                continue
            if name == "EngineeringUnits" and isinstance(value, ua.EUInformation):
                found.unit = (value.DisplayName.Text or value.Description.Text or "").strip()
            elif name == "EURange" and isinstance(value, ua.Range) and found.type.rstrip("[]") in _NUMERIC:
                low, high = float(value.Low), float(value.High)
                if math.isfinite(low) and math.isfinite(high) and low < high:
                    found.range = (low, high)


def _plain(node_id: ua.NodeId) -> ua.NodeId:
    return ua.NodeId(node_id.Identifier, node_id.NamespaceIndex, node_id.NodeIdType)


def _value(dv: ua.DataValue) -> Any:
    if dv.StatusCode is not None and dv.StatusCode.is_bad():
        return None
    return None if dv.Value is None else dv.Value.Value


# --- the entry point --------------------------------------------------------------------------


async def discover(
    endpoint: str,
    *,
    machine: str,
    username: str | None = None,
    password: str | None = None,
    security: str = "None",
    start: str | None = None,
    max_depth: int = 12,
    max_variables: int = 5000,
    timeout: float = 5.0,
) -> str:
    """Browse a controller and return the text of a starting mapping file (YAML).

    Raises ValueError for a bad machine name or endpoint, SourceError when the
    controller cannot be reached or browsed (the message says why).
    """
    if not MACHINE_RE.match(machine):
        raise ValueError(f"machine name {machine!r} must be 1-63 lower-case letters, digits, '-' or '_'")
    check_endpoint(endpoint)
    try:
        client = await open_client(
            endpoint, timeout=timeout, username=username, password=password, security=security
        )
    except Exception as exc:  # noqa: BLE001 - asyncua's failures, translated by describe_error
        raise SourceError(f"cannot connect to {endpoint}: {describe_error(exc)[1]}") from None
    try:
        namespaces = list(await client.get_namespace_array())
        if start:
            try:
                address = parse_address(start)
                start_id = new_node_id(address.identifier, address.resolve(namespaces))
            except AddressError as exc:
                raise SourceError(f"start node: {exc}") from None
        else:
            start_id = new_node_id(ua.ObjectIds.ObjectsFolder)
        browser = _Browser(client, max_depth=max_depth, max_variables=max_variables)
        await browser.walk(start_id)
    except SourceError:
        raise
    except (UaError, OSError, TimeoutError) as exc:
        raise SourceError(f"browsing {endpoint} failed: {describe_error(exc)[1]}") from None
    finally:
        await close_client(client, polite=True)
    start_label = start or "Objects"
    mapped = sorted((f for f in browser.found if f.type is not None), key=lambda f: f.order)
    if not mapped:
        raise SourceError(
            f"found no variables of a supported type under {start_label} on {endpoint}; "
            "try --start or --max-depth"
        )
    emitted = {k for f in mapped for k in f.keys}
    skipped = sorted(
        (f for f in browser.found if f.type is None and f.keys[-1] not in emitted), key=lambda f: f.order
    )
    return render(
        endpoint,
        machine=machine,
        variables=mapped,
        skipped=skipped,
        namespaces=namespaces,
        start=start_label,
        notes=browser.notes,
        username=username,
        security=security,
        timeout=timeout,
    )


def _flow(value: Any) -> str:
    """One YAML value on one line, quoted only where YAML needs it."""
    if isinstance(value, dict):
        return yaml.safe_dump(
            value, default_flow_style=True, sort_keys=False, width=math.inf, allow_unicode=True
        ).strip()
    text = yaml.safe_dump([value], default_flow_style=True, width=math.inf, allow_unicode=True).strip()
    return text[1:-1]  # a scalar alone would come with a document end marker; inside [ ] it does not


def _comment(text: str) -> str:
    return " ".join(str(text).split())


def render(
    endpoint: str,
    *,
    machine: str,
    variables: list[Found],
    skipped: list[Found],
    namespaces: list[str],
    start: str,
    notes: list[str],
    username: str | None,
    security: str,
    timeout: float,
) -> str:
    """The mapping file's text: a commented header, the driver settings, one line per variable."""
    paths = assign_paths([f.keys for f in variables])
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# yaml-language-server: $schema=./mapping.schema.json",
        "#",
        f"# Generated by `cnc-gateway discover` on {when}",
        f"# from {_comment(endpoint)}, browsing from {_comment(start)}.",
        f"# Found {len(variables)} variables"
        + (f"; {len(skipped)} more could not be mapped (listed at the end)." if skipped else "."),
        *[f"# Note: {_comment(n)}." for n in notes],
        "#",
        "# This is a starting point, not a finished mapping: delete what you do not need,",
        "# give the paths names your team uses, and add units, ranges and deadbands.",
        "# Check it with `cnc-gateway check <this file>`.",
        "#",
        "# Namespaces on the controller. A source may also name its namespace by URI,",
        "# e.g. nsu=<uri>;s=…, which survives the controller renumbering its namespaces:",
        *[f"#   ns={i}  {_comment(uri)}" for i, uri in enumerate(namespaces)],
        "",
        f"machine: {_flow(machine)}",
        "",
        "driver:",
        "  type: opcua",
        f"  endpoint: {_flow(endpoint)}",
    ]
    if security and security.strip() != "None":
        lines.append(f"  security: {_flow(security)}")
    if username:
        env = re.sub(r"[^A-Z0-9]", "_", machine.upper()) + "_PASSWORD"
        lines.append(f"  username: {_flow(username)}")
        lines.append(f"  # password: ${{{env}}}   # uncomment, and set {env} in the environment")
    lines += [
        f"  timeout: {timeout:g}                  # s per request",
        "  publishing_interval: 100    # ms",
        "  watchdog_interval: 1.0      # s between liveness probes",
        "  reconnect: {initial: 0.5, max: 10, factor: 2}",
        "",
        "defaults:",
        "  sampling_interval: 100      # ms",
        "  queue_size: 1",
        "",
        "variables:",
    ]
    for path, found in zip(paths, variables, strict=True):
        entry: dict[str, Any] = {"path": path, "source": found.source, "type": found.type}
        if found.unit:
            entry["unit"] = found.unit
        if found.writable:
            entry["access"] = "readwrite"
        if found.range is not None:
            entry["range"] = {"min": found.range[0], "max": found.range[1]}
        if found.description:
            entry["description"] = found.description
        lines.append(f"  - {_flow(entry)}")
    if skipped:
        lines += ["", "# Not mapped:"]
        for found in skipped[:MAX_SKIP_COMMENTS]:
            where = "/".join(name for _, name in found.keys)
            lines.append(f"#   {_comment(where)}  ({_comment(found.source)}): {_comment(found.skip)}")
        if len(skipped) > MAX_SKIP_COMMENTS:
            lines.append(f"#   … and {len(skipped) - MAX_SKIP_COMMENTS} more")
    return "\n".join(lines) + "\n"
