"""The process-wide asyncua adjustments of gateway/shims/asyncua_server.py, on real asyncua servers."""

from __future__ import annotations

import sys

import pytest
from asyncua import Server, ua
from asyncua.server import address_space

from gateway.shims.asyncua_server import (
    NO_CALLBACKS,
    NameAttributeValue,
    NodeAttributes,
    SlimAttributeValue,
    forget_standard_namespace_code,
    slim_attribute_values,
)

pytestmark = pytest.mark.asyncio

FILL = "asyncua.server.standard_address_space"


async def test_attribute_records_are_slim_until_someone_monitors_them() -> None:
    slim_attribute_values()
    server = Server()
    await server.init()
    aspace = server.iserver.aspace
    server_state = ua.NodeId(ua.ObjectIds.Server_ServerStatus_State)
    held = aspace._nodes[server_state].attributes[ua.AttributeIds.Value]
    assert type(held) is SlimAttributeValue and not hasattr(held, "__dict__")
    assert held.datachange_callbacks is NO_CALLBACKS
    with pytest.raises(TypeError):
        NO_CALLBACKS[1] = print  # shared by every record: never filled

    seen: list[object] = []

    async def callback(handle: int, value: ua.DataValue) -> None:
        seen.append(value.Value.Value)

    status, handle = aspace.add_datachange_callback(server_state, ua.AttributeIds.Value, callback)
    assert status.is_good()
    assert held.datachange_callbacks is not NO_CALLBACKS and handle in held.datachange_callbacks
    await aspace.write_attribute_value(
        server_state, ua.AttributeIds.Value, ua.DataValue(ua.Variant(1, ua.VariantType.Int32))
    )
    assert seen == [1]
    aspace.delete_datachange_callback(handle)
    assert not held.datachange_callbacks and not NO_CALLBACKS


async def test_the_code_that_builds_the_standard_namespace_goes_and_comes_back() -> None:
    forget_standard_namespace_code()
    first = Server()
    await first.init()
    assert not [name for name in sys.modules if name.startswith(FILL)]
    second = Server()  # imports it again, and builds the same namespace
    await second.init()
    assert not [name for name in sys.modules if name.startswith(FILL)]
    ids = set(first.iserver.aspace.keys())
    assert ids == set(second.iserver.aspace.keys()) and len(ids) > 5000
    assert address_space.AttributeValue is not None


async def test_name_records_build_what_asyncua_keeps_and_keep_what_is_written() -> None:
    """bulk.py's records of a node's NodeId, BrowseName, DisplayName: read, monitored and written through
    asyncua's own address space as its records are."""
    slim_attribute_values()
    space = address_space.AddressSpace()
    nodeid = ua.NodeId("m1/A", 2)
    node = address_space.NodeData(nodeid)
    name = ua.LocalizedText("A")
    node.attributes[ua.AttributeIds.NodeId] = NameAttributeValue(nodeid, ua.VariantType.NodeId)  # type: ignore[assignment]
    node.attributes[ua.AttributeIds.DisplayName] = NameAttributeValue(name, ua.VariantType.LocalizedText)  # type: ignore[assignment]
    space[nodeid] = node
    read = space.read_attribute_value(nodeid, ua.AttributeIds.DisplayName)
    assert read == ua.DataValue(ua.Variant(name, ua.VariantType.LocalizedText))
    assert space.read_attribute_value(nodeid, ua.AttributeIds.NodeId) == ua.DataValue(
        ua.Variant(nodeid, ua.VariantType.NodeId)
    )
    seen: list[object] = []

    async def callback(handle: int, value: ua.DataValue) -> None:
        seen.append(value.Value.Value)

    status, _ = space.add_datachange_callback(nodeid, ua.AttributeIds.DisplayName, callback)
    assert status.is_good()
    renamed = ua.DataValue(ua.Variant(ua.LocalizedText("B"), ua.VariantType.LocalizedText))
    assert (await space.write_attribute_value(nodeid, ua.AttributeIds.DisplayName, renamed)).is_good()
    assert space.read_attribute_value(nodeid, ua.AttributeIds.DisplayName) == renamed
    assert seen == [ua.LocalizedText("B")]


async def test_node_attributes_answer_as_the_dict_asyncua_would_have_kept() -> None:
    """Own records in the dict, constant ones shared, name records made when first looked up and kept."""
    nodeid = ua.NodeId("m/x", 2)
    browse, display = ua.QualifiedName("x", 2), ua.LocalizedText("x")
    access = SlimAttributeValue(ua.DataValue(ua.Variant(1, ua.VariantType.Byte)))
    value = SlimAttributeValue(ua.DataValue(ua.Variant(2.5)))
    node_class = SlimAttributeValue(ua.DataValue(ua.Variant(2, ua.VariantType.Int32)))
    shared = {ua.AttributeIds.NodeClass: node_class, ua.AttributeIds.AccessLevel: access}
    attributes = NodeAttributes({ua.AttributeIds.Value: value}, shared, nodeid, browse, display)
    plain = {
        ua.AttributeIds.NodeId: nodeid,
        ua.AttributeIds.BrowseName: browse,
        ua.AttributeIds.NodeClass: 2,
        ua.AttributeIds.AccessLevel: 1,
        ua.AttributeIds.DisplayName: display,
        ua.AttributeIds.Value: 2.5,
    }
    assert list(attributes) == list(plain)  # asyncua's order: NodeId, BrowseName, NodeClass, then by name
    assert len(attributes) == len(plain)
    assert {k: v.value.Value.Value for k, v in attributes.items()} == plain
    for key, held in plain.items():
        assert key in attributes
        assert attributes[key].value.Value.Value == held
        assert attributes.get(key).value.Value.Value == held
    assert ua.AttributeIds.Executable not in attributes
    assert attributes.get(ua.AttributeIds.Executable) is None
    with pytest.raises(KeyError):
        attributes[ua.AttributeIds.Executable]
    assert attributes[ua.AttributeIds.NodeClass] is node_class  # handed out as it is, not copied
    name = attributes[ua.AttributeIds.DisplayName]
    assert type(name) is NameAttributeValue and attributes[ua.AttributeIds.DisplayName] is name  # kept
    name.value = ua.DataValue(ua.Variant(ua.LocalizedText("y")))
    assert attributes[ua.AttributeIds.DisplayName].value.Value.Value == ua.LocalizedText("y")
    assert shared == {ua.AttributeIds.NodeClass: node_class, ua.AttributeIds.AccessLevel: access}
