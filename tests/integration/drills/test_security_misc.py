"""Security drill (issue 23, items 4, 9, 10): what a person on the shop network throws at a running gateway,
and proof that the machine saw none of it.

One gateway process (`cnc-gateway run`), a simulator process (its OPC UA and its serial DNC face) and a real
Mosquitto. The gateway runs the shipped laser-sim mapping (COPYDATA targets, MQTT writes and commands on, JSON
topics over MQTT 5, the Sparkplug edge node over MQTT 3.1.1) and laser-dnc (a serial line, so that it reads
drip-feed commands from its state directory). The attempts:

- **COPYDATA writes.** A gateway file whose target accepts writes without `access.copydata_role` does not
  start (and nothing listens); the running one names `viewer`: the 14-byte frame that the issue saw audited
  as `anonymous@copydata/admin … 100 -> 150 ok` reaches a read-only target and a writing one, and is refused
  (audited as `copydata/viewer`, BadUserAccessDenied).
- **MQTT response-topic hijack.** Every request of tests/corpus/mqtt/response_topics.yaml (`rounds` times):
  refused on its own result topic; a spy on `#` sees nothing where it asked.
- **Oversized MQTT packets.** tests/corpus/mqtt/packets.yaml: 8 MiB each (120 MiB in soak, as in the issue)
  to the gateway's request topics: the broker drops them for the MQTT 5 connection, the gateway drops the
  Sparkplug 3.1.1 connection at the packet's header. Its RSS is measured (psutil) before, at its peak and
  after, and reported.
- **The drip-feed command folder.** A link planted at the name the reply used to be written through, and a
  folder every user may write: the link's target is untouched, nothing is taken while the folder is open to
  all, and the gateway says why in its log.

At the end the simulator's override and program are what they were, the audit holds no change made by any
of these doors, a plain MQTT write still goes through, and the gateway's log has no traceback.
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import subprocess
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import psutil
import pytest
import yaml
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from tests.integration.drills import processes
from tests.integration.drills.conftest import SCALE, Report, count
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

ROOT = Path(__file__).resolve().parents[3]
CORPUS = ROOT / "tests" / "corpus" / "mqtt"
ROUNDS = count("security_rounds")
HOLD = 1.0  # s: five of the gateway's looks at its drip-feed command folder (CONTROL_EVERY 0.2 s)
MIB = 1024 * 1024
OVERRIDE = "ns=2;s=::AsGlobalPV:gFeed.Override"  # at the simulator: the machine itself
PROGRAM = "ns=2;s=::AsGlobalPV:gProgram.Name"
FRAME = struct.pack("<IIHHH", 1, 6, 6, 2, 150)  # the 14 bytes: dwData=1, Feed/Override (id 6) = 150
SET = "cnc/laser-sim/feed/override/set"
NBIRTH = "spBv1.0/cnc/NBIRTH/cnc-gateway"


def load_corpus(name: str) -> list[dict[str, Any]]:
    cases: list[dict[str, Any]] = yaml.safe_load((CORPUS / name).read_text(encoding="utf-8"))
    assert cases, f"tests/corpus/mqtt/{name} has no cases"
    return cases


def laser_sim(sim_port: int, copydata_ports: tuple[int, int], accept_writes: bool = True) -> dict[str, Any]:
    data = processes.laser_sim(sim_port, mqtt={"writable": True, "commands": True})
    data["copydata"] = {
        "targets": [
            {"name": "nesting", "transport": "tcp-server", "bind": "127.0.0.1", "port": copydata_ports[0]},
            {"name": "writer", "transport": "tcp-server", "bind": "127.0.0.1", "port": copydata_ports[1],
             "accept_writes": accept_writes},
        ]
    }  # fmt: skip
    return data


def laser_dnc(sim_port: int, dnc_port: int, programs: Path) -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "mappings" / "laser-dnc.yaml").read_text(encoding="utf-8"))
    data["driver"].update(endpoint=f"opc.tcp://127.0.0.1:{sim_port}", reconnect={"initial": 0.2, "max": 2})
    data["jobs"]["controller"]["where"] = f"socket://127.0.0.1:{dnc_port}"
    data["jobs"]["punch"]["requests"]["folder"] = str(programs)
    return data


def gateway_data(machines: list[str], mqtt_port: int, **extra: Any) -> dict[str, Any]:
    """JSON topics over MQTT 5, the Sparkplug edge node over MQTT 3.1.1, both to the drill's Mosquitto."""
    tag = uuid.uuid4().hex[:6]
    broker = {"port": mqtt_port, "keepalive": 5, "reconnect": {"initial": 0.1, "max": 0.5}}
    return {
        "opcua": {"endpoint": f"opc.tcp://127.0.0.1:{free_port()}/cnc-gateway", "security": ["None"]},
        "state_dir": "state",
        "log_level": "info",
        "machines": machines,
        "inbox": {"host": "127.0.0.1", "port": free_port()},
        "mqtt": {**broker, "client_id": f"drill-{tag}", "protocol": "5"},
        "sparkplug": {"broker": {**broker, "client_id": f"drill-spb-{tag}", "protocol": "3.1.1"}},
        **extra,
    }


