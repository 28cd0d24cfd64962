"""The OPC UA server sink: `Objects/Machines/<machine>/...` for SCADA clients (server.py), and the parts
built on it through port.py (extensions.py: alarm conditions, views)."""

from __future__ import annotations

from typing import Any

import gateway.sinks.opcua.extensions as extensions
from gateway.settings.sections import Section
from gateway.sinks.base import Sink, SinkContext, SinkSpec
from gateway.sinks.opcua.config import OpcUaServerConfig


def redundant_set(servers: list[str]) -> Any:
    """With `shard: lease`: the servers `opcua.redundant_servers` lists; else under `cnc-gateway fleet`
    (CNC_SHARD = K/N) the N shards' servers of this host; a shard started by hand lists only itself."""
    from gateway.shards.identity import fleet_size, shard_index
    from gateway.sinks.opcua.redundancy import RedundantSet, application_uri

    if servers:
        return RedundantSet(tuple(servers))
    shards = fleet_size()
    return RedundantSet.of_fleet(shards) if shards else RedundantSet((application_uri(shard_index()),))


def _create(context: SinkContext) -> Sink:
    from gateway.sinks.opcua.security import TrustList
    from gateway.sinks.opcua.server import OpcUaSink

    gateway = context.config.gateway
    config = context.section(SECTION)
    assert isinstance(config, OpcUaServerConfig)  # the gateway file's opcua: always has its defaults
    machines: dict[str, dict[str, Any]] = {}
    for spec in extensions.EXTENSIONS:
        key = spec.machine_section
        machines[spec.name] = (
            {name: m.section(key) for name, m in context.mappings.items() if m.section(key) is not None}
            if key is not None
            else {}
        )
    built = [
        spec.create(
            extensions.ExtensionContext(
                tree=context.tree,
                machines=machines[spec.name],
                server=config.section(spec.server_section) if spec.server_section is not None else None,
                state_dir=context.state_dir,
                alarms=context.alarms,
            )
        )
        for spec in extensions.EXTENSIONS
    ]
    sink = OpcUaSink(
        context.tree,
        config,
        context.state_dir,
        users=gateway.user_directory(context.logins),
        extensions=[e for e in built if e is not None],
        redundant=redundant_set(config.redundant_servers) if gateway.leased else None,
    )
    context.offered.trust = TrustList(sink.pki)  # the console's Certificates page manages its folders
    return sink


SECTION = Section("opcua", OpcUaServerConfig)
SPEC = SinkSpec(
    name="opcua",
    summary="the OPC UA server SCADA clients browse: every machine's tree, writes, methods (asyncua)",
    create=_create,
    section=SECTION,
    machine_sections=extensions.machine_sections(),
)
