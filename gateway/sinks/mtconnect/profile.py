"""The tree as MTConnect devices: one Device per machine, its components and data items, and how values map.

Built once when the sink is made, from the machines' definitions and their mappings'
`mtconnect:` keys (gateway/sinks/mtconnect/config.py):

- each machine is a Device (`uuid` urn:cnc-gateway:<machine>) with an AVAILABILITY item
  (from `Status/Connected`), a SYSTEM condition on its Controller when it has alarms, and
  ASSET_CHANGED/ASSET_REMOVED when it has a job queue (programs are File assets);
- a variable with an `mtconnect:` key is a data item of that category and type, in the
  component its `component:` steps name (`Axes/Linear[X]`: an Axes organizer, a Linear
  named X in it); a SAMPLE's units default to the standard's for the variable's `unit`
  (mm/min is reported in MILLIMETER/SECOND, nativeUnits MILLIMETER/MINUTE, value / 60);
- a variable without one is an EVENT VARIABLE named by its path (or left out: `unmapped: omit`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from gateway.codecs.mtconnect.model import Category, Component, DataItem, Description, Device, Representation
from gateway.codecs.mtconnect.units import factor, native_units, standard_units
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.settings.mtconnect import VariableMTConnect
from gateway.sinks.mtconnect.config import AgentConfig, AgentMachineEntry

UUID_PREFIX = "urn:cnc-gateway:"
_NOT_ID = re.compile(r"[^A-Za-z0-9_.\-]")
_STEP = re.compile(r"^(?P<type>[^\[]+)(?:\[(?P<name>[^\]]+)\])?$")


def ncname(text: str) -> str:
    """`text` made an XML id: invalid characters to `_`, and `_` first if it does not start with a letter."""
    out = _NOT_ID.sub("_", text)
    return out if out[:1].isalpha() or out[:1] == "_" else f"_{out}"


@dataclass(frozen=True, slots=True)
class Binding:
    """How one variable's samples become observations of its data item."""

    item_id: str
    category: Category
    values: Mapping[str, str] | None = None
    scale: float = 1.0
    offset: float = 0.0

    @property
    def converts(self) -> bool:
        return self.scale != 1.0 or self.offset != 0.0


@dataclass(slots=True)
class DeviceItems:
    """One machine's own data items (besides its variables')."""

    machine: str
    device: Device
    availability: str
    system: str | None = None  # the SYSTEM condition the gateway's alarms go to
    asset_changed: str | None = None
    asset_removed: str | None = None
    item_ids: list[str] = field(default_factory=list)  # every data item of the device


@dataclass(slots=True)
class Profile:
    devices: list[Device]
    machines: dict[str, DeviceItems]  # by machine name
    bindings: dict[VariableNode, Binding]
    connected: dict[VariableNode, str]  # Status/Connected node -> machine name


@dataclass(slots=True)
class _Tree:
    """A component being assembled: its data items and children, by step."""

    type: str
    id: str
    name: str | None
    items: list[DataItem] = field(default_factory=list)
    children: dict[str, _Tree] = field(default_factory=dict)

    def child(self, step: str, prefix: str) -> _Tree:
        found = self.children.get(step)
        if found is None:
            m = _STEP.match(step)
            assert m is not None  # the config checked the steps
            kind, name = m.group("type"), m.group("name")
            ident = ncname(f"{prefix}_{kind.rpartition(':')[2].lower()}" + (f"_{name}" if name else ""))
            found = self.children[step] = _Tree(kind, ident, name)
        return found

    def component(self) -> Component:
        return Component(
            type=self.type,
            id=self.id,
            name=self.name,
            data_items=tuple(self.items),
            components=tuple(c.component() for c in self.children.values()),
        )