async def holds(condition: Callable[[], Any], *, seconds: float, message: str) -> None:
    """`condition` stays true for `seconds` (checked every 20 ms): what a drill needs to say that something
    did not happen. Here: five of the gateway's 0.2 s looks at its control folder."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        assert condition(), f"no longer true: {message}"
        await asyncio.sleep(0.02)


def listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.3)
        return s.connect_ex(("127.0.0.1", port)) == 0


class Machine:
    """The simulator as the machine: what it holds, read from its own OPC UA server."""

    def __init__(self, port: int) -> None:
        self.client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=5)

    async def read(self) -> tuple[int, str]:
        override = await self.client.get_node(OVERRIDE).read_value()
        program = await self.client.get_node(PROGRAM).read_value()
        return int(override), str(program)


@contextmanager
def rss_peak(pid: int) -> Iterator[list[int]]:
    """Samples the process's RSS every 20 ms while the block runs; the list gets the samples."""
    proc, samples, done = psutil.Process(pid), [], threading.Event()

    def sample() -> None:
        while not done.is_set():
            samples.append(proc.memory_info().rss)
            done.wait(0.02)

    thread = threading.Thread(target=sample, name="rss", daemon=True)
    thread.start()
    try:
        yield samples
    finally:
        done.set()
        thread.join()


