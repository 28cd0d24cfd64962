"""configure_access: roles are checked with or without users, so anonymous OPC UA clients only read unless
the gateway file says otherwise; the doors a mapping opens itself act with a role that is recorded and
checked alike; and what each door may change (gateway/model/reach.py) is what start-up reports."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest

from gateway.app import configure_access
from gateway.auth.passwords import hash_password
from gateway.commands.runner import install_commands
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config, load_mapping
from gateway.errors import AccessDenied
from gateway.model.context import WriteContext
from gateway.model.reach import reach
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig
from gateway.sinks.mqtt.routes import Routes
from gateway.sinks.mqtt.writes import report_writers
from tests.trees import MappedTree

ROOT = Path(__file__).resolve().parents[2]
MACHINE = "laser-sim"
USERS = [{"name": "olga", "role": "operator", "password_hash": hash_password("x", n=2**4)}]


class Store:
    """Records what reaches the controller."""

    def __init__(self) -> None:
        self.written: list[tuple[str, Any]] = []

    async def write(self, node: Any, raw: Any) -> None:
        self.written.append((node.path, raw))


def tree_for(
    gateway: dict[str, Any] | None = None, mqtt: MachineMqtt | None = None
) -> tuple[MappedTree, Store]:
    mapping = load_mapping(ROOT / "mappings" / "laser-sim.yaml", environ={})
    mapping = mapping.model_copy(update={"mqtt": mqtt, "jobs": None})
    config = Config(GatewayConfig.model_validate(gateway or {}), (mapping,), ROOT)
    tree = MappedTree(config.mappings.values())
    configure_access(config, tree)
    install_commands(tree, config.mappings)
    store = Store()
    tree.machines[MACHINE].writer = store
    return tree, store


def test_without_users_roles_are_checked_and_the_mappings_own_doors_act_with_the_highest_role() -> None:
    tree, _ = tree_for()
    access = tree.access
    assert access.enabled
    assert access.mqtt_role(MACHINE) == "admin"
    assert access.role_of(WriteContext("jobs")) == "operator"  # access.jobs_role, as with users


def test_copydata_writes_never_get_an_implied_role_only_the_one_the_gateway_file_names() -> None:
    """Issue 23: without users, COPYDATA replies used to act as admin; now as access.copydata_role only."""
    tree, _ = tree_for()
    assert tree.access.role_of(WriteContext("copydata")) is None
    named, _ = tree_for({"access": {"copydata_role": "operator"}})
    assert named.access.role_of(WriteContext("copydata")) == "operator"


def test_with_users_a_door_without_a_role_is_refused_and_access_off_checks_nothing() -> None:
    tree, _ = tree_for({"users": USERS})
    assert tree.access.enabled and tree.access.mqtt_role(MACHINE) is None
    assert tree.access.role_of(WriteContext("copydata")) is None
    forced, _ = tree_for({"access": {"enabled": True}})
    assert forced.access.mqtt_role(MACHINE) is None
    off, _ = tree_for({"access": {"enabled": False}})
    assert not off.access.enabled


async def test_a_role_named_in_the_mapping_is_the_role_checked_even_without_users() -> None:
    """The audit records the MQTT writers' role; it is also the one the write is judged by."""
    tree, store = tree_for(mqtt=MachineMqtt(writable=True, writer_role="operator"))
    machine = tree.machines[MACHINE]
    ctx = WriteContext("mqtt", None, tree.access.mqtt_role(MACHINE))
    await machine.write("Feed/Override", 50, ctx)
    with pytest.raises(AccessDenied):
        await machine.write("Machine/Mode", 1, ctx)  # an engineer's variable
    assert store.written == [("Feed/Override", 50)]


async def test_anonymous_opcua_clients_are_viewers_and_viewers_write_nothing() -> None:
    tree, store = tree_for()
    machine = tree.machines[MACHINE]
    with pytest.raises(AccessDenied):
        await machine.write("Feed/Override", 50, WriteContext("opcua", None, "viewer"))
    assert store.written == []
    assert not reach(machine, "viewer")


def test_reach_lists_what_a_role_may_change() -> None:
    tree, _ = tree_for()
    operator = reach(tree.machines[MACHINE], "operator")
    assert "Feed/Override" in operator.writes and "Control/Start" in operator.writes
    assert "Machine/Mode" not in operator.writes and "Status/Connected" not in operator.writes
    assert "Commands.start" in operator.calls and operator.acknowledge
    text = operator.describe()
    assert (
        text.startswith("laser-sim: write Feed/Override, Control/Start, ")
        and "; call Commands.start, " in text
    )
    assert text.endswith("; acknowledge alarms")
    engineer = reach(tree.machines[MACHINE], "engineer", variables=[], objects=(), alarms=False)
    assert not engineer and engineer.what() == "change nothing"


def test_mqtt_says_at_start_up_what_its_requests_may_change_and_as_whom(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    tree, _ = tree_for(mqtt=MachineMqtt(writable=True, commands=True))
    report_writers(tree, Routes(tree, MqttConfig(), tree.mappings), tree.mappings)
    [line] = [r.getMessage() for r in caplog.records if r.getMessage().startswith("MQTT: requests")]
    assert line.startswith("MQTT: requests to laser-sim act as admin and may write Feed/Override, ")
    assert "Machine/Mode" in line and "; call Commands.start, " in line and "Commands.select-program" in line

    caplog.clear()
    tree, _ = tree_for({"users": USERS}, mqtt=MachineMqtt(writable=True))
    report_writers(tree, Routes(tree, MqttConfig(), tree.mappings), tree.mappings)
    assert any("are refused: they have no role" in r.getMessage() for r in caplog.records)
