"""README's alarm walkthrough, run as written against `cnc-gateway demo`, its driver keeping demo.nc going.

The shell block is read from README.md and its `mosquitto_sub`/`mosquitto_pub` lines are run as they are
(with the test broker's port added), each command once the one before it has answered, as the README
says; the comment between them is the acknowledgement in an OPC UA client, logged in as the demo's
operator. Between steps the test pauses as a person reading the answers would (THINK). The walkthrough is
followed several times in a row: each time every command must succeed,
the alarm must stay active until the reset clears it (the driver leaves it alone), and the driver must
start demo.nc again once the walkthrough's program has ended.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from tests.integration.mqtt.conftest import MOSQUITTO, Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
SOFT_LIMIT = "Soft limit X+ exceeded at line 7"
ROUNDS = 3
# A person reads each answer before typing the next command. This pause is that person, not a wait for
# something to happen: it is longer than the driver's cycle (about a second), so that a driver that
# fights the user gets its chance between any two steps, as it did in issue 12.
THINK = 1.5
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)

pytestmark = pytest.mark.skipif(
    not (Path(MOSQUITTO).exists() and shutil.which("mosquitto_pub") and shutil.which("mosquitto_sub")),
    reason="mosquitto and its clients (mosquitto_pub, mosquitto_sub) are not installed",
)


def walkthrough() -> list[str]:
    """The README's alarm walkthrough: its shell block, line by line."""
    blocks = re.findall(r"```sh\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), re.DOTALL)
    [block] = [b for b in blocks if "soft-limit.nc" in b and "commands/stop" in b]
    return [line for line in block.splitlines() if line.strip()]


@dataclass
class Watch:
    """The README's `mosquitto_sub -v …`, running; each line is `topic payload`."""

    proc: asyncio.subprocess.Process
    lines: list[tuple[str, Any]] = field(default_factory=list)

    async def read(self) -> None:
        assert self.proc.stdout is not None
        async for raw in self.proc.stdout:
            topic, _, payload = raw.decode().rstrip("\n").partition(" ")
            self.lines.append((topic, json.loads(payload) if payload else None))

    def on(self, topic: str) -> list[Any]:
        return [payload for t, payload in self.lines if t == topic]

    def events(self, occurrence: int | None = None) -> list[dict[str, Any]]:
        return [
            e
            for e in self.on("cnc/laser-sim/alarms/events")
            if occurrence is None or e["occurrence"] == occurrence
        ]


def broker_args(argv: list[str], port: int) -> list[str]:
    return [argv[0], "-h", "127.0.0.1", "-p", str(port), *argv[1:]]


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    mosquitto = Mosquitto(tmp_path / "mosquitto", free_port())
    mosquitto.start()
    try:
        yield mosquitto
    finally:
        mosquitto.stop()


@pytest.fixture
async def demo(tmp_path: Path, broker: Mosquitto) -> AsyncIterator[str]:
    """`cnc-gateway demo` on free ports, publishing to the test broker; yields its OPC UA endpoint."""
    gw_port = free_port()
    flags = (
        "--sim-opcua-port",
        "--sim-ftp-port",
        "--inbox-port",
        "--copydata-port",
        "--mtconnect-port",
        "--sim-dnc-port",
        "--sim-dnc-opcua-port",
        "--sim-dnc-ftp-port",
        "--sim-focas-port",
        "--sim-modbus-port",
        "--sim-s7-port",
    )
    ports = {flag: free_port() for flag in flags}
    env = {k: v for k, v in os.environ.items() if k != "CNC_DEMO_PASSWORD"}  # the README's passwords
    log = tmp_path / "demo.log"
    with log.open("w") as out:  # a file, not a pipe: nobody reads the demo's log while it runs
        proc = subprocess.Popen(
            [
                str(BIN / "cnc-gateway"),
                "demo",
                "--opcua-port",
                str(gw_port),
                "--mqtt-port",
                str(broker.port),
                "--speed",
                "4",
                "--state-dir",
                str(tmp_path / "state"),
                *(str(a) for pair in ports.items() for a in pair),
            ],
            cwd=ROOT,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        yield f"opc.tcp://127.0.0.1:{gw_port}/cnc-gateway"
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        text = log.read_text(errors="replace")
        assert "Traceback" not in text, text


async def read(client: Client, path: str) -> Any:
    dv = await client.get_node(f"ns=2;s=laser-sim/{path}").read_data_value(raise_on_bad_status=False)
    return dv.Value.Value if dv.StatusCode.is_good() else None


class Alarms:
    """Alarm condition events, as an OPC UA client gets them."""

    def __init__(self) -> None:
        self.received: list[Any] = []

    def event_notification(self, event: Any) -> None:
        if event.EventType == ua.NodeId(ua.ObjectIds.AlarmConditionType):
            self.received.append(event)


async def test_the_readme_alarm_walkthrough_works_every_time_with_the_driver_running(
    demo: str, broker: Mosquitto
) -> None:
    lines = walkthrough()
    sub, *steps = lines
    assert shlex.split(sub)[0] == "mosquitto_sub"
    watch_proc = await asyncio.create_subprocess_exec(
        *broker_args(shlex.split(sub), broker.port), stdout=asyncio.subprocess.PIPE
    )
    watch = Watch(watch_proc)
    reader = asyncio.create_task(watch.read(), name="test:mosquitto_sub")
    client = Client(demo, timeout=5)
    client.set_user("operator")
    client.set_password("operator")
    try:
        await wait_until(_connects(client), timeout=30, interval=0.2, message="the demo's OPC UA server")
        alarms = Alarms()
        subscription = await client.create_subscription(20, alarms)
        await subscription.subscribe_alarms_and_conditions(
            ua.NodeId(ua.ObjectIds.Server), ua.ObjectIds.AlarmConditionType
        )

        async def demo_running() -> bool:
            return (
                await read(client, "Program/Name") == "demo.nc" and await read(client, "Machine/State") == 1
            )

        await wait_until(demo_running, timeout=30, interval=0.1, message="the driver to run demo.nc")
        for round_ in range(ROUNDS):
            await follow(steps, watch, client, alarms, broker.port, round_)
            # The walkthrough's program has ended: the driver takes the machine back.
            await wait_until(
                demo_running,
                timeout=15,
                interval=0.1,
                message=f"round {round_}: the driver to start demo.nc again",
            )
    finally:
        await client.disconnect()
        watch_proc.terminate()
        await watch_proc.wait()
        reader.cancel()
        await asyncio.gather(reader, return_exceptions=True)


def _connects(client: Client) -> Any:
    async def attempt() -> bool:
        try:
            await client.connect()
        except (OSError, TimeoutError, ua.UaError):
            return False
        return True

    return attempt


async def follow(
    steps: list[str], watch: Watch, client: Client, alarms: Alarms, port: int, round_: int
) -> None:
    """One pass through the README's block: each command answered ok; the alarm raised, acked, cleared."""
    occurrence: int | None = None
    comment: list[str] = []
    for line in steps:
        if line.lstrip().startswith("#"):
            comment.append(line)
            continue
        await asyncio.sleep(THINK)
        if comment:  # the step the comment describes: acknowledge in an OPC UA client, as operator
            assert "acknowledge" in " ".join(comment) and "operator" in " ".join(comment)
            assert occurrence is not None, "the walkthrough acknowledges an alarm it has not raised"
            await acknowledge(client, alarms, occurrence, watch, round_)
            comment = []
            await asyncio.sleep(THINK)
        argv = shlex.split(line)
        assert argv[0] == "mosquitto_pub"
        topic = argv[argv.index("-t") + 1]
        command = topic.rsplit("/", 1)[1]
        answered = len(watch.on(f"{topic}/result"))
        known = {e["occurrence"] for e in watch.events()}
        done = await asyncio.to_thread(
            subprocess.run, broker_args(argv, port), capture_output=True, text=True, timeout=30, check=False
        )
        assert done.returncode == 0, done.stderr
        result = await wait_until(
            lambda topic=topic, answered=answered: watch.on(f"{topic}/result")[answered:],
            timeout=15,
            message=f"round {round_}: the answer to {command}",
        )
        assert result[0]["ok"] is True, f"round {round_}: {command}: {result[0]}"
        if command == "start":
            occurrence = await raised(watch, known, round_)
        elif command == "reset":
            assert occurrence is not None
            cleared = await wait_until(
                lambda occurrence=occurrence: [
                    e for e in watch.events(occurrence) if e["event"] == "cleared"
                ],
                timeout=10,
                message=f"round {round_}: the alarm cleared by the reset",
            )
            assert cleared[0]["acked"] is True and cleared[0]["active"] is False
            await wait_until(
                lambda: watch.on("cnc/laser-sim/alarms/active")[-1:] == [[]],
                timeout=10,
                message=f"round {round_}: an empty alarms/active",
            )
    assert occurrence is not None and [e["event"] for e in watch.events(occurrence)] == [
        "raised",
        "acknowledged",
        "cleared",
    ], f"round {round_}: the alarm's events"


async def raised(watch: Watch, known: set[int], round_: int) -> int:
    """The soft-limit alarm this round's start raised (a new occurrence), active and listed."""
    event = await wait_until(
        lambda: next(
            (e for e in watch.events() if e["event"] == "raised" and e["occurrence"] not in known), None
        ),
        timeout=30,
        message=f"round {round_}: the soft-limit alarm",
    )
    assert (event["id"], event["text"], event["active"]) == ("1001", SOFT_LIMIT, True)
    occurrence = int(event["occurrence"])
    await wait_until(
        lambda: any(
            a["occurrence"] == occurrence and a["active"]
            for a in (watch.on("cnc/laser-sim/alarms/active") or [[]])[-1]
        ),
        timeout=10,
        message=f"round {round_}: the alarm in alarms/active",
    )
    return occurrence


async def acknowledge(client: Client, alarms: Alarms, occurrence: int, watch: Watch, round_: int) -> None:
    """What the walkthrough asks of the OPC UA client: acknowledge the active alarm, as operator."""
    event = await wait_until(
        lambda: next(
            (e for e in alarms.received if e.NodeId == ua.NodeId(f"laser-sim/Alarms/{occurrence}", 2)), None
        ),
        timeout=10,
        message=f"round {round_}: the alarm's OPC UA event",
    )
    assert event.ConditionName == "1001" and getattr(event, "ActiveState/Id") is True
    assert not [e for e in watch.events(occurrence) if e["event"] == "cleared"], (
        f"round {round_}: the alarm was cleared before anyone acknowledged it"
    )
    await client.get_node(event.NodeId).call_method(
        ACK,
        ua.Variant(event.EventId, ua.VariantType.ByteString),
        ua.Variant(ua.LocalizedText("walkthrough"), ua.VariantType.LocalizedText),
    )
    acked = await wait_until(
        lambda: [e for e in watch.events(occurrence) if e["event"] == "acknowledged"],
        timeout=10,
        message=f"round {round_}: the acknowledgement on MQTT",
    )
    assert acked[0]["user"] == "operator" and acked[0]["active"] is True


async def test_the_demo_shows_the_chiller_and_the_plc_in_opc_ua_and_mqtt(
    demo: str, broker: Mosquitto, recorders: list[Recorder]
) -> None:
    """The README's PLC section: the demo's Modbus chiller and S7 PLC are machines in OPC UA and MQTT."""
    rec = subscriber(recorders, broker.port, topics=["cnc/chiller/#", "cnc/laser-plc/#"])
    client = Client(demo, timeout=5)
    try:
        await wait_until(_connects(client), timeout=30, interval=0.2, message="the demo's OPC UA server")

        async def value(path: str) -> Any:
            node = client.get_node(f"ns=2;s={path}")
            dv = await node.read_data_value(raise_on_bad_status=False)
            return dv.Value.Value if dv.StatusCode.is_good() else None

        async def both_good() -> bool:
            return (
                await value("chiller/Model") == "LX-CHILL5"
                and await value("laser-plc/Program/Name") == "demo.nc"
            )

        await wait_until(
            both_good, timeout=30, interval=0.2, message="the chiller and the PLC Good in OPC UA"
        )
        assert 10 < await value("chiller/Temperatures/Supply") < 30
        await wait_until(lambda: (rec.last_json("cnc/chiller/setpoint") or {}).get("quality") == "good"
                         and (rec.last_json("cnc/laser-plc/laser/power") or {}).get("quality") == "good",
                         timeout=15, message="both on MQTT")  # fmt: skip
    finally:
        await client.disconnect()
