"""The redundant server set of lease-served shards (gateway/sinks/opcua/redundancy.py), on asyncua's server.

Read back as OPC UA Part 4 (6.6.2) and Part 5 describe the nodes: ServerRedundancy typed
NonTransparentRedundancyType, RedundancySupport Warm, ServerUriArray as its property; the server's
ServiceLevel from the share of the machines served; which URIs make the set.
"""

from __future__ import annotations

import pytest
from asyncua import Server, ua

from gateway.model.definitions import MachineDefinition
from gateway.model.tree import VariableTree
from gateway.sinks.opcua import redundant_set
from gateway.sinks.opcua.redundancy import RedundantSet, application_uri, install, service_level


def tree_of(count: int) -> VariableTree:
    return VariableTree(MachineDefinition(f"m{k}", ()) for k in range(count))


def test_the_service_level_follows_the_share_of_machines_served() -> None:
    tree = tree_of(4)
    assert service_level(tree) == 255  # every machine served here
    for name in ("m0", "m1"):
        tree.machines[name].served = False
    assert service_level(tree) == 227  # half: 200 + 55 × 2 / 4
    for machine in tree.machines.values():
        machine.served = False
    assert service_level(tree) == 200  # a healthy standby
    tree.machines["m3"].served = True
    assert tree.standby == {"m0", "m1", "m2"} and service_level(tree) == 213


def test_the_set_is_the_configured_servers_else_this_hosts_shards(monkeypatch: pytest.MonkeyPatch) -> None:
    assert RedundantSet.of_fleet(3, "gw").uris == tuple(f"urn:gw:cnc-gateway:shard-{k}" for k in (1, 2, 3))
    assert application_uri(None, "gw") == "urn:gw:cnc-gateway"
    monkeypatch.setenv("CNC_SHARD", "2/3")
    assert redundant_set(["urn:a", "urn:b"]).uris == ("urn:a", "urn:b")
    assert len(redundant_set([]).uris) == 3
    monkeypatch.delenv("CNC_SHARD")
    monkeypatch.delenv("CNC_SHARD_INDEX", raising=False)
    assert redundant_set([]).uris == (application_uri(None),)


async def test_installed_nodes_read_as_a_non_transparent_redundant_server() -> None:
    server = Server()
    await server.init()
    await install(server, RedundantSet(("urn:a:cnc-gateway:shard-1", "urn:b:cnc-gateway:shard-2")))
    redundancy = server.get_node(ua.NodeId(ua.ObjectIds.Server_ServerRedundancy, 0))
    type_definition = await redundancy.read_type_definition()
    assert type_definition == ua.NodeId(ua.ObjectIds.NonTransparentRedundancyType, 0)
    support = server.get_node(ua.NodeId(ua.ObjectIds.Server_ServerRedundancy_RedundancySupport, 0))
    assert await support.read_value() == ua.RedundancySupport.Warm
    properties = {(await p.read_browse_name()).Name: p for p in await redundancy.get_properties()}
    assert await properties["ServerUriArray"].read_value() == [
        "urn:a:cnc-gateway:shard-1",
        "urn:b:cnc-gateway:shard-2",
    ]
