"""Per-variable MQTT settings, resolved once: topic, QoS, retain, payload form, writes allowed.

The hot path looks a variable up in one dict and finds everything it needs in
one `Route`; nothing is resolved per message. Precedence for each setting:
the variable's `mqtt:` entry, then the machine's `mqtt:`, then the gateway
file's `mqtt:`. A machine's gateway-owned `Status/*` variables are not routed
one by one: they make up the machine's status document (`status.py`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping

from gateway.codecs.mqtt_publish import first_byte, qos1_first_byte, topic_field, topic_head
from gateway.model.tree import Machine, VariableNode, VariableTree
from gateway.shards.identity import shard_index
from gateway.sinks.mqtt.config import (
    MachineMqtt,
    MqttConfig,
    MqttMachineEntry,
    MqttVariableEntry,
    VariableMqtt,
)
from gateway.sinks.mqtt.payloads import unit_suffix
from gateway.sinks.mqtt.topics import (
    TopicClash,
    gateway_status_topic,
    machine_status_topic,
    topic_depth,
    variable_topic,
)

STATUS_PREFIX = "Status/"


class Route:
    """Where and how one variable is published."""

    __slots__ = (
        "field",
        "first",
        "head",
        "latest_only",
        "machine",
        "node",
        "qos",
        "raw",
        "retain",
        "suffix",
        "topic",
        "writable",
    )

    def __init__(
        self,
        node: VariableNode,
        topic: str,
        qos: int,
        retain: bool,
        raw: bool,
        writable: bool,
        *,
        v5: bool = False,
    ) -> None:
        self.node = node
        self.topic = topic
        self.qos = qos
        self.retain = retain
        self.raw = raw
        self.suffix = unit_suffix(node.definition.unit)
        self.machine = node.machine.name
        self.writable = writable
        # Retained state at QoS 0 promises no history: keep only the newest while the broker is away.
        self.latest_only = qos == 0 and retain
        # QoS 0 changes go out as pre-encoded PUBLISH packets (gateway/codecs/mqtt_publish.py): the constant
        # parts, once per variable.
        self.first = first_byte(retain) if qos == 0 else qos1_first_byte(retain)
        self.field = b""  # empty: through paho's publish(), which says what is wrong with the topic
        self.head = b""  # QoS 1: the topic with its length, the packet id goes after it
        if qos == 0:
            with contextlib.suppress(ValueError):
                self.field = topic_field(topic, v5=v5)
        elif qos == 1:
            with contextlib.suppress(ValueError):
                self.head = topic_head(topic)

    def __repr__(self) -> str:
        return f"<Route {self.topic} q{self.qos}{' r' if self.retain else ''}{' w' if self.writable else ''}>"


def is_status_node(node: VariableNode) -> bool:
    return node.internal and node.path.startswith(STATUS_PREFIX)


def route_for(
    node: VariableNode, cfg: MqttConfig, machine: MachineMqtt | None = None, var: VariableMqtt | None = None
) -> Route | None:
    """The node's route, or None when the mapping keeps it out of MQTT.

    `machine` and `var` are the machine's and the variable's `mqtt:` sections (None: not given)."""
    spec = node.definition
    if var is not None and not var.publish:
        return None

    def pick(name: str) -> object:
        for source in (var, machine):
            value = getattr(source, name, None) if source is not None else None
            if value is not None:
                return value
        return getattr(cfg, name)

    qos = int(pick("qos"))  # type: ignore[call-overload]
    retain = bool(pick("retain"))
    raw = pick("payload") == "raw"
    writable = False
    if spec.writable and not node.internal:
        if var is not None and var.writable is not None:
            writable = var.writable
        elif machine is not None:
            writable = machine.writable
    topic = variable_topic(cfg.prefix, node.machine.name, node.path, var.topic if var is not None else None)
    return Route(node, topic, qos, retain, raw, writable, v5=cfg.protocol == "5")


class Routes:
    """Every variable's route, indexed both ways, checked for topics claimed twice."""

    def __init__(self, tree: VariableTree, cfg: MqttConfig, mappings: Mapping[str, MqttMachineEntry]) -> None:
        self.cfg = cfg
        self.mappings = mappings
        self._specs: dict[tuple[str, str], MqttVariableEntry] = {
            (name, v.path): v for name, mapping in mappings.items() for v in mapping.variables
        }
        self.by_node: dict[VariableNode, Route] = {}
        self.by_topic: dict[str, Route] = {}
        self.unrouted: set[VariableNode] = set()
        self.status_topic = gateway_status_topic(cfg.prefix, shard_index())
        self.machine_status: dict[str, str] = {
            name: machine_status_topic(cfg.prefix, name) for name in tree.machines
        }
        self._claimed: dict[str, str] = {self.status_topic: "the gateway's status topic"}
        for name, topic in self.machine_status.items():
            self._claim(topic, f"{name}'s status topic")
        for node in tree.nodes():
            self.add(node)

    def _claim(self, topic: str, who: str) -> None:
        first = self._claimed.get(topic)
        if first is not None:
            raise TopicClash(
                f"{who} and {first} would both publish to {topic!r}; give one of them an mqtt.topic"
            )
        self._claimed[topic] = who

    def add(self, node: VariableNode) -> Route | None:
        """Route a node (also one that appears after start-up). Raises TopicClash."""
        if is_status_node(node):
            self.unrouted.add(node)
            return None
        mapping = self.mappings.get(node.machine.name)
        spec = None if node.internal else self._specs.get((node.machine.name, node.path))
        machine_mqtt = mapping.mqtt if mapping is not None else None
        route = route_for(node, self.cfg, machine_mqtt, spec.mqtt if spec is not None else None)
        if route is None:
            self.unrouted.add(node)
            return None
        self._claim(route.topic, node.full_path)
        self.by_node[node] = route
        self.by_topic[route.topic] = route
        return route

    def add_machine(self, machine: Machine) -> None:
        topic = machine_status_topic(self.cfg.prefix, machine.name)
        self._claim(topic, f"{machine.name}'s status topic")
        self.machine_status[machine.name] = topic

    def depths(self) -> Iterable[int]:
        """Topic depths below `<prefix>/<machine>/` for the `/set` subscriptions: every depth up to the
        deepest topic, so that a write to a topic that maps to nothing is answered too."""
        deepest = max((topic_depth(topic, self.cfg.prefix) for topic in self.by_topic), default=1)
        return range(1, deepest + 1)
