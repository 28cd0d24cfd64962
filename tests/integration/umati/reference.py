"""The official NodeSets as a reference the tests read on their own (xml.etree, no asyncua, no gateway code).

What an instance of a type must have (OPC UA Part 3 §6.3): the InstanceDeclarations of the type and its
supertypes (a subtype's overrides its supertype's of the same BrowseName), below a declaration its own
nested declarations over its TypeDefinition's; each with a ModellingRule, a NodeClass, a reference type,
a TypeDefinition and (Variables) a DataType. NodeIds and BrowseNames are (namespace URI, text) pairs, so
they compare with what a client reads whatever index the server gave each namespace. The standard
namespace itself (ns=0: BaseObjectType, AnalogUnitRangeType, StateVariableType …) is not among the files;
its nodes come from `Ns0`, which a test fills by browsing the server (asyncua's generated copy of the
standard's Opc.Ua.NodeSet2.xml).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

UA = "http://opcfoundation.org/UA/"
_X = "{http://opcfoundation.org/UA/2011/03/UANodeSet.xsd}"

Id = tuple[str, str]  # (namespace URI, "i=13" / "s=…")

HAS_COMPONENT: Id = (UA, "i=47")
HAS_PROPERTY: Id = (UA, "i=46")
HAS_ORDERED_COMPONENT: Id = (UA, "i=49")
ORGANIZES: Id = (UA, "i=35")
HAS_ADD_IN: Id = (UA, "i=17604")
HAS_SUBTYPE: Id = (UA, "i=45")
HAS_TYPE_DEFINITION: Id = (UA, "i=40")
HAS_MODELLING_RULE: Id = (UA, "i=37")
HIERARCHICAL_CHILDREN = frozenset({HAS_COMPONENT, HAS_PROPERTY, HAS_ORDERED_COMPONENT, ORGANIZES, HAS_ADD_IN})
MANDATORY: Id = (UA, "i=78")
OPTIONAL: Id = (UA, "i=80")
PLACEHOLDERS = frozenset({(UA, "i=11508"), (UA, "i=11510")})

_STANDARD_REFERENCES = {
    "HasComponent": HAS_COMPONENT,
    "HasProperty": HAS_PROPERTY,
    "HasOrderedComponent": HAS_ORDERED_COMPONENT,
    "Organizes": ORGANIZES,
    "HasAddIn": HAS_ADD_IN,
    "HasSubtype": HAS_SUBTYPE,
    "HasTypeDefinition": HAS_TYPE_DEFINITION,
    "HasModellingRule": HAS_MODELLING_RULE,
}


@dataclass
class Node:
    nodeid: Id
    browse_name: Id
    node_class: str  # "Object", "Variable", "ObjectType" … (the XML element without "UA")
    data_type: Id | None = None
    references: list[tuple[Id, Id, bool]] = field(default_factory=list)  # (type, target, forward)


@dataclass(frozen=True)
class Declaration:
    nodeid: Id
    browse_name: Id
    node_class: str
    reference: Id
    type_definition: Id
    rule: Id
    data_type: Id | None

    @property
    def mandatory(self) -> bool:
        return self.rule == MANDATORY


class NodeSets:
    """Every node of the given NodeSet2 files, with both directions of every reference."""

    def __init__(self, files: Iterable[Path]) -> None:
        self.nodes: dict[Id, Node] = {}
        self.enums: dict[Id, list[tuple[str, int]]] = {}
        self.uris: list[str] = []
        pending: list[tuple[Id, Id, Id, bool]] = []
        for path in files:
            self._load(path, pending)
        for owner, rtype, target, forward in pending:
            self.node(owner).references.append((rtype, target, forward))
            self.node(target).references.append((rtype, owner, not forward))

    def node(self, nodeid: Id) -> Node:
        found = self.nodes.get(nodeid)
        if found is None:  # a node of the standard namespace: only its references from ours are known
            found = self.nodes[nodeid] = Node(nodeid, ("", ""), "")
        return found

    def _load(self, path: Path, pending: list[tuple[Id, Id, Id, bool]]) -> None:
        root = ET.parse(path).getroot()
        uris = [UA, *(u.text or "" for u in root.iter(f"{_X}Uri"))]
        self.uris.append(uris[1])
        aliases = {a.get("Alias", ""): a.text or "" for a in root.iter(f"{_X}Alias")}

        def ident(text: str) -> Id:
            text = aliases.get(text, text)
            if text in _STANDARD_REFERENCES:
                return _STANDARD_REFERENCES[text]
            if text.startswith("ns="):
                index, rest = text[3:].split(";", 1)
                return uris[int(index)], rest
            return UA, text

        def qualified(text: str) -> Id:
            if ":" in text and text.split(":", 1)[0].isdigit():
                index, name = text.split(":", 1)
                return uris[int(index)], name
            return UA, text

        for element in root:
            tag = element.tag.removeprefix(_X)
            if not tag.startswith("UA") or element.get("NodeId") is None:
                continue
            nodeid = ident(element.get("NodeId", ""))
            data_type = element.get("DataType")
            node = Node(nodeid, qualified(element.get("BrowseName", "")), tag[2:])
            node.data_type = (
                ident(data_type) if data_type else ((UA, "i=24") if tag == "UAVariable" else None)
            )
            existing = self.nodes.get(nodeid)
            if existing is not None:
                node.references = existing.references
            self.nodes[nodeid] = node
            for ref in element.iter(f"{_X}Reference"):
                forward = ref.get("IsForward", "true").lower() != "false"
                pending.append((nodeid, ident(ref.get("ReferenceType", "")), ident(ref.text or ""), forward))
            if tag == "UADataType":
                fields = [(f.get("Name", ""), int(f.get("Value", "-1"))) for f in element.iter(f"{_X}Field")]
                self.enums[node.browse_name] = fields


class Reference:
    """Instance declarations, read from the NodeSets (companion namespaces) and `ns0` (the standard's)."""

    def __init__(self, sets: NodeSets, ns0: dict[Id, Node]) -> None:
        self.sets = sets
        self.ns0 = ns0

    def node(self, nodeid: Id) -> Node:
        if nodeid[0] == UA:
            found = self.ns0.get(nodeid)
            assert found is not None, f"{nodeid} of the standard namespace was not browsed"
            ours = self.sets.nodes.get(nodeid)  # companion types add subtypes to standard ones
            if ours is not None:
                return Node(
                    found.nodeid,
                    found.browse_name,
                    found.node_class,
                    found.data_type,
                    [*found.references, *ours.references],
                )
            return found
        return self.sets.nodes[nodeid]

    def _forward(self, nodeid: Id, rtype: Id) -> Id | None:
        for ref, target, forward in self.node(nodeid).references:
            if forward and ref == rtype:
                return target
        return None

    def supertype(self, type_id: Id) -> Id | None:
        for ref, target, forward in self.node(type_id).references:
            if not forward and ref == HAS_SUBTYPE:
                return target
        return None

    def is_subtype(self, type_id: Id, of: Id) -> bool:
        current: Id | None = type_id
        while current is not None:
            if current == of:
                return True
            current = self.supertype(current)
        return False

    def declared(self, owner: Id) -> dict[Id, Declaration]:
        found: dict[Id, Declaration] = {}
        for ref, target, forward in self.node(owner).references:
            if not forward or ref not in HIERARCHICAL_CHILDREN:
                continue
            rule = self._forward(target, HAS_MODELLING_RULE)
            if rule is None:
                continue
            child = self.node(target)
            typedef = self._forward(target, HAS_TYPE_DEFINITION) or ("", "")
            found[child.browse_name] = Declaration(
                target, child.browse_name, child.node_class, ref, typedef, rule, child.data_type
            )
        return found

    def type_children(self, type_id: Id) -> dict[Id, Declaration]:
        chain: list[Id] = []
        current: Id | None = type_id
        while current is not None:
            chain.append(current)
            current = self.supertype(current)
        merged: dict[Id, Declaration] = {}
        for owner in reversed(chain):
            merged.update(self.declared(owner))
        return merged

    def children(self, declaration: Declaration) -> dict[Id, Declaration]:
        merged = dict(self.type_children(declaration.type_definition))
        merged.update(self.declared(declaration.nodeid))
        return merged
