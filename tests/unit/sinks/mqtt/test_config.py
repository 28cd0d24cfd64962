"""MQTT settings in gateway and mapping files: defaults, precedence, secrets from the environment."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config.loader import load
from gateway.config.mapping import MachineMapping
from gateway.errors import ConfigError
from gateway.model.tree import VariableTree
from gateway.sinks.mqtt.config import MqttConfig
from gateway.sinks.mqtt.routes import Routes

ROOT = Path(__file__).resolve().parents[4]


def test_a_gateway_file_without_mqtt_has_no_broker(tmp_path: Path) -> None:
    (tmp_path / "g.yaml").write_text(
        "machines: [../../mappings/laser-sim.yaml]\n".replace("../../", f"{ROOT}/")
    )
    assert load([tmp_path / "g.yaml"], environ={}).gateway.mqtt is None
    assert load([ROOT / "mappings" / "laser-sim.yaml"], environ={}).gateway.mqtt is None


def test_mqtt_section_with_a_password_from_the_environment(tmp_path: Path) -> None:
    (tmp_path / "g.yaml").write_text(
        f"machines: [{ROOT}/mappings/laser-sim.yaml]\n"
        "mqtt:\n  host: broker.local\n  port: 8883\n  username: gw\n  password: ${MQTT_PASSWORD}\n"
        "  protocol: 5\n  tls: {ca: ca.pem}\n"
    )
    cfg = load([tmp_path / "g.yaml"], environ={"MQTT_PASSWORD": "s3cret"}).gateway.mqtt
    assert cfg is not None and cfg.password is not None
    assert cfg.password.get_secret_value() == "s3cret" and "s3cret" not in repr(cfg)
    assert cfg.protocol == "5" and cfg.tls is not None and cfg.tls.verify is True
    with pytest.raises(ConfigError, match="MQTT_PASSWORD is not set"):
        load([tmp_path / "g.yaml"], environ={})


def test_the_compose_gateway_file_loads() -> None:
    config = load([ROOT / "mappings" / "compose" / "gateway.yaml"], environ={"MQTT_HOST": "mosquitto"})
    assert config.gateway.mqtt is not None and config.gateway.mqtt.host == "mosquitto"
    assert config.machines[0].machine == "laser-sim"


def test_settings_precedence_variable_then_machine_then_gateway() -> None:
    mapping = MachineMapping.model_validate(
        {
            "machine": "m1",
            "driver": {"endpoint": "opc.tcp://h:1"},
            "mqtt": {"qos": 2, "writable": True},
            "variables": [
                {"path": "A", "source": "a", "type": "Double"},
                {
                    "path": "B",
                    "source": "b",
                    "type": "Double",
                    "access": "readwrite",
                    "mqtt": {"qos": 0, "retain": False},
                },
                {
                    "path": "C",
                    "source": "c",
                    "type": "Double",
                    "access": "readwrite",
                    "mqtt": {"writable": False},
                },
                {"path": "D", "source": "d", "type": "Double", "mqtt": {"payload": "raw"}},
            ],
        }
    )
    tree = VariableTree([mapping.definition()])
    routes = Routes(tree, MqttConfig(qos=1, retain=True, prefix="plant"), {"m1": mapping})
    r = {n.path: routes.by_node[n] for n in tree.machines["m1"].mapped}
    assert (r["A"].qos, r["A"].retain, r["A"].writable, r["A"].raw) == (2, True, False, False)  # read-only
    assert (r["B"].qos, r["B"].retain, r["B"].writable) == (0, False, True)
    assert r["C"].writable is False and r["D"].raw is True
    assert r["A"].topic == "plant/m1/a"
    assert routes.machine_status["m1"] == "plant/m1/status" and routes.status_topic == "plant/status"
    assert not any(n.path.startswith("Status/") for n in routes.by_node)


def test_response_topics_and_max_packet_size_are_checked_with_their_line(tmp_path: Path) -> None:
    (tmp_path / "g.yaml").write_text(
        f"machines: [{ROOT}/mappings/laser-sim.yaml]\n"
        "mqtt:\n"
        "  response_topics:\n"
        "    - replies/#\n"
        "    - cell/7#\n"
        "    - a/#/b\n"
        "    - $SYS/x\n"
    )
    with pytest.raises(ConfigError) as info:
        load([tmp_path / "g.yaml"], environ={})
    found = {(i.line, i.key): i.message for i in info.value.issues}
    assert "'+' must be a whole level and '#' the whole last level" in found[(5, "mqtt.response_topics[1]")]
    assert "'#' the whole last level" in found[(6, "mqtt.response_topics[2]")]
    assert "must not start with '$'" in found[(7, "mqtt.response_topics[3]")]
    assert len(found) == 3
    (tmp_path / "g.yaml").write_text(
        f"machines: [{ROOT}/mappings/laser-sim.yaml]\nmqtt:\n  max_packet_size: 65536\n"
    )
    with pytest.raises(ConfigError, match="must leave room for max_set_payload \\(65536\\)"):
        load([tmp_path / "g.yaml"], environ={})


def test_max_packet_size_defaults_above_what_each_face_decodes() -> None:
    from gateway.codecs.sparkplug.wire import MAX_PAYLOAD
    from gateway.sinks.sparkplug.config import SparkplugConfig

    cfg = MqttConfig()
    assert cfg.max_packet_size == 1024 * 1024 > cfg.max_set_payload and cfg.response_topics == []
    assert SparkplugConfig().max_packet_size == 2 * 1024 * 1024 > MAX_PAYLOAD
    with pytest.raises(ValueError, match="greater than or equal to 1049600"):
        SparkplugConfig(max_packet_size=MAX_PAYLOAD)
