"""The umati view's live values and notifications, through a real client, with the simulator running.

A umati node bound to a variable carries the very sample of the gateway's own node (same value, same
SourceTimestamp, in the same notification round); its own nodes are read-only, so a write there is
refused and the machine does not move; and when the simulator raises an alarm, Notification/Messages
reports a NotificationEventType event, while ActiveProgram's state machine follows the program.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.sinks.opcua.umati.install import MACHINE_TOOL
from tests.integration.alarms.test_alarms import SOFT_LIMIT, raise_soft_limit
from tests.integration.laser_rig import MACHINE, laser_rig
from tests.opcua_client import Client
from tests.waiting import wait_until

UMATI = f"ns=2;s=umati:{MACHINE}"


class Changes:
    """An asyncua subscription handler that records every DataValue per node."""

    def __init__(self) -> None:
        self.seen: dict[str, list[ua.DataValue]] = {}
        self.events: list[Any] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.seen.setdefault(node.nodeid.to_string(), []).append(data.monitored_item.Value)

    def event_notification(self, event: Any) -> None:
        self.events.append(event)

    def values(self, nodeid: str) -> list[Any]:
        return [dv.Value.Value for dv in self.seen.get(nodeid, [])]


async def test_a_umati_node_carries_the_same_sample_as_the_gateways_own_node(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        changes = Changes()
        sub = await client.create_subscription(20, changes)
        own = f"ns=2;s={MACHINE}/Feed/Override"
        umati = f"{UMATI}/Monitoring/Channel1/FeedOverride"
        await sub.subscribe_data_change([client.get_node(own), client.get_node(umati)], queuesize=10)
        await client.get_node(own).write_value(ua.Variant(87, ua.VariantType.UInt16))

        def both() -> bool:
            return 87 in changes.values(own) and 87.0 in changes.values(umati)

        await wait_until(both, timeout=10, message="Feed/Override 87 at both nodes")
        [at_own] = [dv for dv in changes.seen[own] if dv.Value.Value == 87]
        [at_umati] = [dv for dv in changes.seen[umati] if dv.Value.Value == 87.0]
        assert at_umati.Value.VariantType is ua.VariantType.Double  # the NodeSet's DataType, not UInt16
        assert at_umati.SourceTimestamp == at_own.SourceTimestamp
        assert at_umati.SourceTimestamp == rig.machine.nodes["Feed/Override"].sample.source_ts
        # A read without a subscription answers the same sample too.
        read = await client.get_node(umati).read_data_value()
        assert read.Value.Value == 87.0 and read.SourceTimestamp == at_own.SourceTimestamp


async def test_umati_nodes_are_read_only_and_a_write_leaves_the_machine_alone(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        node = client.get_node(f"{UMATI}/Monitoring/Channel1/FeedOverride")
        level = await node.read_attribute(ua.AttributeIds.UserAccessLevel)
        assert level.Value.Value == ua.AccessLevel.CurrentRead.mask
        before = rig.machine.nodes["Feed/Override"].sample.value
        with pytest.raises(ua.UaStatusCodeError) as info:
            await node.write_value(ua.Variant(42.0, ua.VariantType.Double))
        assert info.value.code in (ua.StatusCodes.BadNotWritable, ua.StatusCodes.BadUserAccessDenied)
        assert rig.machine.nodes["Feed/Override"].sample.value == before


async def test_an_alarm_is_a_notification_event_and_the_program_state_follows(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        uris = await client.get_namespace_array()
        mt = uris.index(MACHINE_TOOL)
        changes = Changes()
        sub = await client.create_subscription(20, changes)
        messages = client.get_node(f"{UMATI}/Notification/Messages")
        await sub.subscribe_events(messages, client.get_node(ua.NodeId(35, mt)))  # NotificationEventType
        current = f"{UMATI}/Production/ActiveProgram/State/CurrentState"
        channel = f"{UMATI}/Monitoring/Channel1/ChannelState"
        await sub.subscribe_data_change([client.get_node(current), client.get_node(channel)], queuesize=20)
        await raise_soft_limit(rig, client)
        await wait_until(lambda: changes.events, timeout=10, message="the NotificationEventType event")
        [event] = changes.events
        assert event.EventType == ua.NodeId(35, mt)
        assert event.Identifier == "1001" and event.Message.Text == SOFT_LIMIT and event.Severity == 700
        assert event.SourceName == MACHINE
        await wait_until(
            lambda: "Aborted" in [t.Text for t in changes.values(current)], timeout=10, message="Aborted"
        )
        states = [text.Text for text in changes.values(current)]
        assert states[0] == "Ended" and "Running" in states and states[-1] == "Aborted"
        assert 0 in changes.values(channel)  # ChannelState Active while the program ran


async def test_client_finds_the_machine_tool_the_standard_way(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client: Client = await rig.client()
        identification = client.get_node(f"{UMATI}/Identification")
        serial = await identification.get_child(
            [f"{await client.get_namespace_index('http://opcfoundation.org/UA/DI/')}:SerialNumber"]
        )
        assert await serial.read_value() == "LS-SIM-0001"


async def test_feed_override_is_in_percent_within_the_variables_range(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        base = f"{UMATI}/Monitoring/Channel1/FeedOverride"
        units = await client.get_node(f"{base}/EngineeringUnits").read_value()
        limits = await client.get_node(f"{base}/EURange").read_value()
        assert units.UnitId == int.from_bytes(b"P1", "big") and units.DisplayName.Text == "%"
        assert (limits.Low, limits.High) == (0, 150)  # Feed/Override's range in laser-sim.yaml
