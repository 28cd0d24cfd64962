"""Alarms end to end: the simulator raises a soft-limit alarm, an OPC UA client sees and acknowledges
the condition, MQTT carries every transition, a late client gets it through ConditionRefresh, the
acknowledgement survives a gateway restart, and `cnc-gateway alarms list` shows the history."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from asyncua import ua

from gateway.cli.main import main as cli
from simulator.machine import MachineState
from simulator.runner import Simulator
from tests.integration.laser_rig import MACHINE, Events, LaserRig, laser_rig, text
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.opcua_client import Client
from tests.waiting import wait_until

SOFT_LIMIT = "Soft limit X+ exceeded at line 7"
EVENTS = f"cnc/{MACHINE}/alarms/events"
ACTIVE = f"cnc/{MACHINE}/alarms/active"
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
CONFIRM = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm)


async def raise_soft_limit(rig: LaserRig, client: Client) -> None:
    """Select and start soft-limit.nc through the gateway's commands: alarm 1001 at line 7."""
    await rig.command(client, "select-program", text("soft-limit.nc"))
    await rig.command(client, "start")
    await wait_until(lambda: rig.state() is MachineState.ALARM, timeout=15, message="the simulator in Alarm")


async def acknowledge(client: Client, event: Any, comment: str) -> None:
    await client.get_node(event.NodeId).call_method(
        ACK,
        ua.Variant(event.EventId, ua.VariantType.ByteString),
        ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
    )


async def refresh(client: Client, sub: Any) -> None:
    await client.get_node(ua.ObjectIds.ConditionType).call_method(
        ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
        ua.Variant(sub.subscription_id, ua.VariantType.UInt32),
    )


def state(event: Any, name: str) -> Any:
    return getattr(event, f"{name}/Id")


def names(events: Events) -> list[str]:
    kinds = {
        ua.ObjectIds.RefreshStartEventType: "start",
        ua.ObjectIds.RefreshEndEventType: "end",
        ua.ObjectIds.AlarmConditionType: "alarm",
    }
    return [kinds.get(e.EventType.Identifier, "other") for e in events.received]


async def test_soft_limit_alarm_through_opcua_and_mqtt_acknowledged_refreshed_and_cleared(
    tmp_path: Path, mosquitto: Mosquitto, recorders: list[Recorder], capsys: pytest.CaptureFixture[str]
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=[f"cnc/{MACHINE}/alarms/#"])
    async with laser_rig(tmp_path, mqtt=mqtt_config(mosquitto.port)) as rig:
        client = await rig.client()
        _, seen = await rig.subscribe_alarms(client)
        await raise_soft_limit(rig, client)

        await wait_until(seen.alarms, timeout=10, message="the alarm event")
        raised = seen.alarms()[0]
        assert raised.Message.Text == SOFT_LIMIT and raised.Severity == 700  # class 3 (error) mapped to 700
        assert state(raised, "ActiveState") is True and state(raised, "AckedState") is False
        assert raised.Retain is True and raised.ConditionName == "1001" and raised.SourceName == MACHINE
        assert raised.NodeId.Identifier.startswith(f"{MACHINE}/Alarms/")

        await wait_until(lambda: rec.last_json(ACTIVE), message="the active list on MQTT")
        [active] = rec.last_json(ACTIVE)
        assert (active["id"], active["text"], active["severity"], active["active"]) == (
            "1001",
            SOFT_LIMIT,
            700,
            True,
        )
        [raised_msg] = [m for m in rec.on(EVENTS) if m.json()["event"] == "raised"]
        assert raised_msg.qos == 1 and not raised_msg.retain

        # A client that connects late, on the machine's own notifier, asks for the conditions in force.
        late = await rig.client()
        sub, late_seen = await rig.subscribe_alarms(late, ua.NodeId(MACHINE, 2))
        await refresh(late, sub)
        await wait_until(lambda: "end" in names(late_seen), message="RefreshEndEvent")
        assert names(late_seen) == ["start", "alarm", "end"]
        refreshed = late_seen.alarms()[0]
        assert refreshed.NodeId == raised.NodeId and state(refreshed, "ActiveState") is True

        # The late client acknowledges with the EventId it was given; everyone hears of it.
        await acknowledge(late, refreshed, "operator saw it")
        await wait_until(lambda: len(seen.alarms()) >= 2, message="the acknowledge event")
        acked = seen.alarms()[-1]
        assert state(acked, "AckedState") is True and acked.Comment.Text == "operator saw it"
        assert state(acked, "ActiveState") is True and acked.Retain is True
        await wait_until(lambda: any(m.json()["event"] == "acknowledged" for m in rec.on(EVENTS)))
        [ack_msg] = [m.json() for m in rec.on(EVENTS) if m.json()["event"] == "acknowledged"]
        assert (
            ack_msg["comment"] == "operator saw it" and ack_msg["acked"] is True and ack_msg["id"] == "1001"
        )
        await wait_until(lambda: (rec.last_json(ACTIVE) or [{}])[0].get("acked") is True)

        with pytest.raises(ua.UaStatusCodeError) as info:
            await acknowledge(client, acked, "again")
        assert type(info.value).__name__ == "BadConditionBranchAlreadyAcked"
        with pytest.raises(ua.UaStatusCodeError) as info:
            await acknowledge(client, SimpleNamespace(NodeId=raised.NodeId, EventId=b"not-ours"), "x")
        assert type(info.value).__name__ == "BadEventIdUnknown"

        # A dashboard that subscribes now gets the retained list at once.
        later = subscriber(recorders, mosquitto.port, topics=[ACTIVE])
        await wait_until(lambda: later.last(ACTIVE), message="the retained active list")
        assert later.last(ACTIVE).retain

        # Reset clears it: inactive, and since it was acknowledged, no longer retained.
        await rig.command(client, "reset")
        await wait_until(lambda: len(seen.alarms()) >= 3, message="the clear event")
        cleared = seen.alarms()[-1]
        assert state(cleared, "ActiveState") is False and cleared.Retain is False
        await wait_until(lambda: rec.last_json(ACTIVE) == [], message="an empty active list")
        assert [m.json()["event"] for m in rec.on(EVENTS)] == ["raised", "acknowledged", "cleared"]

        # The history, from the state directory.
        state_dir = rig.config.state_dir
    assert cli(["alarms", "list", "--state-dir", str(state_dir), "--machine", MACHINE, "--since", "1h"]) == 0
    out = capsys.readouterr().out
    assert "1001" in out and SOFT_LIMIT in out and "(opcua)" in out
    assert cli(["alarms", "list", "--state-dir", str(state_dir), "--active"]) == 0
    assert "no alarms" in capsys.readouterr().out


