"""A machine's connection status, published through the tree like any variable.

Because the status lives in ordinary (gateway-owned) variables under `Status/`,
every sink shows it without special code: OPC UA as the machine's Status object,
MQTT as topics.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, Generic, Protocol, TypeVar

from gateway.model.sample import Sample


class _Holder(Protocol):
    """A variable, as far as the status needs one: its latest sample."""

    @property
    def sample(self) -> Sample: ...


N = TypeVar("N", bound=_Holder)


class StatusOwner(Protocol[N]):
    """What the status needs from its machine (gateway/model/tree.py `Machine`): its own variables."""

    def add_internal(self, path: str, type_name: str, description: str, value: Any) -> N: ...

    def set_internal(self, node: N, value: Any) -> None: ...


# The status of a standby machine's values (another shard serves it): OPC UA shows them Bad with it; the MQTT
# and Sparkplug faces never publish a sample that carries it, even one queued before the machine was served.
STANDBY_STATUS = "BadOutOfService"


class MachineStatus(Generic[N]):
    CONNECTED = "connected"
    CONNECTING = "connecting"
    DISCONNECTED = "disconnected"
    STANDBY = "standby"  # another shard of the fleet serves the machine (shard: lease)

    def __init__(self, machine: StatusOwner[N], endpoint: str) -> None:
        self.machine = machine
        add = machine.add_internal
        self.connected_node = add(
            "Status/Connected", "Boolean", "True while the controller connection is up", False
        )
        self.state_node = add(
            "Status/State",
            "String",
            "connected, connecting, disconnected, or standby (another shard serves it)",
            self.DISCONNECTED,
        )
        self.last_error_node = add(
            "Status/LastError", "String", "The most recent connection or driver error", ""
        )
        self.reconnects_node = add(
            "Status/ReconnectCount", "UInt32", "How many times the connection was re-established", 0
        )
        self.last_change_node = add(
            "Status/LastChange",
            "DateTime",
            "Source time of the latest value change (updated at most once a second)",
            datetime(1601, 1, 1, tzinfo=UTC),
        )
        self.endpoint_node = add("Status/Endpoint", "String", "The controller address", endpoint)
        self._ever_connected = False

    @property
    def is_connected(self) -> bool:
        return bool(self.connected_node.sample.value)

    @property
    def state(self) -> str:
        return str(self.state_node.sample.value)

    @property
    def last_error(self) -> str:
        return str(self.last_error_node.sample.value)

    @property
    def reconnects(self) -> int:
        return int(self.reconnects_node.sample.value)

    def connecting(self) -> None:
        self.machine.set_internal(self.state_node, self.CONNECTING)

    def connected(self) -> None:
        m = self.machine
        if self._ever_connected:
            m.set_internal(self.reconnects_node, self.reconnects + 1)
        self._ever_connected = True
        m.set_internal(self.connected_node, True)
        m.set_internal(self.state_node, self.CONNECTED)

    def disconnected(self, reason: str) -> None:
        m = self.machine
        m.set_internal(self.last_error_node, reason)
        m.set_internal(self.connected_node, False)
        m.set_internal(self.state_node, self.DISCONNECTED)

    def standby(self, reason: str) -> None:
        """Not served by this process: another shard of the fleet holds the machine's lease."""
        m = self.machine
        m.set_internal(self.last_error_node, reason)
        m.set_internal(self.connected_node, False)
        m.set_internal(self.state_node, self.STANDBY)

    def error(self, reason: str) -> None:
        """A problem that does not drop the connection (a bad node, a refused write)."""
        self.machine.set_internal(self.last_error_node, reason)

    def changed(self, source_ts: datetime) -> None:
        self.machine.set_internal(self.last_change_node, source_ts)
