"""The seam between the OPC UA server and the parts built on it (alarm conditions today).

A part such as `alarms.OpcUaAlarms` adds nodes, makes objects event notifiers,
reports events and serves method calls; it needs the server for exactly that,
and `ServerPort` says so. The server (`server.OpcUaSink`) implements the port
and knows such parts only as `ServerExtension`s handed to it at construction
(gateway/app.py wires them); it imports none of them, and they import neither
the server nor asyncua's server API.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Protocol

from asyncua import ua
from asyncua.common.events import Event

from gateway.model.context import WriteContext
from gateway.model.sample import Sample
from gateway.model.tree import VariableNode

MethodCallback = Callable[..., Awaitable[ua.CallMethodResult]]
"""Serves a Method node: called with the object's NodeId and the input Variants."""


class Shown(Protocol):
    """How a view shows a tree variable's sample at a node of its own (values.ValueKind is one)."""

    def datavalue(self, sample: Sample, server_ts: datetime) -> ua.DataValue:
        """The DataValue for the sample; raises values.ValueMismatch when it cannot be shown."""
        ...

    def mismatch(self, sample: Sample, server_ts: datetime) -> ua.DataValue: ...


class ServerPort(Protocol):
    """What the OPC UA server offers the parts built on it."""

    @property
    def namespace_index(self) -> int:
        """The gateway's namespace, for the NodeIds a part makes."""
        ...

    def machine_node_id(self, machine: str) -> ua.NodeId:
        """The machine's Object, under which a part attaches its nodes."""
        ...

    async def add_nodes(self, items: Sequence[ua.AddNodesItem]) -> list[ua.NodeId]:
        """Add nodes; raises SinkError if the server refuses one."""
        ...

    async def delete_nodes(self, nodeids: Sequence[ua.NodeId]) -> None:
        """Remove nodes (and their references)."""
        ...

    async def add_event_notifier(self, nodeid: ua.NodeId) -> None:
        """Make an object an event notifier that the Server object reports through (HasNotifier)."""
        ...

    def link_method(self, nodeid: ua.NodeId, callback: MethodCallback) -> None:
        """Serve calls of a Method node (also a standard one, such as Acknowledge) with `callback`."""
        ...

    def caller_context(self) -> WriteContext:
        """Who is calling, inside a method callback."""
        ...

    async def trigger_event(
        self, event: Event, subscription: int | None = None, item: int | None = None
    ) -> None:
        """Report an event to its notifier's subscribers: all, or one subscription (and one of its items)."""
        ...

    async def trigger_unfiltered(self, event: Event, subscription: int, item: int | None = None) -> None:
        """Queue an event for every event item of one subscription, past their filters (RefreshStart/End)."""
        ...

    def has_subscription(self, subscription: int) -> bool:
        """Whether a subscription of that id exists (ConditionRefresh's argument check)."""
        ...

    # --- views built on companion specifications (umati) ----------------------------------------

    async def import_nodesets(self, files: Sequence[Path]) -> None:
        """Load NodeSet2 files (types of companion specifications), in order, once per server."""
        ...

    async def register_namespace(self, uri: str) -> int:
        """Add a namespace URI to the NamespaceArray (if it is not there yet); returns its index."""
        ...

    def namespace_of(self, uri: str) -> int:
        """The index of a namespace URI in the server's NamespaceArray (-1: absent)."""
        ...

    def references(self, nodeid: ua.NodeId) -> Sequence[ua.ReferenceDescription]:
        """A node's references, both directions (empty for an unknown node)."""
        ...

    def attribute(self, nodeid: ua.NodeId, attribute: ua.AttributeIds) -> ua.DataValue | None:
        """One attribute of a node, as held (None: no such node or attribute)."""
        ...

    def show(self, nodeid: ua.NodeId, node: VariableNode, shown: Shown, *, writable: bool = False) -> None:
        """Serve the tree variable's samples at another Variable node too: the same sample, in the same
        publish step, through `shown`. `writable`: client writes there go to the variable through the
        gateway's one write path (then `shown` must be the variable's own ValueKind)."""
        ...

    async def set_value(self, nodeid: ua.NodeId, value: ua.DataValue) -> None:
        """Set the Value of a node that no tree variable feeds (a constant of a view)."""
        ...


class ServerExtension(Protocol):
    """A part built on the server, installed once the tree's nodes exist and before clients connect."""

    async def install(self, server: ServerPort) -> None: ...