async def test_acknowledgement_survives_a_gateway_restart_and_confirm_ends_it(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        _, seen = await rig.subscribe_alarms(client)
        await raise_soft_limit(rig, client)
        await wait_until(seen.alarms, message="the alarm event")
        first = seen.alarms()[0]
        await acknowledge(client, first, "seen before the restart")
        await wait_until(lambda: len(seen.alarms()) >= 2, message="the acknowledge event")

        await rig.stop_gateway()  # the simulator stays in Alarm
        await rig.start_gateway()

        client = await rig.client()
        sub, seen = await rig.subscribe_alarms(client)
        await refresh(client, sub)
        await wait_until(lambda: "end" in names(seen), message="RefreshEndEvent")
        # The refresh brings the occurrence back (a reconnect of the gateway's driver under load may add
        # an event of the same occurrence, which is fine): one condition, the same one as before.
        alarms = seen.alarms()
        assert alarms and {a.NodeId for a in alarms} == {first.NodeId}  # the same occurrence
        again = alarms[-1]
        assert state(again, "AckedState") is True and again.Comment.Text == "seen before the restart"
        assert state(again, "ActiveState") is True
        with pytest.raises(ua.UaStatusCodeError) as info:
            await acknowledge(client, again, "twice")
        assert type(info.value).__name__ == "BadConditionBranchAlreadyAcked"

        await client.get_node(again.NodeId).call_method(
            CONFIRM,
            ua.Variant(again.EventId, ua.VariantType.ByteString),
            ua.Variant(ua.LocalizedText("fixed")),
        )
        await wait_until(
            lambda: any(state(e, "ConfirmedState") for e in seen.alarms()), message="the confirm event"
        )
        [record] = rig.gateway.alarms.store.history(MACHINE)  # type: ignore[union-attr]
        assert record.acked_by == "anonymous (opcua)" and record.confirm_comment == "fixed"


async def test_a_controller_outage_keeps_the_alarm_uncertain_and_reconnecting_reconciles(
    tmp_path: Path,
) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        _, seen = await rig.subscribe_alarms(client)
        await raise_soft_limit(rig, client)
        await wait_until(seen.alarms, message="the alarm event")
        ports = (rig.sim.opcua_port, rig.sim.ftp_port)
        await rig.sim.__aexit__(None, None, None)

        def uncertain() -> bool:
            last = seen.alarms()[-1]
            return last.Quality == ua.StatusCode(ua.StatusCodes.UncertainLastUsableValue)

        await wait_until(uncertain, timeout=10, message="the alarm turning uncertain")
        assert state(seen.alarms()[-1], "ActiveState") is True  # not cleared for want of news

        rig.sim = Simulator(opcua_port=ports[0], ftp_port=ports[1], speed=20.0, store=tmp_path / "store")
        await rig.sim.__aenter__()  # a fresh controller: no alarms any more
        await wait_until(
            lambda: state(seen.alarms()[-1], "ActiveState") is False,
            timeout=15,
            message="the alarm cleared after reconnecting",
        )
        assert seen.alarms()[-1].Quality == ua.StatusCode(ua.StatusCodes.Good)
