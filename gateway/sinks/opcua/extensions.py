"""The parts built on the OPC UA server (alarm conditions, views such as umati): one line each.

An extension is a folder `gateway/sinks/opcua/<name>/` whose `__init__.py` exports an `ExtensionSpec`;
it knows the server only through port.py (`ServerPort`), and the server knows it only as a
`ServerExtension` it installs once the tree's nodes exist, before clients connect. Its keys (per
machine in mapping files, under the gateway file's `opcua:`) are `Section`s, which the files' models
append (gateway/settings/sections.py). Packages of their own add extensions through the entry point
group `cnc_gateway.opcua_extensions`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gateway.plugins import installed
from gateway.settings.sections import Section
from gateway.sinks.opcua.extension_spec import ExtensionContext, ExtensionSpec
from gateway.sinks.opcua.umati import SPEC as UMATI

if TYPE_CHECKING:
    from gateway.sinks.opcua.port import ServerExtension

__all__ = ["ALARMS", "EXTENSIONS", "UMATI", "ExtensionContext", "ExtensionSpec"]


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


BUILT_IN: tuple[ExtensionSpec, ...] = (ALARMS, UMATI)

GROUP = "cnc_gateway.opcua_extensions"
EXTENSIONS: tuple[ExtensionSpec, ...] = BUILT_IN + installed(GROUP, ExtensionSpec, BUILT_IN, lambda s: s.name)


def machine_sections() -> tuple[Section, ...]:
    return tuple(s.machine_section for s in EXTENSIONS if s.machine_section is not None)


def server_sections() -> tuple[Section, ...]:
    return tuple(s.server_section for s in EXTENSIONS if s.server_section is not None)
