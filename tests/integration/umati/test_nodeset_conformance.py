"""The umati view, node by node, against the official NodeSets, through a real client over a socket.

The shipped laser-sim mapping (its `umati:` section) runs in a real Gateway against the simulator; an
asyncua client browses the gateway from the Machinery `Machines` folder (found by its NodeId in the
Machinery namespace, as a generic client does) and checks every MachineTool it finds, recursively: every
Mandatory child of every type instantiated is there, with the declared reference type, NodeClass,
TypeDefinition and DataType; every other child matches an Optional declaration or a placeholder of its
parent's type (nothing contradicts the NodeSet). The reference is read from the NodeSet2 files by
tests/integration/umati/reference.py, not by the gateway's code; the files are the package's vendored
copies (tests/unit/sinks/opcua/umati/test_nodesets.py checks they are shared/'s).
"""

from __future__ import annotations

from pathlib import Path

from asyncua import ua

from gateway.app import Gateway
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.sinks.opcua.umati import config as umati_config
from gateway.sinks.opcua.umati.install import MACHINE_TOOL, MACHINERY, nodeset_paths
from tests.integration.laser_rig import ROOT, laser_rig
from tests.integration.umati.reference import (
    HAS_MODELLING_RULE,
    HAS_SUBTYPE,
    HAS_TYPE_DEFINITION,
    HIERARCHICAL_CHILDREN,
    PLACEHOLDERS,
    UA,
    Declaration,
    Id,
    Node,
    NodeSets,
    Reference,
)
from tests.opcua_client import Client
from tests.waiting import free_port

MACHINE_TOOL_TYPE = (MACHINE_TOOL, "i=13")


class Browser:
    """Reads the server over the client: ids as (URI, text) pairs."""

    def __init__(self, client: Client, uris: list[str]) -> None:
        self.client = client
        self.uris = uris

    def pair(self, nodeid: ua.NodeId) -> Id:
        text = nodeid.to_string()
        rest = text.split(";", 1)[1] if text.startswith("ns=") else text
        return self.uris[nodeid.NamespaceIndex], rest

    def name(self, qn: ua.QualifiedName) -> Id:
        return self.uris[qn.NamespaceIndex], qn.Name

    def node_id(self, pair: Id) -> ua.NodeId:
        return ua.NodeId.from_string(f"ns={self.uris.index(pair[0])};{pair[1]}")

    async def references(self, nodeid: ua.NodeId) -> list[ua.ReferenceDescription]:
        desc = ua.BrowseDescription(
            NodeId=nodeid,
            BrowseDirection=ua.BrowseDirection.Both,
            ReferenceTypeId=ua.NodeId(ua.ObjectIds.References),
            IncludeSubtypes=True,
            NodeClassMask=0,
            ResultMask=ua.BrowseResultMask.All,
        )
        params = ua.BrowseParameters(NodesToBrowse=[desc])
        [result] = await self.client.uaclient.browse(params)
        refs: list[ua.ReferenceDescription] = result.References
        return refs

    async def ns0(self, start: set[Id]) -> dict[Id, Node]:
        """The standard namespace's nodes the check needs: types, their supertypes and declarations."""
        found: dict[Id, Node] = {}
        todo = [i for i in start if i[0] == UA]
        while todo:
            pair = todo.pop()
            if pair in found:
                continue
            nodeid = self.node_id(pair)
            client_node = self.client.get_node(nodeid)
            node = Node(pair, self.name(await client_node.read_browse_name()), "")
            node.node_class = (await client_node.read_node_class()).name
            if node.node_class == "Variable":
                node.data_type = self.pair(await client_node.read_data_type())
            refs = [
                (self.pair(r.ReferenceTypeId), self.pair(r.NodeId), r.IsForward)
                for r in await self.references(nodeid)
            ]
            node.references = refs
            declaration = any(f and t == HAS_MODELLING_RULE for t, _, f in refs)
            is_type = node.node_class.endswith("Type")
            for rtype, target, forward in refs:
                follow = (
                    (not forward and rtype == HAS_SUBTYPE)
                    or (forward and rtype == HAS_TYPE_DEFINITION)
                    or (forward and rtype in HIERARCHICAL_CHILDREN and (is_type or declaration))
                )
                if follow and target[0] == UA and target not in found:
                    todo.append(target)
            found[pair] = node
        return found


def ua_ids(sets: NodeSets) -> set[Id]:
    """Every standard-namespace node the NodeSets refer to (supertypes, TypeDefinitions, DataTypes)."""
    found: set[Id] = set()
    for node in sets.nodes.values():
        for _, target, _ in node.references:
            if target[0] == UA:
                found.add(target)
    return found


