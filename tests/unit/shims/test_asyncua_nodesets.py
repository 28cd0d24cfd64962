"""The NodeSets cache: a server that loads the umati view's NodeSets from it has the address space a
server that imported the files has, node by node (new nodes, and the references added to the standard's)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from asyncua import Server, ua

from gateway.shims.asyncua_nodesets import import_nodesets
from gateway.sinks.opcua.umati.install import nodeset_paths


async def _server(folder: Path) -> tuple[Server, bool]:
    server = Server()
    await server.init()
    await server.register_namespace("urn:test:gateway")

    async def import_one(path: Path) -> None:
        await server.import_xml(str(path), auto_load_definitions=False)

    used = await import_nodesets(server, nodeset_paths(), folder, import_one)
    return server, used


def _refs(record: Any) -> set[tuple[str, str, bool]]:
    return {(r.ReferenceTypeId.to_string(), r.NodeId.to_string(), r.IsForward) for r in record.references}


async def test_a_server_loaded_from_the_cache_has_the_nodes_of_one_that_imported_the_files(
    tmp_path: Path,
) -> None:
    imported, used_first = await _server(tmp_path)
    cached, used_second = await _server(tmp_path)
    assert (used_first, used_second) == (False, True)
    assert await imported.get_namespace_array() == await cached.get_namespace_array()
    a, b = imported.iserver.aspace._nodes, cached.iserver.aspace._nodes
    ours = [key for key in a if key.NamespaceIndex >= 3]
    assert len(ours) > 1500
    for key in ours:
        assert key in b, key
        assert _refs(a[key]) == _refs(b[key]), key
        for attribute in (ua.AttributeIds.BrowseName, ua.AttributeIds.NodeClass, ua.AttributeIds.DataType):
            held_a, held_b = a[key].attributes.get(attribute), b[key].attributes.get(attribute)
            assert (held_a is None) == (held_b is None), key
            if held_a is not None:
                assert held_a.value.Value == held_b.value.Value, key
    # The standard namespace's types that companion types derive from know their new subtypes.
    base_object_type = ua.NodeId(ua.ObjectIds.BaseObjectType)
    assert _refs(a[base_object_type]) == _refs(b[base_object_type])
    assert len(_refs(b[base_object_type])) > 20
