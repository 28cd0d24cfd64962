"""The bad-input corpus, all of it, against ONE running gateway: each input gets its clear error, and the
gateway serves on afterwards.

tests/corpus/ holds the inputs and, beside each, the answer it must get:
mappings/ (`# expect:` headers; through the loader and one `cnc-gateway check`), gcode/ (`(expect: …)`
headers; uploaded to the FTP inbox), mqtt/set.yaml and mqtt/commands.yaml (published with paho; answered on
`…/result`), ftp/paths.yaml (ftplib sessions), ftp/attacks.yaml (passive-port races from a second loopback
address, commands before a login, held sessions, password guesses, appends past the limit),
copydata/frames.yaml (TCP connections to the COPYDATA target), sparkplug/commands.yaml (NCMD and DCMD
published with paho to the gateway's edge node; each counted by kind).
The gateway (corpus_rig.py) runs the whole time, with the simulator and a real Mosquitto. At the end it must
still serve: OPC UA values Good, an MQTT write carried out and mirrored, a valid job delivered, a valid
COPYDATA frame written; and its log must hold no error and no traceback.
"""

from __future__ import annotations

import asyncio
import logging
import struct
from collections import Counter
from pathlib import Path

import pytest

from gateway.jobs.queue.store import JobState
from tests.integration.drills import corpus_runners as runners
from tests.integration.drills.conftest import Records, Report
from tests.integration.drills.corpus_rig import MACHINE, CorpusRig, corpus_rig
from tests.integration.jobs.conftest import GOOD, in_thread
from tests.integration.mqtt.conftest import Mosquitto, Recorder, subscriber
from tests.opcua_client import Client
from tests.waiting import wait_until

OVERRIDE_ID = 6  # Feed/Override's COPYDATA id in mappings/laser-sim.yaml


@pytest.mark.timeout(240)
async def test_every_bad_input_gets_its_clear_error_and_the_gateway_serves_on(
    mosquitto: Mosquitto, recorders: list[Recorder], records: Records, tmp_path: Path, drill_report: Report
) -> None:
    outcomes: list[runners.Outcome] = runners.run_mappings()
    rule_sets = []
    for _, _, rules, _ in runners.gcode_cases():
        if rules not in rule_sets:
            rule_sets.append(rules)
    mqtt = subscriber(recorders, mosquitto.port, topics=["cnc/#"])
    secret = tmp_path / "outside" / "secret.nc"
    secret.parent.mkdir()
    secret.write_bytes(GOOD)
    set_cases = runners.load("mqtt/set.yaml")
    commands = runners.load("mqtt/commands.yaml")
    assert commands, "tests/corpus/mqtt/commands.yaml has no cases"
    await runners.publish_retained(mqtt, set_cases + commands)
    async with corpus_rig(tmp_path / "rig", mosquitto.port, rule_sets) as rig:
        await wait_until(lambda: rig.gateway.tree.machines[MACHINE].status.is_connected, timeout=20,
                         message="the gateway connected to the simulator")  # fmt: skip
        await wait_until(lambda: rig.gateway.sink("mqtt").online, timeout=10, message="MQTT online")
        outcomes += await runners.run_mqtt(mqtt, "mqtt-set", set_cases)
        outcomes += await runners.run_mqtt(mqtt, "mqtt-command", commands)
        outcomes += await runners.run_ftp(rig, runners.load("ftp/paths.yaml"), GOOD, secret)
        outcomes += await runners.run_ftp_attacks(rig.inbox, rig.queue, runners.load("ftp/attacks.yaml"))
        outcomes += await runners.run_gcode(rig)
        outcomes += await runners.run_copydata(
            rig, runners.load("copydata/frames.yaml"), mqtt, records.records
        )
        await wait_until(lambda: rig.gateway.sink("sparkplug").online, timeout=10, message="Sparkplug born")
        outcomes += await runners.run_sparkplug(rig, mqtt, runners.load("sparkplug/commands.yaml"))
        survived = await still_serving(rig, mqtt)
        assert not rig.run.done(), "the gateway stopped"

    failed = [o for o in outcomes if not o.ok]
    summaries = ("nothing escaped", runners.NO_ATTACKER_JOB)
    kinds = Counter(o.kind for o in outcomes if "(all files)" not in o.name and o.name not in summaries)
    controls = sum(1 for o in outcomes if o.kind == "gcode" and "valid control" in o.detail)
    errors = [r for r in records.records if r.levelno >= logging.ERROR or r.exc_info]
    drill_report(
        "bad-input corpus", inputs=sum(kinds.values()) - controls,
        **{kind.replace("-", "_"): n for kind, n in kinds.items()},
        valid_controls=controls, failed=len(failed),
        error_log_lines=len(errors), survived=", ".join(survived),
    )  # fmt: skip
    assert not failed, "inputs without their clear error:\n" + "\n".join(map(str, failed))
    assert not errors, "errors in the log:\n" + "\n".join(f"{r.name}: {r.getMessage()}" for r in errors[:20])
    assert sum(kinds.values()) - controls >= 60


async def still_serving(rig: CorpusRig, mqtt: Recorder) -> list[str]:
    """After the corpus: OPC UA Good, an MQTT write, a valid job, a valid COPYDATA frame; what passed."""
    machine = rig.gateway.tree.machines[MACHINE]
    passed = []
    client = Client(f"opc.tcp://127.0.0.1:{rig.opcua_port}/cnc-gateway", timeout=5)
    await client.connect()
    try:
        for path in ("Axes/X/Position", "Feed/Override", "Machine/State"):
            dv = await client.get_node(f"ns=2;s={MACHINE}/{path}").read_data_value(raise_on_bad_status=False)
            assert dv.StatusCode is None or dv.StatusCode.is_good(), (path, dv.StatusCode)
        assert await client.get_node(f"ns=2;s={MACHINE}/Status/Connected").read_value() is True
    finally:
        await client.disconnect()
    passed.append("opcua")

    topic = f"cnc/{MACHINE}/feed/override"
    before = len(mqtt.on(f"{topic}/set/result"))
    mqtt.publish(f"{topic}/set", b"77")
    await wait_until(
        lambda: len(mqtt.on(f"{topic}/set/result")) > before, timeout=10, message="the write's answer"
    )
    assert mqtt.on(f"{topic}/set/result")[before].json() == {"ok": True}
    await wait_until(
        lambda: (mqtt.last_json(topic) or {}).get("value") == 77, timeout=10, message="77 mirrored"
    )
    assert rig.sim.machine.override == 77
    passed.append("mqtt")

    reply = await in_thread(runners.stor, rig.inbox_port, MACHINE, "after-corpus.nc", GOOD)
    assert reply.startswith("226 J"), reply
    seq = int(reply.split()[1][1:])
    await wait_until(
        lambda: rig.queue.get(seq).state is JobState.DELIVERED, timeout=20, message="the valid job"
    )
    assert (rig.store / "DATA" / "Programs" / "after-corpus.nc").read_bytes() == GOOD
    passed.append("jobs")

    reader, writer = await asyncio.open_connection("127.0.0.1", await rig.copydata_port())
    try:
        frame = struct.pack("<IIHHH", 1, 6, OVERRIDE_ID, 2, 55)  # dwData=1: Feed/Override = 55
        writer.write(frame)
        await writer.drain()
        await wait_until(lambda: rig.sim.machine.override == 55, timeout=10, message="the COPYDATA write")
        await wait_until(lambda: machine.nodes["Feed/Override"].sample.value == 55, timeout=10)
    finally:
        writer.close()
        del reader
    passed.append("copydata")
    return passed
