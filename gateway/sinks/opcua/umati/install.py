"""The umati view installed in the gateway's OPC UA server (a ServerExtension, port.py).

It loads the official NodeSets (nodesets/, in their import order), then plans each machine's MachineTool
instance under the Machinery `Machines` folder (instance.py), adds it, and fills it: constants are
written once; every node bound to a variable is served through `ServerPort.show`, so that it carries the
very sample the gateway's own node carries (same value, same source timestamp, in the same publish
step), translated to the umati type (values.py). The machine's alarms, when it has some, are reported
as NotificationEventType events through Notification/Messages, beside the AlarmCondition events.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from asyncua import ua

from gateway.alarms.records import AlarmChange, Kind
from gateway.alarms.service import AlarmService
from gateway.errors import SinkError
from gateway.model.tree import VariableTree
from gateway.shims.ua import new_node_id
from gateway.sinks.opcua.conditions import SERVER, emitted_by
from gateway.sinks.opcua.port import ServerPort
from gateway.sinks.opcua.umati.bindings import bindings
from gateway.sinks.opcua.umati.config import Binding, UmatiView
from gateway.sinks.opcua.umati.events import notification_event
from gateway.sinks.opcua.umati.instance import InstancePlan
from gateway.sinks.opcua.umati.model import TypeModel
from gateway.sinks.opcua.umati.values import Converted, constant_variant, states
from gateway.sinks.opcua.values import eu_information

log = logging.getLogger(__name__)

MACHINERY = "http://opcfoundation.org/UA/Machinery/"
MACHINE_TOOL = "http://opcfoundation.org/UA/MachineTool/"
# The NodeSet2 files, in import order (each after the models it requires).
NODESET_FILES = (
    "Opc.Ua.Di.NodeSet2.xml",
    "Opc.Ua.IA.NodeSet2.xml",
    "Opc.Ua.Machinery.NodeSet2.xml",
    "opc.ua.isa95-jobcontrol.nodeset2.xml",
    "Opc.Ua.Machinery.Jobs.Nodeset2.xml",
    "Opc.Ua.MachineTool.NodeSet2.xml",
)
MACHINES_FOLDER = 1001  # Machinery: Objects/Machines
MACHINE_TOOL_TYPE = 13
CHANNEL_MONITORING_TYPE = 16
LASER_MONITORING_TYPE = 36
SPINDLE_MONITORING_TYPE = 22
PROGRAM_STATE_MACHINE_TYPE = 15
SOFTWARE_TYPE = 43


def nodeset_paths() -> list[Path]:
    folder = resources.files("gateway.sinks.opcua.umati") / "nodesets"
    return [Path(str(folder / name)) for name in NODESET_FILES]


class UmatiExtension:
    """Every configured machine as a MachineTool (OPC 40501-1)."""

    def __init__(
        self, machines: Mapping[str, UmatiView], tree: VariableTree, alarms: AlarmService | None
    ) -> None:
        self.machines = machines
        self.tree = tree
        self.alarms = alarms
        self.instances: dict[str, ua.NodeId] = {}

    async def install(self, server: ServerPort) -> None:
        await server.import_nodesets(nodeset_paths())
        mt = server.namespace_of(MACHINE_TOOL)
        machinery = server.namespace_of(MACHINERY)
        if mt < 0 or machinery < 0:
            raise SinkError("the umati view's NodeSets did not load (MachineTool, Machinery namespaces)")
        model = TypeModel(server)
        folder = new_node_id(MACHINES_FOLDER, machinery)
        for name, view in self.machines.items():
            await self._machine(server, model, mt, folder, name, view)

    async def _machine(
        self, server: ServerPort, model: TypeModel, mt: int, folder: ua.NodeId, name: str, view: UmatiView
    ) -> None:
        bound = bindings(view)
        wanted = [b.path for b in bound]
        if view.messages:
            wanted.append("Notification/Messages")
        ns = await server.register_namespace(view.namespace) if view.namespace else server.namespace_index
        plan = InstancePlan(model, server, ns, name, wanted)
        self.instances[name] = plan.root(folder, new_node_id(MACHINE_TOOL_TYPE, mt), name)
        for software in view.software:
            plan.add("Identification/SoftwareIdentification", software.name, new_node_id(SOFTWARE_TYPE, mt))
        for channel in view.channels:
            plan.add("Monitoring", channel.name, new_node_id(CHANNEL_MONITORING_TYPE, mt))
        if view.laser is not None:
            plan.add("Monitoring", view.laser.name, new_node_id(LASER_MONITORING_TYPE, mt))
        for spindle in view.spindles:
            plan.add("Monitoring", spindle.name, new_node_id(SPINDLE_MONITORING_TYPE, mt))
        planned = plan.planned
        await server.add_nodes(planned.items)
        machine = self.tree.machines[name]
        program_states = states(server, new_node_id(PROGRAM_STATE_MACHINE_TYPE, mt))
        for item in bound:
            nodeid = planned.ids.get(item.path)
            if nodeid is None:
                raise SinkError(f"umati: {name}: no node {item.path} in the MachineTool instance")
            data_type = planned.data_types[item.path]
            if isinstance(item.source, Binding):
                node = machine.nodes.get(item.source.variable)
                if node is None:  # a Jobs/ variable of a machine without jobs: (the check lets it pass)
                    log.info(
                        "umati: %s has no %s (no jobs:): %s stays empty",
                        name,
                        item.source.variable,
                        item.path,
                    )
                    continue
                server.show(nodeid, node, Converted.of(data_type, item, program_states))
                await _analog(server, planned.ids, item.path, node.definition.range)
            else:
                await _analog(server, planned.ids, item.path, None)
                await server.set_value(
                    nodeid, ua.DataValue(constant_variant(data_type, item.source, item.enum))
                )
        if view.messages and self.alarms is not None and name in self.alarms.managers:
            messages = planned.ids["Notification/Messages"]
            await server.add_event_notifier(messages)
            self.alarms.managers[name].listen(self._notify(server, messages, name, mt))

    def _notify(
        self, server: ServerPort, messages: ua.NodeId, machine: str, mt: int
    ) -> Callable[[AlarmChange], Awaitable[None]]:
        async def listener(change: AlarmChange) -> None:
            if change.kind is not Kind.RAISED:
                return
            event = notification_event(change.record, messages, machine, new_node_id(35, mt))
            for notifier in (messages, SERVER):
                await server.trigger_event(emitted_by(event, notifier))

        return listener


async def _analog(server: ServerPort, ids: dict[str, ua.NodeId], path: str, bounds: Any) -> None:
    """An override (AnalogUnitRangeType) is in percent; its EURange is the bound variable's range, when the
    mapping gives one (else it stays null: no guess)."""
    units, limits = ids.get(f"{path}/EngineeringUnits"), ids.get(f"{path}/EURange")
    if units is not None:
        value = ua.Variant(eu_information("%"), ua.VariantType.ExtensionObject)
        await server.set_value(units, ua.DataValue(value))
    if limits is not None and bounds is not None:
        value = ua.Variant(ua.Range(Low=bounds.min, High=bounds.max), ua.VariantType.ExtensionObject)
        await server.set_value(limits, ua.DataValue(value))
