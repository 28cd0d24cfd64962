"""The MQTT link's lines in each sink's words: a broker that is not there, and what is left at a stop.

Both sinks say these through gateway/sinks/mqtt_link/link.py; each in its own words and under its own
logger, as before the link was shared (issue 24).
"""

from __future__ import annotations

import logging
import re
from datetime import UTC, datetime
from pathlib import Path

import pytest

from tests.integration.mqtt.conftest import mqtt_config
from tests.integration.mqtt.test_sink import make_tree, running
from tests.integration.sparkplug.conftest import sink_rig, sparkplug_config, typed_mapping
from tests.waiting import free_port, wait_until


def lines(caplog: pytest.LogCaptureFixture, logger: str, pattern: str) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name == logger and re.fullmatch(pattern, r.getMessage())]


async def test_mqtt_says_the_broker_is_away_and_what_a_stop_without_a_journal_loses(
    caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    port = free_port()
    tree = make_tree()
    machine = tree.machines["m1"]
    async with running(tree, mqtt_config(port), tmp_path) as sink:
        await wait_until(lambda: sink.attempts >= 1, message="a failed attempt")
        machine.ingest(machine.nodes["Axes/X/Position"], 1.5, datetime.now(UTC))  # QoS 1: kept
        await wait_until(lambda: sink.backlog is not None and sink.backlog.counted > 0)
    [failed, *_] = lines(
        caplog,
        "gateway.sinks.mqtt.sink",
        rf"MQTT: mqtt://127\.0\.0\.1:{port} refused the TCP connection \(is the broker running\?\); "
        r"retrying in \d+\.\d s \(\d+ messages waiting\)",
    )
    assert failed.levelno == logging.WARNING
    [lost] = lines(
        caplog,
        "gateway.sinks.mqtt.sink",
        r"MQTT: [1-9]\d* messages were not delivered \(buffer\.persist is off\)",
    )
    assert lost.levelno == logging.WARNING


async def test_mqtt_says_what_it_keeps_in_its_journal_for_the_next_start(
    caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    tree = make_tree()
    machine = tree.machines["m1"]
    async with running(tree, mqtt_config(free_port(), buffer={"persist": True}), tmp_path) as sink:
        machine.ingest(machine.nodes["Axes/X/Position"], 1.5, datetime.now(UTC))
        await wait_until(lambda: sink.backlog is not None and sink.backlog.counted > 0)
    journal = re.escape(str(tmp_path / "mqtt-backlog.sqlite3"))
    [kept] = lines(
        caplog, "gateway.sinks.mqtt.sink", rf"MQTT: [1-9]\d* messages kept in {journal} for the next start"
    )
    assert kept.levelno == logging.INFO


async def test_sparkplug_says_the_broker_is_away_and_what_a_stop_without_a_journal_loses(
    caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    port = free_port()
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(port)) as rig:
        await wait_until(lambda: rig.sink.attempts >= 1, message="a failed attempt")
        machine = rig.tree.machines["m1"]
        machine.ingest(machine.nodes["Axes/X/Position"], 1.5, datetime.now(UTC))  # no session: stored
        await wait_until(lambda: rig.sink.backlog is not None and rig.sink.backlog.counted > 0)
    [failed, *_] = lines(
        caplog,
        "gateway.sinks.sparkplug.sink",
        rf"Sparkplug: mqtt://127\.0\.0\.1:{port} refused the TCP connection \(is the broker running\?\); "
        r"retrying in \d+\.\d s \(\d+ DDATA messages stored\)",
    )
    assert failed.levelno == logging.WARNING
    [lost] = lines(
        caplog,
        "gateway.sinks.sparkplug.sink",
        r"Sparkplug: [1-9]\d* stored DDATA messages were not delivered \(buffer\.persist is off\)",
    )
    assert lost.levelno == logging.WARNING
