"""The gateway file's `sparkplug:` section: ids Sparkplug allows, and which broker the edge node uses."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from gateway.config.gateway import GatewayConfig
from gateway.config.loader import load
from gateway.errors import ConfigError
from gateway.sinks.sparkplug.config import SparkplugBroker, SparkplugConfig


def test_without_the_section_nothing_sparkplug_is_configured() -> None:
    assert GatewayConfig.model_validate({"mqtt": {}}).sparkplug is None


def test_the_edge_node_shares_the_mqtt_sections_broker_over_a_connection_of_its_own() -> None:
    gw = GatewayConfig.model_validate({
        "mqtt": {"host": "broker.plant", "port": 8883, "client_id": "gw-7", "username": "u", "password": "p",
                 "protocol": 5, "keepalive": 12, "reconnect": {"initial": 0.2, "max": 4}},
        "sparkplug": {"group_id": "hall-2", "edge_node_id": "gw-7", "primary_host_id": "ignition"},
    })  # fmt: skip
    assert gw.sparkplug is not None and gw.mqtt is not None
    broker = gw.sparkplug.connection(gw.mqtt)
    assert (broker.host, broker.port, broker.protocol, broker.keepalive) == ("broker.plant", 8883, "5", 12)
    assert broker.client_id == "gw-7-sparkplug"  # one client id per connection
    assert (
        broker.username == "u" and broker.password is not None and broker.password.get_secret_value() == "p"
    )
    assert broker.reconnect.max == 4
    assert (gw.sparkplug.group_id, gw.sparkplug.edge_node_id, gw.sparkplug.primary_host_id) == (
        "hall-2",
        "gw-7",
        "ignition",
    )


def test_an_mqtt_section_without_a_client_id_leaves_the_default_to_the_sink() -> None:
    gw = GatewayConfig.model_validate({"mqtt": {}, "sparkplug": {}})
    assert gw.sparkplug is not None
    assert gw.sparkplug.connection(gw.mqtt).client_id == ""
    assert (gw.sparkplug.group_id, gw.sparkplug.edge_node_id, gw.sparkplug.primary_host_id) == (
        "cnc",
        "cnc-gateway",
        None,
    )


def test_a_broker_of_its_own_wins_and_needs_no_mqtt_section() -> None:
    gw = GatewayConfig.model_validate(
        {"sparkplug": {"broker": {"host": "scada", "port": 1884, "protocol": "5"}}}
    )
    assert gw.sparkplug is not None and gw.mqtt is None
    assert gw.sparkplug.connection(None) == SparkplugBroker(host="scada", port=1884, protocol="5")


def test_without_any_broker_the_file_is_refused_where_the_section_is(tmp_path: Path) -> None:
    path = tmp_path / "gateway.yaml"
    path.write_text("state_dir: state\nsparkplug:\n  group_id: plant\n", encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        load([path])
    assert "gateway.yaml:2: sparkplug: no broker: give sparkplug.broker, or an mqtt: section" in str(
        caught.value
    )


@pytest.mark.parametrize(
    ("field", "value", "fragment"),
    [
        ("group_id", "plant/1", "contains '/'"),
        ("group_id", "STATE", "where host applications publish"),
        ("group_id", "", "is empty"),
        ("edge_node_id", "gw+1", "contains '+'"),
        ("edge_node_id", "gw#", "contains '#'"),
        ("primary_host_id", "scada/1", "contains '/'"),
    ],
)
def test_ids_sparkplug_reserves_are_refused(field: str, value: str, fragment: str) -> None:
    with pytest.raises(ValidationError) as caught:
        SparkplugConfig.model_validate({field: value})
    assert fragment in str(caught.value)


def test_buffer_limits() -> None:
    assert SparkplugConfig().buffer.limit == 10_000 and not SparkplugConfig().buffer.persist
    with pytest.raises(ValidationError):
        SparkplugConfig.model_validate({"buffer": {"limit": 0}})
    with pytest.raises(ValidationError):
        SparkplugConfig.model_validate({"broker": {"client_id": "two words"}})
