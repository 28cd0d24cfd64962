"""One asyncua habit the gateway cannot afford: a deep copy of every value, per subscribed item, per change.

For every value written to a node that a client monitors, asyncua's server calls
`MonitoredItemValues.set_current_datavalue`, which keeps a `copy.deepcopy` of the
DataValue, so that a caller who mutates a value after writing it cannot change
what the next change is compared against. Profiles of the mirror benchmark
(bench/README.md) put that copy at about half of the gateway's CPU time per
change when one client subscribes, more than everything else the gateway does
for the change together.

Nobody here mutates a written DataValue: the OPC UA sink builds a fresh one for
every write (gateway/sinks/opcua/values.py), and so do asyncua's own writes and
the simulator. `keep_written_values()` makes asyncua keep a reference instead of
a copy. It is process-wide (asyncua has no per-server hook), idempotent, and
leaves the comparison itself (value, status, timestamps) exactly as it was.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from typing import Any

_MARK = "_cnc_gateway_keeps_reference"


class _KeptValues:
    """asyncua's MonitoredItemValues, slotted, keeping a reference to each written DataValue."""

    __slots__ = ("current_dvalue", "old_dvalue")

    def __init__(self) -> None:
        self.current_dvalue: Any = None
        self.old_dvalue: Any = None

    def set_current_datavalue(self, cur_val: Any) -> None:
        self.old_dvalue = self.current_dvalue
        self.current_dvalue = cur_val

    def get_current_datavalue(self) -> Any:
        return self.current_dvalue

    def get_old_datavalue(self) -> Any:
        return self.old_dvalue


class _SlimMonitoredItem(_KeptValues):
    """asyncua's MonitoredItemData with slots: the same fields, about a quarter of its memory
    (a subscriber of 10,000 variables holds 10,000 of them, and as many values). It is its own
    `mvalue` (the item's last two values), which asyncua keeps in an object of its own per item."""

    __slots__ = (
        "callback_handle",
        "client_handle",
        "filter",
        "mode",
        "monitored_item_id",
        "mvalue",
        "queue_size",
        "read_value_id",
        "where_clause_evaluator",
    )

    def __init__(self) -> None:
        super().__init__()
        self.client_handle: Any = None
        self.callback_handle: Any = None
        self.monitored_item_id: Any = None
        self.mode: Any = None
        self.read_value_id: Any = None
        self.filter: Any = None
        self.where_clause_evaluator: Any = None
        self.queue_size: int = 0
        self.mvalue: _KeptValues = self  # a slot, not a property: read on every change of the item


def keep_written_values() -> None:
    """Replace asyncua's deep copy of each monitored value by a reference (once per process), and its
    records of monitored items by slotted ones (`MonitoredItemData()` is looked up at call time)."""
    from asyncua.server import monitored_item_service
    from asyncua.server.monitored_item_service import MonitoredItemValues

    if getattr(MonitoredItemValues, _MARK, False):
        return

    def set_current_datavalue(self: Any, cur_val: Any) -> None:
        self.old_dvalue = self.current_dvalue
        self.current_dvalue = cur_val

    MonitoredItemValues.set_current_datavalue = set_current_datavalue  # type: ignore[method-assign]
    monitored_item_service.MonitoredItemData = _SlimMonitoredItem  # type: ignore[misc,assignment]
    setattr(MonitoredItemValues, _MARK, True)


_SLIM_MARK = "_cnc_gateway_slim"