class Checker:
    def __init__(self, browser: Browser, reference: Reference) -> None:
        self.browser = browser
        self.ref = reference
        self.checked = 0
        self.mandatory_seen = 0
        self.types: set[Id] = set()
        self.names: dict[Id, str] = {}  # the types instantiated that the NodeSets define, by name
        self.instances: dict[str, Id] = {}  # the MachineTools found, by name

    async def instance(self, nodeid: ua.NodeId, type_id: Id, path: str) -> None:
        self.types.add(type_id)
        await self.children(nodeid, self.ref.type_children(type_id), path)

    async def children(self, nodeid: ua.NodeId, expected: dict[Id, Declaration], path: str) -> None:
        b = self.browser
        actual: dict[Id, ua.ReferenceDescription] = {}
        for ref in await b.references(nodeid):
            if ref.IsForward and b.pair(ref.ReferenceTypeId) in HIERARCHICAL_CHILDREN:
                actual[b.name(ref.BrowseName)] = ref
        for name, declaration in expected.items():
            if declaration.mandatory:
                assert name in actual, f"{path}: the mandatory {name[1]} ({name[0]}) is missing"
                self.mandatory_seen += 1
        placeholders = [d for d in expected.values() if d.rule in PLACEHOLDERS]
        for name, ref in actual.items():
            where = f"{path}/{name[1]}"
            typedef = b.pair(ref.TypeDefinition)
            declaration = expected.get(name)
            self.checked += 1
            if declaration is None:
                fitting = [p for p in placeholders if self.ref.is_subtype(typedef, p.type_definition)]
                assert fitting, f"{where} ({typedef}) matches no declaration or placeholder of its parent"
                placeholder = fitting[0]
                assert b.pair(ref.ReferenceTypeId) == placeholder.reference, where
                await self.instance(ref.NodeId, typedef, where)
                continue
            assert ref.NodeClass.name == declaration.node_class, f"{where}: NodeClass {ref.NodeClass.name}"
            assert b.pair(ref.ReferenceTypeId) == declaration.reference, f"{where}: reference type"
            assert typedef == declaration.type_definition or self.ref.is_subtype(
                typedef, declaration.type_definition
            ), f"{where}: TypeDefinition {typedef}, declared {declaration.type_definition}"
            if declaration.node_class == "Variable":
                data_type = b.pair(await b.client.get_node(ref.NodeId).read_data_type())
                assert data_type == declaration.data_type, (
                    f"{where}: DataType {data_type}, declared {declaration.data_type}"
                )
            self.types.add(declaration.type_definition)
            await self.children(ref.NodeId, self.ref.children(declaration), where)


async def check_machine_tools(client: Client, names: list[str]) -> Checker:
    """Find the MachineTools the standard way and check each against the NodeSets; returns the checker."""
    sets = NodeSets(nodeset_paths())
    uris = await client.get_namespace_array()
    assert set(sets.uris) <= set(uris), f"NamespaceArray {uris} lacks a model of the NodeSets"
    browser = Browser(client, uris)
    # The Machinery entry point: Objects/Machines, NodeId i=1001 of the Machinery namespace.
    machines = client.get_node(ua.NodeId(1001, uris.index(MACHINERY)))
    assert browser.name(await machines.read_browse_name()) == (MACHINERY, "Machines")
    objects = await browser.references(ua.NodeId(ua.ObjectIds.ObjectsFolder))
    assert any(r.IsForward and r.NodeId == machines.nodeid for r in objects), (
        "Objects does not organize Machines"
    )
    found = [
        r
        for r in await browser.references(machines.nodeid)
        if r.IsForward and browser.pair(r.TypeDefinition) == MACHINE_TOOL_TYPE
    ]
    assert sorted(browser.name(r.BrowseName)[1] for r in found) == sorted(names)
    reference = Reference(sets, await browser.ns0(ua_ids(sets) | {(UA, "i=58"), (UA, "i=63"), (UA, "i=68")}))
    checker = Checker(browser, reference)
    for machine in found:
        before = checker.mandatory_seen
        await checker.instance(machine.NodeId, MACHINE_TOOL_TYPE, browser.name(machine.BrowseName)[1])
        assert checker.mandatory_seen - before >= 25
    checker.names = {t: sets.nodes[t].browse_name[1] for t in checker.types if t in sets.nodes}
    checker.instances = {browser.name(r.BrowseName)[1]: browser.pair(r.NodeId) for r in found}
    return checker


async def test_every_machine_tool_has_every_mandatory_node_as_the_nodesets_declare(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        checker = await check_machine_tools(await rig.client(), ["laser-sim"])
        # The types the mapping asked for, instantiated: a channel, the laser, software, the messages.
        for name in (
            "ChannelMonitoringType",
            "LaserMonitoringType",
            "SoftwareIdentificationType",
            "MessagesType",
            "ProductionProgramStateMachineType",
        ):
            assert name in checker.names.values(), name


async def test_the_fanuc_and_haas_mappings_are_machine_tools_as_the_nodesets_declare(tmp_path: Path) -> None:
    """Their structure, from the shipped mappings, with no controller reachable (the values are Bad)."""
    closed = {"FANUC_SIM_PORT": str(free_port()), "HAAS_SIM_PORT": str(free_port())}
    mappings = tuple(
        load_mapping(ROOT / "mappings" / name, environ=closed).model_copy(update={"jobs": None})
        for name in ("fanuc-sim.yaml", "haas-sim.yaml")
    )
    gateway = GatewayConfig.model_validate(
        {
            "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway"},
            "state_dir": str(tmp_path / "state"),
            "inbox": {"enabled": False},
            "http": None,
        }
    )
    endpoint = gateway.opcua.endpoint
    async with Gateway(Config(gateway, mappings, tmp_path)), Client(endpoint, timeout=5) as client:
        checker = await check_machine_tools(client, ["fanuc-sim", "haas-sim"])
    # haas-sim.yaml gives its instance a namespace of its own (umati.namespace); fanuc-sim the gateway's.
    assert checker.instances["haas-sim"][0] == "urn:cnc-gateway:simulator:haas-sim"
    assert checker.instances["fanuc-sim"][0] == "urn:cnc-gateway"
    assert {"SpindleMonitoringType", "LaserMonitoringType", "ChannelMonitoringType"} <= set(
        checker.names.values()
    )


def test_the_enumerations_the_mapping_names_are_the_nodesets() -> None:
    sets = NodeSets(nodeset_paths())
    for name, values in {
        "ChannelState": umati_config.CHANNEL_STATE,
        "ChannelMode": umati_config.CHANNEL_MODE,
        "MachineOperationMode": umati_config.OPERATION_MODE,
        "LaserState": umati_config.LASER_STATE,
    }.items():
        assert sets.enums[(MACHINE_TOOL, name)] == [(v, i) for i, v in enumerate(values)], name
