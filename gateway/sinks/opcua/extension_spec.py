"""What an OPC UA server extension is: the spec its folder exports and the context its factory gets.

Apart from gateway/sinks/opcua/extensions.py (the table of extensions) so that an extension's folder can
declare its spec in its `__init__.py` and the table import it, without a cycle.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.model.tree import VariableTree
from gateway.settings.sections import Section

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
