"""MQTT: the variable tree as topics, liveness, store-and-forward and write-back (paho-mqtt)."""

from __future__ import annotations

from gateway.settings.sections import Section
from gateway.sinks.base import Sink, SinkContext, SinkSpec
from gateway.sinks.mqtt.config import MachineMqtt, MqttConfig, VariableMqtt

SECTION = Section("mqtt", MqttConfig)


def _create(context: SinkContext) -> Sink | None:
    config = context.section(SECTION)
    if config is None:  # no `mqtt:` in the gateway file: no broker to reach
        return None
    from gateway.sinks.mqtt.sink import MqttSink

    return MqttSink(context.tree, config, context.state_dir, context.mappings, base_dir=context.base_dir)


SPEC = SinkSpec(
    name="mqtt",
    summary="topics and JSON payloads, /set writes, commands, store-and-forward (paho-mqtt)",
    create=_create,
    section=SECTION,
    machine_sections=(Section("mqtt", MachineMqtt),),
    variable_sections=(Section("mqtt", VariableMqtt),),
)