def audit(state: Path) -> list[dict[str, Any]]:
    out = subprocess.run(
        [str(processes.BIN / "cnc-gateway"), "audit", "list", "--state-dir", str(state), "--json"],
        capture_output=True, text=True, timeout=60, check=True,
    ).stdout  # fmt: skip
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def test_a_copydata_target_that_accepts_writes_without_a_role_does_not_start(tmp_path: Path) -> None:
    port = free_port()
    processes.write_yaml(tmp_path / "laser-sim.yaml", laser_sim(free_port(), (free_port(), port)))
    data = gateway_data(["laser-sim.yaml"], free_port())
    gw_file = processes.write_yaml(tmp_path / "gateway.yaml", data)
    proc = subprocess.run(
        [str(processes.BIN / "cnc-gateway"), "run", str(gw_file)],
        capture_output=True, text=True, timeout=60, check=False, env=processes.clean_env(),
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "copydata.targets[1].accept_writes: target 'writer' accepts writes" in proc.stderr
    assert not listening(port)


@pytest.mark.timeout(300 if SCALE == "soak" else 150)
async def test_security_drill_the_machine_sees_nothing(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path, drill_report: Report
) -> None:
    sim_port, dnc_port, read_port, write_port = free_port(), free_port(), free_port(), free_port()
    programs = tmp_path / "programs"
    programs.mkdir()
    processes.write_yaml(tmp_path / "laser-sim.yaml", laser_sim(sim_port, (read_port, write_port)))
    processes.write_yaml(tmp_path / "laser-dnc.yaml", laser_dnc(sim_port, dnc_port, programs))
    data = gateway_data(
        ["laser-sim.yaml", "laser-dnc.yaml"], mosquitto.port, access={"copydata_role": "viewer"}
    )
    gw_file = processes.write_yaml(tmp_path / "gateway.yaml", data)
    opcua_port = int(data["opcua"]["endpoint"].rsplit(":", 1)[1].split("/")[0])
    state = tmp_path / "state"
    spy = subscriber(recorders, mosquitto.port, v5=True, topics=["#", "$SYS/cnc-gateway-drill"])
    sim = processes.simulator(
        tmp_path, sim_port, free_port(), "--dnc-port", str(dnc_port), "--shdr-port", "off",
        "--dnc-rfc2217-port", "off",
    )  # fmt: skip
    gateway = processes.gateway(tmp_path, gw_file)
    machine = Machine(sim_port)
    figures: dict[str, Any] = {}
    try:
        await asyncio.to_thread(sim.start)
        await asyncio.to_thread(processes.wait_for_port, sim, sim_port)
        await asyncio.to_thread(gateway.start)
        await asyncio.to_thread(processes.wait_for_port, gateway, opcua_port)
        await wait_until(
            lambda: (spy.last_json("cnc/laser-sim/feed/override") or {}).get("quality") == "good",
            timeout=30, message="the gateway mirroring the machine",
        )  # fmt: skip
        await wait_until(lambda: spy.on(NBIRTH), timeout=30, message="the edge node born")
        await machine.client.connect()
        before = await machine.read()
        assert before[0] != 150

        figures |= await copydata_attempts(read_port, write_port, spy, state)
        figures |= await hijack_attempts(spy)
        figures |= await oversized_attempts(gateway, spy)
        figures |= await control_folder_attempts(state, gateway, tmp_path)

        assert await machine.read() == before, "the machine saw a change"
        changed = [
            e for e in audit(state) if e["status"] == "Good" and e["origin"] in ("copydata", "mqtt", "cli")
        ]
        assert changed == [], changed
        # Still serving: a plain MQTT write reaches the machine.
        spy.publish(SET, b"77")
        await wait_until(
            lambda: spy.last_json(SET + "/result") == {"ok": True}, timeout=15, message="a write"
        )
        assert (await machine.read())[0] == 77  # answered once the controller's value was read back
        assert gateway.alive, gateway.tail()
        assert "Traceback" not in gateway.log.read_text(errors="replace")
    finally:
        if machine.client.uaclient.protocol is not None:
            await machine.client.disconnect()
        await asyncio.to_thread(gateway.stop)
        await asyncio.to_thread(sim.stop)
    drill_report("security (items 4, 9, 10)", rounds=ROUNDS, **figures)


async def copydata_attempts(read_port: int, write_port: int, spy: Recorder, state: Path) -> dict[str, Any]:
    """The issue's frame to both targets; the writing one acts as viewer and may not write Feed/Override."""
    feedback = "cnc/laser-sim/copydata/feedback"
    for port in (read_port, write_port):
        before = len(spy.on(feedback))
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        try:
            writer.write(FRAME)
            await writer.drain()
            await wait_until(lambda n=before: len(spy.on(feedback)) > n, message=f"feedback from {port}")
        finally:
            writer.close()
            del reader
    docs = [m.json() for m in spy.on(feedback)]
    [read_only] = [d for d in docs if d["target"] == "nesting"]
    [written] = [d for d in docs if d["target"] == "writer"]
    assert "write" not in read_only["items"][0]  # accept_writes off: feedback only
    assert written["items"][0]["write"]["status"] == "BadUserAccessDenied"
    entries = await wait_until(lambda: [e for e in audit(state) if e["origin"] == "copydata"], timeout=15,
                               message="the refused COPYDATA write audited")  # fmt: skip
    assert [(e["role"], e["status"]) for e in entries] == [("viewer", "BadUserAccessDenied")]
    return {"copydata_frames": 2, "copydata_written": 0}


async def hijack_attempts(spy: Recorder) -> dict[str, Any]:
    cases = load_corpus("response_topics.yaml")
    for case in cases:
        if case["response_topic"].startswith("$"):
            assert case["response_topic"] == "$SYS/cnc-gateway-drill", "the spy subscribes to that one only"
    markers: dict[bytes, dict[str, Any]] = {}
    sent = 0
    for round_ in range(ROUNDS):
        for index, case in enumerate(cases):
            marker = f"drill-{round_}-{index}".encode()
            props = Properties(PacketTypes.PUBLISH)
            props.ResponseTopic = case["response_topic"]
            props.CorrelationData = marker
            spy.publish(case["topic"], case["payload"], properties=props)
            markers[marker] = case
            sent += 1
    answered = await wait_until(
        lambda: found if len(found := answers(spy, markers)) == sent else None,
        timeout=30 + sent / 20, message=f"answers to {sent} hijack attempts",
    )  # fmt: skip
    wrong = []
    for marker, (topic, doc) in answered.items():
        case = markers[marker]
        expect = case["expect"]
        if (
            topic != f"{case['topic']}/result"
            or doc.get("status") != expect["status"]
            or (expect["error"] not in doc.get("error", ""))
        ):
            wrong.append((case["name"], topic, doc))
    assert not wrong, wrong
    outside = {c["response_topic"] for c in cases if not c["response_topic"].startswith("cnc/")}
    published_there = [m.topic for m in spy.messages if m.topic in outside]
    assert published_there == [], published_there
    return {"hijack_requests": sent, "published_elsewhere": len(published_there)}


def answers(spy: Recorder, markers: dict[bytes, dict[str, Any]]) -> dict[bytes, tuple[str, Any]]:
    """Every answer (a JSON object with "ok") that carries a marker's correlation data: (topic, JSON) per
    marker. The spy also hears its own requests, with the same correlation data: those are not answers."""
    found: dict[bytes, tuple[str, Any]] = {}
    for message in list(spy.messages):
        data = getattr(message.properties, "CorrelationData", None)
        if data not in markers:
            continue
        try:
            doc = message.json()
        except ValueError:
            continue
        if not isinstance(doc, dict) or "ok" not in doc:
            continue
        assert data not in found, f"two answers to one request: {found[data]} and {message.topic}"
        found[data] = (message.topic, doc)
    return found


async def oversized_attempts(gateway: processes.Process, spy: Recorder) -> dict[str, Any]:
    cases = load_corpus("packets.yaml")
    pid = gateway.pid
    rss_before = psutil.Process(pid).memory_info().rss
    births = len(spy.on(NBIRTH))
    received_before = len(spy.on(SET + "/result"))
    commands_before = len(spy.on("cnc/laser-sim/commands/select-program/result"))
    sent_mib = 0
    with rss_peak(pid) as samples:
        for case in cases:
            mib = int(case["mib"][SCALE])
            payload = b"7" * (mib * MIB)
            spy.publish(case["topic"], payload, qos=0)
            sent_mib += mib
            del payload
        # Dropped by the gateway: its Sparkplug connection ends and a new birth follows; by the broker: the
        # next small request is the first answered.
        by_gateway = sum(1 for c in cases if c["expect"]["dropped_by"] == "gateway")
        await wait_until(lambda: len(spy.on(NBIRTH)) >= births + by_gateway, timeout=60,
                         message="the edge node born again")  # fmt: skip
        spy.publish(SET, b"bad")  # answered: the connection still takes requests; refused, so nothing changes
        await wait_until(lambda: len(spy.on(SET + "/result")) > received_before, timeout=30,
                         message="the next request answered")  # fmt: skip
    answered = [m.json() for m in spy.on(SET + "/result")[received_before:]]
    assert [a["status"] for a in answered] == ["BadTypeMismatch"], answered  # none for the oversized ones
    assert len(spy.on("cnc/laser-sim/commands/select-program/result")) == commands_before
    rss_after = psutil.Process(pid).memory_info().rss
    log = gateway.log.read_text(errors="replace")
    guard = log.count("more than max_packet_size")
    assert guard >= by_gateway, gateway.tail()
    return {
        "oversized_packets": len(cases),
        "oversized_mib": sent_mib,
        "rss_before_mib": round(rss_before / MIB, 1),
        "rss_peak_mib": round(max(samples, default=rss_before) / MIB, 1),
        "rss_after_mib": round(rss_after / MIB, 1),
        "dropped_at_header": by_gateway,
    }


async def control_folder_attempts(state: Path, gateway: processes.Process, tmp_path: Path) -> dict[str, Any]:
    folder = state / "jobs" / "dnc" / "control"
    await wait_until(folder.is_dir, timeout=15, message="the gateway making its control folder")
    victim = tmp_path / "victim.sqlite3"
    victim.write_bytes(b"the gateway's own data\n")
    # A link where the reply used to be written through, planted before the request it answers.
    rid = uuid.uuid4().hex
    (folder / f"laser-dnc.{rid}.reply-tmp").symlink_to(victim)
    (folder / f"laser-dnc.{rid}.reply").symlink_to(victim)
    (folder / f"laser-dnc.{rid}.request").write_text('{"method": "DripPause"}')
    reply = folder / f"laser-dnc.{rid}.reply"
    await wait_until(lambda: not reply.is_symlink() and reply.exists(), timeout=15, message="the reply")
    assert json.loads(reply.read_text())["status"] == "BadInvalidState"  # nothing is being sent
    assert victim.read_bytes() == b"the gateway's own data\n"
    # A folder every user may write: nothing is taken until it is the gateway's alone again.
    folder.chmod(0o777)
    await wait_until(lambda: "every user may write" in gateway.log.read_text(errors="replace"), timeout=15,
                     message="the gateway refusing the folder")  # fmt: skip
    rid = uuid.uuid4().hex
    request = folder / f"laser-dnc.{rid}.request"
    request.write_text('{"method": "DripAbort"}')
    await holds(request.exists, seconds=HOLD, message="the request left alone in the open folder")
    assert not (folder / f"laser-dnc.{rid}.reply").exists()
    folder.chmod(0o750)
    reply = folder / f"laser-dnc.{rid}.reply"
    await wait_until(reply.exists, timeout=15, message="the request taken once the folder is safe")
    return {"links_planted": 2, "victim_untouched": True, "taken_from_open_folder": 0}
