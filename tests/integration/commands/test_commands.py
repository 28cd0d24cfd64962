"""Commands end to end: OPC UA methods under Commands/ and MQTT requests run the simulator, with
guards, deadlines and argument checks answered the way each protocol expects."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from gateway.errors import InvalidState
from gateway.model.context import WriteContext
from simulator.machine import MachineState
from tests.integration.laser_rig import MACHINE, laser_rig, text
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.waiting import wait_until

PREFIX = f"cnc/{MACHINE}/commands"


def bad(info: pytest.ExceptionInfo[Any]) -> str:
    return type(info.value).__name__


async def test_select_and_start_through_opcua_methods_then_refusals(tmp_path: Path) -> None:
    async with laser_rig(tmp_path, timeouts={"start": 1.0}) as rig:
        client = await rig.client()
        commands = client.get_node(f"ns=2;s={MACHINE}/Commands")
        names = {(await m.read_browse_name()).Name for m in await commands.get_methods()}
        assert names == {"start", "stop", "pause", "resume", "reset", "select-program"}
        inputs = await (await commands.get_child("2:select-program")).get_child("0:InputArguments")
        [argument] = await inputs.read_value()
        assert argument.Name == "name" and argument.DataType == ua.NodeId(ua.ObjectIds.String)

        result, duration = await rig.command(client, "select-program", text("demo.nc"))
        assert result == "Program/Name is 'demo.nc'" and duration >= 0
        assert rig.sim.machine.program.name == "demo.nc"
        result, _ = await rig.command(client, "start")
        assert result == "Machine/State is 1 (Running)"
        assert rig.state() is MachineState.RUNNING

        with pytest.raises(ua.UaStatusCodeError) as info:  # already running: the guard says no
            await rig.command(client, "start")
        assert bad(info) == "BadInvalidState"
        result, _ = await rig.command(client, "stop")
        assert rig.state() is MachineState.IDLE and result == "Machine/State is 0 (Idle)"

        # Wrong argument counts and types are refused before anything is written.
        with pytest.raises(ua.UaStatusCodeError) as info:
            await rig.command(client, "select-program")
        assert bad(info) == "BadArgumentsMissing"
        with pytest.raises(ua.UaStatusCodeError) as info:
            await rig.command(client, "select-program", ua.Variant(7, ua.VariantType.Int32))
        assert bad(info) == "BadTypeMismatch"
        with pytest.raises(ua.UaStatusCodeError) as info:
            await rig.command(client, "select-program", text("a.nc"), text("b.nc"))
        assert bad(info) == "BadTooManyArguments"
        assert rig.sim.machine.program.name == "demo.nc"

        # The controller's own refusal comes back with its status.
        with pytest.raises(ua.UaStatusCodeError) as info:
            await rig.command(client, "select-program", text("missing.nc"))
        assert bad(info) == "BadInvalidArgument"

        # A simulator told to ignore Start: the command gives up at its deadline.
        rig.sim.machine.ignore_start = True
        with pytest.raises(ua.UaStatusCodeError) as info:
            await rig.command(client, "start")
        assert bad(info) == "BadTimeout"
        assert rig.state() is MachineState.IDLE


async def test_start_in_alarm_is_refused_with_the_state(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        client = await rig.client()
        await rig.command(client, "select-program", text("soft-limit.nc"))
        await rig.command(client, "start")
        await wait_until(
            lambda: rig.state() is MachineState.ALARM, timeout=15, message="the soft-limit alarm"
        )
        await wait_until(
            lambda: rig.machine.nodes["Machine/State"].sample.value == 3, message="Alarm mirrored"
        )
        with pytest.raises(ua.UaStatusCodeError) as info:
            await rig.command(client, "start")
        assert bad(info) == "BadInvalidState"
        with pytest.raises(InvalidState) as reason:  # the same call, from inside: what the refusal says
            await rig.machine.call_method(
                rig.machine.methods[("Commands", "start")], [], WriteContext("test", role="operator")
            )
        assert reason.value.reason == (
            "start is not allowed while Machine/State is 3 (Alarm); it needs Machine/State = 0 (Idle)"
        )
        await rig.command(client, "reset")
        assert rig.state() is MachineState.IDLE


async def test_commands_over_mqtt_with_answers_correlation_and_deadlines(
    tmp_path: Path, mosquitto: Mosquitto, recorders: list[Recorder]
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=[f"{PREFIX}/+/result", "replies/#"], v5=True)
    mqtt = mqtt_config(mosquitto.port, protocol="5", response_topics=["replies/#"])
    async with laser_rig(tmp_path, mqtt=mqtt, timeouts={"start": 1.0}) as rig:
        await wait_until(lambda: rig.gateway.sink("mqtt").online, message="the gateway on the broker")  # type: ignore[union-attr]

        def answers(name: str) -> list[dict[str, Any]]:
            return [m.json() for m in rec.on(f"{PREFIX}/{name}/result")]

        rec.publish(f"{PREFIX}/select-program", json.dumps({"name": "demo.nc", "correlation_id": "c-1"}))
        await wait_until(lambda: answers("select-program"), message="the select answer")
        [select] = answers("select-program")
        assert select["ok"] is True and select["status"] == "Good" and select["correlation_id"] == "c-1"
        assert select["reason"] == "Program/Name is 'demo.nc'" and select["duration_ms"] >= 0

        # MQTT 5: the answer goes to the response topic, with the correlation data.
        props = Properties(PacketTypes.PUBLISH)
        props.ResponseTopic = "replies/cell-7"
        props.CorrelationData = b"\x00\x07"
        rec.publish(f"{PREFIX}/start", b"", properties=props)
        await wait_until(lambda: rec.on("replies/cell-7"), message="the start answer")
        [reply] = rec.on("replies/cell-7")
        assert reply.json()["ok"] is True and reply.json()["reason"] == "Machine/State is 1 (Running)"
        assert reply.properties.CorrelationData == b"\x00\x07"
        assert rig.state() is MachineState.RUNNING

        rec.publish(f"{PREFIX}/start", b"{}")  # running already: refused, naming the state
        await wait_until(lambda: answers("start"), message="the refused start")
        refused = answers("start")[-1]
        assert refused["ok"] is False and refused["status"] == "BadInvalidState"
        assert "Machine/State is 1 (Running)" in refused["error"] and "duration_ms" in refused

        rec.publish(f"{PREFIX}/stop", b"")
        await wait_until(lambda: answers("stop"), message="the stop answer")
        assert answers("stop")[0]["ok"] is True and rig.state() is MachineState.IDLE

        rec.publish(f"{PREFIX}/select-program", b'{"name": ')  # malformed
        await wait_until(lambda: len(answers("select-program")) >= 2, message="the malformed body's answer")
        malformed = answers("select-program")[-1]
        assert (
            malformed["ok"] is False
            and malformed["status"] == "BadDecodingError"
            and "JSON" in malformed["error"]
        )

        rig.sim.machine.ignore_start = True
        rec.publish(f"{PREFIX}/start", json.dumps({"correlation_id": 99}))
        await wait_until(lambda: len(answers("start")) >= 2, timeout=10, message="the timed-out start")
        timed_out = answers("start")[-1]
        assert timed_out["ok"] is False and timed_out["status"] == "BadTimeout"
        assert timed_out["correlation_id"] == 99 and timed_out["duration_ms"] >= 1000
        assert "Machine/State is 0 (Idle)" in timed_out["error"]


async def test_mqtt_commands_are_refused_unless_the_mapping_enables_them(
    tmp_path: Path, mosquitto: Mosquitto, recorders: list[Recorder]
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=[f"{PREFIX}/+/result"])
    async with laser_rig(tmp_path, mqtt=mqtt_config(mosquitto.port), mqtt_commands=False) as rig:
        await wait_until(lambda: rig.gateway.sink("mqtt").online, message="the gateway on the broker")  # type: ignore[union-attr]
        rec.publish(f"{PREFIX}/start", b"")
        await wait_until(lambda: rec.last_json(f"{PREFIX}/start/result"), message="the refusal")
        answer = rec.last_json(f"{PREFIX}/start/result")
        assert answer["ok"] is False and answer["status"] == "BadUserAccessDenied"
        assert rig.state() is MachineState.IDLE
