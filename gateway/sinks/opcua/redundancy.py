"""The shards of a lease-served fleet as a non-transparent redundant server set (OPC UA Part 4, 6.6.2).

Every shard's server shows every machine; a machine is Good on the one shard that holds its lease and
Bad (BadOutOfService) on the others. A client with redundant connections (Ignition's, UaExpert's) keeps a
session to each server of `ServerUriArray` and reads where the service level is highest:
`Server.ServiceLevel` for the server as a whole, `Machines/<machine>/Status/ServiceLevel` for one machine
(255 on the shard that serves it, 1 elsewhere). `RedundancySupport` says Warm: a standby server is up and
browsable but has no data of a machine until it takes the machine's lease over.

The server's level (Part 4's ranges: 200-255 healthy) is 200 plus 55 times the share of the fleet's
machines this shard serves: a shard that serves nothing is a healthy standby (200), the one that serves
everything is 255.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from dataclasses import dataclass
from typing import Any

from asyncua import ua

from gateway.model.tree import VariableTree
from gateway.shims.ua import new_node_id

log = logging.getLogger("gateway.opcua")

HEALTHY = 200
LEVEL_EVERY = 0.5  # s: how often the server's ServiceLevel follows the machines served


def application_uri(shard: int | None, host: str | None = None) -> str:
    """`urn:<host>:cnc-gateway`, and `:shard-K` for shard K of a fleet (each server of a set its own URI)."""
    base = f"urn:{host or socket.gethostname()}:cnc-gateway"
    return base if shard is None else f"{base}:shard-{shard}"


@dataclass(frozen=True)
class RedundantSet:
    """This server among its fleet's: the application URIs of the set (this one's included)."""

    uris: tuple[str, ...]

    @classmethod
    def of_fleet(cls, shards: int, host: str | None = None) -> RedundantSet:
        """The N shards of `cnc-gateway fleet` on one host (CNC_SHARD = K/N)."""
        return cls(tuple(application_uri(k, host) for k in range(1, shards + 1)))


def service_level(tree: VariableTree) -> int:
    total = len(tree.machines)
    if not total:
        return HEALTHY
    served = total - len(tree.standby & tree.machines.keys())
    return HEALTHY + (255 - HEALTHY) * served // total


async def install(server: Any, redundant: RedundantSet) -> None:
    """Server.ServerRedundancy as a NonTransparentRedundancyType with the set's ServerUriArray; Warm."""
    node = server.get_node(new_node_id(ua.ObjectIds.Server_ServerRedundancy, 0))
    await server.write_attribute_value(
        new_node_id(ua.ObjectIds.Server_ServerRedundancy_RedundancySupport, 0),
        ua.DataValue(ua.Variant(ua.RedundancySupport.Warm, ua.VariantType.Int32)),
    )
    await node.delete_reference(
        new_node_id(ua.ObjectIds.ServerRedundancyType, 0), ua.ObjectIds.HasTypeDefinition, forward=True
    )
    await node.add_reference(
        new_node_id(ua.ObjectIds.NonTransparentRedundancyType, 0),
        ua.ObjectIds.HasTypeDefinition,
        forward=True,
    )
    # asyncua's standard namespace has the ServerUriArray node (without a reference to it): give it the
    # set's URIs and make it the ServerRedundancy object's property, as the NonTransparentRedundancyType says.
    uris = new_node_id(ua.ObjectIds.Server_ServerRedundancy_ServerUriArray, 0)
    await server.write_attribute_value(
        uris, ua.DataValue(ua.Variant(list(redundant.uris), ua.VariantType.String))
    )
    if uris not in {child.nodeid for child in await node.get_properties()}:
        await node.add_reference(uris, ua.ObjectIds.HasProperty, forward=True)


async def keep_level(server: Any, tree: VariableTree) -> None:
    """Server.ServiceLevel follows the share of the machines this shard serves, until cancelled."""
    node = new_node_id(ua.ObjectIds.Server_ServiceLevel, 0)
    last = -1
    while True:
        level = service_level(tree)
        if level != last:
            await server.write_attribute_value(node, ua.DataValue(ua.Variant(level, ua.VariantType.Byte)))
            if last >= 0:
                log.info("OPC UA: ServiceLevel %d (%d of %d machines served here)", level,
                         len(tree.machines) - len(tree.standby), len(tree.machines))  # fmt: skip
            last = level
        await asyncio.sleep(LEVEL_EVERY)
