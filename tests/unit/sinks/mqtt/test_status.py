"""The machine status document folds the machine's Status/* variables into one retained payload."""

from __future__ import annotations

import json

from gateway.config.mapping import MachineMapping
from gateway.model.tree import VariableTree
from gateway.sinks.mqtt.status import gateway_offline, machine_payload, snake, status_nodes


def machine():  # type: ignore[no-untyped-def]
    mapping = MachineMapping.model_validate(
        {
            "machine": "m1",
            "driver": {"endpoint": "opc.tcp://plc:4840"},
            "variables": [{"path": "A", "source": "a", "type": "Double"}],
        }
    )
    return VariableTree([mapping.definition()]).machines["m1"]


def test_document_follows_the_connection() -> None:
    m = machine()
    m.add_internal("Status/MqttDropped", "UInt64", "", 0)
    m.status.connected()
    doc = json.loads(machine_payload(status_nodes(m)))
    assert (
        doc["state"] == "connected" and doc["reason"] == "" and doc["reconnects"] == 0 and doc["dropped"] == 0
    )
    assert doc["endpoint"] == "opc.tcp://plc:4840" and doc["since"].endswith("Z")
    assert not {"connected", "last_change", "mqtt_state"} & set(doc)
    m.status.disconnected("connection refused")
    m.status.connected()
    m.status.disconnected("watchdog: no answer in 2 s")
    doc = json.loads(machine_payload(status_nodes(m)))
    assert doc["state"] == "disconnected" and doc["reason"] == "watchdog: no answer in 2 s"
    assert doc["reconnects"] == 1


def test_status_variables_added_by_other_components_get_a_snake_case_key() -> None:
    m = machine()
    m.add_internal("Status/Jobs/QueueLength", "UInt32", "", 3)
    assert snake("Status/Jobs/QueueLength") == "jobs_queue_length"
    assert json.loads(machine_payload(status_nodes(m)))["jobs_queue_length"] == 3


def test_offline_document() -> None:
    assert json.loads(gateway_offline("1.2", "gateway stopped")) == {
        "state": "offline",
        "version": "1.2",
        "reason": "gateway stopped",
    }