class _NoCallbacks(dict[int, Any]):
    """The one empty `datachange_callbacks` every attribute starts with; never filled (see below)."""

    def _refuse(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("the shared empty callbacks mapping is read-only")

    __setitem__ = _refuse
    setdefault = _refuse
    update = _refuse

    def __reduce__(self) -> str:
        return "NO_CALLBACKS"  # unpickled (asyncua_ns0.py's cache) as the one shared mapping, not a copy


NO_CALLBACKS: dict[int, Any] = _NoCallbacks()


class SlimAttributeValue:
    """asyncua's AttributeValue with slots, and no dict of its own until a client monitors it.

    asyncua keeps one AttributeValue per attribute per node (twelve to fifteen a node),
    each with an instance `__dict__` and an empty `datachange_callbacks` dict: about
    220 bytes apiece, some 50 MB for the standard namespace and 10,000 variables,
    the largest single item of the gateway's memory. Slotted, with every attribute
    sharing one empty read-only mapping until `add_datachange_callback` (the only
    place asyncua adds a callback) gives it a dict of its own, it is 64 bytes.
    Everything asyncua reads or assigns (`value`, `value_callback`, `value_setter`,
    `datachange_callbacks`) is there, under the same names.
    """

    __slots__ = ("datachange_callbacks", "value", "value_callback", "value_setter")

    def __init__(self, value: Any) -> None:
        self.value = value
        self.value_callback: Any = None
        self.value_setter: Any = None
        self.datachange_callbacks: dict[int, Any] = NO_CALLBACKS

    def __str__(self) -> str:
        return f"AttributeValue({self.value_callback or self.value})"

    __repr__ = __str__


class NameAttributeValue:
    """The record of a node's NodeId, BrowseName or DisplayName, which holds the value (the NodeId, the
    QualifiedName, the LocalizedText: objects the node and its parent's reference hold anyway) and builds
    the DataValue when something reads it.

    asyncua keeps a DataValue and a Variant per node for each of the three (about 150 bytes apiece, 4.5 MB
    over 10,000 variables), which only a client's Read of these attributes looks at. Reading `value` gives
    a DataValue equal to the one asyncua would have kept (a Variant of the attribute's type, no time
    stamps); assigning it (asyncua's write_attribute_value) keeps what is assigned, as asyncua's record
    does. Everything else asyncua reads or assigns is there under the same names, as in SlimAttributeValue.
    """

    __slots__ = ("_assigned", "_held", "_vtype", "datachange_callbacks", "value_callback", "value_setter")

    def __init__(self, held: Any, vtype: Any) -> None:
        self._held = held
        self._vtype = vtype
        self._assigned: Any = None
        self.value_callback: Any = None
        self.value_setter: Any = None
        self.datachange_callbacks: dict[int, Any] = NO_CALLBACKS

    @property
    def value(self) -> Any:
        if self._assigned is not None:
            return self._assigned
        from asyncua import ua

        return ua.DataValue(ua.Variant(self._held, self._vtype))

    @value.setter
    def value(self, value: Any) -> None:
        self._assigned = value

    def __str__(self) -> str:
        return f"AttributeValue({self.value_callback or self.value})"

    __repr__ = __str__


class SharedAttributeValue(SlimAttributeValue):
    """A record that many nodes hold for one constant attribute (their DataType, ValueRank, ...).

    Built by the OPC UA sink for its own nodes (gateway/sinks/opcua/bulk.py). asyncua
    changes a record in place in four places (`write_attribute_value`,
    `set_attribute_value_callback`, `set_attribute_value_setter`,
    `add_datachange_callback`); `slim_attribute_values` makes each of them first give
    the node a record of its own, so that what is done to one node is done to it only.
    """

    __slots__ = ()


# The order in which asyncua's _add_nodeattributes adds the specified attributes (after NodeId, BrowseName
# and NodeClass); UserWriteMask twice, as asyncua has it (the second, a UInt32, is the one kept).
ATTRIBUTE_ORDER = (
    "AccessLevel", "ArrayDimensions", "BrowseName", "ContainsNoLoops", "DataType", "Description",
    "DisplayName", "EventNotifier", "Executable", "Historizing", "InverseName", "IsAbstract",
    "MinimumSamplingInterval", "NodeClass", "NodeId", "Symmetric", "UserAccessLevel", "UserExecutable",
    "UserWriteMask", "ValueRank", "WriteMask", "UserWriteMask", "DataTypeDefinition", "Value",
)  # fmt: skip
_RANKS: dict[int, int] = {}  # AttributeIds value -> position in a node's dict as asyncua fills it


def _rank(key: Any) -> int:
    if not _RANKS:
        from asyncua import ua

        for name in ("NodeId", "BrowseName", "NodeClass", *ATTRIBUTE_ORDER):
            _RANKS.setdefault(int(getattr(ua.AttributeIds, name)), len(_RANKS))
    return _RANKS.get(int(key), len(_RANKS))


# asyncua's AttributeIds of the three name records (NodeId, BrowseName, DisplayName), and their types.
_NODE_ID, _BROWSE_NAME, _DISPLAY_NAME = 1, 3, 4
_NAME_TYPES = {_NODE_ID: 17, _BROWSE_NAME: 20, _DISPLAY_NAME: 21}  # VariantType NodeId, QualifiedName, ...


class NodeAttributes(dict[Any, Any]):
    """A node's attribute records: its own in the dict itself, its constant ones in a dict it shares
    with every node of the same shape, and its three name records made when first looked up.

    A variable of ours has fifteen attributes; a dict of fifteen records is about 630 bytes, and the
    three name records 80 bytes apiece: over 10,000 variables, 8 MB for what is mostly the same ten
    shared records in the same order, and names that only a client's Read of those attributes looks at.
    Here the dict holds the Value record (and any other of the node's own), about 200 bytes; a name
    record, once made, stays in the dict (so what asyncua then does to it, a write or a monitored item,
    is kept); a shared record is handed out as it is (asyncua gives the node its own copy before it
    changes one, `slim_attribute_values`). Everything asyncua and the sink do to `node.attributes`
    works as on a dict: `[]`, `in`, `get`, assignment, iteration and `items()` over every attribute.
    """

    __slots__ = ("_browse", "_display", "_nodeid", "_shared")

    def __init__(
        self, own: dict[Any, Any], shared: dict[Any, Any], nodeid: Any, browse: Any, display: Any
    ) -> None:
        super().__init__(own)
        self._shared = shared
        self._nodeid = nodeid
        self._browse = browse
        self._display = display  # None: the node's DisplayName record is its own, in the dict

    def _name(self, key: Any) -> Any:
        held = self._nodeid if key == _NODE_ID else self._browse if key == _BROWSE_NAME else None
        if key == _DISPLAY_NAME:
            held = self._display
        return held

    def __missing__(self, key: Any) -> Any:
        held = self._name(key)
        if held is not None:
            record = NameAttributeValue(held, _name_type(key))
            self[key] = record
            return record
        return self._shared[key]

    def __contains__(self, key: object) -> bool:
        return dict.__contains__(self, key) or key in self._shared or self._name(key) is not None

    def get(self, key: Any, default: Any = None) -> Any:
        try:
            return self[key]
        except KeyError:
            return default

    def _merged(self) -> dict[Any, Any]:
        """Every attribute's record, as asyncua's own dict would hold them (name records made afresh)."""
        merged = dict(self._shared)
        for key in (_NODE_ID, _BROWSE_NAME, _DISPLAY_NAME):
            held = self._name(key)
            if held is not None:
                merged[key] = NameAttributeValue(held, _name_type(key))
        merged.update(dict.items(self))
        return dict(sorted(merged.items(), key=lambda pair: _rank(pair[0])))

    def __iter__(self) -> Iterator[Any]:
        return iter(self._merged())

    def __len__(self) -> int:
        return len(self._merged())

    def keys(self) -> Any:
        return self._merged().keys()

    def values(self) -> Any:
        return self._merged().values()

    def items(self) -> Any:
        return self._merged().items()

    def __eq__(self, other: object) -> bool:
        return self._merged() == (other._merged() if isinstance(other, NodeAttributes) else other)

    __hash__ = None

    def __reduce__(self) -> Any:
        return (dict, (list(self._merged().items()),))

    def __repr__(self) -> str:
        return repr(self._merged())


def _name_type(key: Any) -> Any:
    from asyncua import ua

    return ua.VariantType(_NAME_TYPES[int(key)])


def _own(space: Any, nodeid: Any, attr: Any) -> None:
    """Give the node its own record of `attr` if it shares one (copy on write)."""
    node = space._nodes.get(nodeid)
    held = node.attributes.get(attr) if node is not None else None
    if type(held) is SharedAttributeValue:
        node.attributes[attr] = SlimAttributeValue(held.value)


def slim_attribute_values() -> None:
    """Make asyncua build SlimAttributeValues from now on, and copy SharedAttributeValues on write
    (once per process; before `Server.init`).

    Process-wide, like `keep_written_values`: asyncua creates every AttributeValue in
    one module (`asyncua.server.address_space`), by the name looked up at call time.
    The wrappers add a call and a type check to asyncua's, nothing more; the one on the
    hot path, `write_attribute_value`, skips even that for Value records (never shared),
    and returns asyncua's own coroutine (no extra frame).
    """
    from asyncua import ua
    from asyncua.server import address_space

    space = address_space.AddressSpace
    if getattr(space, _SLIM_MARK, False):
        return
    add_callback = space.add_datachange_callback
    write = space.write_attribute_value
    set_callback = space.set_attribute_value_callback
    set_setter = space.set_attribute_value_setter
    value_attribute = ua.AttributeIds.Value

    def add_datachange_callback(self: Any, nodeid: Any, attr: Any, callback: Any) -> Any:
        _own(self, nodeid, attr)
        node = self._nodes.get(nodeid)
        held = node.attributes.get(attr) if node is not None else None
        if held is not None and held.datachange_callbacks is NO_CALLBACKS:
            held.datachange_callbacks = {}
        return add_callback(self, nodeid, attr, callback)

    def write_attribute_value(self: Any, nodeid: Any, attr: Any, value: Any) -> Any:
        if attr != value_attribute:
            _own(self, nodeid, attr)
        return write(self, nodeid, attr, value)

    def set_attribute_value_callback(self: Any, nodeid: Any, attr: Any, callback: Any) -> Any:
        _own(self, nodeid, attr)
        return set_callback(self, nodeid, attr, callback)

    def set_attribute_value_setter(self: Any, nodeid: Any, attr: Any, setter: Any) -> Any:
        _own(self, nodeid, attr)
        return set_setter(self, nodeid, attr, setter)

    space.add_datachange_callback = add_datachange_callback  # type: ignore[method-assign]
    space.write_attribute_value = write_attribute_value  # type: ignore[method-assign]
    space.set_attribute_value_callback = set_attribute_value_callback  # type: ignore[method-assign]
    space.set_attribute_value_setter = set_attribute_value_setter  # type: ignore[method-assign]
    address_space.AttributeValue = SlimAttributeValue  # type: ignore[misc,assignment]
    setattr(space, _SLIM_MARK, True)


_FORGET_MARK = "_cnc_gateway_forgets_fill_code"
_FILL_PACKAGE = "asyncua.server.standard_address_space"


class _Fills:
    running = 0  # standard-namespace loads in progress in this process


def forget_standard_namespace_code() -> None:
    """Drop the code that builds asyncua's standard namespace once it has run (install once per process).

    The standard namespace is built by 25 generated modules of straight-line calls,
    about 12 MB of code objects that stay imported for the life of the process and
    never run again. After each `InternalServer.load_standard_address_space`, unless
    another one is still running, the package is taken out of `sys.modules` and its
    modules' dicts cleared, which frees the code at once (no cyclic collection
    needed); the next server to start imports it again from the bytecode cache,
    in a few hundredths of a second. The nodes it built are plain data and stay.
    """
    from asyncua.server.internal_server import InternalServer

    if getattr(InternalServer, _FORGET_MARK, False):
        return
    load = InternalServer.load_standard_address_space

    async def load_standard_address_space(self: Any, shelf_file: Any = None) -> None:
        _Fills.running += 1
        try:
            await load(self, shelf_file)
        finally:
            _Fills.running -= 1
            if _Fills.running == 0:
                _drop_fill_code()

    InternalServer.load_standard_address_space = load_standard_address_space  # type: ignore[method-assign]
    setattr(InternalServer, _FORGET_MARK, True)


def _drop_fill_code() -> None:
    names = [name for name in sys.modules if name == _FILL_PACKAGE or name.startswith(_FILL_PACKAGE + ".")]
    modules = [sys.modules.pop(name) for name in names]
    parent = sys.modules.get(_FILL_PACKAGE.rpartition(".")[0])
    if parent is not None and "standard_address_space" in vars(parent):
        delattr(parent, "standard_address_space")
    for module in modules:
        vars(module).clear()  # functions and their module dicts refer to each other: break it now