def build_profile(
    tree: VariableTree, mappings: Mapping[str, AgentMachineEntry], config: AgentConfig
) -> Profile:
    devices: list[Device] = []
    machines: dict[str, DeviceItems] = {}
    bindings: dict[VariableNode, Binding] = {}
    connected: dict[VariableNode, str] = {}
    for name, machine in tree.machines.items():
        mapping = mappings.get(name)
        device, items, machine_bindings = _device(machine, mapping, config)
        devices.append(device)
        machines[name] = items
        bindings.update(machine_bindings)
        connected[machine.status.connected_node] = name
    return Profile(devices, machines, bindings, connected)


def _device(
    machine: Machine, mapping: AgentMachineEntry | None, config: AgentConfig
) -> tuple[Device, DeviceItems, dict[VariableNode, Binding]]:
    dev_id = ncname(machine.name)
    root = _Tree("Device", dev_id, machine.name)
    bindings: dict[VariableNode, Binding] = {}
    availability = f"{dev_id}_avail"
    root.items.append(DataItem(availability, Category.EVENT, "AVAILABILITY", name="avail"))
    asset_changed = asset_removed = None
    if mapping is not None and mapping.jobs is not None:
        asset_changed, asset_removed = f"{dev_id}_asset_chg", f"{dev_id}_asset_rem"
        root.items.append(DataItem(asset_changed, Category.EVENT, "ASSET_CHANGED", discrete=True))
        root.items.append(DataItem(asset_removed, Category.EVENT, "ASSET_REMOVED", discrete=True))
    specs = {v.path: v for v in mapping.variables} if mapping is not None else {}
    for node in machine.mapped:
        spec = specs.get(node.path)
        settings = spec.mtconnect if spec is not None else None
        if settings is None:
            if config.unmapped == "omit":
                continue
            item_id = ncname(f"{dev_id}.{node.path.replace('/', '.')}")
            root.items.append(DataItem(item_id, Category.EVENT, "VARIABLE", name=node.path))
            bindings[node] = Binding(item_id, Category.EVENT)
            continue
        item, binding = _item(dev_id, node, settings)
        target = root
        if settings.component:
            for step in settings.component.split("/"):
                target = target.child(step, target.id)
        target.items.append(item)
        bindings[node] = binding
    system = None
    if mapping is not None and mapping.alarms is not None and mapping.alarms.source.type != "conditions":
        # (alarms that are MTConnect conditions already are CONDITION items of their own)
        system = f"{dev_id}_system"
        controller = root.child("Controller", dev_id)
        controller.items.append(DataItem(system, Category.CONDITION, "SYSTEM", name="system"))
    description = (
        Description(text=mapping.description) if mapping is not None and mapping.description else None
    )
    device = Device(
        id=dev_id,
        name=machine.name,
        uuid=f"{UUID_PREFIX}{machine.name}",
        description=description,
        data_items=tuple(root.items),
        components=tuple(c.component() for c in root.children.values()),
    )
    items = DeviceItems(machine.name, device, availability, system, asset_changed, asset_removed)
    return device, items, bindings


def _item(dev_id: str, node: VariableNode, s: VariableMTConnect) -> tuple[DataItem, Binding]:
    category = Category(s.category)
    item_id = s.id or ncname(f"{dev_id}.{node.path.replace('/', '.')}")
    units = native = None
    scale, offset = 1.0, 0.0
    if category is Category.SAMPLE:
        native = s.native_units or native_units(node.definition.unit)
        units = s.units or (standard_units(native) if native is not None else None)
        scale, offset = factor(native, units)
        if native == units:
            native = s.native_units
    elif s.units is not None:
        units = s.units
        native = s.native_units
    item = DataItem(
        id=item_id,
        category=category,
        type=s.type,
        name=s.name,
        sub_type=s.sub_type,
        units=units,
        native_units=native,
        significant_digits=s.significant_digits,
        coordinate_system=s.coordinate_system,
        discrete=s.discrete,
        representation=Representation(s.representation),
    )
    return item, Binding(item_id, category, s.values, scale, offset)
