"""The umati types as the server holds them: which children an instance of a type must (or may) have.

After the official NodeSets are imported (nodesets/), the types are nodes of the address space like any
other. This module reads them through two questions (`Space`: a node's references, one attribute) and
answers what OPC UA Part 3 §6 says an instance of a type is made of: the InstanceDeclarations of the type
and its supertypes (a subtype's declaration overrides its supertype's of the same BrowseName), and, below
a declaration, its own nested declarations over those of its TypeDefinition. Each comes with its
ModellingRule, so that the view creates every Mandatory child and the Optional ones the mapping fills.
Pure reading: no I/O, no asyncua server API.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

from asyncua import ua

from gateway.shims.ua import new_node_id

HIERARCHICAL = new_node_id(ua.ObjectIds.HierarchicalReferences)
HAS_SUBTYPE = new_node_id(ua.ObjectIds.HasSubtype)
HAS_MODELLING_RULE = new_node_id(ua.ObjectIds.HasModellingRule)
MANDATORY = new_node_id(ua.ObjectIds.ModellingRule_Mandatory)
OPTIONAL = new_node_id(ua.ObjectIds.ModellingRule_Optional)
MANDATORY_PLACEHOLDER = new_node_id(ua.ObjectIds.ModellingRule_MandatoryPlaceholder)
OPTIONAL_PLACEHOLDER = new_node_id(ua.ObjectIds.ModellingRule_OptionalPlaceholder)


class Space(Protocol):
    """The two reads this module needs (ServerPort offers them)."""

    def references(self, nodeid: ua.NodeId) -> Sequence[ua.ReferenceDescription]: ...

    def attribute(self, nodeid: ua.NodeId, attribute: ua.AttributeIds) -> ua.DataValue | None: ...


@dataclass(frozen=True)
class Declaration:
    """One InstanceDeclaration: a child an instance of its owner has (Mandatory) or may have."""

    nodeid: ua.NodeId
    browse_name: ua.QualifiedName
    node_class: ua.NodeClass
    reference: ua.NodeId  # the reference type from the owner
    type_definition: ua.NodeId
    rule: ua.NodeId

    @property
    def mandatory(self) -> bool:
        return self.rule == MANDATORY

    @property
    def placeholder(self) -> bool:
        return self.rule in (MANDATORY_PLACEHOLDER, OPTIONAL_PLACEHOLDER)


class TypeModel:
    """Reads instance declarations out of the address space, caching per node."""

    def __init__(self, space: Space) -> None:
        self.space = space
        self._declared: dict[ua.NodeId, dict[str, Declaration]] = {}
        self._type_children: dict[ua.NodeId, dict[str, Declaration]] = {}

    @cached_property
    def hierarchical(self) -> frozenset[ua.NodeId]:
        """HierarchicalReferences and all its subtypes (HasComponent, HasProperty, Organizes …)."""
        found = {HIERARCHICAL}
        todo = [HIERARCHICAL]
        while todo:
            for ref in self.space.references(todo.pop()):
                if ref.IsForward and ref.ReferenceTypeId == HAS_SUBTYPE and ref.NodeId not in found:
                    found.add(ref.NodeId)
                    todo.append(ref.NodeId)
        return frozenset(found)

    def supertype(self, type_id: ua.NodeId) -> ua.NodeId | None:
        for ref in self.space.references(type_id):
            if not ref.IsForward and ref.ReferenceTypeId == HAS_SUBTYPE:
                supertype: ua.NodeId = ref.NodeId
                return supertype
        return None

    def is_subtype(self, type_id: ua.NodeId, of: ua.NodeId) -> bool:
        current: ua.NodeId | None = type_id
        while current is not None:
            if current == of:
                return True
            current = self.supertype(current)
        return False

    def declared(self, owner: ua.NodeId) -> dict[str, Declaration]:
        """The declarations directly below `owner` (a type or a declaration), by BrowseName text."""
        cached = self._declared.get(owner)
        if cached is not None:
            return cached
        found: dict[str, Declaration] = {}
        hierarchical = self.hierarchical
        for ref in self.space.references(owner):
            if not ref.IsForward or ref.ReferenceTypeId not in hierarchical:
                continue
            rule = self._rule(ref.NodeId)
            if rule is None:
                continue
            found[_key(ref.BrowseName)] = Declaration(
                ref.NodeId, ref.BrowseName, ref.NodeClass, ref.ReferenceTypeId, ref.TypeDefinition, rule
            )
        self._declared[owner] = found
        return found

    def type_children(self, type_id: ua.NodeId) -> dict[str, Declaration]:
        """The declarations of a type and its supertypes; a subtype's overrides its supertype's."""
        cached = self._type_children.get(type_id)
        if cached is not None:
            return cached
        chain: list[ua.NodeId] = []
        current: ua.NodeId | None = type_id
        while current is not None:
            chain.append(current)
            current = self.supertype(current)
        merged: dict[str, Declaration] = {}
        for owner in reversed(chain):
            merged.update(self.declared(owner))
        self._type_children[type_id] = merged
        return merged

    def children(self, declaration: Declaration) -> dict[str, Declaration]:
        """What an instance of a declaration is made of: its TypeDefinition's, overridden by its own."""
        merged = dict(self.type_children(declaration.type_definition))
        merged.update(self.declared(declaration.nodeid))
        return merged

    def _rule(self, nodeid: ua.NodeId) -> ua.NodeId | None:
        for ref in self.space.references(nodeid):
            if ref.IsForward and ref.ReferenceTypeId == HAS_MODELLING_RULE:
                rule: ua.NodeId = ref.NodeId
                return rule
        return None


def _key(name: ua.QualifiedName) -> str:
    """Children are named by BrowseName text: no type here has two children of one name."""
    return str(name.Name)
