"""The Sparkplug B sink: the gateway as one edge node, every machine one of its devices.

`sink.py` runs the session (connect with the NDEATH will, births, data, deaths, store-and-forward
gated by the primary host's STATE); `devices.py` turns the tree into metrics; `node.py` holds the
edge node's own metrics; `commands.py` carries NCMD and DCMD out through the tree's one write path;
`bdseq.py` keeps the birth/death number across restarts. Payloads and topics come from the pure
codec, gateway/codecs/sparkplug/; the MQTT link (the connection, store-and-forward, the bounds of
requests) from gateway/sinks/mqtt_link/, as the MQTT sink's.
"""

from __future__ import annotations

from gateway.settings.sections import Section
from gateway.sinks.base import Sink, SinkContext, SinkSpec
from gateway.sinks.sparkplug.config import SparkplugConfig

SECTION = Section("sparkplug", SparkplugConfig)


def _create(context: SinkContext) -> Sink | None:
    config = context.section(SECTION)
    if config is None:  # every machine a device of one Sparkplug B edge node, when asked for
        return None
    from gateway.sinks.sparkplug.sink import SparkplugSink

    broker = config.connection(context.config.gateway.mqtt)  # its own broker, or the mqtt: section's
    return SparkplugSink(
        context.tree, config, broker, context.state_dir, context.mappings, base_dir=context.base_dir
    )


SPEC = SinkSpec(
    name="sparkplug",
    summary="a Sparkplug B edge node: births, DDATA, deaths, DCMD/NCMD writes (paho-mqtt)",
    create=_create,
    section=SECTION,
)
