"""The umati view: every machine with a `umati:` section also served as an OPC 40501-1 MachineTool.

config.py is the section's model (loaded with the mapping files, without asyncua's server); install.py
is the ServerExtension, model.py and instance.py read the official types (nodesets/, vendored with their
licence, see nodesets/SOURCES.md) and plan each instance. Its spec is below; gateway/sinks/opcua/extensions.py
lists it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gateway.settings.sections import Section
from gateway.sinks.opcua.extension_spec import ExtensionContext, ExtensionSpec
from gateway.sinks.opcua.umati.config import UmatiView, check, report

if TYPE_CHECKING:
    from gateway.sinks.opcua.port import ServerExtension


def _umati(context: ExtensionContext) -> ServerExtension | None:
    if not context.machines:
        return None
    from gateway.sinks.opcua.umati.install import UmatiExtension

    return UmatiExtension(context.machines, context.tree, context.alarms)


SPEC = ExtensionSpec(
    name="umati",
    summary="the umati view: each machine with a `umati:` section as an OPC 40501-1 MachineTool under "
    "the Machinery Machines folder (identification, monitoring, production, notifications)",
    create=_umati,
    machine_section=Section(
        "umati",
        UmatiView,
        "The machine as an OPC 40501-1 MachineTool (umati) under the Machinery Machines folder",
        check=check,
        report=report,
    ),
)
