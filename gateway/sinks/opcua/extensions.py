"""The parts built on the OPC UA server (alarm conditions, views such as umati): one line each.

An extension is a folder `gateway/sinks/opcua/<name>/` whose `__init__.py` exports an `ExtensionSpec`;
it knows the server only through port.py (`ServerPort`), and the server knows it only as a
`ServerExtension` it installs once the tree's nodes exist, before clients connect. Its keys (per
machine in mapping files, under the gateway file's `opcua:`) are `Section`s, which the files' models
append (gateway/settings/sections.py). Packages of their own add extensions through the entry point
group `cnc_gateway.opcua_extensions`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.model.tree import VariableTree
from gateway.plugins import installed
from gateway.settings.sections import Section
from gateway.sinks.opcua.umati.config import UmatiView
from gateway.sinks.opcua.umati.config import check as umati_check
from gateway.sinks.opcua.umati.config import report as umati_report

if TYPE_CHECKING:  # port.py imports asyncua, the alarm service SQLite: loading a configuration does not
    from gateway.alarms.service import AlarmService
    from gateway.sinks.opcua.port import ServerExtension


@dataclass(frozen=True)
class ExtensionContext:
    """What an extension's factory gets."""

    tree: VariableTree  # machines, nodes, and tree.events (alarms/active, jobs/<id> records)
    machines: Mapping[str, Any]  # machine -> the value of its `machine_section` (only machines with one)
    server: Any  # the value of its `server_section` under the gateway file's `opcua:` (None: absent)
    state_dir: Path
    alarms: AlarmService | None  # the alarm managers, when some machine has alarms:


@dataclass(frozen=True)
class ExtensionSpec:
    name: str
    summary: str  # one line, for the adapters table of docs/architecture.md
    # The part to install, or None when the configuration does not ask for it.
    create: Callable[[ExtensionContext], ServerExtension | None]
    machine_section: Section | None = None  # a key per machine in mapping files (umati:)
    server_section: Section | None = None  # a key under the gateway file's `opcua:`


def _alarms(context: ExtensionContext) -> ServerExtension | None:
    if context.alarms is None:
        return None
    from gateway.sinks.opcua.alarms import OpcUaAlarms

    return OpcUaAlarms(context.alarms)


ALARMS = ExtensionSpec(
    name="alarms",
    summary="the machines' alarms as OPC UA Alarms & Conditions (events, Acknowledge, ConditionRefresh)",
    create=_alarms,
)


def _umati(context: ExtensionContext) -> ServerExtension | None:
    if not context.machines:
        return None
    from gateway.sinks.opcua.umati.install import UmatiExtension

    return UmatiExtension(context.machines, context.tree, context.alarms)


UMATI = ExtensionSpec(
    name="umati",
    summary="the umati view: each machine with a `umati:` section as an OPC 40501-1 MachineTool under "
    "the Machinery Machines folder (identification, monitoring, production, notifications)",
    create=_umati,
    machine_section=Section(
        "umati",
        UmatiView,
        "The machine as an OPC 40501-1 MachineTool (umati) under the Machinery Machines folder",
        check=umati_check,
        report=umati_report,
    ),
)

BUILT_IN: tuple[ExtensionSpec, ...] = (ALARMS, UMATI)

GROUP = "cnc_gateway.opcua_extensions"
EXTENSIONS: tuple[ExtensionSpec, ...] = BUILT_IN + installed(GROUP, ExtensionSpec, BUILT_IN, lambda s: s.name)


def machine_sections() -> tuple[Section, ...]:
    return tuple(s.machine_section for s in EXTENSIONS if s.machine_section is not None)


def server_sections() -> tuple[Section, ...]:
    return tuple(s.server_section for s in EXTENSIONS if s.server_section is not None)
